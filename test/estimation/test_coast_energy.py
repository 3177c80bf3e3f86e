"""The coast regression's energy form (estimation/coast_energy.py) at 10 s sampling on a real profile.

The profile is TTOBench's Stadelhofen-Altstetten (bench/validation/ttobench): gradients up to 28 per mille that
change every few dozen metres, so the track force at 10 s samples says little about its mean over a 250 m step.
A coast is integrated here by scipy (solve_ivp over t with the track's exact g(s)), independently of the
project's simulator.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from repo_paths import REPO
from scipy.integrate import cumulative_trapezoid, solve_ivp

from train_calib.estimation.coast_energy import energy_bounds, energy_equations, uses_energy_form
from train_calib.estimation.coast_posterior import coast_consistency, posterior, prior_covariance, prior_information
from train_calib.estimation.coast_regression import (
    CoastRegression,
    CoastSettings,
    RunArrays,
    fit_coasts,
)
from train_calib.physics import KMH
from train_calib.track import load_track, track_from_mapping
from train_calib.train import Davis, load_train

TTOBENCH = REPO / "bench" / "validation" / "ttobench"
PERIOD = 10.0  # s


@pytest.fixture(scope="module")
def track():
    return load_track(TTOBENCH / "track_stadelhofen.yaml")


@pytest.fixture(scope="module")
def train():
    return load_train(TTOBENCH / "train_kiss.yaml")


def truth_of(train, factor: float = 0.8) -> Davis:
    return Davis(*(factor * x for x in train.davis.as_tuple()))


def coast(track, train, truth: Davis, s0: float, v0: float, seconds: float) -> tuple[np.ndarray, ...]:
    """(t, s, v) every PERIOD s of a coast (u = 0) from (s0, v0), integrated with the exact g(s) of the track."""
    r = np.array(truth.as_tuple())

    def rhs(_t, y):
        s, v = y
        g = float(track.track_force(s, train.length_m))
        return [v, -(r[0] + r[1] * v + r[2] * v * v) - g]

    t_eval = np.arange(0.0, seconds + 1e-9, PERIOD)
    sol = solve_ivp(rhs, (0.0, seconds), [s0, v0], t_eval=t_eval, max_step=0.2, rtol=1e-9, atol=1e-9)
    return sol.t, sol.y[0], sol.y[1]


def arrays(track, train, t, s, v, *, gamma: bool = True) -> RunArrays:
    n = t.size
    return RunArrays(
        t=t.astype(float),
        v=v.astype(float),
        g=np.asarray(track.track_force(s, train.length_m), dtype=float),
        tunnel=np.asarray(track.tunnel_fraction(s, train.length_m), dtype=float),
        run=np.zeros(n, dtype=np.int64),
        s=s.astype(float),
        gamma=np.asarray(track.track_force_integral(s, train.length_m), dtype=float) if gamma else None,
        s_var=np.full(n, 16.0),
        v_var=np.full(n, 0.16**2),
    )


def rel_err(r, truth: Davis, v: float = 80 * KMH) -> float:
    h = np.array([1.0, v, v * v])
    return float(h @ np.asarray(r) / (h @ np.array(truth.as_tuple())) - 1.0)


def test_gamma_makes_the_steps_exact_where_the_time_form_is_not(track, train):
    """Noise-free 10 s samples of two coasts on the steep section: the energy form's equations recover r(v) at 40,
    80 and 120 km/h to 0.5 %; the time form's (trapezoid of g at the samples) misses one of them by more than 5 %."""
    truth = truth_of(train)
    parts = [coast(track, train, truth, s0, 90 * KMH, 120.0) for s0 in (1500.0, 5200.0)]
    settings = CoastSettings(
        coast_stretch_std=0.0, prior_scale_std=10.0, prior_coefficient_std=10.0, coast_energy_end_effort=0.0
    )
    prior = np.array(train.davis.as_tuple())
    p0 = prior_covariance(prior, 10.0, 10.0)
    energy, timeform = [], []
    from train_calib.estimation.coast_regression import stretch_equations

    for k, (t, s, v) in enumerate(parts):
        arr = arrays(track, train, t + 1000.0 * k, s, v)
        arr.run[:] = k
        energy.append(energy_equations(arr, 0, t.size - 1, settings, prior, 0.16, train.tunnel_factor, PERIOD))
        timeform.append(stretch_equations(arr, 0, t.size - 1, settings, prior, 0.16, train.tunnel_factor))
        energy[-1].group = timeform[-1].group = k
    r_energy, _ = posterior(prior, p0, energy)
    r_time, _ = posterior(prior, p0, timeform)
    speeds = [kmh * KMH for kmh in (40, 80, 120)]
    assert max(abs(rel_err(r_energy, truth, v)) for v in speeds) < 0.005
    assert max(abs(rel_err(r_time, truth, v)) for v in speeds) > 0.05


