"""Tunnels from GNSS outages (trackbuild.tunnels): consistent across runs, plausible length, edges from the phases."""

from __future__ import annotations

import numpy as np
import pytest

from train_calib.trackbuild.runs import RunData
from train_calib.trackbuild.tunnels import find_tunnels

SPEED = 30.0  # m/s
FIX_S = 10.0  # fix interval, s


def _run(phase_s: float, outages_m: list[tuple[float, float]], length_m: float = 12_000.0):
    """A run at 30 m/s along a straight line from s = 0, 10 s fixes starting at phase_s, none inside outages_m."""
    t_fix = np.arange(phase_s, length_m / SPEED, FIX_S)
    s_fix = SPEED * t_fix
    keep = np.ones(s_fix.size, dtype=bool)
    for a, b in outages_m:
        keep &= ~((s_fix >= a) & (s_fix <= b))
    t_speed = np.arange(0.0, length_m / SPEED, 1.0)
    run = RunData(
        source=f"run{phase_s:g}",
        fix_t_ns=(t_fix[keep] * 1e9).astype(np.int64),
        lat=np.zeros(keep.sum()),
        lon=np.zeros(keep.sum()),
        alt=np.zeros(keep.sum()),
        speed_t_ns=(t_speed * 1e9).astype(np.int64),
        speed_ms=np.full(t_speed.size, SPEED),
    )
    return run, s_fix[keep]  # the chainage of each fix: exact here


def test_a_tunnel_in_every_run_is_found_and_narrowed_by_the_phases():
    """A 1,000 m tunnel at 4,000-5,000 m, five runs with fix phases 0-8 s: each run bounds each edge to 300 m;
    together to 60 m, so the edges are within 30 m (1-sigma stated as 60 / sqrt(12) = 17 m)."""
    runs, chains = zip(*(_run(p, [(4000.0, 5000.0)]) for p in (0.0, 2.0, 4.0, 6.0, 8.0)))
    found = find_tunnels(list(runs), list(chains))
    assert len(found.tunnels) == 1 and found.seen_by == [5] and not found.dropped
    start, end = found.tunnels[0]
    assert start == pytest.approx(4000.0, abs=30.0) and end == pytest.approx(5000.0, abs=30.0)
    assert 5.0 < found.edge_sigma_m[0] < 30.0
    # one run alone: the middle of its bounds, within half a fix interval of travel (150 m)
    alone = find_tunnels([runs[1]], [chains[1]])
    assert len(alone.tunnels) == 1
    assert alone.tunnels[0] == pytest.approx((4000.0, 5000.0), abs=150.0)


def test_an_outage_in_one_run_of_four_or_too_short_is_not_a_tunnel():
    """A receiver hiccup in one run of four (8,000-8,400 m) is not a tunnel, the 1 km tunnel in all four is kept;
    with a shortest tunnel of 1,500 m it is reported as too short; a gap in the fixes while standing is no outage."""
    outages = [[(4000.0, 5000.0), (8000.0, 8400.0)], [(4000.0, 5000.0)], [(4000.0, 5000.0)], [(4000.0, 5000.0)]]
    runs, chains = zip(*(_run(p, o) for p, o in zip((0.0, 2.5, 5.0, 7.5), outages)))
    found = find_tunnels(list(runs), list(chains))
    assert len(found.tunnels) == 1 and found.tunnels[0][0] == pytest.approx(4000.0, abs=40.0)
    assert len(found.dropped) == 1 and "in 1 of 4 runs, not a tunnel" in found.dropped[0]
    strict = find_tunnels(list(runs), list(chains), min_length_m=1500.0)
    assert strict.tunnels == [] and any("outside [1500, 60000] m" in d for d in strict.dropped)
    # a gap while standing (the fixes stop at a stop, the speed is 0) is no outage at all
    run, chain = _run(0.0, [])
    keep = np.r_[0:15, 25 : chain.size]  # 100 s without fixes
    standing = RunData(run.source, run.fix_t_ns[keep], run.lat[keep], run.lon[keep], run.alt[keep], run.speed_t_ns,
                       np.zeros_like(run.speed_ms))  # fmt: skip
    assert find_tunnels([standing], [chain[keep]]).tunnels == []
    assert len(find_tunnels([run], [chain]).tunnels) == 0
    moving = RunData(run.source, run.fix_t_ns[keep], run.lat[keep], run.lon[keep], run.alt[keep], run.speed_t_ns,
                     run.speed_ms)  # fmt: skip
    assert len(find_tunnels([moving], [chain[keep]]).tunnels) == 1  # the same gap while moving: a tunnel
