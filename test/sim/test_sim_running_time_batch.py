"""The population-vectorised running-time model against the scalar one, closed forms and a fixed-step reference."""

from __future__ import annotations

import math

import numpy as np
import pytest
import yaml
from sim_helpers import reference_run_time, track, train

from train_calib.errors import ConfigError
from train_calib.physics import tractive_envelope
from train_calib.sim import RunningTimeParams, running_time_profile
from train_calib.sim.model import MotionModel, TrackTerms
from train_calib.sim.running_time_batch import running_time_batch
from train_calib.track import load_track

CASES = [
    ("dense_corridor_14km", "virm4"),
    ("dense_corridor_14km", "virm10"),
    ("intercity_32km", "virm6"),
    ("tunnel_line_37km", "icrm"),
]


def _box(rng, n):
    """A wide calibration box (wider than the bundled bounds): corners where trains stall or never cruise."""
    return dict(
        c0=rng.uniform(0.2, 1.0, n),
        c2=rng.uniform(2.0, 15.0, n),
        r0=rng.uniform(0.005, 0.03, n),
        r2=rng.uniform(1e-5, 8e-5, n),
        b_limit=rng.uniform(0.2, 1.0, n),
        b_stop=rng.uniform(0.3, 1.0, n),
        theta_cruise=rng.uniform(0.7, 1.1, n),
    )


@pytest.mark.parametrize("track_name, train_name", CASES)
def test_batch_matches_the_scalar_model_at_its_knots(track_name, train_name):
    """At the scalar model's knots (its RK45 step ends, rtol 1e-10) the batch (rtol 1e-7) gives the same times.

    Measured: <= 8e-5 s over 40 random vectors per track (1.5-3e-5 s typical); the scalar's own passage
    times between knots (cubic Hermite) are off by up to 2e-3 s at its default rtol, the batch's dense
    output is not.
    """
    trk, trn = track(track_name), train(train_name)
    base = RunningTimeParams.from_train(trn, adhesive_mass_fraction=0.0)
    s0, s1 = trk.stations[0].s_m, trk.stations[-1].s_m
    n = 16
    vals = _box(np.random.default_rng(7), n)
    batch = running_time_batch(trk, base, s0, s1, **vals)
    assert batch.time_at(np.array([s0, s1])).shape == (n, 2)
    worst = 0.0
    for i in range(n):
        p = base.replace(**{k: float(v[i]) for k, v in vals.items()})
        try:
            ref = running_time_profile(trk, p, s0, s1, rtol=1e-10)
        except ConfigError as exc:  # the same members fail, for the same reason
            assert not batch.ok[i]
            assert ("stalls" in str(exc)) == ("stalls" in batch.error[i])
            assert np.isnan(batch.run_time[i])
            continue
        assert batch.ok[i], batch.error[i]
        member = batch.member(i)
        worst = max(worst, float(np.max(np.abs(member.time_at(ref.s) - ref.t))))
        assert member.run_time == pytest.approx(ref.run_time, abs=1e-4)
        # the speed never exceeds theta x the limit over the train, and time increases
        s = np.linspace(s0, s1, 3001)
        ceiling = np.array([p.theta_cruise * trk.limit_over_train(float(x), trn.length_m) for x in s])
        assert np.all(member.speed_at(s) <= ceiling * (1 + 1e-9) + 1e-6)
        assert np.all(np.diff(member.time_at(s)) > 0)
    assert worst < 2e-4, worst