def test_posterior_equals_weighted_least_squares_with_the_start_energies_unknown(track, train):
    """energy_equations + posterior (whitened, E_0 projected out, Sherman-Morrison for the common error) equal an
    independent generalised least squares: unknowns r and one E_0 per stretch (flat), rows E_i = E_0 - Phi_i r
    with Phi from scipy's cumulative_trapezoid over s, noise diag(v^2 sigma_v^2 + g^2 sigma_s^2) plus the
    common error as a random slope over s - s_0 within a coast."""
    rng = np.random.default_rng(3)
    truth = truth_of(train, 1.2)
    settings = CoastSettings(coast_energy_end_effort=0.0)  # the detected ends as sure (the mixture: below)
    prior = np.array(train.davis.as_tuple())
    p0 = prior_covariance(prior, 0.18, 0.10)
    stretches, blocks = [], []
    for k, s0 in enumerate((1500.0, 5200.0)):
        t, s, v = coast(track, train, truth, s0, 85 * KMH, 90.0)
        v = v + rng.normal(0.0, 0.16, v.size)
        s = s + rng.normal(0.0, 4.0, s.size)
        arr = arrays(track, train, t, s, v)
        st = energy_equations(arr, 0, t.size - 1, settings, prior, 0.16, train.tunnel_factor, PERIOD)
        st.group = k
        stretches.append(st)
        blocks.append(arr)
    mean_fast, cov_fast = posterior(prior, p0, stretches)

    rows, rhs, cov_blocks = [], [], []
    for k, (arr, st) in enumerate(zip(blocks, stretches)):
        s, v = arr.s, arr.v
        phi = np.column_stack([
            s - s[0], cumulative_trapezoid(v, s, initial=0.0),
            cumulative_trapezoid(v * v * (1.0 + train.tunnel_factor * arr.tunnel), s, initial=0.0),
        ])  # fmt: skip
        e0 = np.zeros((s.size, len(blocks)))
        e0[:, k] = 1.0
        rows.append(np.hstack([-phi, e0]))
        rhs.append(0.5 * v * v + arr.gamma)
        slope = s - s[0]
        cov_blocks.append(np.diag(v * v * 0.16**2 + arr.g**2 * 16.0) + st.bias_std**2 * np.outer(slope, slope))
    x, y = np.vstack(rows), np.concatenate(rhs)
    noise = np.zeros((y.size, y.size))
    i = 0
    for c in cov_blocks:
        noise[i : i + c.shape[0], i : i + c.shape[0]] = c
        i += c.shape[0]
    w0 = np.linalg.cholesky(np.linalg.inv(p0)).T
    w = np.linalg.cholesky(np.linalg.inv(noise)).T
    a = np.vstack([np.hstack([w0, np.zeros((3, len(blocks)))]), w @ x])
    b = np.concatenate([w0 @ prior, w @ y])
    mean, *_ = np.linalg.lstsq(a, b, rcond=None)
    cov = np.linalg.inv(a.T @ a)[:3, :3]
    np.testing.assert_allclose(mean_fast, mean[:3], rtol=1e-7)
    np.testing.assert_allclose(cov_fast, cov, rtol=1e-6)


