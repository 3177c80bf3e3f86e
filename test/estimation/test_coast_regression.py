"""Coast regression (estimation/coast_regression.py, coast_detection.py, coast_posterior.py): detection, posterior,
causal form, UKF integration.

Truth comes from the tests' own generator (synthetic.py: RK4 of a scripted driver), not the product simulator.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from synthetic import Script, make_run

from train_calib.estimation import COASTING, UKFConfig, estimate_run
from train_calib.estimation.coast_detection import speed_noise
from train_calib.estimation.coast_posterior import posterior, prior_covariance
from train_calib.estimation.coast_regression import (
    POWER_DRIVE,
    POWER_NONE,
    CoastRegression,
    CoastSettings,
    RunArrays,
    fit_coasts,
)
from train_calib.physics import KMH
from train_calib.train import Davis

V_REF = 80 * KMH
H_REF = np.array([1.0, V_REF, V_REF**2])


def scaled(d: Davis, factors) -> Davis:
    return Davis(*(np.array(d.as_tuple()) * np.asarray(factors, dtype=float)))


def run_with_truth(train, factors, period: float, seed: int = 0, script: Script | None = None):
    truth = scaled(train.davis, factors)
    _, _, series = make_run(seed=seed, period=period, resistance=truth, train=train, script=script)
    return truth, series


def rel_error(r: np.ndarray, truth: Davis) -> float:
    t = H_REF @ np.array(truth.as_tuple())
    return float((H_REF @ r - t) / t)


def rel_sigma(cov: np.ndarray, truth: Davis) -> float:
    return float(np.sqrt(H_REF @ cov @ H_REF) / (H_REF @ np.array(truth.as_tuple())))


def test_prior_covariance_says_about_19_percent_of_r(train):
    """The default prior: r(80 km/h) std 15-25 % (a train file 10-30 % off lies inside 2 sigma); positive definite
    also with a zero coefficient."""
    p0 = prior_covariance(train.davis, 0.18, 0.10)
    rel = np.sqrt(H_REF @ p0 @ H_REF) / (H_REF @ np.array(train.davis.as_tuple()))
    assert 0.15 < rel < 0.25
    assert np.all(np.linalg.eigvalsh(prior_covariance((0.01, 0.0, 1e-5), 0.18, 0.10)) > 0.0)


def test_posterior_equals_stacked_least_squares(train):
    """The posterior (centred equations, Sherman-Morrison for the error common to a coast) equals an independent
    solution of the uncentred problem: unknowns r and one start speed per stretch (flat prior), one row per
    sample v_i + G_i = c_k - Phi_i r (integrals by scipy's cumulative_trapezoid), noise sigma_v^2 I plus the
    bias as a random slope over t - t_0 shared within a coast, whitened and solved by numpy lstsq."""
    from scipy.integrate import cumulative_trapezoid

    _, series = run_with_truth(train, (0.8, 0.8, 0.8), 1.0)
    arr = RunArrays.from_series(series)
    fit = fit_coasts(arr, train)
    assert fit.stretches, "the scripted run has a final coast"
    prior = np.array(train.davis.as_tuple())
    p0 = prior_covariance(prior, 0.18, 0.10)
    k_count = len(fit.stretches)
    rows, rhs, slope, owner = [], [], [], []
    for k, st in enumerate(fit.stretches):
        sel = (arr.t >= st.t_start) & (arr.t <= st.t_end)
        t, v, g, tun = arr.t[sel], arr.v[sel], arr.g[sel], arr.tunnel[sel]
        assert t.size == st.y.size
        phi = np.column_stack([
            t - t[0], cumulative_trapezoid(v, t, initial=0.0),
            cumulative_trapezoid(v * v * (1.0 + train.tunnel_factor * tun), t, initial=0.0),
        ])  # fmt: skip
        c = np.zeros((t.size, k_count))
        c[:, k] = 1.0
        rows.append(np.hstack([-phi, c]))
        rhs.append(v + cumulative_trapezoid(g, t, initial=0.0))
        slope.append(t - t[0])
        owner += [k] * t.size
    x, y, u = np.vstack(rows), np.concatenate(rhs), np.concatenate(slope)
    groups = np.array([fit.stretches[k].group for k in owner])
    bias = np.array([max(st.bias_std for st in fit.stretches if st.group == gr) for gr in groups])
    same = groups[:, None] == groups[None, :]
    noise = fit.stretches[0].noise_var * np.eye(y.size) + np.where(same, np.outer(bias * u, bias * u), 0.0)
    w0 = np.linalg.cholesky(np.linalg.inv(p0)).T  # W0^T W0 = P0^-1, on r only (the start speeds: flat)
    w = np.linalg.cholesky(np.linalg.inv(noise)).T
    a = np.vstack([np.hstack([w0, np.zeros((3, k_count))]), w @ x])
    b = np.concatenate([w0 @ prior, w @ y])
    mean, *_ = np.linalg.lstsq(a, b, rcond=None)
    cov = np.linalg.inv(a.T @ a)[:3, :3]
    m, c = posterior(prior, p0, fit.stretches)
    np.testing.assert_allclose(m, mean[:3], rtol=1e-8)
    np.testing.assert_allclose(c, cov, rtol=1e-6)


@pytest.mark.parametrize("period", [1.0, 10.0])
@pytest.mark.parametrize("factors", [(0.75, 0.8, 0.75), (1.25, 1.2, 1.3)])
def test_whole_run_recovers_truth_from_a_wrong_train_file(train, period, factors):
    """Truth 20-30 % off the train file, either way (the detection must not favour the prior): r(80 km/h) within
    5 % at 1 Hz and 8 % at 10 s (one final coast from 130 to 80 km/h at 1 km/h resolution: measured 0.2-2.5 %,
    and 1.6 / 6.9 % at 10 s, where the coast's first sample after the W/2 trim still holds some of the cruise),
    truth inside 2 sigma, moved at least halfway toward the truth."""
    truth, series = run_with_truth(train, factors, period)
    fit = fit_coasts(RunArrays.from_series(series), train)
    err = rel_error(fit.r, truth)
    prior_err = rel_error(np.array(train.davis.as_tuple()), truth)
    assert len(fit.stretches) >= 1
    assert abs(err) < (0.05 if period == 1.0 else 0.08), (err, prior_err)
    assert abs(err) <= 2.0 * rel_sigma(fit.covariance, truth)
    assert abs(err) < 0.5 * abs(prior_err)


def test_no_coasting_keeps_prior_and_its_covariance(train):
    """A run that never coasts (held speed, then braking straight from the cruise speed) on a downhill where a
    hold's apparent resistance lies inside the band: no stretch, the prior and its covariance exactly."""
    script = Script(
        cruise_time=600.0,
        coast_until_speed=130 * KMH,  # brake at once after the cruise
        gradient_permille=((0.0, 0.0), (4000.0, -2.5)),
    )
    _, series = run_with_truth(train, (0.8, 0.8, 0.8), 1.0, script=script)
    fit = fit_coasts(RunArrays.from_series(series), train)
    assert fit.stretches == []
    np.testing.assert_array_equal(fit.r, np.array(train.davis.as_tuple()))
    np.testing.assert_array_equal(fit.covariance, prior_covariance(train.davis, 0.18, 0.10))


def test_speed_noise_from_the_data():
    """1 km/h quantisation alone gives about q / sqrt(12); Gaussian noise of 0.2 m/s its own std (within 15 %)."""
    rng = np.random.default_rng(3)
    v = 30.0 - 0.02 * np.arange(2000.0)
    assert speed_noise(np.round(v / KMH) * KMH) == pytest.approx(KMH / np.sqrt(12.0), rel=0.15)
    assert speed_noise(v + rng.normal(0.0, 0.2, v.size)) == pytest.approx(0.2, rel=0.15)


@pytest.mark.parametrize("period", [1.0, 10.0])
def test_causal_ends_where_the_whole_run_estimate_is(train, period):
    """Pushed sample by sample, the regression has used the coast by the end of the run (it is over): r(80 km/h)
    within 8 % of the truth, the truth inside 2 sigma, and at most half the prior's error. Its running speed-noise
    estimate and slope window differ from the whole run's, and it takes a long coast in pieces, so its chunks are
    cut elsewhere; with 1 km/h speeds each 20 s chunk carries about 30 % noise on r, and the two ends differ by up
    to 5 % here (measured -7.0 % against the whole run's -2.0 % at 1 Hz)."""
    truth, series = run_with_truth(train, (0.8, 0.85, 0.8), period)
    arr = RunArrays.from_series(series)
    fit = fit_coasts(arr, train)
    online = CoastRegression(train, CoastSettings())
    changed = [online.push(*args) for args in zip(arr.t, arr.v, arr.g, arr.tunnel, arr.run)]
    assert any(changed)
    assert len(online.stretches) >= len(fit.stretches) >= 1
    assert abs(rel_error(online.r, truth)) < 0.08
    assert abs(rel_error(online.r, truth)) <= 2.0 * rel_sigma(online.covariance, truth)
    assert abs(rel_error(online.r, truth)) < 0.5 * abs(rel_error(np.array(train.davis.as_tuple()), truth))


def test_causal_never_uses_the_future(train):
    """r moves only when a stretch is over: every stretch it adds ended at least W/2 + trim (= W) before the
    sample at which it was added; before the first, r is the prior."""
    _, series = run_with_truth(train, (0.8, 0.8, 0.8), 1.0)
    arr = RunArrays.from_series(series)
    online = CoastRegression(train, CoastSettings())
    used = 0
    for args in zip(arr.t, arr.v, arr.g, arr.tunnel, arr.run):
        if online.push(*args):
            for st in online.stretches[used:]:
                assert st.t_end + online.window <= args[0] + 1e-9
            used = len(online.stretches)
        elif used == 0:
            np.testing.assert_array_equal(online.r, np.array(train.davis.as_tuple()))
    assert used >= 1


def test_ukf_publishes_the_regression_at_the_defaults(train):
    """UKFConfig() learns r by the coast regression: the last estimate carries its r and r covariance (no cross
    terms with s, v); the paper preset stays at the train file's values with Table 1's tiny covariance."""
    truth, series = run_with_truth(train, (0.8, 0.8, 0.8), 1.0)
    arr = RunArrays.from_series(series)
    est = estimate_run(series, train, UKFConfig())
    online = CoastRegression(train, CoastSettings.from_config(UKFConfig()))
    for args in zip(arr.t + series.stamp_ns[0] * 1e-9, arr.v, arr.g, arr.tunnel, arr.run):
        online.push(*args)
    r = np.array([est.r0[-1], est.r1[-1], est.r2[-1]])
    np.testing.assert_allclose(r, online.r, rtol=1e-12)
    np.testing.assert_allclose(est.covariance[-1][2:, 2:], online.covariance, rtol=1e-12)
    assert np.all(est.covariance[-1][:2, 2:] == 0.0)
    assert abs(rel_error(r, truth)) < 0.05
    paper = estimate_run(series, train, UKFConfig.paper())
    assert abs(paper.r0[-1] / train.davis.r0 - 1.0) < 1e-3
    assert rel_sigma(paper.covariance[-1][2:, 2:], truth) < 1e-3


def test_settings_follow_the_config():
    cfg = UKFConfig(coast_stretch_std=0.2, prior_scale_std=0.3)
    s = CoastSettings.from_config(cfg)
    assert (s.coast_stretch_std, s.prior_scale_std) == (0.2, 0.3)
    assert replace(s, coast_min_duration=5.0).coast_min_duration == 5.0


def test_power_marks_the_coast_and_traction_power_vetoes_it(train):
    """With pantograph power a coast is where the power shows neither traction nor regeneration: its stretch is
    trimmed by one sample period, not by the slope window (more data: starts within 2 s of the true coast's start),
    r(80 km/h) within 5 %. Power that shows traction everywhere leaves no stretch (the speeds alone would find one)."""
    from synthetic import add_power

    truth = scaled(train.davis, (0.8, 0.8, 0.8))
    _, dense, series = make_run(seed=2, period=1.0, resistance=truth, train=train)
    add_power(series, dense, train, np.random.default_rng(2))
    arr = RunArrays.from_series(series, train)
    assert arr.power is not None and set(np.unique(arr.power)) == {POWER_NONE, POWER_DRIVE}
    fit = fit_coasts(arr, train)
    coast_start = dense.t[np.flatnonzero((dense.regime == COASTING) & (dense.v > 5.0))[0]]
    assert fit.stretches and fit.stretches[0].t_start - coast_start <= 2.0
    assert abs(rel_error(fit.r, truth)) < 0.05
    speeds_only = fit_coasts(RunArrays.from_series(series), train)
    assert speeds_only.stretches[0].t_start > fit.stretches[0].t_start + 5.0
    arr.power = np.full(arr.t.size, POWER_DRIVE, dtype=np.int8)
    assert fit_coasts(arr, train).stretches == []


def test_a_clock_reset_starts_a_new_time_base_and_keeps_what_was_learnt(train):
    """A recording whose second run's stamps lie before the first's (a clock reset): the whole-run fit takes each
    part on its own time base and finds the coast of both; the causal form learns in both too (found by the bag
    fuzz test: an IndexError in the summary's fit)."""
    truth, series = run_with_truth(train, (0.8, 0.8, 0.8), 1.0)
    arr = RunArrays.from_series(series)
    both = RunArrays(
        np.concatenate([arr.t, arr.t - 5000.0]),
        np.concatenate([arr.v, arr.v]),
        np.concatenate([arr.g, arr.g]),
        np.concatenate([arr.tunnel, arr.tunnel]),
        np.concatenate([arr.run, arr.run + 1]),
    )
    one = fit_coasts(arr, train)
    fit = fit_coasts(both, train)
    assert len(fit.stretches) == 2 * len(one.stretches) >= 2
    assert abs(rel_error(fit.r, truth)) < 0.05
    online = CoastRegression(train, CoastSettings())
    for args in zip(both.t, both.v, both.g, both.tunnel, both.run):
        online.push(*args)
        if args[0] < arr.t[-1] and args[4] == 0:
            first = len(online.stretches)
    assert first >= 1 and len(online.stretches) > first


def test_a_sample_without_speed_is_left_out_as_on_board(train):
    """A NaN speed (run_measurements takes any series) is no measurement: the whole-run fit equals the fit
    without that sample (it raised an IndexError in the slope windows), as CoastRegression.push skips it."""
    _, series = run_with_truth(train, (0.8, 0.8, 0.8), 1.0)
    arr = RunArrays.from_series(series)
    keep = np.ones(arr.t.size, dtype=bool)
    keep[100] = False
    clean = arr.part(keep)
    arr.v[100] = np.nan
    np.testing.assert_array_equal(fit_coasts(arr, train).r, fit_coasts(clean, train).r)
