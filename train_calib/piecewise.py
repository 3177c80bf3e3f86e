"""Piecewise-constant functions of the track position and their means over the train length."""

from __future__ import annotations

import bisect

import numpy as np


class PiecewiseConstant:
    """f(s) = values[i] for breaks[i] <= s < breaks[i+1]; constant beyond both ends.

    ``mean_over(a, b)`` integrates exactly through a cumulative integral that is piecewise
    linear, so averaging over a train length costs two ``np.interp`` calls for any array of
    positions.
    """

    def __init__(self, breaks_m, values) -> None:
        breaks = np.asarray(breaks_m, dtype=float)
        vals = np.asarray(values, dtype=float)
        if breaks.ndim != 1 or breaks.shape != vals.shape or breaks.size == 0:
            raise ValueError("breaks and values must be 1-D arrays of the same non-zero length")
        if np.any(np.diff(breaks) <= 0):
            raise ValueError("breaks must be strictly increasing")
        self.breaks = breaks
        self.values = vals
        self._cumulative = np.concatenate(([0.0], np.cumsum(vals[:-1] * np.diff(breaks))))
        width = np.diff(breaks)
        # the integral of the (piecewise linear) integral: piecewise quadratic, exact at the breaks
        self._cumulative2 = np.concatenate(
            ([0.0], np.cumsum(self._cumulative[:-1] * width + 0.5 * vals[:-1] * width * width))
        )

    def __call__(self, s_m) -> np.ndarray:
        s = np.asarray(s_m, dtype=float)
        idx = np.clip(np.searchsorted(self.breaks, s, side="right") - 1, 0, self.breaks.size - 1)
        return self.values[idx]

    def integral(self, s_m) -> np.ndarray:
        """Integral of f from breaks[0] to s (negative below breaks[0])."""
        s = np.asarray(s_m, dtype=float)
        idx = np.clip(np.searchsorted(self.breaks, s, side="right") - 1, 0, self.breaks.size - 1)
        return self._cumulative[idx] + self.values[idx] * (s - self.breaks[idx])

    def integral2(self, s_m) -> np.ndarray:
        """Integral from breaks[0] to s of :meth:`integral` (m times f's unit times m): exact, piecewise quadratic."""
        s = np.asarray(s_m, dtype=float)
        idx = np.clip(np.searchsorted(self.breaks, s, side="right") - 1, 0, self.breaks.size - 1)
        d = s - self.breaks[idx]
        return self._cumulative2[idx] + self._cumulative[idx] * d + 0.5 * self.values[idx] * d * d

    def mean_integral_over(self, start_m, end_m) -> np.ndarray:
        """Mean of :meth:`integral` over [start, end] (integral(end) where the interval is empty)."""
        return _mean_over(self.integral2, self.integral, start_m, end_m)

    def mean_over(self, start_m, end_m) -> np.ndarray:
        """Mean of f over [start, end] (f(end) where the interval is empty)."""
        return _mean_over(self.integral, self, start_m, end_m)

    def next_change(self, s_m: float) -> float:
        """The first break strictly after s (inf when none)."""
        i = int(np.searchsorted(self.breaks, s_m, side="right"))
        return float(self.breaks[i]) if i < self.breaks.size else float("inf")


class ScalarPiecewise:
    """One position at a time: a PiecewiseConstant's values with the same arithmetic (the same floats) as its
    numpy methods, on plain floats (per sample, ~20x faster than numpy on 0-d arrays). Positions in m."""

    __slots__ = ("breaks", "cumulative", "cumulative2", "last", "values")

    def __init__(self, f: PiecewiseConstant) -> None:
        self.breaks = [float(x) for x in f.breaks]
        self.values = [float(x) for x in f.values]
        self.cumulative = [float(x) for x in f._cumulative]
        self.cumulative2 = [float(x) for x in f._cumulative2]
        self.last = len(self.breaks) - 1

    def _index(self, s: float) -> int:
        i = bisect.bisect_right(self.breaks, s) - 1  # <= last
        return 0 if i < 0 else i

    def __call__(self, s: float) -> float:
        """f(s)."""
        return self.values[self._index(s)]

    def integral(self, s: float) -> float:
        """Integral of f from breaks[0] to s."""
        i = self._index(s)
        return self.cumulative[i] + self.values[i] * (s - self.breaks[i])

    def integral2(self, s: float) -> float:
        """Integral of :meth:`integral` from breaks[0] to s."""
        i = self._index(s)
        d = s - self.breaks[i]
        return self.cumulative2[i] + self.cumulative[i] * d + 0.5 * self.values[i] * d * d

    def mean_integral_over(self, a: float, b: float) -> float:
        """Mean of :meth:`integral` over [a, b] (integral(b) where the interval is empty)."""
        if b - a > 1e-9:
            return (self.integral2(b) - self.integral2(a)) / (b - a)
        return self.integral(b)

    def means(self, a: float, b: float) -> tuple[float, float]:
        """(:meth:`mean_over`, :meth:`mean_integral_over`) of [a, b] with one index look-up per end: their floats
        (the same operations in the same order; the ingest's per-sample form). Positions in m."""
        breaks, values, cumulative = self.breaks, self.values, self.cumulative
        i = bisect.bisect_right(breaks, b) - 1  # <= last
        if i < 0:
            i = 0
        db = b - breaks[i]
        if b - a > 1e-9:
            if a >= breaks[i]:  # a in b's piece (a < b): the same index
                j = i
            else:
                j = bisect.bisect_right(breaks, a) - 1
                if j < 0:
                    j = 0
            da = a - breaks[j]
            ci, cj, vi, vj = cumulative[i], cumulative[j], values[i], values[j]
            cumulative2 = self.cumulative2
            mean = (ci + vi * db - (cj + vj * da)) / (b - a)
            integral2_b = cumulative2[i] + ci * db + 0.5 * vi * db * db
            integral2_a = cumulative2[j] + cj * da + 0.5 * vj * da * da
            return mean, (integral2_b - integral2_a) / (b - a)
        return values[i], cumulative[i] + values[i] * db

    def mean_over(self, a: float, b: float) -> float:
        """Mean of f over [a, b] (f(b) where the interval is empty)."""
        if b - a > 1e-9:
            breaks, values, cumulative = self.breaks, self.values, self.cumulative
            i = bisect.bisect_right(breaks, b) - 1  # <= last
            if i < 0:
                i = 0
            if a >= breaks[i]:  # a in b's piece (a < b): the same index
                j = i
            else:
                j = bisect.bisect_right(breaks, a) - 1
                if j < 0:
                    j = 0
            return (cumulative[i] + values[i] * (b - breaks[i]) - (cumulative[j] + values[j] * (a - breaks[j]))) / (
                b - a
            )
        return self(b)


def _mean_over(antiderivative, function, start_m, end_m) -> np.ndarray:
    """Mean of a function over [start, end] (m) from its antiderivative, (F(end) - F(start)) / (end - start); the
    function at end where the interval is empty (under 1e-9 m)."""
    a = np.asarray(start_m, dtype=float)
    b = np.asarray(end_m, dtype=float)
    width = b - a
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = (antiderivative(b) - antiderivative(a)) / width
    return np.where(width > 1e-9, mean, function(b))
