"""Speed odometer and the GNSS checks built on it: stamp delay (clock offset) and running direction (no ROS).

The ingest integrates the validated speed samples into a distance (:class:`Odometer`) and compares the
accepted GNSS fixes with it:

* :class:`DelayEstimator` — a GNSS stamped ``delta`` s after the measurement time reports the position of
  ``t - delta`` at ``t``, i.e. ``s_fix(t) = D(t) - delta v(t) + c`` along the odometer D. Weighted least squares
  of ``s_fix - D`` on ``(1, v, D)`` with exponential forgetting gives ``delta`` (and the speed scale error,
  the D coefficient, and the offset c). ``delta`` is identified by the speed changes: a run from standstill
  to 120 km/h at 1 Hz with 3-4 m GNSS noise gives it to a few hundredths of a second.
* :class:`DirectionMonitor` — the speed is >= 0 by contract, so a train moving against the track direction
  (shunting, or running the line the other way) shows only in the fixes: over the last ``distance`` m of
  odometer travel the fixes moved backwards.
"""

from __future__ import annotations

import math
from collections import deque

NS = 1_000_000_000


class Odometer:
    """Distance travelled by the speed samples (trapezoid between samples), m, over the last ``horizon_s`` s.

    Only samples newer than the latest are taken (a late, reordered sample is left out of the integral). A gap
    longer than ``max_gap_s`` is not bridged: the history restarts (``restarts`` counts it) at distance 0.
    """

    def __init__(self, horizon_s: float = 600.0, max_gap_s: float = 30.0) -> None:
        self.horizon_ns = int(horizon_s * NS)
        self.max_gap_ns = int(max_gap_s * NS)
        self.restarts = 0
        self.latest_ns: int | None = None  # stamp of the newest sample
        self._t: deque[int] = deque()
        self._d: deque[float] = deque()
        self._v: deque[float] = deque()

    def clear(self) -> None:
        self._t.clear()
        self._d.clear()
        self._v.clear()
        self.latest_ns = None

    def add(self, t_ns: int, v: float) -> None:
        ts = self._t
        if ts:
            last = ts[-1]
            if t_ns <= last:
                return
            if t_ns - last > self.max_gap_ns:
                self.clear()
                self.restarts += 1
                d = 0.0
            else:
                d = self._d[-1] + 0.5 * (self._v[-1] + v) * (t_ns - last) / NS
        else:
            d = 0.0
        ts.append(t_ns)
        self._d.append(d)
        self._v.append(v)
        self.latest_ns = t_ns
        oldest = t_ns - self.horizon_ns
        if len(ts) > 2 and ts[1] < oldest:
            while len(ts) > 2 and ts[1] < oldest:
                ts.popleft()
                self._d.popleft()
                self._v.popleft()

    def at(self, t_ns: int) -> tuple[float, float] | None:
        """(distance, speed) at t, interpolated between the samples around it (exact at constant acceleration
        for the speed, to second order for the distance); None outside the history."""
        ts = self._t
        if not ts or t_ns < ts[0] or t_ns > ts[-1]:
            return None
        i = _index_from_end(ts, t_ns)
        if ts[i] == t_ns:
            return self._d[i], self._v[i]
        t0, t1 = ts[i - 1], ts[i]
        v0, v1 = self._v[i - 1], self._v[i]
        w = (t_ns - t0) / (t1 - t0)
        v = v0 + w * (v1 - v0)
        return self._d[i - 1] + 0.5 * (v0 + v) * (t_ns - t0) / NS, v


def _index_from_end(ts: deque[int], t_ns: int) -> int:
    """``bisect.bisect_left(ts, t_ns)`` for increasing stamps with ts[0] <= t_ns <= ts[-1], scanning back from the
    end (the odometer is asked about the newest fixes: a step or two, where indexing a deque's middle walks it)."""
    i = len(ts) - 1
    while i > 0 and ts[i - 1] >= t_ns:
        i -= 1
    return i


