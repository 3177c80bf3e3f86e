"""Driving features of a run (Cunillera et al. 2022, Sections 3.3, 4.3-4.4), incremental and whole-run.

Every sample after the first closes a *step* (the interval from the previous sample): its duration
dt, its distance, its mean speed v_mid = (v_prev + v) / 2 and the sample's regime, effort (the mean
effort over the step) and acceleration. Steps with v_mid below ``standstill_speed`` are standing time
(regime UNKNOWN). Definitions (docs/estimator.md, "Features"):

* max tractive effort: least-squares line effort = a + b v_mid over TRACTION steps with acceleration > 0
  and v_mid in the effort window; reported at the mean v_mid of those steps (= their mean effort).
* max tractive power: mean and sample std of effort * v_mid over the same kind of steps in the power window.
* brake rate per speed step: mean and sample std of -acceleration over BRAKING samples, binned by speed; a
  sample counts only after ``brake_window`` s of braking and when its speed over that window stayed in one
  step (the acceleration is a window average: transitions and step changes would mix rates).
* cruise speeds: median filtered speed of each CRUISING phase lasting at least ``cruise_min_duration``;
  cruise_speed: the duration-weighted median over the samples of those phases.
* regime time shares: step durations per regime over the run time.
* final brake / final coast (Cunillera 3.3: "the length of the final brake and of the previous coasting
  phase"): duration and distance of the last BRAKING phase (the braking that ends at the stop) and of the
  last COASTING phase (the coasting before it) seen so far. A phase is a maximal run of steps of one regime;
  an interruption up to ``phase_merge_gap`` is merged into it (label noise), except that a coast is never
  continued across braking; it counts when at least ``final_*_min_duration`` of it is labelled with its
  regime. Its start and end are located between samples (``boundary_refinement``): at the break of a
  continuous two-segment line fitted to the speed around the labelled change, searched up to
  ``boundary_search`` before it (the recogniser's latency); the final brake ends where its last speeds
  extrapolate to zero. The simulator's truth uses the same definitions on its exact phases.
"""

from __future__ import annotations

import bisect
import math
from collections import deque
from dataclasses import dataclass, field

import numpy as np

from .config import FeatureConfig
from .records import (
    EFFORT_COASTING,
    EFFORT_COMPUTED,
    EFFORT_POWER,
    EFFORT_POWER_COASTING,
    EstimateSample,
    EstimateSeries,
)
from .regimes import BRAKING, COASTING, CRUISING, TRACTION, UNKNOWN

_NAN = math.nan
_FINAL = (COASTING, BRAKING)
_QUANT_VAR = (1.0 / 3.6) ** 2 / 12.0
"""Variance of a speed rounded to 1 km/h, (m/s)^2: the floor of the speed noise in the hold test."""


@dataclass
class Features:
    """Mirror of DrivingFeatures.msg (SI units); NaN with count 0 where there is no data yet."""

    stamp_ns: int = 0
    run_id: int = 0
    run_complete: bool = False
    run_time: float = 0.0
    run_distance: float = 0.0
    regime: int = UNKNOWN
    max_tractive_effort_window_low: float = _NAN
    max_tractive_effort_window_high: float = _NAN
    max_tractive_effort: float = _NAN
    max_tractive_effort_intercept: float = _NAN
    max_tractive_effort_slope: float = _NAN
    max_tractive_effort_count: int = 0
    max_tractive_power_window_low: float = _NAN
    max_tractive_power_window_high: float = _NAN
    max_tractive_power: float = _NAN
    max_tractive_power_std: float = _NAN
    max_tractive_power_count: int = 0
    brake_step_low: np.ndarray = field(default_factory=lambda: np.zeros(0))
    brake_step_high: np.ndarray = field(default_factory=lambda: np.zeros(0))
    brake_rate_mean: np.ndarray = field(default_factory=lambda: np.zeros(0))
    brake_rate_std: np.ndarray = field(default_factory=lambda: np.zeros(0))
    brake_rate_count: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.uint32))
    cruise_speeds: np.ndarray = field(default_factory=lambda: np.zeros(0))
    cruise_speed: float = _NAN
    regime_time_share: np.ndarray = field(default_factory=lambda: np.zeros(5))
    final_coast_duration: float = _NAN
    final_coast_distance: float = _NAN
    final_brake_duration: float = _NAN
    final_brake_distance: float = _NAN

    def as_dict(self) -> dict:
        """JSON-friendly (lists for arrays, None for NaN)."""
        out = {}
        for name in self.__dataclass_fields__:
            value = getattr(self, name)
            if isinstance(value, np.ndarray):
                value = [None if isinstance(x, float) and math.isnan(x) else x for x in value.tolist()]
            elif isinstance(value, float) and math.isnan(value):
                value = None
            out[name] = value
        return out


class _Moments:
    """Count, mean and sum of squared deviations (Welford)."""

    __slots__ = ("m2", "mean", "n")

    def __init__(self) -> None:
        self.n = 0
        self.mean = 0.0
        self.m2 = 0.0

    def add(self, x: float) -> None:
        self.n += 1
        d = x - self.mean
        self.mean += d / self.n
        self.m2 += d * (x - self.mean)

    def copy(self) -> _Moments:
        out = _Moments()
        out.n, out.mean, out.m2 = self.n, self.mean, self.m2
        return out

    def result(self) -> tuple[float, float, int]:
        if self.n == 0:
            return _NAN, _NAN, 0
        std = math.sqrt(self.m2 / (self.n - 1)) if self.n > 1 else _NAN
        return self.mean, std, self.n


