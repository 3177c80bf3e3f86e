"""The speed odometer (train_calib.odometry): its look-up from the end is the bisection it replaces."""

from __future__ import annotations

import bisect
from collections import deque

import numpy as np

from train_calib.odometry import NS, Odometer, _index_from_end


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
