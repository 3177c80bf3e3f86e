"""Driving features of a run (Cunillera et al. 2022, Sections 3.3, 4.3-4.4), incremental and whole-run.

Every sample after the first closes a *step* (the interval from the previous sample): its duration
dt, its distance, its mean speed v_mid = (v_prev + v) / 2 and the sample's regime, effort (the mean
effort over the step) and acceleration. Steps with v_mid below ``standstill_speed`` are standing time
(regime UNKNOWN). Definitions (docs/estimator.md, "Features"):

* max tractive effort: least-squares line effort = a + b v_mid over TRACTION steps with acceleration > 0
  and v_mid in the effort window; reported at the mean v_mid of those steps (= their mean effort).
* max tractive power: mean and sample std of effort * v_mid over the same kind of steps in the power window.
* brake rate per speed step: mean and sample std of -acceleration over BRAKING samples, binned by speed; a
  sample counts only after ``brake_window`` s of braking and when its speed over that window stayed in one
  step (the acceleration is a window average: transitions and step changes would mix rates).
* cruise speeds: median filtered speed of each CRUISING phase lasting at least ``cruise_min_duration``;
  cruise_speed: the duration-weighted median over the samples of those phases.
* regime time shares: step durations per regime over the run time.
* final coast / final brake: duration and distance of the last COASTING / BRAKING phase seen so far that
  lasted at least ``final_*_min_duration`` (a phase is a maximal run of steps of one regime; interruptions
  up to ``phase_merge_gap`` are merged into it).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from .config import FeatureConfig
from .records import EstimateSample, EstimateSeries
from .regimes import BRAKING, COASTING, CRUISING, TRACTION, UNKNOWN

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


class _Moments:
    """Count, mean and sum of squared deviations (Welford)."""

    __slots__ = ("m2", "mean", "n")

    def __init__(self) -> None:
        self.n = 0
        self.mean = 0.0
        self.m2 = 0.0

    def add(self, x: float) -> None:
        self.n += 1
        d = x - self.mean
        self.mean += d / self.n
        self.m2 += d * (x - self.mean)

    def result(self) -> tuple[float, float, int]:
        if self.n == 0:
            return _NAN, _NAN, 0
        std = math.sqrt(self.m2 / (self.n - 1)) if self.n > 1 else _NAN
        return self.mean, std, self.n


class _Phase:
    __slots__ = ("end_s", "end_t", "start_s", "start_t")

    def __init__(self, t0: float, t1: float, s0: float, s1: float) -> None:
        self.start_t, self.end_t, self.start_s, self.end_s = t0, t1, s0, s1


def _fit(n: int, sv: float, su: float, svv: float, svu: float) -> tuple[float, float, float]:
    """(value at mean v, intercept, slope) of the least-squares line u = a + b v."""
    if n == 0:
        return _NAN, _NAN, _NAN
    mean_v, mean_u = sv / n, su / n
    sxx = svv - sv * mean_v
    if n < 2 or not sxx > 1e-12 * max(svv, 1e-300):
        return mean_u, _NAN, _NAN
    slope = (svu - sv * mean_u) / sxx
    return mean_u, mean_u - slope * mean_v, slope


def _weighted_median(values: np.ndarray, weights: np.ndarray) -> float:
    """Lower weighted median (the smallest value whose cumulative weight reaches half)."""
    if values.size == 0:
        return _NAN
    order = np.argsort(values, kind="stable")
    cw = np.cumsum(weights[order])
    if cw[-1] <= 0.0:
        return float(np.median(values))
    return float(values[order][np.searchsorted(cw, 0.5 * cw[-1])])


class FeatureAccumulator:
    """Running features of the current run, updated per estimate (the feature node's core)."""

    def __init__(self, config: FeatureConfig | None = None) -> None:
        self.config = cfg = config if config is not None else FeatureConfig()
        self._edges = np.asarray(cfg.brake_step_edges, dtype=float)
        self._edges_list = list(cfg.brake_step_edges)
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
        self._shares = [0.0] * 5
        self._fit = [0, 0.0, 0.0, 0.0, 0.0]
        self._power = _Moments()
        self._brake = [_Moments() for _ in self._edges_list]
        self._brake_first_t = 0.0
        self._cruise_done: list[tuple[float, np.ndarray, np.ndarray]] = []  # (median, v, dt) of listed phases
        self._cruise_v: list[float] = []
        self._cruise_dt: list[float] = []
        self._cruise_start = 0.0
        self._coast: _Phase | None = None
        self._brake_phase: _Phase | None = None
        self._final_coast: _Phase | None = None
        self._final_brake: _Phase | None = None

    def update(self, sample: EstimateSample, regime: int) -> bool:
        """Add one estimate with its regime; True when the regime changed (publish the features)."""
        return self._add(
            int(sample.stamp_ns),
            int(sample.run_id),
            float(sample.s),
            float(sample.v),
            float(sample.effort),
            float(sample.acceleration),
            int(regime),
        )

    def _add(self, stamp: int, run_id: int, s: float, v: float, effort: float, accel: float, regime: int) -> bool:
        cfg = self.config
        t = stamp * 1e-9
        if run_id != self._run_id:
            self.reset()
            self._run_id = run_id
            self._stamp, self._t0, self._t, self._s0, self._s, self._v = stamp, t, t, s, s, v
            self._regime = regime if v >= cfg.standstill_speed else UNKNOWN
            return True
        dt = t - self._t
        t_prev, s_prev = self._t, self._s
        v_mid = 0.5 * (self._v + v)
        if not v_mid >= cfg.standstill_speed or regime not in (TRACTION, CRUISING, COASTING, BRAKING):
            regime = UNKNOWN
        if dt > 0.0:
            self._shares[regime] += dt
            if regime == TRACTION and accel > 0.0:
                if cfg.max_effort_window_low <= v_mid <= cfg.max_effort_window_high:
                    f = self._fit
                    f[0] += 1
                    f[1] += v_mid
                    f[2] += effort
                    f[3] += v_mid * v_mid
                    f[4] += v_mid * effort
                if cfg.max_power_window_low <= v_mid <= cfg.max_power_window_high:
                    self._power.add(effort * v_mid)
            elif regime == BRAKING:
                if self._regime != BRAKING:
                    self._brake_first_t = t
                w = cfg.brake_window
                if t - self._brake_first_t >= 0.98 * w - 1e-6:
                    i = self._step_index(v)
                    if i >= 0 and i == self._step_index(v - accel * max(w, dt)):
                        self._brake[i].add(-accel)
            gap = cfg.phase_merge_gap
            if regime == COASTING:
                ph = self._coast
                if ph is not None and t_prev - ph.end_t <= gap + 1e-9:
                    ph.end_t, ph.end_s = t, s
                else:
                    self._coast = ph = _Phase(t_prev, t, s_prev, s)
                if ph.end_t - ph.start_t >= cfg.final_coast_min_duration - 1e-9:
                    self._final_coast = ph
            elif regime == BRAKING:
                ph = self._brake_phase
                if ph is not None and t_prev - ph.end_t <= gap + 1e-9:
                    ph.end_t, ph.end_s = t, s
                else:
                    self._brake_phase = ph = _Phase(t_prev, t, s_prev, s)
                if ph.end_t - ph.start_t >= cfg.final_brake_min_duration - 1e-9:
                    self._final_brake = ph
        # cruising phases (by sample)
        if regime == CRUISING:
            if self._regime != CRUISING:
                self._cruise_v, self._cruise_dt, self._cruise_start = [], [], t_prev
            self._cruise_v.append(v)
            self._cruise_dt.append(max(dt, 0.0))
        elif self._regime == CRUISING:
            self._close_cruise(t_prev)
        changed = regime != self._regime
        self._stamp, self._t, self._s, self._v, self._regime = stamp, t, s, v, regime
        return changed

    def _step_index(self, v: float) -> int:
        return int(np.searchsorted(self._edges, v, side="right")) - 1

    def _close_cruise(self, t_end: float) -> None:
        if t_end - self._cruise_start >= self.config.cruise_min_duration and self._cruise_v:
            v = np.array(self._cruise_v)
            self._cruise_done.append((float(np.median(v)), v, np.array(self._cruise_dt)))
        self._cruise_v, self._cruise_dt = [], []

    def snapshot(self, run_complete: bool = False) -> Features:
        """Features of the run so far (``run_complete`` is copied into the record)."""
        cfg = self.config
        f = Features(stamp_ns=self._stamp, run_id=self._run_id or 0, run_complete=bool(run_complete))
        f.run_time = self._t - self._t0
        f.run_distance = self._s - self._s0
        f.regime = self._regime
        f.max_tractive_effort_window_low = cfg.max_effort_window_low
        f.max_tractive_effort_window_high = cfg.max_effort_window_high
        f.max_tractive_effort, f.max_tractive_effort_intercept, f.max_tractive_effort_slope = _fit(*self._fit)
        f.max_tractive_effort_count = self._fit[0]
        f.max_tractive_power_window_low = cfg.max_power_window_low
        f.max_tractive_power_window_high = cfg.max_power_window_high
        f.max_tractive_power, f.max_tractive_power_std, f.max_tractive_power_count = self._power.result()
        f.brake_step_low = self._edges.copy()
        f.brake_step_high = np.append(self._edges[1:], np.inf)
        res = [m.result() for m in self._brake]
        f.brake_rate_mean = np.array([r[0] for r in res])
        f.brake_rate_std = np.array([r[1] for r in res])
        f.brake_rate_count = np.array([r[2] for r in res], dtype=np.uint32)
        phases = list(self._cruise_done)
        if self._regime == CRUISING and self._cruise_v and self._t - self._cruise_start >= cfg.cruise_min_duration:
            v = np.array(self._cruise_v)
            phases.append((float(np.median(v)), v, np.array(self._cruise_dt)))
        f.cruise_speeds = np.array([p[0] for p in phases])
        if phases:
            values, weights = np.concatenate([p[1] for p in phases]), np.concatenate([p[2] for p in phases])
            f.cruise_speed = _weighted_median(values, weights)
        total = sum(self._shares)
        f.regime_time_share = np.array(self._shares) / total if total > 0.0 else np.zeros(5)
        if self._final_coast is not None:
            f.final_coast_duration = self._final_coast.end_t - self._final_coast.start_t
            f.final_coast_distance = self._final_coast.end_s - self._final_coast.start_s
        if self._final_brake is not None:
            f.final_brake_duration = self._final_brake.end_t - self._final_brake.start_t
            f.final_brake_distance = self._final_brake.end_s - self._final_brake.start_s
        return f


def _runs(values: np.ndarray) -> list[tuple[int, int]]:
    """(start, stop) index pairs of maximal runs of equal values."""
    if values.size == 0:
        return []
    cuts = np.flatnonzero(values[1:] != values[:-1]) + 1
    starts = np.concatenate(([0], cuts))
    stops = np.concatenate((cuts, [values.size]))
    return list(zip(starts.tolist(), stops.tolist()))


def extract_features(
    estimates: EstimateSeries, regimes: np.ndarray, config: FeatureConfig | None = None, run_complete: bool = True
) -> Features:
    """Features of one whole run (vectorised); equal to FeatureAccumulator after the last sample."""
    cfg = config if config is not None else FeatureConfig()
    n = len(estimates)
    regimes = np.asarray(regimes).astype(np.int64)
    if regimes.shape != (n,):
        raise ValueError(f"regimes: expected shape ({n},), found {regimes.shape}")
    if n and np.any(estimates.run_id != estimates.run_id[0]):
        raise ValueError("estimates: several run_ids; use features_per_run()")
    acc = FeatureAccumulator(cfg)
    if n == 0:
        return acc.snapshot(run_complete)
    t = estimates.stamp_ns * 1e-9
    s, v = estimates.s, estimates.v
    f = Features(stamp_ns=int(estimates.stamp_ns[-1]), run_id=int(estimates.run_id[0]), run_complete=run_complete)
    f.run_time = float(t[-1] - t[0])
    f.run_distance = float(s[-1] - s[0])
    dt = np.diff(t)
    v_mid = 0.5 * (v[1:] + v[:-1])
    reg = regimes[1:].copy()
    reg[~(v_mid >= cfg.standstill_speed) | (reg < TRACTION) | (reg > BRAKING)] = UNKNOWN
    first = regimes[0] if v[0] >= cfg.standstill_speed and TRACTION <= regimes[0] <= BRAKING else UNKNOWN
    f.regime = int(reg[-1]) if n > 1 else int(first)
    effort, accel = estimates.effort[1:], estimates.acceleration[1:]
    pos = dt > 0.0
    # effort fit
    f.max_tractive_effort_window_low = cfg.max_effort_window_low
    f.max_tractive_effort_window_high = cfg.max_effort_window_high
    tr = pos & (reg == TRACTION) & (accel > 0.0)
    m = tr & (v_mid >= cfg.max_effort_window_low) & (v_mid <= cfg.max_effort_window_high)
    vm, um = v_mid[m], effort[m]
    sums = (int(m.sum()), float(vm.sum()), float(um.sum()), float((vm * vm).sum()), float((vm * um).sum()))
    f.max_tractive_effort, f.max_tractive_effort_intercept, f.max_tractive_effort_slope = _fit(*sums)
    f.max_tractive_effort_count = sums[0]
    # power
    f.max_tractive_power_window_low = cfg.max_power_window_low
    f.max_tractive_power_window_high = cfg.max_power_window_high
    m = tr & (v_mid >= cfg.max_power_window_low) & (v_mid <= cfg.max_power_window_high)
    power = effort[m] * v_mid[m]
    f.max_tractive_power_count = int(power.size)
    if power.size:
        f.max_tractive_power = float(power.mean())
        f.max_tractive_power_std = float(power.std(ddof=1)) if power.size > 1 else _NAN
    # brake rates
    edges = np.asarray(cfg.brake_step_edges, dtype=float)
    f.brake_step_low = edges.copy()
    f.brake_step_high = np.append(edges[1:], np.inf)
    br = pos & (reg == BRAKING)
    first_t = np.full(n - 1, np.inf)
    for a, b in _runs(reg):
        if reg[a] == BRAKING:
            first_t[a:b] = t[a + 1]
    w = cfg.brake_window
    br &= t[1:] - first_t >= 0.98 * w - 1e-6
    idx = np.searchsorted(edges, v[1:], side="right") - 1
    br &= idx == np.searchsorted(edges, v[1:] - accel * np.maximum(w, dt), side="right") - 1
    means, stds, counts = [], [], []
    for i in range(edges.size):
        d = -accel[br & (idx == i)]
        counts.append(d.size)
        means.append(float(d.mean()) if d.size else _NAN)
        stds.append(float(d.std(ddof=1)) if d.size > 1 else _NAN)
    f.brake_rate_mean, f.brake_rate_std = np.array(means), np.array(stds)
    f.brake_rate_count = np.array(counts, dtype=np.uint32)
    # time shares
    total = float(dt[pos].sum())
    shares = np.bincount(reg[pos], weights=dt[pos], minlength=5)
    f.regime_time_share = shares / total if total > 0.0 else np.zeros(5)
    # phases (loop over phases, not samples)
    phases = _runs(reg)
    cruise = []
    t_step0, t_step1 = t[:-1], t[1:]
    for a, b in phases:
        if reg[a] == CRUISING and t_step1[b - 1] - t_step0[a] >= cfg.cruise_min_duration:
            cruise.append((float(np.median(v[a + 1 : b + 1])), v[a + 1 : b + 1], np.maximum(dt[a:b], 0.0)))
    f.cruise_speeds = np.array([c[0] for c in cruise])
    if cruise:
        values, weights = np.concatenate([c[1] for c in cruise]), np.concatenate([c[2] for c in cruise])
        f.cruise_speed = _weighted_median(values, weights)
    for regime, attr, min_len in (
        (COASTING, "coast", cfg.final_coast_min_duration),
        (BRAKING, "brake", cfg.final_brake_min_duration),
    ):
        last = final = None
        for a, b in phases:
            if reg[a] != regime or not np.any(pos[a:b]):
                continue
            start_t, end_t, start_s, end_s = t_step0[a], t_step1[b - 1], s[a], s[b]
            if last is not None and start_t - last[1] <= cfg.phase_merge_gap + 1e-9:
                last = (last[0], end_t, last[2], end_s)
            else:
                last = (start_t, end_t, start_s, end_s)
            if last[1] - last[0] >= min_len - 1e-9:
                final = last
        if final is not None:
            setattr(f, f"final_{attr}_duration", float(final[1] - final[0]))
            setattr(f, f"final_{attr}_distance", float(final[3] - final[2]))
    return f


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
