"""Fast paths against the readable code they stand for, float for float (outputs must not move by one bit)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from train_calib.estimation import UKFConfig
from train_calib.estimation.coast_regression import median
from train_calib.estimation.ukf import ResistanceEstimator
from train_calib.paths import train_file
from train_calib.train import load_train


def same_float(a: float, b: float) -> bool:
    """Equal bit for bit (NaN equals NaN, 0.0 differs from -0.0)."""
    return float(a).hex() == float(b).hex()


def test_median_is_numpy_median():
    """coast_regression.median equals float(np.median(x)): odd and even sizes, ties, signed zeros, NaN."""
    rng = np.random.default_rng(7)
    for n in [*range(1, 30), 64, 65, 1199, 1200, 4000]:
        for kind in range(6):
            if kind == 0:
                x = rng.normal(size=n)
            elif kind == 1:
                x = np.round(rng.normal(size=n), 1)  # ties
            elif kind == 2:
                x = np.abs(rng.standard_cauchy(n))
            elif kind == 3:
                x = rng.choice([-0.0, 0.0, 1.0, -1.0], n)  # signed zeros in the middle
            elif kind == 4:
                x = np.abs(rng.normal(size=n) * 1e-3)
            else:
                x = rng.normal(size=n)
                x[rng.integers(n)] = np.nan
            assert same_float(median(x), float(np.median(x))), (n, kind)


@pytest.mark.parametrize("seed", range(3))
def test_euler_speed_directions_equal_the_general_ones(seed):
    """The Euler rule's written-out sigma directions equal _speed_directions_any (the closure) float for float."""
    est = ResistanceEstimator(load_train(train_file("virm6")), UKFConfig(integration="euler"))
    assert not est._midpoint
    rng = np.random.default_rng(seed)
    for _ in range(2000):
        v = float(rng.choice([0.0, rng.uniform(0.0, 60.0), rng.uniform(0.0, 1e-3)]))
        x = [0.0, v, *(float(r) for r in rng.uniform(0.0, 1.0, 3) * [0.02, 3e-4, 8e-5])]
        l10, l11 = float(rng.normal() * 0.1), float(abs(rng.normal()) * 10 ** rng.uniform(-4, 1))
        h = float(rng.uniform(0.05, 10.0))
        vh = v + h * float(rng.normal())
        fast = est._speed_directions(x, vh, h, l10, l11)
        reference = est._speed_directions_any(x, vh, h, l10, l11)
        assert all(same_float(a, b) for a, b in zip(fast, reference, strict=True))
    assert math.isfinite(sum(fast))
