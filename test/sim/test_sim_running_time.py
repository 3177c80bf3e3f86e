"""The fast running-time model (Besinovic): closed forms, a fixed-step reference, the time-domain driver."""

from __future__ import annotations

import math

import numpy as np
import pytest
import yaml
from sim_helpers import reference_run_time, track, train

from train_calib.errors import ConfigError
from train_calib.sim import DriverParams, RunningTimeParams, SensorParams, running_time_profile, simulate_run
from train_calib.track import load_track


@pytest.fixture(scope="module")
def flat_track(tmp_path_factory):
    """10 km, level, straight, 100 km/h, stations at 500 and 9500 m."""
    data = {
        "name": "flat",
        "length_m": 10000,
        "geometry": [{"s_m": 0, "lat": 52.0, "lon": 5.0}, {"s_m": 10000, "lat": 52.0899322, "lon": 5.0}],
        "gradients": [{"s_m": 0, "permille": 0}],
        "speed_limits": [{"s_m": 0, "kmh": 100}],
        "stations": [{"s_m": 500, "name": "A"}, {"s_m": 9500, "name": "B"}],
    }
    path = tmp_path_factory.mktemp("flat") / "flat.yaml"
    path.write_text(yaml.safe_dump(data))
    return load_track(path)


def test_constant_force_case_is_exact(flat_track):
    """c2 large (no power limit below the limit), r1 = r2 = 0: uniform acceleration, cruise, uniform braking."""
    a_net, b = 0.5 - 0.01, 0.6
    p = RunningTimeParams(
        c0=0.5, c1=0.0, c2=1000.0, r0=0.01, r1=0.0, r2=0.0, b_limit=b, b_stop=b, theta_cruise=0.9, length_m=100.0
    )
    v = 0.9 * 100 / 3.6
    d = 9000.0
    d_acc, d_brk = v * v / (2 * a_net), v * v / (2 * b)
    expected = v / a_net + (d - d_acc - d_brk) / v + v / b
    prof = running_time_profile(flat_track, p, 500.0, 9500.0)
    assert prof.run_time == pytest.approx(expected, abs=1e-5)  # measured 3e-6 s (rtol 1e-7)
    # passage times in each phase
    s = np.array([500.0 + 0.5 * d_acc, 500.0 + d_acc + 1000.0, 9500.0 - 0.5 * d_brk, 9500.0])
    t_exp = [
        math.sqrt(2 * 0.5 * d_acc / a_net),
        v / a_net + 1000.0 / v,
        expected - math.sqrt(2 * 0.5 * d_brk / b),
        expected,
    ]
    assert np.allclose(prof.time_at(s), t_exp, atol=1e-5)
    assert np.allclose(prof.speed_at(s[:3]), [math.sqrt(a_net * d_acc), v, math.sqrt(b * d_brk)], atol=1e-6)
    assert np.isnan(prof.time_at([100.0, 9600.0])).all()


@pytest.mark.parametrize(
    "track_name, train_name, theta, ds",
    [
        ("intercity_32km", "virm6", 1.0, 1.0),
        ("dense_corridor_14km", "virm4", 0.9, 0.5),
        ("tunnel_line_37km", "icrm", 1.0, 1.0),
    ],
)
def test_rk45_against_fixed_step_reference(track_name, train_name, theta, ds):
    """Run time within 0.1 s of an independent RK4 over 0.5-1 m steps (measured 0.02-0.06 s: the
    reference's O(ds) capping error; the profile is far more accurate, see the Richardson test)."""
    trk, trn = track(track_name), train(train_name)
    p = RunningTimeParams.from_train(trn, theta_cruise=theta, b_limit=0.5)
    s0, s1 = trk.stations[0].s_m, trk.stations[-1].s_m
    prof = running_time_profile(trk, p, s0, s1)
    ref = reference_run_time(trk, p, s0, s1, ds=ds)
    assert abs(prof.run_time - ref) < 0.1, (prof.run_time, ref)
    # the profile never exceeds theta * limit over the train
    s = np.linspace(s0, s1, 4001)
    ceiling = np.array([theta * trk.limit_over_train(float(x), trn.length_m) for x in s])
    assert np.all(prof.speed_at(s) <= ceiling + 1e-6)
    assert np.all(np.diff(prof.time_at(s)) > 0)


def test_reference_converges_to_the_profile():
    """The reference's error is first order in ds: its Richardson extrapolation meets the RK45 run time."""
    trk, trn = track("dense_corridor_14km"), train("virm4")
    p = RunningTimeParams.from_train(trn, theta_cruise=0.9, b_limit=0.5)
    s0, s1 = trk.stations[0].s_m, trk.stations[-1].s_m
    coarse = reference_run_time(trk, p, s0, s1, ds=1.0)
    fine = reference_run_time(trk, p, s0, s1, ds=0.5)
    extrapolated = 2.0 * fine - coarse
    assert abs(running_time_profile(trk, p, s0, s1).run_time - extrapolated) < 0.005  # measured 1e-5 s


