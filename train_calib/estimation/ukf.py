"""Online UKF estimate of the Davis running resistance (Cunillera et al. 2022, Section 3.1).

State x = (s, v, r0, r1, r2); process (eq. 4-5) over the step dt between two measurements:

    a  = u - g - r0 - r1 v - r2 v^2       (euler; midpoint: a at v + dt/2 * a)
    s' = s + dt v + dt^2/2 a,  v' = v + dt a,  r' = r

with u the applied effort and g the track force of the measurement at the start of the step; the
measurement z = (s, v) (or v alone when s was not measured) is linear.

The unscented transform is done in closed form. Every sigma point is x + d with d = 0 or +-c L_j
(L the Cholesky factor of P, c^2 = L + lambda), and the process is A x + b a(x) with A linear,
b = (dt^2/2, dt, 0, 0, 0) and a(x) a scalar; with o_j, e_j the odd and even parts of
a(x +- c L_j) - a(x):

    a_bar = a(x) + sum_j e_j / c^2
    m     = sum_j L_j o_j / c                      (cross-covariance of x and a)
    q     = (beta - alpha^2) E^2 + sum_j (o_j^2 + e_j^2) / c^2,  E = sum_j e_j / c^2
    x_bar = A x + b a_bar,   P_bar = A P A^T + A m b^T + b m^T A^T + q b b^T + Q

which is algebraically the weighted sums of eq. 10-11 (van der Merwe weights, eq. 9) without
forming the 11 sigma points or their huge cancelling weights (w0 = -1.7e6 with Table 1), and the
update (eq. 12-18) with a linear h reduces to a 2x2 Kalman update (derivation: docs/estimator.md, "The filter").
``ukf_reference.py`` is the same step written as the paper's equations with explicit sigma points; tests check
the closed form against it step by step and against filterpy's UnscentedKalmanFilter + MerweScaledSigmaPoints.

Known effort with look-ahead (``effort_mode: exploit_known``, ``coast_confirm_ahead`` > 0): whether a step
was coasting (u = 0 known) is decided only when the speeds up to ``coast_confirm_ahead`` after it are in
(a traction ramp that starts inside the step is invisible in the past samples). The *resistance filter*
therefore runs that far behind the latest measurement, on the steps whose decision is final; it is the
filter that learns r, and the one the filterpy test and the smoother use (``resistance_run``). An *output
filter* at the latest measurement brings s and v up to date: the unscented step of (s, v) with r a consider
parameter fixed at the resistance filter's latest estimate (its uncertainty enters on known-effort steps as
acceleration noise J P_rr J^T, first order: a is linear in r), the effort decided at once from past samples.
The published estimate is the output filter's s, v and the resistance filter's r (covariance block
diagonal); both are causal. Without look-ahead the two are one filter.

Reading order: ``ResistanceEstimator.process`` (one measurement: ``_rejection``, ``_repaired``, ``_start_run`` /
``_restart_after_gap``, ``_step`` = ``_predict_published`` (effort decision ``_known_effort``, prediction),
``_measure`` (gate, update), ``_safeguard``, ``_look_ahead`` (the resistance filter: ``_advance``,
``_resistance_step``)), then the closed-form step at the end of the class. Results are named tuples:
``StepResult`` per measurement, ``PendingStep`` per step waiting for the look-ahead, ``TraceStep`` per step of the
resistance filter (``record_trace``). Packed covariance indices: ``covariance.py`` and docs/estimator.md.
"""

from __future__ import annotations

import math
from collections import deque
from functools import lru_cache, partial
from typing import NamedTuple

import numpy as np
from scipy.stats import chi2

from ..measurement import Measurement
from ..train import Davis, TrainSpec
from . import ukf_fast
from .coast_regression import POWER_DRIVE, POWER_NONE, POWER_UNKNOWN, CoastRegression, CoastSettings
from .config import UKFConfig
from .covariance import cholesky, project_nonnegative, repair, unpack
from .effort import PowerEffort, SpeedSlope
from .records import (
    EFFORT_COASTING,
    EFFORT_COMPUTED,
    EFFORT_POWER,
    EFFORT_POWER_COASTING,
    HEALTH_DEGRADED,
    HEALTH_OK,
    HEALTH_REPAIRED,
    HEALTH_RESET,
    EstimateSample,
)
from .safeguards import SafeguardConfig
from .ukf_fast import eligible as common_eligible

_NONNEG = (1, 2, 3, 4)  # v, r0, r1, r2
# inputs beyond these are not measurements of a train (a corrupt message): rejected or repaired, never used
MAX_SPEED = 200.0  # m/s (720 km/h)
MAX_TRACK_FORCE = 5.0  # N/kg (a 50 % gradient)
MAX_POSITION = 1.0e7  # m along the track
MAX_POWER = 1.0e9  # W
VARIANCE_RANGE = (1e-12, 1e12)  # m^2 or (m/s)^2
_CLIP_ONLY = (1,)  # v >= 0 is clipped: a speed below 0 says nothing about r (standstill noise would move it)
RELOCK_COUNT = 3  # gated positions in a row (besides gate_relock_time) before s is re-initialised there
_JITTER = 0.02  # relative tolerance on time windows for stamp jitter (as SpeedSlope)
COUNTERS = (
    "updates",
    "runs",
    "repairs",
    "resets",
    "gaps",
    "degraded",
    "projections",
    "known_effort_coast",
    "known_effort_rejected",
    "known_effort_power",
    "known_effort_power_coast",
    "power_regenerating",
    "power_braking_unseen",
    "coast_unconfirmed",
    "nonpositive_dt",
    "invalid_input",
    "position_missing",
    "input_repaired",
    "position_gated",
    "position_relocks",
    "nis_resets",
)
"""Diagnostic counters of ResistanceEstimator (``counters``), in this order."""


@lru_cache(maxsize=64)
def _chi2_quantile(q: float, dof: int) -> float:
    """Chi-square quantile (cached: a filter is made per run and per node parameter change)."""
    return float(chi2.ppf(q, dof))


@lru_cache(maxsize=16)
def _nis_limits(q: float, window: int) -> tuple[float, ...]:
    """Chi-square quantile q of 0..2 window degrees of freedom (inf for 0)."""
    return (math.inf, *(float(x) for x in chi2.ppf(q, range(1, 2 * window + 1))))


