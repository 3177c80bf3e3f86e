"""The pairer's searches from the newest back against the plain scans they replace (the same sample, ties too)."""

from __future__ import annotations

from collections import deque

import numpy as np

from train_calib.ingest.config import IngestConfig, Settings
from train_calib.ingest.pairing import Pairer, nearest, nearest_in_order
from train_calib.ingest.records import NS, SpeedSample


def _stamps(rng: np.random.Generator, n: int) -> list[int]:
    """Increasing stamps with repeats, on a coarse grid so that ties of distance occur."""
    return sorted(int(x) * NS // 4 for x in rng.integers(0, 40, n))


def test_nearest_in_order_is_nearest():
    rng = np.random.default_rng(17)
    for _ in range(150):
        samples = deque(SpeedSample(t, float(k)) for k, t in enumerate(_stamps(rng, int(rng.integers(0, 9)))))
        for t in range(-NS, 11 * NS, NS // 8):
            for tolerance in (0.0, 0.5 * NS, 1.0 * NS, 5.0 * NS):
                assert nearest_in_order(samples, t, tolerance) is nearest(samples, t, tolerance)


def _speed_at_forward(speeds: deque, t_ns: int, default: float) -> float:
    """The scan from the oldest (the reference of Pairer.speed_at)."""
    before = after = None
    for sp in speeds:
        if sp.stamp_ns <= t_ns:
            before = sp
        else:
            after = sp
            break
    if before is None:
        return after.v if after is not None else default
    if after is None or before.stamp_ns == t_ns:
        return before.v
    w = (t_ns - before.stamp_ns) / (after.stamp_ns - before.stamp_ns)
    return before.v + w * (after.v - before.v)


def test_speed_at_is_the_forward_scan():
    rng = np.random.default_rng(23)
    pairer = Pairer(Settings(IngestConfig(), None))
    for _ in range(120):
        pairer.speeds = deque(SpeedSample(t, float(rng.uniform(0, 40))) for t in _stamps(rng, int(rng.integers(0, 9))))
        for t in range(-NS, 11 * NS, NS // 8):
            assert pairer.speed_at(t, -1.0) == _speed_at_forward(pairer.speeds, t, -1.0)
