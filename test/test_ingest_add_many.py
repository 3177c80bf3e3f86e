"""Ingest.add_many (ingest/offline.py: the common path of add written out in one loop, the fix's position in the
window in C) against Ingest.add on each event: the same Measurements float for float and the same counts, on the
robustness scenario with every fault class, with and without the C kernel; the kernel's Locator against
geodesy.ScalarEnu and track.WindowProjector bit for bit."""

from __future__ import annotations

import json
import math
import random
import sys
from dataclasses import astuple
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent / "robustness"))
import faultlib
from build_context import kernel_skip_reason
from repo_paths import DATA
from test_ingest import NS, T0, fix_at

from train_calib.cdr_inputs import read_input_events
from train_calib.geodesy import ScalarEnu
from train_calib.ingest import GnssFix, Ingest, IngestConfig, PowerSample, SpeedSample, offline
from train_calib.paths import track_file, train_file
from train_calib.track import WindowProjector, load_track
from train_calib.train import load_train

BAGS = Path(__file__).resolve().parents[1] / "bags"
KERNEL = [True, pytest.param(False, id="python")]


def _record(e: faultlib.Event) -> GnssFix | SpeedSample | PowerSample:
    """A faultlib event as the ingest's record (what fix_from_msg, speed_from_msg, power_from_msg give)."""
    f = e.fields
    if e.topic == faultlib.GNSS:
        known = int(f.get("cov_type", 0)) != 0
        cov = f.get("cov", [0.0] * 9)
        variance = 0.5 * (float(cov[0]) + float(cov[4])) if known else math.nan
        return GnssFix(e.stamp_ns, float(f["lat"]), float(f["lon"]), int(f["status"]), variance, known)
    if e.topic == faultlib.SPEED:
        return SpeedSample(e.stamp_ns, float(f["v"]))
    return PowerSample(e.stamp_ns, float(f["consumed"]), float(f["regenerated"]))


def _exact(measurements) -> list[tuple]:
    return [tuple(x.hex() if isinstance(x, float) else x for x in astuple(m)) for m in measurements]


def _both(track, train, events, offline_like: bool, config: IngestConfig | None = None):
    """(add on each event + flush, add_many + flush): each as (exact Measurements, counts)."""
    results = []
    for many in (False, True):
        ingest = Ingest(track, train, config)
        if offline_like:  # as pipeline.run_bag
            ingest.skip_delay_estimate()
            ingest.defer_terms()
        if many:
            out = ingest.add_many(events)
        else:
            out = []
            for e in events:
                out += ingest.add(e)
        if offline_like:
            ingest.fill_terms()
        out += ingest.flush()
        stats = ingest.stats
        counts = (stats.as_dict(), dict(stats.consecutive_dropped), stats.last_drop)
        results.append((_exact(out), counts, ingest.run_id, ingest.gnss_delay_estimate))
    return results


@pytest.fixture(scope="module")
def scenario(tmp_path_factory):
    return faultlib.make_scenario(tmp_path_factory.mktemp("scenario"))


def _require_kernel() -> None:
    """Skip where the source tree has no kernel but a colcon build has one (build_context); elsewhere a missing
    kernel is a failed build, as the window's."""
    if offline._kernel is None:
        reason = kernel_skip_reason()
        if reason:
            pytest.skip(reason)
        pytest.fail("train_calib/ingest/_kernel.c is not built (setup.py build_ext --inplace, or make setup)")


@pytest.fixture(params=KERNEL)
def kernel(request, monkeypatch):
    if request.param:
        _require_kernel()
    else:
        monkeypatch.setattr(offline, "_kernel", None)
    return request.param


def _jumps(sc: faultlib.Scenario) -> list[faultlib.Event]:
    """Single fixes 300 m ahead every other second (a normal fix between two jumps), then a jump held for 4 s."""
    events = list(sc.events)
    for t in (100.0, 150.0, 152.0, 154.0, 156.0, 300.0, 301.0, 302.0, 303.0):
        events = faultlib.moved_fixes(sc.track, events, t, t + 1.0, along_m=300.0)
    return events


def _shunted(sc: faultlib.Scenario, distance: float, speed: float, a: float = 0.25, gap: float = 0.0):
    """A shunting move backwards before the run (as test_scenario_faults: reversing, the low-speed window); gap:
    every input silent for that long 5 s into the move (the fix after it is behind the window ahead)."""
    truth, duration = faultlib.shunt(sc.truth.s[0], distance, speed, a)
    shunt = faultlib.sensor_events(sc.track, truth, seed=8)
    if gap:
        shunt = [e for e in shunt if not 25.0 <= e.t < 25.0 + gap]
    return faultlib.sort_events(shunt + faultlib.delayed(sc.events, duration))


VARIANTS = {  # inputs beside the fault classes: fixes between the speed samples, sparser fixes, isolated jumps
    "gnss_0.37s_after_speed": lambda sc: faultlib.restamped(list(sc.events), 0.0, faultlib.GNSS, 0.37),
    "gnss_0.5hz_0.6s_after": lambda sc: faultlib.restamped(
        [e for e in sc.events if e.topic != faultlib.GNSS or round(e.t) % 2 == 0], 0.0, faultlib.GNSS, 0.6
    ),
    "speed_0.7s_after_gnss": lambda sc: faultlib.restamped(list(sc.events), 0.0, faultlib.SPEED, 0.7),
    "isolated_gnss_jumps": _jumps,
    "shunt_200m_then_the_run": lambda sc: _shunted(sc, 200.0, 2.0),
    "shunt_30m_then_the_run": lambda sc: _shunted(sc, 30.0, 1.0),
    "shunt_300m_8s_silent": lambda sc: _shunted(sc, 300.0, 8.0, 2.0, 8.0),
}


