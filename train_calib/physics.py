"""The train motion model shared by every method, per unit of effective mass (N/kg = m/s^2).

    dv/dt = f_t(v) - f_b(v) - r(v) - g(s)

All forces are divided by the effective mass gamma*m (gamma: rotating-mass factor), as in
Cunillera et al. (2022) eq. 1-2 and Besinovic et al. (2013) eq. 3-6.
"""

from __future__ import annotations

import numpy as np

GRAVITY = 9.81
"""Gravitational acceleration, m/s^2 (the value the papers use)."""

CURVE_CONSTANT_M = 0.7
"""Curve resistance per unit weight = CURVE_CONSTANT_M / R (the "700/R" rule in per mille, R in m)."""

KMH = 1.0 / 3.6
"""One km/h in m/s."""


def davis(v_ms, r0: float, r1: float, r2: float, tunnel_fraction=0.0, tunnel_factor: float = 0.0):
    """Running resistance r(v) = r0 + r1 v + (1 + f_tun * tunnel) r2 v^2, N/kg (De Martinis eq. 5)."""
    v = np.asarray(v_ms, dtype=float)
    return r0 + r1 * v + (1.0 + tunnel_factor * np.asarray(tunnel_fraction, dtype=float)) * r2 * v * v


def tractive_envelope(v_ms, c0: float, c2: float, c1: float = 0.0):
    """Maximum tractive effort, N/kg: c0 + c1 v up to the transition speed, c2 / v above (Besinovic eq. 4).

    c0 in N/kg, c1 in N/(kg m/s), c2 (maximum power per unit effective mass) in W/kg. The switch is at
    the first crossing of the two branches (``transition_speed``); without a crossing (c1 < 0 and the
    line always below the hyperbola) the linear branch holds throughout. Never negative.
    """
    v = np.asarray(v_ms, dtype=float)
    v_t = transition_speed(c0, c2, c1)
    with np.errstate(divide="ignore"):
        hyperbolic = np.where(v > 0.0, c2 / np.maximum(v, 1e-12), np.inf)
    return np.maximum(np.where(v <= v_t, c0 + c1 * v, hyperbolic), 0.0)


def transition_speed(c0: float, c2: float, c1: float = 0.0) -> float:
    """Speed (m/s) of the first crossing of c0 + c1 v and c2 / v: the switch from the effort to the power limit.

    inf when the branches never cross (c1 < 0 with c0^2 + 4 c1 c2 < 0).
    """
    if c1 == 0.0:
        return c2 / c0
    discriminant = c0 * c0 + 4.0 * c1 * c2
    if discriminant < 0.0:
        return float("inf")
    return float((-c0 + np.sqrt(discriminant)) / (2.0 * c1))


def adhesion_coefficient(v_ms):
    """Curtius-Kniffler adhesion coefficient mu(v) = 0.161 + 7.5 / (3.6 v + 44), v in m/s (De Martinis eq. 6)."""
    v = np.asarray(v_ms, dtype=float)
    return 0.161 + 7.5 / (3.6 * v + 44.0)


def adhesion_limit(v_ms, adhesive_mass_fraction: float, rotating_mass_factor: float):
    """Maximum effort the driven wheels can transmit, N/kg of effective mass: mu(v) g m_adh / (gamma m)."""
    return adhesion_coefficient(v_ms) * GRAVITY * adhesive_mass_fraction / rotating_mass_factor
