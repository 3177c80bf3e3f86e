"""Every drop reason and every counter of the ingest made non-zero, with its exact count, through the public
``Ingest`` API (events in, measurements and ``stats`` out; issue 23's mutation test: deleting a drop count passed the
whole suite).

``test_ingest.py`` counts the value checks (nan, no_fix, negative and implausible speed, speed_jump, duplicate,
stale, negative_power) and the map matching (jump, off_track); this file adds the rest (no_position,
out_of_order, reversing, the bad_covariance repair, dead reckoning, clock resets), the drops the mutation test found
uncounted (regenerated power, off_track just beyond max_cross_track, an accepted speed step's held samples), and
checks that every reason has an exact count asserted in some test_ingest*.py. Scenes: the small track (a 3 km line
due north) with fixes and speed at exactly known positions; ``_accelerating`` is a train standing at 200 m for
10 s, accelerating at 0.5 m/s^2 and cruising at 20 m/s.
"""

from __future__ import annotations

import itertools
import math
import re
from pathlib import Path

import numpy as np
import pytest
import test_ingest
from test_ingest import NS, T0, Profile, events, fix_at

from train_calib.ingest import (
    DROP_REASONS,
    GNSS,
    POWER,
    REPAIR_REASONS,
    SPEED,
    GnssFix,
    Ingest,
    IngestConfig,
    PowerSample,
    SpeedSample,
)

track, train = test_ingest.track, test_ingest.train  # the small track and train fixtures


def _runs(ms) -> list[tuple[int, int]]:
    """(run_id, number of measurements) per run, in order."""
    return [(run, len(list(group))) for run, group in itertools.groupby(m.run_id for m in ms)]


def _accelerating(t: float) -> tuple[float, float]:
    """(s m, v m/s): standing at 200 m for 10 s, then 0.5 m/s^2 up to 20 m/s, then cruising."""
    ta = min(max(t - 10.0, 0.0), 40.0)
    s = 200.0 + 0.25 * ta * ta + 20.0 * max(t - 50.0, 0.0)
    return s, 0.5 * ta


def _accelerating_events(track, until: float, fix=lambda t: True, speed=lambda t: True) -> list:
    """``_accelerating``'s fix then speed sample at every whole second below ``until`` where ``fix(t)`` /
    ``speed(t)``."""
    out = []
    for t in np.arange(0.0, until, 1.0):
        s, v = _accelerating(float(t))
        if fix(t):
            lat, lon = track.latlon_at(s)
            out.append(GnssFix(T0 + int(t) * NS, float(lat), float(lon), 0))
        if speed(t):
            out.append(SpeedSample(T0 + int(t) * NS, v))
    return out


def _fix(track, t: float, s: float, east: float = 0.0) -> GnssFix:
    """The fix at time t (s) of the point s (m) along the track, ``east`` m off it."""
    lat, lon = track.latlon_at(s)
    if east:
        e, n = track.to_enu(lat, lon)
        lat, lon = track.frame.to_geodetic(e + east, n)
    return GnssFix(T0 + round(t * NS), float(lat), float(lon), 0)


