"""The Newton model per unit effective mass, prepared for fast scalar evaluation.

    dv/dt = u - r(t, s, v) - g(s)
    r     = r0 + r1 v + (1 + f_tun * tunnel(s)) * r2 * (1 + w(t)) * v^2
    u_max = min(eq. 4 envelope, adhesion(v))                (traction envelope)

Eq. 4 (Besinovic): c0 + c1 v up to the transition speed (first crossing), c2 / v above; for c1 >= 0
that is min(c0 + c1 v, c2 / v), for c1 < 0 the switch is explicit (physics.tractive_envelope).

g(s) and tunnel(s) are averaged over the train (head at s, tail at s - L). The mean of a
piecewise-constant profile over a sliding window is piecewise linear, with knots at the profile's
breaks and at the breaks + L, so :class:`TrackTerms` stores it exactly as knots and evaluates it
by bisection in plain floats (the integrators call it six times per step). w(t) is an optional
head/tail-wind factor on r2 (:class:`Wind`). The same formulas are available vectorised for
truth evaluation; a test checks scalar against vector and against ``Track``/``TrainSpec``.
"""

from __future__ import annotations

import math
from bisect import bisect_right
from dataclasses import dataclass

import numpy as np

from ..physics import GRAVITY, adhesion_limit, tractive_envelope, transition_speed
from ..track import Track


class TrackTerms:
    """g(s) (N/kg) and the tunnel fraction over a train of length L, head at s, as exact knots."""

    def __init__(self, track: Track, length_m: float) -> None:
        if length_m <= 0.0:
            raise ValueError("train length must be positive")
        self.length_m = float(length_m)
        breaks = np.unique(np.concatenate([track.gradient.breaks, track.curvature.breaks, track.tunnel.breaks]))
        knots = np.unique(np.concatenate([breaks, breaks + length_m, [0.0, track.length_m]]))
        self.knots = knots
        self.g = np.asarray(track.track_force(knots, length_m), dtype=float)
        self.tunnel = np.asarray(track.tunnel_fraction(knots, length_m), dtype=float)
        self._k = knots.tolist()
        self._g = self.g.tolist()
        self._tun = self.tunnel.tolist()
        dk = np.diff(knots)
        self._gs = [*(np.diff(self.g) / dk).tolist(), 0.0]
        self._ts = [*(np.diff(self.tunnel) / dk).tolist(), 0.0]
        self._n = len(self._k)
        # knots where the piecewise-linear functions really bend (for integrator stops)
        bend = np.ones(knots.size, dtype=bool)
        if knots.size > 2:
            same_g = np.isclose(np.diff(self.g[:-1]) / dk[:-1], np.diff(self.g[1:]) / dk[1:], rtol=0, atol=1e-15)
            same_t = np.isclose(
                np.diff(self.tunnel[:-1]) / dk[:-1], np.diff(self.tunnel[1:]) / dk[1:], rtol=0, atol=1e-15
            )
            bend[1:-1] = ~(same_g & same_t)
        self.bends = knots[bend].tolist()

    def g_at(self, s: float) -> float:
        i = bisect_right(self._k, s) - 1
        if i < 0:
            return self._g[0]
        if i >= self._n - 1:
            return self._g[-1]
        return self._g[i] + self._gs[i] * (s - self._k[i])

    def tunnel_at(self, s: float) -> float:
        i = bisect_right(self._k, s) - 1
        if i < 0:
            return self._tun[0]
        if i >= self._n - 1:
            return self._tun[-1]
        return self._tun[i] + self._ts[i] * (s - self._k[i])

    def g_vec(self, s) -> np.ndarray:
        return np.interp(np.asarray(s, dtype=float), self.knots, self.g)

    def tunnel_vec(self, s) -> np.ndarray:
        return np.interp(np.asarray(s, dtype=float), self.knots, self.tunnel)

    def bends_between(self, a: float, b: float) -> list[float]:
        """Knots strictly inside (a, b), sorted."""
        return [k for k in self.bends if a < k < b]


@dataclass(frozen=True)
class Wind:
    """Relative change of r2 by head (+) or tail (-) wind: w(t) = mean + amplitude sin(2 pi t / period + phase)."""

    mean: float = 0.0
    amplitude: float = 0.0
    period_s: float = 600.0
    phase_rad: float = 0.0

    @property
    def active(self) -> bool:
        return self.mean != 0.0 or self.amplitude != 0.0

    def factor(self, t: float) -> float:
        return 1.0 + self.mean + self.amplitude * math.sin(2.0 * math.pi / self.period_s * t + self.phase_rad)

    def factor_vec(self, t) -> np.ndarray:
        t = np.asarray(t, dtype=float)
        return 1.0 + self.mean + self.amplitude * np.sin(2.0 * np.pi / self.period_s * t + self.phase_rad)