class _Change:
    """A change of regime (``old`` to ``new``) into or out of a final-phase regime, located between two samples.

    ``t_prev``: the last sample of the old regime; ``t_first``: the first of the new one. With
    ``boundary_refinement`` the change is placed at the break of a continuous two-segment line fitted by
    least squares to the speed samples within max(``boundary_window``, 3 dt) on each side, searched over
    [t_first - max(boundary_search, 2 dt), t_first] (the recogniser reports a change up to a few samples
    late); with ``boundary_from_power``, where the effort sources show the change (``_power_interval``), within
    the step(s) where the power changed, except at the end of a coast whose speeds broke more than a step before
    the power did (a brake without electric braking regenerates nothing). Kind "stop": where the line through the
    last braking speeds reaches zero. Without refinement, or with too few samples: the middle of the step.
    """

    __slots__ = (
        "_memo",
        "_time",
        "closed",
        "kind",
        "lo",
        "new",
        "old",
        "power",
        "pts",
        "s_stop",
        "standstill",
        "t_first",
        "t_prev",
        "until",
    )

    def __init__(
        self,
        kind: str,
        t_prev: float,
        t_first: float,
        pts: list,
        cfg: FeatureConfig,
        old: int = UNKNOWN,
        new: int = UNKNOWN,
    ) -> None:
        self.kind, self.t_prev, self.t_first = kind, t_prev, t_first
        self.old, self.new = old, new
        self.power = cfg.boundary_from_power
        # (t, s, v_fit, acceleration, v, effort source) of the moving samples around the change (features.fit_speed)
        self.pts = pts
        self.lo = t_first - max(cfg.boundary_search, 2.0 * (t_first - t_prev))
        self.until = t_first + max(cfg.boundary_window, 3.0 * (t_first - t_prev))
        self.closed = kind == "stop"
        self.s_stop = _NAN
        self.standstill = cfg.standstill_speed
        self._time: float | None = None
        self._memo: tuple[int, bool, float] | None = None  # (len(pts), refine, time): pts only grow by appending

    def add(self, t: float, s: float, v_fit: float, a: float, v: float, src: int) -> None:
        if t <= self.until:
            self.pts.append((t, s, v_fit, a, v, src))
        else:
            self.closed = True

    def time(self, refine: bool) -> float:
        """Time of the change, s (cached once no more samples can change it)."""
        if self._time is not None:
            return self._time
        memo = self._memo
        if memo is not None and memo[0] == len(self.pts) and memo[1] == refine:
            out = memo[2]  # the same samples as the last call: the same time
        else:
            mid = 0.5 * (self.t_prev + self.t_first)
            if not refine:
                out = mid
            elif self.kind == "stop":
                out = _stop_time(self.pts, self.t_prev, self.t_first, self.standstill)
            else:
                span = _power_interval(self.pts, self.t_first, self.lo, self.old, self.new) if self.power else None
                speed = _break_time(self.pts, self.lo, self.t_first) if span is None or self.old == COASTING else None
                if span is None:
                    out = speed
                elif self.old == COASTING and speed is not None and speed < 2.0 * span[0] - span[1]:
                    out = speed  # the speeds broke a step before the power: braking without electric brake
                elif span[2]:  # one step: the power says no more than "within it"
                    out = 0.5 * (span[0] + span[1])
                else:
                    out = _break_time(self.pts, span[0], span[1])
                    out = 0.5 * (span[0] + span[1]) if out is None else out
                out = mid if out is None else out
            self._memo = (len(self.pts), refine, out)
        if self.closed:
            self._time = out
        return out

    def s_at(self, t: float) -> float:
        """Position at time t (linear between the samples), m."""
        if self.kind == "stop" and not math.isnan(self.s_stop):
            return self.s_stop
        ts = [p[0] for p in self.pts]
        ss = [p[1] for p in self.pts]
        return float(np.interp(t, ts, ss)) if ts else _NAN


_MEASURED_TRACTION, _MEASURED_COAST = EFFORT_POWER, EFFORT_POWER_COASTING
_UNMEASURED = (EFFORT_COMPUTED, EFFORT_COASTING)
_POWER_GAP_STEPS = 2
"""Steps without a measured effort (the step the power changed in, one missing power sample) that a change located
on the power may span; a longer stretch is not one change (a brake between traction and coasting)."""


def _power_interval(pts: list, t_first: float, lo: float, old: int, new: int) -> tuple[float, float, bool] | None:
    """(a, b, one_step): the steps (a, b] in which the effort sources (pts[i][5], of the step ending at sample i)
    place the change from ``old`` to ``new`` labelled at t_first, or None where they do not show it.

    A measured effort needs the power at both ends of a step, so the step in which traction power ends or starts,
    or electric braking starts, has a computed effort (EFFORT_COMPUTED):

    * into coasting (from traction or a hold): the measured-coasting steps that reach t_first (or start after it)
      follow measured traction and at most ``_POWER_GAP_STEPS`` steps without a measured effort: the change lies in
      those steps;
    * out of coasting: the last measured-coasting step before t_first (not before ``lo``) is followed by a step
      without it: the change lies in that step.

    Braking that follows traction or a hold is not located on the power: the braking phase ends at the stop,
    located on the speeds, which the power's clock (paired within half a period) would not shift alike.
    """
    n = len(pts)
    f = next((i for i in range(n - 1, -1, -1) if pts[i][0] <= t_first), -1)
    if f < 1:
        return None
    src = [p[5] for p in pts]
    if new == COASTING:
        if old not in (TRACTION, CRUISING):
            return None
        j = f
        if src[j] == _MEASURED_COAST:
            while j > 0 and src[j - 1] == _MEASURED_COAST:
                j -= 1
        else:  # labelled before the power shows it: the measured coasting must follow the computed steps
            while j < n and src[j] in _UNMEASURED:
                j += 1
            if j == n or src[j] != _MEASURED_COAST:
                return _traction_end(src, pts, f, lo)
        i = _last_measured(src, j - 1)
        gap = j - 1 - i
        if i < 0 or src[i] != _MEASURED_TRACTION or not 1 <= gap <= _POWER_GAP_STEPS:
            return None
        return pts[i][0], pts[j - 1][0], gap == 1
    if old != COASTING:
        return None
    k = f
    while k >= 0 and src[k] != _MEASURED_COAST:
        k -= 1
    if k < 0 or k == f or pts[k][0] < lo or src[k + 1] not in _UNMEASURED:
        return None
    return pts[k][0], pts[k + 1][0], True


