"""Feature rules with exactly known answers, online (FeatureAccumulator) and offline (extract_features) alike: the
effort line's intercept and slope, and the cruise speed as the duration-weighted median over samples of unequal
spacing (issue 23's mutation test: a wrong intercept sign, a quartile for the median and a per-sample weight passed
the other feature tests, whose lines were flat and whose samples were evenly spaced)."""

from __future__ import annotations

import numpy as np
import pytest

from train_calib.estimation import (
    BRAKING,
    CRUISING,
    TRACTION,
    EstimateSeries,
    FeatureAccumulator,
    FeatureConfig,
    extract_features,
)

NS = 1_000_000_000


def _series(t: np.ndarray, v: np.ndarray, effort: np.ndarray, accel: np.ndarray) -> EstimateSeries:
    est = EstimateSeries.empty(t.size)
    est.stamp_ns[:] = np.round(t * NS).astype(np.int64)
    est.v[:], est.effort[:], est.acceleration[:] = v, effort, accel
    est.s[:] = np.concatenate(([0.0], np.cumsum(0.5 * (v[1:] + v[:-1]) * np.diff(t))))
    est.dt[1:] = np.diff(t)
    return est


def _both(est: EstimateSeries, regimes: np.ndarray, cfg: FeatureConfig):
    """(online snapshot after the last sample, offline features) of the run."""
    acc = FeatureAccumulator(cfg)
    for i in range(len(est)):
        acc.update(est.sample(i), int(regimes[i]))
    return acc.snapshot(run_complete=True), extract_features(est, regimes, cfg)


def test_the_max_effort_line_has_the_intercept_and_slope_of_the_efforts():
    """Traction at 0.5 m/s^2 from 3 to 8 m/s (inside the 10-30 km/h window), the effort of each step 0.4 + 0.03
    v_mid N/kg: the fitted line is that one, reported at the steps' mean effort."""
    t = np.arange(11.0)
    v = 3.0 + 0.5 * t
    v_mid = np.concatenate(([v[0]], 0.5 * (v[1:] + v[:-1])))
    effort = 0.4 + 0.03 * v_mid
    est = _series(t, v, effort, np.full(t.size, 0.5))
    for f in _both(est, np.full(t.size, TRACTION), FeatureConfig()):
        assert f.max_tractive_effort_count == 10
        assert f.max_tractive_effort_intercept == pytest.approx(0.4, abs=1e-12)
        assert f.max_tractive_effort_slope == pytest.approx(0.03, abs=1e-12)
        assert f.max_tractive_effort == pytest.approx(float(effort[1:].mean()), abs=1e-12)


def test_the_cruise_speed_is_the_median_over_the_cruising_time_not_over_the_samples():
    """A 35 s cruise at 20 m/s sampled every 0.5 s (70 samples), traction, a 45 s cruise at 25 m/s sampled every
    1 s (45 samples), braking. Over time 35 s at 20 and 45 s at 25: the weighted median is 25 m/s (per sample it
    would be 20, and so would the lower quartile); the phases' own medians are 20 and 25."""
    parts = [
        (np.arange(0.0, 10.0, 1.0), lambda x: 10.0 + x, TRACTION),
        (np.arange(10.0, 45.25, 0.5), lambda x: np.full(x.size, 20.0), CRUISING),
        (np.arange(46.0, 51.0, 1.0), lambda x: x - 25.0, TRACTION),
        (np.arange(51.0, 96.0, 1.0), lambda x: np.full(x.size, 25.0), CRUISING),
        (np.arange(96.0, 101.0, 1.0), lambda x: 120.0 - x, BRAKING),
    ]
    t = np.concatenate([p[0] for p in parts])
    v = np.concatenate([p[1](p[0]) for p in parts])
    regimes = np.concatenate([np.full(p[0].size, p[2]) for p in parts])
    accel = np.gradient(v, t)
    est = _series(t, v, accel + 0.02, accel)
    for f in _both(est, regimes, FeatureConfig()):
        np.testing.assert_array_equal(f.cruise_speeds, [20.0, 25.0])
        assert f.cruise_speed == 25.0
