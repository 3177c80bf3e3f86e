"""The speed odometer (train_calib.odometry): its look-up from the end is the bisection it replaces."""

from __future__ import annotations

import bisect
from collections import deque

import numpy as np

from train_calib.odometry import NS, DelayEstimator, Odometer, _index_from_end


def test_index_from_end_is_bisect_left():
    ts = deque([0, 5, 7, 20, 21, 40])
    for t in range(0, 41):
        assert _index_from_end(ts, t) == bisect.bisect_left(ts, t)


def test_odometer_at_between_and_on_samples():
    """Trapezoid distance, speed interpolated linearly; None outside the history."""
    odometer = Odometer(horizon_s=600.0, max_gap_s=30.0)
    rng = np.random.default_rng(3)
    t, speeds = 0, []
    for _ in range(50):
        t += int(rng.integers(NS // 2, 2 * NS))
        v = float(rng.uniform(0.0, 40.0))
        odometer.add(t, v)
        speeds.append((t, v))
    ts = [s for s, _ in speeds]
    assert odometer.at(ts[0] - 1) is None and odometer.at(ts[-1] + 1) is None
    assert odometer.at(ts[10]) == (odometer._d[10], speeds[10][1])
    mid = (ts[10] + ts[11]) // 2
    d, v = odometer.at(mid)
    w = (mid - ts[10]) / (ts[11] - ts[10])
    assert v == speeds[10][1] + w * (speeds[11][1] - speeds[10][1])
    assert d == odometer._d[10] + 0.5 * (speeds[10][1] + v) * (mid - ts[10]) / NS


def _fixes(n: int, seed: int) -> list[tuple[int, float, float, float]]:
    """(t_ns, s_fix, d, v) of a train accelerating and braking, GNSS 0.3 s late with 4 m noise and a few jumps."""
    rng = np.random.default_rng(seed)
    out, t, d, v = [], 0, 0.0, 0.0
    for k in range(n):
        t += NS
        v = max(0.0, v + float(rng.uniform(-0.6, 0.8)))
        d += v
        s_fix = d - 0.3 * v + float(rng.normal(0.0, 4.0)) + (80.0 if k % 97 == 50 else 0.0)
        out.append((t, s_fix, d, v))
    return out


def test_lazy_delay_fit_is_the_eager_one():
    """The fit of the fixes noted is the same whenever it is read: after every fix (the node's diagnostics), only
    at the end (offline), across a reset and a change of the time constant."""
    fixes = _fixes(400, 5)
    eager, lazy = DelayEstimator(300.0, 4.0), DelayEstimator(300.0, 4.0)
    estimates = []
    for k, fix in enumerate(fixes):
        for estimator in (eager, lazy):
            if k == 150:
                estimator.time_constant_s = 120.0
            if k == 250:
                estimator.reset()
            estimator.add(*fix)
        estimates.append(eager.estimate())
    assert lazy.estimate() == estimates[-1] and lazy.outliers == eager.outliers > 0
    assert estimates[-1] is not None and abs(estimates[-1][0] - 0.3) < 0.2