def cruise_coast_brake(track, train, truth: Davis, rng) -> RunArrays:
    """10 s samples: a held 80 km/h (u = r + g), a 150 s coast, braking at 0.5 m/s^2 to a stop, 60 s standing; speeds
    with 0.5 km/h noise rounded to 1 km/h, positions with 4 m noise."""
    r = np.array(truth.as_tuple())
    dt = 0.1
    s, v, t = 800.0, 80 * KMH, 0.0
    out_t, out_s, out_v, out_u = [], [], [], []
    while True:
        if t < 200.0:
            phase_u = None  # hold
        elif t < 350.0:
            phase_u = 0.0
        else:
            phase_u = -0.5
        g = float(track.track_force(s, train.length_m))
        a = 0.0 if phase_u is None else phase_u - (r[0] + r[1] * v + r[2] * v * v) - g
        if abs(t / PERIOD - round(t / PERIOD)) < 1e-6:
            out_t.append(t)
            out_s.append(s)
            out_v.append(v)
            out_u.append(phase_u if phase_u is not None else 1.0)
        if v <= 0.0 and t > 350.0:
            break
        v = max(v + a * dt, 0.0)
        s += v * dt
        t = round(t + dt, 6)
    for _ in range(6):  # standing
        out_t.append(out_t[-1] + PERIOD)
        out_s.append(s)
        out_v.append(0.0)
        out_u.append(-0.5)
    t_arr, s_arr, v_arr = np.array(out_t), np.array(out_s), np.array(out_v)
    v_meas = np.maximum(np.round((v_arr + rng.normal(0.0, 0.5 * KMH, v_arr.size)) / KMH) * KMH, 0.0)
    arr = arrays(track, train, t_arr, s_arr + rng.normal(0.0, 4.0, s_arr.size), v_meas)
    arr.gamma[:] = track.track_force_integral(arr.s, train.length_m)
    return arr, np.array(out_u)


def test_detection_finds_the_coast_and_not_the_hold(track, train):
    """Ten noisy runs: every detected stretch lies inside the true coast (no held or braking sample), and the
    stretches cover at least half of the coast's samples in 8 of 10 runs; the whole-run estimate of r(80 km/h)
    lies within 2 sigma of the truth in at least 9 of 10."""
    truth = truth_of(train, 0.8)
    inside, covered = 0, 0
    for seed in range(10):
        arr, u = cruise_coast_brake(track, train, truth, np.random.default_rng(seed))
        assert uses_energy_form(arr, CoastSettings(), PERIOD, 1.0)
        bounds, _ = energy_bounds(arr, CoastSettings(), np.array(train.davis.as_tuple()), 0.16, PERIOD)
        for k0, k1, _, _ in bounds:
            assert np.all(u[k0:k1] == 0.0), (seed, k0, k1, u[k0 : k1 + 1])  # every step (from u[i-1]) coasting
        used = sum(k1 - k0 + 1 for k0, k1, _, _ in bounds)
        covered += used >= 0.5 * np.count_nonzero(u == 0.0)
        fit = fit_coasts(arr, train, CoastSettings(coast_energy_grade_error=0.0))
        h = np.array([1.0, 80 * KMH, (80 * KMH) ** 2])
        inside += abs(h @ fit.r - h @ np.array(truth.as_tuple())) <= 2.0 * math.sqrt(h @ fit.covariance @ h)
    assert covered >= 8
    assert inside >= 9


