"""Output records of the resistance estimator: one sample (ResistanceEstimate.msg) and a whole run (arrays)."""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

import numpy as np

from ..train import Davis

HEALTH_OK = 0
"""Normal update."""
HEALTH_REPAIRED = 1
"""The covariance was not positive definite (or not finite off the diagonal) and was repaired."""
HEALTH_DEGRADED = 2
"""Innovations inconsistent with their covariance over the NIS window."""
HEALTH_RESET = 3
"""State or covariance invalid, or a gap longer than max_dt: the filter was re-initialised."""

EFFORT_COMPUTED = 0
"""The effort of the step is computed from the speed change and the current resistance (Cunillera eq. 4)."""
EFFORT_COASTING = 1
"""u = 0 taken as known: the speeds confirm coasting (``effort_mode: exploit_known``)."""
EFFORT_POWER = 2
"""u from the measured traction power at both ends of the step (De Martinis & Corman 2019, eq. 3)."""
EFFORT_POWER_COASTING = 3
"""u = 0 taken as known: the power at both ends of the step shows neither traction nor electric braking."""
EFFORT_SOURCES = ("computed", "coasting", "power", "power_coasting")
"""Names of the effort sources by code (ResistanceEstimate.EFFORT_*)."""

STATE_NAMES = ("s", "v", "r0", "r1", "r2")


@dataclass(slots=True)
class EstimateSample:
    """One filter update; fields as ResistanceEstimate.msg (SI units), plus dt and input_effort. Slotted: one is made
    and kept per measurement (no per-instance dict: 4 fleet 1 Hz runs' UKF stage ~1 ms less, CPU)."""

    stamp_ns: int
    run_id: int
    s: float  # m
    v: float  # m/s
    r0: float  # N/kg
    r1: float  # N/(kg m/s)
    r2: float  # N/(kg (m/s)^2)
    covariance: np.ndarray  # (5, 5) over s, v, r0, r1, r2
    effort: float  # u = f_t - f_b over the step ending here, N/kg
    acceleration: float  # observed dv/dt over the step (accel_window fit), m/s^2
    resistance: float  # r(v) at the filtered speed, N/kg
    track_force: float  # g(s) used in this step, N/kg
    nis: float  # normalised innovation squared (2 dof; 1 when s is not measured)
    effort_known: bool  # effort taken as known (coasting u = 0, or measured traction power)
    health: int  # HEALTH_*
    dt: float = 0.0  # s since the previous sample of the run (0 for the first)
    input_effort: float = 0.0  # u fed to the process model (the paper's two-point effort when not known), N/kg
    v_measured: float = math.nan  # the speed measurement of this update, m/s (features locate phase changes on it)
    effort_source: int = EFFORT_COMPUTED  # EFFORT_*: how the step's effort was obtained (effort_known: not computed)

    @property
    def davis(self) -> Davis:
        return Davis(self.r0, self.r1, self.r2)

    @property
    def state(self) -> np.ndarray:
        return np.array([self.s, self.v, self.r0, self.r1, self.r2])


@dataclass
class EstimateSeries:
    """A run of estimates as arrays (field names as EstimateSample; covariance is (n, 5, 5))."""

    stamp_ns: np.ndarray
    run_id: np.ndarray
    s: np.ndarray
    v: np.ndarray
    r0: np.ndarray
    r1: np.ndarray
    r2: np.ndarray
    covariance: np.ndarray
    effort: np.ndarray
    acceleration: np.ndarray
    resistance: np.ndarray
    track_force: np.ndarray
    nis: np.ndarray
    effort_known: np.ndarray
    health: np.ndarray
    dt: np.ndarray
    input_effort: np.ndarray
    decoupled: np.ndarray  # bool: the step's process used the mean resistance (decouple_unknown_effort)
    v_measured: np.ndarray  # the speed measurements, m/s (NaN where unknown)
    effort_source: np.ndarray  # uint8 EFFORT_* per sample

    @classmethod
    def empty(cls, n: int) -> EstimateSeries:
        ints = {"stamp_ns", "run_id", "health", "effort_source"}
        bools = {"effort_known", "decoupled"}
        data = {}
        for f in fields(cls):
            if f.name == "covariance":
                data[f.name] = np.zeros((n, 5, 5))
            elif f.name in ints:
                data[f.name] = np.zeros(n, dtype=np.uint8 if f.name in ("health", "effort_source") else np.int64)
            elif f.name in bools:
                data[f.name] = np.zeros(n, dtype=bool)
            elif f.name == "v_measured":
                data[f.name] = np.full(n, np.nan)
            else:
                data[f.name] = np.zeros(n)
        return cls(**data)

    def __len__(self) -> int:
        return int(self.stamp_ns.shape[0])

    @property
    def t(self) -> np.ndarray:
        """Seconds since the first sample."""
        return (self.stamp_ns - self.stamp_ns[0]) * 1e-9 if len(self) else np.zeros(0)

    @property
    def state(self) -> np.ndarray:
        """(n, 5) states over s, v, r0, r1, r2."""
        return np.stack([self.s, self.v, self.r0, self.r1, self.r2], axis=1)

    def sample(self, i: int) -> EstimateSample:
        values = {f.name: getattr(self, f.name)[i] for f in fields(EstimateSample)}
        values = {k: (v.copy() if k == "covariance" else v.item()) for k, v in values.items()}
        return EstimateSample(**values)

    def __iter__(self):
        return (self.sample(i) for i in range(len(self)))

    def select(self, mask_or_index) -> EstimateSeries:
        """A sub-series (boolean mask or index array)."""
        return EstimateSeries(**{f.name: getattr(self, f.name)[mask_or_index] for f in fields(self)})

    def final_davis(self) -> Davis:
        return Davis(float(self.r0[-1]), float(self.r1[-1]), float(self.r2[-1]))

    @classmethod
    def from_samples(cls, samples: list[EstimateSample]) -> EstimateSeries:
        out = cls.empty(len(samples))
        for i, smp in enumerate(samples):
            for f in fields(EstimateSample):
                getattr(out, f.name)[i] = getattr(smp, f.name)
        return out
