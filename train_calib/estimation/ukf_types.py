"""The resistance UKF's types and input limits: the named tuples it takes and returns, one filter's state, the
effort decision of a step, the health order and the input limits (docs/estimator.md, docs/reliability.md).

``StepInput`` per measurement in, ``StepResult`` per measurement out, ``PendingStep`` per step waiting for the
look-ahead, ``TraceStep`` per step of the resistance filter (``record_trace``), ``Prediction`` the resistance
filter's prediction; ``FilterState`` one (s, v, r0, r1, r2) filter (packed covariance indices: ``covariance.py``).
Where the package was built with a compiler, the C kernel is given the tuples and the limits here
(``_ukf_kernel.configure``) and builds StepInput in C (:data:`step_input`).
"""

from __future__ import annotations

import math
from functools import partial
from typing import NamedTuple

from ..measurement import Measurement
from . import ukf_fast
from .records import EFFORT_COMPUTED, HEALTH_DEGRADED, HEALTH_OK, HEALTH_REPAIRED, HEALTH_RESET

# inputs beyond these are not measurements of a train (a corrupt message): rejected or repaired, never used
MAX_SPEED = 200.0  # m/s (720 km/h)
MAX_TRACK_FORCE = 5.0  # N/kg (a 50 % gradient)
MAX_POSITION = 1.0e7  # m along the track
MAX_POWER = 1.0e9  # W
VARIANCE_RANGE = (1e-12, 1e12)  # m^2 or (m/s)^2
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


step_input = (
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


class EffortDecision(NamedTuple):
    """The effort decision of one step of the published filter."""

    effort: float  # published effort, N/kg
    input_effort: float  # effort the prediction used, N/kg
    acceleration: float  # causal acceleration of the speeds, m/s^2
    source: int = EFFORT_COMPUTED
    decoupled: bool = False
    coast_provisional: bool = False
    power_u: float | None = None
    power_kind: str | None = None


class FilterState:
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

    def assign(self, other: FilterState) -> None:
        self.x = list(other.x) if other.x is not None else None
        self.P, self.L, self.m, self.q_sv = other.P, other.L, other.m, other.q_sv
