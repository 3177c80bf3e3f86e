"""A phase of one regime for the final coast and brake, and the test for a speed hold at the end of a coast.

Units: times s, positions m, speeds m/s, w = r + g in N/kg.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Sequence
from typing import NamedTuple

import numpy as np

from .boundaries import Change, columns

_NAN = math.nan
_QUANT_VAR = (1.0 / 3.6) ** 2 / 12.0
"""Variance of a speed rounded to 1 km/h, (m/s)^2: the floor of the speed noise in the hold test."""


class TailPoint(NamedTuple):
    """A sample of the tail of a coasting phase (the hold test)."""

    t: float
    """Time, s."""
    s: float
    """Position, m."""
    u: float
    """Speed change integrated from the published accelerations since the run began, m/s."""


_T, _U = TailPoint._fields.index("t"), TailPoint._fields.index("u")


class Phase:
    """A (merged) phase of one regime: start and end changes, the time labelled with the regime; for coasting the
    samples of its last ``hold_check_window`` seconds (``TailPoint``) and the last r + g (N/kg)."""

    __slots__ = ("end", "first_s", "first_t", "hold_memo", "labelled", "last_s", "last_t", "start", "tail", "w_last")

    def __init__(self, start: Change | None, t0: float, s0: float) -> None:
        self.start, self.end = start, None
        self.first_t, self.first_s = t0, s0  # the first step's start (no change object: the run began in it)
        self.last_t, self.last_s = t0, s0
        self.labelled = 0.0
        self.tail: deque[TailPoint] = deque()
        self.w_last = _NAN
        self.hold_memo: tuple | None = None  # FinalPhases._hold_start's last question and answer

    def start_point(self, refine: bool) -> tuple[float, float]:
        """(t s, s m) where the phase starts."""
        if self.start is None:
            return self.first_t, self.first_s
        t0 = self.start.time(refine)
        return t0, self.start.s_at(t0)

    def end_point(self, refine: bool) -> tuple[float, float]:
        """(t s, s m) where the phase ends (its last sample while it is open)."""
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


def hold_tail(tail: Sequence[TailPoint], w: float, min_tail: float) -> float | None:
    """Start of a speed hold that ends a labelled coasting phase (a low-speed hold has its effort r + g inside the
    coasting band and may be labelled coasting), or None.

    The tail speeds (the published accelerations integrated: the filtered speed follows the estimator's coasting
    model where it takes the effort as a known zero) are fitted with a continuous line that turns flat at tau;
    the part after tau (at least ``min_tail`` s, three samples) is a hold when its own slope is 100 times likelier
    under a = 0 than under the coasting deceleration a = -w (w = r + g, 30 % uncertain).
    """
    if len(tail) < 5 or not w > 0.0:
        return None
    arr = columns(tail, _T, _U)
    t = arr[:, 0] - arr[-1, 0]
    v = arr[:, 1]
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
