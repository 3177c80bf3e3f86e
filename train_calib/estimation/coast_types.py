"""The coast regression's data types: its settings, the samples it looks at (RunArrays) and one coasting stretch's
equations (Stretch); shared by the time form (:mod:`coast_detection`, :mod:`coast_regression`) and the energy form
(:mod:`coast_energy`)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from ..train import TrainSpec
from .effort import PowerEffort


@dataclass(frozen=True)
class CoastSettings:
    """The coast regression's settings (UKFConfig fields of the same names; units in UKFConfig)."""

    prior_scale_std: float = 0.18
    prior_coefficient_std: float = 0.10
    coast_ratio_min: float = 0.4
    coast_ratio_max: float = 2.5
    coast_hold_sigmas: float = 3.0
    coast_slope_precision: float = 0.2
    coast_window_min: float = 10.0
    coast_window_samples: float = 4.0
    coast_min_duration: float = 12.0
    coast_stretch_std: float = 0.03
    coast_min_speed: float = 5.0
    coast_energy_period: float = 5.0  # s
    coast_energy_window: float = 4.0  # samples
    coast_energy_end_effort: float = 0.5  # N/kg
    coast_energy_grade_error: float = 0.1  # of r
    use_power: bool = True
    power_coasting: bool = True
    power_threshold: float = 0.005
    max_gap: float = 30.0

    @classmethod
    def from_config(cls, config) -> CoastSettings:
        """From a UKFConfig (or anything with the same attribute names)."""
        flags = ("use_power", "power_coasting")
        names = [f for f in cls.__dataclass_fields__ if f not in ("max_gap", *flags)]
        values: dict = {n: float(getattr(config, n)) for n in names}
        values.update({n: bool(getattr(config, n)) for n in flags})
        return cls(**values)

    @property
    def power_decides(self) -> bool:
        """Measured power marks coasting (no traction, no regeneration) and excludes traction and braking."""
        return self.use_power and self.power_coasting


def davis_value(r: np.ndarray | tuple[float, float, float], v: float | np.ndarray) -> float | np.ndarray:
    """r0 + r1 v + r2 v^2 (N/kg)."""
    return r[0] + (r[1] + r[2] * v) * v


POWER_UNKNOWN, POWER_NONE, POWER_DRIVE = 0, 1, 2
"""Per sample: no power measurement; neither traction nor regeneration (coasting, or a pneumatic brake); traction or
electric braking."""


def power_states(
    train: TrainSpec, valid: np.ndarray, consumed_w: np.ndarray, regenerated_w: np.ndarray, threshold: float
) -> np.ndarray:
    """POWER_* per sample from the pantograph power: traction where the wheel power eta (P - P_aux) / (gamma m)
    exceeds ``threshold`` (W/kg), electric braking where anything is regenerated."""
    wheel = PowerEffort(train).wheel_power(np.asarray(consumed_w, dtype=float))
    drive = (wheel > threshold) | (np.asarray(regenerated_w, dtype=float) > 0.0)
    out = np.where(drive, POWER_DRIVE, POWER_NONE).astype(np.int8)
    out[~np.asarray(valid, dtype=bool)] = POWER_UNKNOWN
    return out


