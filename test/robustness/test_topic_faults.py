"""Topic data faults: each is counted by reason, never reaches the filter, and the estimates recover.

Every fault class of faultlib.CASES is injected into the inputs of a physics-consistent 1 Hz run (a bag
written with bagio.BagWriter) and run through the core chain (``pipeline.run_bag``: the same objects the
nodes call, in the same order) with the converging filter, which learns r and so is the one a fault could
spoil. Asserted per class: the drops and repairs by reason, nothing else lost (one estimate per valid speed
sample), every estimate physical, s and v near the fault-free run throughout, and the number of samples
after the fault until the estimates are back within tolerance of the fault-free run (faultlib.Tolerance).

One bag holding every class at once is then replayed through the real node graph: its outputs equal the
core chain's message for message, and /diagnostics and summary.json carry the same counts.
"""

from __future__ import annotations

import math
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))
from faultlib import (
    CASES,
    CONVERGING,
    FAULT_START,
    GNSS,
    NAN,
    NS,
    POWER,
    SPEED,
    T0,
    Event,
    FaultCase,
    duplicated,
    final_difference,
    moved_fixes,
    physical,
    recovery,
    reference_stamp,
    remove,
    restamped,
    set_fields,
    sort_events,
    swapped,
    write_bag,
)

from train_calib.ingest import SPEED as SPEED_STREAM
from train_calib.pipeline import run_bag


def _counts(stats_counters) -> dict[str, dict[str, int]]:
    return {stream: dict(c) for stream, c in stats_counters.items() if c}


@pytest.mark.parametrize("case", CASES, ids=lambda c: c.name)
def test_fault_is_counted_kept_from_the_filter_and_estimates_recover(scenario, reference, case: FaultCase, tmp_path):
    out = run_bag(write_bag(tmp_path / "bag", case.inject(scenario)), scenario.track, scenario.train, ukf=CONVERGING)
    stats = out.ingest_stats
    assert _counts(stats.dropped) == case.drops
    assert _counts(stats.repaired) == case.repaired
    assert physical(out.estimates) == []
    # nothing lost but what the fault spoiled: one estimate per valid speed sample
    assert len(reference.estimates) - len(out.estimates) == case.lost
    assert stats.received[SPEED_STREAM] == stats.published + sum(stats.dropped[SPEED_STREAM].values())
    runs = sorted({e.run_id for e in out.estimates})
    assert runs == ([0, 1] if case.new_run else [0])
    # near the fault-free run throughout, and back within tolerance soon after the fault
    to_reference = reference_stamp(case)
    by_stamp = {(to_reference(e) if to_reference else e.stamp_ns): e for e in out.estimates}
    pairs = [(e, by_stamp[e.stamp_ns]) for e in reference.estimates if e.stamp_ns in by_stamp]
    assert max(abs(a.s - b.s) for a, b in pairs) <= case.max_s
    assert max(abs(a.v - b.v) for a, b in pairs) <= case.max_v
    fault_end = T0 + int(case.window[1] * NS)
    assert recovery(reference.estimates, out.estimates, fault_end, stamp_map=to_reference) <= case.max_recovery
    assert final_difference(reference.estimates, out.estimates) < case.max_final  # the final r(v) (1 %)


def test_without_the_position_gate_a_multipath_jump_would_spoil_r(scenario, reference, tmp_path):
    """The gnss_jump_* rows hold because of the UKF's position gate: with it off, a 500 m jump that the ingest
    re-acquires (3 consistent fixes) drags s by > 100 m and r(v) by tens of percent."""
    from train_calib.estimation.safeguards import SafeguardConfig

    case = next(c for c in CASES if c.name == "gnss_jump_500m_5s")
    bag = write_bag(tmp_path / "bag", case.inject(scenario))
    off = run_bag(bag, scenario.track, scenario.train, ukf=CONVERGING, safeguards=SafeguardConfig(position_gate=1.0))
    on = run_bag(bag, scenario.track, scenario.train, ukf=CONVERGING)
    worst = max(abs(a.s - b.s) for a, b in zip(reference.estimates, off.estimates))
    assert worst > 100.0
    assert max(abs(a.s - b.s) for a, b in zip(reference.estimates, on.estimates)) < 1.0


# -- every class at once through the node graph --------------------------------------------------------


