"""Brake rate samples per speed step, online: Welford moments, and a braking run's samples held until its located end.

Units: times s, rates (deceleration) m/s^2.
"""

from __future__ import annotations

import math
from typing import NamedTuple

from .boundaries import Change

_NAN = math.nan


class BrakeSample(NamedTuple):
    """A braking sample that counts for the brake rate of its speed step."""

    t: float
    """Time, s."""
    step: int
    """Speed step index (``SpeedSteps``)."""
    rate: float
    """Brake rate, -acceleration, m/s^2."""


def run_end_time(end: Change | None, refine: bool) -> float:
    """Time (s) up to which a braking run's samples count: the located change that ended it; all of them (inf) when
    it ended at the stop or no change was located. Shared by both paths (``extract_features``'s brake mask)."""
    if end is None or end.kind == "stop":
        return math.inf
    return end.time(refine)


class Moments:
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

    def copy(self) -> Moments:
        out = Moments()
        out.n, out.mean, out.m2 = self.n, self.mean, self.m2
        return out

    def result(self) -> tuple[float, float, int]:
        """(mean, sample std, count); NaN where undefined (std needs two)."""
        if self.n == 0:
            return _NAN, _NAN, 0
        std = math.sqrt(self.m2 / (self.n - 1)) if self.n > 1 else _NAN
        return self.mean, std, self.n


def _count_until(items: list[BrakeSample], t_end: float, moments: list[Moments]) -> None:
    """Add the rates of the samples with t <= t_end to their step's moments."""
    for t, step, rate in items:
        if t <= t_end:
            moments[step].add(rate)


class BrakeRates:
    """Brake rate samples per speed step; the samples of a braking run count up to its located end.

    The published acceleration is a window average (``accel_window``) and the recogniser, whose effort follows
    it, labels the end of a brake late: at 1 Hz a brake into a hold stayed labelled braking for 8 s after it, and
    those samples mixed the hold into the rate (0.28 instead of 0.47 m/s^2). So a run's samples wait until the
    change out of braking is located (``Change``, boundary refinement) and those after it are dropped; a run that
    ends at the stop keeps them all. ``result`` counts the waiting ones as they stand (the open run: all).
    """

    __slots__ = ("closing", "done", "open", "refine")

    def __init__(self, steps: int, refine: bool) -> None:
        self.done = [Moments() for _ in range(steps)]
        self.open: list[BrakeSample] = []  # the current braking run
        self.closing: list[tuple[Change, list[BrakeSample]]] = []  # ended runs, end still moving
        self.refine = refine

    def add(self, t: float, step: int, rate: float) -> None:
        self.open.append(BrakeSample(t, step, rate))

    def end_run(self, end: Change | None) -> None:
        """The braking run ended with the change ``end`` (the last one located)."""
        if self.open:
            if end is None or end.kind == "stop":
                _count_until(self.open, run_end_time(end, self.refine), self.done)
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
                    _count_until(items, run_end_time(end, self.refine), self.done)
                else:
                    keep.append((end, items))
            self.closing = keep

    def result(self) -> list[tuple[float, float, int]]:
        """(mean, sample std, count) per step, the waiting samples included as they stand."""
        if not self.open and not self.closing:
            return [m.result() for m in self.done]
        moments = [m.copy() for m in self.done]
        for end, items in self.closing:
            _count_until(items, run_end_time(end, self.refine), moments)
        _count_until(self.open, math.inf, moments)
        return [m.result() for m in moments]
