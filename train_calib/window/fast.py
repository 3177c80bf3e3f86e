"""The streaming calibrator's fast path for RMSE: the window's fit from the 4 x 4 QR factor of [x y].

Least squares depends on the rows only through R, the triangular factor of [x y] (one LAPACK call on
n x 4; Householder QR is invariant to column scaling, so R's columns are scaled afterwards, to unit
root mean square): ||x theta - y||^2 = ||R3 phi - c||^2 + rho^2 with phi = theta * scale, which gives
the GoF without another pass over the rows. The bounded problem in three variables is then solved
exactly by the KKT conditions of its active sets (each variable free, at its lower or at its upper
bound), the last window's active set tried first; if the result violates an eq. 6/7 row, by the reference's own
Lawson & Hanson reduction LSI -> LDP -> NNLS on R3. The condition number and the standard errors
come from R3 too. No sums are carried from window to window (no cancellation over long runs).

Whatever this path does not cover is left to the reference (``fit_design``: the same results by
construction): SAE, fewer than 4 rows, infinite bounds, negative design entries, a condition number
above ``MAX_CONDITION`` (near rank deficiency: the exact solution is not unique, the reference picks
one), or any numerical doubt. Agreement with the reference: test/window/test_window_fast.py.

The path runs in C (``_kernel.c``: the same QR, active sets, condition number, LSI and standard errors
in the same order of operations, no interpreter per step); the windows it leaves (the cases above, or
inconsistent eq. 6/7 rows) take the Python path below, which is also the whole path where the package
was installed without a C compiler. Agreement of the two: test/window/test_window_kernel.py.
"""

from __future__ import annotations

import math
from itertools import product

import numpy as np
from scipy.linalg import lapack
from scipy.optimize import nnls

from ..physics import KMH
from ..train import TrainSpec
from .config import WindowConfig
from .fit import WindowFit, fit_design, ill_posed_why, make_fit
from .model import StepModel

MAX_CONDITION = 1e6
"""Above this scaled condition number the window goes to the reference solver (never published at the defaults)."""

Pattern = tuple[int, int, int]
"""Active set of the bounds: per variable -1 at the lower bound, 0 free, 1 at the upper bound."""

PATTERNS: tuple[Pattern, ...] = tuple(product((0, -1, 1), repeat=3))  # type: ignore[assignment]
CODES = {p: 9 * (p[0] + 1) + 3 * (p[1] + 1) + (p[2] + 1) for p in PATTERNS}
"""The kernel's code of each active set."""
PATTERNS_BY_CODE = {code: p for p, code in CODES.items()}

try:
    from . import _kernel  # the C kernel of this path (setup.py builds it where a C compiler is found)
except ImportError:  # pragma: no cover - built without a compiler: the Python path alone
    _kernel = None

KERNEL_AVAILABLE = _kernel is not None


