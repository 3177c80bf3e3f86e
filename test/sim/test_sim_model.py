"""The fast scalar physics against the foundation's vectorised Track/TrainSpec/physics functions."""

from __future__ import annotations

import numpy as np
import pytest
from sim_helpers import TRACKS, track, train

from train_calib import physics
from train_calib.sim.limits import SpeedCeiling
from train_calib.sim.model import MotionModel, TrackTerms, Wind


@pytest.mark.parametrize("name", TRACKS)
def test_track_terms_are_exact(name):
    trk = track(name)
    for length in (108.0, 282.0):
        terms = TrackTerms(trk, length)
        s = np.random.default_rng(1).uniform(-100.0, trk.length_m + 100.0, 3000)
        s = np.concatenate([s, terms.knots])
        assert np.allclose([terms.g_at(x) for x in s], trk.track_force(s, length), rtol=0, atol=1e-12)
        assert np.allclose([terms.tunnel_at(x) for x in s], trk.tunnel_fraction(s, length), rtol=0, atol=1e-12)
        assert np.allclose(terms.g_vec(s), trk.track_force(s, length), rtol=0, atol=1e-12)


def test_envelope_and_resistance_match_the_foundation():
    trn = train("icrm")  # the adhesion cap binds at low speed
    trk = track("tunnel_line_37km")
    terms = TrackTerms(trk, trn.length_m)
    m = MotionModel(
        terms,
        c0=trn.max_tractive_effort,
        c2=trn.max_tractive_power,
        adhesive_mass_fraction=trn.adhesive_mass_fraction,
        rotating_mass_factor=trn.rotating_mass_factor,
        r0=trn.davis.r0,
        r1=trn.davis.r1,
        r2=trn.davis.r2,
        tunnel_factor=trn.tunnel_factor,
    )
    v = np.linspace(0.0, 45.0, 451)
    assert np.allclose([m.envelope(x) for x in v], trn.tractive_envelope(v), rtol=1e-13)
    assert np.allclose(m.envelope_vec(v), trn.tractive_envelope(v), rtol=1e-13)
    assert trn.tractive_envelope(0.0) < trn.max_tractive_effort  # adhesion binds
    s = np.linspace(0.0, trk.length_m, 451)
    expected = physics.davis(v, *trn.davis.as_tuple(), trk.tunnel_fraction(s, trn.length_m), trn.tunnel_factor)
    assert np.allclose(
        [m.opposing(0.0, a, b) for a, b in zip(s, v)], expected + trk.track_force(s, trn.length_m), rtol=0, atol=1e-13
    )
    assert np.allclose(m.resistance_vec(np.zeros_like(s), s, v), expected, rtol=0, atol=1e-13)


def test_wind_scales_r2_only():
    trk = track("intercity_32km")
    terms = TrackTerms(trk, 162.0)
    wind = Wind(0.1, 0.05, 600.0, 0.3)
    calm = MotionModel(terms, c0=0.5, c2=6.0, r0=0.01, r1=2e-4, r2=4e-5)
    windy = MotionModel(terms, c0=0.5, c2=6.0, r0=0.01, r1=2e-4, r2=4e-5, wind=wind)
    for t in (0.0, 100.0, 450.0):
        factor = 1.1 + 0.05 * np.sin(2 * np.pi * t / 600.0 + 0.3)
        assert windy.opposing(t, 5000.0, 30.0) - calm.opposing(t, 5000.0, 30.0) == pytest.approx(
            4e-5 * (factor - 1) * 900.0, rel=1e-12
        )
        assert windy.r2_in_force(t) == pytest.approx(4e-5 * factor, rel=1e-12)


def test_ceiling_waits_for_the_tail():
    trk = track("dense_corridor_14km")
    ceil = SpeedCeiling(trk, 162.0, 250.0, 14550.0)
    for s in np.linspace(300.0, 14500.0, 300):
        assert ceil.at(s) == pytest.approx(trk.limit_over_train(float(s), 162.0))
    # 80 -> 130 at 2300: the ceiling rises when the tail clears, at 2462
    assert 2300.0 + 162.0 in ceil.rises()
    assert [d.s_m for d in ceil.drops()] == [4300.0, 12600.0, 13900.0]
