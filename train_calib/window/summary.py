"""Per-regime results of a run (De Martinis Section 5.3: acceleration, cruising, coasting, braking)."""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

from ..regime_codes import regime_name
from .fit import WindowFit


@dataclass(frozen=True)
class RegimeStats:
    """Well-posed window estimates whose dominant regime is ``regime``; forces in N for the whole train.

    median/iqr/mean are over the windows' own estimates of (A [N], B [N/(m/s)], C [N/(m/s)^2]);
    specific_median is the same median per unit effective mass (r0, r1, r2).
    """

    regime: int
    name: str
    windows: int  # well-posed windows
    ill_posed: int  # windows of this regime flagged ill posed (not in the statistics)
    median: tuple[float, float, float]
    iqr: tuple[float, float, float]
    mean: tuple[float, float, float]
    specific_median: tuple[float, float, float]


def summarize_by_regime(fits: Iterable[WindowFit], effective_mass_kg: float) -> dict[int, RegimeStats]:
    """Group the fits by dominant regime; statistics over the well-posed ones (NaN when there are none)."""
    by_regime: dict[int, list[tuple[float, float, float]]] = {}
    ill: dict[int, int] = {}
    for fit in fits:
        by_regime.setdefault(fit.regime, [])
        if fit.ill_posed:
            ill[fit.regime] = ill.get(fit.regime, 0) + 1
        else:
            by_regime[fit.regime].append(fit.estimate)
    out = {}
    for regime, estimates in sorted(by_regime.items()):
        r = np.array(estimates, dtype=float).reshape(-1, 3) * effective_mass_kg
        if len(r):
            q1, med, q3 = np.percentile(r, [25, 50, 75], axis=0)
            mean = r.mean(axis=0)
        else:
            q1 = med = q3 = mean = np.full(3, np.nan)
        out[regime] = RegimeStats(
            regime=regime,
            name=regime_name(regime),
            windows=len(r),
            ill_posed=ill.get(regime, 0),
            median=tuple(float(x) for x in med),
            iqr=tuple(float(x) for x in q3 - q1),
            mean=tuple(float(x) for x in mean),
            specific_median=tuple(float(x) for x in med / effective_mass_kg),
        )
    return out
