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


def test_integral_of_the_integral_by_hand_and_by_quadrature(f):
    """integral2 (piecewise quadratic, exact) against hand values and scipy's quad of ``integral``; the scalar twin
    gives the same floats; mean_integral_over is its difference quotient."""
    from scipy.integrate import quad

    assert float(f.integral2(100.0)) == 0.5 * 0.5 * 100.0**2  # 0.5 s^2 / 2 up to the first break
    assert float(f.integral2(0.0)) == 0.0
    scalar = ScalarPiecewise(f)
    for b in (-150.0, 37.0, 100.0, 180.0, 250.0, 999.0, 1300.0):
        ref, _ = quad(lambda x: float(f.integral(x)), 0.0, b, points=[p for p in f.breaks if min(0, b) < p < max(0, b)])
        assert float(f.integral2(b)) == pytest.approx(ref, rel=1e-12, abs=1e-9)
        assert scalar.integral2(b) == float(f.integral2(b))
        a = b - 140.0
        assert scalar.mean_integral_over(a, b) == float(f.mean_integral_over(a, b))
        assert float(f.mean_integral_over(a, b)) == pytest.approx((ref - float(f.integral2(a))) / 140.0, rel=1e-12)
    assert float(f.mean_integral_over(300.0, 300.0)) == float(f.integral(300.0))  # an empty interval


def test_means_are_mean_over_and_mean_integral_over(f):
    """The fused per-sample form gives both means' floats exactly (empty intervals and the ends included)."""
    rng = np.random.default_rng(11)
    scalar = ScalarPiecewise(f)
    heads = np.concatenate((rng.uniform(-200.0, 1300.0, 300), f.breaks, f.breaks + 1e-10))
    for head in heads:
        for length in (0.0, 1e-10, 37.5, 180.0, 1500.0):
            a, b = float(head - length), float(head)
            assert scalar.means(a, b) == (scalar.mean_over(a, b), scalar.mean_integral_over(a, b))