def _last_measured(src: list, k: int) -> int:
    """Index of the last step at or before k whose effort source is not in _UNMEASURED; -1 if none."""
    while k >= 0 and src[k] in _UNMEASURED:
        k -= 1
    return k


def _traction_end(src: list, pts: list, f: int, lo: float) -> tuple[float, float, bool] | None:
    """The step after the last measured-traction step before sample f (not before ``lo``), when no measured effort
    follows it up to f: coasting without power coasting (``UKFConfig.power_coasting`` false, or the speeds showed
    braking) still starts where the traction power ended."""
    i = _last_measured(src, f)
    if i < 0 or i == f or src[i] != _MEASURED_TRACTION or pts[i][0] < lo:
        return None
    return pts[i][0], pts[i + 1][0], True


def _break_time(pts: list, lo: float, hi: float) -> float | None:
    """Break of the continuous two-segment least-squares line through the speeds, searched in [lo, hi] (a grid
    of 40 steps, then 40 around the best); at least two samples on each side, so the new phase needs two samples.
    None otherwise (a one-sample phase leaves the break anywhere in its step)."""
    if len(pts) < 4:
        return None
    arr = np.asarray(pts, dtype=float)
    t0 = float(arr[:, 0].mean())
    t, v = arr[:, 0] - t0, arr[:, 2]
    lo, hi = max(lo - t0, float(t[1])), min(hi - t0, float(t[-1]))
    if not hi > lo:
        return None
    if (t >= hi - 1e-9).sum() < 2:
        return None
    width = (hi - lo) / 40.0
    best = _best_break(t, v, np.linspace(lo, hi, 41))
    if best is None:
        return None
    fine = _best_break(t, v, np.linspace(max(lo, best - width), min(hi, best + width), 41))
    return (fine if fine is not None else best) + t0


def _best_break(t: np.ndarray, v: np.ndarray, grid: np.ndarray) -> float | None:
    """The break in ``grid`` with the least residual sum of squares (basis 1, min(t - tau, 0), max(t - tau, 0)).

    The two hinge columns never overlap (min(d, 0) max(d, 0) = 0), so the normal matrix is
    [[n, a, b], [a, c, 0], [b, 0, e]] and its solution has a closed form, for every grid point at once.
    """
    d = t[None, :] - grid[:, None]
    x1, x2 = np.minimum(d, 0.0), np.maximum(d, 0.0)
    n = float(t.size)
    a, b = x1.sum(axis=1), x2.sum(axis=1)
    c, e = (x1 * x1).sum(axis=1), (x2 * x2).sum(axis=1)
    b0, b1, b2 = float(v.sum()), x1 @ v, x2 @ v
    ok = ((d < 0.0).sum(axis=1) >= 2) & ((d > 0.0).sum(axis=1) >= 2)
    det = n * c * e - a * a * e - b * b * c
    scale = np.maximum(np.maximum(np.maximum(np.abs(a), np.abs(b)), np.maximum(c, e)), n)
    ok &= np.abs(det) > 1e-12 * scale**3
    if not ok.any():
        return None
    a, b, c, e, b1, b2, det = a[ok], b[ok], c[ok], e[ok], b1[ok], b2[ok], det[ok]
    # Cramer's rule on the normal equations (c, e > 0 where two samples lie on each side)
    beta0 = (b0 * c * e - a * b1 * e - b * b2 * c) / det
    beta1 = (b1 - a * beta0) / c
    beta2 = (b2 - b * beta0) / e
    rss = float(v @ v) - (beta0 * b0 + beta1 * b1 + beta2 * b2)
    return float(grid[ok][int(np.argmin(rss))])


def _stop_time(pts: list, t_prev: float, t_first: float, standstill: float) -> float:
    """Where the speed of the braking reaches zero: the line through its last (up to four) moving samples, or through
    the last one with its published acceleration; no earlier than the last moving sample and no later than t_first
    plus the time to brake the standstill speed away (the first "standing" sample may still be rolling).

    On the filtered speeds (p[4]): "moving" is decided on them, and near the stop the measured ones of the last
    moving samples may already be the standstill's noise."""
    last = [p for p in pts if p[0] <= t_prev][-4:]
    if not last:
        return 0.5 * (t_prev + t_first)
    t_last, v_last = last[-1][0], last[-1][4]
    if len(last) >= 2:
        slope = float(np.polyfit([p[0] - t_last for p in last], [p[4] for p in last], 1)[0])
    else:
        slope = float(last[-1][3])
    if not slope < 0.0:
        return 0.5 * (t_prev + t_first)
    return min(max(t_last - v_last / slope, t_last), t_first - standstill / slope)


def fit_speed(v: float, v_measured: float) -> float:
    """The speed phase changes are located on: the measurement where there is one (finite, >= 0), else the
    filtered speed, m/s. The filter lags a strong onset (a brake application) by a sample or two at 1 Hz, which
    placed the end of a coast 1-3 s late; the measured profile is unbiased (docs/estimator.md)."""
    return v_measured if v_measured >= 0.0 and v_measured < math.inf else v


def fit_speeds(v: np.ndarray, v_measured: np.ndarray) -> np.ndarray:
    """``fit_speed`` over arrays."""
    return np.where((v_measured >= 0.0) & (v_measured < np.inf), v_measured, v)