def _seconds(measurements) -> list[int]:
    return [(m.stamp_ns - T0) // NS for m in measurements]


def test_every_drop_and_repair_reason_has_an_exact_count_asserted_in_the_ingest_tests():
    """Each reason of DROP_REASONS and REPAIR_REASONS stands as ``"reason": <count>`` in a test_ingest*.py."""
    text = "\n".join(p.read_text() for p in sorted(Path(__file__).parent.glob("test_ingest*.py")))
    asserted = set(re.findall(r'"([a-z_]+)": [1-9][0-9]*', text))
    assert set(DROP_REASONS) | set(REPAIR_REASONS) <= asserted
    assert len(DROP_REASONS) == 13 and set(REPAIR_REASONS) == {"bad_covariance"}


def test_speed_before_the_first_fix_has_no_position(track, train):
    """Without any fix the position is never acquired: every speed sample is dropped as no_position."""
    ingest = Ingest(track, train)
    out = []
    for k in range(5):
        out += ingest.add_speed(SpeedSample(T0 + k * NS, 3.0))
    out += ingest.flush()
    assert out == []
    assert dict(ingest.stats.dropped[SPEED]) == {"no_position": 5}
    assert ingest.stats.accepted[SPEED] == 5 and ingest.stats.published == 0 and not ingest.acquired


def test_speed_before_the_first_fix_is_dropped_as_no_position(track, train):
    """Speed from t = 0, GNSS only from t = 30 s: the 29 speed samples more than the pairing tolerance before the
    first fix have no position yet (not acquired); each is counted as no_position and none is published (the one at
    29 s pairs with the fix at 30 s)."""
    ingest = Ingest(track, train)
    out = list(ingest.run(_accelerating_events(track, 100.0, fix=lambda t: t >= 30.0)))
    assert dict(ingest.stats.dropped[SPEED]) == {"no_position": 29}
    assert dict(ingest.stats.dropped[GNSS]) == {}
    assert _seconds(out) == list(range(29, 100))
    assert ingest.stats.received[SPEED] == 100 and ingest.stats.published == 71


def test_dead_reckoning_ends_after_max_dead_reckoning(track, train):
    """After the last fix the position is dead-reckoned for max_dead_reckoning (10 s) and no longer: the speed
    sample 15 s after the last measurement has no position, the one 8 s after it is dead-reckoned."""
    ingest = Ingest(track, train, IngestConfig(max_dead_reckoning=10.0))
    out = ingest.add_fix(fix_at(track, 0.0, 500.0))
    out += ingest.add_speed(SpeedSample(T0, 2.0))
    out += ingest.add_speed(SpeedSample(T0 + 8 * NS, 2.0))
    out += ingest.add_speed(SpeedSample(T0 + 23 * NS, 2.0))
    out += ingest.flush()
    assert [(m.stamp_ns - T0) // NS for m in out] == [0, 8]
    assert [m.s_measured for m in out] == [True, False]
    assert out[1].s == pytest.approx(516.0, abs=1e-3)  # 8 s at 2 m/s from the fix
    assert dict(ingest.stats.dropped[SPEED]) == {"no_position": 1}
    assert ingest.stats.dead_reckoned == 1 and ingest.stats.published == 2


def test_speed_after_a_gap_longer_than_max_dead_reckoning_is_dropped_as_no_position(track, train):
    """Fixes missing from 61 to 99 s and speed from 61 to 69 s: after the speed gap (9 s > max_dead_reckoning 5 s)
    the samples cannot be dead-reckoned from the last position; they are dropped as no_position until the fix at
    100 s positions the train again."""
    ingest = Ingest(track, train, IngestConfig(max_dead_reckoning=5.0))
    gnss_out, speed_out = (lambda t: not 60.0 < t < 100.0), (lambda t: not 60.0 < t < 70.0)
    out = list(ingest.run(_accelerating_events(track, 120.0, fix=gnss_out, speed=speed_out)))
    assert dict(ingest.stats.dropped[SPEED]) == {"no_position": 29}
    assert _seconds(out) == [*range(0, 61), *range(99, 120)]
    assert ingest.stats.published == len(out) == 82


def test_dead_reckoned_measurements_are_counted(track, train):
    """Fixes every 5 s, speed at 1 Hz, pairing within 0.5 s: 4 of 5 measurements are dead-reckoned."""
    profile = Profile()
    ingest = Ingest(track, train, IngestConfig(pair_tolerance=0.5))
    out = list(ingest.run(events(track, profile, fix_dt=5.0, until=100.0)))
    assert len(out) == 100 and ingest.stats.published == 100
    assert ingest.stats.dead_reckoned == 80 == sum(not m.s_measured for m in out)
    assert ingest.stats.as_dict()["dropped"] == {}


def test_a_speed_sample_older_than_the_last_released_one_is_out_of_order(track, train):
    profile = Profile()
    ingest = Ingest(track, train)
    out = []
    for e in events(track, profile, until=10.0):
        out += ingest.add(e)
    late = SpeedSample(T0 + 4 * NS + NS // 2, 1.0)  # 4.5 s, after 9 s was released
    out += ingest.add_speed(late)
    out += ingest.flush()
    assert dict(ingest.stats.dropped[SPEED]) == {"out_of_order": 1}
    assert ingest.stats.dropped[GNSS] == {} and ingest.stats.clock_resets == 0
    assert len(out) == 10 and late.stamp_ns not in {m.stamp_ns for m in out}
    assert ingest.stats.consecutive_dropped[SPEED] == 1 and ingest.stats.last_drop[SPEED] == "out_of_order"


def test_late_power_is_put_in_order_but_older_than_the_release_is_out_of_order(track, train):
    profile = Profile()
    ingest = Ingest(track, train)
    for e in events(track, profile, until=10.0):
        ingest.add(e)
    ingest.add_power(PowerSample(T0 + 9 * NS, 1.0e5, 0.0))
    ingest.add_power(PowerSample(T0 + 8 * NS, 2.0e5, 0.0))  # older than the power stream's latest, released
    assert dict(ingest.stats.dropped[POWER]) == {"out_of_order": 1}
    assert ingest.stats.accepted[POWER] == 1


def test_negative_consumed_or_regenerated_power_is_dropped(track, train):
    """Either power below 0 is a negative_power drop (the regenerated one too)."""
    evs = _accelerating_events(track, 20.0)
    evs[10:10] = [PowerSample(T0 + 5 * NS, 1000.0, -5.0), PowerSample(T0 + 6 * NS, -1.0, 0.0)]
    ingest = Ingest(track, train)
    list(ingest.run(evs))
    assert dict(ingest.stats.dropped[POWER]) == {"negative_power": 2}
    assert ingest.stats.accepted[POWER] == 0


def test_a_fix_beyond_max_cross_track_is_off_track_and_one_within_is_kept(track, train):
    """max_cross_track 30 m: a fix 45 m east of the line is dropped as off_track, one 15 m east is used."""
    evs = []
    for t in range(40):
        s, v = _accelerating(float(t))
        evs += [_fix(track, t, s, east=45.0 if t == 20 else 15.0 if t == 30 else 0.0), SpeedSample(T0 + t * NS, v)]
    ingest = Ingest(track, train, IngestConfig(max_cross_track=30.0))
    out = list(ingest.run(evs))
    assert dict(ingest.stats.dropped[GNSS]) == {"off_track": 1}
    assert ingest.stats.accepted[GNSS] == 39 and len(out) == 40


def test_speed_against_the_track_direction_is_reversing_until_the_fixes_move_forward(track, train):
    """40 s forward at 5 m/s, 40 s backward, 40 s forward: the backward speed samples are dropped as reversing
    (from the 9th backward second, once the fixes have moved back over reverse_distance), then a new run."""
    ingest = Ingest(track, train)
    out = []
    s = 1000.0
    for k in range(120):
        out += ingest.add_fix(fix_at(track, float(k), s))
        out += ingest.add_speed(SpeedSample(T0 + k * NS, 5.0))
        s += 5.0 if k < 40 or k >= 80 else -5.0
    out += ingest.flush()
    assert dict(ingest.stats.dropped[SPEED]) == {"reversing": 40}
    assert ingest.stats.reversals == 1 and not ingest.reversing
    assert ingest.stats.published == 80 and ingest.stats.dropped[GNSS] == {}
    assert _runs(out) == [(0, 48), (1, 32)]
    stamps = [(m.stamp_ns - T0) // NS for m in out]
    assert stamps[47:49] == [47, 88] and out[48].dt == 0.0


def test_reversing_is_reported_while_the_fixes_move_backwards(track, train):
    ingest = Ingest(track, train)
    s = 1000.0
    for k in range(60):
        ingest.add_fix(fix_at(track, float(k), s))
        ingest.add_speed(SpeedSample(T0 + k * NS, 5.0))
        s += 5.0 if k < 40 else -5.0
    assert ingest.reversing and ingest.stats.reversals == 1
    assert dict(ingest.stats.dropped[SPEED]) == {"reversing": 12}


def test_speed_while_the_fixes_move_backwards_is_dropped_as_reversing(track, train):
    """Forward at 10 m/s for 60 s, then the fixes move back along the track at the same (unsigned) speed: once the
    direction is seen (from 64 s) every speed sample is counted as reversing and none is published."""
    evs = []
    for t in range(120):
        evs += [
            _fix(track, t, 500.0 + 10.0 * t if t < 60 else 1100.0 - 10.0 * (t - 60)),
            SpeedSample(T0 + t * NS, 10.0),
        ]
    ingest = Ingest(track, train)
    out = list(ingest.run(evs))
    assert dict(ingest.stats.dropped[SPEED]) == {"reversing": 56}
    assert _seconds(out) == list(range(64))


def test_a_known_but_invalid_covariance_is_repaired_with_position_std(track, train):
    ingest = Ingest(track, train, IngestConfig(position_std=3.0))
    fixes = [
        fix_at(track, 0.0, 500.0),
        fix_at(track, 1.0, 500.0),
        fix_at(track, 2.0, 500.0),
    ]
    fixes[0] = GnssFix(fixes[0].stamp_ns, fixes[0].lat, fixes[0].lon, 0, math.nan, True)  # known, NaN
    fixes[1] = GnssFix(fixes[1].stamp_ns, fixes[1].lat, fixes[1].lon, 0, -1.0, True)  # known, negative
    fixes[2] = GnssFix(fixes[2].stamp_ns, fixes[2].lat, fixes[2].lon, 0, 2.0, True)  # known, valid
    out = []
    for k, fix in enumerate(fixes):
        out += ingest.add_fix(fix)
        out += ingest.add_speed(SpeedSample(T0 + k * NS, 0.0))
    out += ingest.flush()
    assert dict(ingest.stats.repaired[GNSS]) == {"bad_covariance": 2}
    assert ingest.stats.dropped[GNSS] == {} and ingest.stats.accepted[GNSS] == 3
    assert [m.s_variance for m in out] == [9.0, 9.0, 2.0]


def test_a_bag_loop_is_one_clock_reset_and_a_new_run_with_nothing_dropped(track, train):
    profile = Profile()
    first = events(track, profile, until=40.0)
    ingest = Ingest(track, train)
    out = list(ingest.run([*first, *first]))
    assert ingest.stats.clock_resets == 1
    assert ingest.stats.as_dict()["dropped"] == {}
    assert ingest.stats.received[SPEED] == 80 and ingest.stats.accepted[SPEED] == 80
    assert _runs(out) == [(0, 40), (1, 40)]
    assert [m.s for m in out[:40]] == [m.s for m in out[40:]]


def test_a_stamp_seen_before_is_a_duplicate_even_when_it_is_not_the_latest(track, train):
    ingest = Ingest(track, train)
    for e in events(track, Profile(), until=10.0):
        ingest.add(e)
    ingest.add_speed(SpeedSample(T0 + 8 * NS, 1.0))  # 8 s was released: a duplicate, not out of order
    assert dict(ingest.stats.dropped[SPEED]) == {"duplicate": 1}


def _speed_step_run(track, train, speed, fix_from: tuple[int, int] | None = None):
    """40-50 s at 1 Hz with max_acceleration 1 m/s^2: speed(k) in m/s; the fixes follow it (none in fix_from)."""
    ingest = Ingest(track, train, IngestConfig(max_acceleration=1.0))
    out, s = [], 200.0
    for k in range(50 if fix_from is None else 40):
        if fix_from is None or not fix_from[0] <= k < fix_from[1]:
            out += ingest.add_fix(fix_at(track, float(k), s))
        out += ingest.add_speed(SpeedSample(T0 + k * NS, speed(k)))
        s += speed(k) if fix_from is None else 10.0
    return ingest, out + ingest.flush()


def test_a_new_speed_level_held_for_speed_step_time_is_accepted_with_its_earlier_samples(track, train):
    """10 -> 25 m/s in 1 s (beyond 1 m/s^2), the fixes moving at 25 m/s: the new level is a speed_jump until it has
    held for speed_step_time (10 s); then its 10 earlier samples are accepted too and their drops taken back."""
    ingest, out = _speed_step_run(track, train, lambda k: 10.0 if k < 20 else 25.0)
    assert ingest.stats.dropped[SPEED] == {} and ingest.stats.consecutive_dropped[SPEED] == 0
    assert ingest.stats.accepted[SPEED] == 50 and ingest.stats.published == 50
    assert [m.v for m in out[18:31]] == [10.0] * 2 + [25.0] * 11


def test_a_slip_shorter_than_speed_step_time_stays_a_speed_jump_without_fixes_to_contradict_it(track, train):
    """A 5 s wheel slip (25 m/s while the train runs at 10) in a GNSS gap: 5 speed_jump drops, nothing of it
    published, although no fix contradicts it."""
    ingest, out = _speed_step_run(track, train, lambda k: 25.0 if 20 <= k < 25 else 10.0, fix_from=(15, 30))
    assert dict(ingest.stats.dropped[SPEED]) == {"speed_jump": 5}
    assert ingest.stats.accepted[SPEED] == 35 and ingest.stats.published == 35
    assert [(m.stamp_ns - T0) // NS for m in out[18:22]] == [18, 19, 25, 26] and {m.v for m in out} == {10.0}


def test_a_speed_change_across_a_gap_longer_than_run_gap_is_no_speed_jump(track, train):
    ingest = Ingest(track, train, IngestConfig(max_acceleration=0.01, run_gap=10.0))
    out = []
    for t, s, v in ((0, 500.0, 5.0), (20, 600.0, 10.0), (21, 610.0, 10.0)):
        out += ingest.add_fix(fix_at(track, float(t), s))
        out += ingest.add_speed(SpeedSample(T0 + t * NS, v))
    out += ingest.flush()
    assert ingest.stats.dropped[SPEED] == {}
    assert [(m.v, m.run_id) for m in out] == [(5.0, 0), (10.0, 1), (10.0, 1)]


def test_an_accepted_speed_step_takes_back_the_speed_jump_drops_of_its_held_samples(track, train):
    """10 m/s, then from 45 s a new level of 18 m/s, with max_acceleration 0.5 m/s^2 (the bound, grown with the time
    since the last accepted sample, reaches the step only after 16 s) and no fixes after 40 s to contradict it: the
    step is accepted once held for speed_step_time (10 s, at 55 s); the samples that held it (45-54 s) are then
    published after all and no longer counted as speed_jump drops."""
    evs = []
    for t in range(80):
        if t <= 40:
            evs.append(_fix(track, t, 500.0 + 10.0 * t))
        evs.append(SpeedSample(T0 + t * NS, 10.0 if t < 45 else 18.0))
    ingest = Ingest(track, train, IngestConfig(max_acceleration=0.5))
    out = list(ingest.run(evs))
    assert dict(ingest.stats.dropped[SPEED]) == {}
    assert ingest.stats.accepted[SPEED] == 80
    assert _seconds(out) == list(range(80))
    assert [m.v for m in out] == [10.0] * 45 + [18.0] * 35


def test_the_last_two_valid_speed_samples_are_known_as_duplicates_after_a_rejected_stretch(track, train):
    """Valid speed at 0-9 s, then 11 s of NaN speeds (fixes go on): the pairer forgets what no sample can pair with,
    but keeps the last two valid speed samples; repeats of them (8 s, 9 s) are duplicates, a repeat of 7 s
    (forgotten, older than the last release) is out of order. Nothing of the repeats is published."""
    ingest = Ingest(track, train)
    out = []
    for t in range(21):
        out += ingest.add_fix(fix_at(track, float(t), 500.0 + 10.0 * t))
        out += ingest.add_speed(SpeedSample(T0 + t * NS, 10.0 if t < 10 else math.nan))
    for t in (7, 8, 9):
        out += ingest.add_speed(SpeedSample(T0 + t * NS, 10.0))
    out += ingest.flush()
    assert dict(ingest.stats.dropped[SPEED]) == {"nan": 11, "out_of_order": 1, "duplicate": 2}
    assert _seconds(out) == list(range(10)) and ingest.stats.published == 10