@dataclass
class RunArrays:
    """The samples a regression looks at (one recording; several run_ids allowed, in time order)."""

    t: np.ndarray  # s
    v: np.ndarray  # m/s, measured
    g: np.ndarray  # N/kg, track force at the measured position
    tunnel: np.ndarray  # fraction of the train in a tunnel
    run: np.ndarray  # run id
    power: np.ndarray | None = None  # POWER_* per sample (None: no power measured)
    s: np.ndarray | None = None  # m, position along the track (None: not known; the energy form needs it)
    gamma: np.ndarray | None = None  # J/kg, the track force's integral over s (Measurement.track_force_integral)
    s_var: np.ndarray | None = None  # m^2, variance of s
    v_var: np.ndarray | None = None  # (m/s)^2, the speed sensor's stated variance (Measurement.v_variance)

    @classmethod
    def from_columns(
        cls,
        t: np.ndarray,
        v: np.ndarray,
        g: np.ndarray,
        tunnel: np.ndarray,
        run: np.ndarray,
        power_valid: np.ndarray,
        power_consumed_w: np.ndarray,
        power_regenerated_w: np.ndarray,
        train: TrainSpec | None = None,
        settings: CoastSettings | None = None,
        s: np.ndarray | None = None,
        gamma: np.ndarray | None = None,
        s_var: np.ndarray | None = None,
        v_var: np.ndarray | None = None,
    ) -> RunArrays:
        """From measurement columns (t in s); with the train, the power states of the traction power (if any);
        s, gamma, s_var, v_var where known (the energy form)."""
        power = None
        if train is not None and np.any(power_valid):
            threshold = (settings or CoastSettings()).power_threshold
            power = power_states(train, power_valid, power_consumed_w, power_regenerated_w, threshold)
        return cls(
            t=np.asarray(t, dtype=float),
            v=np.asarray(v, dtype=float),
            g=np.asarray(g, dtype=float),
            tunnel=np.asarray(tunnel, dtype=float),
            run=np.asarray(run, dtype=np.int64),
            power=power,
            **{
                name: None if x is None else np.asarray(x, dtype=float)
                for name, x in (("s", s), ("gamma", gamma), ("s_var", s_var), ("v_var", v_var))
            },
        )

    @classmethod
    def from_series(cls, series, train: TrainSpec | None = None, settings: CoastSettings | None = None) -> RunArrays:
        """From a MeasurementSeries (t from its first stamp): :meth:`from_columns`."""
        t = (series.stamp_ns - series.stamp_ns[0]) * 1e-9 if len(series) else np.zeros(0)
        return cls.from_columns(
            t, series.v, series.track_force, series.tunnel_fraction, series.run_id, series.power_valid,
            series.power_consumed, series.power_regenerated, train, settings, series.s,
            series.track_force_integral, series.s_variance, series.v_variance,
        )  # fmt: skip

    def part(self, sl: slice | np.ndarray) -> RunArrays:
        """The samples of a slice or a boolean mask (every column)."""
        cut = {k: (None if x is None else x[sl]) for k, x in vars(self).items()}
        return RunArrays(**cut)


class EndMixture(NamedTuple):
    """A stretch in the energy form with its ends uncertain (:func:`coast_energy.end_mixture`): the samples from the
    outer neighbour before its first sample to the one after its last, E = E0 + H r + noise over them, and the
    configurations of which samples coast. A sample outside a configuration's coasting part keeps its equation with
    the variance of an effort over its step added."""

    E: np.ndarray  # (n,) v^2/2 + Gamma(s), J/kg
    H: np.ndarray  # (n, 3) -(s - s_a, integral of v ds, integral of v^2 (1 + f_tun tunnel) ds): m, m^2/s, m^3/s^2
    var: np.ndarray  # (n,) the noise variance of E, (J/kg)^2
    effort_var: np.ndarray  # (n,) the variance added where a sample is not coasting, (J/kg)^2
    distance: np.ndarray  # (n,) s - s at the stretch's first sample, m (the direction of the coast's common error)
    masks: np.ndarray  # (configurations, n) bool: the samples taken as coasting in each configuration


@dataclass
class Stretch:
    """One coasting stretch used by the regression: its samples' centred equations y = A r + noise (step 5)."""

    t_start: float  # s
    t_end: float  # s
    speed_min: float  # m/s
    speed_max: float  # m/s
    A: np.ndarray  # (n, 3) centred -(t - t0, integral of v, integral of v^2 (1 + f_tun tunnel)): s, m, m^2/s
    y: np.ndarray  # (n,) centred v + integral of g, m/s
    tau: np.ndarray  # (n,) centred time, s (the direction of an error common to the coast)
    noise_var: float  # (m/s)^2, the speed noise's variance per sample
    bias_std: float  # N/kg, std of the error common to the coast
    run: int = 0
    group: int = 0  # stretches of one coast (split by a short gap) share their bias
    ends: EndMixture | None = None  # energy form: the samples around the stretch and its configurations of ends