def test_causal_takes_the_coast_at_the_stop_and_equals_the_whole_run(track, train):
    """The causal regression adds the coast once the train has stopped (the stretch is then over) and ends where
    the whole-run estimate is (both in the energy form)."""
    truth = truth_of(train, 0.8)
    arr, _ = cruise_coast_brake(track, train, truth, np.random.default_rng(1))
    energy = CoastSettings(coast_energy_grade_error=0.0)  # the energy form whatever the grade error of this stretch
    reg = CoastRegression(train, energy)
    changed_at = None
    for i in range(arr.t.size):
        if reg.push(arr.t[i], arr.v[i], arr.g[i], arr.tunnel[i], 0, s=arr.s[i], gamma=arr.gamma[i], s_var=16.0,
                    v_var=0.16**2):  # fmt: skip
            changed_at = changed_at if changed_at is not None else arr.t[i]
    fit = fit_coasts(arr, train, energy)
    assert fit.stretches and changed_at is not None
    assert fit.stretches[0].noise_var == 0.16**2  # the energy form's: the sensor's stated noise
    assert changed_at <= arr.t[np.flatnonzero(arr.v < 5.0)[0]]  # at the stop at the latest
    np.testing.assert_allclose(reg.r, fit.r, rtol=1e-12)


def test_grade_error_decides_the_form(track, train):
    """The median step error of the time form's gradient term, relative to r: large on the Stadelhofen profile at
    10 s (above coast_energy_grade_error 0.1), zero on a constant gradient."""
    from train_calib.estimation.coast_energy import step_grade_error

    prior = np.array(train.davis.as_tuple())
    t, s, v = coast(track, train, truth_of(train), 1500.0, 90 * KMH, 120.0)
    assert step_grade_error(arrays(track, train, t, s, v), prior, 5.0) > 0.1
    flat = arrays(track, train, t, s, v)
    flat.g[:] = 0.02
    flat.gamma[:] = 0.02 * flat.s
    assert step_grade_error(flat, prior, 5.0) < 1e-12


def test_without_gamma_the_time_form_runs_unchanged(track, train):
    """NaN (unknown) Gamma, or 1 Hz sampling: the time form, as before the energy form existed."""
    truth = truth_of(train, 0.8)
    arr, _ = cruise_coast_brake(track, train, truth, np.random.default_rng(2))
    arr.gamma[:] = np.nan
    assert not uses_energy_form(arr, CoastSettings(), PERIOD, 1.0)
    no_gamma = RunArrays(arr.t, arr.v, arr.g, arr.tunnel, arr.run)
    np.testing.assert_array_equal(fit_coasts(arr, train).r, fit_coasts(no_gamma, train).r)
    assert not uses_energy_form(arr, CoastSettings(), 1.0, 1.0)


def test_the_causal_grade_error_is_the_offline_one(track, train):
    """CoastRegression keeps step_grade_error's terms per step as they arrive (plain floats); over one run its
    median is the offline function's over the same samples, float for float."""
    from train_calib.estimation.coast_energy import step_grade_error

    arr, _ = cruise_coast_brake(track, train, truth_of(train, 0.8), np.random.default_rng(4))
    reg = CoastRegression(train, CoastSettings())
    for i in range(arr.t.size):
        reg.push(arr.t[i], arr.v[i], arr.g[i], arr.tunnel[i], 0, s=arr.s[i], gamma=arr.gamma[i], s_var=16.0,
                 v_var=0.16**2)  # fmt: skip
    offline = step_grade_error(arr, np.array(train.davis.as_tuple()), CoastSettings().coast_min_speed)
    assert offline > 0.0 and reg.grade_error() == offline


def _slope_track(permille: float):
    """12 km straight: flat to 4 km, then ``permille`` to the end."""
    return track_from_mapping(
        {
            "name": "slope",
            "length_m": 12000.0,
            "geometry": [
                {"s_m": 0, "lat": 47.0, "lon": 8.0},
                {"s_m": 12000.0, "lat": 47.0 + 12000.0 / 111195.0, "lon": 8.0},
            ],
            "gradients": [{"s_m": 0, "permille": 0.0}, {"s_m": 4000, "permille": permille}],
            "speed_limits": [{"s_m": 0, "kmh": 140}],
            "stations": [{"s_m": 100, "name": "A"}, {"s_m": 11900, "name": "B"}],
        },
        "slope",
    )