class FastFit:
    """Fit of one window of rows for a (train, config); ``reference`` counts the windows left to fit_design."""

    def __init__(self, train: TrainSpec, config: WindowConfig, compiled: bool = True) -> None:
        self.train, self.config = train, config
        bounds = config.specific_bounds
        self.lo = [b[0] for b in bounds]
        self.hi = [b[1] for b in bounds]
        self.enabled = config.gof == "rmse" and all(math.isfinite(b) for b in self.lo + self.hi)
        self.lo_zero = all(b == 0.0 for b in self.lo)
        speeds = np.asarray(config.reference_speeds_kmh, dtype=float) * KMH
        self.speeds = speeds.tolist()
        self.davis = np.asarray(train.davis(speeds), dtype=float).tolist()
        self.pattern: Pattern = (0, 0, 0)
        # compiled: the window's numbers by the C kernel (status 1 there: by _numbers, as without it)
        self.compiled = compiled and KERNEL_AVAILABLE and self.enabled
        self._params = np.array([*self.lo, *self.hi, MAX_CONDITION, len(self.speeds), *self.speeds, *self.davis])
        self.reference = 0
        self.kernel_windows = 0  # windows fitted by the C kernel
        self.constrained = 0  # windows solved by the LDP (an eq. 6/7 row binds)

    def __call__(
        self,
        xy: np.ndarray,
        upper: np.ndarray,
        upper_tol: np.ndarray,
        v: np.ndarray,
        regime: int,
        *,
        stamp_ns: int,
        run_id: int,
        previous: WindowFit | None,
        nonnegative: bool = True,
        below_zero: int | None = None,
        span: float | None = None,
    ) -> WindowFit:
        """The rows used: xy (n, 4) = [x y], upper (N/kg), upper_tol = upper + 1e-12 max(1, |upper|), v (m/s).

        x's first column is 1 and its second v (as StepModel.row gives them). nonnegative: every entry of x is
        >= 0 (the caller knows it from the rows); below_zero: the number of rows with upper_tol < 0, span:
        max(v) - min(v), if the caller keeps them (else computed here).
        """
        context = {"stamp_ns": stamp_ns, "run_id": run_id, "previous": previous}
        return self._fit_arrays(xy, upper, upper_tol, v, regime, context, nonnegative, below_zero, span, self.compiled)

    def _fit_arrays(self, xy, upper, upper_tol, v, regime, context, nonnegative, below_zero, span, kernel) -> WindowFit:
        """__call__'s fit; kernel: try the C kernel on the arrays first."""
        use_fast = self.enabled and nonnegative
        fit = self._fast(xy, upper, upper_tol, v, regime, context, below_zero, span, kernel) if use_fast else None
        if fit is None:
            self.reference += 1
            fit = fit_design(xy[:, :3], xy[:, 3], upper, v, regime, self.train, self.config, **context)
        return fit

    def new_window(self, step: StepModel):
        """The C kernel's Window for the streaming calibrator (None: no kernel, or this config is not for it)."""
        return _kernel.Window(self._params, step.params(_kernel.STEP_PARAM_NAMES)) if self.compiled else None

    def fit_window(self, window, context: dict) -> WindowFit:
        """The fit of a streaming window: the kernel's Window (fitted in place) or calibrator._PyWindow.

        A window the kernel leaves goes to the Python path without the kernel again (same rows, same answer)."""
        if self.compiled:
            *numbers, n, span, regime = window.fit(CODES[self.pattern])
            numbers = self._kernel_numbers(numbers)
            if numbers is not None:
                return self._result(numbers, n, span, regime, context)
            xy, upper, upper_tol = (np.frombuffer(b) for b in window.view())
            xy = xy.reshape(-1, 4)
            v = xy[:, 1]
        else:
            xy, upper, upper_tol, v = window.arrays()
            span, regime = window.speed_span, window.regime
        return self._fit_arrays(xy, upper, upper_tol, v, regime, context, not window.negatives, window.below_zero,
                                span, kernel=False)  # fmt: skip

    def _fast(self, xy, upper, upper_tol, v, regime, context, below_zero, span, kernel) -> WindowFit | None:
        numbers = self._compiled(xy, upper, upper_tol, below_zero) if kernel else None
        if numbers is None:
            numbers = self._numbers(xy, upper, upper_tol, below_zero)
            if numbers is None:
                return None
        if span is None:
            span = float(v.max() - v.min())
        return self._result(numbers, len(v), span, regime, context)

    def _result(self, numbers, n: int, span: float, regime: int, context: dict) -> WindowFit:
        """The WindowFit of the window's numbers (see _numbers), n rows, speed span (m/s), dominant regime."""
        condition, theta0, theta1, theta2, squares, relative_error, mean_speed, dropped = numbers
        why = ill_posed_why(n, span, condition, self.config, relative_error)
        return make_fit(self.train, self.config, n=n, regime=regime, span=span, mean_speed=mean_speed,
                        condition=condition, estimate=(theta0, theta1, theta2), objective=math.sqrt(squares / n),
                        relative_error=relative_error, dropped=dropped, why=why, **context)  # fmt: skip

    def _compiled(self, xy, upper, upper_tol, below_zero) -> list | None:
        """The window's numbers by the C kernel; None where it leaves the window to :meth:`_numbers`."""
        try:
            out = _kernel.fit(xy, upper, upper_tol, self._params, CODES[self.pattern],
                              -1 if below_zero is None else below_zero)  # fmt: skip
        except (BufferError, TypeError, ValueError):  # not C-contiguous float64 arrays: the Python path takes them
            return None
        return self._kernel_numbers(out)

    def _kernel_numbers(self, out) -> list | None:
        """The kernel's (status, pattern, constrained, numbers...) -> the numbers, counted; None: status 1."""
        status, code, constrained, *numbers = out
        if status:
            return None
        self.kernel_windows += 1
        self.constrained += constrained
        self.pattern = PATTERNS_BY_CODE[code]
        return numbers

    def _numbers(self, xy, upper, upper_tol, below_zero) -> tuple | None:
        """(condition, theta0, theta1, theta2, squares, relative_error, mean_speed, dropped) of the window, N/kg units.

        squares = ||x theta - y||^2; None: the window goes to the reference solver.
        """
        n = len(xy)
        if n < 4:
            return None
        qr, _, _, info = lapack.dgeqrf(xy)  # Householder QR is column-scaling invariant: scale R, not x
        if info != 0:
            return None
        (r00, r01, r02, c0), (_, r11, r12, c1), (_, _, r22, c2), (_, _, _, rho) = qr[:4, :4].tolist()
        norm1 = math.sqrt(r01 * r01 + r11 * r11)
        norm2 = math.sqrt(r02 * r02 + r12 * r12 + r22 * r22)
        if r00 == 0.0 or norm1 == 0.0 or norm2 == 0.0:
            return None
        root_n = math.sqrt(n)  # columns scaled to unit root mean square: |r00| / sqrt(n) = 1
        s0, s1, s2 = abs(r00) / root_n, norm1 / root_n, norm2 / root_n
        scale = (s0, s1, s2)
        r = [[r00 / s0, r01 / s1, r02 / s2, c0], [0.0, r11 / s1, r12 / s2, c1], [0.0, 0.0, r22 / s2, c2]]
        condition = _scaled_condition(r)
        if not condition <= MAX_CONDITION:
            return None
        x = xy[:, :3]
        lo = [b * s for b, s in zip(self.lo, scale)]
        hi = [b * s for b, s in zip(self.hi, scale)]
        # eq. 6/7 rows that hold at the lower bounds; the others are dropped
        alone = None
        if self.lo_zero:
            dropped = int(np.count_nonzero(upper_tol < 0.0)) if below_zero is None else below_zero
        else:
            alone = x @ self.lo <= upper_tol
            dropped = n - int(np.count_nonzero(alone))
        phi = self._box(r, lo, hi)
        if phi is None:
            return None
        feasible = x @ [p / s for p, s in zip(phi, scale)] <= upper_tol
        if not feasible.all():
            if dropped and alone is None:
                alone = upper_tol >= 0.0
            if not (dropped and np.all(feasible, where=alone)):
                self.constrained += 1
                use = np.isfinite(upper) if alone is None else alone & np.isfinite(upper)
                phi = _lsi(r, lo, hi, x[use] / scale, upper[use])
                if phi is None:
                    return None
                phi = _clip(phi, lo, hi)
        theta = [p / s for p, s in zip(phi, scale)]
        # ||x theta - y||^2 = ||R3 phi - c||^2 + rho^2 (the residual of the rows orthogonal to the columns)
        (a0, a1, a2, _), (_, b1, b2, _), (_, _, d2, _) = r
        f0, f1, f2 = phi
        e0, e1, e2 = a0 * f0 + a1 * f1 + a2 * f2 - c0, b1 * f1 + b2 * f2 - c1, d2 * f2 - c2
        squares = e0 * e0 + e1 * e1 + e2 * e2 + rho * rho
        relative_error = self._relative_error(r, scale, math.sqrt(squares / (n - 3)))
        # R's first row is q0^T [x y] with q0 = -+ ones / sqrt(n) (the first column of x is 1): r01 / r00 = mean(v)
        return condition, theta[0], theta[1], theta[2], squares, relative_error, r01 / r00, dropped

    def _box(self, r, lo, hi) -> list[float] | None:
        """min ||R3 phi - c|| over lo <= phi <= hi (scaled variables): the active set meeting the KKT conditions.

        From the last window's active set, each miss corrected (a free variable out of its bounds fixed
        at the bound it crosses, a bound with the gradient pointing inwards freed); every active set if
        that cycles.
        """
        current, tried = self.pattern, set()
        while current not in tried:
            tried.add(current)
            phi = _solve(r, current, lo, hi)
            if phi is None:
                break
            corrected = _kkt(r, phi, current, lo, hi)
            if corrected is None:
                self.pattern = current
                return _clip(phi, lo, hi)
            current = corrected
        for pattern in PATTERNS:
            if pattern in tried:
                continue
            phi = _solve(r, pattern, lo, hi)
            if phi is not None and _kkt(r, phi, pattern, lo, hi) is None:
                self.pattern = pattern
                return _clip(phi, lo, hi)
        return None

    def _relative_error(self, r, scale, sigma: float) -> float:
        """max over the reference speeds of the standard error of r(v) / the train file's r(v) (as the reference)."""
        if not self.speeds:
            return 0.0
        (r00, r01, r02, _), (_, r11, r12, _), (_, _, r22, _) = r[0], r[1], r[2]
        d0 = 1.0  # |diagonal| / column norm of the column-normalised R3
        d1 = abs(r11) / math.sqrt(r01 * r01 + r11 * r11)
        d2 = abs(r22) / math.sqrt(r02 * r02 + r12 * r12 + r22 * r22)
        if min(d0, d1, d2) <= 1e-12 * max(d0, d1, d2):
            return math.inf
        worst = -math.inf
        for speed, davis in zip(self.speeds, self.davis):
            w0 = 1.0 / scale[0] / r00  # R3^T w = (1, v, v^2) / scale, forward substitution
            w1 = (speed / scale[1] - r01 * w0) / r11
            w2 = (speed * speed / scale[2] - r02 * w0 - r12 * w1) / r22
            se = sigma * math.sqrt(w0 * w0 + w1 * w1 + w2 * w2)
            ratio = se / davis if davis != 0.0 else (math.inf if se > 0.0 else math.nan)
            if math.isnan(ratio):
                return math.nan
            worst = max(worst, ratio)
        return worst


