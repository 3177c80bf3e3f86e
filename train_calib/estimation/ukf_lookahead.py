"""Known effort with look-ahead: the coasting confirmation windows and the resistance filter that runs behind the
published one (docs/estimator.md).

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

:class:`LookAhead` is a base class of ``ResistanceEstimator`` (``ukf.py``): the confirmation windows
(``_coast_confirmation``, with ``exploit_known`` with or without look-ahead), the known-effort prediction and its gate
(``_known_predict``, both filters), the resistance filter's steps (``_look_ahead``: ``_advance``,
``_resistance_step``) and the output filter taking its r (``_sync``).
"""

from __future__ import annotations

import math
from collections import deque

from .config import UKFConfig
from .effort import SpeedSlope
from .records import HEALTH_OK
from .ukf_safeguards import FilterSafeguards, chi2_quantile
from .ukf_step import UnscentedStep
from .ukf_types import FilterState, PendingStep, TraceStep, running_resistance, worse

_JITTER = 0.02  # relative tolerance on time windows for stamp jitter (as SpeedSlope)


class LookAhead(FilterSafeguards, UnscentedStep):
    """The resistance filter ``_rf`` behind the published one ``_h`` and the coasting confirmation it waits for;
    the unscented step and the safeguards it uses are the base classes'. Its settings: ``_init_lookahead``; its
    run state: ``_reset_lookahead``."""

    # what it reads of ResistanceEstimator
    _rf: FilterState  # the resistance filter (``_h`` itself without look-ahead)
    _trace: list[TraceStep] | None  # record_trace(): the resistance filter's steps
    _exploit: bool  # effort_mode: exploit_known
    _decouple: bool  # r enters a computed-effort step at its mean (consider step)
    _prior_r: tuple[float, float, float]  # the prior's (r0, r1, r2)

    def _init_lookahead(self, cfg: UKFConfig) -> None:
        """The confirmation windows, the look-ahead and the known-effort gate (after ``_exploit``)."""
        self._coast_prior = cfg.coast_reference == "prior"
        self._coast_slope = SpeedSlope(cfg.coast_confirm_time)
        self._coast_span = (1.0 - _JITTER) * cfg.coast_confirm_time - 1e-6
        self._ahead = cfg.coast_confirm_ahead if self._exploit else 0.0
        self._lookahead = self._ahead > 0.0
        self._ahead_span = (1.0 - _JITTER) * self._ahead - 1e-6
        # look-ahead windows are tested from half the confirmation time on (own windows need all of it)
        self._ahead_test_span = (
            min(self._coast_span, 0.5 * cfg.coast_confirm_time) if self._lookahead else self._coast_span
        )
        self._gate = chi2_quantile(cfg.known_effort_gate, 1) if cfg.known_effort_gate < 1.0 else math.inf
        self._pending: deque[PendingStep] = deque()  # measurements the resistance filter has not used yet

    def _reset_lookahead(self) -> None:
        """A new run (or a gap): no step waiting, an empty confirmation window."""
        self._pending.clear()
        self._coast_slope.reset()
        self._coast_pass = False  # the confirmation window ending at the latest sample passed
        self._index = 0  # samples of the run so far
        self._last_fail = 0  # the latest sample whose confirmation window was tested and failed (look-ahead)

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

    def _known_predict(
        self, f: FilterState, dt: float, known_u: float, g: float, zv: float, rv: float, output: bool = False
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

    def _look_ahead(self, step: PendingStep) -> int:
        """Queue the step for the resistance filter, let it use the steps whose look-ahead is complete, and give the
        published filter its r. Returns the worst health of both."""
        self._pending.append(step)
        return worse(self._advance(step.t), self._sync())

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
