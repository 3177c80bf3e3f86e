"""The features record (a mirror of DrivingFeatures.msg in SI units) and how both paths fill it."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from ...regime_codes import BRAKING, COASTING, UNKNOWN
from ..config import FeatureConfig
from .final_phases import FinalPhases
from .rules import CruisePhase, cruise_speeds, line_fit

_NAN = math.nan


@dataclass
class Features:
    """Mirror of DrivingFeatures.msg (SI units); NaN with count 0 where there is no data yet."""

    stamp_ns: int = 0
    run_id: int = 0
    run_complete: bool = False
    run_time: float = 0.0
    run_distance: float = 0.0
    regime: int = UNKNOWN
    max_tractive_effort_window_low: float = _NAN
    max_tractive_effort_window_high: float = _NAN
    max_tractive_effort: float = _NAN
    max_tractive_effort_intercept: float = _NAN
    max_tractive_effort_slope: float = _NAN
    max_tractive_effort_count: int = 0
    max_tractive_power_window_low: float = _NAN
    max_tractive_power_window_high: float = _NAN
    max_tractive_power: float = _NAN
    max_tractive_power_std: float = _NAN
    max_tractive_power_count: int = 0
    brake_step_low: np.ndarray = field(default_factory=lambda: np.zeros(0))
    brake_step_high: np.ndarray = field(default_factory=lambda: np.zeros(0))
    brake_rate_mean: np.ndarray = field(default_factory=lambda: np.zeros(0))
    brake_rate_std: np.ndarray = field(default_factory=lambda: np.zeros(0))
    brake_rate_count: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.uint32))
    cruise_speeds: np.ndarray = field(default_factory=lambda: np.zeros(0))
    cruise_speed: float = _NAN
    regime_time_share: np.ndarray = field(default_factory=lambda: np.zeros(5))
    final_coast_duration: float = _NAN
    final_coast_distance: float = _NAN
    final_brake_duration: float = _NAN
    final_brake_distance: float = _NAN

    def as_dict(self) -> dict:
        """JSON-friendly (lists for arrays, None for NaN)."""
        out = {}
        for name in self.__dataclass_fields__:
            value = getattr(self, name)
            if isinstance(value, np.ndarray):
                value = [None if isinstance(x, float) and math.isnan(x) else x for x in value.tolist()]
            elif isinstance(value, float) and math.isnan(value):
                value = None
            out[name] = value
        return out


# -- filling a record: the same for the online and the offline path -------------------------------------------------
class FeatureParts(NamedTuple):
    """What either path has computed of a run, for ``fill``."""

    effort_sums: tuple[int, float, float, float, float]
    """Max tractive effort fit: n, sum v (m/s), sum u (N/kg), sum v^2, sum v u."""
    power: tuple[float, float, int]
    """Max tractive power: mean (W/kg), sample std (W/kg), count."""
    brake_edges: np.ndarray
    """Lower bounds of the brake-rate speed steps, m/s."""
    brake_rates: list[tuple[float, float, int]]
    """Per speed step: mean brake rate (m/s^2), sample std (m/s^2), count."""
    cruise: list[CruisePhase]
    """The cruising phases that count."""
    time_per_regime: np.ndarray | list[float]
    """Time per regime code, s."""
    total_time: float
    """Their sum (the steps of positive duration), s."""
    final: FinalPhases
    """The final coast and brake tracker."""


def fill(f: Features, cfg: FeatureConfig, parts: FeatureParts) -> Features:
    """Set every feature field of ``f`` (all but stamp, run, run time and distance and regime) from ``parts``."""
    f.max_tractive_effort_window_low = cfg.max_effort_window_low
    f.max_tractive_effort_window_high = cfg.max_effort_window_high
    f.max_tractive_effort, f.max_tractive_effort_intercept, f.max_tractive_effort_slope = line_fit(*parts.effort_sums)
    f.max_tractive_effort_count = parts.effort_sums[0]
    f.max_tractive_power_window_low = cfg.max_power_window_low
    f.max_tractive_power_window_high = cfg.max_power_window_high
    f.max_tractive_power, f.max_tractive_power_std, f.max_tractive_power_count = parts.power
    edges, rates = parts.brake_edges, parts.brake_rates
    f.brake_step_low = edges.copy()
    f.brake_step_high = np.append(edges[1:], np.inf)
    f.brake_rate_mean = np.array([r[0] for r in rates])
    f.brake_rate_std = np.array([r[1] for r in rates])
    f.brake_rate_count = np.array([r[2] for r in rates], dtype=np.uint32)
    f.cruise_speeds, f.cruise_speed = cruise_speeds(parts.cruise)
    total = parts.total_time
    f.regime_time_share = np.asarray(parts.time_per_regime) / total if total > 0.0 else np.zeros(5)
    f.final_coast_duration, f.final_coast_distance = parts.final.result(COASTING)
    f.final_brake_duration, f.final_brake_distance = parts.final.result(BRAKING)
    return f
