"""Errors of a calibration on a run: their E_k (eq. 8) and the resistance curve against a known truth."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ..measurement import MeasurementSeries
from ..physics import KMH
from ..train import TrainSpec
from .config import WindowConfig
from .fit import WindowFit
from .model import DifferenceRows, difference_rows, tractive_force


def series_rows(series: MeasurementSeries, train: TrainSpec, config: WindowConfig) -> DifferenceRows:
    """Eq. 4 rows of a whole series (row k is the step from sample k to k+1); invalid without power."""
    force = tractive_force(series.v, series.power_consumed, series.power_regenerated, train, config.min_speed)
    force = np.where(series.power_valid, force / train.effective_mass_kg, np.nan)
    return difference_rows(series.t, series.v, force, series.track_force, series.tunnel_fraction, train, config,
                           v_variance=series.v_variance, segment=series.run_id)  # fmt: skip


def step_errors(rows: DifferenceRows, theta, effective_mass_kg: float) -> np.ndarray:
    """E_k = M (y_k - x_k theta_k) in N per row (eq. 8); theta is one (r0, r1, r2) or one per row; NaN if invalid."""
    theta = np.broadcast_to(np.asarray(theta, dtype=float), rows.x.shape)
    e = (rows.y - np.einsum("ij,ij->i", rows.x, theta)) * effective_mass_kg
    return np.where(rows.valid, e, np.nan)


@dataclass(frozen=True)
class StepErrorReport:
    """Mean |E_k| and RMS E_k (N) over the steps that every parameter set could be evaluated on."""

    steps: int
    mean_abs: dict[str, float]
    rms: dict[str, float]


def windowed_thetas(series: MeasurementSeries, fits: Sequence[WindowFit], lag: int = 0, published: bool = False):
    """(r0, r1, r2) per row k of the series from the fit whose window ends with step k (lag 0, in-sample,
    as their eq. 8) or with step k - lag (lag 1: one step ahead, out of sample). NaN where there is none.

    published: use the published values (held over ill-posed windows) instead of each window's own estimate.
    """
    index = {fit.stamp_ns: fit for fit in fits}
    theta = np.full((len(series) - 1, 3), np.nan)
    for k in range(len(series) - 1):
        j = k + 1 - lag
        fit = index.get(int(series.stamp_ns[j])) if j >= 0 else None
        if fit is not None:
            theta[k] = (fit.r0, fit.r1, fit.r2) if published else fit.estimate
    return theta


def compare_step_errors(rows: DifferenceRows, thetas: dict[str, np.ndarray], effective_mass_kg: float):
    """StepErrorReport for several parameter sets (each one triple or one per row) on common rows."""
    errors = {name: step_errors(rows, theta, effective_mass_kg) for name, theta in thetas.items()}
    common = np.logical_and.reduce([np.isfinite(e) for e in errors.values()])
    mean_abs = {name: float(np.mean(np.abs(e[common]))) for name, e in errors.items()}
    rms = {name: float(np.sqrt(np.mean(e[common] ** 2))) for name, e in errors.items()}
    return StepErrorReport(int(common.sum()), mean_abs, rms)


def resistance_at(theta, speeds_kmh: Sequence[float] = (40.0, 80.0, 120.0)) -> np.ndarray:
    """Open-air r(v) in N/kg at the given speeds for one theta (3,) or many (n, 3) -> (n, len(speeds))."""
    theta = np.atleast_2d(np.asarray(theta, dtype=float))
    v = np.asarray(speeds_kmh, dtype=float) * KMH
    return theta[:, :1] + theta[:, 1:2] * v + theta[:, 2:3] * v * v


def resistance_errors(fits: Sequence[WindowFit], truth, speeds_kmh: Sequence[float] = (40.0, 80.0, 120.0),
                      well_posed_only: bool = True) -> np.ndarray:  # fmt: skip
    """Relative error (estimate - truth) / truth of r(v) at the speeds, one row per window estimate."""
    chosen = [f.estimate for f in fits if not (well_posed_only and f.ill_posed)]
    if not chosen:
        return np.zeros((0, len(speeds_kmh)))
    true = resistance_at(truth, speeds_kmh)
    return (resistance_at(chosen, speeds_kmh) - true) / true