class DelayEstimator:
    """GNSS stamp delay from fixes against the odometer: WLS of s_fix - D on (1, v, D/1000) with forgetting.

    ``estimate()`` returns (delay s, its standard deviation s) once enough fixes have been seen, else None. A
    weak prior (delay 0 +- 1 s, scale error 0 +- 5 %) keeps the fit defined before the train has accelerated;
    a fix whose residual exceeds 5 standard deviations of the fit's prediction (a multipath fix, a
    re-acquisition) is not used.
    """

    MIN_WEIGHT = 20.0  # fixes (effective) before an estimate is given
    PRIOR_STD = (math.inf, 1.0, 50.0)  # intercept (free), delay s, scale error m per km

    def __init__(self, time_constant_s: float = 600.0, sigma_m: float = 4.0) -> None:
        self.time_constant_s = float(time_constant_s)
        self.sigma_m = float(sigma_m)
        self.outliers = 0
        self._prior = tuple(0.0 if math.isinf(p) else self.sigma_m**2 / p**2 for p in self.PRIOR_STD)
        self.reset()

    # The normal equations are 3x3: kept as plain floats (a numpy call per fix cost more than the algebra).
    # _a = (a00, a01, a02, a11, a12, a22) of the symmetric sum of x x^T; _inverse the same layout.

    def reset(self) -> None:
        self._a: tuple[float, ...] = (0.0,) * 6
        self._b: tuple[float, float, float] = (0.0, 0.0, 0.0)
        self._yy = 0.0
        self._w = 0.0
        self._t_ns: int | None = None
        self._d0: float | None = None
        self._beta: tuple[float, float, float] | None = None
        self._inverse: tuple[float, ...] | None = None
        self._sigma2 = self.sigma_m**2

    def add(self, t_ns: int, s_fix: float, d: float, v: float) -> None:
        d0 = self._d0
        if d0 is None:
            self._d0 = d0 = d
        x2 = (d - d0) * 1e-3  # x = (1, v, x2)
        y = s_fix - d
        beta, inv, w = self._beta, self._inverse, self._w
        if beta is not None and inv is not None and w >= self.MIN_WEIGHT:
            residual = y - (beta[0] + beta[1] * v + beta[2] * x2)
            i00, i01, i02, i11, i12, i22 = inv
            quad = i00 + i11 * v * v + i22 * x2 * x2 + 2.0 * (i01 * v + i02 * x2 + i12 * v * x2)
            if residual * residual > 25.0 * self._sigma2 * (1.0 + quad):
                self.outliers += 1
                return
        a00, a01, a02, a11, a12, a22 = self._a
        b0, b1, b2 = self._b
        yy = self._yy
        t_prev = self._t_ns
        if t_prev is not None:
            elapsed = t_ns - t_prev
            decay = math.exp(-(elapsed if elapsed > 0 else 0) / NS / self.time_constant_s)  # = max(elapsed, 0)
            a00, a01, a02, a11, a12, a22 = a00 * decay, a01 * decay, a02 * decay, a11 * decay, a12 * decay, a22 * decay
            b0, b1, b2, yy, w = b0 * decay, b1 * decay, b2 * decay, yy * decay, w * decay
        self._t_ns = t_ns
        self._a = a = (a00 + 1.0, a01 + v, a02 + x2, a11 + v * v, a12 + v * x2, a22 + x2 * x2)
        self._b = b = (b0 + y, b1 + v * y, b2 + x2 * y)
        self._yy, self._w = yy + y * y, w + 1.0
        self._solve(a, b)

    def _solve(self, a: tuple[float, ...], b: tuple[float, float, float]) -> None:
        """The fit of the normal equations ``a`` (the layout of ``_a``) and ``b``, with the prior."""
        w = self._w
        if w < 2.0:
            return
        p0, p1, p2 = self._prior
        a00, a01, a02, a11, a12, a22 = a
        a00, a11, a22 = a00 + p0, a11 + p1, a22 + p2
        c00 = a11 * a22 - a12 * a12  # cofactors of the symmetric matrix
        c01 = a02 * a12 - a01 * a22
        c02 = a01 * a12 - a02 * a11
        det = a00 * c00 + a01 * c01 + a02 * c02
        if not (math.isfinite(det) and abs(det) > 1e-300):
            return
        f = 1.0 / det
        i00, i01, i02 = c00 * f, c01 * f, c02 * f
        i11, i12, i22 = (a00 * a22 - a02 * a02) * f, (a01 * a02 - a00 * a12) * f, (a00 * a11 - a01 * a01) * f
        b0, b1, b2 = b
        beta0 = i00 * b0 + i01 * b1 + i02 * b2
        beta1 = i01 * b0 + i11 * b1 + i12 * b2
        beta2 = i02 * b0 + i12 * b1 + i22 * b2
        self._beta, self._inverse = (beta0, beta1, beta2), (i00, i01, i02, i11, i12, i22)
        fit = beta0 * b0 + beta1 * b1 + beta2 * b2
        dof = w - 3.0
        sigma2 = (self._yy - fit) / (1.0 if dof < 1.0 else dof)  # = max(dof, 1.0)
        self._sigma2 = 0.25 if sigma2 < 0.25 else sigma2  # = max(sigma2, 0.25)

    def estimate(self) -> tuple[float, float] | None:
        """(delay, std) in s: the GNSS stamps are this much later than the measurement time."""
        if self._beta is None or self._inverse is None or self._w < self.MIN_WEIGHT:
            return None
        var = self._inverse[3] * self._sigma2
        if not (math.isfinite(var) and var > 0.0):
            return None
        return -self._beta[1], math.sqrt(var)


FORWARD = 1
BACKWARD = -1


class DirectionMonitor:
    """Running direction along the track from the accepted fixes against the odometer.

    Over the newest stretch in which the odometer advanced at least ``distance`` m, the fixes moved forward
    (direction +1, more than half that distance) or backward (-1, more than half of it backwards); in between
    (the fixes barely moved: a speed sensor reading motion the fixes do not show) the direction is kept.
    """

    def __init__(self, distance_m: float = 40.0, horizon_s: float = 600.0) -> None:
        self.distance_m = float(distance_m)
        self.horizon_ns = int(horizon_s * NS)
        self.direction = FORWARD
        self.changes = 0
        self._track: deque[tuple[int, float, float]] = deque()  # (t, s_fix, odometer distance)

    def reset(self) -> None:
        self.direction = FORWARD
        self._track.clear()

    def add(self, t_ns: int, s_fix: float, d: float) -> int:
        """Record a fix (with the odometer distance at its stamp); returns the direction after it."""
        track = self._track
        if track and t_ns <= track[-1][0]:
            return self.direction
        track.append((t_ns, s_fix, d))
        oldest, distance = t_ns - self.horizon_ns, self.distance_m
        while len(track) > 2 and (track[0][0] < oldest or d - track[1][2] >= distance):
            track.popleft()
        _, s_old, d_old = track[0]
        travelled = d - d_old
        if travelled >= distance:
            moved = s_fix - s_old
            new = FORWARD if moved > 0.5 * travelled else BACKWARD if moved < -0.5 * travelled else self.direction
            if new != self.direction:
                self.direction = new
                self.changes += 1
                track.clear()
                track.append((t_ns, s_fix, d))
        return self.direction


__all__ = ["BACKWARD", "FORWARD", "DelayEstimator", "DirectionMonitor", "Odometer"]
