"""Drop reasons the other ingest tests leave at zero, made non-zero through the public ``Ingest`` API only (issue 23's
mutation test: deleting a drop count passed the whole suite). Self-contained: a straight line due north on
test/data/small_track.yaml, a train standing, accelerating at 0.5 m/s^2 and cruising at 20 m/s, fixes and speed at
1 Hz at exactly known positions.
"""

from __future__ import annotations

import numpy as np
import test_ingest

from train_calib.ingest import GNSS, POWER, SPEED, GnssFix, Ingest, IngestConfig, PowerSample, SpeedSample

NS = 1_000_000_000
T0 = 1_700_000_000 * NS
track, train = test_ingest.track, test_ingest.train  # the small track and train fixtures


def _position(t: float) -> tuple[float, float]:
    """(s m, v m/s): standing at 200 m for 10 s, then 0.5 m/s^2 up to 20 m/s, then cruising."""
    ta = min(max(t - 10.0, 0.0), 40.0)
    s = 200.0 + 0.25 * ta * ta + 20.0 * max(t - 50.0, 0.0)
    return s, 0.5 * ta


def _events(track, until: float, fix=lambda t: True, speed=lambda t: True) -> list:
    """Fix then speed sample at every whole second below ``until`` where ``fix(t)`` / ``speed(t)``."""
    out = []
    for t in np.arange(0.0, until, 1.0):
        s, v = _position(float(t))
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


def test_speed_before_the_first_fix_is_dropped_as_no_position(track, train):
    """Speed from t = 0, GNSS only from t = 30 s: the 29 speed samples more than the pairing tolerance before the
    first fix have no position yet (not acquired); each is counted as no_position and none is published (the one at
    29 s pairs with the fix at 30 s)."""
    ingest = Ingest(track, train)
    out = list(ingest.run(_events(track, 100.0, fix=lambda t: t >= 30.0)))
    assert dict(ingest.stats.dropped[SPEED]) == {"no_position": 29}
    assert dict(ingest.stats.dropped[GNSS]) == {}
    assert _seconds(out) == list(range(29, 100))
    assert ingest.stats.received[SPEED] == 100 and ingest.stats.published == 71


def test_speed_after_a_gap_longer_than_max_dead_reckoning_is_dropped_as_no_position(track, train):
    """Fixes missing from 61 to 99 s and speed from 61 to 69 s: after the speed gap (9 s > max_dead_reckoning 5 s)
    the samples cannot be dead-reckoned from the last position; they are dropped as no_position until the fix at
    100 s positions the train again."""
    ingest = Ingest(track, train, IngestConfig(max_dead_reckoning=5.0))
    gnss_out, speed_out = (lambda t: not 60.0 < t < 100.0), (lambda t: not 60.0 < t < 70.0)
    out = list(ingest.run(_events(track, 120.0, fix=gnss_out, speed=speed_out)))
    assert dict(ingest.stats.dropped[SPEED]) == {"no_position": 29}
    assert _seconds(out) == [*range(0, 61), *range(99, 120)]
    assert ingest.stats.published == len(out) == 82


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


def test_negative_consumed_or_regenerated_power_is_dropped(track, train):
    """Either power below 0 is a negative_power drop (the regenerated one too)."""
    evs = _events(track, 20.0)
    evs[10:10] = [PowerSample(T0 + 5 * NS, 1000.0, -5.0), PowerSample(T0 + 6 * NS, -1.0, 0.0)]
    ingest = Ingest(track, train)
    list(ingest.run(evs))
    assert dict(ingest.stats.dropped[POWER]) == {"negative_power": 2}
    assert ingest.stats.accepted[POWER] == 0


def test_a_fix_beyond_max_cross_track_is_off_track_and_one_within_is_kept(track, train):
    """max_cross_track 30 m: a fix 45 m east of the line is dropped as off_track, one 15 m east is used."""
    evs = []
    for t in range(40):
        s, v = _position(float(t))
        evs += [_fix(track, t, s, east=45.0 if t == 20 else 15.0 if t == 30 else 0.0), SpeedSample(T0 + t * NS, v)]
    ingest = Ingest(track, train, IngestConfig(max_cross_track=30.0))
    out = list(ingest.run(evs))
    assert dict(ingest.stats.dropped[GNSS]) == {"off_track": 1}
    assert ingest.stats.accepted[GNSS] == 39 and len(out) == 40


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
