"""Fixtures shared by the window tests."""

from __future__ import annotations

import pytest
from window_synthetic import streaming_runs


@pytest.fixture(scope="session")
def runs():
    """window_synthetic.streaming_runs(), built once per test process (test_window_fast, test_window_kernel)."""
    return streaming_runs()