def _scaled_condition(r) -> float:
    """2-norm condition number of R3 with unit columns B (= that of x with unit columns, Belsley's).

    From the eigenvalues l1 >= l2 >= l3 of G = B^T B (unit diagonal): l1 in closed form (the trigonometric
    solution of the cubic, accurate to round-off for the largest), then l2 + l3 = 3 - l1 and l2 l3 = det(B)^2 / l1
    (det B = the product of the diagonal: no cancellation), so l3 is as accurate as l2, to eps l1 / l2. Where
    that bound or the closed form's own (l1 near l2) is loose, the singular values by LAPACK (dgesdd).
    """
    (r00, r01, r02, _), (_, r11, r12, _), (_, _, r22, _) = r[0], r[1], r[2]
    n0 = abs(r00)
    n1 = math.sqrt(r01 * r01 + r11 * r11)
    n2 = math.sqrt(r02 * r02 + r12 * r12 + r22 * r22)
    if n0 == 0.0 or n1 == 0.0 or n2 == 0.0:
        return math.inf
    b01, b11, b02, b12, b22 = r01 / n1, r11 / n1, r02 / n2, r12 / n2, r22 / n2
    sign = 1.0 if r00 > 0.0 else -1.0  # B's first column is (sign, 0, 0)
    g01, g02, g12 = sign * b01, sign * b02, b01 * b02 + b11 * b12  # the off-diagonal of G
    det2 = (b11 * b22) ** 2  # det(G) = det(B)^2
    p2 = (g01 * g01 + g02 * g02 + g12 * g12) / 3.0
    if p2 > 0.0 and det2 > 0.0:
        p = math.sqrt(p2)
        q = g01 * g02 * g12 / (p2 * p)  # det((G - I) / p) / 2
        l1 = 1.0 + 2.0 * p * math.cos(math.acos(-1.0 if q < -1.0 else 1.0 if q > 1.0 else q) / 3.0)
        rest = 3.0 - l1  # l2 + l3
        disc = rest * rest - 4.0 * det2 / l1
        l2 = 0.5 * (rest + math.sqrt(disc if disc > 0.0 else 0.0))
        if 1e-4 * l1 <= l2 <= 0.5 * l1:
            return math.sqrt(l1 * l2 / det2 * l1)  # sqrt(l1 / l3), l3 = det2 / (l1 l2)
    b = np.array(((sign, b01, b02), (0.0, b11, b12), (0.0, 0.0, b22)))
    _, sv, _, info = lapack.dgesdd(b, compute_uv=0)
    if info != 0:
        return math.nan
    return float(sv[0] / sv[2]) if sv[2] > 0.0 else math.inf


