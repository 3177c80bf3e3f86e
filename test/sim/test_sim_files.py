"""The bundled track and train files: they load, and their contents are what the papers describe."""

from __future__ import annotations

import math

import numpy as np
import pytest
from sim_helpers import REPO, TRACKS, TRAINS, track, train

from train_calib.sim.trackgen import BUNDLED, render


@pytest.mark.parametrize("name", TRACKS)
def test_track_files_load_and_are_marked_synthetic(name):
    trk = track(name)
    assert "SYNTHETIC" in trk.description
    assert "SYNTHETIC" in (REPO / "config" / "tracks" / f"{name}.yaml").read_text().splitlines()[0]
    assert len(trk.stations) >= 2


@pytest.mark.parametrize("make", BUNDLED, ids=lambda f: f.__name__)
def test_track_files_are_the_generators_output(make):
    spec = make()
    assert (REPO / "config" / "tracks" / f"{spec.name}.yaml").read_text() == render(spec)


@pytest.mark.parametrize("name", TRACKS)
def test_geometry_consistent_with_chainage_and_curves(name):
    trk = track(name)
    e, n = trk.east_m, trk.north_m
    chord = np.hypot(np.diff(e), np.diff(n))
    ds = np.diff(trk.geometry_s_m)
    mid = 0.5 * (trk.geometry_s_m[1:] + trk.geometry_s_m[:-1])
    k_mid = trk.curvature(mid) / 0.7  # 1 / R of the curve list (curve resistance is 0.7 / R)
    # every vertex pair is a chord of the listed straight or arc: 2 R sin(ds / 2R) (coordinates to 1e-7 deg)
    expected_chord = np.where(k_mid > 0, 2 * np.sin(ds * k_mid / 2) / np.maximum(k_mid, 1e-12), ds)
    assert np.allclose(chord, expected_chord, rtol=0, atol=0.03)
    heading = np.unwrap(np.arctan2(np.diff(e), np.diff(n)))
    # the heading turns by length / R over every curve of the file, and not elsewhere
    turn = np.abs(np.diff(heading))
    expected = 0.5 * (k_mid[1:] * ds[1:] + k_mid[:-1] * ds[:-1])
    assert np.allclose(turn, expected, atol=2e-3)


def test_intercity_corridor():
    trk = track("intercity_32km")
    a, b = trk.stations
    assert b.s_m - a.s_m == 32103.0  # Cunillera et al. 2022, 4.1
    assert trk.speed_limit_at(a.s_m) == pytest.approx(40 / 3.6) and trk.speed_limit_at(b.s_m) == pytest.approx(40 / 3.6)
    assert trk.speed_limit_at(16000.0) == pytest.approx(140 / 3.6)
    assert len(trk.tunnels) == 1
    assert np.max(np.abs(trk.gradient.values)) <= 0.005  # predominantly flat


def test_tunnel_line():
    trk = track("tunnel_line_37km")
    lengths = [t.end_m - t.start_m for t in trk.tunnels]
    assert lengths == [350.0, 270.0, 1250.0, 2230.0]  # De Martinis & Corman 2019, 5.1
    assert max(trk.speed_limit.values) == pytest.approx(160 / 3.6)
    assert trk.stations[-1].s_m - trk.stations[0].s_m == pytest.approx(36800.0)


def test_dense_corridor():
    trk = track("dense_corridor_14km")
    assert len(trk.sections) == 42  # Besinovic et al. 2013, 4
    starts = [s.start_m for s in trk.sections]
    ends = [s.end_m for s in trk.sections]
    assert starts[0] == 0.0 and ends[-1] == trk.length_m and starts[1:] == ends[:-1]
    assert trk.stations[-1].s_m - trk.stations[0].s_m == pytest.approx(14300.0)
    assert len(set(trk.speed_limit.values)) >= 5


@pytest.mark.parametrize("name", TRAINS)
def test_train_files(name):
    trn = train(name)
    assert trn.rotating_mass_factor == 1.06 and trn.max_brake_decel == 0.66
    assert trn.length_m in (108.0, 162.0, 270.0, 282.0)  # Besinovic Table 2
    text = (REPO / "config" / "trains" / f"{name}.yaml").read_text()
    assert "Besinovic" in text and "ESTIMATED" in text
    # a train starts and reaches 140 km/h on the level
    v = np.linspace(0.1, 140 / 3.6, 100)
    assert np.all(trn.tractive_envelope(v) > trn.davis(v))


def test_virm6_values_and_the_c0_unit_fix():
    trn = train("virm6")
    assert (trn.max_tractive_effort, trn.max_tractive_power) == (0.562, 6.21)
    assert trn.davis.as_tuple() == (1.53e-2, 1.939e-4, 4.08e-5)
    # transition c2/c0 near the 38 km/h of Cunillera et al. (2022), 4.4
    assert trn.transition_speed_ms * 3.6 == pytest.approx(38.0, abs=2.0)
    # rated 2388 kW at the wheel per unit effective mass
    assert trn.max_tractive_power * trn.effective_mass_kg == pytest.approx(2388e3, rel=0.01)
    assert math.isclose(trn.length_m, 162.0)
