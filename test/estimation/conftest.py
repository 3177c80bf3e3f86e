"""Fixtures of the estimator tests (the shared cases live in estimation_cases.py)."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))

from synthetic import virm_like_train


@pytest.fixture
def train():
    return virm_like_train()
