"""The streaming fast path (StepModel, FastFit) against the reference (difference_rows, fit_design / solvers.solve).

Tolerances: rows bit for bit; speeds and condition number to 1e-9 relative; GoF and relative standard
error to max(1e-9, 1e-17 cond^2) relative (1e-9 up to a condition number of 1e4; of an exact window,
round-off themselves: 1e-12 N/kg and 1e-9 absolute); r0, r1, r2 (the window's estimate and the
published values, A, B, C likewise) to max(1e-11, 1e-15 cond^2) of each bound's range: 1e-9 at the
default max_condition 1e3. Both solvers carry round-off of order eps cond^2 on theta (least squares
with a residual); components sit at a bound of 0, so a relative test means nothing there.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from window_synthetic import FAST_TRAIN

from train_calib.window import (
    WindowCalibrator,
    WindowConfig,
    difference_rows,
    objective,
    regime_from_power,
    solve,
    tractive_force,
)
from train_calib.window.fast import FastFit
from train_calib.window.model import StepModel

TRAIN = FAST_TRAIN
FLOATS = ("speed_span", "mean_speed", "condition_number")
EXACT = ("stamp_ns", "run_id", "window_length", "sample_count", "gof_kind", "regime", "ill_posed",
         "dropped_constraints", "reason")  # fmt: skip


def _close(a: float, b: float, rtol: float = 1e-9, atol: float = 0.0) -> bool:
    if math.isnan(a) or math.isnan(b) or math.isinf(a) or math.isinf(b):
        return (math.isnan(a) and math.isnan(b)) or a == b
    return abs(a - b) <= rtol * max(abs(a), abs(b)) + atol


def _assert_same_fit(fast, ref, config: WindowConfig, mass: float) -> None:
    for name in EXACT:
        assert getattr(fast, name) == getattr(ref, name), (name, fast, ref)
    for name in FLOATS:
        assert _close(getattr(fast, name), getattr(ref, name)), (name, fast, ref)
    rtol = _objective_rtol(ref.condition_number)
    assert _close(fast.gof_value, ref.gof_value, rtol, 1e-12 * mass), (fast, ref)
    assert _close(fast.relative_error, ref.relative_error, rtol, 1e-9), (fast, ref)
    width = np.array([hi - lo for lo, hi in config.specific_bounds])
    published = _theta_tolerance(config.max_condition) * width
    for names, unit in ((("r0", "r1", "r2"), 1.0), (("a", "b", "c"), mass)):
        difference = [abs(getattr(fast, n) - getattr(ref, n)) for n in names]
        assert np.all(np.asarray(difference) <= published * unit) or all(
            math.isnan(getattr(fast, n)) and math.isnan(getattr(ref, n)) for n in names
        ), (names, fast, ref)
    if ref.condition_number <= 1e6:
        tolerance = _theta_tolerance(ref.condition_number) * width
        np.testing.assert_array_less(np.abs(np.subtract(fast.estimate, ref.estimate)), tolerance)


def _objective_rtol(condition: float) -> float:
    """Relative, of the GoF and the standard errors (above 1e6 both fits are the reference's)."""
    return max(1e-9, 1e-17 * condition * condition) if condition <= 1e6 else 1e-9


def _theta_tolerance(condition: float) -> float:
    """Of a bound's range: the round-off of least squares with a residual, eps cond^2 with a margin."""
    return max(1e-11, 1e-15 * condition * condition)


# -- one step in plain floats --------------------------------------------------------------------


@pytest.mark.parametrize("scheme", ["forward", "midpoint", "trapezoid"])
@pytest.mark.parametrize("constraints", [(True, True), (False, True), (False, False)])
def test_step_model_equals_the_array_functions_bit_for_bit(scheme, constraints):
    config = WindowConfig(difference_scheme=scheme, traction_constraint=constraints[0],
                          adhesion_constraint=constraints[1], max_gap=2.0)  # fmt: skip
    step = StepModel(TRAIN, config)
    rng = np.random.default_rng(7)
    n = 400
    t = np.cumsum(rng.choice([0.0, 0.5, 1.0, 1.0, 1.0, 3.0], n))
    v = np.maximum(rng.uniform(-2.0, 45.0, n), 0.0)
    consumed = rng.uniform(-2e5, 4e6, n)
    regenerated = np.where(rng.random(n) < 0.3, rng.uniform(0.0, 3e6, n), 0.0)
    force = tractive_force(v, consumed, regenerated, TRAIN, config.min_speed) / TRAIN.effective_mass_kg
    force[rng.random(n) < 0.05] = np.nan  # no power
    g = rng.normal(0.0, 0.05, n)
    tau = np.where(rng.random(n) < 0.3, rng.random(n), 0.0)
    var = rng.uniform(0.0, 0.02, n)
    with np.errstate(invalid="ignore", divide="ignore"):  # steps of dt = 0 (not valid)
        rows = difference_rows(t, v, force, g, tau, TRAIN, config, v_variance=var)
    regimes = regime_from_power(rows.force, rows.acceleration, config)
    samples = [(t[i], v[i], force[i], g[i], tau[i], var[i], step.limit(float(v[i]))) for i in range(n)]
    for i in range(n):
        f = step.force(float(v[i]), float(consumed[i]), float(regenerated[i]))
        assert f == force[i] or (math.isnan(f) and np.isnan(force[i])) or np.isnan(force[i])
    valid = 0
    for k in range(n - 1):
        row = step.row(samples[k], samples[k + 1])
        assert (row is not None) == rows.valid[k], k
        if row is None:
            continue
        valid += 1
        expected = (*rows.x[k], rows.y[k], rows.upper[k], rows.v[k], rows.acceleration[k], rows.force[k])
        assert row == expected, (k, row, expected)
        assert row[5] == row[1]  # the row's speed is its x1 (the calibrator's buffer keeps it once)
        assert step.regime(row[7], row[6]) == regimes[k]
    assert 50 < valid < n - 50


# -- the whole window: streaming fast against the reference -----------------------------------------


CONFIGS = {
    "default": WindowConfig(),
    "bounds binding": WindowConfig(
        window_length=30.0,
        r0_bounds=(0.009, 0.02),
        r1_bounds=(0.0, 1e-4),
        r2_bounds=(0.0, 5.0e-5),
        constraint_sigma=0.5,
    ),
    "trapezoid 10 s": WindowConfig(window_length=10.0, difference_scheme="trapezoid", exclude_braking=False),
    "midpoint 120 s": WindowConfig(
        window_length=120.0,
        difference_scheme="midpoint",
        max_condition=1e5,
        max_relative_error=5.0,
        regime_source="power",
    ),
}


@pytest.mark.parametrize("name", list(CONFIGS))
def test_streaming_fast_equals_the_reference_solver(runs, name):
    config = CONFIGS[name]
    seen = {"well_posed": 0, "ill_posed": 0, "bound_active": 0, "row_binding": 0}
    fitted = fallbacks = 0
    for _, train, series in runs:
        fast, reference = WindowCalibrator(train, config), WindowCalibrator(train, config, fast=False)
        for i in range(len(series)):
            a, b = fast.update(series[i]), reference.update(series[i])
            assert (a is None) == (b is None)
            if a is None:
                continue
            _assert_same_fit(a, b, config, train.effective_mass_kg)
            fitted += 1
            seen["ill_posed" if b.ill_posed else "well_posed"] += 1
            if b.sample_count >= 4 and np.isfinite(b.estimate[0]):
                lo, hi = np.array(config.specific_bounds).T
                seen["bound_active"] += bool(np.any((np.array(b.estimate) == lo) | (np.array(b.estimate) == hi)))
        assert fast.counts == reference.counts
        fallbacks += fast.reference_windows
        seen["row_binding"] += fast._fit.constrained
    assert fitted > 1500
    assert fallbacks < 0.25 * fitted, (fallbacks, fitted)  # the fast path did the work
    assert all(count > 0 for count in seen.values()), seen


# -- one window at a time: FastFit against solvers.solve ---------------------------------------------


def _window(rng, n, v_lo, v_hi, noise, envelope):
    v = rng.uniform(v_lo, v_hi, n)
    tau = np.where(rng.random(n) < 0.2, 1.0, 0.0)
    x = np.column_stack([np.ones(n), v, v * v * (1.0 + 0.4 * tau)])
    theta = np.array([0.008, 1.2e-4, 4.5e-5])
    y = x @ theta + rng.normal(0.0, noise, n)
    upper = np.full(n, np.inf) if envelope is None else y + rng.normal(envelope, 0.01, n)
    return x, y, upper, v


@pytest.mark.parametrize("seed", range(6))
def test_fast_window_equals_solve(seed):
    """Well-posed and ill-posed designs, bounds active and not, eq. 6/7 rows binding, dropped and absent."""
    rng = np.random.default_rng(seed)
    cases = [
        (60, 5.0, 40.0, 0.02, None),  # well posed, free
        (60, 5.0, 40.0, 0.3, None),  # noisy: bounds active
        (30, 20.0, 21.0, 0.05, None),  # narrow speed range: ill conditioned
        (60, 5.0, 40.0, 0.05, 0.0),  # eq. 6/7 rows at the fit: some binding
        (60, 5.0, 40.0, 0.05, -0.05),  # rows below the fit: binding, some dropped
        (8, 10.0, 30.0, 0.01, 0.02),
    ]
    config = WindowConfig(r1_bounds=(0.0, 1e-3), r2_bounds=(0.0, 1e-4))
    for n, v_lo, v_hi, noise, envelope in cases:
        x, y, upper, v = _window(rng, n, v_lo, v_hi, noise, envelope)
        fit = FastFit(TRAIN, config)
        upper_tol = upper + 1e-12 * np.maximum(1.0, np.abs(upper))
        result = fit(np.column_stack([x, y]), upper, upper_tol, v, 1, stamp_ns=0, run_id=0, previous=None)
        exact = solve(x, y, config.specific_bounds, upper, "rmse")
        assert fit.reference == 0  # all of these are for the fast path
        assert result.dropped_constraints == exact.dropped_constraints
        rtol = _objective_rtol(result.condition_number)
        assert result.gof_value == pytest.approx(exact.objective * TRAIN.effective_mass_kg, rel=rtol)
        assert objective(x, y, result.estimate, "rmse") <= exact.objective * (1 + 1e-9)
        fin = np.isfinite(upper) & (x @ np.zeros(3) <= upper)
        assert np.all(x[fin] @ np.array(result.estimate) <= upper[fin] + 1e-9)
        width = np.array([hi - lo for lo, hi in config.specific_bounds])
        tolerance = _theta_tolerance(result.condition_number) * width
        np.testing.assert_array_less(np.abs(np.subtract(result.estimate, exact.theta)), tolerance)


def test_rank_deficient_and_short_windows_go_to_the_reference():
    config = WindowConfig()
    fit = FastFit(TRAIN, config)
    x = np.column_stack([np.ones(10), np.full(10, 20.0), np.full(10, 400.0)])  # one speed: rank 1
    y = np.full(10, 0.05)
    inf = np.full(10, np.inf)
    fit(np.column_stack([x, y]), inf, inf, x[:, 1], 2, stamp_ns=0, run_id=0, previous=None)
    fit(np.column_stack([x, y])[:3], inf[:3], inf[:3], x[:3, 1], 2, stamp_ns=0, run_id=0, previous=None)
    assert fit.reference == 2
