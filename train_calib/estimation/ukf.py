"""Online UKF estimate of the Davis running resistance (Cunillera et al. 2022, Section 3.1): ``ResistanceEstimator``.

State x = (s, v, r0, r1, r2), the measurement z = (s, v) (or v alone when s was not measured); the effort u of a
step is computed from the speeds (eq. 1) or known (power, confirmed coasting). One module per job:

- ``ukf.py`` (this module): ``ResistanceEstimator``, one measurement job by job, the effort decision, the results;
- ``ukf_step.py``: the closed-form unscented step, prediction and update (its docstring derives the closed form);
- ``ukf_safeguards.py``: the position gate, the check after an update, the NIS rule, the resets;
- ``ukf_lookahead.py``: the coasting confirmation and the resistance filter that runs ``coast_confirm_ahead``
  behind the published one;
- ``ukf_types.py``: the named tuples in and out, one filter's state, the input limits;
- ``ukf_fast.py`` and ``_ukf_kernel.c``: the common step (and a common sample's ``process``) in one function, in C.

The step, the safeguards and the look-ahead are base classes of ``ResistanceEstimator``: its methods and attributes
keep their names (the C kernel reads them by name). Reading order: ``ResistanceEstimator.process`` (one measurement:
``_rejection``, ``_repaired``, ``_start_run`` / ``_restart_after_gap``, ``_step`` = ``_predict_published`` (effort
decision ``_known_effort``, prediction ``_predict`` / ``_predict_output``), ``_measure`` (gate ``_gate_position``,
``_update``), ``_safeguard``, ``_look_ahead`` (the resistance filter: ``_advance``, ``_resistance_step``)). Results
are named tuples: ``StepResult`` per measurement, ``PendingStep`` per step waiting for the look-ahead, ``TraceStep``
per step of the resistance filter (``record_trace``). Packed covariance indices: ``covariance.py`` and
docs/estimator.md.
"""

from __future__ import annotations

import math

import numpy as np

from ..measurement import Measurement
from ..train import Davis, TrainSpec
from . import ukf_fast
from .coast_regression import POWER_DRIVE, POWER_NONE, POWER_UNKNOWN, CoastRegression, CoastSettings
from .config import UKFConfig
from .covariance import cholesky, unpack
from .effort import PowerEffort, SpeedSlope
from .records import (
    EFFORT_COASTING,
    EFFORT_COMPUTED,
    EFFORT_POWER,
    EFFORT_POWER_COASTING,
    HEALTH_OK,
    HEALTH_RESET,
    EstimateSample,
)
from .safeguards import SafeguardConfig
from .ukf_fast import eligible as common_eligible
from .ukf_lookahead import LookAhead
from .ukf_safeguards import FilterSafeguards
from .ukf_step import UnscentedStep
from .ukf_types import (
    COUNTERS,
    MAX_POSITION,
    MAX_POWER,
    MAX_SPEED,
    MAX_TRACK_FORCE,
    VARIANCE_RANGE,
    EffortDecision,
    FilterState,
    PendingStep,
    Prediction,
    StepInput,
    StepResult,
    TraceStep,
    running_resistance,
    step_input,
    worse,
)

_SOURCE = {
    "known_effort_coast": EFFORT_COASTING,
    "known_effort_power": EFFORT_POWER,
    "known_effort_power_coast": EFFORT_POWER_COASTING,
}
"""Effort source (EstimateSample.effort_source) of a known-effort step, by its counter."""