class _Phase:
    """A (merged) phase of one regime: start and end changes, the time labelled with the regime; for coasting the
    samples of its last ``hold_check_window`` seconds (t, s, integrated acceleration) and the last r + g."""

    __slots__ = ("end", "first_s", "first_t", "labelled", "last_s", "last_t", "start", "tail", "w_last")

    def __init__(self, start: _Change | None, t0: float, s0: float) -> None:
        self.start, self.end = start, None
        self.first_t, self.first_s = t0, s0  # the first step's start (no change object: the run began in it)
        self.last_t, self.last_s = t0, s0
        self.labelled = 0.0
        self.tail: deque[tuple[float, float, float]] = deque()
        self.w_last = _NAN

    def start_point(self, refine: bool) -> tuple[float, float]:
        if self.start is None:
            return self.first_t, self.first_s
        t0 = self.start.time(refine)
        return t0, self.start.s_at(t0)

    def end_point(self, refine: bool) -> tuple[float, float]:
        if self.end is None:
            return self.last_t, self.last_s
        t1 = self.end.time(refine)
        return t1, self.end.s_at(t1)

    def bounds(self, refine: bool) -> tuple[float, float]:
        """(duration s, distance m) of the phase."""
        (t0, s0), (t1, s1) = self.start_point(refine), self.end_point(refine)
        return max(t1 - t0, 0.0), s1 - s0


def _flat_break(t: np.ndarray, v: np.ndarray, min_tail: float) -> int | None:
    """Index k (2 <= k < n - 2, at least ``min_tail`` s before the end) of the continuous line v = a + b min(t - t_k, 0)
    with the least residual sum of squares (the first of equal ones); None when there is no such k. Closed-form
    two-parameter least squares, every k at once (t in s, v in m/s)."""
    n = t.size
    ks = np.arange(2, n - 2)
    ks = ks[t[-1] - t[ks] >= min_tail]
    if ks.size == 0:
        return None
    x = np.minimum(t[None, :] - t[ks, None], 0.0)
    xc = x - x.mean(axis=1, keepdims=True)
    vc = v - v.mean()
    sxx = (xc * xc).sum(axis=1)
    slope = (xc @ vc) / np.where(sxx > 0.0, sxx, 1.0)
    resid = xc * slope[:, None] - vc
    rss = (resid * resid).sum(axis=1)
    return int(ks[int(np.argmin(rss))])


def _hold_tail(tail: deque, w: float, min_tail: float) -> float | None:
    """Start of a speed hold that ends a labelled coasting phase (a low-speed hold has its effort r + g inside the
    coasting band and may be labelled coasting), or None.

    The tail speeds (the published accelerations integrated: the filtered speed follows the estimator's coasting
    model where it takes the effort as a known zero) are fitted with a continuous line that turns flat at tau;
    the part after tau (at least ``min_tail`` s, three samples) is a hold when its own slope is 100 times likelier
    under a = 0 than under the coasting deceleration a = -w (w = r + g, 30 % uncertain).
    """
    if len(tail) < 5 or not w > 0.0:
        return None
    arr = np.asarray(tail, dtype=float)
    t = arr[:, 0] - arr[-1, 0]
    v = arr[:, 2]
    k = _flat_break(t, v, min_tail)
    if k is None:
        return None
    tt, vv = t[k:], v[k:]
    sxx = float(((tt - tt.mean()) ** 2).sum())
    if not sxx > 0.0:
        return None
    slope = float(((tt - tt.mean()) * (vv - vv.mean())).sum()) / sxx
    resid = vv - vv.mean() - slope * (tt - tt.mean())
    sigma2 = max(float(resid @ resid) / max(tt.size - 2, 1), _QUANT_VAR)  # the flat part's own scatter
    var = sigma2 / sxx
    var_c = var + (0.3 * w) ** 2
    log_lr = 0.5 * ((slope + w) ** 2 / var_c - slope * slope / var) + 0.5 * math.log(var_c / var)
    return float(arr[k, 0]) if log_lr > math.log(100.0) else None


