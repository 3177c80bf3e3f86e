"""The resistance at each window's mean speed, and the run's windows pooled into r(v) with its covariance.

A 60 s window driven at near-constant speed cannot separate r0, r1, r2 (ill-posed), but it measures the
resistance at its own speed well whenever the effort is known: under measured traction power, cruising and
coasting. Averaged over the window's rows (N/kg of effective mass, see :mod:`.model`),

    mean(y) = mean(x) . theta + mean(e),     y_k = f_k - g_k - a_k,   x_k = (1, v_k, v_k^2 (1 + f_tun tau_k))

and the mean of the differenced speed telescopes, sum_k a_k dt = v_last - v_first per run of consecutive rows,
so the speed noise enters the window's equation through the two ends of each such run only (its variance is
2 v_variance / T^2 per run of rows instead of 2 v_variance / dt^2 per row). That makes one equation per window
that is well posed with 1 km/h speeds too.

Rows used (:class:`WindowEquations`): the window's rows as the fit takes them (braking steps left out), without
the steps whose power shows regeneration: the electric brake is measured, the blended mechanical brake is not
(80 % electric on the simulator's trains), so those steps would be biased.

Variance of a window's equation (N/kg)^2: the speed ends above, plus (``power_noise`` f_k)^2 per row (power
meter noise, 1 % relative), plus the square of a bound on the bias from the power and speed stamps being up to
half a sample period apart (|mean(f / v)| |mean(a)| dt / 2: dominant at a departure, negligible in cruise), plus
the square of a bound on the effort changes the rows miss between two samples (the row holds the force of its first
sample; the switch between traction and coasting falls anywhere in the step, and power and speed stamps differ):
0.5 |sum of the changes of f within the runs of rows| / n, which telescopes to the runs' ends.

Pooling (:class:`PooledResistance`): the windows that do not overlap (each sample counted once) are the rows of
a weighted least squares with the train file's prior, theta ~ N(r, (0.18)^2 r r^T + diag((0.10 r_i)^2)), so
the estimate is defined when the speeds span little and stays at the prior without data. The weights are made
robust (Huber, 4 sigma) and the data's covariance is scaled by the reduced chi-square of the windows about the
estimate when it exceeds 1 (Birge ratio), so that the published covariance covers the noise the model of the
variances misses. docs/window.md gives the measured accuracy and coverage.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from ..physics import KMH
from ..train import Davis

PRIOR_COMMON = 0.18
"""Prior: relative standard deviation of the train file's r(v) as a whole (common factor)."""
PRIOR_EACH = 0.10
"""Prior: relative standard deviation of each coefficient on its own."""
PRIOR_REFERENCE_SPEED = 80.0 * KMH
"""A coefficient that is zero in the train file gets 0.05 r(v_ref) / v_ref^i as its own sigma (v_ref in m/s)."""
POWER_NOISE = 0.01
"""Relative noise of the measured tractive force per row (the pantograph power meter)."""
HUBER = 4.0
"""Windows further than this many sigma from the pooled r(v) are down-weighted (Huber)."""
MIN_ROWS = 8
"""A window's equation needs at least this many rows (its resistance is NaN below)."""

_SUMS = 9  # n, x1, x2, y, f/v, a, f^2, starts of runs of rows, change of f within runs of rows
SWITCH = 0.5
"""Bound on the share of an effort change the window's mean misses, per unit of the net change of f over its runs
of rows: the row holds f of its first sample (forward difference) and power and speed stamps differ."""


def prior_covariance(davis: Davis | tuple[float, float, float]) -> np.ndarray:
    """(0.18)^2 r r^T + diag((0.10 r_i)^2) of the train file's coefficients r, N/kg units (3 x 3).

    A zero coefficient (e.g. r1 = 0 in a train file) gets 0.05 r(80 km/h) / (80 km/h)^i as its own sigma, so the
    matrix is positive definite."""
    r = np.asarray(davis.as_tuple() if isinstance(davis, Davis) else davis, dtype=float)
    scale = np.array([1.0, PRIOR_REFERENCE_SPEED, PRIOR_REFERENCE_SPEED**2])
    floor = 0.05 * float(r @ scale) / scale
    own = np.where(r != 0.0, PRIOR_EACH * np.abs(r), floor)
    return PRIOR_COMMON**2 * np.outer(r, r) + np.diag(own**2)


