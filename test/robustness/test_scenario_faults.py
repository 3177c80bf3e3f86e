"""Faults that need a scenario of their own: a bag loop, shunting (reversing), hours of standstill, a clock
offset between the sensors, and a speed stream silent for minutes while the GNSS continues.

Core chain (``pipeline.run_bag``, equal to the node graph message for message); converging filter unless
stated. Tolerances as in test_topic_faults (faultlib.Tolerance).
"""

from __future__ import annotations

import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))
from faultlib import (
    CONVERGING,
    DEFAULT_SCRIPT,
    GNSS,
    NS,
    SPEED,
    STAND,
    T0,
    Phase,
    deep_size,
    delayed,
    final_difference,
    physical,
    recovery,
    remove,
    restamped,
    sensor_events,
    shunt,
    simulate,
    sort_events,
    write_bag,
)

from train_calib.estimation import UKFConfig
from train_calib.ingest import IngestConfig
from train_calib.pipeline import Pipeline, bag_messages, run_bag


def test_bag_loop_is_a_clock_reset_and_the_second_pass_repeats_the_first(scenario, tmp_path):
    """The same recording played twice (stamps jump back by its length): a new time base and a new run, and
    with carry_over reset the second pass gives exactly the estimates of the first; nothing is dropped."""
    duration = scenario.events[-1].log_ns - scenario.events[0].log_ns + NS
    looped = scenario.events + [replace(e, log_ns=e.log_ns + duration) for e in scenario.events]
    out = run_bag(write_bag(tmp_path / "bag", looped), scenario.track, scenario.train, ukf=CONVERGING)
    n = len(out.estimates) // 2
    first, second = out.estimates[:n], out.estimates[n:]
    assert len(first) == len(second) == sum(1 for e in scenario.events if e.topic == SPEED)
    assert [(e.s, e.v, e.r0, e.r1, e.r2) for e in first] == [(e.s, e.v, e.r0, e.r1, e.r2) for e in second]
    assert {e.run_id for e in first} == {0} and {e.run_id for e in second} == {1}
    assert out.ingest_stats.clock_resets == 1 and out.ingest_stats.dropped_total() == 0
    assert sum(f.run_complete for f in out.features) == 2


def test_one_sensor_clock_an_hour_behind_is_dropped_as_stale_without_a_reset(scenario, tmp_path):
    events = restamped(list(scenario.events), 0.0, GNSS, -3600.0)
    out = run_bag(write_bag(tmp_path / "bag", events), scenario.track, scenario.train)
    stats = out.ingest_stats
    assert stats.clock_resets == 0
    assert stats.dropped["gnss"]["stale"] == sum(1 for e in events if e.topic == GNSS)
    assert stats.consecutive_dropped["gnss"] > 700 and stats.last_drop["gnss"] == "stale"  # diagnostics WARN


@pytest.mark.parametrize(
    ("distance", "speed", "detected"), [(200.0, 2.0, True), (500.0, 5.0, True), (30.0, 1.0, False)]
)
def test_shunting_backwards_is_detected_dropped_and_the_run_after_it_is_the_normal_run(
    scenario, reference, tmp_path, distance, speed, detected
):
    """The speed is >= 0 by contract: reversing shows only in the fixes moving backwards. While it lasts the
    speed samples are dropped (reason reversing); forward again starts a new run, which then gives the
    estimates of the same run without the shunt. A move shorter than reverse_distance (50 m) is not judged."""
    truth, duration = shunt(scenario.truth.s[0], distance, speed)
    events = sort_events(sensor_events(scenario.track, truth, seed=8) + delayed(scenario.events, duration))
    out = run_bag(write_bag(tmp_path / "bag", events), scenario.track, scenario.train, ukf=CONVERGING)
    stats = out.ingest_stats
    assert physical(out.estimates) == []
    assert stats.reversals == (1 if detected else 0)
    moving = int(np.count_nonzero(truth.v > 0.0))
    if detected:  # every sample of the move after the first reverse_distance (50 m) and of the stop after it
        assert moving - 40 <= stats.dropped["speed"]["reversing"] <= len(truth.t) + 60
    else:
        assert stats.dropped_total() == 0
    last_run = [e for e in out.estimates if e.run_id == out.estimates[-1].run_id]
    back = round(duration * NS)
    rec = recovery(reference.estimates, last_run, T0, stamp_map=lambda e: e.stamp_ns - back)
    # the samples of the first reverse_distance of the departure are the ones missing (direction unknown yet)
    assert rec <= 45
    assert final_difference(reference.estimates, last_run) < 1e-3


