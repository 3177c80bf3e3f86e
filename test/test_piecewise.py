"""PiecewiseConstant and its scalar twin ScalarPiecewise (the ingest's per-sample form): the same floats."""

from __future__ import annotations

import numpy as np
import pytest

from train_calib.piecewise import PiecewiseConstant, ScalarPiecewise


@pytest.fixture
def f():
    return PiecewiseConstant([0.0, 100.0, 250.0, 1000.0], [0.5, -2.0, 3.25, 0.0])


def test_values_and_means_by_hand(f):
    scalar = ScalarPiecewise(f)
    assert scalar(-5.0) == 0.5 and scalar(100.0) == -2.0 and scalar(5000.0) == 0.0
    assert scalar.integral(150.0) == 50.0 - 100.0
    assert scalar.mean_over(50.0, 150.0) == (25.0 - 100.0) / 100.0
    assert scalar.mean_over(300.0, 300.0) == 3.25  # an empty interval: f(b)


def test_scalar_twin_gives_the_numpy_floats_exactly(f):
    rng = np.random.default_rng(7)
    scalar = ScalarPiecewise(f)
    heads = np.concatenate((rng.uniform(-200.0, 1300.0, 400), f.breaks, f.breaks + 1e-10))
    for head in heads:
        for length in (0.0, 1e-10, 37.5, 180.0, 1500.0):
            a, b = float(head - length), float(head)
            assert scalar(b) == float(f(b))
            assert scalar.integral(b) == float(f.integral(b))
            assert scalar.mean_over(a, b) == float(f.mean_over(a, b))