_SOURCE = {
    "known_effort_coast": EFFORT_COASTING,
    "known_effort_power": EFFORT_POWER,
    "known_effort_power_coast": EFFORT_POWER_COASTING,
}
"""Effort source (EstimateSample.effort_source) of a known-effort step, by its counter."""
_SEVERITY = {HEALTH_OK: 0, HEALTH_DEGRADED: 1, HEALTH_REPAIRED: 2, HEALTH_RESET: 3}


def worse(a: int, b: int) -> int:
    """The more severe of two health flags: RESET over REPAIRED over DEGRADED over OK (as one filter step sets
    them: an inconsistent NIS window flags DEGRADED only when nothing else happened)."""
    return a if _SEVERITY[a] >= _SEVERITY[b] else b


def running_resistance(r0: float, r1: float, r2: float, v: float) -> float:
    """Davis running resistance r(v) = r0 + r1 v + r2 v^2 in Horner form, N/kg (v in m/s; numpy arrays too)."""
    return r0 + (r1 + r2 * v) * v


class StepInput(NamedTuple):
    """One measurement as the filter takes it: the fields of :class:`Measurement` it uses, SI units."""

    stamp_ns: int
    run_id: int
    s: float  # position along the track, m (NaN: not measured)
    v: float  # speed, m/s
    track_force: float  # g(s), N/kg
    s_measured: bool
    s_variance: float  # m^2
    v_variance: float  # (m/s)^2
    power_valid: bool
    power_consumed: float  # W
    power_regenerated: float  # W
    tunnel_fraction: float = 0.0  # share of the train inside a tunnel, 0..1
    track_force_integral: float = math.nan  # Gamma(s), J/kg (NaN: unknown)

    @classmethod
    def from_measurement(cls, m: Measurement) -> StepInput:
        return cls(int(m.stamp_ns), int(m.run_id), float(m.s), float(m.v), float(m.track_force), bool(m.s_measured),
                   float(m.s_variance), float(m.v_variance), bool(m.power_valid), float(m.power_consumed),
                   float(m.power_regenerated), float(m.tunnel_fraction), float(m.track_force_integral))  # fmt: skip


_step_input = (
    partial(ukf_fast._ukf_kernel.step_input, StepInput) if ukf_fast.KERNEL_AVAILABLE else StepInput.from_measurement
)
"""StepInput.from_measurement, in C where the package was built with a compiler (``_ukf_kernel.step_input``)."""


class StepResult(NamedTuple):
    """The published estimate after one measurement (:meth:`ResistanceEstimator.process`), SI units."""

    s: float  # m
    v: float  # m/s
    r0: float  # N/kg
    r1: float  # N/(kg m/s)
    r2: float  # N/(kg (m/s)^2)
    effort: float  # published applied effort u = f_t - f_b, N/kg
    acceleration: float  # causal fit of the measured speeds, m/s^2
    resistance: float  # r(v) at the estimate, N/kg
    track_force: float  # g(s) of the measurement, N/kg
    nis: float  # normalised innovation squared of the update (0 without one)
    effort_source: int  # EFFORT_COMPUTED (0: not known) or the known effort's source, EFFORT_*
    health: int  # HEALTH_*
    dt: float  # s since the previous measurement (0: no prediction)
    input_effort: float  # the effort u the prediction used, N/kg
    decoupled: bool  # the prediction used r at its mean (consider step)
    covariance: tuple[float, ...]  # packed upper triangle over (s, v, r0, r1, r2), covariance.UPPER_INDEX


if ukf_fast.KERNEL_AVAILABLE:  # what the kernel's process_common needs of this module
    ukf_fast._ukf_kernel.configure(
        StepInput, StepResult, MAX_SPEED, MAX_TRACK_FORCE, MAX_POSITION, MAX_POWER, *VARIANCE_RANGE, HEALTH_OK,
        EFFORT_COMPUTED,
    )  # fmt: skip


class TraceStep(NamedTuple):
    """One step of the resistance filter (:meth:`ResistanceEstimator.record_trace`), SI units."""

    arrival: int  # the update() call (counted from 1) whose measurement the step used
    x: tuple[float, ...]  # (s, v, r0, r1, r2) after the step
    covariance: tuple[float, ...]  # packed upper triangle after the step
    input_effort: float  # effort u the prediction used, N/kg
    dt: float  # s (0: first sample of a run or after a gap)
    track_force: float  # g(s) of the measurement, N/kg
    decoupled: bool  # the prediction used r at its mean (consider step)
    effort_known: bool  # u was known (power or confirmed coasting)
    health: int  # HEALTH_*


class Prediction(NamedTuple):
    """The resistance filter's unscented prediction (:meth:`ResistanceEstimator.predict`)."""

    x: tuple[float, ...]  # predicted mean (s, v, r0, r1, r2)
    covariance: tuple[float, ...]  # packed predicted covariance (Q included)
    m: tuple[float, ...]  # cross-covariance of the state and the acceleration a (the smoother's P A^T term)


class PendingStep(NamedTuple):
    """A measurement the published filter has used and the resistance filter has not yet (look-ahead)."""

    index: int  # sample of the run (confirmation windows are numbered by it)
    t: float  # stamp, s
    dt: float  # s since the previous measurement
    zs: float  # measured position, m
    zv: float  # measured speed, m/s
    zv_prev: float  # previous measured speed, m/s
    g_prev: float  # track force at the start of the step, N/kg
    g: float  # track force of this measurement, N/kg
    s_measured: bool  # the position was used (after the gate)
    rs: float  # position variance, m^2
    rv: float  # speed variance, (m/s)^2
    coast_provisional: bool  # may coast, and the confirmation window up to the previous sample passed
    power_u: float | None  # effort from the measured power, N/kg (None: not known from the power)
    power_kind: str | None  # its counter ("known_effort_power", "known_effort_power_coast")
    relock: bool  # the published filter re-initialised s here (position relock)
    nis_reset: bool  # the published filter restarted s and v here (NIS rule)
    arrival: int  # the update() call (counted from 1)
    output_used_coast: bool  # the published filter took u = 0 as known here