@pytest.mark.parametrize(
    "track_name, train_name",
    [("intercity_32km", "virm6"), ("dense_corridor_14km", "virm10"), ("tunnel_line_37km", "icrm")],
)
def test_time_domain_driver_reproduces_the_distance_model(track_name, train_name):
    """One physics, two integrations: the realistic simulator with Besinovic's driver gives the same run."""
    trk, trn = track(track_name), train(train_name)
    p = RunningTimeParams.from_train(trn, theta_cruise=0.95, b_limit=0.45, b_stop=0.6)
    s0, s1 = trk.stations[0].s_m, trk.stations[-1].s_m
    prof = running_time_profile(trk, p, s0, s1)
    run = simulate_run(
        trk,
        trn,
        driver=DriverParams.minimum_time(0.95, 0.45, 0.6),
        sensors=SensorParams(pre_roll_s=0.0, post_roll_s=0.0),
        rng=np.random.default_rng(0),
    )
    assert abs(run.run_time_s - prof.run_time) < 0.1  # measured 7e-6 to 4e-5 s
    # and the trajectories agree: head passage times at the dense samples
    d = run.dense
    moving = d.v > 1.0
    t_dense = (d.t_ns[moving] - run.meta["departure_time_ns"]) * 1e-9
    assert np.max(np.abs(prof.time_at(d.s[moving]) - t_dense)) < 0.05


def test_occupation_release_and_tail(flat_track):
    p = RunningTimeParams(c0=0.5, c2=1000.0, r0=0.01, r1=0.0, r2=0.0, length_m=200.0, theta_cruise=1.0)
    prof = running_time_profile(flat_track, p, 500.0, 9500.0)
    occ, rel = prof.occupation_release(np.array([1000.0, 5000.0, 9400.0]), np.array([2000.0, 6000.0, 9450.0]))
    assert np.allclose(rel[:2], prof.time_at([2200.0, 6200.0]))
    assert np.isnan(rel[2])  # the tail never clears a section the train stops in
    assert np.all(occ[:2] < rel[:2])


def test_parameters_and_bad_input(flat_track):
    trn = train("virm6")
    p = RunningTimeParams.from_train(trn)
    assert (p.c0, p.c2, p.r1, p.length_m) == (0.562, 6.21, 1.939e-4, 162.0)
    with pytest.raises(ConfigError, match="stop_s"):
        running_time_profile(flat_track, p, 5000.0, 4000.0)
    with pytest.raises(ConfigError, match="cannot start"):
        running_time_profile(flat_track, p.replace(r0=0.6), 500.0, 9500.0)
    with pytest.raises(ConfigError, match="theta_cruise"):
        p.replace(theta_cruise=2.0)


def test_random_parameters_in_a_calibration_box_never_break_the_model():
    """The GA samples corners: every draw gives a monotone profile or a one-line ConfigError (stall)."""
    rng = np.random.default_rng(0)
    trk = track("dense_corridor_14km")
    base = RunningTimeParams.from_train(train("virm6"))
    grid = np.linspace(250.0, 14550.0, 2001)
    limits = {L: np.array([trk.limit_over_train(float(x), L) for x in grid]) for L in (108.0, 162.0, 270.0, 282.0)}
    ok = 0
    for _ in range(150):
        p = base.replace(
            c0=rng.uniform(0.2, 1.0),
            c2=rng.uniform(2.0, 15.0),
            r0=rng.uniform(0.005, 0.03),
            r2=rng.uniform(1e-5, 8e-5),
            b_limit=rng.uniform(0.2, 1.0),
            b_stop=rng.uniform(0.3, 1.0),
            theta_cruise=rng.uniform(0.7, 1.1),
            length_m=float(rng.choice([108, 162, 270, 282])),
        )
        try:
            prof = running_time_profile(trk, p, 250.0, 14550.0)
        except ConfigError as exc:
            assert "stalls" in str(exc) or "cannot start" in str(exc)
            continue
        ok += 1
        assert np.all(np.diff(prof.s) > 0) and np.all(np.diff(prof.t) > 0) and prof.v[-1] == 0.0
        # never above theta x the limit over the train: neither when b_stop < b_limit (the stop's braking
        # curve meets a lower limit's) nor when the ceiling is reached in a step that ends on a rise
        assert np.all(prof.speed_at(grid) <= p.theta_cruise * limits[p.length_m] + 1e-6)
    assert ok > 100


def test_braking_curves_that_meet_are_followed_to_the_lower_target():
    """b_stop < b_limit: the stop's braking curve meets the last lower limit's; the train must take the
    steeper one there (it used to keep braking at b_stop and pass the 40 km/h limit at 77 km/h)."""
    trk, trn = track("intercity_32km"), train("virm6")
    p = RunningTimeParams.from_train(trn, theta_cruise=0.786, b_limit=0.708, b_stop=0.379, c2=2.77, c0=0.404)
    s0, s1 = trk.stations[0].s_m, trk.stations[-1].s_m
    prof = running_time_profile(trk, p, s0, s1)
    s = np.linspace(s1 - 1500.0, s1, 1501)
    ceiling = np.array([p.theta_cruise * trk.limit_over_train(float(x), trn.length_m) for x in s])
    assert np.all(prof.speed_at(s) <= ceiling + 1e-6)
    assert prof.run_time == pytest.approx(reference_run_time(trk, p, s0, s1, ds=1.0), abs=0.1)