@pytest.mark.parametrize("preset", ["paper", "converging"])
def test_two_hours_of_standstill_no_drift_no_nis_blow_up_no_memory_growth(scenario, tmp_path, preset):
    script = [*DEFAULT_SCRIPT[:-1], Phase(STAND, 2 * 3600.0)]
    truth = simulate(scenario.track, scenario.train, script)
    bag = write_bag(tmp_path / "bag", sensor_events(scenario.track, truth, seed=7))
    pipeline = Pipeline(scenario.track, scenario.train, ukf=UKFConfig.preset(preset))
    stop_ns = T0 + int((truth.t[np.nonzero(truth.v > 0)[0][-1]] + 60.0) * NS)
    first = last = None
    nis: list[float] = []
    var_s: list[float] = []
    health: set[int] = set()
    sizes = []
    for k, (topic, msg) in enumerate(bag_messages(bag)):
        pipeline.add_message(topic, msg)
        out = pipeline.out
        for e in out.estimates:
            if e.stamp_ns > stop_ns:
                first = first or e
                last = e
                nis.append(e.nis)
                var_s.append(e.covariance[0, 0])
                health.add(e.health)
        out.measurements.clear()
        out.estimates.clear()
        out.regimes.clear()
        out.features.clear()
        if k % 3600 == 1800:
            sizes.append(deep_size(pipeline))
    assert len(nis) >= 2 * 3600 - 60
    for c in ("r0", "r1", "r2"):  # r does not drift at a standstill (converging: it does not move at all)
        assert abs(getattr(last, c) - getattr(first, c)) <= (1e-3 if preset == "paper" else 0.0) * getattr(first, c)
    assert abs(last.s - first.s) < 4.0 and last.v < 0.05  # nor does the position (GNSS noise 3 m per axis)
    assert np.mean(nis) < 2.0 and max(nis) < 25.0  # consistent (2 dof: mean 2) all along, no blow-up
    assert health == {0}
    assert min(var_s) > 0.0 and max(var_s) < 20.0  # P neither collapses nor grows
    # what the core holds (its outputs discarded at each step) does not grow over the hours of standstill
    assert max(sizes[2:]) - sizes[2] < 16 * 1024, sizes


@pytest.mark.parametrize("delay", [0.5, 1.0, 2.0, -1.0])
def test_gnss_stamps_late_are_detected_estimated_and_compensated_with_gnss_delay(scenario, tmp_path, delay):
    """A GNSS stamping its fixes `delay` s after the measurement time puts the position v*delay behind (30 m at
    1 s and 108 km/h). The ingest estimates the delay from the fixes against the speed odometer (diagnostics
    WARN beyond delay_warn, 0.3 s); with gnss_delay set, the result is that of the fault-free run."""
    events = restamped(list(scenario.events), 0.0, GNSS, delay)
    bag = write_bag(tmp_path / "bag", events)
    pipeline = Pipeline(scenario.track, scenario.train, ukf=CONVERGING)
    for topic, msg in bag_messages(bag):
        pipeline.add_message(topic, msg)
    estimate, std = pipeline.ingest.gnss_delay_estimate
    assert abs(estimate - delay) < 0.15 and std < 0.05
    assert abs(estimate) > pipeline.ingest.config.delay_warn and abs(estimate) > 3 * std  # the WARN condition
    fixed = run_bag(bag, scenario.track, scenario.train, ukf=CONVERGING, ingest=IngestConfig(gnss_delay=delay))
    clean = run_bag(write_bag(tmp_path / "clean", scenario.events), scenario.track, scenario.train, ukf=CONVERGING)
    assert [(e.s, e.v, e.r0) for e in fixed.estimates] == [(e.s, e.v, e.r0) for e in clean.estimates]


def test_no_false_delay_warning_on_synchronous_sensors(scenario, reference):
    pipeline = Pipeline(scenario.track, scenario.train, ukf=CONVERGING)
    for e in scenario.events:
        from train_calib.ingest import GnssFix, SpeedSample

        f = e.fields
        pipeline.add_event(
            GnssFix(e.stamp_ns, f["lat"], f["lon"], f["status"], 9.0, True)
            if e.topic == GNSS
            else SpeedSample(e.stamp_ns, f["v"])
        )
    estimate, _ = pipeline.ingest.gnss_delay_estimate
    assert abs(estimate) < 0.15 < pipeline.ingest.config.delay_warn


def test_speed_silent_for_minutes_while_the_gnss_continues(scenario, reference, tmp_path):
    """400 s without speed while the GNSS goes on: nothing is made of the fixes alone, the ingest holds only what
    pairing can still use (no pile-up), no stale pairing when the speed returns (its first sample pairs with the
    fix of its own epoch), and a new run starts (gap longer than run_gap)."""
    events = remove(list(scenario.events), 200.0, 600.0, SPEED)
    pipeline = Pipeline(scenario.track, scenario.train, ukf=CONVERGING)
    held = []
    for topic, msg in bag_messages(write_bag(tmp_path / "bag", events)):
        pipeline.add_message(topic, msg)
        held.append(len(pipeline.ingest.pairer.fixes))
    out = pipeline.end_of_input()
    assert max(held) <= 40  # fixes kept for pairing: max_sample_age + pair_tolerance worth, not 400 s of them
    after = [m for m in out.measurements if m.stamp_ns >= T0 + 600 * NS]
    truth_s = np.interp([(m.stamp_ns - T0) / NS for m in after[:5]], scenario.truth.t, scenario.truth.s)
    assert all(m.s_measured for m in after[:5])
    assert np.max(np.abs(np.array([m.s for m in after[:5]]) - truth_s)) < 15.0
    assert {m.run_id for m in after} == {1} and after[0].dt == 0.0
    assert physical(out.estimates) == []