def test_adhesion_tunnels_and_c1():
    """The adhesion cap (not cut at its kinks, as in the scalar model: 3.6e-4 s measured), tunnel resistance
    and c1 of both signs (eq. 4 switches at the transition speed: measured 2e-4 s)."""
    trk, trn = track("tunnel_line_37km"), train("icrm")
    base = RunningTimeParams.from_train(trn)  # adhesion on, tunnel factor of the train file
    assert base.adhesive_mass_fraction > 0 and base.tunnel_factor > 0
    s0, s1 = trk.stations[0].s_m, trk.stations[-1].s_m
    c1 = np.array([-0.02, -0.005, 0.0, 0.01])
    batch = running_time_batch(trk, base, s0, s1, c1=c1, c2=np.full(4, 9.0))
    for i in range(c1.size):
        ref = running_time_profile(trk, base.replace(c1=float(c1[i]), c2=9.0), s0, s1, rtol=1e-10)
        assert np.max(np.abs(batch.member(i).time_at(ref.s) - ref.t)) < 1e-3


def _line(directory, gradients):
    """10 km, straight, 100 km/h, stations at 500 and 9500 m."""
    data = {
        "name": "line",
        "length_m": 10000,
        "geometry": [{"s_m": 0, "lat": 52.0, "lon": 5.0}, {"s_m": 10000, "lat": 52.0899322, "lon": 5.0}],
        "gradients": gradients,
        "speed_limits": [{"s_m": 0, "kmh": 100}],
        "stations": [{"s_m": 500, "name": "A"}, {"s_m": 9500, "name": "B"}],
    }
    path = directory / "line.yaml"
    path.write_text(yaml.safe_dump(data))
    return load_track(path)


def _steep_track(directory):
    """60 permille (0.59 N/kg) over 5 km: a train with c0 = 0.5 N/kg stalls on it."""
    return _line(directory, [{"s_m": 0, "permille": 0}, {"s_m": 3000, "permille": 60}, {"s_m": 8000, "permille": 0}])


@pytest.fixture(scope="module")
def flat(tmp_path_factory):
    return _line(tmp_path_factory.mktemp("flat"), [{"s_m": 0, "permille": 0}])


def test_constant_force_case_is_exact(flat):
    """No power limit, r1 = r2 = 0: uniform acceleration, cruise, uniform braking (closed forms)."""
    base = RunningTimeParams(c0=0.5, c2=1000.0, r0=0.01, r1=0.0, r2=0.0, length_m=100.0)
    b = np.array([0.6, 0.4])
    theta = np.array([0.9, 0.8])
    batch = running_time_batch(flat, base, 500.0, 9500.0, b_limit=b, b_stop=b, theta_cruise=theta)
    a_net = 0.49
    for i in range(2):
        v = theta[i] * 100 / 3.6
        d_acc, d_brk = v * v / (2 * a_net), v * v / (2 * b[i])
        expected = v / a_net + (9000.0 - d_acc - d_brk) / v + v / b[i]
        assert batch.run_time[i] == pytest.approx(expected, abs=1e-5)  # measured 1e-7 s
        s = np.array([500.0 + 0.3 * d_acc, 500.0 + d_acc + 1000.0, 9500.0 - 0.5 * d_brk])
        t = [
            math.sqrt(2 * 0.3 * d_acc / a_net),
            v / a_net + 1000.0 / v,
            expected - math.sqrt(2 * 0.5 * d_brk / b[i]),
        ]
        np.testing.assert_allclose(batch.member(i).time_at(s), t, atol=1e-5)
        np.testing.assert_allclose(
            batch.speed_at(s)[i], [math.sqrt(2 * a_net * 0.3 * d_acc), v, math.sqrt(b[i] * d_brk)], atol=1e-6
        )
    occ, rel = batch.member(0).occupation_release(np.array([1000.0]), np.array([2000.0]))
    assert rel[0] == pytest.approx(batch.member(0).time_at(2100.0)) and occ[0] < rel[0]
    assert np.isnan(batch.time_at(np.array([100.0, 9600.0]))).all()