def _solve(r, pattern: Pattern, lo, hi) -> list[float] | None:
    """Least squares of R3 phi = c with the variables of the pattern fixed at their bounds (None: singular)."""
    (r00, r01, r02, c0), (_, r11, r12, c1), (_, _, r22, c2) = r[0], r[1], r[2]
    p0, p1, p2 = pattern
    if not (p0 or p1 or p2):  # all free: back substitution
        if r00 == 0.0 or r11 == 0.0 or r22 == 0.0:
            return None
        x2 = c2 / r22
        x1 = (c1 - r12 * x2) / r11
        return [(c0 - r01 * x1 - r02 * x2) / r00, x1, x2]
    phi = [lo[j] if p < 0 else hi[j] if p > 0 else 0.0 for j, p in enumerate(pattern)]
    f0, f1, f2 = (0.0 if p0 == 0 else phi[0]), (0.0 if p1 == 0 else phi[1]), (0.0 if p2 == 0 else phi[2])
    d = (c0 - r00 * f0 - r01 * f1 - r02 * f2, c1 - r11 * f1 - r12 * f2, c2 - r22 * f2)
    columns = [column for column, p in zip(((r00, 0.0, 0.0), (r01, r11, 0.0), (r02, r12, r22)), pattern) if not p]
    values = _lstsq(columns, d)
    if values is None:
        return None
    free = iter(values)
    return [next(free) if not p else value for p, value in zip(pattern, phi)]