class _FinalPhases:
    """The final coast and final brake of a run, per step (shared by the accumulator and the whole-run path).

    Definitions (docs/estimator.md, "Final coast and final brake"): a phase is a maximal run of steps of one
    regime, interruptions up to ``phase_merge_gap`` merged; the final brake is the last braking phase with at
    least ``final_brake_min_duration`` labelled braking, ending at the stop; the final coast is the last
    coasting phase with at least ``final_coast_min_duration`` labelled coasting (the coasting before the final
    brake). Start and end are the located changes (``_Change``), the end of the final brake the stop.
    """

    __slots__ = (
        "_coasts",
        "_hist",
        "_hold_window",
        "_last",
        "_merge_gap",
        "_min_brake",
        "_min_coast",
        "_open",
        "_power",
        "_span",
        "_standstill",
        "_traction_t",
        "_u",
        "cfg",
        "final",
        "latest",
        "refine",
    )

    def __init__(self, cfg: FeatureConfig) -> None:
        self.cfg = cfg
        self.refine = cfg.boundary_refinement
        self._span = cfg.boundary_window + cfg.boundary_search
        # per-step constants (s, m/s)
        self._standstill = cfg.standstill_speed
        self._merge_gap = cfg.phase_merge_gap + 1e-9
        self._hold_window = cfg.hold_check_window
        self._min_coast = cfg.final_coast_min_duration - 1e-9
        self._min_brake = cfg.final_brake_min_duration - 1e-9
        self._hist: deque[tuple] = deque()  # (t, s, v_fit, acceleration, v, effort source) of the recent moving samples
        self._open: list[_Change] = []  # changes still collecting the samples after them
        self._last: dict[int, _Phase | None] = {COASTING: None, BRAKING: None}
        self.final: dict[int, _Phase | None] = {COASTING: None, BRAKING: None}
        self._coasts: list[_Phase] = []  # the last coasting phases that qualified (the final one last)
        self._u = 0.0  # speed change integrated from the published accelerations (the measured speeds at 10 s)
        self._traction_t = -math.inf  # end of the last step with measured traction (EFFORT_POWER)
        self.latest: _Change | None = None  # the last change located (the end of a braking run for the brake rates)
        self._power = cfg.boundary_from_power

    def step(
        self,
        t_prev: float,
        s_prev: float,
        r_prev: int,
        t: float,
        s: float,
        v: float,
        r: int,
        dt: float,
        accel: float,
        w: float,
        v_fit: float,
        src: int = EFFORT_COMPUTED,
    ) -> None:
        """One step (t_prev, t] labelled r (UNKNOWN when standing) after one labelled r_prev; accel: its published
        acceleration; w = r + g (effort - acceleration; NaN where the effort is a known zero); v: the filtered
        speed (moving or not), v_fit: the speed the changes are located on (``fit_speed``); src: the step's effort
        source (EFFORT_*)."""
        if dt > 0.0 and math.isfinite(accel):
            self._u += accel * dt
        moving = v >= self._standstill
        last = self._last
        brake = last[BRAKING]
        if brake is not None and brake.end is None and not moving and (r == BRAKING or r_prev == BRAKING):
            # the train stopped within this step (still labelled braking) or the last: the end of the braking
            brake.end = self._change("stop", t_prev, t, s, brake)
        elif r != r_prev and (r in _FINAL or r_prev in _FINAL):
            ch = self._change("change", t_prev, t, s, None, r_prev, r)
            ph = last.get(r_prev)
            if ph is not None and ph.end is None:
                ph.end = ch
            if r in _FINAL:
                ph = last[r]
                gap = t_prev - ph.last_t if ph is not None else math.inf
                if gap <= self._merge_gap and not self._braked_since(ph, r):
                    ph.end = None  # resumed after a short interruption
                else:
                    last[r] = _Phase(ch, t_prev, s_prev)
        elif r in _FINAL and last[r] is None:
            last[r] = _Phase(None, t_prev, s_prev)  # the first step of the run
        if not moving and r == BRAKING:
            r = UNKNOWN  # the step the train stopped in: its braking ended at the stop located above
        if r in _FINAL:
            ph = last[r]
            ph.last_t, ph.last_s = t, s
            if dt > 0.0:
                ph.labelled += dt
            if r == COASTING:
                tail = ph.tail
                tail.append((t, s, self._u))
                t_old = t - self._hold_window
                while tail[0][0] < t_old:
                    tail.popleft()
                if math.isfinite(w):
                    ph.w_last = w
                minimum = self._min_coast
            else:
                minimum = self._min_brake
            if ph.labelled >= minimum and self.final[r] is not ph:
                self.final[r] = ph
                if r == COASTING:
                    self._coasts = [*self._coasts[-2:], ph]
        hist = self._hist
        if src == _MEASURED_TRACTION and self._power:
            self._traction_t = t
        if moving:
            hist.append((t, s, v_fit, accel, v, src))
            if self._open:
                for ch in self._open:
                    ch.add(t, s, v_fit, accel, v, src)
                self._open = [ch for ch in self._open if not ch.closed]
        t_old = t - self._span - 5.0 * max(dt, 0.0)
        while hist and hist[0][0] < t_old:
            hist.popleft()

    def _change(
        self, kind: str, t_prev: float, t: float, s: float, brake: _Phase | None, old: int = UNKNOWN, new: int = UNKNOWN
    ) -> _Change:
        """A change (from regime old to new) between the samples at t_prev and t; it ends the collection of the open
        ones."""
        cfg = self.cfg
        span = max(cfg.boundary_search, 2.0 * (t - t_prev)) + max(cfg.boundary_window, 3.0 * (t - t_prev))
        if brake is not None:  # stop: the speeds of the braking since its start
            since = brake.start.time(self.refine) if brake.start is not None else brake.first_t
            pts = [p for p in self._hist if p[0] >= since]
        else:
            pts = [p for p in self._hist if p[0] >= t - span]
        ch = _Change(kind, t_prev, t, pts, cfg, old, new)
        self.latest = ch
        if kind == "stop":
            ch.s_stop = s
        for other in self._open:  # the phase after them ended: the line after a change fits that phase only
            other.closed = True
        self._open = [ch]
        return ch

    def _braked_since(self, ph: _Phase | None, r: int) -> bool:
        """A coasting phase is not continued across braking (the coast before a brake is a different one), nor across
        measured traction (no label noise: the power shows it; ``boundary_from_power``)."""
        if r != COASTING or ph is None:
            return False
        brake = self._last[BRAKING]
        return (brake is not None and brake.last_t > ph.last_t) or self._traction_t > ph.last_t

    def first(self, t: float, s: float, v: float, v_fit: float) -> None:
        """The first sample of the run (v filtered, v_fit as in ``step``)."""
        if v >= self.cfg.standstill_speed:
            self._hist.append((t, s, v_fit, 0.0, v, EFFORT_COMPUTED))

    def result(self, regime: int) -> tuple[float, float]:
        """(duration s, distance m) of the final COASTING or BRAKING phase so far; NaN when there is none.

        Final coast with ``boundary_refinement``: a hold at its end (``_hold_tail``, on the phase up to its located
        end) is cut off; a phase that is then shorter than ``final_coast_min_duration`` was a hold, and the coasting
        phase before it is the final one.
        """
        if regime == BRAKING or not self.refine:
            ph = self.final[regime]
            return ph.bounds(self.refine) if ph is not None else (_NAN, _NAN)
        cfg = self.cfg
        for ph in reversed(self._coasts):
            tail = ph.tail
            if ph.end is not None:  # the samples labelled coasting after its located end are the next phase's
                t_end = ph.end.time(True)
                tail = [p for p in tail if p[0] <= t_end]
            t_hold = _hold_tail(tail, ph.w_last, cfg.hold_check_min)
            if t_hold is None:
                return ph.bounds(True)
            t0, s0 = ph.start_point(True)
            if t_hold - t0 >= cfg.final_coast_min_duration:
                ts = [p[0] for p in ph.tail]
                return t_hold - t0, float(np.interp(t_hold, ts, [p[1] for p in ph.tail])) - s0
        return _NAN, _NAN


