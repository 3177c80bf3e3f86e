"""The coasting integrator against an independent solver (scipy's solve_ivp over time, tight tolerances), and its
sigma against Monte Carlo; the nominal strategy's time against the running-time model without coasting."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from train_calib.paths import track_file, train_file
from train_calib.prediction import GradientIntegral, coast, coast_with_sigma
from train_calib.prediction.nominal import NominalLeg, nominal_time
from train_calib.sim.model import TrackTerms
from train_calib.sim.running_time import RunningTimeParams, running_time_profile
from train_calib.track import load_track
from train_calib.train import load_train


@pytest.fixture(scope="module")
def line():
    track, train = load_track(track_file("tunnel_line_37km")), load_train(train_file("icrm"))
    terms = TrackTerms(track, train.length_m)
    return track, train, terms, GradientIntegral(terms)


def _reference(terms, train, r, s0, v0, targets):
    """(v, t) at each target by solve_ivp over time (rtol 1e-11), events at the targets."""

    def f(_t, y):
        k = 1.0 + train.tunnel_factor * terms.tunnel_at(y[0])
        return [y[1], -(r[0] + r[1] * y[1] + k * r[2] * y[1] ** 2) - terms.g_at(y[0])]

    events = []
    for x in targets:
        ev = lambda _t, y, x=x: y[0] - x  # noqa: E731
        events.append(ev)
    sol = solve_ivp(f, (0.0, 5000.0), [s0, v0], rtol=1e-11, atol=1e-9, events=events, dense_output=True)
    t = np.array([te[0] for te in sol.t_events])
    return np.array([sol.sol(x)[1] for x in t]), t


def test_the_grid_integral_of_g_is_exact(line):
    _, _, terms, G = line
    s = np.linspace(0.0, 37000.0, 20001)
    trapezoid = np.concatenate(([0.0], np.cumsum(0.5 * np.diff(s) * (terms.g_vec(s)[1:] + terms.g_vec(s)[:-1]))))
    assert np.max(np.abs(G(s) - G(0.0) - trapezoid)) < 2e-4  # m^2/s^2 over 37 km (the trapezoid's own error)


@pytest.mark.parametrize(("s0", "v0", "targets"), [(5000.0, 35.0, (7000.0, 9500.0)), (20000.0, 30.0, (23000.0,))])
def test_coasting_matches_an_independent_solver_to_integration_accuracy(line, s0, v0, targets):
    """Across gradient breaks and a tunnel (r2 x (1 + tunnel_factor) inside): speed within 5e-3 m/s (0.02 km/h) and
    time within 0.2 s (of 195) of solve_ivp at the default step (800 m); 1e-5 m/s and 1 ms at 50 m."""
    _, train, terms, G = line
    r = np.array(train.davis.as_tuple()) * 1.2
    v_ref, t_ref = _reference(terms, train, r, s0, v0, targets)
    for ds, tol_v, tol_t in ((800.0, 5e-3, 0.2), (50.0, 1e-5, 1e-3)):
        res = coast(terms, G, s0, np.array([v0]), r[None, :], np.array(targets), tunnel_factor=train.tunnel_factor,
                    ds_max_m=ds, max_steps=10000)  # fmt: skip
        assert np.max(np.abs(res.v_ms[0] - v_ref)) < tol_v
        assert np.max(np.abs(res.t_s[0] - t_ref)) < tol_t


def test_a_coast_that_stops_first_gives_speed_0_and_no_time(line):
    _, train, terms, G = line
    res = coast(terms, G, 5000.0, np.array([10.0]), np.array([train.davis.as_tuple()]), np.array([30000.0]))
    assert res.v_ms[0, 0] == 0.0 and np.isnan(res.t_s[0, 0])


def test_sigma_points_agree_with_monte_carlo(line):
    """The sigma of end speed and time from the 9 sigma points within 10 % of 4,000 Monte Carlo draws (the draws'
    own sampling error of a std is ~1.1 %), the centre within 0.05 km/h of their mean."""
    _, train, terms, G = line
    r = np.array(train.davis.as_tuple())
    mean = np.concatenate(([33.0], r))
    P = np.diag(np.concatenate(([0.2**2], (0.1 * r) ** 2)))
    P[1:, 1:] += 0.12**2 * np.outer(r, r)
    target = np.array([9000.0])
    ((v, vs, _t, ts),) = coast_with_sigma(terms, G, 6000.0, [(mean, P)], target, tunnel_factor=train.tunnel_factor)
    draws = np.random.default_rng(24).multivariate_normal(mean, P, size=4000)
    mc = coast(terms, G, 6000.0, draws[:, 0], draws[:, 1:], target, tunnel_factor=train.tunnel_factor)
    assert np.all(mc.v_ms > 1.0)
    assert abs(vs[0] / mc.v_ms[:, 0].std() - 1.0) < 0.10
    assert abs(ts[0] / mc.t_s[:, 0].std() - 1.0) < 0.10
    assert abs(v[0] - mc.v_ms[:, 0].mean()) * 3.6 < 0.05


def test_nominal_time_without_coasting_equals_the_running_time_model():
    """coast_distance 0 is the minimum-time strategy (full traction, cruise at the limit, brake at max_brake_decel):
    the running-time model of sim/ (RK45 with events) gives the same time to the stop within 0.5 % (Heun steps of
    20 m here, a ceiling sampled on the grid)."""
    track, train = load_track(track_file("intercity_32km")), load_train(train_file("virm6"))
    terms = TrackTerms(track, train.length_m)
    start, stop = track.stations[0].s_m, track.stations[-1].s_m
    params = RunningTimeParams.from_train(train, adhesive_mass_fraction=train.adhesive_mass_fraction)
    reference = running_time_profile(track, params, start, stop).run_time
    leg = NominalLeg(track, train, terms, stop, 20.0)
    t = nominal_time(leg, train, train.davis.as_tuple(), start, 0.0, coast_distance_m=0.0)
    assert abs(t / reference - 1.0) < 0.005, (t, reference)
    # coasting the last 3 km takes longer, with a higher resistance longer still
    t_coast = nominal_time(leg, train, train.davis.as_tuple(), start, 0.0, coast_distance_m=3000.0)
    t_coast_high = nominal_time(leg, train, tuple(1.3 * c for c in train.davis.as_tuple()), start, 0.0,
                                coast_distance_m=3000.0)  # fmt: skip
    assert reference < t_coast < t_coast_high


def test_the_start_speed_takes_the_gradient_out_of_its_line():
    """A coast from 157 km/h on the Vasteras profile (TTOBench, bench/validation/ttobench), 1 Hz, noise-free,
    integrated by scipy with the exact g(s): the line through the first 30 s of v alone starts one of three coasts
    0.9 km/h low (measured; the gradient changes within the 30 s); through v + the integral of g over t
    (gradient_speed_loss, g's step means from the track force's integral) every one within 0.25 km/h (measured
    0.12-0.20: what is left is r(v)'s own change over 30 s, the same on a flat stretch)."""
    from repo_paths import REPO

    from train_calib.measurement import Measurement
    from train_calib.prediction.offline import edge_speed, gradient_speed_loss

    ttobench = REPO / "bench" / "validation" / "ttobench"
    track, train = load_track(ttobench / "track_vasteras.yaml"), load_train(ttobench / "train_kiss.yaml")
    r = np.array(train.davis.as_tuple())
    worst_plain = 0.0
    for s0 in (6000.0, 14000.0, 21000.0):

        def rhs(_t, y):
            g = float(track.track_force(y[0], train.length_m))
            return [y[1], -(r[0] + r[1] * y[1] + r[2] * y[1] ** 2) - g]

        t = np.arange(0.0, 31.0)
        sol = solve_ivp(rhs, (0.0, 30.0), [s0, 157 / 3.6], t_eval=t, max_step=0.1, rtol=1e-10, atol=1e-10)
        s, v = sol.y
        ms = [Measurement(int(k * 1e9), float(si), float(vi), float(track.track_force(si, train.length_m)),
                          track_force_integral=float(track.track_force_integral(si, train.length_m)))
              for k, si, vi in zip(t, s, v)]  # fmt: skip
        plain, _ = edge_speed(t, v, 0.0, True, 30.0)
        corrected, _ = edge_speed(t, v + gradient_speed_loss(ms, t), 0.0, True, 30.0)
        assert abs(corrected - v[0]) * 3.6 < 0.25, (s0, corrected * 3.6, v[0] * 3.6)
        worst_plain = max(worst_plain, abs(plain - v[0]) * 3.6)
    assert worst_plain > 0.8