def _lstsq(columns, d) -> list[float] | None:
    """Least squares with no, one or two columns of length 3, by modified Gram-Schmidt on [columns d]."""
    if not columns:
        return []
    (a0, a1, a2), (d0, d1, d2) = columns[0], d
    r11 = math.sqrt(a0 * a0 + a1 * a1 + a2 * a2)
    if r11 == 0.0:
        return None
    q0, q1, q2 = a0 / r11, a1 / r11, a2 / r11
    e1 = q0 * d0 + q1 * d1 + q2 * d2
    if len(columns) == 1:
        return [e1 / r11]
    b0, b1, b2 = columns[1]
    r12 = q0 * b0 + q1 * b1 + q2 * b2
    b0, b1, b2 = b0 - r12 * q0, b1 - r12 * q1, b2 - r12 * q2
    r22 = math.sqrt(b0 * b0 + b1 * b1 + b2 * b2)
    if r22 <= 1e-14 * r11:
        return None
    e2 = (b0 * (d0 - e1 * q0) + b1 * (d1 - e1 * q1) + b2 * (d2 - e1 * q2)) / r22
    x2 = e2 / r22
    return [(e1 - r12 * x2) / r11, x2]


def _kkt(r, phi, pattern: Pattern, lo, hi) -> Pattern | None:
    """None if phi meets the KKT conditions of the bounded problem with this active set, else the corrected set.

    Free variables must lie within their bounds (to 1e-12 of the range), the gradient of a variable at
    a bound must point out of the box (to round-off).
    """
    (r00, r01, r02, c0), (_, r11, r12, c1), (_, _, r22, c2) = r[0], r[1], r[2]
    x0, x1, x2 = phi
    e0 = r00 * x0 + r01 * x1 + r02 * x2 - c0  # residual R3 phi - c
    e1 = r11 * x1 + r12 * x2 - c1
    e2 = r22 * x2 - c2
    size = math.sqrt(c0 * c0 + c1 * c1 + c2 * c2) + abs(r00 * x0) + abs(r01 * x1) + abs(r02 * x2)
    size += abs(r11 * x1) + abs(r12 * x2) + abs(r22 * x2)  # scale of the residual's terms, for the round-off
    corrected, ok = list(pattern), True
    for j, p in enumerate(pattern):
        if p == 0:
            margin = 1e-12 * (hi[j] - lo[j])
            if phi[j] < lo[j] - margin:
                corrected[j], ok = -1, False
            elif phi[j] > hi[j] + margin:
                corrected[j], ok = 1, False
            continue
        if j == 0:
            gradient, norm = r00 * e0, abs(r00)
        elif j == 1:
            gradient, norm = r01 * e0 + r11 * e1, math.sqrt(r01 * r01 + r11 * r11)
        else:
            gradient, norm = r02 * e0 + r12 * e1 + r22 * e2, math.sqrt(r02 * r02 + r12 * r12 + r22 * r22)
        tolerance = 1e-12 * norm * size
        if (p < 0 and gradient < -tolerance) or (p > 0 and gradient > tolerance):
            corrected[j], ok = 0, False
    return None if ok else (corrected[0], corrected[1], corrected[2])


