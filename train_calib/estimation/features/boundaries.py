"""Where a change of regime lies between two samples (features' ``boundary_refinement``): on the speeds (a
continuous two-segment line), on the effort sources (``boundary_from_power``), or at the stop.

Units: times s, positions m, speeds m/s, accelerations m/s^2.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from functools import partial
from typing import NamedTuple

import numpy as np

from ...regime_codes import COASTING, CRUISING, TRACTION, UNKNOWN
from ..config import FeatureConfig
from ..records import EFFORT_COASTING, EFFORT_COMPUTED, EFFORT_POWER, EFFORT_POWER_COASTING

_NAN = math.nan


class Point(NamedTuple):
    """A moving sample as the change location sees it (``np.asarray`` of a list of them is read by column)."""

    t: float
    """Time, s."""
    s: float
    """Position, m."""
    v_fit: float
    """The speed the changes are located on (``fit_speed``), m/s."""
    accel: float
    """Published acceleration of the step ending here, m/s^2."""
    v: float
    """Filtered speed, m/s."""
    src: int
    """Effort source (EFFORT_*) of the step ending here."""


_T, _V_FIT = Point._fields.index("t"), Point._fields.index("v_fit")


def columns(rows: Sequence[tuple], *fields: int) -> np.ndarray:
    """The fields (indices) of the rows (named tuples) as the columns of an (n, len(fields)) float array: a column is
    a strided view as of ``np.asarray(rows)``, so sums and products run as on it (BLAS's dot product of a strided
    vector adds in another order than of a contiguous one), at a fifth of the cost (no per-row conversion)."""
    out = np.empty((len(rows), len(fields)))
    by_field = list(zip(*rows))
    for j, field in enumerate(fields if by_field else ()):
        out[:, j] = by_field[field]
    return out


new_point = partial(tuple.__new__, Point)
"""``new_point((t, s, v_fit, accel, v, src))``: a Point without the Python-level ``Point.__new__`` (the per-sample
paths make one a step; this is a third of the cost)."""


class PowerSpan(NamedTuple):
    """The steps (start, end] in which the effort sources place a change."""

    start: float
    """Time of the sample before them, s."""
    end: float
    """Time of the sample after them, s."""
    one_step: bool
    """True when it is a single step: the power says no more than "within it"."""


class Change:
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
        pts: list[Point],
        cfg: FeatureConfig,
        old: int = UNKNOWN,
        new: int = UNKNOWN,
    ) -> None:
        self.kind, self.t_prev, self.t_first = kind, t_prev, t_first
        self.old, self.new = old, new
        self.power = cfg.boundary_from_power
        # the moving samples around the change
        self.pts = pts
        self.lo = t_first - max(cfg.boundary_search, 2.0 * (t_first - t_prev))
        self.until = t_first + max(cfg.boundary_window, 3.0 * (t_first - t_prev))
        self.closed = kind == "stop"
        self.s_stop = _NAN
        self.standstill = cfg.standstill_speed
        self._time: float | None = None
        self._memo: tuple[int, bool, float] | None = None  # (len(pts), refine, time): pts only grow by appending

    def add(self, p: Point) -> None:
        """A moving sample after the change: collected up to ``until``, then the change is closed."""
        if p[_T] <= self.until:
            self.pts.append(p)
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
                elif self.old == COASTING and speed is not None and speed < 2.0 * span.start - span.end:
                    out = speed  # the speeds broke a step before the power: braking without electric brake
                elif span.one_step:  # one step: the power says no more than "within it"
                    out = 0.5 * (span.start + span.end)
                else:
                    out = _break_time(self.pts, span.start, span.end)
                    out = 0.5 * (span.start + span.end) if out is None else out
                out = mid if out is None else out
            self._memo = (len(self.pts), refine, out)
        if self.closed:
            self._time = out
        return out

    def s_at(self, t: float) -> float:
        """Position at time t (linear between the samples), m."""
        if self.kind == "stop" and not math.isnan(self.s_stop):
            return self.s_stop
        ts = [p.t for p in self.pts]
        ss = [p.s for p in self.pts]
        return float(np.interp(t, ts, ss)) if ts else _NAN


_MEASURED_TRACTION, _MEASURED_COAST = EFFORT_POWER, EFFORT_POWER_COASTING
_UNMEASURED = (EFFORT_COMPUTED, EFFORT_COASTING)
_POWER_GAP_STEPS = 2
"""Steps without a measured effort (the step the power changed in, one missing power sample) that a change located
on the power may span; a longer stretch is not one change (a brake between traction and coasting)."""


def _power_interval(pts: list[Point], t_first: float, lo: float, old: int, new: int) -> PowerSpan | None:
    """The steps (start, end] in which the effort sources (``pts[i].src``, of the step ending at sample i)
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
    f = next((i for i in range(n - 1, -1, -1) if pts[i].t <= t_first), -1)
    if f < 1:
        return None
    src = [p.src for p in pts]
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
        return PowerSpan(pts[i].t, pts[j - 1].t, gap == 1)
    if old != COASTING:
        return None
    k = f
    while k >= 0 and src[k] != _MEASURED_COAST:
        k -= 1
    if k < 0 or k == f or pts[k].t < lo or src[k + 1] not in _UNMEASURED:
        return None
    return PowerSpan(pts[k].t, pts[k + 1].t, True)


def _last_measured(src: list[int], k: int) -> int:
    """Index of the last step at or before k whose effort source is not in _UNMEASURED; -1 if none."""
    while k >= 0 and src[k] in _UNMEASURED:
        k -= 1
    return k


def _traction_end(src: list[int], pts: list[Point], f: int, lo: float) -> PowerSpan | None:
    """The step after the last measured-traction step before sample f (not before ``lo``), when no measured effort
    follows it up to f: coasting without power coasting (``UKFConfig.power_coasting`` false, or the speeds showed
    braking) still starts where the traction power ended."""
    i = _last_measured(src, f)
    if i < 0 or i == f or src[i] != _MEASURED_TRACTION or pts[i].t < lo:
        return None
    return PowerSpan(pts[i].t, pts[i + 1].t, True)


def _break_time(pts: list[Point], lo: float, hi: float) -> float | None:
    """Break of the continuous two-segment least-squares line through the speeds, searched in [lo, hi] (a grid
    of 40 steps, then 40 around the best); at least two samples on each side, so the new phase needs two samples.
    None otherwise (a one-sample phase leaves the break anywhere in its step)."""
    if len(pts) < 4:
        return None
    arr = columns(pts, _T, _V_FIT)
    t0 = float(arr[:, 0].mean())
    t, v = arr[:, 0] - t0, arr[:, 1]
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


def _stop_time(pts: list[Point], t_prev: float, t_first: float, standstill: float) -> float:
    """Where the speed of the braking reaches zero: the line through its last (up to four) moving samples, or through
    the last one with its published acceleration; no earlier than the last moving sample and no later than t_first
    plus the time to brake the standstill speed away (the first "standing" sample may still be rolling).

    On the filtered speeds (``Point.v``): "moving" is decided on them, and near the stop the measured ones of the last
    moving samples may already be the standstill's noise."""
    last = [p for p in pts if p.t <= t_prev][-4:]
    if not last:
        return 0.5 * (t_prev + t_first)
    t_last, v_last = last[-1].t, last[-1].v
    if len(last) >= 2:
        slope = float(np.polyfit([p.t - t_last for p in last], [p.v for p in last], 1)[0])
    else:
        slope = float(last[-1].accel)
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