class MotionModel:
    """Forces per unit effective mass for one run: envelope, resistance (tunnel, wind) and g(s)."""

    def __init__(
        self,
        terms: TrackTerms,
        *,
        c0: float,
        c2: float,
        c1: float = 0.0,
        adhesive_mass_fraction: float = 0.0,
        rotating_mass_factor: float = 1.0,
        r0: float,
        r1: float,
        r2: float,
        tunnel_factor: float = 0.0,
        wind: Wind | None = None,
    ) -> None:
        self.terms = terms
        self.c0, self.c1, self.c2 = float(c0), float(c1), float(c2)
        self.adhesive_mass_fraction = float(adhesive_mass_fraction)
        self.rotating_mass_factor = float(rotating_mass_factor)
        self._adh = GRAVITY * self.adhesive_mass_fraction / self.rotating_mass_factor
        self.r0, self.r1, self.r2 = float(r0), float(r1), float(r2)
        self.tunnel_factor = float(tunnel_factor)
        self.wind = wind if wind is not None and wind.active else None
        self.transition_speed = transition_speed(self.c0, self.c2, self.c1)
        self.envelope = self._make_envelope()
        self.opposing = self._make_opposing(self.wind)
        self.opposing_calm = self._make_opposing(None)  # without wind: what a driver can plan with

    # -- scalar (integrators) ---------------------------------------------------------------
    # The integrators call these six times per step: they are closures over local constants
    # (``opposing``, ``opposing_calm``, ``envelope`` are set in __init__ by the _make_* below).

    def _make_envelope(self):
        c0, c1, c2, adh = self.c0, self.c1, self.c2, self._adh
        if c1 < 0.0:
            # Besinovic eq. 4 switches at the transition speed (the first crossing): with c1 < 0 the line
            # falls below the hyperbola again above the second crossing, where min() would be wrong
            v_t = self.transition_speed

            def envelope_falling(v: float) -> float:
                """Maximum tractive effort at speed v, N/kg (eq. 4 with c1 < 0, and adhesion); never negative."""
                f = c0 + c1 * v if v <= v_t else c2 / v
                if f < 0.0:
                    f = 0.0
                if adh > 0.0:
                    cap = (0.161 + 7.5 / (3.6 * v + 44.0)) * adh
                    if cap < f:
                        f = cap
                return f

            return envelope_falling

        # c1 >= 0: one crossing, min(c0 + c1 v, c2 / v) is eq. 4

        def envelope(v: float) -> float:
            """Maximum tractive effort at speed v, N/kg (effort/power limit and adhesion)."""
            f = c0 + c1 * v
            if v > 0.0:
                p = c2 / v
                if p < f:
                    f = p
            if adh > 0.0:
                cap = (0.161 + 7.5 / (3.6 * v + 44.0)) * adh
                if cap < f:
                    f = cap
            return f

        return envelope

    def _make_opposing(self, wind: Wind | None):
        r0, r1, r2, ft = self.r0, self.r1, self.r2, self.tunnel_factor
        terms = self.terms
        k, g, gs, tun, ts, last = terms._k, terms._g, terms._gs, terms._tun, terms._ts, terms._n - 1
        sin = math.sin
        if wind is not None:
            w1, wa, wk, wph = 1.0 + wind.mean, wind.amplitude, 2.0 * math.pi / wind.period_s, wind.phase_rad

        def opposing(t: float, s: float, v: float) -> float:
            """r + g: Davis resistance (tunnel, wind) plus the track force, N/kg."""
            i = bisect_right(k, s) - 1
            if i < 0:
                gg, tt = g[0], tun[0]
            elif i >= last:
                gg, tt = g[last], tun[last]
            else:
                d = s - k[i]
                gg, tt = g[i] + gs[i] * d, tun[i] + ts[i] * d
            q = r2 * (1.0 + ft * tt)
            if wind is not None:
                q *= w1 + wa * sin(wk * t + wph)
            return r0 + r1 * v + q * v * v + gg

        return opposing

    def resistance(self, t: float, s: float, v: float) -> float:
        """Davis resistance with tunnel and wind terms, N/kg."""
        return self.opposing(t, s, v) - self.terms.g_at(s)

    # -- vectorised (truth, tests) ------------------------------------------------------------
    def envelope_vec(self, v) -> np.ndarray:
        v = np.asarray(v, dtype=float)
        if self.c1 < 0.0:  # eq. 4 switches at the transition speed (see _make_envelope)
            f = tractive_envelope(v, self.c0, self.c2, self.c1)
        else:
            with np.errstate(divide="ignore"):
                f = np.minimum(self.c0 + self.c1 * v, np.where(v > 0.0, self.c2 / np.maximum(v, 1e-300), np.inf))
        if self._adh > 0.0:
            f = np.minimum(f, adhesion_limit(v, self.adhesive_mass_fraction, self.rotating_mass_factor))
        return f

    def r2_in_force(self, t) -> np.ndarray:
        """r2 including the wind factor (not the tunnel term), N/(kg (m/s)^2)."""
        t = np.asarray(t, dtype=float)
        if self.wind is None:
            return np.full(t.shape, self.r2)
        return self.r2 * self.wind.factor_vec(t)

    def resistance_vec(self, t, s, v) -> np.ndarray:
        v = np.asarray(v, dtype=float)
        r2 = self.r2_in_force(t) * (1.0 + self.tunnel_factor * self.terms.tunnel_vec(s))
        return self.r0 + self.r1 * v + r2 * v * v
