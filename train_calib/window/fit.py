"""One window: fit A, B, C (their eq. 5 subject to eq. 6-7), judge whether it is well posed, make the result.

The result mirrors train_calib_msgs/msg/WindowResistance: force units for the whole train (A in N,
B in N/(m/s), C in N/(m/s)^2, GoF in N) and the same resistance per unit of effective mass
(r0, r1, r2 = (A, B, C) / (gamma m)).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..physics import KMH
from ..train import TrainSpec
from . import solvers
from .config import WindowConfig
from .model import BRAKING, UNKNOWN, DifferenceRows, difference_rows, regime_from_power, tractive_force

NAN3 = (math.nan, math.nan, math.nan)


@dataclass(slots=True)
class WindowFit:
    """The calibration of one window (fields of WindowResistance.msg first, then diagnostics).

    ``a, b, c, r0, r1, r2`` are the values to publish: this window's estimate when it is well posed,
    otherwise the last well-posed values (NaN before the first). ``estimate`` is always this window's
    own solution (N/kg units), for diagnostics. A plain record like Measurement and EstimateSample (slots,
    not frozen: one is made per sample, and a frozen dataclass takes 8x longer to build).
    """

    stamp_ns: int  # time of the newest sample in the window, ns
    run_id: int
    window_length: float  # s
    sample_count: int  # difference steps used in the fit
    gof_kind: int  # 0 = SAE, 1 = RMSE
    gof_value: float  # N: SAE = sum |E_k|, RMSE = sqrt(mean E_k^2) of this window's estimate
    a: float  # N
    b: float  # N/(m/s)
    c: float  # N/(m/s)^2, open air
    r0: float  # N/kg
    r1: float  # N/(kg m/s)
    r2: float  # N/(kg (m/s)^2)
    regime: int  # dominant regime of the window's steps (DrivingRegime constants)
    ill_posed: bool
    speed_span: float  # max - min speed over the steps used, m/s
    estimate: tuple[float, float, float] = NAN3  # this window's r0, r1, r2, N/kg units
    condition_number: float = math.inf  # of the column-scaled design [1, v, v^2]
    mean_speed: float = math.nan  # m/s
    why: tuple = ()  # why ill posed, unformatted (see ``reason``); () when well posed
    relative_error: float = math.inf  # max standard error of r(v) at the reference speeds / train file r(v)
    dropped_constraints: int = 0  # eq. 6/7 rows infeasible on their own (noise at the envelope), left out
    # the window's resistance at its own speed (pooled.py; the streaming calibrator sets these, NaN otherwise)
    resistance_speed: float = math.nan  # mean speed of the rows with measured effort, m/s
    resistance_at_speed: float = math.nan  # open-air r(resistance_speed), N/kg
    resistance_at_speed_std: float = math.nan  # its sigma, N/kg
    # the run's windows pooled into r(v) (pooled.PooledResistance): N/kg units, covariance 3 x 3 row-major
    pooled: tuple[float, float, float] = NAN3
    pooled_covariance: tuple[float, ...] = ()
    pooled_windows: int = 0  # windows pooled (0: the prior)

    @property
    def reason(self) -> str:
        """Why ill posed ("" when well posed): ``why`` formatted when asked (one window per sample is fitted; its
        text is rarely read, and formatting the numbers cost more than the C kernel's whole fit)."""
        return self.why[0].format(*self.why[1:]) if self.why else ""

    @property
    def pooled_r0(self) -> float:
        """The pooled r0 (WindowResistance.pooled_r0), N/kg."""
        return self.pooled[0]

    @property
    def pooled_r1(self) -> float:
        """The pooled r1, N/(kg m/s)."""
        return self.pooled[1]

    @property
    def pooled_r2(self) -> float:
        """The pooled r2, N/(kg (m/s)^2)."""
        return self.pooled[2]

    @property
    def constraints_relaxed(self) -> bool:
        return self.dropped_constraints > 0

    @property
    def resistance_specific(self) -> tuple[float, float, float]:
        return (self.r0, self.r1, self.r2)

    def resistance(self, v_ms, tunnel_fraction=0.0, tunnel_factor: float = 0.0):
        """Published running resistance r(v), N/kg of effective mass."""
        v = np.asarray(v_ms, dtype=float)
        return self.r0 + self.r1 * v + (1.0 + tunnel_factor * np.asarray(tunnel_fraction)) * self.r2 * v * v


def scaled_condition_number(x: np.ndarray) -> float:
    """2-norm condition number of x with columns scaled to unit length (Belsley's collinearity measure)."""
    if x.shape[0] < x.shape[1]:
        return math.inf
    norms = np.linalg.norm(x, axis=0)
    if np.any(norms == 0.0):
        return math.inf
    sv = np.linalg.svd(x / norms, compute_uv=False)
    return float(sv[0] / sv[-1]) if sv[-1] > 0.0 else math.inf


def resistance_standard_error(x: np.ndarray, residuals: np.ndarray, speeds_ms) -> np.ndarray:
    """Standard error of the fitted open-air r(v) at the speeds, N/kg (inf when the design is singular).

    sigma^2 (X^T X)^-1 propagated to (1, v, v^2), sigma the RMS residual over n - 3 degrees of freedom,
    for both GoFs (a robust scale such as the MAD fails for SAE: the LAD fit interpolates 3 steps
    exactly and quantised speeds repeat, so half the residuals can be 0). Unconstrained,
    least-squares theory: active bounds and constraints make the true error smaller.
    """
    n, p = x.shape
    speeds = np.asarray(speeds_ms, dtype=float)
    if n <= p:
        return np.full(speeds.shape, math.inf)
    scale = np.linalg.norm(x, axis=0)
    if np.any(scale == 0.0):
        return np.full(speeds.shape, math.inf)
    r = np.linalg.qr(x / scale, mode="r")
    diag = np.abs(np.diag(r))
    if diag.min() <= 1e-12 * diag.max():
        return np.full(speeds.shape, math.inf)
    sigma = math.sqrt(float(residuals @ residuals) / (n - p))
    at = np.column_stack([np.ones_like(speeds), speeds, speeds * speeds]) / scale
    w = np.linalg.solve(r.T, at.T)  # R^-T x*
    return sigma * np.linalg.norm(w, axis=0)


def dominant_regime(regimes: np.ndarray) -> int:
    """The most frequent regime; a tie goes to the regime of the newest step among the tied."""
    if len(regimes) == 0:
        return UNKNOWN
    counts = np.bincount(regimes.astype(np.int64), minlength=5)
    tied = np.flatnonzero(counts == counts.max())
    if len(tied) == 1:
        return int(tied[0])
    for r in regimes[::-1]:
        if r in tied:
            return int(r)
    return int(tied[0])  # pragma: no cover


def ill_posed_why(
    n: int, speed_span: float, condition: float, config: WindowConfig, relative_error: float = 0.0
) -> tuple:
    """Why the window cannot separate A, B, C, as (format string, its values); () if it can (WindowFit.reason
    formats it)."""
    if n < config.min_samples:
        return ("{} usable steps < min_samples {}", n, config.min_samples)
    if speed_span < config.min_speed_span:
        return ("speed span {:.2f} m/s < min_speed_span {:g} m/s", speed_span, config.min_speed_span)
    if not condition <= config.max_condition:
        return ("condition number {:.3g} > max_condition {:g}", condition, config.max_condition)
    if not relative_error <= config.max_relative_error:
        return ("relative standard error {:.3g} > max_relative_error {:g}", relative_error, config.max_relative_error)
    return ()


def fit_rows(
    rows: DifferenceRows,
    regimes: np.ndarray,
    train: TrainSpec,
    config: WindowConfig,
    *,
    stamp_ns: int = 0,
    run_id: int = 0,
    previous: WindowFit | None = None,
) -> WindowFit:
    """Fit the valid rows of one window (see :func:`fit_window` for arrays of samples).

    regimes: one DrivingRegime constant per row; previous: the last result, whose published values
    are carried over when this window is ill posed.
    """
    regimes = np.asarray(regimes)
    regime = dominant_regime(regimes[rows.valid])
    keep = rows.valid & (regimes != BRAKING) if config.exclude_braking else rows.valid
    return fit_design(rows.x[keep], rows.y[keep], rows.upper[keep], rows.v[keep], regime, train, config,
                      stamp_ns=stamp_ns, run_id=run_id, previous=previous)  # fmt: skip


def fit_design(
    x: np.ndarray,
    y: np.ndarray,
    upper: np.ndarray,
    v: np.ndarray,
    regime: int,
    train: TrainSpec,
    config: WindowConfig,
    *,
    stamp_ns: int = 0,
    run_id: int = 0,
    previous: WindowFit | None = None,
) -> WindowFit:
    """The reference fit of the rows used (x (n, 3), y, upper in N/kg, v in m/s): the exact solver on the rows.

    regime: the window's dominant regime (of its valid steps, braking ones included).
    """
    n = len(y)
    if n == 0:
        why = ill_posed_why(0, 0.0, math.inf, config)
        return make_fit(train, config, n=0, regime=regime, why=why, stamp_ns=stamp_ns, run_id=run_id,
                        previous=previous)  # fmt: skip
    span = float(v.max() - v.min())
    condition = scaled_condition_number(x)
    solution = solvers.solve(x, y, config.specific_bounds, upper, config.gof)
    speeds = np.asarray(config.reference_speeds_kmh, dtype=float) * KMH
    se = resistance_standard_error(x, y - x @ solution.theta, speeds)
    relative_error = float(np.max(se / np.asarray(train.davis(speeds)))) if len(speeds) else 0.0
    why = ill_posed_why(n, span, condition, config, relative_error)
    estimate = tuple(float(value) for value in solution.theta)
    return make_fit(train, config, n=n, regime=regime, span=span, mean_speed=float(v.mean()), condition=condition,
                    estimate=estimate, objective=solution.objective, relative_error=relative_error,
                    dropped=solution.dropped_constraints, why=why, stamp_ns=stamp_ns, run_id=run_id,
                    previous=previous)  # fmt: skip


def make_fit(
    train: TrainSpec,
    config: WindowConfig,
    *,
    n: int,
    regime: int,
    why: tuple,
    stamp_ns: int,
    run_id: int,
    previous: WindowFit | None,
    span: float = 0.0,
    mean_speed: float = math.nan,
    condition: float = math.inf,
    estimate: tuple[float, float, float] | None = None,
    objective: float = math.nan,
    relative_error: float = math.inf,
    dropped: int = 0,
) -> WindowFit:
    """The WindowFit of a window's numbers: span, mean_speed in m/s, estimate (r0, r1, r2) and objective in N/kg;
    why: ill_posed_why's.

    estimate None: no solution (no usable step); the published values are then the previous ones.
    """
    mass = train.effective_mass_kg
    if estimate is None or why:  # publish the last well-posed values
        r0, r1, r2 = (previous.r0, previous.r1, previous.r2) if previous is not None else NAN3
    else:
        r0, r1, r2 = estimate
    r0, r1, r2 = float(r0), float(r1), float(r2)
    head = (int(stamp_ns), int(run_id), float(config.window_length), n, config.gof_kind)
    published = (r0 * mass, r1 * mass, r2 * mass, r0, r1, r2, regime)
    if estimate is None:
        return WindowFit(*head, math.nan, *published, True, 0.0, why=why)
    return WindowFit(*head, objective * mass, *published, bool(why), span, estimate, condition, mean_speed, why,
                     relative_error, dropped)  # fmt: skip


def fit_window(
    t,
    v,
    power_consumed,
    power_regenerated,
    track_force,
    tunnel_fraction,
    train: TrainSpec,
    config: WindowConfig,
    *,
    v_variance=None,
    regime=None,
    stamp_ns: int | None = None,
    run_id: int = 0,
    previous: WindowFit | None = None,
) -> WindowFit:
    """Calibrate A, B, C on one window given as arrays of consecutive samples (all of them are used).

    t in s, v in m/s, power in W, track_force g(s) in N/kg, tunnel_fraction 0..1, v_variance in
    (m/s)^2 (margin of eq. 6/7), regime: DrivingRegime per sample (None: from power, Section 5.1).
    """
    t = np.asarray(t, dtype=float)
    force = tractive_force(v, power_consumed, power_regenerated, train, config.min_speed) / train.effective_mass_kg
    rows = difference_rows(t, v, force, track_force, tunnel_fraction, train, config, v_variance)
    regimes = regime_from_power(rows.force, rows.acceleration, config) if regime is None else np.asarray(regime)[:-1]
    stamp = int(np.rint(t[-1] * 1e9)) if stamp_ns is None else stamp_ns
    return fit_rows(rows, regimes, train, config, stamp_ns=stamp, run_id=run_id, previous=previous)
