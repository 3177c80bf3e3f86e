"""Ingest core: map matching with continuity, pairing at different rates, drops by reason, run segmentation.

Synthetic runs on test/data/small_track.yaml (a 3 km line due north) with exactly known positions; the
hairpin tests build a line that comes back parallel to itself 50 m away, where a projection onto the
whole polyline picks the wrong branch.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from train_calib.errors import ConfigError
from train_calib.ingest import (
    GNSS,
    POWER,
    SPEED,
    GnssFix,
    Ingest,
    IngestConfig,
    PowerSample,
    SpeedSample,
)
from train_calib.piecewise import PiecewiseConstant
from train_calib.track import Station, Track, load_track
from train_calib.train import load_train

NS = 1_000_000_000
T0 = 1_700_000_000 * NS


@pytest.fixture(scope="module")
def track(request):
    from repo_paths import DATA

    return load_track(DATA / "small_track.yaml")


@pytest.fixture(scope="module")
def train():
    from repo_paths import DATA

    return load_train(DATA / "small_train.yaml")


class Profile:
    """Stand at s0 for `wait` s, accelerate at a to v_max, cruise, brake at b to a stop at s_stop, stand."""

    def __init__(self, s0=200.0, s_stop=2800.0, v_max=20.0, a=0.5, b=0.5, wait=30.0, dwell=60.0):
        self.s0, self.v_max, self.a, self.b, self.wait = s0, v_max, a, b, wait
        d_acc, d_brk = v_max**2 / (2 * a), v_max**2 / (2 * b)
        self.t1 = wait + v_max / a
        self.t2 = self.t1 + (s_stop - s0 - d_acc - d_brk) / v_max
        self.t3 = self.t2 + v_max / b
        self.end = self.t3 + dwell

    def __call__(self, t):
        t = np.asarray(t, dtype=float)
        ta = np.clip(t - self.wait, 0.0, self.t1 - self.wait)
        s = self.s0 + 0.5 * self.a * ta**2
        v = self.a * ta
        tc = np.clip(t - self.t1, 0.0, self.t2 - self.t1)
        s = s + self.v_max * tc
        tb = np.clip(t - self.t2, 0.0, self.t3 - self.t2)
        s = s + self.v_max * tb - 0.5 * self.b * tb**2
        v = np.where(t > self.t1, self.v_max - self.b * tb, v)
        return s, np.maximum(v, 0.0)


def fix_at(track, t_s, s, offset_east=0.0, status=0):
    lat, lon = track.latlon_at(s)
    if offset_east:
        e, n = track.to_enu(lat, lon)
        lat, lon = track.frame.to_geodetic(e + offset_east, n)
    return GnssFix(T0 + round(t_s * NS), float(lat), float(lon), status)


def events(track, profile, fix_dt=1.0, speed_dt=1.0, fix_offset=0.0, fix_first=True, until=None):
    """Fixes and speed samples of the profile in stamp order (fix before speed at equal stamps if fix_first)."""
    until = profile.end if until is None else until
    out = []
    for t in np.arange(0.0, until, fix_dt) + fix_offset:
        s, _ = profile(t)
        out.append((t, 0 if fix_first else 1, fix_at(track, t, float(s))))
    for t in np.arange(0.0, until, speed_dt):
        _, v = profile(t)
        out.append((t, 1 if fix_first else 0, SpeedSample(T0 + round(t * NS), float(v))))
    out.sort(key=lambda e: (e[0], e[1]))
    return [e[2] for e in out]


def run_all(ingest, evs):
    return list(ingest.run(evs))


def test_synchronous_1hz_positions_are_exact_and_track_terms_are_over_the_train(track, train):
    profile = Profile()
    ms = run_all(Ingest(track, train), events(track, profile))
    assert len(ms) == math.ceil(profile.end)
    t = np.array([(m.stamp_ns - T0) / NS for m in ms])
    s_true, v_true = profile(t)
    s = np.array([m.s for m in ms])
    assert np.max(np.abs(s - s_true)) < 1e-3  # projection is exact to < 1 mm on this line
    assert all(m.s_measured for m in ms)
    assert np.array_equal([m.v for m in ms], v_true)
    assert [m.run_id for m in ms] == [0] * len(ms)
    assert ms[0].dt == 0.0 and all(m.dt == 1.0 for m in ms[1:])
    # g(s) averaged over the 100 m train: at s = 1050 the train straddles 0 and 5 permille -> 2.5 permille
    i = int(np.argmin(np.abs(s - 1050.0)))
    expected = 9.81 * (0.005 * max(0.0, s[i] - 1000.0) / 100.0)
    assert ms[i].track_force == pytest.approx(expected, abs=1e-9)
    for m in ms[::17]:
        assert m.track_force == pytest.approx(float(track.track_force(m.s, train.length_m)), abs=1e-12)
        assert m.tunnel_fraction == pytest.approx(float(track.tunnel_fraction(m.s, train.length_m)), abs=1e-12)
        assert m.speed_limit == float(track.speed_limit_at(m.s))
    # inside the tunnel (1200-1600 m) with the whole train
    inside = [m for m in ms if 1300.0 < m.s < 1600.0]
    assert inside and all(m.tunnel_fraction == 1.0 for m in inside)
    assert ms[0].v_variance == pytest.approx((1 / 3.6) ** 2)
    assert ms[0].s_variance == pytest.approx(16.0)


def test_deferred_track_terms_are_the_terms_computed_per_sample(track, train):
    """defer_terms + fill_terms (offline: one numpy pass) gives the Measurements of the per-sample ingest, bit for bit,
    across a clock reset (a bag loop: a new releaser), with the samples flushed at the end computed per sample."""
    evs = events(track, Profile())
    evs = evs + evs[:400]  # the bag again from its start: a clock reset
    reference = run_all(Ingest(track, train), evs)
    ingest, ms = Ingest(track, train), []
    ingest.defer_terms()
    for e in evs:
        ms += ingest.add(e)
    assert all(math.isnan(m.track_force) for m in ms)
    ingest.fill_terms()
    ms += ingest.flush()
    assert ingest.stats.clock_resets == 1 and len(ms) == len(reference)
    assert [repr(m) for m in ms] == [repr(m) for m in reference]


def test_skipping_the_delay_estimate_changes_nothing_else(track, train):
    """skip_delay_estimate (offline: nobody reads the estimate) gives the same Measurements and counts, across a
    clock reset; only gnss_delay_estimate stays None."""
    evs = events(track, Profile())
    evs = evs + evs[:400]  # the bag again from its start: a clock reset
    reference, skipping = Ingest(track, train), Ingest(track, train)
    skipping.skip_delay_estimate()
    expected, ms = run_all(reference, evs), run_all(skipping, evs)
    assert [repr(m) for m in ms] == [repr(m) for m in expected]
    assert skipping.stats.as_dict() == reference.stats.as_dict() and skipping.stats.clock_resets == 1
    assert reference.gnss_delay_estimate is not None and skipping.gnss_delay_estimate is None


def test_pairing_at_different_rates_dead_reckons_between_fixes(track, train):
    """Speed at 10 Hz, fixes at 0.2 Hz offset by 0.37 s, pairing within 0.5 s: one measurement per speed
    sample, s within 0.3 m, paired near the fixes and dead-reckoned between them."""
    profile = Profile()
    ingest = Ingest(track, train, IngestConfig(pair_tolerance=0.5))
    ms = run_all(ingest, events(track, profile, fix_dt=5.0, speed_dt=0.1, fix_offset=0.37))
    n_speed = len(np.arange(0.0, profile.end, 0.1))
    first_fix_t = 0.37
    # speed samples before the first fix are held for max_pairing_wait; those within 0.5 s of it are paired
    t = np.array([(m.stamp_ns - T0) / NS for m in ms])
    assert t[0] == pytest.approx(0.0) and ingest.stats.dropped[SPEED] == {}
    assert len(ms) + ingest.stats.dropped[SPEED]["no_position"] == n_speed
    s_true, _ = profile(t)
    err = np.abs(np.array([m.s for m in ms]) - s_true)
    assert err.max() < 0.3, err.max()  # trapezoidal dead reckoning on exact speeds at 10 Hz
    measured = np.array([m.s_measured for m in ms])
    fix_t = np.arange(0.0, profile.end, 5.0) + first_fix_t
    nearest_fix = np.min(np.abs(t[:, None] - fix_t[None, :]), axis=1)
    assert np.array_equal(measured, nearest_fix <= 0.5 + 1e-9)
    var = np.array([m.s_variance for m in ms])
    assert np.all(var[~measured] > 16.0)  # grows while dead reckoning


def test_a_fix_arriving_after_the_speed_of_its_epoch_is_still_paired(track, train):
    profile = Profile()
    early = run_all(Ingest(track, train), events(track, profile, fix_first=True))
    late = run_all(Ingest(track, train), events(track, profile, fix_first=False))
    assert [m.s for m in late] == [m.s for m in early]
    assert all(m.s_measured for m in late)


def test_a_dead_fix_stream_is_waited_for_at_most_max_pairing_wait(track, train):
    """After the GNSS stops, each speed sample comes out when an input max_pairing_wait (1 s) newer arrives."""
    profile = Profile()
    evs = [e for e in events(track, profile) if not (isinstance(e, GnssFix) and e.stamp_ns > T0 + 50 * NS)]
    ingest = Ingest(track, train)
    released_late = []
    for e in evs:
        out = ingest.add(e)
        if isinstance(e, SpeedSample) and e.stamp_ns > T0 + 52 * NS:
            released_late.append(len(out))
    # each speed sample after the outage comes out at once (the stale stream is not waited for)
    assert released_late and all(n == 1 for n in released_late)
    assert ingest.pending == 1 and len(ingest.flush()) == 1 and ingest.pending == 0


def _hairpin_track() -> Track:
    """3 km north along lon 5.0, a 50 m wide turn, 3 km back south: two branches 50 m apart."""
    from train_calib.geodesy import LocalFrame

    frame = LocalFrame(52.0, 5.0)
    east = [0.0, 0.0, 25.0, 50.0, 50.0]
    north = [0.0, 3000.0, 3025.0, 3000.0, 0.0]
    s = [0.0]
    for i in range(1, len(east)):
        s.append(s[-1] + math.hypot(east[i] - east[i - 1], north[i] - north[i - 1]))
    lat, lon = frame.to_geodetic(np.array(east), np.array(north))
    return Track(
        name="hairpin",
        length_m=s[-1],
        geometry_s_m=np.array(s),
        geometry_lat=np.asarray(lat),
        geometry_lon=np.asarray(lon),
        gradient=PiecewiseConstant([0.0], [0.0]),
        curvature=PiecewiseConstant([0.0], [0.0]),
        speed_limit=PiecewiseConstant([0.0], [40.0]),
        tunnel=PiecewiseConstant([0.0], [0.0]),
        stations=[Station(500.0, "Out"), Station(s[-1] - 500.0, "Back")],
    )


def _fix_offset(track, t_s, s, east_offset):
    e, n = track.enu_at(s)
    lat, lon = track.frame.to_geodetic(e + east_offset, n)
    return GnssFix(T0 + round(t_s * NS), float(lat), float(lon))


def test_continuity_keeps_the_branch_where_projection_on_the_whole_line_would_jump(train):
    track = _hairpin_track()
    config = IngestConfig(max_cross_track=35.0)
    ingest = Ingest(track, train, config)
    out = []
    for k in range(60):  # 10 m/s on the outbound branch from s = 500, every 4th fix pulled 30 m east
        t = float(k)
        s_true = 500.0 + 10.0 * t
        offset = 30.0 if k % 4 == 3 else 0.0
        out += ingest.add_fix(_fix_offset(track, t, s_true, offset))
        out += ingest.add_speed(SpeedSample(T0 + k * NS, 10.0))
        # the pulled fix is nearer the return branch: the whole-line projection would say ~6 km
        if offset:
            s_whole, _ = track.project(*[float(x) + y for x, y in zip(track.enu_at(s_true), (offset, 0.0))])
            assert s_whole > 3100.0
    s = np.array([m.s for m in out])
    assert np.max(np.abs(s - (500.0 + 10.0 * np.arange(60)))) < 1e-3
    assert ingest.stats.dropped[GNSS] == {}


def test_start_at_a_station_resolves_the_first_fix(train):
    track = _hairpin_track()
    far_from_out = 30.0  # first fix at station Out, pulled 30 m toward the return branch
    for start_station, expect_near in (("", track.length_m - 500.0), ("Out", 500.0)):
        ingest = Ingest(track, train, IngestConfig(max_cross_track=35.0, start_station=start_station))
        ingest.add_fix(_fix_offset(track, 0.0, 500.0, far_from_out))
        (m,) = ingest.add_speed(SpeedSample(T0, 0.0))
        assert abs(m.s - expect_near) < 25.0, (start_station, m.s)


def test_unknown_start_station_is_refused(track, train):
    with pytest.raises(ConfigError, match=r"no station 'Nowhere'.*Alpha, Beta"):
        Ingest(track, train, IngestConfig(start_station="Nowhere"))


def test_jumps_and_off_track_fixes_are_dropped_and_consistent_jumps_reacquire(track, train):
    profile = Profile()
    evs = events(track, profile, until=100.0)
    ingest = Ingest(track, train)
    out = []
    for e in evs:
        t = (e.stamp_ns - T0) / NS
        if isinstance(e, GnssFix) and t in (60.0, 61.0):
            s_true, _ = profile(t)
            e = fix_at(track, t, float(s_true) + 800.0)  # on the track 800 m ahead: a jump
        if isinstance(e, GnssFix) and t == 70.0:
            s_true, _ = profile(t)
            e = fix_at(track, t, float(s_true), offset_east=200.0)  # 200 m off the line
        out += ingest.add(e)
    out += ingest.flush()
    assert dict(ingest.stats.dropped[GNSS]) == {"jump": 2, "off_track": 1}
    t = np.array([(m.stamp_ns - T0) / NS for m in out])
    s_true, _ = profile(t)
    err = np.abs(np.array([m.s for m in out]) - s_true)
    assert err.max() < 1e-3  # the bad fixes never moved the position; their epochs were dead-reckoned exactly
    # their epochs were paired with the neighbouring good fixes, 1 s away
    assert [m.s_measured for m in out if m.stamp_ns in (T0 + 60 * NS, T0 + 61 * NS, T0 + 70 * NS)] == [True] * 3
    assert ingest.stats.reacquisitions == 0

    # the position really was wrong (e.g. a bad first lock): three consistent fixes elsewhere re-acquire
    ingest = Ingest(track, train)
    ingest.add_fix(fix_at(track, 0.0, 2000.0))
    ingest.add_speed(SpeedSample(T0, 0.0))
    for k in range(1, 5):
        ingest.add_fix(fix_at(track, float(k), 300.0))
        out = ingest.add_speed(SpeedSample(T0 + k * NS, 0.0))
    assert dict(ingest.stats.dropped[GNSS]) == {"jump": 2}
    assert ingest.stats.reacquisitions == 1
    assert out[0].s == pytest.approx(300.0, abs=1e-3) and out[0].s_measured


@pytest.mark.parametrize("v, matched", [(5.0, True), (12.0, False)])
def test_at_shunting_speed_the_window_also_covers_motion_against_the_track_direction(track, train, v, matched):
    """After 20 s without samples the train is 20 v behind where it was: at or below reverse_max_speed (10 m/s)
    the fix there is matched, above it the fix is a jump (and the position dead-reckoned forward)."""
    ingest = Ingest(track, train)
    out = ingest.add_fix(fix_at(track, 0.0, 1000.0)) + ingest.add_speed(SpeedSample(T0, v))
    out += ingest.add_fix(fix_at(track, 20.0, 1000.0 - 20.0 * v)) + ingest.add_speed(SpeedSample(T0 + 20 * NS, v))
    out += ingest.flush()
    assert dict(ingest.stats.dropped[GNSS]) == ({} if matched else {"jump": 1})
    assert [m.s_measured for m in out] == [True, matched]
    assert out[1].s == pytest.approx(1000.0 - 20.0 * v if matched else 1000.0 + 20.0 * v, abs=1e-3)


def test_reacquisition_after_a_gnss_gap_with_drifting_dead_reckoning(track, train):
    """A 100 s GNSS gap; the speed reads 2 % high, so the dead-reckoned position drifts ~30 m; the next fix
    is still matched (the window grew with the gap) and the position snaps back."""
    profile = Profile(v_max=15.0, s_stop=2900.0)
    evs = []
    for e in events(track, profile):
        t = (e.stamp_ns - T0) / NS
        if isinstance(e, GnssFix) and 60.0 < t < 160.0:
            continue
        if isinstance(e, SpeedSample):
            e = SpeedSample(e.stamp_ns, e.v * 1.02)
        evs.append(e)
    ingest = Ingest(track, train)
    out = run_all(ingest, evs)
    by_t = {round((m.stamp_ns - T0) / NS): m for m in out}
    assert not by_t[120].s_measured and by_t[120].s_variance > 16.0 + (1 / 3.6 * 59) ** 2
    assert by_t[150].s - float(profile(150.0)[0]) > 20.0  # drifted (10 s from the next fix)
    # 156 s is released (dead-reckoned) 1 s later (max_pairing_wait), not held for the fix of 160 s; 159 s is
    # released by that fix and paired with it
    assert not by_t[150].s_measured and not by_t[156].s_measured and by_t[159].s_measured
    # the sample of 159 s waited for the fix stream: the fix of 160 s came first and anchors it (1 s back)
    assert by_t[159].s == pytest.approx(float(profile(159.0)[0]) - 0.3, abs=1e-3)
    assert by_t[160].s_measured and by_t[160].s == pytest.approx(float(profile(160.0)[0]) + 0.0, abs=1e-3)
    assert ingest.stats.dropped[GNSS] == {} and ingest.stats.reacquisitions == 0


def test_every_bad_sample_is_dropped_with_its_reason_and_never_published(track, train):
    profile = Profile()
    ingest = Ingest(track, train)
    good = events(track, profile, until=120.0)
    bad_speed_t = {}
    out = []
    for e in good:
        t = (e.stamp_ns - T0) / NS
        if isinstance(e, SpeedSample):
            if t == 40.0:
                e, bad_speed_t[40] = SpeedSample(e.stamp_ns, math.nan), "nan"
            elif t == 41.0:
                e, bad_speed_t[41] = SpeedSample(e.stamp_ns, -1.0), "negative_speed"
            elif t == 42.0:
                e, bad_speed_t[42] = SpeedSample(e.stamp_ns, 150.0), "implausible_speed"
            elif t == 45.0:
                e, bad_speed_t[45] = SpeedSample(e.stamp_ns, e.v + 8.0), "speed_jump"
        if isinstance(e, GnssFix):
            if t == 50.0:
                e = GnssFix(e.stamp_ns, math.nan, e.lon)
            elif t == 51.0:
                e = GnssFix(e.stamp_ns, e.lat, e.lon, status=-1)
        out += ingest.add(e)
        if isinstance(e, SpeedSample) and t == 60.0:
            out += ingest.add(SpeedSample(e.stamp_ns, e.v))  # duplicate stamp
            out += ingest.add(SpeedSample(e.stamp_ns - 45 * NS, 1.0))  # 45 s old: stale
        if isinstance(e, GnssFix) and t == 70.0:
            out += ingest.add(PowerSample(e.stamp_ns, -5.0, 0.0))
            out += ingest.add(PowerSample(e.stamp_ns + 1, math.inf, 0.0))
    out += ingest.flush()
    assert dict(ingest.stats.dropped[SPEED]) == {
        "nan": 1,
        "negative_speed": 1,
        "implausible_speed": 1,
        "speed_jump": 1,
        "duplicate": 1,
        "stale": 1,
    }
    assert dict(ingest.stats.dropped[GNSS]) == {"nan": 1, "no_fix": 1}
    assert dict(ingest.stats.dropped[POWER]) == {"negative_power": 1, "nan": 1}
    stamps = [(m.stamp_ns - T0) // NS for m in out]
    assert not set(bad_speed_t) & set(stamps)
    assert len(out) == 120 - 4 and len(set(stamps)) == len(stamps)
    assert all(math.isfinite(m.s) and m.v >= 0.0 for m in out)
    assert ingest.stats.received[SPEED] == 122 and ingest.stats.accepted[SPEED] == 116
    assert ingest.stats.published == len(out)


def test_run_segmentation_new_run_at_a_departure_after_a_standstill(track, train):
    ingest = Ingest(track, train, IngestConfig(min_standstill=20.0, run_gap=300.0))
    speeds = [0.0] * 30 + [2.5] * 20 + [0.0] * 10 + [2.5] * 20 + [0.0] * 25 + [2.5] * 10
    stamps = list(range(len(speeds)))
    stamps += [stamps[-1] + 400 + k for k in range(5)]  # a 400 s gap in the speed stream
    speeds += [2.5] * 5
    s = 200.0
    out = []
    for k, (t, v) in enumerate(zip(stamps, speeds)):
        out += ingest.add_fix(fix_at(track, float(t), min(s, 2900.0)))
        out += ingest.add_speed(SpeedSample(T0 + t * NS, v))
        if k + 1 < len(stamps):
            s += v * (stamps[k + 1] - t) if stamps[k + 1] - t < 10 else 0.0
    runs = [m.run_id for m in out]
    # initial standstill and first departure: run 0; a 10 s stop: still run 0; 25 s stop then departure: run 1;
    # the 400 s gap: run 2
    assert runs == [0] * 80 + [0] * 25 + [1] * 10 + [2] * 5
    first_of_run = [m for i, m in enumerate(out) if i == 0 or out[i - 1].run_id != m.run_id]
    assert [m.dt for m in first_of_run] == [0.0, 0.0, 0.0]
    assert all(m.dt == 1.0 for i, m in enumerate(out) if i and out[i - 1].run_id == m.run_id)


def test_a_gap_at_standstill_starts_no_new_run(track, train):
    """A run starts anew after a gap longer than run_gap only once it has moved: 400 s at a standstill is one run."""
    ingest = Ingest(track, train)
    out = []
    for t in [*range(10), *range(410, 420)]:
        out += ingest.add_fix(fix_at(track, float(t), 500.0))
        out += ingest.add_speed(SpeedSample(T0 + t * NS, 0.0))
    out += ingest.flush()
    assert [m.run_id for m in out] == [0] * 20
    assert out[10].dt == 401.0  # from 9 s to 410 s


def test_power_is_paired_by_stamp(track, train):
    profile = Profile()
    ingest = Ingest(track, train)
    out = []
    for e in events(track, profile, until=60.0):
        out += ingest.add(e)
        if isinstance(e, GnssFix) and (e.stamp_ns - T0) // NS % 2 == 0:
            out += ingest.add(PowerSample(e.stamp_ns + NS // 10, 1.0e6, 0.0))
    out += ingest.flush()
    for m in out:
        even = (m.stamp_ns - T0) // NS % 2 == 0
        assert m.power_valid == even
        assert m.power_consumed == (1.0e6 if even else 0.0)


def test_parameters_are_validated_with_reasons():
    assert IngestConfig.check("max_cross_track", -1.0)[1] == "-1 m is out of range: must be greater than 0 m"
    assert IngestConfig.check("reacquire_after", 2.5)[1] == "expected an integer, found 2.5"
    assert IngestConfig.check("start_station", 3)[1].startswith("expected a string")
    with pytest.raises(ConfigError, match=r"standstill_speed: 5 m/s must be below max_speed \(4 m/s\)"):
        IngestConfig.from_mapping({"standstill_speed": 5.0, "max_speed": 4.0})
