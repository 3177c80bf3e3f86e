"""The parts of the HMM regime model that the per-sample classifier (:mod:`.regimes`) and the whole-run filter
(:mod:`.regimes_batch`) share: its constants, the paper's rule, the choice of the most probable regime and the scalar
helpers (log erfc, an input as a float). A module of its own so that neither of the two imports the other's internals
(they used to import each other).

Units: efforts and forces N/kg, accelerations m/s^2.
"""

from __future__ import annotations

import math

import numpy as np

from ..regime_codes import BRAKING, COASTING, CRUISING, TRACTION, UNKNOWN
from .config import RegimeConfig
from .effort import PowerEffort

SQRT2 = math.sqrt(2.0)
"""sqrt(2), for the normal cdf via erf."""
LOG_SQRT_2PI = 0.5 * math.log(2.0 * math.pi)
"""log sqrt(2 pi): the normal density's constant."""
START_PRIOR = (0.85, 0.05, 0.05, 0.05)
"""Probabilities of (TRACTION, CRUISING, COASTING, BRAKING) before the first moving sample: departing."""
DEFAULT_W = 0.02
"""r + g (N/kg) assumed before any computed-effort sample was seen (r0 of an EMU on level track)."""


def rule(e: float, a: float, cfg: RegimeConfig) -> int:
    """The paper's rule on effort e and acceleration a (not NaN)."""
    tol_a = cfg.cruise_tolerance
    if abs(e) <= cfg.effort_tolerance and not (cfg.hold_detection and abs(a) < abs(e) and abs(a) <= tol_a):
        return COASTING
    if abs(a) <= tol_a:
        return CRUISING
    return TRACTION if e > 0.0 else BRAKING


def most_probable(p0: float, p1: float, p2: float, p3: float) -> int:
    """The regime code of the largest of the weights of (TRACTION, CRUISING, COASTING, BRAKING); the first of equal
    maxima."""
    best, top = TRACTION, p0
    if p1 > top:
        best, top = CRUISING, p1
    if p2 > top:
        best, top = COASTING, p2
    if p3 > top:
        best = BRAKING
    return best


def log_erfc(x: float) -> float:
    """log(erfc(x)); the asymptotic series where erfc underflows."""
    if x < 5.0:
        return math.log(math.erfc(x))
    x2 = x * x
    return -x2 - math.log(x * math.sqrt(math.pi)) + math.log1p(-0.5 / x2 + 0.75 / (x2 * x2))


def to_float(x) -> float | None:
    """x as a float; None where it is not a number."""
    try:
        return float(x)
    except (TypeError, ValueError):
        return None


def to_float_or_none(x) -> float | None:
    """An optional value as a float: None where it is None or not a number."""
    return None if x is None else to_float(x)


POWER_OFF, POWER_TRACTION, POWER_REGEN = 0, 1, 2
"""The traction power's state at a sample (``RegimeClassifier.classify(power=...)``): neither drawn for traction nor
regenerated; drawn for traction (wheel power above the threshold); regenerated (electric braking)."""
POWER_THRESHOLD = 0.005
"""Wheel power per effective mass (W/kg) above which the power is traction (UKFConfig.power_threshold's default)."""


def power_state(measurement, power: PowerEffort, threshold: float = POWER_THRESHOLD) -> int | None:
    """POWER_* of a measurement's traction power (``power_valid``, ``power_consumed``, ``power_regenerated`` in W),
    with the train's efficiency, effective mass and auxiliary power (``PowerEffort``); None where no valid power was
    measured."""
    if measurement is None or not measurement.power_valid:
        return None
    if measurement.power_regenerated > 0.0:
        return POWER_REGEN
    return POWER_TRACTION if power.wheel_power(measurement.power_consumed) > threshold else POWER_OFF


def backward_message(
    c0: float, c1: float, c2: float, c3: float, keep: float, share: float
) -> tuple[float, float, float, float]:
    """One step of the backward recursion of the forward-backward algorithm over the four regimes: T c normalised,
    for c = the next sample's likelihoods times its backward message and T = keep I + share 1 1^T (the transition
    matrix of both filters: stay on the diagonal, share to each other regime, keep = stay - share)."""
    common = share * (c0 + c1 + c2 + c3)
    b0, b1, b2, b3 = keep * c0 + common, keep * c1 + common, keep * c2 + common, keep * c3 + common
    total = b0 + b1 + b2 + b3
    return b0 / total, b1 / total, b2 / total, b3 / total


def rule_array(e: np.ndarray, a: np.ndarray, cfg: RegimeConfig, speed, smooth: bool) -> np.ndarray:
    """:func:`rule` vectorised over arrays of effort e (N/kg) and acceleration a (m/s^2) of one shape; UNKNOWN where
    NaN or, with ``speed`` (m/s), standing."""
    if smooth:
        raise ValueError("smooth: only with method hmm (the rule has no state to smooth)")
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