def _power(events: list[Event]) -> list[Event]:
    """A traction power stream at 1 Hz (constant, not used by the default filter) with a NaN and a negative."""
    out = list(events)
    for e in events:
        if e.topic == SPEED:
            value = NAN if round(e.t) == 400 else -5.0 if round(e.t) == 401 else 2.0e5
            out.append(Event(POWER, e.log_ns + NS // 20, e.stamp_ns, {"consumed": value, "regenerated": 0.0}))
    return sort_events(out)


def combined_faults(scenario) -> list[Event]:
    """Every topic fault class in one bag, at separate times, and a clock reset (new run) at the end."""
    track = scenario.track
    ev = _power(list(scenario.events))
    ev = set_fields(ev, 60, 65, GNSS, lat=NAN)
    ev = set_fields(ev, 70, 75, GNSS, cov=[NAN] * 9)
    ev = set_fields(ev, 80, 85, SPEED, v=NAN)
    ev = set_fields(ev, 90, 95, SPEED, v=lambda e: -e.fields["v"])
    ev = set_fields(ev, 100, 101, SPEED, v=lambda e: e.fields["v"] + 15.0)
    ev = set_fields(ev, 110, 113, SPEED, v=lambda e: e.fields["v"] + 15.0)
    ev = moved_fixes(track, ev, 120, 125, along_m=-500.0)
    ev = set_fields(ev, 140, 160, GNSS, status=-1)
    ev = moved_fixes(track, ev, 170, 180, east_m=200.0)
    ev = duplicated(ev, 190, 200, SPEED, v=0.0)
    ev = swapped(ev, 210, 230, GNSS)
    ev = set_fields(ev, 240, 250, SPEED, vy=NAN, wz=math.inf)
    ev = set_fields(ev, 250, 370, GNSS, status=-1, lat=NAN, lon=NAN)  # a tunnel: 2 minutes without GNSS
    ev = remove(ev, 420, 450, SPEED)  # the speed silent for 30 s
    return restamped(ev, 600.0, None, -3600.0)  # the clock jumps back an hour: a new time base


@pytest.mark.ros
def test_every_fault_class_through_the_node_graph_equals_the_core_and_is_counted(scenario, tmp_path):
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "nodes"))
    from compare import compare, read_outputs

    from train_calib.replay import ReplayOptions, replay
    from train_calib.summary import read_outputs as summary_outputs
    from train_calib.summary import summarize

    events = combined_faults(scenario)
    bag = write_bag(tmp_path / "bag", events)
    reference = run_bag(bag, scenario.track, scenario.train)  # the shipped defaults
    result = replay(
        ReplayOptions(bag=bag, track=str(scenario.track_path), train=str(scenario.train_path), out=tmp_path / "o")
    )
    sent = {t: sum(1 for e in events if e.topic == t) for t in (GNSS, SPEED, POWER)}
    assert result.sent == sent
    assert compare(read_outputs(tmp_path / "o"), reference) == []
    stats = reference.ingest_stats
    expected = {
        "gnss": {"nan": 5, "jump": 4, "no_fix": 140, "off_track": 10, "out_of_order": 10},
        "speed": {"nan": 5, "negative_speed": 5, "speed_jump": 4, "duplicate": 10},
        "power": {"nan": 1, "negative_power": 1},
    }
    assert _counts(stats.dropped) == expected
    assert stats.clock_resets == 1 and sorted({e.run_id for e in reference.estimates}) == [0, 1]
    assert stats.received[SPEED_STREAM] == stats.published + sum(stats.dropped[SPEED_STREAM].values())
    assert physical(reference.estimates) == []
    # /diagnostics (gnss_speed_node's last status) and summary.json carry the counts by reason
    summary = summarize(summary_outputs(tmp_path / "o"))
    topics = {"gnss": "/gnss/fix", "speed": "/train/speed", "power": "/train/traction_power"}
    dropped = {s: summary["dropped"]["gnss_speed_node"][topics[s]] for s in expected}
    assert dropped == expected
    assert summary["repaired"]["gnss_speed_node"] == {"/gnss/fix": {"bad_covariance": 5}}
    assert summary["ingest"]["clock_resets"] == "1"
    assert summary["output_counts"]["/train_calib/resistance"] == len(reference.estimates)
    assert summary["filter"]["filter_updates"] == len(reference.estimates)


def test_fault_catalogue_starts_in_the_learning_phase(scenario, reference):
    """The faults sit where they can do harm: in the first coasting phase, while the filter learns r."""
    i = next(k for k, e in enumerate(reference.estimates) if e.stamp_ns >= T0 + int(FAULT_START * NS))
    before, after = reference.estimates[i - 30], reference.estimates[i + 30]
    assert after.effort_known and abs(after.r0 - before.r0) > 0.02 * before.r0
