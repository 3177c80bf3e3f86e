"""Train length from occupation/release (eq. 1-2) and composition assignment, against known lengths."""

from __future__ import annotations

import numpy as np
import pytest
from occupation_synthetic import even_sections, kinematic_run

from train_calib.occupation.generate import occupation_events
from train_calib.occupation.length import (
    assign_composition,
    assignment_accuracy,
    estimate_length,
    joint_estimates,
)
from train_calib.track import Section

LENGTHS = {"VIRM4": 108.0, "VIRM6": 162.0, "VIRM10": 270.0, "ICRm": 282.0}


def test_exact_times_at_constant_speed_give_the_length():
    t, s, _ = kinematic_run(8000.0, 35.0, accel=0.6, brake=0.6)
    sections = even_sections(8000.0, 20)
    run = occupation_events(t, s, 162.0, sections, round_down=False)
    for speed in ("eq1", "centred", "ahead"):
        j = joint_estimates(run, sections, delta_s=0.0, speed=speed)
        cruise = np.abs(j.speed_ms - 35.0) < 1e-6
        assert cruise.sum() >= 10
        np.testing.assert_allclose(j.length_m[cruise], 162.0, rtol=1e-9)
        np.testing.assert_allclose(j.low_m, j.high_m)  # delta 0: point intervals
    j = joint_estimates(run, sections, delta_s=1.0)
    np.testing.assert_allclose(j.high_m - j.low_m, 2.0 * j.speed_ms)  # eq. 2 width: 2 v delta


def test_assignment_rules():
    assert assign_composition(150.0, 120.0, 180.0, LENGTHS)[0] == "VIRM6"
    name, reason, inside = assign_composition(280.0, 240.0, 320.0, LENGTHS)
    assert (name, inside) == ("ICRm", ["VIRM10", "ICRm"])
    name, reason, _ = assign_composition(280.0, 240.0, 320.0, LENGTHS, strict=True)
    assert name is None and reason.startswith("ambiguous: VIRM10, ICRm")
    name, reason, _ = assign_composition(200.0, 190.0, 210.0, LENGTHS)
    assert name is None and reason == "no composition length in [190, 210] m"
    assert assign_composition(float("nan"), 0, 0, LENGTHS)[0] is None


def test_joints_need_contiguous_sections_and_all_three_times():
    t, s, _ = kinematic_run(3000.0, 30.0)
    sections = [Section("P", 0, 200), Section("A", 200, 1000), Section("B", 1000, 2000), Section("C", 2100, 3000)]
    run = occupation_events(t, s, 100.0, sections)
    # eq1 at P|A needs the occupation of P, where the train starts (never logged); B|C is no joint
    assert joint_estimates(run, sections, speed="eq1").section_ids == ["A"]
    # ahead at P|A uses the speed over A; at A|B it needs the speed over B, i.e. a joint B|C
    assert joint_estimates(run, sections, speed="ahead").section_ids == ["P"]
    del run.release["P"]
    assert joint_estimates(run, sections).length_m.size == 0
    est = estimate_length(run, sections, LENGTHS)
    assert est.composition is None and est.n_joints == 0 and "no usable joint" in est.reason


@pytest.fixture(scope="module")
def fleet():
    """40 rounded runs on 42 uneven sections, random cruise speeds, a 22 m/s restriction, random clocks."""
    rng = np.random.default_rng(7)
    edges = np.concatenate(([0.0], np.sort(rng.uniform(0, 14300.0, 41)), [14300.0]))
    sections = [Section(f"S{k:02d}", float(edges[k]), float(edges[k + 1])) for k in range(42)]
    runs, truth = [], {}
    for k in range(40):
        name = list(LENGTHS)[k % 4]
        vc = rng.uniform(30.0, 44.0)
        t, s, _ = kinematic_run(
            14300.0,
            lambda x, vc=vc: np.where((x > 6000) & (x < 7000), 22.0, vc),
            accel=rng.uniform(0.3, 0.6),
            brake=rng.uniform(0.3, 0.8),
            ds=2.0,
        )
        run = occupation_events(t, s, LENGTHS[name], sections, run_id=f"r{k}", t0_s=rng.uniform(0, 1e5))
        runs.append(run)
        truth[run.run_id] = name
    return sections, runs, truth


def _accuracy(fleet, delta, **kw):
    sections, runs, truth = fleet
    return assignment_accuracy([estimate_length(r, sections, LENGTHS, delta, **kw) for r in runs], truth, LENGTHS)


def test_fleet_accuracy_per_delta(fleet):
    # delta 0: eq. 2 gives point intervals; no composition length falls inside
    assert _accuracy(fleet, 0.0).n_assigned == 0
    # measured: eq1 35/40 right (median |error| 5.1 m), centred 37/40 (3.6 m), ahead 39/40 (2.7 m)
    for speed, min_correct, max_median in (("eq1", 0.85, 6.0), ("centred", 0.9, 4.5), ("ahead", 0.95, 3.5)):
        acc = _accuracy(fleet, 1.0, speed=speed)
        assert acc.assigned_share == 1.0
        assert acc.correct_share >= min_correct
        # VIRM4 and VIRM6 differ by 54 m: never confused
        assert acc.confusion["VIRM4"] == {"VIRM4": 10} and acc.confusion["VIRM6"] == {"VIRM6": 10}
        assert acc.length_error_m["median"] < max_median and acc.length_error_m["p95"] < 10.0
        # nearest-inside: a wider interval changes nothing once the nearest is inside
        assert _accuracy(fleet, 2.0, speed=speed).n_correct == acc.n_correct


def test_strict_rule_reproduces_the_papers_delta_trade_off(fleet):
    one, two = _accuracy(fleet, 1.0, strict=True), _accuracy(fleet, 2.0, strict=True)
    # delta 1: the 108/162 m trains are told apart; 270 vs 282 m never (the intervals hold both)
    assert one.n_assigned == 20 and one.precision == 1.0
    assert one.confusion["VIRM10"] == {"none": 10} and one.confusion["ICRm"] == {"none": 10}
    # delta 2: intervals of +-2 v cover several compositions: almost nothing assigned
    assert two.n_assigned <= 4


def test_joints_slower_than_min_speed_are_skipped():
    """Accelerating at 0.6 m/s^2 from a stop to 35 m/s over 100 m sections: the joints where the mean speed is below
    min_speed_ms (the train too slow: a stop nearby) give no estimate; the others are those of min_speed_ms = 0."""
    t, s, _ = kinematic_run(8000.0, 35.0, accel=0.6, brake=0.6)
    sections = even_sections(8000.0, 80)
    run = occupation_events(t, s, 162.0, sections, round_down=False)
    every = joint_estimates(run, sections, min_speed_ms=0.0)
    fast = joint_estimates(run, sections, min_speed_ms=15.0)
    keep = every.speed_ms >= 15.0
    assert (~keep).sum() > 0 and keep.sum() >= 40
    np.testing.assert_array_equal(fast.joint_m, every.joint_m[keep])
    assert fast.section_ids == [sid for sid, k in zip(every.section_ids, keep) if k]
