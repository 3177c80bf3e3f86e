"""The unhindered-run filter: hindered runs rejected with the reason, unhindered ones kept."""

from __future__ import annotations

import numpy as np
import pytest
from occupation_synthetic import kinematic_run

from train_calib.occupation.events import RunEvents
from train_calib.occupation.generate import occupation_events
from train_calib.occupation.unhindered import (
    FilterConfig,
    check_run,
    filter_runs,
    fleet_reference,
    profile_reference,
    section_speeds,
)
from train_calib.track import Section

LENGTH_M = 14300.0
STOPS = (0.0, 7150.0, LENGTH_M)


@pytest.fixture(scope="module")
def sections():
    rng = np.random.default_rng(1)
    edges = np.concatenate(([0.0], np.sort(rng.uniform(100, LENGTH_M - 100, 41)), [LENGTH_M]))
    return [Section(f"S{k:02d}", float(edges[k]), float(edges[k + 1])) for k in range(42)]


def _cap(vc, extra=None):
    def cap(s):
        v = np.where((s > 3000) & (s < 3800), 22.0, vc)  # a permanent restriction every run obeys
        if extra is not None:
            v = np.where((s > extra[0]) & (s < extra[1]), np.minimum(v, extra[2]), v)
        return v

    return cap


def _run(sections, k, rng, *, extra=None, dwell_at=None):
    """Two legs with a scheduled stop at 7150 m (glued), optional hindrance in the second leg."""
    vc, a, b = rng.uniform(33, 40), rng.uniform(0.35, 0.6), rng.uniform(0.4, 0.8)
    t1, s1, _ = kinematic_run(7150.0, _cap(vc), accel=a, brake=b, ds=2.0)
    dwell = None if dwell_at is None else (dwell_at - 7150.0, 45.0)
    t2, s2, _ = kinematic_run(
        LENGTH_M - 7150.0, lambda s: _cap(vc, extra)(s + 7150.0), accel=a, brake=b, ds=2.0, dwell=dwell
    )
    t = np.concatenate((t1, t1[-1] + rng.uniform(40, 90) + t2[1:]))
    s = np.concatenate((s1, 7150.0 + s2[1:]))
    return occupation_events(t, s, 162.0, sections, run_id=f"r{k}", t0_s=rng.uniform(0, 1e5))


@pytest.fixture(scope="module")
def fleet(sections):
    rng = np.random.default_rng(4)
    runs = {r.run_id: r for r in (_run(sections, k, rng) for k in range(12))}
    runs["slowed"] = _run(sections, 90, rng, extra=(10000.0, 10600.0, 11.0))
    runs["slowed"].run_id = "slowed"
    runs["stopped"] = _run(sections, 91, rng, dwell_at=11500.0)
    runs["stopped"].run_id = "stopped"
    return runs


def test_section_speeds_bounds(sections):
    run = RunEvents("x", occupy={"S00": 0.0, "S01": 10.0, "S02": 11.0})
    sp = section_speeds(run, sections[:4])
    d = sections[1].start_m - sections[0].start_m
    assert sp.speed_ms[0] == pytest.approx(d / 10) and sp.low_ms[0] == pytest.approx(d / 11)
    assert sp.high_ms[0] == pytest.approx(d / 9) and sp.high_ms[1] == np.inf
    assert np.isnan(sp.speed_ms[2:]).all()


def test_fleet_filter_keeps_unhindered_and_names_the_hindrance(fleet, sections):
    ref = fleet_reference(fleet.values(), sections)
    kept, rejected = filter_runs(fleet, sections, STOPS, ref)
    assert sorted(rejected) == ["slowed", "stopped"]
    assert len(kept) == 12
    (why,) = rejected["slowed"]
    assert why.startswith("unexpected deceleration in section")
    # the restriction 10.0-10.6 km is in the named sections
    named = why.split("in section ")[1].split(":")[0].split("-")
    ids = [s.id for s in sections]
    lo, hi = ids.index(named[0]), ids.index(named[-1])
    assert sections[lo].start_m < 10600.0 and sections[hi + 1].start_m > 10000.0
    (why,) = rejected["stopped"]
    assert why.startswith("unexpected stop in section")


def test_profile_reference_and_thresholds(fleet, sections):
    # a model profile as reference (here the median run's own trajectory, cruise at 36 m/s)
    t, s, _ = kinematic_run(LENGTH_M, _cap(36.0), accel=0.45, brake=0.6, ds=2.0)
    ref = profile_reference(lambda x: np.interp(x, s, t), sections)
    assert np.isfinite(ref[:-1]).all()
    # a single leg as reference misses the scheduled stop: only data checks without stops fail nothing else
    res = check_run(fleet["slowed"], sections, STOPS, ref)
    assert not res.unhindered and "unexpected deceleration" in res.reasons[0]
    # a dip threshold above the restriction's depth lets it pass
    assert check_run(fleet["slowed"], sections, STOPS, ref, FilterConfig(dip=0.9)).unhindered
    assert check_run(fleet["slowed"], sections, STOPS, None).unhindered  # no reference: data checks only


def test_data_inconsistencies(fleet, sections):
    ids = [s.id for s in sections]
    base = fleet["r0"]
    few = RunEvents("few", occupy={k: base.occupy[k] for k in ids[1:4]})
    assert check_run(few, sections, STOPS, None).reasons == ["too few occupation events: 3 < 5"]
    gaps = RunEvents("gaps", occupy={k: v for i, (k, v) in enumerate(base.occupy.items()) if i % 3})
    assert check_run(gaps, sections, STOPS, None).reasons[0].startswith("incomplete: 13 of 40 sections")
    back = RunEvents("back", occupy=dict(base.occupy), release=dict(base.release))
    back.occupy[ids[10]] = back.occupy[ids[9]] - 5.0
    assert any(
        r.startswith(f"occupation times go backwards at section {ids[10]}")
        for r in check_run(back, sections, STOPS, None).reasons
    )
    early = RunEvents("early", occupy=dict(base.occupy), release=dict(base.release))
    early.release[ids[5]] = early.occupy[ids[5]] - 1.0
    assert check_run(early, sections, STOPS, None).reasons == [
        f"release before occupation in section {ids[5]} ({early.release[ids[5]]:g} s < {early.occupy[ids[5]]:g} s)"
    ]