class ResistanceEstimator(LookAhead, FilterSafeguards, UnscentedStep):
    """Per-measurement UKF of (s, v, r0, r1, r2) with effort computation, safeguards and health.

    ``update(m)`` once per measurement (variable dt from the stamps); a new ``run_id`` starts a new
    run (``carry_over``). Never returns NaN or a negative r. Counters for diagnostics: ``counters``.
    ``safeguards``: the position gate and the recovery rules (:class:`SafeguardConfig`, docs/reliability.md).
    With ``exploit_known`` and ``coast_confirm_ahead`` > 0 the resistance is learnt ``coast_confirm_ahead``
    behind the latest measurement (``ukf_lookahead.py``); ``flush()`` uses the measurements still waiting.
    ``process(StepInput) -> StepResult`` is ``update`` without the EstimateSample (the whole-run API uses it);
    ``record_trace()`` / ``trace`` give the resistance filter's own steps, ``predict()`` its prediction.
    """

    def __init__(
        self,
        train: TrainSpec,
        config: UKFConfig | None = None,
        initial: Davis | None = None,
        safeguards: SafeguardConfig | None = None,
    ) -> None:
        self.train = train
        self.config = cfg = config if config is not None else UKFConfig()
        self.safeguards = guard = safeguards if safeguards is not None else SafeguardConfig()
        self.prior = initial if initial is not None else train.davis
        if min(self.prior.as_tuple()) < 0.0 or not all(math.isfinite(x) for x in self.prior.as_tuple()):
            raise ValueError(f"initial resistance must be finite and >= 0, found {self.prior}")
        self._init_step(cfg)
        self._exploit = cfg.effort_mode == "exploit_known"
        # coast regression: r comes from the coasting stretches, the UKF keeps it as a consider parameter
        self._coast = (
            CoastRegression(train, CoastSettings.from_config(cfg), self.prior)
            if cfg.resistance_learning == "coast_regression"
            else None
        )
        self._decouple = bool(cfg.decouple_unknown_effort) or self._coast is not None
        self._rs = cfg.meas_std_s**2
        self._rv = cfg.meas_std_v**2
        self._power = PowerEffort(train)
        self._slope = SpeedSlope(cfg.accel_window)
        self._prior_r = self.prior.as_tuple()
        self._init_lookahead(cfg)
        self._init_safeguards(cfg, guard)
        self._common = common_eligible(self)  # the common step by ukf_fast.common_step
        self._common_step = ukf_fast.common_step  # the C kernel's, or the Python one without it
        # a common sample's whole process() in C (the kernel's process_common; None: the Python process alone)
        self._process_kernel = ukf_fast._ukf_kernel.process_common if ukf_fast.KERNEL_AVAILABLE else None
        self.counters: dict[str, int] = dict.fromkeys(COUNTERS, 0)
        self.rejected: str | None = None  # why the latest measurement was not used (None: it was)
        self._h = FilterState()  # the published (output) filter
        self._rf = FilterState() if self._lookahead else self._h  # the resistance filter (without look-ahead: _h)
        self._trace: list[TraceStep] | None = None  # record_trace(): the resistance filter's steps
        self._keep_next = False
        self._run_id: int | None = None
        self._reset_run_state()

    # -- public API -----------------------------------------------------------------------------
    @property
    def state(self) -> np.ndarray:
        """Current (s, v, r0, r1, r2); NaN before the first measurement."""
        h, rf = self._h, self._rf
        if h.x is None or rf.x is None:
            return np.full(5, np.nan)
        return np.array([h.x[0], h.x[1], rf.x[2], rf.x[3], rf.x[4]], dtype=float)

    @property
    def covariance(self) -> np.ndarray:
        """Current 5x5 covariance over (s, v, r0, r1, r2); NaN before the first measurement."""
        h, rf = self._h, self._rf
        if h.x is None or rf.x is None:
            return np.full((5, 5), np.nan)
        return unpack(self._published_cov() if self._lookahead else h.P)

    @property
    def davis(self) -> Davis:
        x = self._rf.x if self._rf.x is not None else [0.0, 0.0, *self.prior.as_tuple()]
        return Davis(x[2], x[3], x[4])

    @property
    def coast_regression(self) -> CoastRegression | None:
        """The coast regression that learns r (``resistance_learning: coast_regression``), else None."""
        return self._coast

    def reset(self, keep_resistance: bool = False) -> None:
        """Forget the run: the next measurement re-initialises s and v; r (and its covariance) are kept
        when ``keep_resistance`` (times ``carry_over_inflation``), else taken from the prior. Measurements
        still waiting for the resistance filter are used first (``flush``). With the coast regression, r is
        the regression's, which keeps what it learnt unless ``keep_resistance`` is false."""
        self.flush()
        if self._coast is not None and not keep_resistance:
            self._coast.reset()
        self._keep_next = bool(keep_resistance) and self._h.x is not None
        if not self._keep_next:
            self._h.x = None
            self._rf.x = None
        self._run_id = None
        self._reset_run_state()

    def power_braking_unseen(self) -> int:
        """Steps on which the speeds brake clearly while the power shows neither traction nor regeneration, when
        ``power_coasting`` is on and they are at least 10 and four times the regenerating steps; else 0. Braking then
        does not show in the power (no electric brake, or a meter without regeneration): the first steps of each
        brake are taken as power coasting, and ``power_coasting`` should be false (docs/estimator.md). Simulated
        runs: 13-57 such steps per run without electric brake, none with it."""
        c = self.counters
        unseen = c["power_braking_unseen"]
        if self.config.power_coasting and unseen >= 10 and unseen >= 4 * c["power_regenerating"]:
            return unseen
        return 0

    def flush(self) -> None:
        """Let the resistance filter use every measurement still waiting for its look-ahead (end of a
        recording): their coasting is not confirmed (computed effort), measured traction power is used."""
        while self._pending:
            self._resistance_step(self._pending.popleft(), False)
        if self._lookahead and self._h.x is not None and self._rf.x is not None:
            self._sync()

    def update(self, m: Measurement) -> EstimateSample:
        """Process one measurement; returns the estimate after it."""
        s, v, r0, r1, r2, effort, accel, resistance, g, nis, source, health, dt, u, _, cov = self.process(step_input(m))
        # positional, in EstimateSample's field order (stamp_ns, run_id, s, v, r0, r1, r2, covariance, effort,
        # acceleration, resistance, track_force, nis, effort_known, health, dt, input_effort, v_measured,
        # effort_source): a third of the keyword call's cost, once per sample
        return EstimateSample(int(m.stamp_ns), int(m.run_id), s, v, r0, r1, r2, unpack(cov), effort, accel, resistance,
                              g, nis, source != EFFORT_COMPUTED, health, dt, u, float(m.v), int(source))  # fmt: skip

    @property
    def has_lookahead(self) -> bool:
        """True when the resistance filter runs ``coast_confirm_ahead`` behind the published one (two filters)."""
        return self._lookahead

    def record_trace(self) -> list[TraceStep]:
        """Start recording the resistance filter's steps (one :class:`TraceStep` per measurement it uses, its own
        state and covariance after the step and the effort it used); returns the list, also ``trace``. Only with
        look-ahead: without it the resistance filter is the published one (``process``)."""
        self._trace = []
        return self._trace

    @property
    def trace(self) -> list[TraceStep] | None:
        """The resistance filter's steps since ``record_trace()`` (None when not recording)."""
        return self._trace

    def predict(
        self, x: tuple[float, ...], covariance: tuple[float, ...], dt: float, u: float, g: float, decoupled: bool
    ) -> Prediction | None:
        """The resistance filter's closed-form unscented prediction from mean x (s, v, r0, r1, r2) and packed
        covariance over dt s with effort u and track force g (N/kg); ``decoupled``: r at its mean (consider step).
        None when the covariance is not positive definite. The filter's own state is not touched."""
        chol = cholesky(covariance)
        if chol is None:
            return None
        f = FilterState()
        f.x, f.P, f.L = list(x), tuple(covariance), chol
        self._predict(f, dt, u, g, decoupled)
        return Prediction(tuple(f.x), f.P, f.m)

    # -- internals ------------------------------------------------------------------------------
    def _reset_run_state(self) -> None:
        self._slope.reset()
        self._last_stamp = 0
        self._zv_prev = 0.0
        self._g_prev = 0.0
        self._pw_prev = (False, 0.0, 0.0)
        self._last_effort = 0.0
        self._last_accel = 0.0
        self._last_input = 0.0
        self._reset_lookahead()
        self._reset_safeguards()

    def _initial_cov(self, r: tuple[float, float, float]) -> list[float]:
        cfg = self.config
        rel = cfg.init_std_r_relative
        s0 = max(cfg.init_std_r0, rel * abs(r[0]))
        s1 = max(cfg.init_std_r1, rel * abs(r[1]))
        s2 = max(cfg.init_std_r2, rel * abs(r[2]))
        p = [0.0] * 15
        p[0] = cfg.init_std_s**2
        p[5] = cfg.init_std_v**2
        p[9], p[12], p[14] = s0 * s0, s1 * s1, s2 * s2
        return p

    def _initialise(self, zs: float, zv: float, keep: bool, inflation: float = 1.0) -> None:
        """(Re)start both filters at the measurement (run start, gap); keep: r and its covariance block (times
        inflation) from the resistance filter."""
        self._initialise_filter(self._h, zs, zv, keep, inflation)
        if self._lookahead:
            self._rf.assign(self._h)

    def _initialise_filter(self, f: FilterState, zs: float, zv: float, keep: bool, inflation: float = 1.0) -> None:
        """Restart filter f at the measurement; keep: r and its covariance block (times inflation) from the
        resistance filter when they are finite and r >= 0, else (or if that is not positive definite) the prior."""
        src = self._rf
        if self._coast is not None:  # r and its covariance are the regression's
            r = (float(self._coast.r[0]), float(self._coast.r[1]), float(self._coast.r[2]))
            p = self._initial_cov(r)
            c = self._coast.covariance
            p[9:15] = [float(c[i, j]) for i, j in ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))]
        elif keep and src.x is not None and all(math.isfinite(xi) and xi >= 0.0 for xi in src.x[2:]):
            r = (src.x[2], src.x[3], src.x[4])
            old = src.P
            p = self._initial_cov(r)
            for idx in (9, 10, 11, 12, 13, 14):
                p[idx] = old[idx] * inflation
        else:
            r = self._prior_r
            p = self._initial_cov(r)
        f.x = [zs, max(zv, 0.0), r[0], r[1], r[2]]
        if self._set_cov(f, tuple(p)) != HEALTH_OK:
            f.x[2:] = list(self._prior_r)
            self._set_cov(f, tuple(self._initial_cov(self._prior_r)))

    def _power_state(self, m: StepInput) -> int:
        """The coast regression's POWER_* state of a (repaired) sample: unknown without a power measurement."""
        if not (m.power_valid and self.config.use_power):
            return POWER_UNKNOWN
        drive = m.power_regenerated > 0.0 or self._power.wheel_power(m.power_consumed) > self.config.power_threshold
        return POWER_DRIVE if drive else POWER_NONE

    def _take_coast_resistance(self) -> None:
        """Both filters take the coast regression's r and r covariance (no cross-covariance with s, v)."""
        r, c = self._coast.r, self._coast.covariance
        for f in (self._h, self._rf) if self._lookahead else (self._h,):
            if f.x is None:
                continue
            f.x[2], f.x[3], f.x[4] = float(r[0]), float(r[1]), float(r[2])
            p = list(f.P)
            p[2] = p[3] = p[4] = p[6] = p[7] = p[8] = 0.0
            p[9], p[10], p[11] = float(c[0, 0]), float(c[0, 1]), float(c[0, 2])
            p[12], p[13], p[14] = float(c[1, 1]), float(c[1, 2]), float(c[2, 2])
            self._set_cov(f, tuple(p))

    # -- one measurement, job by job ----------------------------------------------------------------
    def process(self, m: StepInput) -> StepResult:
        """Process one measurement (``update`` without building the EstimateSample): reject or repair the input,
        start a run or restart after a gap, else one filter step (effort, prediction, update, safeguards,
        look-ahead bookkeeping). Returns the estimate after it.

        A common sample (used as it is, the run going on, 0 < dt <= max_dt, the common step configured) is processed
        in C where the package was built with a compiler (``_ukf_kernel.process_common``: this method, ``_step`` and
        ``_common_result`` step for step, calling back here where they do something else); the kernel returns None
        for every other sample, nothing changed, and this method runs."""
        kernel = self._process_kernel
        if kernel is not None:
            out = kernel(self, m)
            if out is not None:
                return out
        self.counters["updates"] += 1
        self.rejected = self._rejection(m)
        if self.rejected is not None:
            return self._rejected(m.stamp_ns)
        m = self._repaired(m)
        if self._coast is not None and self._coast.push(
            m.stamp_ns * 1e-9, m.v, m.track_force, m.tunnel_fraction, m.run_id, self._power_state(m), m.s,
            m.track_force_integral, m.s_variance, m.v_variance,
        ):  # fmt: skip
            self._take_coast_resistance()
        if self._h.x is None or m.run_id != self._run_id:
            return self._start_run(m)
        dt = (m.stamp_ns - self._last_stamp) * 1e-9
        if dt > self.config.max_dt:
            return self._restart_after_gap(m)
        return self._step(m, dt)

    def _rejection(self, m: StepInput) -> str | None:
        """Why the measurement cannot be used (``rejected``), or None."""
        if not (math.isfinite(m.v) and math.isfinite(m.track_force)):
            return "nan"
        if m.v < 0.0:
            return "negative_speed"
        if m.v > MAX_SPEED or abs(m.track_force) > MAX_TRACK_FORCE:
            return "implausible"
        if self._h.x is not None and m.run_id == self._run_id and m.stamp_ns < self._last_stamp:
            return "out_of_order"
        return None

    def _repaired(self, m: StepInput) -> StepInput:
        """The measurement with what the filter cannot use replaced (counted in ``input_repaired``): a position that
        is not one (NaN too: a speed-only update), a variance out of VARIANCE_RANGE (the configured one), a power
        that is not a power (no power measurement)."""
        counters = self.counters
        h = self._h
        if not abs(m.s) <= MAX_POSITION:  # NaN too: no position, a speed-only update
            if math.isfinite(m.s):
                counters["input_repaired"] += 1
            m = m._replace(s_measured=False, s=h.x[0] if h.x is not None and m.run_id == self._run_id else 0.0)
        lo_var, hi_var = VARIANCE_RANGE
        s_var, v_var = m.s_variance, m.v_variance
        if not (lo_var <= s_var <= hi_var and lo_var <= v_var <= hi_var):
            counters["input_repaired"] += 1  # a variance the filter cannot use: the configured one
            m = m._replace(s_variance=s_var if lo_var <= s_var <= hi_var else self._rs,
                           v_variance=v_var if lo_var <= v_var <= hi_var else self._rv)  # fmt: skip
        if m.power_valid and not (0.0 <= m.power_consumed <= MAX_POWER and 0.0 <= m.power_regenerated <= MAX_POWER):
            counters["input_repaired"] += 1  # power that is not a power is no power measurement
            m = m._replace(power_valid=False, power_consumed=0.0, power_regenerated=0.0)
        return m

    def _start_run(self, m: StepInput) -> StepResult:
        """A new run_id (or the first measurement): the waiting measurements are used, both filters restart at the
        measurement, r from the prior or carried over (``carry_over``)."""
        cfg = self.config
        keep = self._h.x is not None and (self._keep_next or cfg.carry_over == "keep")
        self.flush()
        self._reset_run_state()
        self._initialise(m.s, m.v, keep, cfg.carry_over_inflation)
        self._keep_next = False
        self._run_id = m.run_id
        self.counters["runs"] += 1
        return self._first_sample(m, HEALTH_OK)

    def _restart_after_gap(self, m: StepInput) -> StepResult:
        """dt > ``max_dt``: s and v restart at the measurement, r and its covariance are kept (health RESET)."""
        self.counters["gaps"] += 1
        self.counters["resets"] += 1
        self.flush()
        self._reset_run_state()
        self._initialise(m.s, m.v, True)
        return self._first_sample(m, HEALTH_RESET)

    def _step(self, m: StepInput, dt: float) -> StepResult:
        """One filter step of the published (output) filter after dt s; with look-ahead the resistance filter then
        catches up on the steps whose coasting is decided."""
        cfg = self.config
        t = m.stamp_ns * 1e-9
        a_obs = self._slope.push(t, m.v)
        rs, rv = (m.s_variance, m.v_variance) if cfg.use_measurement_variance else (self._rs, self._rv)
        if self._common and dt > 0.0:  # the fast path of the common step (ukf_fast); None: this chain
            common = self._common_step(self, m, dt, a_obs, rs, rv)
            if common is not None:
                return self._common_result(m, dt, a_obs, *common)
        return self._step_chain(m, dt, t, a_obs, rs, rv)

    def _step_chain(self, m: StepInput, dt: float, t: float, a_obs: float, rs: float, rv: float) -> StepResult:
        """``_step`` after the speed slope a_obs (m/s^2) at t (s) and the variances rs, rv: the readable chain."""
        if dt > 0.0:
            eff = self._predict_published(m, dt, a_obs, rv)
        else:
            self.counters["nonpositive_dt"] += 1
            dt = 0.0
            eff = EffortDecision(self._last_effort, self._last_input, self._last_accel)
        s_measured, health, nis, dof = self._measure(m, rs, rv, dt, eff.decoupled)
        health, nis, nis_reset = self._safeguard(m.s, m.v, health, nis, dof)
        zv_prev, g_prev = self._zv_prev, self._g_prev
        self._remember(m)
        if self._exploit:
            self._coast_confirmation(t, m.v, self._h.x[1], m.track_force)
        if self._lookahead:
            used_coast = eff.coast_provisional and eff.source != EFFORT_COMPUTED
            step = PendingStep(self._index, t, dt, m.s, m.v, zv_prev, g_prev, m.track_force, s_measured, rs, rv,
                               eff.coast_provisional, eff.power_u, eff.power_kind, self._relocked, nis_reset,
                               self.counters["updates"], used_coast)  # fmt: skip
            health = worse(health, self._look_ahead(step))
        return self._result(eff, m.track_force, nis, health, dt)

    def _common_result(self, m: StepInput, dt: float, a_obs: float, effort: float, u: float, nis: float) -> StepResult:
        """The rest of ``_step`` after ukf_fast.common_step: the NIS window (``_safeguard``'s tail), the measurement
        remembered, the published estimate (``_result`` of a computed effort, r at its mean)."""
        health, nis, _ = self._nis_rule(m.s, m.v, HEALTH_OK, nis, 2)
        self._remember(m)
        h = self._h
        x = h.x
        vf = x[1]
        resistance = running_resistance(x[2], x[3], x[4], vf)
        return StepResult(x[0], vf, x[2], x[3], x[4], effort, a_obs, resistance, m.track_force, nis, EFFORT_COMPUTED,
                          health, dt, u, True, h.P)  # fmt: skip

    def _predict_published(self, m: StepInput, dt: float, a_obs: float, rv: float) -> EffortDecision:
        """The applied effort of the step and the prediction of the published filter with it: the effort computed
        from the speed change (Cunillera eq. 1) unless a known one (power, confirmed coasting) passes the gate."""
        counters = self.counters
        h = self._h
        x = h.x
        zv, zv_prev, g_prev = m.v, self._zv_prev, self._g_prev
        dz = zv - zv_prev
        v = x[1]
        r_ref = running_resistance(x[2], x[3], x[4], v + 0.5 * dz if self._midpoint else v)
        effort = a_obs + r_ref + g_prev
        u = dz / dt + r_ref + g_prev
        power_u, power_kind, coast_eligible = self._known_effort(m, zv_prev, effort)
        known_u, kind = power_u, power_kind
        provisional = False
        if coast_eligible and self._coast_pass:  # the confirmation window up to the previous sample
            known_u, kind = 0.0, "known_effort_coast"
            provisional = True
        source = EFFORT_COMPUTED
        if known_u is not None:
            if self._known_predict(h, dt, known_u, g_prev, zv, rv, self._lookahead):
                source = _SOURCE[kind]
                u = effort = known_u
                if not self._lookahead:
                    counters[kind] += 1
            elif not self._lookahead:
                counters["known_effort_rejected"] += 1
        decoupled = self._decouple and source == EFFORT_COMPUTED
        if source == EFFORT_COMPUTED:
            if self._lookahead:
                self._predict_output(h, dt, u, g_prev, not self._decouple)
            else:
                self._predict(h, dt, u, g_prev, decoupled)
        self._last_effort, self._last_accel, self._last_input = effort, a_obs, u
        return EffortDecision(effort, u, a_obs, source, decoupled, provisional, power_u, power_kind)

    def _known_effort(self, m: StepInput, zv_prev: float, effort: float) -> tuple[float | None, str | None, bool]:
        """The effort decision from the power (``exploit_known``, both speeds above ``known_effort_min_speed``):
        (u from the power or None, its counter name or None, whether the step may be a coasting step)."""
        cfg = self.config
        if not (self._exploit and zv_prev >= cfg.known_effort_min_speed and m.v >= cfg.known_effort_min_speed):
            return None, None, False
        counters = self.counters
        power_u = power_kind = traction = None
        pv0, pc0, pr0 = self._pw_prev
        if cfg.use_power and pv0 and m.power_valid:
            if pr0 > 0.0 or m.power_regenerated > 0.0:
                traction = False  # electric braking: f_b unknown (blended)
                counters["power_regenerating"] += 1
            else:
                w0 = self._power.wheel_power(pc0)
                w1 = self._power.wheel_power(m.power_consumed)
                if w0 > cfg.power_threshold and w1 > cfg.power_threshold:
                    power_u = 0.5 * (w0 / zv_prev + w1 / m.v)
                    power_kind = "known_effort_power"
                elif w0 > cfg.power_threshold or w1 > cfg.power_threshold:
                    traction = False  # traction switched within the step
                elif effort > -4.0 * cfg.coast_effort_tolerance:
                    if cfg.power_coasting:
                        power_u = 0.0  # no traction, no electric brake, not clearly braking: coasting
                        power_kind = "known_effort_power_coast"
                else:
                    counters["power_braking_unseen"] += 1  # the speeds brake, the power shows no brake
        return power_u, power_kind, power_u is None and traction is None

    def _measure(self, m: StepInput, rs: float, rv: float, dt: float, decoupled: bool) -> tuple[bool, int, float, int]:
        """The measurement update of the published filter after the position gate: (position used, health, NIS,
        its degrees of freedom); a gated position counts in the NIS as an inconsistent innovation."""
        s_measured = m.s_measured
        health = HEALTH_OK
        if not s_measured:
            self.counters["position_missing"] += 1
        gated_nis = 0.0
        self._relocked = False
        if s_measured:
            s_measured, health, gated_nis = self._gate_position(m.stamp_ns, m.s, rs, dt, health)
        if self._lookahead:
            nis, dof = self._update(self._h, m.s, m.v, rs, rv, s_measured, dt, True, sv_only=True)
        else:
            nis, dof = self._update(self._h, m.s, m.v, rs, rv, s_measured, dt, decoupled)
        if gated_nis:  # a gated position is an inconsistent innovation: it counts in the NIS window
            nis, dof = nis + gated_nis, dof + 1
        return s_measured, health, nis, dof

    def _remember(self, m: StepInput) -> None:
        """What the next step needs of this measurement: stamp, speed, track force, power."""
        self._last_stamp = m.stamp_ns
        self._zv_prev = m.v
        self._g_prev = m.track_force
        self._pw_prev = (m.power_valid, m.power_consumed, m.power_regenerated)

    def _result(self, eff: EffortDecision, g: float, nis: float, health: int, dt: float) -> StepResult:
        """The published estimate after the step (on the step that needed a reset: the effort of the restarted
        state)."""
        h = self._h
        x = h.x
        vf = x[1]
        resistance = running_resistance(x[2], x[3], x[4], vf)
        effort, a_obs, u = eff.effort, eff.acceleration, eff.input_effort
        if not math.isfinite(effort + a_obs + u):
            a_obs = a_obs if math.isfinite(a_obs) else 0.0
            effort = u = a_obs + resistance + g
            self._last_effort, self._last_accel, self._last_input = effort, a_obs, u
        return StepResult(x[0], vf, x[2], x[3], x[4], effort, a_obs, resistance, g, nis, eff.source, health, dt, u,
                          eff.decoupled, h.P)  # fmt: skip

    def _first_sample(self, m: StepInput, health: int) -> StepResult:
        """The estimate at the first measurement of a run or after a gap (no prediction, no update)."""
        t = m.stamp_ns * 1e-9
        self._slope.push(t, m.v)
        if self._exploit:
            self._coast_confirmation(t, m.v, m.v, m.track_force)
        self._remember(m)
        if self._trace is not None and self._lookahead:
            rf = self._rf
            self._trace.append(TraceStep(self.counters["updates"], tuple(rf.x), rf.P, 0.0, 0.0, m.track_force, False,
                                         False, health))  # fmt: skip
        h = self._h
        x = h.x
        return StepResult(x[0], x[1], x[2], x[3], x[4], 0.0, 0.0, running_resistance(x[2], x[3], x[4], x[1]),
                          m.track_force, 0.0, EFFORT_COMPUTED, health, 0.0, 0.0, False, h.P)  # fmt: skip

    def _rejected(self, stamp_ns: int) -> StepResult:
        """A sample that cannot be used (NaN or negative speed, NaN track force, stamp older than the last):
        counted, the filter is left as it is, and the current estimate is returned."""
        self.counters["invalid_input"] += 1
        h = self._h
        x = h.x if h.x is not None else [0.0, 0.0, *self._prior_r]
        if h.x is None:
            self._set_cov(h, tuple(self._initial_cov(self._prior_r)))
        return StepResult(x[0], x[1], x[2], x[3], x[4], self._last_effort, self._last_accel,
                          running_resistance(x[2], x[3], x[4], x[1]), self._g_prev, 0.0, EFFORT_COMPUTED, HEALTH_OK,
                          0.0, self._last_input, False, h.P)  # fmt: skip