class _BrakeRates:
    """Brake rate samples per speed step; the samples of a braking run count up to its located end.

    The published acceleration is a window average (``accel_window``) and the recogniser, whose effort follows
    it, labels the end of a brake late: at 1 Hz a brake into a hold stayed labelled braking for 8 s after it, and
    those samples mixed the hold into the rate (0.28 instead of 0.47 m/s^2). So a run's samples wait until the
    change out of braking is located (``_Change``, boundary refinement) and those after it are dropped; a run that
    ends at the stop keeps them all. ``result`` counts the waiting ones as they stand (the open run: all).
    """

    __slots__ = ("closing", "done", "open", "refine")

    def __init__(self, steps: int, refine: bool) -> None:
        self.done = [_Moments() for _ in range(steps)]
        self.open: list[tuple[float, int, float]] = []  # (t, step, rate) of the current braking run
        self.closing: list[tuple[_Change, list[tuple[float, int, float]]]] = []  # ended runs, end still moving
        self.refine = refine

    def add(self, t: float, step: int, rate: float) -> None:
        self.open.append((t, step, rate))

    def end_run(self, end: _Change | None) -> None:
        """The braking run ended with the change ``end`` (the last one located)."""
        if self.open:
            if end is None or end.kind == "stop":
                _count_until(self.open, math.inf, self.done)
            else:
                self.closing.append((end, self.open))
            self.open = []
        self.settle()

    def settle(self) -> None:
        """Commit the ended runs whose end no longer moves."""
        if self.closing and any(end.closed for end, _ in self.closing):
            keep = []
            for end, items in self.closing:
                if end.closed:
                    _count_until(items, end.time(self.refine), self.done)
                else:
                    keep.append((end, items))
            self.closing = keep

    def result(self) -> list[tuple[float, float, int]]:
        """(mean, sample std, count) per step, the waiting samples included as they stand."""
        if not self.open and not self.closing:
            return [m.result() for m in self.done]
        moments = [m.copy() for m in self.done]
        for end, items in self.closing:
            _count_until(items, end.time(self.refine), moments)
        _count_until(self.open, math.inf, moments)
        return [m.result() for m in moments]


def _count_until(items: list[tuple[float, int, float]], t_end: float, moments: list[_Moments]) -> None:
    """Add the rates of the (t, step, rate) items with t <= t_end to their step's moments."""
    for t, step, rate in items:
        if t <= t_end:
            moments[step].add(rate)


def _fit(n: int, sv: float, su: float, svv: float, svu: float) -> tuple[float, float, float]:
    """(value at mean v, intercept, slope) of the least-squares line u = a + b v."""
    if n == 0:
        return _NAN, _NAN, _NAN
    mean_v, mean_u = sv / n, su / n
    sxx = svv - sv * mean_v
    if n < 2 or not sxx > 1e-12 * max(svv, 1e-300):
        return mean_u, _NAN, _NAN
    slope = (svu - sv * mean_u) / sxx
    return mean_u, mean_u - slope * mean_v, slope


def _weighted_median(values: np.ndarray, weights: np.ndarray) -> float:
    """Lower weighted median (the smallest value whose cumulative weight reaches half)."""
    if values.size == 0:
        return _NAN
    order = np.argsort(values, kind="stable")
    cw = np.cumsum(weights[order])
    if cw[-1] <= 0.0:
        return float(np.median(values))
    return float(values[order][np.searchsorted(cw, 0.5 * cw[-1])])


