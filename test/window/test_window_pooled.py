"""The window's resistance at its mean speed and the run's windows pooled into r(v) (train_calib.window.pooled).

Against truth: exact on the discrete model without noise; on simulated 1 Hz runs with power (seeds not tuned on,
window_pool_runs.TUNED_SEEDS), r(80 km/h) and the 2 sigma coverage, the per-window sigmas. docs/window.md has the
full tables (8 track/train cases, 2 sensors, 2 driving styles, 3 seeds).
"""

from __future__ import annotations

import copy
import math
import pickle

import numpy as np
import pytest
from window_pool_runs import TUNED_SEEDS, make_run
from window_synthetic import TRUTH, euler_run, train_spec

from train_calib.nodes.window_calib_node import window_to_msg
from train_calib.pipeline import run_measurements
from train_calib.summary import window_pooled
from train_calib.summary_outputs import window_pooled_from_msg
from train_calib.train import Davis
from train_calib.window import WindowCalibrator, WindowConfig, WindowFit
from train_calib.window.pooled import PooledResistance, WindowEquation, prior_covariance

SEED = 3  # held out: not among TUNED_SEEDS


def _calibrate(series, train, config=None, compiled=True):
    cal = WindowCalibrator(train, config, compiled=compiled)
    fits = [f for i in range(len(series)) if (f := cal.update(series[i])) is not None]
    return cal, fits


def _r(theta, v):
    return theta[0] + theta[1] * v + theta[2] * v * v


def _sigma(cov, v):
    x = np.array([1.0, v, v * v])
    return math.sqrt(x @ np.asarray(cov).reshape(3, 3) @ x)


def test_prior_covariance_is_the_stated_formula_and_positive_definite_with_a_zero_coefficient():
    r = np.array([0.015, 2.0e-4, 4.0e-5])
    expected = 0.18**2 * np.outer(r, r) + np.diag((0.10 * r) ** 2)
    assert np.allclose(prior_covariance(Davis(*r)), expected, rtol=1e-12, atol=0.0)
    with_zero = prior_covariance((0.015, 0.0, 4.0e-5))  # a metro train file has r1 = 0
    assert np.all(np.linalg.eigvalsh(with_zero) > 0.0)


def test_without_windows_the_pooled_estimate_is_the_prior():
    train = train_spec()
    pooled = PooledResistance(train.davis)
    assert pooled.windows == 0
    assert np.array_equal(pooled.estimate, np.array(train.davis.as_tuple()))
    assert np.array_equal(pooled.covariance, prior_covariance(train.davis))
    assert not pooled.add(None)


def test_overlapping_windows_are_pooled_once():
    """Each step counts once: a window is pooled only when it starts after the last pooled one ended."""
    pooled = PooledResistance((0.01, 1e-4, 4e-5))

    def eq(start_s, end_s):
        return WindowEquation(int(start_s * 1e9), int(end_s * 1e9), 60, (1.0, 20.0, 400.0), 0.03, 1e-6)

    assert pooled.add(eq(1, 60))
    assert not pooled.add(eq(2, 61))  # shares 59 steps
    assert not pooled.add(eq(60, 119))  # shares the step ending at 60 s
    assert pooled.add(eq(61, 120))
    assert pooled.windows == 2


def test_a_new_run_whose_clock_restarts_is_pooled_too():
    """A recording of several runs (run_id) whose stamps restart: the second run's windows are pooled as well."""
    train = train_spec()
    run = euler_run(train)
    cal = WindowCalibrator(train)
    for i in range(len(run.series)):
        cal.update(run.series[i])
    first = cal.pooled.windows
    for i in range(len(run.series)):  # the same run again, same stamps, next run_id
        m = run.series[i]
        m.run_id = 1
        cal.update(m)
    assert first >= 3 and cal.pooled.windows == 2 * first


def test_noise_free_discrete_model_gives_the_resistance_at_the_mean_speed():
    """Euler-integrated run (the forward difference is exact, no noise): every window with enough steps gives
    r(mean v) within 2 sigma of the truth (the sigma bounds the train file's r2 taken for the spread of v^2, here
    mostly the tunnel's, and the offset of power and speed stamps); the pooled r(v) holds the truth within 2 sigma
    from 30 to 130 km/h and within 1 % from 80 km/h up."""
    train = train_spec(davis=Davis(TRUTH.r0 * 1.25, TRUTH.r1 * 0.8, TRUTH.r2 * 1.2))
    run = euler_run(train)
    _, fits = _calibrate(run.series, train)
    at_speed = [f for f in fits if math.isfinite(f.resistance_at_speed)]
    assert len(at_speed) > 0.5 * len(fits)
    errors = np.array([f.resistance_at_speed - TRUTH(f.resistance_speed) for f in at_speed])
    sigmas = np.array([f.resistance_at_speed_std for f in at_speed])
    assert np.all(np.abs(errors) <= 2.0 * sigmas)
    last = fits[-1]
    assert last.pooled_windows >= 5
    v = np.linspace(30.0, 130.0, 11) / 3.6
    sigma = np.array([_sigma(last.pooled_covariance, x) for x in v])
    assert np.all(np.abs(_r(last.pooled, v) - TRUTH(v)) <= 2.0 * sigma)
    fast = v >= 80.0 / 3.6  # below, the departure's windows weigh little (power/speed stamp bound): prior's share
    assert np.max(np.abs(_r(last.pooled, v[fast]) / TRUTH(v[fast]) - 1.0)) < 0.01  # measured 0.4 % at 80 km/h