def test_growth_takes_in_a_coast_where_r_plus_g_is_zero(train):
    """A coast from 25 m/s on the flat, then on a downhill where g = -r at the speed reached (19.0 m/s: the speed
    stays constant for 8 samples), then braking. The window test's hold check leaves the constant-speed windows
    out (a hold looks the same); growing the stretch by its neighbours within GROW_SIGMAS takes them in. Over ten
    noisy runs at least 75 % of those samples are used (66 of 80 at 2 sigma; 52 at 1.5), and no braking sample."""
    truth = truth_of(train, 0.8)
    r = np.array(truth.as_tuple())

    def r_of(v):
        return r[0] + r[1] * v + r[2] * v * v

    def run(track, s_brake: float, t_eval=None):
        def rhs(_t, y):
            s, v = y
            a = -0.5 if s > s_brake else -r_of(v) - float(track.track_force(s, train.length_m))
            return [v, a]

        at_4km = lambda _t, y: y[0] - 4000.0  # noqa: E731
        at_4km.terminal = t_eval is None
        stop = lambda _t, y: y[1] - 0.01  # noqa: E731
        stop.terminal = True
        return solve_ivp(
            rhs, (0.0, 600.0), [500.0, 25.0], t_eval=t_eval, events=[at_4km, stop], max_step=0.2, rtol=1e-9
        )

    v1 = run(_slope_track(0.0), np.inf).y[1, -1]
    per_permille = float(_slope_track(1.0).track_force(6000.0, train.length_m))
    track = _slope_track(-r_of(v1) / per_permille)
    sol = run(track, 5600.0, np.arange(0.0, 600.0, PERIOD))
    t, s, v = sol.t, sol.y[0], sol.y[1]
    coasting = s <= 5600.0
    constant = coasting & (s >= 4000.0 + train.length_m)
    assert constant.sum() == 8 and np.ptp(v[constant]) < 0.05  # m/s: r + g = 0 there
    taken = 0
    for seed in range(10):
        rng = np.random.default_rng(seed)
        vm = np.maximum(np.round((v + rng.normal(0.0, 0.5 * KMH, v.size)) / KMH) * KMH, 0.0)
        arr = arrays(track, train, t, s + rng.normal(0.0, 4.0, s.size), vm)
        bounds, _ = energy_bounds(arr, CoastSettings(coast_energy_grade_error=0.0), np.array(train.davis.as_tuple()),
                                  0.16, PERIOD)  # fmt: skip
        used = np.zeros(t.size, dtype=bool)
        for k0, k1, _, _ in bounds:
            used[k0 : k1 + 1] = True
        assert not np.any(used & ~coasting), seed
        taken += int(np.sum(used & constant))
    assert taken >= 60


# -- the ends of a stretch (coast_energy.end_mixture, coast_posterior.add_coast_with_ends) -----------------------
def traction_then_coast(track, train, truth: Davis, s0: float, v0: float, traction_s: float, seconds: float):
    """(t, s, v) every PERIOD s from t = 0: u = 0.5 N/kg for ``traction_s`` (inside the first step), then a coast;
    integrated by scipy with the exact g(s)."""
    r = np.array(truth.as_tuple())

    def rhs(t, y):
        s, v = y
        u = 0.5 if t < traction_s else 0.0
        return [v, u - (r[0] + r[1] * v + r[2] * v * v) - float(track.track_force(s, train.length_m))]

    t_eval = np.arange(0.0, seconds + 1e-9, PERIOD)
    sol = solve_ivp(rhs, (0.0, seconds), [s0, v0], t_eval=t_eval, max_step=0.1, rtol=1e-9, atol=1e-9)
    return sol.t, sol.y[0], sol.y[1]