class FeatureAccumulator:
    """Running features of the current run, updated per estimate (the feature node's core)."""

    def __init__(self, config: FeatureConfig | None = None) -> None:
        self.config = cfg = config if config is not None else FeatureConfig()
        self._edges = np.asarray(cfg.brake_step_edges, dtype=float)
        self._edges_list = list(cfg.brake_step_edges)
        self.reset()

    def reset(self) -> None:
        """Forget the run (the next sample starts a new one)."""
        self._run_id: int | None = None
        self._stamp = 0
        self._t0 = 0.0
        self._t = 0.0
        self._s0 = 0.0
        self._s = 0.0
        self._v = 0.0
        self._regime = UNKNOWN
        self._shares = [0.0] * 5
        self._fit = [0, 0.0, 0.0, 0.0, 0.0]
        self._power = _Moments()
        self._brake = _BrakeRates(len(self._edges_list), self.config.boundary_refinement)
        self._brake_first_t = 0.0
        self._cruise_done: list[tuple[float, np.ndarray, np.ndarray]] = []  # (median, v, dt) of listed phases
        self._cruise_v: list[float] = []
        self._cruise_dt: list[float] = []
        self._cruise_start = 0.0
        self._final = _FinalPhases(self.config)

    def update(self, sample: EstimateSample, regime: int) -> bool:
        """Add one estimate with its regime; True when the regime changed (publish the features)."""
        v = float(sample.v)
        return self._add(
            int(sample.stamp_ns),
            int(sample.run_id),
            float(sample.s),
            v,
            float(sample.effort),
            float(sample.acceleration),
            int(regime),
            fit_speed(v, float(getattr(sample, "v_measured", _NAN))),
            int(getattr(sample, "effort_source", EFFORT_COMPUTED)),
        )

    def _add(
        self,
        stamp: int,
        run_id: int,
        s: float,
        v: float,
        effort: float,
        accel: float,
        regime: int,
        v_fit: float,
        src: int = EFFORT_COMPUTED,
    ) -> bool:
        """v: filtered speed; v_fit: the speed the phase changes are located on (fit_speed), m/s; src: the effort
        source (EFFORT_*)."""
        cfg = self.config
        t = stamp * 1e-9
        if run_id != self._run_id:
            self.reset()
            self._run_id = run_id
            self._stamp, self._t0, self._t, self._s0, self._s, self._v = stamp, t, t, s, s, v
            self._regime = regime if v >= cfg.standstill_speed else UNKNOWN
            self._final.first(t, s, v, v_fit)
            return True
        dt = t - self._t
        t_prev, s_prev = self._t, self._s
        v_mid = 0.5 * (self._v + v)
        if not v_mid >= cfg.standstill_speed or regime not in (TRACTION, CRUISING, COASTING, BRAKING):
            regime = UNKNOWN
        if dt > 0.0:
            self._shares[regime] += dt
            if regime == TRACTION and accel > 0.0:
                if cfg.max_effort_window_low <= v_mid <= cfg.max_effort_window_high:
                    f = self._fit
                    f[0] += 1
                    f[1] += v_mid
                    f[2] += effort
                    f[3] += v_mid * v_mid
                    f[4] += v_mid * effort
                if cfg.max_power_window_low <= v_mid <= cfg.max_power_window_high:
                    self._power.add(effort * v_mid)
            elif regime == BRAKING:
                if self._regime != BRAKING:
                    self._brake_first_t = t
                w = cfg.brake_window
                if t - self._brake_first_t >= 0.98 * w - 1e-6:
                    i = self._step_index(v)
                    if i >= 0 and i == self._step_index(v - accel * max(w, dt)):
                        self._brake.add(t, i, -accel)
        # cruising phases (by sample)
        if regime == CRUISING:
            if self._regime != CRUISING:
                self._cruise_v, self._cruise_dt, self._cruise_start = [], [], t_prev
            self._cruise_v.append(v)
            self._cruise_dt.append(max(dt, 0.0))
        elif self._regime == CRUISING:
            self._close_cruise(t_prev)
        w = effort - accel if effort != 0.0 else _NAN
        self._final.step(t_prev, s_prev, self._regime, t, s, v, regime, dt, accel, w, v_fit, src)
        if self._regime == BRAKING and regime != BRAKING:
            self._brake.end_run(self._final.latest)
        else:
            self._brake.settle()
        changed = regime != self._regime
        self._stamp, self._t, self._s, self._v, self._regime = stamp, t, s, v, regime
        return changed

    def _step_index(self, v: float) -> int:
        return bisect.bisect_right(self._edges_list, v) - 1  # = np.searchsorted(edges, v, side='right') - 1

    def _close_cruise(self, t_end: float) -> None:
        if t_end - self._cruise_start >= self.config.cruise_min_duration and self._cruise_v:
            v = np.array(self._cruise_v)
            self._cruise_done.append((float(np.median(v)), v, np.array(self._cruise_dt)))
        self._cruise_v, self._cruise_dt = [], []

    def snapshot(self, run_complete: bool = False) -> Features:
        """Features of the run so far (``run_complete`` is copied into the record)."""
        cfg = self.config
        f = Features(stamp_ns=self._stamp, run_id=self._run_id or 0, run_complete=bool(run_complete))
        f.run_time = self._t - self._t0
        f.run_distance = self._s - self._s0
        f.regime = self._regime
        f.max_tractive_effort_window_low = cfg.max_effort_window_low
        f.max_tractive_effort_window_high = cfg.max_effort_window_high
        f.max_tractive_effort, f.max_tractive_effort_intercept, f.max_tractive_effort_slope = _fit(*self._fit)
        f.max_tractive_effort_count = self._fit[0]
        f.max_tractive_power_window_low = cfg.max_power_window_low
        f.max_tractive_power_window_high = cfg.max_power_window_high
        f.max_tractive_power, f.max_tractive_power_std, f.max_tractive_power_count = self._power.result()
        f.brake_step_low = self._edges.copy()
        f.brake_step_high = np.append(self._edges[1:], np.inf)
        res = self._brake.result()
        f.brake_rate_mean = np.array([r[0] for r in res])
        f.brake_rate_std = np.array([r[1] for r in res])
        f.brake_rate_count = np.array([r[2] for r in res], dtype=np.uint32)
        phases = list(self._cruise_done)
        if self._regime == CRUISING and self._cruise_v and self._t - self._cruise_start >= cfg.cruise_min_duration:
            v = np.array(self._cruise_v)
            phases.append((float(np.median(v)), v, np.array(self._cruise_dt)))
        f.cruise_speeds = np.array([p[0] for p in phases])
        if phases:
            values, weights = np.concatenate([p[1] for p in phases]), np.concatenate([p[2] for p in phases])
            f.cruise_speed = _weighted_median(values, weights)
        total = sum(self._shares)
        f.regime_time_share = np.array(self._shares) / total if total > 0.0 else np.zeros(5)
        f.final_coast_duration, f.final_coast_distance = self._final.result(COASTING)
        f.final_brake_duration, f.final_brake_distance = self._final.result(BRAKING)
        return f


def _runs(values: np.ndarray) -> list[tuple[int, int]]:
    """(start, stop) index pairs of maximal runs of equal values."""
    if values.size == 0:
        return []
    cuts = np.flatnonzero(values[1:] != values[:-1]) + 1
    starts = np.concatenate(([0], cuts))
    stops = np.concatenate((cuts, [values.size]))
    return list(zip(starts.tolist(), stops.tolist()))


