"""The rules of the driving features, each defined once for both paths: the online one (``FeatureAccumulator``,
per sample, on floats) and the offline one (``extract_features``, per run, on numpy arrays). The functions use
only operations that mean the same on a float and on an array (comparisons combined with ``&``, arithmetic),
so each path gets the same bits it computed before these rules were shared.

Units: times s, speeds m/s, accelerations m/s^2, efforts N/kg (= m/s^2).
"""

from __future__ import annotations

import bisect
import math
from collections.abc import Sequence
from typing import NamedTuple, TypeVar

import numpy as np

from ...regime_codes import BRAKING, TRACTION
from ..config import FeatureConfig
from ..records import EFFORT_COASTING, EFFORT_POWER_COASTING

_NAN = math.nan
Values = TypeVar("Values", float, np.ndarray)
"""A float (online path) or an array of them (offline path)."""

KNOWN_ZERO_EFFORT = (EFFORT_COASTING, EFFORT_POWER_COASTING)
"""Effort sources (EFFORT_*) of a step whose effort the estimator took as a known zero (coasting)."""


# -- the step ------------------------------------------------------------------------------------------------------
def labelled_moving(regime: Values, v_mid: Values, standstill: float) -> Values:
    """Whether a step keeps its regime: its mean speed ``v_mid`` reaches ``standstill`` and its regime is one of
    TRACTION .. BRAKING; otherwise it counts as UNKNOWN (standing time)."""
    return (v_mid >= standstill) & (regime >= TRACTION) & (regime <= BRAKING)


def opposing_force(effort: float, accel: float, src: int) -> float:
    """w = r + g of a step (effort - acceleration), N/kg; NaN where the estimator took the effort as a known zero
    (``src`` in ``KNOWN_ZERO_EFFORT``): its acceleration is then the measured one, not the model's r + g."""
    return _NAN if src in KNOWN_ZERO_EFFORT else effort - accel


# -- max tractive effort and power ---------------------------------------------------------------------------------
def accelerating_traction(regime: Values, accel: Values) -> Values:
    """Whether a step counts for the max tractive effort and power: TRACTION with a positive acceleration."""
    return (regime == TRACTION) & (accel > 0.0)


def in_effort_window(v_mid: Values, cfg: FeatureConfig) -> Values:
    """Whether a step's mean speed lies in the max tractive effort fit window (inclusive)."""
    return (v_mid >= cfg.max_effort_window_low) & (v_mid <= cfg.max_effort_window_high)


def in_power_window(v_mid: Values, cfg: FeatureConfig) -> Values:
    """Whether a step's mean speed lies in the max tractive power window (inclusive)."""
    return (v_mid >= cfg.max_power_window_low) & (v_mid <= cfg.max_power_window_high)


def line_fit(n: int, sv: float, su: float, svv: float, svu: float) -> tuple[float, float, float]:
    """(value at mean v, intercept, slope) of the least-squares line u = a + b v, from the count and the sums of v,
    u, v^2 and v u."""
    if n == 0:
        return _NAN, _NAN, _NAN
    mean_v, mean_u = sv / n, su / n
    sxx = svv - sv * mean_v
    if n < 2 or not sxx > 1e-12 * max(svv, 1e-300):
        return mean_u, _NAN, _NAN
    slope = (svu - sv * mean_u) / sxx
    return mean_u, mean_u - slope * mean_v, slope


def sample_moments(x: np.ndarray) -> tuple[float, float, int]:
    """(mean, sample std, count) of the values; NaN where undefined (std needs two)."""
    mean = float(x.mean()) if x.size else _NAN
    std = float(x.std(ddof=1)) if x.size > 1 else _NAN
    return mean, std, int(x.size)


# -- brake rates ---------------------------------------------------------------------------------------------------
def brake_settled(t: Values, first_t: Values, window: float) -> Values:
    """Whether a braking sample at ``t`` counts: ``brake_window`` (2 % and 1 us slack) after the run's first braking
    sample ``first_t`` (before it, the acceleration window still reaches back before the braking)."""
    return t - first_t >= 0.98 * window - 1e-6


class SpeedSteps:
    """The brake-rate speed steps (lower bounds ``edges``, ascending; the last open above)."""

    def __init__(self, edges: Sequence[float]) -> None:
        self.edges = np.asarray(edges, dtype=float)
        self._edges = list(edges)

    def __len__(self) -> int:
        return len(self._edges)

    def index(self, v: Values) -> Values:
        """Step of speed v (-1 below the first edge): bisect for a float, searchsorted for an array (equal)."""
        if isinstance(v, np.ndarray):
            return np.searchsorted(self.edges, v, side="right") - 1
        return bisect.bisect_right(self._edges, v) - 1

    def of_brake_sample(self, v: Values, accel: Values, dt: Values, window: float) -> tuple[Values, Values]:
        """(index, counts): the step of a braking sample at speed v and whether its rate counts there, i.e. the speed
        over the acceleration window (``window`` or the step dt, the longer) stayed in that step."""
        i = self.index(v)
        return i, (i >= 0) & (i == self.index(v - accel * _longer(window, dt)))


def _longer(window: float, dt: Values) -> Values:
    """The longer of the window and the step (s): ``np.maximum`` for an array, ``max`` (faster) for a float."""
    return np.maximum(window, dt) if isinstance(dt, np.ndarray) else max(window, dt)


# -- cruise speeds ---------------------------------------------------------------------------------------------------
class CruisePhase(NamedTuple):
    """A cruising phase that counts (``cruise_min_duration``)."""

    speed: float
    """Median filtered speed of its samples, m/s."""
    speeds: np.ndarray
    """Filtered speed of each sample, m/s."""
    durations: np.ndarray
    """Duration of the step ending at each sample (>= 0), s: the weights of the run's cruise speed."""


def cruise_counts(start: float, end: float, cfg: FeatureConfig) -> bool:
    """Whether a cruising phase from ``start`` to ``end`` (s) counts: it lasts at least ``cruise_min_duration``."""
    return end - start >= cfg.cruise_min_duration


def cruise_phase(start: float, end: float, speeds: np.ndarray, durations: np.ndarray, cfg: FeatureConfig):
    """The phase from ``start`` to ``end`` (s) as a CruisePhase, or None when it does not count (``cruise_counts``;
    the paths ask that first, before they make the arrays)."""
    if cruise_counts(start, end, cfg):
        return CruisePhase(float(np.median(speeds)), speeds, durations)
    return None


def weighted_median(values: np.ndarray, weights: np.ndarray) -> float:
    """Lower weighted median (the smallest value whose cumulative weight reaches half)."""
    if values.size == 0:
        return _NAN
    order = np.argsort(values, kind="stable")
    cw = np.cumsum(weights[order])
    if cw[-1] <= 0.0:
        return float(np.median(values))
    return float(values[order][np.searchsorted(cw, 0.5 * cw[-1])])


def cruise_speeds(phases: list[CruisePhase]) -> tuple[np.ndarray, float]:
    """(median speed of each phase, the duration-weighted median over all their samples; NaN without a phase)."""
    speeds = np.array([p.speed for p in phases])
    if not phases:
        return speeds, _NAN
    values, weights = np.concatenate([p.speeds for p in phases]), np.concatenate([p.durations for p in phases])
    return speeds, weighted_median(values, weights)