def _clip(phi, lo, hi) -> list[float]:
    return [min(max(p, low), high) for p, low, high in zip(phi, lo, hi)]


_BOUND_ROWS = np.vstack([np.eye(3), -np.eye(3)])
_TARGET = np.array([0.0, 0.0, 0.0, 1.0])


def _lsi(r, lo, hi, rows: np.ndarray, rhs: np.ndarray) -> list[float] | None:
    """min ||R3 phi - c|| s.t. rows phi <= rhs, lo <= phi <= hi: solvers._rmse_lsi's LSI -> LDP -> NNLS on R3.

    None where the reference would take another branch (its ridge for near rank deficiency) or the
    constraints are inconsistent.
    """
    (r00, r01, r02, c0), (_, r11, r12, c1), (_, _, r22, c2) = r[0], r[1], r[2]
    r3 = np.array(((r00, r01, r02), (0.0, r11, r12), (0.0, 0.0, r22)))
    _, sv, _, info = lapack.dgesdd(r3, compute_uv=0)
    if info != 0 or sv[2] < 2e-7 * sv[0]:  # the reference adds a ridge below 1e-7: leave it these windows
        return None
    r_inv = np.linalg.inv(r3)
    c = np.array((c0, c1, c2))
    phi_ls = r_inv @ c
    g = np.vstack((_BOUND_ROWS, rows))
    h = np.concatenate((hi, [-b for b in lo], rhs))
    slack = h - g @ phi_ls
    if (slack >= 0.0).all():
        return phi_ls.tolist()
    e = g @ r_inv
    norm = np.maximum(np.sqrt((e * e).sum(axis=1)), 1e-300)
    m = np.empty((4, len(slack)))
    m[:3] = e.T
    m[:3] /= -norm
    m[3] = slack
    m[3] /= -norm
    u, _ = nnls(m, _TARGET, maxiter=50 * (len(slack) + 4))
    resid = m @ u - _TARGET
    if abs(resid[3]) < 1e-12 or np.linalg.norm(resid) < 1e-12:
        return None
    z = -resid[:3] / resid[3]
    return (r_inv @ (z + c)).tolist()