def test_a_traction_leak_in_the_first_step_is_weighed_out(track, train):
    """A coast that starts 4 s after its first sample (0.5 N/kg of traction before it, about 40 J/kg, 12 sigma of that
    sample's energy): taken as sure, the detected ends miss r(80 km/h) by more than 50 %; with the ends
    uncertain (default coast_energy_end_effort) the configuration without that sample carries the weight and the
    estimate is within 1 % (noise-free samples, a wide prior)."""
    truth = truth_of(train, 1.2)
    t, s, v = traction_then_coast(track, train, truth, 1500.0, 70 * KMH, 4.0, 110.0)
    arr = arrays(track, train, t, s, v)
    prior = np.array(train.davis.as_tuple())
    p0 = prior_covariance(prior, 10.0, 10.0)
    sure = CoastSettings(coast_stretch_std=0.0, coast_energy_end_effort=0.0)
    uncertain = CoastSettings(coast_stretch_std=0.0)
    r_sure, _ = posterior(prior, p0, [energy_equations(arr, 0, t.size - 1, sure, prior, 0.16, 0.0, PERIOD)])
    st = energy_equations(arr, 0, t.size - 1, uncertain, prior, 0.16, 0.0, PERIOD)
    assert st.ends is not None and st.ends.masks.shape == (4, t.size)  # starts 0 or 1, ends n - 2 or n - 1
    r_ends, _ = posterior(prior, p0, [st])
    assert abs(rel_err(r_sure, truth)) > 0.5
    assert abs(rel_err(r_ends, truth)) < 0.01


def test_one_configuration_is_the_detected_ends(track, train):
    """A stretch of 3 samples with no neighbour has one configuration: the mixture's update equals the information
    form's (energy_equations with the ends sure, Sherman-Morrison), to 1e-9."""
    rng = np.random.default_rng(5)
    truth = truth_of(train, 0.9)
    t, s, v = coast(track, train, truth, 5200.0, 85 * KMH, 20.0)
    arr = arrays(track, train, t, s + rng.normal(0.0, 4.0, s.size), v + rng.normal(0.0, 0.16, v.size))
    prior = np.array(train.davis.as_tuple())
    p0 = prior_covariance(prior, 0.18, 0.10)
    st = energy_equations(arr, 0, 2, CoastSettings(), prior, 0.16, train.tunnel_factor, PERIOD)
    assert st.ends.masks.shape == (1, 3)
    sure = energy_equations(
        arr, 0, 2, CoastSettings(coast_energy_end_effort=0.0), prior, 0.16, train.tunnel_factor, PERIOD
    )
    mean_ends, cov_ends = posterior(prior, p0, [st])
    mean_sure, cov_sure = posterior(prior, p0, [sure])
    np.testing.assert_allclose(mean_ends, mean_sure, rtol=1e-9)
    np.testing.assert_allclose(cov_ends, cov_sure, rtol=1e-9)


