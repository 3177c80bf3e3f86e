"""Gradients from the recorded GNSS altitude when no profile is given: a straight-line fit of altitude against
chainage over each ``step_m`` segment (every run's fixes pooled), with the slope's standard error."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import ConfigError


@dataclass
class AltitudeGradients:
    """Segments' start (track s, m), gradient and its 1-sigma (per mille), and the altitude scatter (m)."""

    s_m: np.ndarray
    permille: np.ndarray
    sigma_permille: np.ndarray
    altitude_scatter_m: float


def gradients_from_altitude(
    s_m: np.ndarray, alt_m: np.ndarray, length_m: float, step_m: float, source: str
) -> AltitudeGradients:
    """Fit each segment [k step, (k+1) step); a segment with under 3 fixes takes its neighbour's gradient."""
    ok = np.isfinite(alt_m)
    if ok.sum() < 10 or np.all(alt_m[ok] == alt_m[ok][0]):
        raise ConfigError(source, "altitude", "the GNSS altitude is missing or constant: give --profile")
    s, a = s_m[ok], alt_m[ok]
    edges = np.arange(0.0, length_m, step_m)
    grad = np.full(edges.size, np.nan)
    sigma = np.full(edges.size, np.nan)
    resid: list[np.ndarray] = []
    for k, lo in enumerate(edges):
        inside = (s >= lo) & (s < lo + step_m)
        if inside.sum() < 3 or np.ptp(s[inside]) < 0.3 * step_m:
            continue
        x, y = s[inside] - lo, a[inside]
        coef = np.polyfit(x, y, 1)
        r = y - np.polyval(coef, x)
        resid.append(r)
        dof = max(x.size - 2, 1)
        s2 = float(r @ r) / dof
        sxx = float(((x - x.mean()) ** 2).sum())
        grad[k] = coef[0] * 1000.0
        sigma[k] = np.sqrt(s2 / sxx) * 1000.0
    if np.all(np.isnan(grad)):
        raise ConfigError(source, "altitude", f"too few fixes with altitude for {step_m:g} m segments")
    filled = np.flatnonzero(~np.isnan(grad))
    idx = filled[np.clip(np.searchsorted(filled, np.arange(grad.size)), 0, filled.size - 1)]
    grad, sigma = grad[idx], sigma[idx]
    scatter = float(np.std(np.concatenate(resid))) if resid else float("nan")
    return AltitudeGradients(edges, np.clip(grad, -99.0, 99.0), sigma, scatter)