@pytest.mark.parametrize(
    "case", [None, *faultlib.CASES, *VARIANTS], ids=lambda c: c if isinstance(c, str) else getattr(c, "name", "none")
)
def test_add_many_is_add_on_each_event_for_every_fault_class(scenario, case, kernel):
    if case is None:
        raw = scenario.events
    elif isinstance(case, str):
        raw = VARIANTS[case](scenario)
    else:
        raw = case.inject(scenario)
    events = [_record(e) for e in raw]
    for offline_like in (True, False):
        reference, many = _both(scenario.track, scenario.train, events, offline_like)
        assert many == reference
        assert reference[0]  # Measurements were compared


def test_add_many_in_pieces_with_power_a_start_station_and_a_gnss_delay(scenario, kernel):
    """Power samples (each taken by add), the first fix matched near a start station, a known GNSS delay (the
    general path throughout), and add_many called on pieces of the input (the state carried between calls)."""
    events = [_record(e) for e in scenario.events]
    first = next(e.stamp_ns for e in events)
    events = sorted(
        [*events, *(PowerSample(first + k * 500_000_000 + 1, 1.0e5 * (k % 7), 0.0) for k in range(0, 1200))],
        key=lambda e: e.stamp_ns,
    )
    station = scenario.track.stations[0].name if scenario.track.stations else ""
    for config in (IngestConfig(start_station=station), IngestConfig(gnss_delay=0.2), IngestConfig()):
        reference, _ = _both(scenario.track, scenario.train, events, False, config)
        ingest = Ingest(scenario.track, scenario.train, config)
        out = []
        for k in range(0, len(events), 97):
            out += ingest.add_many(events[k : k + 97])
        out += ingest.flush()
        stats = ingest.stats
        counts = (stats.as_dict(), dict(stats.consecutive_dropped), stats.last_drop)
        assert (_exact(out), counts, ingest.run_id, ingest.gnss_delay_estimate) == reference


@pytest.mark.parametrize("bag", ["intercity_32km_10s_00", "intercity_32km_10s_01"])
def test_add_many_is_add_on_each_event_on_a_bundled_bag(bag, kernel):
    meta = json.loads((BAGS / f"{bag}.truth.json").read_text())
    track = load_track(track_file(meta["track"]["name"]))
    train = load_train(train_file(Path(meta["train"]["file"]).stem))
    events = read_input_events(BAGS / bag)
    assert events
    reference, many = _both(track, train, events, True)
    assert many == reference


def test_the_kernel_locator_is_scalar_enu_and_the_window_projector_bit_for_bit():
    _require_kernel()
    track = load_track(track_file("intercity_32km"))
    enu, projector = ScalarEnu(track.frame), WindowProjector(track)
    locator = offline.locator(enu, projector)
    rng = random.Random(5)
    frame, length = track.frame, projector.length
    for _ in range(20000):
        lat = frame.lat0_deg + rng.uniform(-0.3, 0.3)
        lon = frame.lon0_deg + rng.uniform(-0.3, 0.3)
        assert locator.enu(lat, lon) == enu(lat, lon)
        e, n = enu(lat, lon)
        centre = rng.uniform(-500.0, length + 500.0)
        width = rng.choice([0.0, 1.0, 60.0, 400.0, 5000.0])
        lo, hi = centre - width, centre + rng.uniform(0.0, width)
        assert locator.project(e, n, lo, hi) == projector.project(e, n, lo, hi)
        assert locator.locate(lat, lon, lo, hi) == projector.project(e, n, lo, hi)
    for e, n, lo, hi in [(0.0, 0.0, math.nan, 10.0), (1.0, 2.0, 5.0, math.inf), (math.nan, 0.0, 0.0, 100.0)]:
        a, b = locator.project(e, n, lo, hi), projector.project(e, n, lo, hi)
        assert [x.hex() for x in a] == [x.hex() for x in b]


def test_the_kernel_takes_every_bundled_track(kernel):
    for name in ("intercity_32km", "dense_corridor_14km", "tunnel_line_37km"):
        track = load_track(track_file(name))
        locator = offline.locator(ScalarEnu(track.frame), WindowProjector(track))
        assert (locator is None) == (not kernel)
        assert Ingest(track, load_train(train_file("virm6"))).add_many([]) == []


def test_add_many_matches_a_fix_behind_at_low_speed_in_the_window_of_both_directions(kernel):
    """After 8 s of silence at low speed a fix 50 m behind the last one: outside the window ahead, inside the one
    that also covers the other direction (MapMatcher._window at or below reverse_max_speed): accepted by both."""
    track, train = load_track(DATA / "small_track.yaml"), load_train(DATA / "small_train.yaml")
    events: list = []
    for k in range(11):
        events += [SpeedSample(T0 + k * NS, 2.0), fix_at(track, float(k), 1000.0 + 2.0 * k)]
    events += [SpeedSample(T0 + 18 * NS, 8.0), fix_at(track, 18.0, 970.0)]
    events += [SpeedSample(T0 + 19 * NS, 8.0), fix_at(track, 19.0, 962.0)]
    reference, many = _both(track, train, events, False)
    assert many == reference
    assert "gnss" not in reference[1][0]["dropped"]  # the fixes behind were matched, not jumps (then: reversing)
