"""The features' fast paths against what they replace: the point columns (``boundaries.columns``) are
``np.asarray``'s, and the remembered hold test (``FinalPhases._hold_start``) answers as the test run afresh."""

from __future__ import annotations

import math

import numpy as np
from test_features import profile_series

from train_calib.estimation import COASTING, CRUISING, FeatureAccumulator, FeatureConfig
from train_calib.estimation.features.boundaries import _T, _V_FIT, columns, new_point
from train_calib.estimation.features.phases import TailPoint


def test_columns_are_those_of_asarray_with_its_layout():
    """The same values, and columns that are not contiguous either (BLAS adds a strided vector in its own order)."""
    rng = np.random.default_rng(1)
    for n in (4, 5, 17, 60, 301):
        pts = [new_point((1e4 + k + rng.random(), 10.0 * k, 20.0 + rng.normal(), -0.1, 20.0, k % 4)) for k in range(n)]
        ref = np.asarray(pts, dtype=float)
        got = columns(pts, _T, _V_FIT)
        assert got[:, 0].tobytes() == ref[:, _T].tobytes() and got[:, 1].tobytes() == ref[:, _V_FIT].tobytes()
        assert not got[:, 1].flags.c_contiguous and not ref[:, _V_FIT].flags.c_contiguous
        for a, b in ((got[:, 1], ref[:, _V_FIT]), (got[:, 0], ref[:, _T])):
            assert float(a @ a) == float(b @ b) and float(a.sum()) == float(b.sum())
    tail = [TailPoint(float(k), 2.0 * k, 0.01 * k) for k in range(7)]
    assert columns(tail, 0, 2).tolist() == np.asarray(tail)[:, [0, 2]].tolist()
    assert columns([], 0, 1).shape == (0, 2)


def test_the_remembered_hold_test_answers_as_a_fresh_one():
    """A feature snapshot after every sample (as the feature node at each change, and more), with the hold test's
    memory and with it cleared before each: the same final coast, float for float."""
    knots = [(0, 140), (100, 140), (600, 45), (610, 40), (660, 40), (680, 0), (720, 0)]
    est, t = profile_series(knots, period=1.0)
    regimes = np.where(t <= 100, CRUISING, COASTING).astype(np.uint8)  # the hold at 40 km/h labelled coasting
    cfg = FeatureConfig()
    remembered, fresh = FeatureAccumulator(cfg), FeatureAccumulator(cfg)
    for i in range(len(est)):
        remembered.update(est.sample(i), int(regimes[i]))
        fresh.update(est.sample(i), int(regimes[i]))
        for ph in fresh._final._coasts:
            ph.hold_memo = None
        a, b = remembered.snapshot(), fresh.snapshot()
        for x, y in (
            (a.final_coast_duration, b.final_coast_duration),
            (a.final_coast_distance, b.final_coast_distance),
        ):
            assert x == y or (math.isnan(x) and math.isnan(y)), (i, x, y)
    assert math.isfinite(a.final_coast_duration)
