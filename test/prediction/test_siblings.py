"""The validation family's units (bench/prediction/siblings.py): a sibling run is the same unit on another day -- the
held-out run's true resistance drifted by at most 3 %, the same train, track and family settings, other samples --
and the family's own runs are what they were."""

from __future__ import annotations

import numpy as np
import pytest
from repo_paths import bench_module

S = bench_module("prediction/siblings.py", "prediction_siblings")
HOLD_10S = next(f for f in S.family.FAMILIES if f.name == "hold_10s")


def _coasting_resistance_error(streams, truth, track, train) -> tuple[int, float]:
    """(coasting samples, max |-(a + g) - r(v)| in N/kg) over the simulator's dense truth: on a coast (u = 0) the
    acceleration is -(r(v) + g(s)) exactly, so this shows which r(v) the simulation ran with."""
    d = streams.legs[0].run.dense
    m = (d.u == 0.0) & (d.v > 1.0)
    g = np.asarray(track.track_force(d.s[m], train.length_m))
    k = 1.0 + train.tunnel_factor * np.asarray(track.tunnel_fraction(d.s[m], train.length_m))
    r = truth.r0 + truth.r1 * d.v[m] + truth.r2 * k * d.v[m] ** 2
    return int(m.sum()), float(np.max(np.abs(-(d.a[m] + g) - r)))


def test_a_sibling_runs_the_held_out_runs_truth_drifted_by_at_most_3_percent_with_other_samples():
    run = S.family.RunSpec(HOLD_10S, 1)  # a report run
    streams, truth, track, train = S.family.simulate_spec(run)
    assert truth == S.run_truth(run)  # the hook left alone: the run's own draw
    n, err = _coasting_resistance_error(streams, truth, track, train)
    assert n > 100 and err < 1e-12
    factors = []
    for j in (1, 2):
        sib = S.SiblingSpec(HOLD_10S, 1, j)
        assert sib.name == f"hold_10s_01_s{j}" and sib.parent == run and sib.split == "report"
        s_streams, s_truth, s_track, s_train = S.simulate_sibling(sib)
        assert (s_track, s_train) == (track, train)
        f = S.drift_factor(sib)
        factors.append(f)
        assert abs(f - 1.0) <= S.MAX_DRIFT
        for c in ("r0", "r1", "r2"):
            assert getattr(s_truth, c) == pytest.approx(getattr(truth, c) * f, rel=1e-12)
        # the simulation ran with the sibling's truth: its coasts decelerate by exactly that r(v)
        n, err = _coasting_resistance_error(s_streams, s_truth, track, train)
        assert n > 100 and err < 1e-12
        # other driver and noise: other speed samples, another cruise target
        assert not np.array_equal(s_streams.speed.v_ms[:100], streams.speed.v_ms[:100])
        assert s_streams.legs[0].driver.theta_cruise != streams.legs[0].driver.theta_cruise
    assert factors[0] != factors[1]


def test_siblings_of_the_report_half_only_and_the_same_bytes_from_the_same_seed():
    sibs = S.sibling_specs(["hold_10s"])
    assert [s.name for s in sibs] == [f"hold_10s_{k:02d}_s{j}" for k in (1, 3, 5, 7) for j in (1, 2)]
    a, _, _, _ = S.simulate_sibling(sibs[0])
    b, _, _, _ = S.simulate_sibling(sibs[0])
    assert np.array_equal(a.speed.v_ms, b.speed.v_ms) and np.array_equal(a.gnss.t_ns, b.gnss.t_ns)