@dataclass(slots=True)
class WindowEquation:
    """One window as an equation in (r0, r1, r2): mean_y = mean_x . theta, with its variance.

    mean_x: (1, mean v, mean v^2 (1 + f_tun tau)) over the rows, m/s and (m/s)^2; mean_y N/kg; variance (N/kg)^2.
    A plain record (slots, not frozen: one is made per sample, and a frozen dataclass takes longer to build).
    """

    start_ns: int  # end of the oldest step in the window, ns
    stamp_ns: int  # end of the newest step, ns
    rows: int
    mean_x: tuple[float, float, float]
    mean_y: float
    variance: float

    @property
    def mean_speed(self) -> float:
        """Mean speed of the rows, m/s."""
        return self.mean_x[1]

    def resistance_at_mean_speed(self, r2: float, r2_std: float, scale: float = 1.0) -> tuple[float, float]:
        """Open-air r(mean v) and its sigma, N/kg, given r2 and its sigma (N/(kg (m/s)^2)) for the spread of v^2.

        mean(r(v_k)) = r(mean v) + r2 (mean(v^2 (1 + f_tun tau)) - mean(v)^2): the second term is taken from r2
        (the train file's), its uncertainty added to the variance; scale multiplies the equation's own variance
        (the pooled reduced chi-square, :attr:`PooledResistance.scale`)."""
        spread = self.mean_x[2] - self.mean_x[1] * self.mean_x[1]
        value = self.mean_y - r2 * spread
        return value, math.sqrt(scale * self.variance + (r2_std * spread) ** 2)


class WindowEquations:
    """Running sums of the window's rows with measured effort, per step: the window's equation at any time.

    ``push`` takes each step of the streaming window (its row as StepModel.row gives it, or None), whether the fit
    keeps it and whether its power shows regeneration; ``expire`` drops the steps ending at or before a time;
    ``equation`` gives the window's equation. Prefix sums in a deque (O(1) per step, no pass over the window).
    """

    def __init__(self, sample_period: float = 1.0) -> None:
        # (end_ns, prefix sums up to that step, the step is a row continuing a run of rows)
        self._cum: deque[tuple[int, tuple[float, ...], bool]] = deque()
        self._base: tuple[float, ...] = (0.0,) * _SUMS  # prefix sums before the oldest step in the window
        self._total: tuple[float, ...] = (0.0,) * _SUMS
        self._in_run = False  # the last step was a row used here
        self._last_f = 0.0  # its force, N/kg
        self.sample_period = sample_period  # s, the last step's length (half of it bounds the stamp offset)

    def clear(self) -> None:
        self._cum.clear()
        self._base = self._total = (0.0,) * _SUMS
        self._in_run = False

    def push(self, end_ns: int, dt: float, row: tuple[float, ...] | None, use: bool) -> None:
        """A step ending at end_ns (ns) of length dt (s); row: (x0, x1, x2, y, upper, v, a, f) or None; use: a
        row with measured effort (kept by the fit, no regeneration)."""
        if dt > 0.0:
            self.sample_period = dt
        if row is None or not use:
            self._in_run = False
            self._cum.append((end_ns, self._total, False))
            return
        _, x1, x2, y, _, v, a, f = row
        continues = self._in_run
        change = f - self._last_f if continues else 0.0
        self._in_run = True
        self._last_f = f
        n, s1, s2, sy, sfv, sa, sff, runs, sdf = self._total
        self._total = (n + 1.0, s1 + x1, s2 + x2, sy + y, sfv + f / v, sa + a, sff + f * f, runs + (not continues),
                       sdf + change)  # fmt: skip
        self._cum.append((end_ns, self._total, continues))

    def expire(self, min_ns: int) -> None:
        """Drop the steps ending at or before min_ns (ns)."""
        cum = self._cum
        while cum and cum[0][0] <= min_ns:
            self._base = cum.popleft()[1]

    def equation(self, v_variance: float) -> WindowEquation | None:
        """The window's equation (None with fewer than MIN_ROWS rows); v_variance: of one speed sample, (m/s)^2."""
        if not self._cum:
            return None
        n, s1, s2, sy, sfv, sa, sff, runs, sdf = (t - b for t, b in zip(self._total, self._base))
        if n < MIN_ROWS - 0.5:
            return None
        runs += self._cum[0][2]  # a run of rows cut by the window's start: its start is not in the window
        dt = self.sample_period
        span = n * dt
        speed = 2.0 * runs * v_variance / (span * span)
        power = POWER_NOISE * POWER_NOISE * sff / (n * n)
        stamps = abs(sfv / n) * abs(sa / n) * 0.5 * dt
        switch = SWITCH * abs(sdf) / n
        variance = speed + power + stamps * stamps + switch * switch
        start_ns = self._cum[0][0]
        return WindowEquation(start_ns, self._cum[-1][0], round(n), (1.0, s1 / n, s2 / n), sy / n, variance)