def extract_features(
    estimates: EstimateSeries, regimes: np.ndarray, config: FeatureConfig | None = None, run_complete: bool = True
) -> Features:
    """Features of one whole run (vectorised); equal to FeatureAccumulator after the last sample."""
    cfg = config if config is not None else FeatureConfig()
    n = len(estimates)
    regimes = np.asarray(regimes).astype(np.int64)
    if regimes.shape != (n,):
        raise ValueError(f"regimes: expected shape ({n},), found {regimes.shape}")
    if n and np.any(estimates.run_id != estimates.run_id[0]):
        raise ValueError("estimates: several run_ids; use features_per_run()")
    if n == 0:
        return FeatureAccumulator(cfg).snapshot(run_complete)
    t = estimates.stamp_ns * 1e-9
    s, v = estimates.s, estimates.v
    f = Features(stamp_ns=int(estimates.stamp_ns[-1]), run_id=int(estimates.run_id[0]), run_complete=run_complete)
    f.run_time = float(t[-1] - t[0])
    f.run_distance = float(s[-1] - s[0])
    dt = np.diff(t)
    v_mid = 0.5 * (v[1:] + v[:-1])
    reg = regimes[1:].copy()
    reg[~(v_mid >= cfg.standstill_speed) | (reg < TRACTION) | (reg > BRAKING)] = UNKNOWN
    first = regimes[0] if v[0] >= cfg.standstill_speed and TRACTION <= regimes[0] <= BRAKING else UNKNOWN
    f.regime = int(reg[-1]) if n > 1 else int(first)
    effort, accel = estimates.effort[1:], estimates.acceleration[1:]
    pos = dt > 0.0
    # effort fit
    f.max_tractive_effort_window_low = cfg.max_effort_window_low
    f.max_tractive_effort_window_high = cfg.max_effort_window_high
    tr = pos & (reg == TRACTION) & (accel > 0.0)
    m = tr & (v_mid >= cfg.max_effort_window_low) & (v_mid <= cfg.max_effort_window_high)
    vm, um = v_mid[m], effort[m]
    sums = (int(m.sum()), float(vm.sum()), float(um.sum()), float((vm * vm).sum()), float((vm * um).sum()))
    f.max_tractive_effort, f.max_tractive_effort_intercept, f.max_tractive_effort_slope = _fit(*sums)
    f.max_tractive_effort_count = sums[0]
    # power
    f.max_tractive_power_window_low = cfg.max_power_window_low
    f.max_tractive_power_window_high = cfg.max_power_window_high
    m = tr & (v_mid >= cfg.max_power_window_low) & (v_mid <= cfg.max_power_window_high)
    power = effort[m] * v_mid[m]
    f.max_tractive_power_count = int(power.size)
    if power.size:
        f.max_tractive_power = float(power.mean())
        f.max_tractive_power_std = float(power.std(ddof=1)) if power.size > 1 else _NAN
    # time shares
    total = float(dt[pos].sum())
    shares = np.bincount(reg[pos], weights=dt[pos], minlength=5)
    f.regime_time_share = shares / total if total > 0.0 else np.zeros(5)
    # phases (loop over phases, not samples)
    phases = _runs(reg)
    cruise = []
    t_step0, t_step1 = t[:-1], t[1:]
    for a, b in phases:
        if reg[a] == CRUISING and t_step1[b - 1] - t_step0[a] >= cfg.cruise_min_duration:
            cruise.append((float(np.median(v[a + 1 : b + 1])), v[a + 1 : b + 1], np.maximum(dt[a:b], 0.0)))
    f.cruise_speeds = np.array([c[0] for c in cruise])
    if cruise:
        values, weights = np.concatenate([c[1] for c in cruise]), np.concatenate([c[2] for c in cruise])
        f.cruise_speed = _weighted_median(values, weights)
    # final coast and brake: the per-step tracker of the accumulator (phase changes located on the speed)
    final = _FinalPhases(cfg)
    tl, sl, vl, rl = t.tolist(), s.tolist(), v.tolist(), reg.tolist()
    fl = fit_speeds(v, estimates.v_measured).tolist()
    dtl = dt.tolist()
    al = estimates.acceleration.tolist()
    srcl = estimates.effort_source.tolist()
    wl = np.where(estimates.effort != 0.0, estimates.effort - estimates.acceleration, np.nan).tolist()
    final.first(tl[0], sl[0], vl[0], fl[0])
    r_prev = int(first)
    brake_ends: dict[int, _Change | None] = {}  # step index -> the change that ended the braking run before it
    for k in range(1, n):
        final.step(
            tl[k - 1], sl[k - 1], r_prev, tl[k], sl[k], vl[k], rl[k - 1], dtl[k - 1], al[k], wl[k], fl[k], srcl[k]
        )
        if r_prev == BRAKING and rl[k - 1] != BRAKING:
            brake_ends[k - 1] = final.latest
        r_prev = rl[k - 1]
    # brake rates
    edges = np.asarray(cfg.brake_step_edges, dtype=float)
    f.brake_step_low = edges.copy()
    f.brake_step_high = np.append(edges[1:], np.inf)
    br = pos & (reg == BRAKING)
    first_t = np.full(n - 1, np.inf)
    for a, b in phases:
        if reg[a] == BRAKING:
            first_t[a:b] = t[a + 1]
            end = brake_ends.get(b)  # samples after the located end of the run mix in what followed (_BrakeRates)
            if end is not None and end.kind != "stop":
                br[a:b] &= t[a + 1 : b + 1] <= end.time(cfg.boundary_refinement)
    w = cfg.brake_window
    br &= t[1:] - first_t >= 0.98 * w - 1e-6
    idx = np.searchsorted(edges, v[1:], side="right") - 1
    br &= idx == np.searchsorted(edges, v[1:] - accel * np.maximum(w, dt), side="right") - 1
    means, stds, counts = [], [], []
    for i in range(edges.size):
        d = -accel[br & (idx == i)]
        counts.append(d.size)
        means.append(float(d.mean()) if d.size else _NAN)
        stds.append(float(d.std(ddof=1)) if d.size > 1 else _NAN)
    f.brake_rate_mean, f.brake_rate_std = np.array(means), np.array(stds)
    f.brake_rate_count = np.array(counts, dtype=np.uint32)
    f.final_coast_duration, f.final_coast_distance = final.result(COASTING)
    f.final_brake_duration, f.final_brake_distance = final.result(BRAKING)
    return f


def features_per_run(
    estimates: EstimateSeries, regimes: np.ndarray, config: FeatureConfig | None = None
) -> list[Features]:
    """``extract_features`` for each run_id of the series, in order of appearance."""
    regimes = np.asarray(regimes)
    out = []
    for a, b in _runs(np.asarray(estimates.run_id)):
        sel = np.arange(a, b)
        out.append(extract_features(estimates.select(sel), regimes[sel], config))
    return out
