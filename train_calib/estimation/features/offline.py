"""The features of a whole run at once (vectorised over the steps), equal to ``FeatureAccumulator`` after the last
sample; one helper per feature.

Units: times s (stamps ns), positions m, speeds m/s, accelerations m/s^2, efforts N/kg.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ...regime_codes import BRAKING, CRUISING, UNKNOWN
from ..config import FeatureConfig
from ..records import EstimateSeries
from . import rules
from .boundaries import Change, fit_speeds, new_point
from .brake_rates import run_end_time
from .final_phases import FinalPhases
from .online import FeatureAccumulator
from .record import FeatureParts, Features, fill


class _Steps(NamedTuple):
    """The steps of a run as arrays; index k is the step from sample k to sample k + 1."""

    t: np.ndarray
    """Time of each sample (n), s."""
    dt: np.ndarray
    """Duration, s."""
    v_mid: np.ndarray
    """Mean speed (v_prev + v) / 2, m/s."""
    regime: np.ndarray
    """Regime (int64), UNKNOWN where standing or not a driving regime."""
    positive: np.ndarray
    """dt > 0."""
    accelerating: np.ndarray
    """Positive duration, TRACTION and acceleration > 0 (the effort fit's and the power's steps)."""
    effort: np.ndarray
    """Effort of the step (of the sample ending it), N/kg."""
    accel: np.ndarray
    """Published acceleration of the step, m/s^2."""
    first: int
    """Regime of the first sample (UNKNOWN where standing)."""


def _runs(values: np.ndarray) -> list[tuple[int, int]]:
    """(start, stop) index pairs of maximal runs of equal values."""
    if values.size == 0:
        return []
    cuts = np.flatnonzero(values[1:] != values[:-1]) + 1
    starts = np.concatenate(([0], cuts))
    stops = np.concatenate((cuts, [values.size]))
    return list(zip(starts.tolist(), stops.tolist()))


def _checked_regimes(estimates: EstimateSeries, regimes: np.ndarray) -> np.ndarray:
    """The regimes as int64, one per estimate of a single run (ValueError otherwise)."""
    n = len(estimates)
    regimes = np.asarray(regimes).astype(np.int64)
    if regimes.shape != (n,):
        raise ValueError(f"regimes: expected shape ({n},), found {regimes.shape}")
    if n and np.any(estimates.run_id != estimates.run_id[0]):
        raise ValueError("estimates: several run_ids; use features_per_run()")
    return regimes


def _steps_of(estimates: EstimateSeries, regimes: np.ndarray, cfg: FeatureConfig) -> _Steps:
    """The run's steps (at least two samples)."""
    t, v = estimates.stamp_ns * 1e-9, estimates.v
    dt = np.diff(t)
    v_mid = 0.5 * (v[1:] + v[:-1])
    reg = np.where(rules.labelled_moving(regimes[1:], v_mid, cfg.standstill_speed), regimes[1:], UNKNOWN)
    first = regimes[0] if rules.labelled_moving(regimes[0], v[0], cfg.standstill_speed) else UNKNOWN
    effort, accel = estimates.effort[1:], estimates.acceleration[1:]
    pos = dt > 0.0
    accelerating = pos & rules.accelerating_traction(reg, accel)
    return _Steps(t, dt, v_mid, reg, pos, accelerating, effort, accel, int(first))


def extract_features(
    estimates: EstimateSeries, regimes: np.ndarray, config: FeatureConfig | None = None, run_complete: bool = True
) -> Features:
    """Features of one whole run (vectorised); equal to FeatureAccumulator after the last sample."""
    cfg = config if config is not None else FeatureConfig()
    n = len(estimates)
    regimes = _checked_regimes(estimates, regimes)
    if n == 0:
        return FeatureAccumulator(cfg).snapshot(run_complete)
    steps = _steps_of(estimates, regimes, cfg)
    f = Features(stamp_ns=int(estimates.stamp_ns[-1]), run_id=int(estimates.run_id[0]), run_complete=run_complete)
    f.run_time = float(steps.t[-1] - steps.t[0])
    f.run_distance = float(estimates.s[-1] - estimates.s[0])
    f.regime = int(steps.regime[-1]) if n > 1 else steps.first
    phases = _runs(steps.regime)
    final, brake_ends = _final_phases(estimates, steps, cfg)
    speed_steps = rules.SpeedSteps(cfg.brake_step_edges)
    brake_rates = _brake_rates(estimates.v, steps, phases, brake_ends, speed_steps, cfg)
    time_per_regime, total = _time_per_regime(steps)
    parts = FeatureParts(
        effort_sums=_effort_fit_sums(steps, cfg),
        power=rules.sample_moments(_powers(steps, cfg)),
        brake_edges=speed_steps.edges,
        brake_rates=brake_rates,
        cruise=_cruise_phases(estimates.v, steps, phases, cfg),
        time_per_regime=time_per_regime,
        total_time=total,
        final=final,
    )
    return fill(f, cfg, parts)


