"""Driving regime per sample (Cunillera et al. 2022, Section 3.2); constants as DrivingRegime.msg.

|effort| <= effort_tolerance -> COASTING; above -> TRACTION, below -> BRAKING; a TRACTION or BRAKING
sample with |acceleration| <= cruise_tolerance -> CRUISING. Option ``hold_detection``: an in-band sample
with |acceleration| < |effort| (nearer a speed hold than coasting) is CRUISING. NaN effort or acceleration -> UNKNOWN;
when the speed is given, a sample slower than standstill_speed is UNKNOWN (standing is not a regime).
"""

from __future__ import annotations

import math

import numpy as np

from .config import RegimeConfig

UNKNOWN = 0
TRACTION = 1
CRUISING = 2
COASTING = 3
BRAKING = 4
REGIME_NAMES = ("unknown", "traction", "cruising", "coasting", "braking")


class RegimeClassifier:
    """Stateless per-sample rule; ``classify`` for the node, ``classify_regimes`` for arrays."""

    __slots__ = ("_a", "_e", "_hold", "_v", "config")

    def __init__(self, config: RegimeConfig | None = None) -> None:
        self.config = config if config is not None else RegimeConfig()
        self._e = self.config.effort_tolerance
        self._a = self.config.cruise_tolerance
        self._v = self.config.standstill_speed
        self._hold = self.config.hold_detection

    def classify(self, effort: float, acceleration: float, speed: float | None = None) -> int:
        """Regime of one sample: effort in N/kg, acceleration in m/s^2, optional speed in m/s."""
        try:
            e = float(effort)
            a = float(acceleration)
        except (TypeError, ValueError):
            return UNKNOWN
        if math.isnan(e) or math.isnan(a):
            return UNKNOWN
        if speed is not None:
            try:
                v = float(speed)
            except (TypeError, ValueError):
                return UNKNOWN
            if not v >= self._v:  # NaN too
                return UNKNOWN
        if abs(e) <= self._e and not (self._hold and abs(a) < abs(e) and abs(a) <= self._a):
            return COASTING
        if abs(a) <= self._a:
            return CRUISING
        return TRACTION if e > 0.0 else BRAKING


def classify_regimes(effort, acceleration, config: RegimeConfig | None = None, speed=None) -> np.ndarray:
    """Vectorised ``RegimeClassifier.classify``: uint8 array of the broadcast shape."""
    cfg = config if config is not None else RegimeConfig()
    e = np.asarray(effort, dtype=float)
    a = np.asarray(acceleration, dtype=float)
    e, a = np.broadcast_arrays(e, a)
    coast = np.abs(e) <= cfg.effort_tolerance
    if cfg.hold_detection:
        coast &= ~((np.abs(a) < np.abs(e)) & (np.abs(a) <= cfg.cruise_tolerance))
    out = np.where(
        coast,
        COASTING,
        np.where(np.abs(a) <= cfg.cruise_tolerance, CRUISING, np.where(e > 0.0, TRACTION, BRAKING)),
    ).astype(np.uint8)
    bad = np.isnan(e) | np.isnan(a)
    if speed is not None:
        v = np.broadcast_to(np.asarray(speed, dtype=float), e.shape)
        bad = bad | ~(v >= cfg.standstill_speed)
    out[bad] = UNKNOWN
    return out
