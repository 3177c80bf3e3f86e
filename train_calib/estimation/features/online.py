"""The running features of the current run, updated per estimate (the feature node's core).

Units: times s (stamps ns), positions m, speeds m/s, accelerations m/s^2, efforts N/kg.
"""

from __future__ import annotations

import math

import numpy as np

from ...regime_codes import BRAKING, CRUISING, UNKNOWN
from ..config import FeatureConfig
from ..records import EFFORT_COMPUTED, EstimateSample
from . import rules
from .boundaries import fit_speed, new_point
from .brake_rates import BrakeRates, Moments
from .final_phases import FinalPhases
from .record import FeatureParts, Features, fill
from .rules import accelerating_traction, in_effort_window, in_power_window, labelled_moving


class FeatureAccumulator:
    """Running features of the current run, updated per estimate (the feature node's core)."""

    def __init__(self, config: FeatureConfig | None = None) -> None:
        self.config = config if config is not None else FeatureConfig()
        self._steps = rules.SpeedSteps(self.config.brake_step_edges)
        self.reset()

    def reset(self) -> None:
        """Forget the run (the next sample starts a new one)."""
        self._run_id: int | None = None
        self._stamp = 0
        self._t0 = 0.0
        self._t = 0.0
        self._s0 = 0.0
        self._s = 0.0
        self._v = 0.0
        self._regime = UNKNOWN
        self._shares = [0.0] * 5  # time per regime, s
        self._fit = [0, 0.0, 0.0, 0.0, 0.0]  # effort fit: n, sum v, sum u, sum v^2, sum v u
        self._power = Moments()
        self._brake = BrakeRates(len(self._steps), self.config.boundary_refinement)
        self._brake_first_t = 0.0
        self._cruise_done: list[rules.CruisePhase] = []
        self._cruise_v: list[float] = []
        self._cruise_dt: list[float] = []
        self._cruise_start = 0.0
        self._final = FinalPhases(self.config)

    def update(self, sample: EstimateSample, regime: int) -> bool:
        """Add one estimate with its regime; True when the regime changed (publish the features).

        Per step: v the filtered speed, v_fit the speed the phase changes are located on (``fit_speed``), m/s; src
        the effort source (EFFORT_*). (One method, no per-sample helpers: it runs once a sample.)"""
        stamp, run_id, s, v = int(sample.stamp_ns), int(sample.run_id), float(sample.s), float(sample.v)
        effort, accel, regime = float(sample.effort), float(sample.acceleration), int(regime)
        v_fit = fit_speed(v, float(getattr(sample, "v_measured", math.nan)))
        src = int(getattr(sample, "effort_source", EFFORT_COMPUTED))
        t = stamp * 1e-9
        if run_id != self._run_id:
            self._start_run(stamp, run_id, t, s, v, regime, v_fit)
            return True
        t_prev, dt = self._t, t - self._t
        v_mid = 0.5 * (self._v + v)
        cfg = self.config
        if not labelled_moving(regime, v_mid, cfg.standstill_speed):
            regime = UNKNOWN
        if dt > 0.0:  # a step of positive duration: its time share, effort fit and power, or brake rate
            self._shares[regime] += dt
            if accelerating_traction(regime, accel):
                if in_effort_window(v_mid, cfg):
                    f = self._fit
                    f[0] += 1
                    f[1] += v_mid
                    f[2] += effort
                    f[3] += v_mid * v_mid
                    f[4] += v_mid * effort
                if in_power_window(v_mid, cfg):
                    self._power.add(effort * v_mid)
            elif regime == BRAKING:
                self._brake_sample(t, v, accel, dt)
        if regime == CRUISING or self._regime == CRUISING:
            self._cruise_step(t_prev, v, regime, dt)
        self._final.step(new_point((t, s, v_fit, accel, v, src)), regime, effort)
        brake = self._brake
        if self._regime == BRAKING and regime != BRAKING:
            brake.end_run(self._final.latest)
        elif brake.closing:
            brake.settle()  # (nothing to settle without ended runs waiting)
        changed = regime != self._regime
        self._stamp, self._t, self._s, self._v, self._regime = stamp, t, s, v, regime
        return changed

    def _start_run(self, stamp: int, run_id: int, t: float, s: float, v: float, regime: int, v_fit: float) -> None:
        """The first sample of a run."""
        self.reset()
        self._run_id = run_id
        self._stamp, self._t0, self._t, self._s0, self._s, self._v = stamp, t, t, s, s, v
        self._regime = regime if v >= self.config.standstill_speed else UNKNOWN
        self._final.first(t, s, v, v_fit, self._regime)

    def _brake_sample(self, t: float, v: float, accel: float, dt: float) -> None:
        """A braking step of positive duration: its brake rate, once settled and held in its speed step."""
        if self._regime != BRAKING:
            self._brake_first_t = t
        window = self.config.brake_window
        if rules.brake_settled(t, self._brake_first_t, window):
            i, counts = self._steps.of_brake_sample(v, accel, dt, window)
            if counts:
                self._brake.add(t, i, -accel)

    def _cruise_step(self, t_prev: float, v: float, regime: int, dt: float) -> None:
        """Collect the cruising phase's samples; close it at the step after it (t_prev: its last sample)."""
        if regime == CRUISING:
            if self._regime != CRUISING:
                self._cruise_v, self._cruise_dt, self._cruise_start = [], [], t_prev
            self._cruise_v.append(v)
            self._cruise_dt.append(0.0 if dt < 0.0 else dt)  # max(dt, 0.0), without the call
        elif self._regime == CRUISING:
            phase = self._cruise_phase(t_prev)
            if phase is not None:
                self._cruise_done.append(phase)
            self._cruise_v, self._cruise_dt = [], []

    def _cruise_phase(self, t_end: float) -> rules.CruisePhase | None:
        """The current cruising phase ending at t_end, if it counts."""
        if not self._cruise_v or not rules.cruise_counts(self._cruise_start, t_end, self.config):
            return None
        speeds, durations = np.array(self._cruise_v), np.array(self._cruise_dt)
        return rules.cruise_phase(self._cruise_start, t_end, speeds, durations, self.config)

    def snapshot(self, run_complete: bool = False) -> Features:
        """Features of the run so far (``run_complete`` is copied into the record)."""
        cfg = self.config
        f = Features(stamp_ns=self._stamp, run_id=self._run_id or 0, run_complete=bool(run_complete))
        f.run_time = self._t - self._t0
        f.run_distance = self._s - self._s0
        f.regime = self._regime
        phases = list(self._cruise_done)
        current = self._cruise_phase(self._t) if self._regime == CRUISING else None
        if current is not None:
            phases.append(current)
        parts = FeatureParts(
            effort_sums=tuple(self._fit),
            power=self._power.result(),
            brake_edges=self._steps.edges,
            brake_rates=self._brake.result(),
            cruise=phases,
            time_per_regime=self._shares,
            total_time=sum(self._shares),
            final=self._final,
        )
        fill(f, cfg, parts)
        return f
