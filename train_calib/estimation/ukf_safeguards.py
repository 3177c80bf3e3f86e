"""The resistance UKF's safeguards and recovery rules (docs/reliability.md, "Filter"; parameters
:class:`SafeguardConfig`): the position gate and its relock, the check after an update (NaN or inf: hard reset;
projection onto r >= 0, v clipped at 0; the covariance stored with its Cholesky factor, repaired when not positive
definite, the filter restarted when beyond repair), the NIS window (DEGRADED) and the NIS reset.

:class:`FilterSafeguards` is a base class of ``ResistanceEstimator`` (``ukf.py``); it keeps its own thresholds
(``_init_safeguards``) and run state (``_reset_safeguards``) and reads the estimator's attributes and method
declared in the class.
"""

from __future__ import annotations

import math
from collections import deque
from functools import lru_cache

from scipy.stats import chi2

from .config import UKFConfig
from .covariance import cholesky, project_nonnegative, repair
from .records import HEALTH_DEGRADED, HEALTH_OK, HEALTH_REPAIRED, HEALTH_RESET
from .safeguards import SafeguardConfig
from .ukf_types import FilterState

_NONNEG = (1, 2, 3, 4)  # v, r0, r1, r2
_CLIP_ONLY = (1,)  # v >= 0 is clipped: a speed below 0 says nothing about r (standstill noise would move it)
RELOCK_COUNT = 3  # gated positions in a row (besides gate_relock_time) before s is re-initialised there


@lru_cache(maxsize=64)
def chi2_quantile(q: float, dof: int) -> float:
    """Chi-square quantile (cached: a filter is made per run and per node parameter change)."""
    return float(chi2.ppf(q, dof))


@lru_cache(maxsize=16)
def _nis_limits(q: float, window: int) -> tuple[float, ...]:
    """Chi-square quantile q of 0..2 window degrees of freedom (inf for 0)."""
    return (math.inf, *(float(x) for x in chi2.ppf(q, range(1, 2 * window + 1))))


class FilterSafeguards:
    """The safeguards of the published filter ``_h`` (and, with look-ahead, of the resistance filter): the position
    gate (``_gate_position``), the check after an update (``_safeguard``, ``_project_and_check``, ``_set_cov``,
    ``_hard_reset``), the NIS rule (``_nis_rule``, ``_nis_reset``)."""

    # what it reads of ResistanceEstimator
    config: UKFConfig
    counters: dict[str, int]
    _h: FilterState  # the published (output) filter
    _lookahead: bool  # a resistance filter runs behind ``_h``: r and its bounds are that filter's

    def _initialise_filter(self, f: FilterState, zs: float, zv: float, keep: bool, inflation: float = 1.0) -> None:
        """Restart filter f at the measurement, r kept or from the prior: ``ResistanceEstimator``'s."""
        raise NotImplementedError

    def _init_safeguards(self, cfg: UKFConfig, guard: SafeguardConfig) -> None:
        """The thresholds of the gate and the NIS rule."""
        self._nis_limit = _nis_limits(cfg.nis_quantile, cfg.nis_window)
        self._nis_window = cfg.nis_window
        self._position_gate = chi2_quantile(guard.position_gate, 1) if guard.position_gate < 1.0 else math.inf
        self._relock_ns = int(guard.gate_relock_time * 1e9)
        self._gate_accel = guard.gate_accel_std
        self._nis_reset_steps = guard.nis_reset_windows * cfg.nis_window

    def _reset_safeguards(self) -> None:
        """A new run (or a gap): an empty NIS window, no position gated."""
        self._nis_ring: deque[tuple[float, int]] = deque()
        self._nis_sum = 0.0
        self._nis_dof = 0
        self._degraded_steps = 0  # consecutive DEGRADED steps (NIS recovery rule)
        self._gated_since: int | None = None  # stamp of the first position gated in a row (relock rule)
        self._gated_count = 0
        self._relocked = False

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

    def _project_and_check(self, f: FilterState, zs: float, zv: float) -> int:
        """After an update with a finite result: r (and v) projected onto >= 0, P stored and checked (repaired when
        not positive definite, f restarted when beyond repair). Returns HEALTH_OK, HEALTH_REPAIRED or HEALTH_RESET."""
        x = f.x
        if (x[1] < 0.0 or x[2] < 0.0 or x[3] < 0.0 or x[4] < 0.0) and project_nonnegative(
            x, f.P, _NONNEG, self.config.nonnegative, clip_only=_CLIP_ONLY
        ):
            self.counters["projections"] += 1
        flag = self._set_cov(f, f.P)
        return self._hard_reset_filter(f, zs, zv) if flag == HEALTH_RESET else flag

    def _set_cov(self, f: FilterState, p: tuple[float, ...]) -> int:
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

    def _hard_reset(self, zs: float, zv: float) -> int:
        """Invalid state or covariance of the output filter: restart s and v at the measurement; r and its
        covariance block are kept when they are finite and valid (r >= 0, positive definite), else taken from the
        prior (Table 1)."""
        return self._hard_reset_filter(self._h, zs, zv)

    def _hard_reset_filter(self, f: FilterState, zs: float, zv: float) -> int:
        self.counters["resets"] += 1
        self._initialise_filter(f, zs, zv, True)
        return HEALTH_RESET

    def _nis_rule(self, zs: float, zv: float, health: int, nis: float, dof: int) -> tuple[int, float, bool]:
        """The NIS window after the update: DEGRADED while it is inconsistent, the NIS reset after
        ``nis_reset_windows`` windows of it. Returns (health, NIS, NIS reset)."""
        nis_reset = False
        if self._nis_push(nis, dof):
            health, nis_reset = self._nis_inconsistent(zs, zv, health)
        else:
            self._degraded_steps = 0
        return health, nis, nis_reset

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

    def _nis_inconsistent(self, zs: float, zv: float, health: int) -> tuple[int, bool]:
        """``_nis_rule`` after an inconsistent window: (health, NIS reset)."""
        self._degraded_steps += 1
        if self._nis_reset_steps and self._degraded_steps >= self._nis_reset_steps:
            return self._nis_reset(zs, zv), True
        if health == HEALTH_OK:
            health = HEALTH_DEGRADED
            self.counters["degraded"] += 1
        return health, False

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

    def _restart_speed(self, f: FilterState, zs: float, zv: float) -> None:
        """s and v of f restart at the measurement with their initial covariance; r and its covariance block kept."""
        cfg = self.config
        f.x[0], f.x[1] = zs, max(zv, 0.0)
        p = list(f.P)
        p[0:9] = [cfg.init_std_s**2, 0.0, 0.0, 0.0, 0.0, cfg.init_std_v**2, 0.0, 0.0, 0.0]
        if self._set_cov(f, tuple(p)) == HEALTH_RESET:
            self._hard_reset_filter(f, zs, zv)

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