@pytest.fixture(scope="module")
def simulated():
    """Held-out simulated runs: four tracks/trains, 0.1 km/h speeds with cruise held and 1 km/h with cycles."""
    assert SEED not in TUNED_SEEDS
    out = []
    for quantum, style in ((0.1, "hold"), (1.0, "cycles")):
        for case in range(4):
            run = make_run(case, SEED, quantum, style)
            cal, fits = _calibrate(run.series, run.train)
            out.append((quantum, run, cal, fits))
    return out


def test_pooled_resistance_at_80_kmh_against_truth(simulated):
    """docs/window.md, seed 3: 0.1 km/h errors 0.3-1.5 %, 1 km/h 0.6-1.7 %; the prior is 17-31 % off."""
    errors = {0.1: [], 1.0: []}
    for quantum, run, _, fits in simulated:
        v = run.v_eval
        true = run.truth(v)
        error = abs(_r(fits[-1].pooled, v) / true - 1.0)
        prior_error = abs(run.train.davis(v) / true - 1.0)
        assert error < 0.06 and error < 0.25 * prior_error, (run.train.name, quantum, error, prior_error)
        errors[quantum].append(error)
    assert np.median(errors[0.1]) < 0.03
    assert np.median(errors[1.0]) < 0.03


def test_pooled_covariance_covers_the_truth(simulated):
    """Truth of r(80 km/h) inside the published 2 sigma in all 8 runs (docs: 95 of 96 held-out runs), and the
    sigma says what the data gave: below 2.5 % with 0.1 km/h speeds, larger with 1 km/h."""
    z = []
    for quantum, run, _, fits in simulated:
        v = run.v_eval
        last = fits[-1]
        sigma = _sigma(last.pooled_covariance, v)
        z.append((_r(last.pooled, v) - run.truth(v)) / sigma)
        if quantum == 0.1:
            assert sigma < 0.025 * run.truth(v)
        cov = np.asarray(last.pooled_covariance).reshape(3, 3)
        assert np.allclose(cov, cov.T) and np.all(np.linalg.eigvalsh(cov) > 0.0)
    assert sum(abs(x) < 2.0 for x in z) >= 7, z


def test_each_window_resistance_at_its_mean_speed_covers_the_truth(simulated):
    """The per-window values are well posed where the windows are not (every window of these runs is ill posed,
    with 0.1 km/h speeds too) and their sigma is about honest: at least 80 % of the windows within 2 sigma of the truth
    (measured 86-97 %; tests of the pooled value above hold it to 90 % of runs)."""
    for quantum, run, _, fits in simulated:
        values = [f for f in fits if math.isfinite(f.resistance_at_speed)]
        assert len(values) > 0.9 * len(fits)  # measured 95-97 %
        z = np.array([(f.resistance_at_speed - run.truth(f.resistance_speed)) / f.resistance_at_speed_std
                      for f in values])  # fmt: skip
        assert np.mean(np.abs(z) < 2.0) >= 0.80, (run.train.name, quantum, np.mean(np.abs(z) < 2.0))
        assert all(f.ill_posed for f in fits)


def test_python_path_and_copies_give_the_same_pooled_estimate(simulated):
    """The Python twin of the kernel and a calibrator copied or pickled mid-run give the same window equations."""
    _, run, _, fits = simulated[0]
    _, python_fits = _calibrate(run.series, run.train, compiled=False)
    assert np.allclose(python_fits[-1].pooled, fits[-1].pooled, rtol=1e-9, atol=0.0)
    cal = WindowCalibrator(run.train)
    half = len(run.series) // 2
    for i in range(half):
        cal.update(run.series[i])
    for twin in (copy.deepcopy(cal), pickle.loads(pickle.dumps(cal))):
        rest = [f for i in range(half, len(run.series)) if (f := twin.update(run.series[i])) is not None]
        assert np.allclose(rest[-1].pooled, fits[-1].pooled, rtol=1e-12, atol=0.0)
        assert rest[-1].pooled_windows == fits[-1].pooled_windows


def test_pipeline_message_and_summary_carry_the_pooled_estimate(simulated):
    """run_measurements (the graph's reference) exposes it, the message carries it, summary.json's window.pooled
    reads it back (N/kg units, covariance 3x3); a message recorded before the fields gives None."""
    _, run, _, fits = simulated[1]
    out = run_measurements(run.series, run.train, window=WindowConfig(regime_source="power"))
    pooled = out.window_pooled
    assert pooled is not None and set(pooled) == {"r0", "r1", "r2", "covariance", "windows"}
    assert np.allclose([pooled["r0"], pooled["r1"], pooled["r2"]], fits[-1].pooled, rtol=1e-12, atol=0.0)
    msg = window_to_msg(fits[-1])
    fit = WindowFit(fits[-1].stamp_ns, 0, 60.0, 0, 1, 0.0, *(math.nan,) * 6, 0, True, 0.0)
    window_pooled_from_msg(fit, msg)
    summary = window_pooled(fit)
    assert summary is not None and summary["windows"] == fits[-1].pooled_windows
    assert np.allclose(summary["covariance"], np.asarray(fits[-1].pooled_covariance).reshape(3, 3))
    assert fit.resistance_at_speed == fits[-1].resistance_at_speed

    class Old:  # a WindowResistance of an older bag: none of the new fields
        pass

    old_fit = WindowFit(0, 0, 60.0, 0, 1, 0.0, *(math.nan,) * 6, 0, True, 0.0)
    window_pooled_from_msg(old_fit, Old())
    assert window_pooled(old_fit) is None and math.isnan(old_fit.resistance_at_speed)
