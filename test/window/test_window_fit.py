"""fit_window / fit_rows against synthetic runs with a known resistance."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from window_synthetic import TRUTH, euler_run, fine_run, train_spec

from train_calib.window import (
    BRAKING,
    TRACTION,
    WindowConfig,
    calibrate_series,
    fit_window,
    scaled_condition_number,
)
from train_calib.window.evaluation import resistance_errors, series_rows, step_errors
from train_calib.window.fit import ill_posed_why, resistance_standard_error

TRAIN = train_spec()
M = TRAIN.effective_mass_kg


def _slice(series, start, stop, **kwargs):
    sl = slice(start, stop)
    return fit_window(
        series.t[sl], series.v[sl], series.power_consumed[sl], series.power_regenerated[sl], series.track_force[sl],
        series.tunnel_fraction[sl], TRAIN, kwargs.pop("config", WindowConfig()), **kwargs,
    )  # fmt: skip


@pytest.fixture(scope="module")
def exact_run():
    return euler_run()


@pytest.mark.parametrize("gof", ["sae", "rmse"])
def test_exact_data_gives_exact_coefficients_in_both_units(exact_run, gof):
    """Noise-free data of the discrete model: every well-posed window returns the true A, B, C."""
    series = dataclasses.replace(
        exact_run.series,
        **{f.name: getattr(exact_run.series, f.name)[:260] for f in dataclasses.fields(exact_run.series)},
    )  # departure, two accelerations, cruise, coast
    config = WindowConfig(gof=gof, window_length=30.0)
    fits = calibrate_series(series, TRAIN, config)
    well = [f for f in fits if not f.ill_posed]
    assert len(well) > 60
    est = np.array([f.estimate for f in well])
    np.testing.assert_allclose(est, np.broadcast_to(TRUTH.as_tuple(), est.shape), rtol=1e-7)
    f = well[len(well) // 2]
    assert (f.a, f.b, f.c) == pytest.approx((TRUTH.r0 * M, TRUTH.r1 * M, TRUTH.r2 * M), rel=1e-7)
    assert f.a == pytest.approx(f.r0 * 400e3 * 1.06, rel=1e-12)  # A = gamma m r0
    assert f.gof_value == pytest.approx(0.0, abs=1e-3)  # N, for a 424 t train
    assert f.gof_kind == (0 if gof == "sae" else 1)


def test_tunnel_factor_is_needed_to_recover_c(exact_run):
    """The run crosses two tunnels; ignoring f_tun biases the fit on the windows that contain one."""
    series = exact_run.series
    in_tunnel = np.flatnonzero(series.tunnel_fraction > 0)
    start = in_tunnel[0] - 5
    right = _slice(series, start, start + 31)
    wrong_train = train_spec(tunnel_factor=0.0)
    wrong = fit_window(
        series.t[start : start + 31], series.v[start : start + 31], series.power_consumed[start : start + 31],
        series.power_regenerated[start : start + 31], series.track_force[start : start + 31],
        series.tunnel_fraction[start : start + 31], wrong_train, WindowConfig(),
    )  # fmt: skip
    assert right.estimate == pytest.approx(TRUTH.as_tuple(), rel=1e-7)
    assert abs(wrong.estimate[2] / TRUTH.r2 - 1) > 0.05


def test_gof_value_is_their_error_in_newton(exact_run):
    rng = np.random.default_rng(0)
    series = exact_run.series
    noisy_v = series.v + rng.normal(0, 0.05, len(series))
    sl = slice(40, 71)
    for gof in ("sae", "rmse"):
        cfg = WindowConfig(gof=gof)
        fit = fit_window(series.t[sl], noisy_v[sl], series.power_consumed[sl], series.power_regenerated[sl],
                         series.track_force[sl], series.tunnel_fraction[sl], TRAIN, cfg)  # fmt: skip
        noisy = series.__class__(**{**series.__dict__, "v": noisy_v})
        rows = series_rows(noisy, TRAIN, cfg).take(slice(40, 70))
        e = step_errors(rows, fit.estimate, M)
        expected = np.abs(e).sum() if gof == "sae" else np.sqrt(np.mean(e**2))
        assert fit.sample_count == 30
        assert fit.gof_value == pytest.approx(expected, rel=1e-9)


def test_bounds_hold(exact_run):
    cfg = WindowConfig(r2_bounds=(0.0, 3e-5))  # below the true 5.2e-5
    fit = _slice(exact_run.series, 60, 91, config=cfg)
    assert fit.estimate[2] == pytest.approx(3e-5, rel=1e-9)


def test_constant_speed_window_is_ill_posed_and_holds_the_last_values(exact_run):
    series = exact_run.series
    regime = exact_run.regime
    cruise = np.flatnonzero(regime == 2)
    start = cruise[5]
    assert np.ptp(series.v[start : start + 11]) < 0.5
    first = _slice(series, start, start + 11, config=WindowConfig(window_length=10.0))
    assert first.ill_posed and first.reason
    assert all(math.isnan(value) for value in (first.a, first.b, first.c, first.r0, first.r1, first.r2))
    good = _slice(series, 2, 33)
    assert not good.ill_posed
    held = _slice(series, start, start + 11, config=WindowConfig(window_length=10.0), previous=good)
    assert held.ill_posed
    assert (held.a, held.b, held.c) == (good.a, good.b, good.c)
    # the window's own solution still fits the total resistance at the cruise speed
    v0 = float(np.mean(series.v[start : start + 10]))
    r_est = np.polyval(held.estimate[::-1], v0)
    assert r_est == pytest.approx(TRUTH(v0), rel=1e-6)


def test_condition_number_of_scaled_design():
    v = np.linspace(30.0, 31.0, 10)
    x = np.column_stack([np.ones(10), v, v * v])
    narrow = scaled_condition_number(x)
    wide = scaled_condition_number(np.column_stack([np.ones(10), v - 25, (v - 25) ** 2]))
    assert narrow > 1e4 > wide
    assert math.isinf(scaled_condition_number(x[:2]))


def test_dominant_regime_from_given_regimes(exact_run):
    series = exact_run.series
    fit = _slice(series, 2, 22, regime=exact_run.regime[2:22])
    assert fit.regime == TRACTION


def test_midpoint_scheme_removes_the_step_bias_on_continuous_data():
    """Continuous dynamics with the effort held over each second: their forward eq. 4 carries a few per cent
    of discretisation bias at 1 Hz, the midpoint variant removes it (medians over all well-posed 30 s windows)."""
    run = fine_run()
    forward = resistance_errors(calibrate_series(run.series, TRAIN, WindowConfig()), TRUTH.as_tuple())
    midpoint = resistance_errors(
        calibrate_series(run.series, TRAIN, WindowConfig(difference_scheme="midpoint")), TRUTH.as_tuple()
    )
    assert np.all(np.median(np.abs(midpoint), axis=0) < 0.002)
    assert np.median(np.abs(forward[:, 0])) > 0.01


def test_standard_error_of_the_resistance_against_the_textbook_formula():
    rng = np.random.default_rng(5)
    v = rng.uniform(5.0, 40.0, 40)
    x = np.column_stack([np.ones_like(v), v, v * v])
    e = rng.normal(0.0, 0.02, 40)
    speeds = np.array([40.0, 80.0, 120.0]) / 3.6
    at = np.column_stack([np.ones(3), speeds, speeds**2])
    sigma2 = e @ e / (40 - 3)
    expected = np.sqrt(sigma2 * np.einsum("ij,jk,ik->i", at, np.linalg.inv(x.T @ x), at))
    np.testing.assert_allclose(resistance_standard_error(x, e, speeds), expected, rtol=1e-9)
    assert np.all(np.isinf(resistance_standard_error(x[:3], e[:3], speeds)))


def test_noise_makes_a_well_conditioned_window_ill_posed(exact_run):
    """Same accelerating window: exact data are published; quantised speed (1 km/h) is flagged as noise."""
    series = exact_run.series
    sl = slice(2, 62)
    assert np.ptp(series.v[sl]) > 20.0  # wide speed span, well conditioned
    clean = _slice(series, 2, 62)
    assert not clean.ill_posed and clean.condition_number < 100
    quantised = np.round(series.v * 3.6) / 3.6
    noisy = fit_window(series.t[sl], quantised[sl], series.power_consumed[sl], series.power_regenerated[sl],
                       series.track_force[sl], series.tunnel_fraction[sl], TRAIN, WindowConfig())  # fmt: skip
    assert noisy.ill_posed and "relative standard error" in noisy.reason
    assert noisy.relative_error > 0.5 > clean.relative_error
    assert noisy.condition_number == pytest.approx(clean.condition_number, rel=0.05)


def test_braking_steps_with_unmeasured_mechanical_brake_are_left_out():
    """Half of the brake effort is mechanical (not in the power): braking steps bias the fit unless excluded."""
    run = euler_run(electric_brake_max=0.2)
    series = run.series
    brake = np.flatnonzero(run.regime == BRAKING)
    start = brake[0] - 40
    sl = slice(start, brake[0] + 20)  # 40 s of traction/cruise, 20 s of braking
    kwargs = dict(regime=run.regime[sl])
    args = (series.t[sl], series.v[sl], series.power_consumed[sl], series.power_regenerated[sl],
            series.track_force[sl], series.tunnel_fraction[sl], TRAIN)  # fmt: skip
    excluded = fit_window(*args, WindowConfig(max_relative_error=1e9), **kwargs)
    included = fit_window(*args, WindowConfig(max_relative_error=1e9, exclude_braking=False), **kwargs)
    assert excluded.sample_count == 40 and included.sample_count == 59
    v = np.array([40.0, 80.0, 120.0]) / 3.6
    assert np.allclose(np.polyval(excluded.estimate[::-1], v), TRUTH(v), rtol=1e-6)
    assert np.max(np.abs(np.polyval(included.estimate[::-1], v) / TRUTH(v) - 1)) > 0.2


def test_a_window_of_nearly_constant_speed_is_ill_posed_by_its_speed_span():
    """min_speed_span 1 m/s: a span of 0.5 m/s names the speed span as the reason, whatever the other criteria; 0.1
    m/s more than the bound passes."""
    config = WindowConfig()
    assert config.min_speed_span == 1.0
    why = ill_posed_why(60, 0.5, 10.0, config)
    assert why == ("speed span {:.2f} m/s < min_speed_span {:g} m/s", 0.5, 1.0)
    assert why[0].format(*why[1:]) == "speed span 0.50 m/s < min_speed_span 1 m/s"
    assert ill_posed_why(60, 1.1, 10.0, config) == ()
    assert ill_posed_why(60, 0.95, 10.0, WindowConfig(min_speed_span=0.9)) == ()