def test_fixed_step_reference_and_its_extrapolation():
    """As the scalar model: within 0.1 s of RK4 over 0.5 m steps, and its Richardson extrapolation to 5 ms."""
    trk, trn = track("dense_corridor_14km"), train("virm4")
    p = RunningTimeParams.from_train(trn, theta_cruise=0.9, b_limit=0.5)
    s0, s1 = trk.stations[0].s_m, trk.stations[-1].s_m
    run_time = running_time_batch(trk, p, s0, s1).run_time[0]
    fine = reference_run_time(trk, p, s0, s1, ds=0.5)
    coarse = reference_run_time(trk, p, s0, s1, ds=1.0)
    assert abs(run_time - fine) < 0.1
    assert abs(run_time - (2.0 * fine - coarse)) < 0.005


def test_members_that_cannot_run(flat, tmp_path):
    """Cannot start (resistance above the effort) and stall (no power) give NaN, with the scalar model's reason."""
    base = RunningTimeParams(c0=0.5, c2=6.0, r0=0.015, r1=0.0, r2=4e-5, length_m=100.0)
    batch = running_time_batch(flat, base, 500.0, 9500.0, r0=[0.015, 0.6], c2=[6.0, 6.0])
    assert list(batch.ok) == [True, False]
    assert "cannot start" in batch.error[1]
    assert np.isnan(batch.time_at(np.array([1000.0]))[1, 0]) and np.isnan(batch.run_time[1])
    steep = _steep_track(tmp_path)
    stall = running_time_batch(steep, base, 500.0, 9500.0, c0=[0.9, 0.5])  # 60 permille: 0.59 N/kg
    with pytest.raises(ConfigError, match="stalls"):
        running_time_profile(steep, base.replace(c0=0.5), 500.0, 9500.0)
    assert list(stall.ok) == [True, False] and "stalls" in stall.error[1]


def test_input_checks(flat):
    base = RunningTimeParams()
    with pytest.raises(ConfigError, match="theta_cruise"):
        running_time_batch(flat, base, 500.0, 9500.0, theta_cruise=[1.0, 2.0])
    with pytest.raises(ConfigError, match="length_m"):
        running_time_batch(flat, base, 500.0, 9500.0, length_m=[100.0, 200.0])
    with pytest.raises(ValueError, match="different lengths"):
        running_time_batch(flat, base, 500.0, 9500.0, c0=[0.5, 0.6], c2=[6.0, 7.0, 8.0])
    with pytest.raises(ConfigError, match="stop_s"):
        running_time_batch(flat, base, 5000.0, 4000.0)
    batch = running_time_batch(flat, base, 500.0, 9500.0, c0=[0.5, 0.6])
    with pytest.raises(ValueError, match="shape"):
        batch.time_at(np.ones((3, 2)))
    per_member = batch.time_at(np.array([[1000.0, 2000.0], [3000.0, 4000.0]]))  # positions per member
    assert per_member[1, 0] == pytest.approx(batch.member(1).time_at(3000.0))


def test_motion_model_envelope_switches_at_the_transition_speed():
    """Eq. 4 with c1 < 0: c2 / v above the first crossing (min() would return to the falling line above the
    second one); c1 >= 0 unchanged."""
    terms = TrackTerms(track("dense_corridor_14km"), 162.0)
    v = np.linspace(0.0, 120.0, 241)
    for c1 in (-0.02, -0.01, -0.004, 0.0, 0.01):
        m = MotionModel(terms, c0=0.562, c1=c1, c2=6.21, r0=0.015, r1=0.0, r2=4e-5)
        expected = tractive_envelope(v, 0.562, 6.21, c1)
        np.testing.assert_allclose([m.envelope(float(x)) for x in v], expected, rtol=1e-12, atol=1e-15)
        np.testing.assert_allclose(m.envelope_vec(v), expected, rtol=1e-12, atol=1e-15)
    m = MotionModel(terms, c0=0.562, c1=-0.01, c2=6.21, r0=0.015, r1=0.0, r2=4e-5)  # crossings 15 and 41 m/s
    # above the second crossing the old min() returned to the falling line (0.062 N/kg at 50 m/s)
    assert m.envelope(50.0) == pytest.approx(6.21 / 50.0) and 0.562 - 0.01 * 50.0 < 6.21 / 50.0
