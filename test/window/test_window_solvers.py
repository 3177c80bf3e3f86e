"""The exact solvers against brute-force enumerations (independent implementations) and scipy's BVLS."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from scipy.optimize import lsq_linear

from train_calib.window import objective, solve

BOUNDS = ((0.0, 0.05), (0.0, 0.005), (0.0, 5e-4))
THETA = np.array([0.008, 1.2e-4, 4.5e-5])


def _window(rng, n, noise=0.05, v_range=(5.0, 40.0)):
    v = rng.uniform(*v_range, n)
    x = np.column_stack([np.ones(n), v, v * v])
    return x, x @ THETA + rng.normal(0.0, noise, n)


def _planes(x, y, upper):
    """All hyperplanes a theta = b that can define a vertex: residual zero, bounds, constraints."""
    planes = [(row, b) for row, b in zip(x, y)]
    for j, (lo, hi) in enumerate(BOUNDS):
        e = np.eye(3)[j]
        planes += [(e, lo), (e, hi)]
    planes += [(row, b) for row, b in zip(x, upper) if np.isfinite(b)]
    return planes


def _feasible(theta, x, upper, tol=1e-9):
    lo = np.array([b[0] for b in BOUNDS])
    hi = np.array([b[1] for b in BOUNDS])
    scale = np.abs(x).max(axis=0)
    ok = np.all(theta * scale >= lo * scale - tol) and np.all(theta * scale <= hi * scale + tol)
    fin = np.isfinite(upper)
    return ok and np.all(x[fin] @ theta <= upper[fin] + tol)


def brute_force_sae(x, y, upper):
    """Minimum of the convex piecewise-linear SAE over the polytope: at a vertex of the plane arrangement."""
    best = np.inf
    for (a1, b1), (a2, b2), (a3, b3) in itertools.combinations(_planes(x, y, upper), 3):
        m = np.array([a1, a2, a3])
        if abs(np.linalg.det(m / np.abs(x).max(axis=0))) < 1e-9:
            continue
        theta = np.linalg.solve(m, [b1, b2, b3])
        if _feasible(theta, x, upper):
            best = min(best, objective(x, y, theta, "sae"))
    return best


def brute_force_rmse(x, y, upper):
    """Convex QP: the optimum solves the equality-constrained LS of some active set; try all of size <= 3."""
    constraint_planes = _planes(x, y, upper)[len(y) :]
    best = np.inf
    for k in range(4):
        for active in itertools.combinations(constraint_planes, k):
            a = np.array([p[0] for p in active]).reshape(k, 3)
            b = np.array([p[1] for p in active])
            kkt = np.block([[2 * x.T @ x, a.T], [a, np.zeros((k, k))]])
            rhs = np.concatenate([2 * x.T @ y, b])
            try:
                theta = np.linalg.solve(kkt, rhs)[:3]
            except np.linalg.LinAlgError:
                continue
            if _feasible(theta, x, upper):
                best = min(best, objective(x, y, theta, "rmse"))
    return best


@pytest.mark.parametrize("seed", range(6))
def test_rmse_bounds_only_equals_bvls(seed):
    rng = np.random.default_rng(seed)
    x, y = _window(rng, 30, noise=0.1)
    sol = solve(x, y, BOUNDS, None, "rmse")
    ref = lsq_linear(x, y, bounds=([b[0] for b in BOUNDS], [b[1] for b in BOUNDS]), tol=1e-14, method="bvls")
    assert sol.objective <= objective(x, y, ref.x, "rmse") * (1 + 1e-10)
    np.testing.assert_allclose(sol.theta * [1, 30, 900], ref.x * [1, 30, 900], atol=1e-8)


@pytest.mark.parametrize("seed", range(8))
def test_exact_solvers_match_enumeration_with_active_bounds_and_constraints(seed):
    rng = np.random.default_rng(100 + seed)
    x, y = _window(rng, 8, noise=0.15)
    # constraints that cut into the unconstrained optimum on a few rows (eq. 6/7 active)
    upper = np.full(8, np.inf)
    upper[:3] = x[:3] @ THETA * rng.uniform(0.5, 0.95, 3)
    for gof, brute in (("sae", brute_force_sae), ("rmse", brute_force_rmse)):
        sol = solve(x, y, BOUNDS, upper, gof)
        assert not sol.constraints_relaxed
        assert _feasible(sol.theta, x, upper, tol=1e-7)
        expected = brute(x, y, upper)
        assert sol.objective == pytest.approx(expected, rel=1e-7, abs=1e-12), gof


def test_constraints_bind_when_the_data_ask_for_more_resistance():
    rng = np.random.default_rng(7)
    x, y = _window(rng, 20, noise=0.01)
    upper = x @ THETA * 0.9  # the traction envelope allows only 90 % of the resistance the data imply
    for gof in ("sae", "rmse"):
        free = solve(x, y, BOUNDS, None, gof)
        held = solve(x, y, BOUNDS, upper, gof)
        assert np.any(x @ free.theta > upper + 1e-6)  # the unconstrained fit violates eq. 7
        assert np.all(x @ held.theta <= upper + 1e-9)
        assert held.objective > free.objective


def test_rows_infeasible_on_their_own_are_dropped_and_counted():
    rng = np.random.default_rng(3)
    x, y = _window(rng, 12)
    upper = np.full(12, np.inf)
    upper[:3] = -1.0  # below zero resistance: impossible with the lower bounds at 0
    for gof in ("sae", "rmse"):
        upper[3:6] = x[3:6] @ solve(x, y, BOUNDS, None, gof).theta * 0.8  # feasible and binding
        sol = solve(x, y, BOUNDS, upper, gof)
        assert sol.dropped_constraints == 3 and sol.constraints_relaxed
        kept = upper.copy()
        kept[:3] = np.inf
        assert sol.objective == pytest.approx(solve(x, y, BOUNDS, kept, gof).objective, rel=1e-9)
        assert sol.objective > solve(x, y, BOUNDS, None, gof).objective


def test_rank_deficient_window_still_solves():
    x = np.column_stack([np.ones(11), np.full(11, 30.0), np.full(11, 900.0)])  # constant speed
    y = x @ THETA + np.linspace(-0.01, 0.01, 11)  # odd: unique median
    for gof in ("sae", "rmse"):
        sol = solve(x, y, BOUNDS, None, gof)
        # A, B, C are not separable but the resistance at that speed is identified
        assert x[0] @ sol.theta == pytest.approx(x[0] @ THETA, abs=1e-6)


def _box_enumeration_rmse(x, y):
    """Bounds only: each coefficient at its lower bound, upper bound or free (27 cases), least squares."""
    best = np.inf
    for combo in itertools.product((0, 1, 2), repeat=3):
        theta = np.zeros(3)
        fixed = [j for j in range(3) if combo[j] < 2]
        free = [j for j in range(3) if combo[j] == 2]
        for j in fixed:
            theta[j] = BOUNDS[j][combo[j]]
        if free:
            theta[free] = np.linalg.lstsq(x[:, free], y - x[:, fixed] @ theta[fixed], rcond=None)[0]
        lo, hi = np.array(BOUNDS).T
        if np.all(theta >= lo - 1e-15) and np.all(theta <= hi + 1e-15):
            best = min(best, objective(x, y, theta, "rmse"))
    return best


@pytest.mark.parametrize("seed", range(5))
def test_near_constant_quantised_speed_windows(seed):
    """Cruising at 1 km/h resolution: v, v^2 nearly collinear with 1 (condition ~1e4-1e16), bounds active."""
    rng = np.random.default_rng(200 + seed)
    kmh = np.round(108.0 + rng.normal(0.0, 0.6, 10))
    v = kmh / 3.6
    x = np.column_stack([np.ones(10), v, v * v])
    y = x @ THETA + rng.normal(0.0, 0.1, 10)
    sae = solve(x, y, BOUNDS, None, "sae")
    assert sae.objective == pytest.approx(brute_force_sae(x, y, np.full(10, np.inf)), rel=1e-7, abs=1e-12)
    rmse = solve(x, y, BOUNDS, None, "rmse")
    assert rmse.objective <= _box_enumeration_rmse(x, y) * (1 + 1e-9)
