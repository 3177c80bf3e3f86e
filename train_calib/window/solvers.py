"""Exact solvers of the window fit, linear in theta = (r0, r1, r2), and the paper's multistart reference.

* SAE (sum of absolute residuals): a linear programme, solved by HiGHS (scipy.optimize.linprog):
  min sum t_k  s.t.  -t_k <= y_k - x_k theta <= t_k,  x_k theta <= upper_k (eq. 6/7),  lo <= theta <= hi.
* RMSE: least squares with the same linear inequalities, an LSI problem solved exactly by the
  Lawson & Hanson reduction LSI -> LDP -> NNLS (scipy.optimize.nnls, a finite active-set method).
* ``multistart``: the paper's method (Section 5.2), a gradient solver (SLSQP) from 40 random starts,
  kept as the reference the exact solvers must match or beat.

Columns are scaled to a maximum of 1 before solving (v^2 spans four decades more than 1).

Infeasible eq. 6/7 rows: the design columns (1, v, v^2 (1 + f_tun tau)) are non-negative, so the lower
bounds minimise every x_k theta at once and the constraints are jointly feasible exactly when each
row holds at theta = lower bounds. A row that does not (the measured acceleration exceeds the
envelope even with no resistance: speed noise at full traction) carries no information on
theta; it is dropped and counted (``dropped_constraints``), the others are kept.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import linprog, lsq_linear, minimize, nnls

GOF_NAMES = ("sae", "rmse")


@dataclass(frozen=True)
class Solution:
    """theta = (r0, r1, r2) in N/kg units and the objective (SAE: sum |e|, RMSE: sqrt(mean e^2)), N/kg."""

    theta: np.ndarray
    objective: float
    dropped_constraints: int = 0  # eq. 6/7 rows infeasible on their own, left out
    solver: str = ""

    @property
    def constraints_relaxed(self) -> bool:
        return self.dropped_constraints > 0


def objective(x: np.ndarray, y: np.ndarray, theta, gof: str) -> float:
    """GoF of theta on rows (x, y): SAE = sum |y - x theta|, RMSE = sqrt(mean (y - x theta)^2), N/kg."""
    e = y - x @ np.asarray(theta, dtype=float)
    return float(np.abs(e).sum()) if gof == "sae" else float(np.sqrt(np.mean(e * e)))


def _scales(x: np.ndarray) -> np.ndarray:
    s = np.max(np.abs(x), axis=0) if len(x) else np.ones(x.shape[1])
    return np.where(s > 0.0, s, 1.0)


def solve(x, y, bounds, upper=None, gof: str = "sae") -> Solution:
    """Exact minimiser of the GoF over bounds (3 (lo, hi) pairs) and x theta <= upper (inf = none)."""
    x = np.asarray(x, dtype=float)
    y = np.asarray(y, dtype=float)
    if x.ndim != 2 or x.shape[0] != y.shape[0] or x.shape[0] == 0:
        raise ValueError(f"need n >= 1 rows of 3 columns and n targets, got x {x.shape}, y {y.shape}")
    scale = _scales(x)
    xs = x / scale
    lo = np.array([b[0] for b in bounds], dtype=float) * scale
    hi = np.array([b[1] for b in bounds], dtype=float) * scale
    if upper is None:
        rows, rhs = np.zeros((0, x.shape[1])), np.zeros(0)
    else:
        upper = np.asarray(upper, dtype=float)
        finite = np.isfinite(upper)
        rows, rhs = xs[finite], upper[finite]
    dropped = 0
    if len(rhs) and np.all(rows >= 0.0) and np.all(np.isfinite(lo)):
        alone = rows @ lo <= rhs + 1e-12 * np.maximum(1.0, np.abs(rhs))
        dropped = int(np.count_nonzero(~alone))
        rows, rhs = rows[alone], rhs[alone]
    solver = _sae_lp if gof == "sae" else _rmse_lsi
    phi = solver(xs, y, lo, hi, rows, rhs)
    if phi is None and len(rhs):  # general rows (negative entries): drop them all
        phi, dropped = solver(xs, y, lo, hi, rows[:0], rhs[:0]), dropped + len(rhs)
    if phi is None:  # only with inconsistent bounds, which WindowConfig refuses
        raise RuntimeError("window fit: bounds admit no solution")
    phi = np.clip(phi, lo, hi)
    theta = phi / scale
    return Solution(theta, objective(x, y, theta, gof), dropped, "highs-lp" if gof == "sae" else "lsi-nnls")


def _sae_lp(xs, y, lo, hi, rows, rhs):
    """SAE as the dual linear programme of least absolute deviations (3 equality rows whatever the window).

    Primal: min sum |y - X phi| s.t. G phi <= h, lo <= phi <= hi. Dual: max y.d - h.mu + lo.c+ - hi.c-
    s.t. -X^T d + G^T mu - c+ + c- = 0, -1 <= d <= 1, mu, c+, c- >= 0. The primal phi is the multiplier
    of the dual's equality rows (HiGHS returns it as their marginals); strong duality makes the two
    objectives equal, which the tests check against an enumeration of the primal's vertices.
    """
    n, p = xs.shape
    m = len(rhs)
    cost = -np.concatenate([y, -rhs, np.where(np.isfinite(lo), lo, 0.0), -np.where(np.isfinite(hi), hi, 0.0)])
    a_eq = np.hstack([-xs.T, rows.T, -np.eye(p), np.eye(p)])
    var_bounds = np.zeros((n + m + 2 * p, 2))
    var_bounds[:n] = (-1.0, 1.0)
    var_bounds[n:, 1] = np.inf
    var_bounds[n + m : n + m + p, 1] = np.where(np.isfinite(lo), np.inf, 0.0)  # no lower bound: c+ = 0
    var_bounds[n + m + p :, 1] = np.where(np.isfinite(hi), np.inf, 0.0)
    result = linprog(cost, A_eq=a_eq, b_eq=np.zeros(p), bounds=var_bounds, method="highs")
    if result.status == 3:  # the dual (always feasible: all zero) is unbounded <=> the primal is infeasible
        return None
    if result.status != 0:
        return _sae_primal(xs, y, lo, hi, rows, rhs)
    return np.asarray(result.eqlin.marginals, dtype=float)


def _sae_primal(xs, y, lo, hi, rows, rhs):
    """The primal LP (fallback when the dual run reports a numerical problem)."""
    n, p = xs.shape
    eye = np.eye(n)
    a_ub = np.vstack(
        [
            np.hstack([-xs, -eye]),  # y - x phi <= t
            np.hstack([xs, -eye]),  # x phi - y <= t
            np.hstack([rows, np.zeros((len(rows), n))]),
        ]
    )
    b_ub = np.concatenate([-y, y, rhs])
    cost = np.concatenate([np.zeros(p), np.ones(n)])
    var_bounds = np.vstack([np.column_stack([lo, hi]), np.column_stack([np.zeros(n), np.full(n, np.inf)])])
    result = linprog(cost, A_ub=a_ub, b_ub=b_ub, bounds=var_bounds, method="highs")
    return result.x[:p] if result.status == 0 else None


def _rmse_lsi(xs, y, lo, hi, rows, rhs):
    """min ||xs phi - y|| s.t. rows phi <= rhs, lo <= phi <= hi.

    First the bounded least squares alone (scipy's BVLS, exact and indifferent to rank deficiency): if
    it satisfies the eq. 6/7 rows it is the optimum (the optimum of a relaxation that is feasible).
    Otherwise the LSI problem by Lawson & Hanson's reduction LSI -> LDP -> NNLS (1974, ch. 23).
    """
    n, p = xs.shape
    if np.all(np.isfinite(lo)) and np.all(np.isfinite(hi)):
        # max_iter: scipy's default for BVLS is the number of variables, and it stops there (status 0)
        result = lsq_linear(xs, y, bounds=(lo, hi), method="bvls", tol=1e-13, max_iter=100)
        phi = result.x
        converged = result.status > 0
        if converged and (len(rhs) == 0 or np.all(rows @ phi <= rhs + 1e-12 * np.maximum(1.0, np.abs(rhs)))):
            return phi
    sv = np.linalg.svd(xs, compute_uv=False)
    if n < p or sv[-1] < 1e-7 * sv[0]:  # (near) rank deficient: a small ridge makes the problem strictly convex
        ridge = 1e-7 * sv[0]
        xs = np.vstack([xs, ridge * np.eye(p)])
        y = np.concatenate([y, np.zeros(p)])
    q, r = np.linalg.qr(xs)
    r_inv = np.linalg.inv(r)
    phi_ls = r_inv @ (q.T @ y)
    g = np.vstack([np.eye(p)[np.isfinite(hi)], -np.eye(p)[np.isfinite(lo)], rows])
    h = np.concatenate([hi[np.isfinite(hi)], -lo[np.isfinite(lo)], rhs])
    slack = h - g @ phi_ls
    if np.all(slack >= 0.0):
        return phi_ls
    # z = r phi - q^T y;  g phi <= h  <=>  (-g r^-1) z >= g phi_ls - h ;  LDP: min ||z|| s.t. e z >= f
    e = -g @ r_inv
    f = -slack
    norm = np.maximum(np.linalg.norm(e, axis=1), 1e-300)  # row scaling does not change the feasible set
    e, f = e / norm[:, None], f / norm
    m = np.vstack([e.T, f[None, :]])
    target = np.zeros(p + 1)
    target[-1] = 1.0
    u, _ = nnls(m, target, maxiter=50 * (len(f) + p + 1))
    resid = m @ u - target
    if abs(resid[-1]) < 1e-12 or np.linalg.norm(resid) < 1e-12:
        return None  # constraints inconsistent
    z = -resid[:p] / resid[-1]
    return r_inv @ (z + q.T @ y)


def multistart(x, y, bounds, upper=None, gof: str = "sae", starts: int = 40, rng=None) -> Solution:
    """The paper's reference: gradient-based local solver (SLSQP) from ``starts`` random points in the bounds.

    De Martinis & Corman use MATLAB's MultiStart with 40 random starting points; this is its scipy
    counterpart, run in the same scaled variables as the exact solvers.
    """
    rng = np.random.default_rng(rng)
    x = np.asarray(x, dtype=float)
    y = np.asarray(y, dtype=float)
    scale = _scales(x)
    xs = x / scale
    lo = np.array([b[0] for b in bounds], dtype=float) * scale
    hi = np.array([b[1] for b in bounds], dtype=float) * scale
    constraints = []
    if upper is not None:
        upper = np.asarray(upper, dtype=float)
        finite = np.isfinite(upper)
        rows, rhs = xs[finite], upper[finite]
        if len(rhs):
            constraints = [{"type": "ineq", "fun": lambda phi: rhs - rows @ phi, "jac": lambda phi: -rows}]

    if gof == "sae":

        def fun(phi):
            e = y - xs @ phi
            return float(np.abs(e).sum()), -(xs.T @ np.sign(e))
    else:

        def fun(phi):
            e = y - xs @ phi
            value = float(np.sqrt(np.mean(e * e)))
            return value, -(xs.T @ e) / (len(e) * max(value, 1e-300))

    best_phi, best_value = None, np.inf
    for _ in range(starts):
        start = rng.uniform(lo, hi)
        result = minimize(fun, start, jac=True, method="SLSQP", bounds=list(zip(lo, hi)), constraints=constraints)
        phi = np.clip(result.x, lo, hi)
        feasible = not constraints or np.all(rows @ phi <= rhs + 1e-9)
        value = fun(phi)[0]
        if feasible and value < best_value:
            best_phi, best_value = phi, value
    if best_phi is None:
        return Solution(np.full(3, np.nan), np.inf, 0, "multistart-slsqp")
    theta = best_phi / scale
    return Solution(theta, objective(x, y, theta, gof), 0, "multistart-slsqp")
