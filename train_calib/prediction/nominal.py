"""The time to the next station under a nominal strategy: full traction to the limit, cruise at the limit, coast
from ``coast_distance_m`` before the station, then brake at the train's rate (``max_brake_decel``) to the stop.

Per unit effective mass, over distance with w = v^2 / 2: traction dw/ds = f_t(v) - r(v) - g(s) (the train's
tractive envelope with its adhesion cap, :meth:`TrainSpec.tractive_envelope`'s formulas), coasting the same without
f_t. The speed is capped by the ceiling over the train (:class:`train_calib.sim.limits.SpeedCeiling`) and by the
braking curves v^2 = v_low^2 + 2 b (p - s) to every lower limit and to the stop (as the running-time model of
``train_calib.sim.running_time`` brakes). A coast that falls below ``resume_fraction`` of the ceiling resumes
traction (the driver would not crawl into the station). Heun steps of ``step_m`` in plain floats; the time of a
step is 2 ds / (v_a + v_b) (exact at constant deceleration, so the stop is reached in finite time).
"""

from __future__ import annotations

import math
from bisect import bisect_right

import numpy as np

from ..physics import GRAVITY
from ..sim.limits import SpeedCeiling
from ..sim.model import TrackTerms
from ..track import Track
from ..train import TrainSpec


class NominalLeg:
    """The parameter-independent part of a leg to a station (cached per station): on a grid of ``step_m`` ending at
    the station, g(s), the tunnel factor, the ceiling and the allowed v^2 (ceiling and every braking curve ahead)."""

    def __init__(self, track: Track, train: TrainSpec, terms: TrackTerms, station_s_m: float, step_m: float) -> None:
        v_max = train.max_speed_kmh / 3.6 if train.max_speed_kmh > 0 else math.inf
        ceiling = SpeedCeiling(track, train.length_m, 0.0, station_s_m, v_max)
        self.station_s_m = float(station_s_m)
        self.step_m = float(step_m)
        n = max(math.ceil(station_s_m / step_m), 1)
        x = station_s_m - step_m * np.arange(n, -1, -1, dtype=float)  # ascending, the last node at the station
        b = train.max_brake_decel
        cap2 = ceiling.at_vec(x) ** 2
        for d in ceiling.drops():
            cap2 = np.minimum(cap2, np.where(x <= d.s_m, d.v_low**2 + 2.0 * b * (d.s_m - x), np.inf))
        cap2 = np.minimum(cap2, 2.0 * b * np.maximum(station_s_m - x, 0.0))
        self.x = x.tolist()
        self.g = terms.g_vec(x).tolist()
        self.k = (1.0 + train.tunnel_factor * terms.tunnel_vec(x)).tolist()
        self.ceiling = ceiling.at_vec(x).tolist()
        self.cap2 = cap2.tolist()


def nominal_time(
    leg: NominalLeg,
    train: TrainSpec,
    r: tuple[float, float, float],
    s0_m: float,
    v0_ms: float,
    *,
    coast_distance_m: float = 2000.0,
    resume_fraction: float = 0.5,
) -> float:
    """Seconds from (s0, v0) to the stop at the leg's station under the nominal strategy with resistance r
    (r0 N/kg, r1 N/(kg m/s), r2 N/(kg (m/s)^2)); NaN if s0 is not before the station or the train cannot start.
    g(s) and the caps are the leg's grid values (linear between nodes); the first step runs from s0 to the next
    node."""
    end = leg.station_s_m
    if not s0_m < end:
        return math.nan
    r0, r1, r2 = r
    c0, c2 = train.max_tractive_effort, train.max_tractive_power
    adh_k = GRAVITY * train.adhesive_mass_fraction / train.rotating_mass_factor
    coast_from = end - coast_distance_m
    X, Gs, K, C, CAP = leg.x, leg.g, leg.k, leg.ceiling, leg.cap2
    i = bisect_right(X, s0_m)  # first node beyond s0
    frac = (X[i] - s0_m) / leg.step_m if i > 0 else 0.0
    # state at s0: g and k interpolated between nodes i-1 and i
    g_a = Gs[i] - frac * (Gs[i] - Gs[i - 1]) if i > 0 else Gs[0]
    k_a = K[i] - frac * (K[i] - K[i - 1]) if i > 0 else K[0]
    s, w, t = float(s0_m), 0.5 * v0_ms * v0_ms, 0.0
    resumed = False
    sqrt = math.sqrt
    for j in range(i, len(X)):
        v = sqrt(2.0 * w)
        coasting = s >= coast_from and not resumed
        if coasting and v < resume_fraction * C[j - 1 if j > 0 else 0] and CAP[j] > 2.0 * w + 1e-9:
            resumed = True
            coasting = False
        h = X[j] - s
        # acceleration at (s, v) and at the Euler predictor's end (Heun)
        a0 = -(r0 + v * (r1 + k_a * r2 * v)) - g_a
        if not coasting:
            f = c0 if v * c0 <= c2 else c2 / v
            if adh_k > 0.0:  # physics.adhesion_limit in floats
                f = min(f, (0.161 + 7.5 / (3.6 * v + 44.0)) * adh_k)
            a0 += f
        w1 = w + h * a0
        v1 = sqrt(w1 + w1) if w1 > 0.0 else 0.0
        a1 = -(r0 + v1 * (r1 + K[j] * r2 * v1)) - Gs[j]
        if not coasting:
            f = c0 if v1 * c0 <= c2 else c2 / v1
            if adh_k > 0.0:
                f = min(f, (0.161 + 7.5 / (3.6 * v1 + 44.0)) * adh_k)
            a1 += f
        w1 = min(max(w + 0.5 * h * (a0 + a1), 0.0), 0.5 * CAP[j])
        v1 = sqrt(w1 + w1)
        if v + v1 <= 1e-9:
            return math.nan  # stalled: cannot start on this gradient
        t += 2.0 * h / (v + v1)
        s, w, g_a, k_a = X[j], w1, Gs[j], K[j]
    return t
