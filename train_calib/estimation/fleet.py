"""Statistics of driving features across runs (Cunillera et al. 2022, Section 4.3-4.4: histograms, CV)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..physics import KMH
from .features import Features
from .regimes import REGIME_NAMES

SCALAR_FEATURES: tuple[tuple[str, str], ...] = (
    ("max_tractive_effort", "N/kg"),
    ("max_tractive_power", "W/kg"),
    ("cruise_speed", "m/s"),
    ("final_coast_duration", "s"),
    ("final_coast_distance", "m"),
    ("final_brake_duration", "s"),
    ("final_brake_distance", "m"),
    ("run_time", "s"),
    ("run_distance", "m"),
)


@dataclass
class FeatureStatistics:
    """One feature over the runs that have it (NaN values are left out)."""

    name: str
    unit: str
    count: int
    mean: float
    std: float  # sample standard deviation (ddof 1), NaN below 2 runs
    cv: float  # std / |mean|
    minimum: float
    maximum: float
    hist_counts: np.ndarray
    hist_edges: np.ndarray

    @classmethod
    def of(cls, name: str, unit: str, values, bins: int) -> FeatureStatistics:
        x = np.asarray(values, dtype=float)
        x = x[np.isfinite(x)]
        if x.size == 0:
            nan = math.nan
            return cls(name, unit, 0, nan, nan, nan, nan, nan, np.zeros(0, dtype=np.int64), np.zeros(0))
        mean = float(x.mean())
        std = float(x.std(ddof=1)) if x.size > 1 else math.nan
        cv = std / abs(mean) if mean != 0.0 and math.isfinite(std) else math.nan
        counts, edges = np.histogram(x, bins=bins)
        return cls(name, unit, int(x.size), mean, std, cv, float(x.min()), float(x.max()), counts, edges)


@dataclass
class FleetStatistics:
    """Per-feature statistics over a set of runs; ``features`` keyed by feature name."""

    runs: int
    features: dict[str, FeatureStatistics] = field(default_factory=dict)

    def __getitem__(self, name: str) -> FeatureStatistics:
        return self.features[name]

    def table(self) -> str:
        """Markdown table: feature, unit, runs, mean, std, CV, min, max."""
        lines = ["| feature | unit | runs | mean | std | CV | min | max |", "|---|---|---|---|---|---|---|---|"]
        for st in self.features.values():
            lines.append(
                f"| {st.name} | {st.unit} | {st.count} | {st.mean:.4g} | {st.std:.3g} | {st.cv:.1%} | "
                f"{st.minimum:.4g} | {st.maximum:.4g} |"
            )
        return "\n".join(lines)


def _step_name(low: float, high: float) -> str:
    lo = f"{low / KMH:.0f}"
    hi = "inf" if math.isinf(high) else f"{high / KMH:.0f}"
    return f"brake_rate_{lo}_{hi}kmh"


def fleet_statistics(runs: list[Features], bins: int = 10) -> FleetStatistics:
    """Histograms and coefficients of variation of every scalar feature, brake step and regime share."""
    out = FleetStatistics(runs=len(runs))
    for name, unit in SCALAR_FEATURES:
        out.features[name] = FeatureStatistics.of(name, unit, [getattr(f, name) for f in runs], bins)
    if runs:
        lows, highs = runs[0].brake_step_low, runs[0].brake_step_high
        for i, (lo, hi) in enumerate(zip(lows, highs)):
            values = [f.brake_rate_mean[i] if i < len(f.brake_rate_mean) else math.nan for f in runs]
            name = _step_name(float(lo), float(hi))
            out.features[name] = FeatureStatistics.of(name, "m/s^2", values, bins)
    for i, regime in enumerate(REGIME_NAMES):
        name = f"time_share_{regime}"
        out.features[name] = FeatureStatistics.of(name, "1", [f.regime_time_share[i] for f in runs], bins)
    cruise = [v for f in runs for v in np.asarray(f.cruise_speeds).tolist()]
    out.features["cruise_speeds_all"] = FeatureStatistics.of("cruise_speeds_all", "m/s", cruise, bins)
    return out
