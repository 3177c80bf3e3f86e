"""The final coast and final brake of a run, tracked per step (shared by the accumulator and the whole-run path).

Units: times s, positions m, speeds m/s, accelerations m/s^2, efforts N/kg.
"""

from __future__ import annotations

import math
from collections import deque
from functools import partial

import numpy as np

from ...regime_codes import BRAKING, COASTING, UNKNOWN
from ..config import FeatureConfig
from ..records import EFFORT_COMPUTED, EFFORT_POWER
from .boundaries import Change, Point
from .phases import _T, Phase, TailPoint, hold_tail
from .rules import opposing_force

_NAN = math.nan
_INF = math.inf
_FINAL = (COASTING, BRAKING)
_PT = Point._fields.index("t")
_tail_point = partial(tuple.__new__, TailPoint)  # TailPoint((t, s, u)) without the Python-level __new__


class FinalPhases:
    """The final coast and final brake of a run, per step.

    Definitions (docs/estimator.md, "Final coast and final brake"): a phase is a maximal run of steps of one
    regime, interruptions up to ``phase_merge_gap`` merged; the final brake is the last braking phase with at
    least ``final_brake_min_duration`` labelled braking, ending at the stop; the final coast is the last
    coasting phase with at least ``final_coast_min_duration`` labelled coasting (the coasting before the final
    brake). Start and end are the located changes (``Change``), the end of the final brake the stop.
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
        "_prev_r",
        "_prev_s",
        "_prev_t",
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
        self._hist: deque[Point] = deque()  # the recent moving samples
        self._open: Change | None = None  # the change still collecting the samples after it (a new one ends it)
        self._last: dict[int, Phase | None] = {COASTING: None, BRAKING: None}
        self.final: dict[int, Phase | None] = {COASTING: None, BRAKING: None}
        self._coasts: list[Phase] = []  # the last coasting phases that qualified (the final one last)
        self._u = 0.0  # speed change integrated from the published accelerations (the measured speeds at 10 s)
        self._traction_t = -math.inf  # end of the last step with measured traction (EFFORT_POWER)
        self.latest: Change | None = None  # the last change located (the end of a braking run for the brake rates)
        self._power = cfg.boundary_from_power
        # the last sample: t s, s m, its regime
        self._prev_t, self._prev_s, self._prev_r = math.nan, math.nan, UNKNOWN

    def first(self, t: float, s: float, v: float, v_fit: float, regime: int) -> None:
        """The first sample of the run (v filtered, v_fit the speed the changes are located on, ``fit_speed``; regime
        as the first step's ``r_prev``: UNKNOWN when standing)."""
        self._prev_t, self._prev_s, self._prev_r = t, s, regime
        if v >= self.cfg.standstill_speed:
            self._hist.append(Point(t, s, v_fit, 0.0, v, EFFORT_COMPUTED))

    def step(self, cur: Point, regime: int, effort: float) -> None:
        """One step from the last sample to ``cur``, labelled ``regime`` (UNKNOWN when standing); ``effort``: its
        published effort (with ``cur.src`` it gives w = r + g, ``opposing_force``).

        The per-step work (the open phase extended, the moving sample kept for the changes to come and given to
        the open ones, the old samples forgotten) is written out here, not in helpers: this runs once a sample in
        the feature node and in the whole-run path."""
        t, s, _, accel, v, src = cur
        t_prev, s_prev, r_prev = self._prev_t, self._prev_s, self._prev_r
        self._prev_t, self._prev_s, self._prev_r = t, s, regime
        dt = t - t_prev
        if dt > 0.0 and -_INF < accel < _INF:  # math.isfinite, without the call
            self._u += accel * dt
        moving = v >= self._standstill
        last = self._last
        if not moving or regime != r_prev or (regime in _FINAL and last[regime] is None):
            self._locate_change(t_prev, s_prev, r_prev, cur, regime, moving)  # (a no-op on the other steps)
        if not moving and regime == BRAKING:
            regime = UNKNOWN  # the step the train stopped in: its braking ended at the stop located above
        if regime in _FINAL:  # the step extends the open phase of its regime; it is the final one once long enough
            ph = last[regime]
            ph.last_t, ph.last_s = t, s
            if dt > 0.0:
                ph.labelled += dt
            if regime == COASTING:
                tail = ph.tail
                tail.append(_tail_point((t, s, self._u)))
                t_old = t - self._hold_window
                while tail[0][_T] < t_old:
                    tail.popleft()
                w = opposing_force(effort, accel, src)
                if -_INF < w < _INF:
                    ph.w_last = w
                minimum = self._min_coast
            else:
                minimum = self._min_brake
            if ph.labelled >= minimum and self.final[regime] is not ph:
                self.final[regime] = ph
                if regime == COASTING:
                    self._coasts = [*self._coasts[-2:], ph]
        if src == EFFORT_POWER and self._power:
            self._traction_t = t
        hist = self._hist
        if moving:  # kept for the changes to come, and given to the open ones
            hist.append(cur)
            ch = self._open
            if ch is not None:
                ch.add(cur)
                if ch.closed:
                    self._open = None
        t_old = t - self._span - (0.0 if dt < 0.0 else 5.0 * dt)  # 5 max(dt, 0), without the call
        while hist and hist[0][_PT] < t_old:
            hist.popleft()

    def _locate_change(self, t_prev: float, s_prev: float, r_prev: int, cur: Point, r: int, moving: bool) -> None:
        """End or start the phases at a change of regime (r_prev to r) into or out of a final-phase regime, or at
        the stop; the step runs from the sample (t_prev, s_prev) to ``cur``."""
        last = self._last
        brake = last[BRAKING]
        if brake is not None and brake.end is None and not moving and (r == BRAKING or r_prev == BRAKING):
            # the train stopped within this step (still labelled braking) or the last: the end of the braking
            brake.end = self._change("stop", t_prev, cur.t, cur.s, brake)
        elif r != r_prev and (r in _FINAL or r_prev in _FINAL):
            ch = self._change("change", t_prev, cur.t, cur.s, None, r_prev, r)
            ph = last.get(r_prev)
            if ph is not None and ph.end is None:
                ph.end = ch
            if r in _FINAL:
                ph = last[r]
                gap = t_prev - ph.last_t if ph is not None else math.inf
                if gap <= self._merge_gap and not self._braked_since(ph, r):
                    ph.end = None  # resumed after a short interruption
                else:
                    last[r] = Phase(ch, t_prev, s_prev)
        elif r in _FINAL and last[r] is None:
            last[r] = Phase(None, t_prev, s_prev)  # the first step of the run

    def _change(
        self, kind: str, t_prev: float, t: float, s: float, brake: Phase | None, old: int = UNKNOWN, new: int = UNKNOWN
    ) -> Change:
        """A change (from regime old to new) between the samples at t_prev and t; it ends the collection of the open
        ones."""
        cfg = self.cfg
        span = max(cfg.boundary_search, 2.0 * (t - t_prev)) + max(cfg.boundary_window, 3.0 * (t - t_prev))
        if brake is not None:  # stop: the speeds of the braking since its start
            since = brake.start.time(self.refine) if brake.start is not None else brake.first_t
            pts = [p for p in self._hist if p.t >= since]
        else:
            pts = [p for p in self._hist if p.t >= t - span]
        ch = Change(kind, t_prev, t, pts, cfg, old, new)
        self.latest = ch
        if kind == "stop":
            ch.s_stop = s
        if self._open is not None:  # the phase after it ended: the line after a change fits that phase only
            self._open.closed = True
        self._open = ch
        return ch

    def _braked_since(self, ph: Phase | None, r: int) -> bool:
        """A coasting phase is not continued across braking (the coast before a brake is a different one), nor across
        measured traction (no label noise: the power shows it; ``boundary_from_power``)."""
        if r != COASTING or ph is None:
            return False
        brake = self._last[BRAKING]
        return (brake is not None and brake.last_t > ph.last_t) or self._traction_t > ph.last_t

    def result(self, regime: int) -> tuple[float, float]:
        """(duration s, distance m) of the final COASTING or BRAKING phase so far; NaN when there is none.

        Final coast with ``boundary_refinement``: a hold at its end (``hold_tail``, on the phase up to its located
        end) is cut off; a phase that is then shorter than ``final_coast_min_duration`` was a hold, and the coasting
        phase before it is the final one.
        """
        if regime == BRAKING or not self.refine:
            ph = self.final[regime]
            return ph.bounds(self.refine) if ph is not None else (_NAN, _NAN)
        cfg = self.cfg
        for ph in reversed(self._coasts):
            t_hold = self._hold_start(ph)
            if t_hold is None:
                return ph.bounds(True)
            t0, s0 = ph.start_point(True)
            if t_hold - t0 >= cfg.final_coast_min_duration:
                ts = [p.t for p in ph.tail]
                return t_hold - t0, float(np.interp(t_hold, ts, [p.s for p in ph.tail])) - s0
        return _NAN, _NAN

    def _hold_start(self, ph: Phase) -> float | None:
        """``hold_tail`` of a coasting phase up to its located end (s), remembered while its tail (the same first and
        last point objects and length: points are only appended and dropped from the front), w and end stay; a
        feature snapshot at every change of regime asks again for the same coasts."""
        tail, w = ph.tail, ph.w_last
        t_end = ph.end.time(True) if ph.end is not None else None
        first, last = (tail[0], tail[-1]) if tail else (None, None)
        memo = ph.hold_memo  # (length, first point, last point, w, t_end, the result); a NaN w is never equal
        same_tail = memo is not None and memo[0] == len(tail) and memo[1] is first and memo[2] is last
        if same_tail and memo[3] == w and memo[4] == t_end:  # type: ignore[index]
            return memo[5]  # type: ignore[index]
        points = tail if t_end is None else [p for p in tail if p.t <= t_end]  # after the end: the next phase's
        t_hold = hold_tail(points, w, self.cfg.hold_check_min)
        ph.hold_memo = (len(tail), first, last, w, t_end, t_hold)
        return t_hold