def _effort_fit_sums(steps: _Steps, cfg: FeatureConfig) -> tuple[int, float, float, float, float]:
    """(n, sum v, sum u, sum v^2, sum v u) over the steps of the max tractive effort fit."""
    m = steps.accelerating & rules.in_effort_window(steps.v_mid, cfg)
    vm, um = steps.v_mid[m], steps.effort[m]
    return int(m.sum()), float(vm.sum()), float(um.sum()), float((vm * vm).sum()), float((vm * um).sum())


def _powers(steps: _Steps, cfg: FeatureConfig) -> np.ndarray:
    """effort * v_mid (W/kg) of the steps of the max tractive power."""
    m = steps.accelerating & rules.in_power_window(steps.v_mid, cfg)
    return steps.effort[m] * steps.v_mid[m]


def _time_per_regime(steps: _Steps) -> tuple[np.ndarray, float]:
    """(time per regime code, their sum), s, over the steps of positive duration."""
    pos = steps.positive
    return np.bincount(steps.regime[pos], weights=steps.dt[pos], minlength=5), float(steps.dt[pos].sum())


def _cruise_phases(
    v: np.ndarray, steps: _Steps, phases: list[tuple[int, int]], cfg: FeatureConfig
) -> list[rules.CruisePhase]:
    """The cruising phases that count; v: the filtered speed of each sample, m/s."""
    out = []
    t = steps.t
    for a, b in phases:
        if steps.regime[a] == CRUISING and rules.cruise_counts(t[a], t[b], cfg):
            phase = rules.cruise_phase(t[a], t[b], v[a + 1 : b + 1], np.maximum(steps.dt[a:b], 0.0), cfg)
            if phase is not None:
                out.append(phase)
    return out


def _final_phases(
    estimates: EstimateSeries, steps: _Steps, cfg: FeatureConfig
) -> tuple[FinalPhases, dict[int, Change | None]]:
    """The final coast and brake tracker after every step (the accumulator's, phase changes located on the speed),
    and the change that ended each braking run, by the index of the step after it."""
    final = FinalPhases(cfg)
    tl, sl, vl, rl = steps.t.tolist(), estimates.s.tolist(), estimates.v.tolist(), steps.regime.tolist()
    fl = fit_speeds(estimates.v, estimates.v_measured).tolist()
    al, el = estimates.acceleration.tolist(), estimates.effort.tolist()
    srcl = estimates.effort_source.tolist()
    final.first(tl[0], sl[0], vl[0], fl[0], steps.first)
    r_prev = steps.first
    brake_ends: dict[int, Change | None] = {}
    # the point of each sample after the first (made in C: zip's rows as Points), with its step's regime and effort
    points = map(new_point, zip(tl[1:], sl[1:], fl[1:], al[1:], vl[1:], srcl[1:]))
    for k, (point, r, effort) in enumerate(zip(points, rl, el[1:])):
        final.step(point, r, effort)
        if r_prev == BRAKING and r != BRAKING:
            brake_ends[k] = final.latest
        r_prev = r
    return final, brake_ends


def _brake_rates(
    v: np.ndarray,
    steps: _Steps,
    phases: list[tuple[int, int]],
    brake_ends: dict[int, Change | None],
    speed_steps: rules.SpeedSteps,
    cfg: FeatureConfig,
) -> list[tuple[float, float, int]]:
    """(mean, sample std, count) of the brake rate per speed step; v: the filtered speed of each sample, m/s."""
    t, reg = steps.t, steps.regime
    counts = steps.positive & (reg == BRAKING)
    first_t = np.full(reg.size, np.inf)
    for a, b in phases:
        if reg[a] == BRAKING:
            first_t[a:b] = t[a + 1]
            # samples after the located end of the run mix in what followed (BrakeRates)
            counts[a:b] &= t[a + 1 : b + 1] <= run_end_time(brake_ends.get(b), cfg.boundary_refinement)
    counts &= rules.brake_settled(t[1:], first_t, cfg.brake_window)
    idx, held = speed_steps.of_brake_sample(v[1:], steps.accel, steps.dt, cfg.brake_window)
    counts &= held
    return [rules.sample_moments(-steps.accel[counts & (idx == i)]) for i in range(len(speed_steps))]


def features_per_run(
    estimates: EstimateSeries, regimes: np.ndarray, config: FeatureConfig | None = None
) -> list[Features]:
    """``extract_features`` for each run_id of the series, in order of appearance."""
    regimes = np.asarray(regimes)
    out = []
    for a, b in _runs(np.asarray(estimates.run_id)):
        sel = np.arange(a, b)
        out.append(extract_features(estimates.select(sel), regimes[sel], config))
    return out