class _Effort(NamedTuple):
    """The effort decision of one step of the published filter."""

    effort: float  # published effort, N/kg
    input_effort: float  # effort the prediction used, N/kg
    acceleration: float  # causal acceleration of the speeds, m/s^2
    source: int = EFFORT_COMPUTED
    decoupled: bool = False
    coast_provisional: bool = False
    power_u: float | None = None
    power_kind: str | None = None


class _Filter:
    """One (s, v, r0, r1, r2) filter: mean ``x``, packed covariance ``P`` and its Cholesky factor ``L``; ``m``
    (cross-covariance of x and the acceleration, for the smoother) and ``q_sv`` (the (s, v) process noise left out
    of the gain) of the last prediction."""

    __slots__ = ("L", "P", "m", "q_sv", "x")

    def __init__(self) -> None:
        self.x: list[float] | None = None
        self.P: tuple[float, ...] = ()
        self.L: tuple[float, ...] = ()
        self.m: tuple[float, ...] = (0.0, 0.0, 0.0, 0.0, 0.0)
        self.q_sv: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def assign(self, other: _Filter) -> None:
        self.x = list(other.x) if other.x is not None else None
        self.P, self.L, self.m, self.q_sv = other.P, other.L, other.m, other.q_sv


class ResistanceEstimator:
    """Per-measurement UKF of (s, v, r0, r1, r2) with effort computation, safeguards and health.

    ``update(m)`` once per measurement (variable dt from the stamps); a new ``run_id`` starts a new
    run (``carry_over``). Never returns NaN or a negative r. Counters for diagnostics: ``counters``.
    ``safeguards``: the position gate and the recovery rules (:class:`SafeguardConfig`, docs/reliability.md).
    With ``exploit_known`` and ``coast_confirm_ahead`` > 0 the resistance is learnt ``coast_confirm_ahead``
    behind the latest measurement (module docstring); ``flush()`` uses the measurements still waiting.
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
        n = 5
        lam = cfg.lam
        self._c2 = n + lam
        self._c = math.sqrt(self._c2)
        self._ic = 1.0 / self._c
        self._beta_alpha = cfg.beta - cfg.alpha**2
        self._midpoint = cfg.integration == "midpoint"
        self._exploit = cfg.effort_mode == "exploit_known"
        # coast regression: r comes from the coasting stretches, the UKF keeps it as a consider parameter
        self._coast = (
            CoastRegression(train, CoastSettings.from_config(cfg), self.prior)
            if cfg.resistance_learning == "coast_regression"
            else None
        )
        self._decouple = bool(cfg.decouple_unknown_effort) or self._coast is not None
        self._use_q_gain = bool(cfg.update_uses_process_noise)
        self._qa = cfg.accel_noise_std**2
        self._qr = (cfg.noise_r0**2, cfg.noise_r1**2, cfg.noise_r2**2)
        self._rs = cfg.meas_std_s**2
        self._rv = cfg.meas_std_v**2
        self._power = PowerEffort(train)
        self._slope = SpeedSlope(cfg.accel_window)
        self._coast_prior = cfg.coast_reference == "prior"
        self._prior_r = self.prior.as_tuple()
        self._coast_slope = SpeedSlope(cfg.coast_confirm_time)
        self._coast_span = (1.0 - _JITTER) * cfg.coast_confirm_time - 1e-6
        self._ahead = cfg.coast_confirm_ahead if self._exploit else 0.0
        self._lookahead = self._ahead > 0.0
        self._ahead_span = (1.0 - _JITTER) * self._ahead - 1e-6
        # look-ahead windows are tested from half the confirmation time on (own windows need all of it)
        self._ahead_test_span = (
            min(self._coast_span, 0.5 * cfg.coast_confirm_time) if self._lookahead else self._coast_span
        )
        self._nis_limit = _nis_limits(cfg.nis_quantile, cfg.nis_window)
        self._nis_window = cfg.nis_window
        self._common = common_eligible(self)  # the common step by ukf_fast.common_step
        self._common_step = ukf_fast.common_step  # the C kernel's, or the Python one without it
        # a common sample's whole process() in C (the kernel's process_common; None: the Python process alone)
        self._process_kernel = ukf_fast._ukf_kernel.process_common if ukf_fast.KERNEL_AVAILABLE else None
        self._gate = _chi2_quantile(cfg.known_effort_gate, 1) if cfg.known_effort_gate < 1.0 else math.inf
        self._position_gate = _chi2_quantile(guard.position_gate, 1) if guard.position_gate < 1.0 else math.inf
        self._relock_ns = int(guard.gate_relock_time * 1e9)
        self._gate_accel = guard.gate_accel_std
        self._nis_reset_steps = guard.nis_reset_windows * cfg.nis_window
        self.counters: dict[str, int] = dict.fromkeys(COUNTERS, 0)
        self.rejected: str | None = None  # why the latest measurement was not used (None: it was)
        self._h = _Filter()  # the published (output) filter
        self._rf = _Filter() if self._lookahead else self._h  # the resistance filter (the same one without look-ahead)
        self._pending: deque[PendingStep] = deque()  # measurements the resistance filter has not used yet
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
        s, v, r0, r1, r2, effort, accel, resistance, g, nis, source, health, dt, u, _, cov = self.process(
            _step_input(m)
        )
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
        f = _Filter()
        f.x, f.P, f.L = list(x), tuple(covariance), chol
        self._predict(f, dt, u, g, decoupled)
        return Prediction(tuple(f.x), f.P, f.m)

    # -- internals ------------------------------------------------------------------------------
    def _reset_run_state(self) -> None:
        self._pending.clear()
        self._slope.reset()
        self._last_stamp = 0
        self._zv_prev = 0.0
        self._g_prev = 0.0
        self._pw_prev = (False, 0.0, 0.0)
        self._coast_slope.reset()
        self._coast_pass = False  # the confirmation window ending at the latest sample passed
        self._index = 0  # samples of the run so far
        self._last_fail = 0  # the latest sample whose confirmation window was tested and failed (look-ahead)
        self._last_effort = 0.0
        self._last_accel = 0.0
        self._last_input = 0.0
        self._nis_ring: deque[tuple[float, int]] = deque()
        self._nis_sum = 0.0
        self._nis_dof = 0
        self._degraded_steps = 0  # consecutive DEGRADED steps (NIS recovery rule)
        self._gated_since: int | None = None  # stamp of the first position gated in a row (relock rule)
        self._gated_count = 0
        self._relocked = False

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

    def _initialise_filter(self, f: _Filter, zs: float, zv: float, keep: bool, inflation: float = 1.0) -> None:
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

    def _set_cov(self, f: _Filter, p: tuple[float, ...]) -> int:
        """Store P and its factor; repair when not positive definite. Returns a health flag."""
        chol = cholesky(p)
        if chol is not None:
            f.P, f.L = p, chol
            return HEALTH_OK
        fixed = repair(p, self.config.repair_min_eigenvalue)
        chol = cholesky(fixed) if fixed is not None else None
        if chol is None:
            return HEALTH_RESET
        self.counters["repairs"] += 1
        f.P, f.L = fixed, chol
        return HEALTH_REPAIRED

    def _published_cov(self) -> tuple[float, ...]:
        """The output filter's (s, v) block and the resistance filter's r block (no cross-covariance)."""
        hp, mp = self._h.P, self._rf.P
        return (hp[0], hp[1], 0.0, 0.0, 0.0, hp[5], 0.0, 0.0, 0.0, mp[9], mp[10], mp[11], mp[12], mp[13], mp[14])

    def _sync(self) -> int:
        """The output filter takes the resistance filter's r and r covariance (no cross-covariance). P is block
        diagonal, so its Cholesky factor is the (s, v) block's and the r block's, each in closed form (equal to
        the 5x5 factorisation, whose cross terms are exact zeros); the general path when either is not positive
        definite."""
        h = self._h
        hx, mx = h.x, self._rf.x
        hx[2], hx[3], hx[4] = mx[2], mx[3], mx[4]
        p = self._published_cov()
        p00, p01, p11 = p[0], p[1], p[5]
        p22, p23, p24, p33, p34, p44 = p[9], p[10], p[11], p[12], p[13], p[14]
        if p00 > 0.0 and p22 > 0.0:
            l00 = math.sqrt(p00)
            l10 = p01 / l00
            d1 = p11 - l10 * l10
            l22 = math.sqrt(p22)
            l32 = p23 / l22
            l42 = p24 / l22
            d3 = p33 - l32 * l32
            if d1 > 0.0 and d3 > 0.0:
                l11 = math.sqrt(d1)
                l33 = math.sqrt(d3)
                l43 = (p34 - l42 * l32) / l33
                d4 = p44 - l42 * l42 - l43 * l43
                if d4 > 0.0:
                    h.P = p
                    h.L = (l00, l10, 0.0, 0.0, 0.0, l11, 0.0, 0.0, 0.0, l22, l32, l42, l33, l43, math.sqrt(d4))
                    return HEALTH_OK
        return self._set_cov(h, p)

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
            eff = _Effort(self._last_effort, self._last_input, self._last_accel)
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

    def _predict_published(self, m: StepInput, dt: float, a_obs: float, rv: float) -> _Effort:
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
        return _Effort(effort, u, a_obs, source, decoupled, provisional, power_u, power_kind)

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

    def _safeguard(self, zs: float, zv: float, health: int, nis: float, dof: int) -> tuple[int, float, bool]:
        """After the update of the published filter: reset on NaN/inf, bounds (v >= 0; without look-ahead r >= 0 and
        the covariance check), the NIS window (DEGRADED, or the NIS reset rule). Returns (health, NIS, NIS reset)."""
        h = self._h
        x = h.x
        if not math.isfinite(sum(x) + sum(h.P) + nis):  # NaN or inf anywhere
            health = self._hard_reset(zs, zv)
            nis, dof = 0.0, 0
        elif self._lookahead:
            if x[1] < 0.0:  # r is the resistance filter's: only the speed bound here
                x[1] = 0.0
        else:
            flag = self._project_and_check(h, zs, zv)
            if flag != HEALTH_OK:
                health = flag
        return self._nis_rule(zs, zv, health, nis, dof)

    def _nis_rule(self, zs: float, zv: float, health: int, nis: float, dof: int) -> tuple[int, float, bool]:
        """The NIS window after the update: DEGRADED while it is inconsistent, the NIS reset after
        ``nis_reset_windows`` windows of it. Returns (health, NIS, NIS reset)."""
        nis_reset = False
        if self._nis_push(nis, dof):
            health, nis_reset = self._nis_inconsistent(zs, zv, health)
        else:
            self._degraded_steps = 0
        return health, nis, nis_reset

    def _nis_inconsistent(self, zs: float, zv: float, health: int) -> tuple[int, bool]:
        """``_nis_rule`` after an inconsistent window: (health, NIS reset)."""
        self._degraded_steps += 1
        if self._nis_reset_steps and self._degraded_steps >= self._nis_reset_steps:
            return self._nis_reset(zs, zv), True
        if health == HEALTH_OK:
            health = HEALTH_DEGRADED
            self.counters["degraded"] += 1
        return health, False

    def _remember(self, m: StepInput) -> None:
        """What the next step needs of this measurement: stamp, speed, track force, power."""
        self._last_stamp = m.stamp_ns
        self._zv_prev = m.v
        self._g_prev = m.track_force
        self._pw_prev = (m.power_valid, m.power_consumed, m.power_regenerated)

    def _look_ahead(self, step: PendingStep) -> int:
        """Queue the step for the resistance filter, let it use the steps whose look-ahead is complete, and give the
        published filter its r. Returns the worst health of both."""
        self._pending.append(step)
        return worse(self._advance(step.t), self._sync())

    def _result(self, eff: _Effort, g: float, nis: float, health: int, dt: float) -> StepResult:
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

    def _coast_confirmation(self, t: float, zv: float, v: float, g: float) -> None:
        """Push the sample into the confirmation window and test the window ending here: covered, the speeds on a
        line (residual), and the effort of its slope in the coasting band at the filtered speed v and track force g
        (band cut at (r + g) / 2 on the hold side, ``coast_vs_hold``; r from the prior or the estimate)."""
        cfg = self.config
        cs = self._coast_slope
        cs.push(t, zv)
        self._index += 1
        ok = False
        span = cs.span
        if span >= self._ahead_test_span:
            p0, p1, p2 = self._prior_r if self._coast_prior else self._rf.x[2:5]
            r_dec = running_resistance(p0, p1, p2, v)
            hi = cfg.coast_effort_tolerance
            lo = -hi
            if cfg.coast_vs_hold:
                hold = r_dec + g
                if hold > 0.0:
                    hi = min(hi, 0.5 * hold)
                else:
                    lo = max(lo, 0.5 * hold)
            ok = lo <= cs.slope + r_dec + g <= hi and cs.residual_std() <= cfg.coast_max_residual
            if not ok:  # a failed test (a window too short to test, after a hole in the speeds, is no evidence)
                self._last_fail = self._index
        self._coast_pass = ok and span >= self._coast_span

    def _advance(self, t: float) -> int:
        """The resistance filter uses every waiting measurement whose look-ahead is complete at time t (s): a
        coasting step is confirmed when every confirmation window from the one ending at its start to the latest
        passed. Returns the worst health of those steps."""
        pending = self._pending
        horizon = t - self._ahead_span
        health = HEALTH_OK
        while pending and pending[0].t <= horizon:
            step = pending.popleft()
            confirmed = step.coast_provisional and self._last_fail < step.index - 1
            health = worse(health, self._resistance_step(step, confirmed))
        return health

    def _resistance_step(self, step: PendingStep, confirmed: bool) -> int:
        """One step of the resistance filter (the same UKF step as the output filter's, on the decided effort)."""
        f = self._rf
        counters = self.counters
        known = decoupled = False
        u = 0.0
        dt, zs, zv, g_prev, rs, rv = step.dt, step.zs, step.zv, step.g_prev, step.rs, step.rv
        if dt > 0.0:
            x = f.x
            dz = zv - step.zv_prev
            v_ref = x[1] + 0.5 * dz if self._midpoint else x[1]
            u = dz / dt + x[2] + (x[3] + x[4] * v_ref) * v_ref + g_prev  # (dz/dt + r0) + ...: kept for bit-identity
            known_u, kind = step.power_u, step.power_kind
            if known_u is None and step.coast_provisional:
                if confirmed:
                    known_u, kind = 0.0, "known_effort_coast"
                elif step.output_used_coast:
                    counters["coast_unconfirmed"] += 1
            if known_u is not None:
                if self._known_predict(f, dt, known_u, g_prev, zv, rv):
                    known = True
                    u = known_u
                    counters[kind] += 1
                else:
                    counters["known_effort_rejected"] += 1
            decoupled = self._decouple and not known
            if not known:
                self._predict(f, dt, u, g_prev, decoupled)
        if step.relock:  # the output filter re-initialised s at this measurement
            f.x[0] = zs
            p = list(f.P)
            p[0], p[1], p[2], p[3], p[4] = rs, 0.0, 0.0, 0.0, 0.0
            f.P = tuple(p)
        nis, _ = self._update(f, zs, zv, rs, rv, step.s_measured, dt, decoupled)
        if not math.isfinite(sum(f.x) + sum(f.P) + nis):
            health = self._hard_reset_filter(f, zs, zv)
        else:
            health = self._project_and_check(f, zs, zv)
        if step.nis_reset:  # the output filter restarted s and v here (NIS rule)
            self._restart_speed(f, zs, zv)
        if self._trace is not None:
            self._trace.append(TraceStep(step.arrival, tuple(f.x), f.P, u, dt, step.g, decoupled, known, health))
        return health

    def _known_predict(
        self, f: _Filter, dt: float, known_u: float, g: float, zv: float, rv: float, output: bool = False
    ) -> bool:
        """Predict f with the known effort (``output``: the output filter's (s, v) step); False (f unchanged) when
        the speed innovation fails the gate."""
        saved = (list(f.x), f.P, f.L, f.m, f.q_sv)
        if output:
            self._predict_output(f, dt, known_u, g, True)
        else:
            self._predict(f, dt, known_u, g, False)
        nu = zv - f.x[1]
        if nu * nu <= self._gate * (f.P[5] + rv):
            return True
        f.x[:] = saved[0]
        f.P, f.L, f.m, f.q_sv = saved[1], saved[2], saved[3], saved[4]
        return False

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

    def _gate_position(self, stamp_ns: int, zs: float, rs: float, dt: float, health: int) -> tuple[bool, int, float]:
        """Position gate: (use the position, health, NIS of a gated position). An innovation beyond the
        ``position_gate`` quantile of its predicted variance is left out (speed-only update); gated for
        ``gate_relock_time`` and at least RELOCK_COUNT measurements in a row, s is re-initialised at the
        measurement (its covariance row reset: variance rs, no correlation): health RESET."""
        h = self._h
        nu = zs - h.x[0]
        model = self._gate_accel * 0.5 * dt * dt
        var = h.P[0] + rs + model * model
        if nu * nu <= self._position_gate * var:
            self._gated_since = None
            self._gated_count = 0
            return True, health, 0.0
        if self._gated_since is None:
            self._gated_since = stamp_ns
            self._gated_count = 0
        self._gated_count += 1
        if stamp_ns - self._gated_since < self._relock_ns or self._gated_count < RELOCK_COUNT:
            self.counters["position_gated"] += 1
            return False, health, nu * nu / var
        self._gated_since = None
        self._gated_count = 0
        self.counters["position_relocks"] += 1
        self.counters["resets"] += 1
        self._relocked = True
        h.x[0] = zs
        p = list(h.P)
        p[0], p[1], p[2], p[3], p[4] = rs, 0.0, 0.0, 0.0, 0.0
        h.P = tuple(p)
        return True, HEALTH_RESET, 0.0

    def _restart_speed(self, f: _Filter, zs: float, zv: float) -> None:
        """s and v of f restart at the measurement with their initial covariance; r and its covariance block kept."""
        cfg = self.config
        f.x[0], f.x[1] = zs, max(zv, 0.0)
        p = list(f.P)
        p[0:9] = [cfg.init_std_s**2, 0.0, 0.0, 0.0, 0.0, cfg.init_std_v**2, 0.0, 0.0, 0.0]
        if self._set_cov(f, tuple(p)) == HEALTH_RESET:
            self._hard_reset_filter(f, zs, zv)

    def _nis_reset(self, zs: float, zv: float) -> int:
        """The innovations stayed inconsistent for ``nis_reset_windows`` NIS windows: s and v restart at the
        measurement with their initial covariance; r and its covariance block are kept (no cross terms)."""
        self.counters["nis_resets"] += 1
        self.counters["resets"] += 1
        self._restart_speed(self._h, zs, zv)
        self._nis_ring.clear()
        self._nis_sum = 0.0
        self._nis_dof = 0
        self._degraded_steps = 0
        return HEALTH_RESET

    def _project_and_check(self, f: _Filter, zs: float, zv: float) -> int:
        """After an update with a finite result: r (and v) projected onto >= 0, P stored and checked (repaired when
        not positive definite, f restarted when beyond repair). Returns HEALTH_OK, HEALTH_REPAIRED or HEALTH_RESET."""
        x = f.x
        if (x[1] < 0.0 or x[2] < 0.0 or x[3] < 0.0 or x[4] < 0.0) and project_nonnegative(
            x, f.P, _NONNEG, self.config.nonnegative, clip_only=_CLIP_ONLY
        ):
            self.counters["projections"] += 1
        flag = self._set_cov(f, f.P)
        return self._hard_reset_filter(f, zs, zv) if flag == HEALTH_RESET else flag

    def _hard_reset(self, zs: float, zv: float) -> int:
        """Invalid state or covariance of the output filter: restart s and v at the measurement; r and its
        covariance block are kept when they are finite and valid (r >= 0, positive definite), else taken from the
        prior (Table 1)."""
        return self._hard_reset_filter(self._h, zs, zv)

    def _hard_reset_filter(self, f: _Filter, zs: float, zv: float) -> int:
        self.counters["resets"] += 1
        self._initialise_filter(f, zs, zv, True)
        return HEALTH_RESET

    def _nis_push(self, nis: float, dof: int) -> bool:
        """Add the step's NIS (and its degrees of freedom) to the window; True when the window is full and its sum
        exceeds the chi-square limit of its degrees of freedom."""
        ring = self._nis_ring
        ring.append((nis, dof))
        total, dofs = self._nis_sum + nis, self._nis_dof + dof
        window = self._nis_window
        if len(ring) > window:
            old, odof = ring.popleft()
            total -= old
            dofs -= odof
        self._nis_sum, self._nis_dof = total, dofs
        if len(ring) < window or dofs <= 0:
            return False
        return total > self._nis_limit[dofs]

    # -- the closed-form unscented step (docs/estimator.md, "The filter") ------------------------------------------
    def _mean_acceleration(self, x: list[float], w: float, h: float) -> tuple[float, float]:
        """(a at the mean, the mid-step speed v + h a_euler), w = u - g in N/kg, h = dt/2 in s (eq. 5; the midpoint
        rule takes a at the mid-step speed)."""
        v, r0, r1, r2 = x[1], x[2], x[3], x[4]
        a0 = w - r0 - (r1 + r2 * v) * v
        vh = v + h * a0
        if self._midpoint:
            a0 = w - r0 - (r1 + r2 * vh) * vh
        return a0, vh

    def _speed_directions(
        self, x: list[float], vh: float, h: float, l10: float, l11: float
    ) -> tuple[float, float, float, float]:
        """(o0, e0, o1, e1): odd and even parts of a(x +- c L_j) - a(x) along the sigma directions j = 0, 1 when r
        enters at its mean (only the speed component c L_1j of the direction moves a); zero along j = 2, 3, 4.
        Euler rule: :meth:`_speed_directions_any`'s ``da`` written out (the same operations without its closure and
        four calls: 1.1 -> 0.6 us a step); the midpoint rule there."""
        if self._midpoint:
            return self._speed_directions_any(x, vh, h, l10, l11)
        r1, r2 = x[3], x[4]
        two_v = 2.0 * x[1]
        c = self._c
        dv = c * l10  # da(dv) = -(r1 + r2 (2 v + dv)) dv, at +dv and -dv
        ap, am = -((r1 + r2 * (two_v + dv)) * dv), -((r1 + r2 * (two_v + -dv)) * -dv)
        o0, e0 = 0.5 * (ap - am), 0.5 * (ap + am)
        dv = c * l11
        ap, am = -((r1 + r2 * (two_v + dv)) * dv), -((r1 + r2 * (two_v + -dv)) * -dv)
        return o0, e0, 0.5 * (ap - am), 0.5 * (ap + am)

    def _speed_directions_any(
        self, x: list[float], vh: float, h: float, l10: float, l11: float
    ) -> tuple[float, float, float, float]:
        """:meth:`_speed_directions` under either integration rule (the reference of its Euler fast path)."""
        v, r1, r2 = x[1], x[3], x[4]
        c = self._c
        mid = self._midpoint

        def da(dv: float) -> float:
            dr = (r1 + r2 * (2.0 * v + dv)) * dv
            if not mid:
                return -dr
            dvh = dv - h * dr
            return -(r1 + r2 * (2.0 * vh + dvh)) * dvh

        dv0 = c * l10
        ap, am = da(dv0), da(-dv0)
        o0, e0 = 0.5 * (ap - am), 0.5 * (ap + am)
        dv1 = c * l11
        ap, am = da(dv1), da(-dv1)
        return o0, e0, 0.5 * (ap - am), 0.5 * (ap + am)

    def _all_directions(self, x: list[float], vh: float, h: float, lf: tuple[float, ...]) -> tuple[float, ...]:
        """(o0, e0, ..., o4, e4): odd and even parts of a(x +- c L_j) - a(x) along the five sigma directions, r
        moving with the sigma point (lf: the packed Cholesky factor)."""
        v, r1, r2 = x[1], x[3], x[4]
        _l00, l10, l20, l30, l40, l11, l21, l31, l41, l22, l32, l42, l33, l43, l44 = lf
        c = self._c
        mid = self._midpoint

        def da(dv: float, d0: float, d1: float, d2: float) -> float:  # a(x + d) - a(x), d over (v, r0, r1, r2)
            w1 = v + dv
            dr = d0 + (d1 + d2 * w1) * w1 + (r1 + r2 * (2.0 * v + dv)) * dv
            if not mid:
                return -dr
            dvh = dv - h * dr
            wh = vh + dvh
            return -(d0 + (d1 + d2 * wh) * wh + (r1 + r2 * (2.0 * vh + dvh)) * dvh)

        dv0, d00, d10, d20 = c * l10, c * l20, c * l30, c * l40
        ap, am = da(dv0, d00, d10, d20), da(-dv0, -d00, -d10, -d20)
        o0, e0 = 0.5 * (ap - am), 0.5 * (ap + am)
        dv1, d01, d11, d21 = c * l11, c * l21, c * l31, c * l41
        ap, am = da(dv1, d01, d11, d21), da(-dv1, -d01, -d11, -d21)
        o1, e1 = 0.5 * (ap - am), 0.5 * (ap + am)
        d02, d12, d22 = c * l22, c * l32, c * l42
        ap, am = da(0.0, d02, d12, d22), da(0.0, -d02, -d12, -d22)
        o2, e2 = 0.5 * (ap - am), 0.5 * (ap + am)
        d13, d23 = c * l33, c * l43
        ap, am = da(0.0, 0.0, d13, d23), da(0.0, 0.0, -d13, -d23)
        o3, e3 = 0.5 * (ap - am), 0.5 * (ap + am)
        d24 = c * l44
        ap, am = da(0.0, 0.0, 0.0, d24), da(0.0, 0.0, 0.0, -d24)
        return o0, e0, o1, e1, o2, e2, o3, e3, 0.5 * (ap - am), 0.5 * (ap + am)

    def _propagate_sv(
        self, f: _Filter, dt: float, abar: float, m0: float, m1: float, q: float, grouped: bool
    ) -> tuple[float, float, float]:
        """Mean of s and v (eq. 4 at a_bar) in place and their predicted covariance block (n00, n01, n11):
        A P A^T + A m b^T + b m^T A^T + q b b^T + Q_a, b = (dt^2/2, dt), Q_a the acceleration noise; sets f.q_sv (the
        part left out of the gain). ``grouped``: the two terms of n00 are added as one sum (the resistance filter)
        or one by one (the output filter) -- the same maths, both kept for bit-identical outputs."""
        x = f.x
        P = f.P
        p00, p01, p11 = P[0], P[1], P[5]
        s, v = x[0], x[1]
        b0 = 0.5 * dt * dt
        b1 = dt
        am0 = m0 + dt * m1  # (A m)_s
        x[0] = s + dt * v + b0 * abar
        x[1] = v + dt * abar
        n01 = p01 + dt * p11
        base = p00 + dt * (p01 + n01)
        n00 = base + (2.0 * am0 * b0 + q * b0 * b0) if grouped else base + 2.0 * am0 * b0 + q * b0 * b0
        n01 += am0 * b1 + b0 * m1 + q * b0 * b1
        n11 = p11 + 2.0 * m1 * b1 + q * b1 * b1
        f.q_sv = (0.0, 0.0, 0.0)
        qa = self._qa
        if qa > 0.0:
            qs, qsv, qv = qa * b0 * b0, qa * b0 * b1, qa * b1 * b1
            n00 += qs
            n01 += qsv
            n11 += qv
            if not self._use_q_gain:
                f.q_sv = (qs, qsv, qv)
        return n00, n01, n11

    def _predict(self, f: _Filter, dt: float, u: float, g: float, decoupled: bool) -> None:
        """The resistance filter's prediction over dt s with effort u and track force g (N/kg), eq. 7-11 in closed
        form; ``decoupled``: r enters the process at its mean (consider step)."""
        x = f.x
        lf = f.L
        _, _, p02, p03, p04, _, p12, p13, p14, p22, p23, p24, p33, p34, p44 = f.P
        h = 0.5 * dt
        a0, vh = self._mean_acceleration(x, u - g, h)
        if decoupled:  # only the v-components of the sigma points move a
            o0, e0, o1, e1 = self._speed_directions(x, vh, h, lf[1], lf[5])
            o2 = e2 = o3 = e3 = o4 = e4 = 0.0
        else:
            o0, e0, o1, e1, o2, e2, o3, e3, o4, e4 = self._all_directions(x, vh, h, lf)
        c2 = self._c2
        big_e = (e0 + e1 + e2 + e3 + e4) / c2
        q = (
            self._beta_alpha * big_e * big_e
            + (o0 * o0 + o1 * o1 + o2 * o2 + o3 * o3 + o4 * o4 + e0 * e0 + e1 * e1 + e2 * e2 + e3 * e3 + e4 * e4) / c2
        )
        l00, l10, l20, l30, l40, l11, l21, l31, l41, l22, l32, l42, l33, l43, l44 = lf
        ic = self._ic
        m0 = l00 * o0 * ic
        m1 = (l10 * o0 + l11 * o1) * ic
        m2 = (l20 * o0 + l21 * o1 + l22 * o2) * ic
        m3 = (l30 * o0 + l31 * o1 + l32 * o2 + l33 * o3) * ic
        m4 = (l40 * o0 + l41 * o1 + l42 * o2 + l43 * o3 + l44 * o4) * ic
        f.m = (m0, m1, m2, m3, m4)
        # the s and v rows of A P A^T before the mean moves
        n02, n03, n04 = p02 + dt * p12, p03 + dt * p13, p04 + dt * p14
        n00, n01, n11 = self._propagate_sv(f, dt, a0 + big_e, m0, m1, q, True)
        b0 = h * dt
        qr0, qr1, qr2 = self._qr
        f.P = (n00, n01, n02 + b0 * m2, n03 + b0 * m3, n04 + b0 * m4, n11, p12 + dt * m2, p13 + dt * m3,
               p14 + dt * m4, p22 + qr0 * dt, p23, p24, p33 + qr1 * dt, p34, p44 + qr2 * dt)  # fmt: skip

    def _predict_output(self, f: _Filter, dt: float, u: float, g: float, with_r: bool) -> None:
        """The output filter's step (look-ahead): the unscented step of (s, v) with r at its mean (f's P is block
        diagonal after ``_sync``, so the v-directions of the sigma points carry no r), and with ``with_r`` (known
        effort) r's uncertainty as acceleration noise J P_rr J^T, J = -da/dr at the mean (a is linear in r; with the
        midpoint rule through the mid-step speed too). Only the (s, v) block of P changes: r is a consider parameter
        whose cross-covariance ``_sync`` drops."""
        x = f.x
        l00, l10, l11 = f.L[0], f.L[1], f.L[5]
        P = f.P
        h = 0.5 * dt
        a0, vh = self._mean_acceleration(x, u - g, h)
        o0, e0, o1, e1 = self._speed_directions(x, vh, h, l10, l11)
        c2 = self._c2
        big_e = (e0 + e1) / c2
        q = self._beta_alpha * big_e * big_e + (o0 * o0 + o1 * o1 + e0 * e0 + e1 * e1) / c2
        if with_r:
            v, r1, r2 = x[1], x[3], x[4]
            if self._midpoint:  # a = w - r(vh), vh = v + h (w - r(v)): da/dr_i = -(1 - h r'(vh)) (1, ., .) at vh, v
                k = h * (r1 + 2.0 * r2 * vh)
                j0, j1, j2 = 1.0 - k, vh - k * v, vh * vh - k * v * v
            else:
                j0, j1, j2 = 1.0, v, v * v
            q22, q23, q24, q33, q34, q44 = P[9], P[10], P[11], P[12], P[13], P[14]
            q += j0 * (j0 * q22 + 2.0 * (j1 * q23 + j2 * q24)) + j1 * (j1 * q33 + 2.0 * j2 * q34) + j2 * j2 * q44
        ic = self._ic
        m0 = l00 * o0 * ic
        m1 = (l10 * o0 + l11 * o1) * ic
        f.m = (m0, m1, 0.0, 0.0, 0.0)
        n00, n01, n11 = self._propagate_sv(f, dt, a0 + big_e, m0, m1, q, False)
        f.P = (n00, n01, P[2], P[3], P[4], n11, *P[6:])

    def _update(
        self, f: _Filter, zs: float, zv: float, rs: float, rv: float, s_measured: bool, dt: float, consider: bool,
        sv_only: bool = False,
    ) -> tuple[float, int]:  # fmt: skip
        """Eq. 12-18 with the linear h(x) = (s, v) (v alone when not ``s_measured``): a 2x2 (or scalar) Kalman update
        in the gain basis (P without the process noise left out of the gain, ``q_sv``); variances rs (m^2), rv
        ((m/s)^2). ``consider``: r is a consider parameter (Schmidt-Kalman): its gain is zero, so r and P_rr stay, and
        the r-(s, v) covariances get the Joseph-form update. ``sv_only`` (the output filter, whose r-(s, v)
        covariances are zero): only s, v and their block change. Returns (NIS, degrees of freedom); NaN when the
        innovation covariance is not positive."""
        x = f.x
        P = f.P
        p00, p01, p11 = P[0], P[1], P[5]
        qs, qsv, qv = f.q_sv if dt > 0.0 else (0.0, 0.0, 0.0)
        c00, c01, c11 = p00 - qs, p01 - qsv, p11 - qv  # Pxz of the s and v rows
        nu1 = zv - x[1]
        if s_measured:
            nu0 = zs - x[0]
            s00, s11 = c00 + rs, c11 + rv
            det = s00 * s11 - c01 * c01
            if not det > 0.0:
                return math.nan, 2
            i00, i01, i11 = s11 / det, -c01 / det, s00 / det
            k00, k01 = c00 * i00 + c01 * i01, c00 * i01 + c01 * i11
            k10, k11 = c01 * i00 + c11 * i01, c01 * i01 + c11 * i11
            x[0] += k00 * nu0 + k01 * nu1
            x[1] += k10 * nu0 + k11 * nu1
            nis = nu0 * nu0 * i00 + 2.0 * nu0 * nu1 * i01 + nu1 * nu1 * i11
            n00, n01, n11 = p00 - (k00 * c00 + k01 * c01), p01 - (k00 * c01 + k01 * c11), p11 - (k10 * c01 + k11 * c11)
            if sv_only:
                f.P = (n00, n01, P[2], P[3], P[4], n11, *P[6:])
                return nis, 2
            _, _, p02, p03, p04, _, p12, p13, p14, p22, p23, p24, p33, p34, p44 = P
            if consider:
                k20 = k21 = k30 = k31 = k40 = k41 = 0.0
            else:
                k20, k21 = p02 * i00 + p12 * i01, p02 * i01 + p12 * i11
                k30, k31 = p03 * i00 + p13 * i01, p03 * i01 + p13 * i11
                k40, k41 = p04 * i00 + p14 * i01, p04 * i01 + p14 * i11
            x[2] += k20 * nu0 + k21 * nu1
            x[3] += k30 * nu0 + k31 * nu1
            x[4] += k40 * nu0 + k41 * nu1
            f.P = (
                n00, n01,
                p02 - (k00 * p02 + k01 * p12), p03 - (k00 * p03 + k01 * p13), p04 - (k00 * p04 + k01 * p14),
                n11,
                p12 - (k10 * p02 + k11 * p12), p13 - (k10 * p03 + k11 * p13), p14 - (k10 * p04 + k11 * p14),
                p22 - (k20 * p02 + k21 * p12), p23 - (k20 * p03 + k21 * p13), p24 - (k20 * p04 + k21 * p14),
                p33 - (k30 * p03 + k31 * p13), p34 - (k30 * p04 + k31 * p14),
                p44 - (k40 * p04 + k41 * p14),
            )  # fmt: skip
            return nis, 2
        sv = c11 + rv
        if not sv > 0.0:
            return math.nan, 1
        k0, k1 = c01 / sv, c11 / sv
        x[0] += k0 * nu1
        x[1] += k1 * nu1
        n00, n01, n11 = p00 - k0 * c01, p01 - k0 * c11, p11 - k1 * c11
        if sv_only:
            f.P = (n00, n01, P[2], P[3], P[4], n11, *P[6:])
            return nu1 * nu1 / sv, 1
        _, _, p02, p03, p04, _, p12, p13, p14, p22, p23, p24, p33, p34, p44 = P
        k2, k3, k4 = (0.0, 0.0, 0.0) if consider else (p12 / sv, p13 / sv, p14 / sv)
        x[2] += k2 * nu1
        x[3] += k3 * nu1
        x[4] += k4 * nu1
        f.P = (
            n00, n01, p02 - k0 * p12, p03 - k0 * p13, p04 - k0 * p14,
            n11, p12 - k1 * p12, p13 - k1 * p13, p14 - k1 * p14,
            p22 - k2 * p12, p23 - k2 * p13, p24 - k2 * p14,
            p33 - k3 * p13, p34 - k3 * p14,
            p44 - k4 * p14,
        )  # fmt: skip
        return nu1 * nu1 / sv, 1