class PooledResistance:
    """The run's non-overlapping window equations pooled into r(v) = r0 + r1 v + r2 v^2 with its 3 x 3 covariance.

    ``add`` takes each window's equation and uses it when it starts after the last one used ended (each step
    counted once); the estimate is a weighted least squares with the prior N(prior, prior_cov) (train file's
    values and :func:`prior_covariance`), robust (Huber weights) and with the data's covariance scaled by the
    reduced chi-square when above 1. Without windows: the prior. N/kg units throughout.
    """

    def __init__(self, prior: Davis | tuple[float, float, float], prior_cov: np.ndarray | None = None) -> None:
        self.prior = np.asarray(prior.as_tuple() if isinstance(prior, Davis) else prior, dtype=float)
        self.prior_cov = prior_covariance(tuple(self.prior)) if prior_cov is None else np.asarray(prior_cov, float)
        self._prior_info = np.linalg.inv(self.prior_cov)
        self._prior_b = self._prior_info @ self.prior
        self.equations: list[WindowEquation] = []
        self.estimate = self.prior.copy()
        self.covariance = self.prior_cov.copy()
        self.scale = 1.0  # reduced chi-square applied to the data (>= 1)
        self._ratio = np.ones(0)  # Huber factor of each pooled window (weight / its own 1 / variance)
        self._last_ns: int | None = None
        self._publish()

    def clear(self) -> None:
        """Back to the prior."""
        self.equations.clear()
        self.estimate = self.prior.copy()
        self.covariance = self.prior_cov.copy()
        self.scale = 1.0
        self._ratio = np.ones(0)
        self._last_ns = None
        self._publish()

    def new_run(self) -> None:
        """The streaming window restarted (a new run, whose clock may restart): its windows share no step with
        the ones pooled, whatever their stamps."""
        self._last_ns = None

    @property
    def windows(self) -> int:
        """Windows pooled so far."""
        return len(self.equations)

    def add(self, equation: WindowEquation | None) -> bool:
        """Pool the equation if it does not overlap the last one used; True when it was used (estimate updated)."""
        if equation is None or not math.isfinite(equation.mean_y) or not equation.variance > 0.0:
            return False
        if self._last_ns is not None and equation.start_ns <= self._last_ns:
            return False
        self._last_ns = equation.stamp_ns
        self.equations.append(equation)
        self._solve()
        return True

    def _solve(self, iterations: int = 10) -> None:
        """Iteratively reweighted least squares from the last solution's weights and scale (warm start: one or two
        iterations per new window)."""
        x = np.array([e.mean_x for e in self.equations])
        y = np.array([e.mean_y for e in self.equations])
        w0 = 1.0 / np.array([e.variance for e in self.equations])
        ratio = np.ones(len(y))
        ratio[: len(self._ratio)] = self._ratio  # Huber factors of the windows pooled before
        w = w0 * ratio
        scale = self.scale
        for _ in range(iterations):
            data = (x.T * w) @ x
            info = self._prior_info + data / scale
            theta = np.linalg.solve(info, self._prior_b + (x.T * w) @ y / scale)
            z = (y - x @ theta) * np.sqrt(w0)  # normalised residuals (their own variances)
            effective = float(np.trace(np.linalg.solve(info, data / scale)))  # parameters the data determine
            chi2 = float(z * z @ ratio)
            new_scale = max(1.0, chi2 / max(len(y) - effective, 1.0))
            new_ratio = np.minimum(1.0, HUBER / np.maximum(np.abs(z) / math.sqrt(new_scale), 1e-12))
            done = abs(new_scale - scale) <= 1e-6 * scale and float(np.max(np.abs(new_ratio - ratio))) <= 1e-6
            scale, ratio = new_scale, new_ratio
            w = w0 * ratio
            if done:
                break
        self._ratio = ratio
        data = (x.T * w) @ x
        info = self._prior_info + data / scale
        self.covariance = np.linalg.inv(info)
        self.covariance = 0.5 * (self.covariance + self.covariance.T)
        self.estimate = self.covariance @ (self._prior_b + (x.T * w) @ y / scale)
        self.scale = scale
        self._publish()

    def _publish(self) -> None:
        self.published: tuple[tuple[float, float, float], tuple[float, ...], int] = (
            (float(self.estimate[0]), float(self.estimate[1]), float(self.estimate[2])),
            tuple(self.covariance.ravel().tolist()),
            len(self.equations),
        )
        """(r0, r1, r2), the covariance row-major (9), windows pooled: what a WindowFit carries."""

    def resistance(self, v_ms) -> tuple[np.ndarray, np.ndarray]:
        """Pooled open-air r(v) and its sigma at speeds v (m/s), N/kg."""
        v = np.asarray(v_ms, dtype=float)
        basis = np.stack([np.ones_like(v), v, v * v], axis=-1)
        value = basis @ self.estimate
        sigma = np.sqrt(np.einsum("...i,ij,...j->...", basis, self.covariance, basis))
        return value, sigma


def pooled_summary(
    r: tuple[float, float, float], covariance: tuple[float, ...] | np.ndarray, windows: int
) -> dict[str, object] | None:
    """summary.json's ``window.pooled``: {"r0", "r1", "r2" (N/kg units), "covariance" (3 x 3 nested lists),
    "windows"}; None when r is not finite (a WindowFit or message that carries no pooled r(v))."""
    values = [float(x) for x in r]
    cov = np.asarray(covariance, dtype=float)
    if len(values) != 3 or cov.size != 9 or not all(math.isfinite(x) for x in values):
        return None
    return {"r0": values[0], "r1": values[1], "r2": values[2], "covariance": cov.reshape(3, 3).tolist(),
            "windows": int(windows)}  # fmt: skip