def test_the_mixture_equals_an_explicit_enumeration(track, train):
    """Two stretches of one coast, each with both neighbours (81 configurations together), one with a leak at its
    first sample: add_coast_with_ends equals an independent enumeration in the augmented state (r, E0 per stretch)
    with E0 ~ N(E at the first sample, (1e4 J/kg)^2), each configuration's evidence from scipy's multivariate normal
    and its posterior by the joint Gaussian's conditioning, moment-matched: mean to 1e-6, covariance to 1e-5."""
    import itertools

    from scipy.stats import multivariate_normal

    rng = np.random.default_rng(11)
    truth = truth_of(train, 1.15)
    settings = CoastSettings()
    prior = np.array(train.davis.as_tuple())
    p0 = prior_covariance(prior, 0.18, 0.10)
    parts = []
    for k, (s0, lead) in enumerate(((1500.0, 3.0), (2600.0, 0.0))):
        t, s, v = traction_then_coast(track, train, truth, s0, 80 * KMH, lead, 90.0)
        arr = arrays(track, train, t + 200.0 * k, s + rng.normal(0.0, 4.0, s.size), v + rng.normal(0.0, 0.16, v.size))
        st = energy_equations(arr, 1, t.size - 2, settings, prior, 0.16, train.tunnel_factor, PERIOD)
        assert st.ends.masks.shape == (9, t.size)
        parts.append((arr, st))
    mean_fast, cov_fast = posterior(prior, p0, [st for _, st in parts])  # one coast: group 0 for both

    big = 1e4
    blocks = []
    for arr, _ in parts:
        s, v = arr.s, arr.v
        phi = np.column_stack([
            s - s[0], cumulative_trapezoid(v, s, initial=0.0),
            cumulative_trapezoid(v * v * (1.0 + train.tunnel_factor * arr.tunnel), s, initial=0.0),
        ])  # fmt: skip
        energy = 0.5 * v * v + arr.gamma
        noise = v * v * 0.16**2 + arr.g**2 * 16.0
        leak = (settings.coast_energy_end_effort * v * PERIOD) ** 2
        n = v.size
        options = [(i0, i1) for i0 in (0, 1, 2) for i1 in (n - 3, n - 2, n - 1)]
        blocks.append((energy, -phi, noise, leak, s - s[1], options))
    x0 = np.concatenate([prior, [b[0][0] for b in blocks]])
    P_aug = np.zeros((5, 5))
    P_aug[:3, :3] = p0
    P_aug[3, 3] = P_aug[4, 4] = big * big
    H = np.zeros((sum(b[0].size for b in blocks), 5))
    row = 0
    for j, b in enumerate(blocks):
        H[row : row + b[0].size, :3] = b[1]
        H[row : row + b[0].size, 3 + j] = 1.0
        row += b[0].size
    y = np.concatenate([b[0] for b in blocks])
    d = np.concatenate([b[4] for b in blocks])
    bias = max(st.bias_std for _, st in parts)
    logs, means, covs, nis = [], [], [], []
    for choice in itertools.product(*(b[5] for b in blocks)):
        extra = []
        for (i0, i1), b in zip(choice, blocks):
            idx = np.arange(b[0].size)
            extra.append(np.where((idx >= i0) & (idx <= i1), 0.0, b[3]))
        C = np.diag(np.concatenate([b[2] for b in blocks]) + np.concatenate(extra)) + bias**2 * np.outer(d, d)
        S = H @ P_aug @ H.T + C
        logs.append(multivariate_normal(H @ x0, S).logpdf(y))
        nis.append(float((y - H @ x0) @ np.linalg.solve(S, y - H @ x0)))  # E0's share vanishes as 1 / big^2
        K = np.linalg.solve(S, H @ P_aug).T
        means.append((x0 + K @ (y - H @ x0))[:3])
        covs.append((P_aug - K @ H @ P_aug)[:3, :3])
    w = np.exp(np.array(logs) - max(logs))
    w /= w.sum()
    mean = sum(wi * m for wi, m in zip(w, means))
    cov = sum(wi * (c + np.outer(m - mean, m - mean)) for wi, m, c in zip(w, means, covs))
    np.testing.assert_allclose(mean_fast, mean, rtol=1e-6)
    np.testing.assert_allclose(cov_fast, cov, rtol=1e-5)
    # the coast's consistency (bench/validation/coast_consistency.py): the weighted NIS and samples less E0s
    fast_nis, dof = coast_consistency(prior_information(prior, p0), [st for _, st in parts])
    assert dof == y.size - 2
    assert fast_nis == pytest.approx(float(w @ np.array(nis)), rel=1e-5)  # measured 1.3e-6
