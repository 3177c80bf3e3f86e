"""The realistic driver: a phase machine integrated over time with RK45 and events.

State (s, v) over time t. The driver follows the target speed theta * limit-over-train, in the
style of :class:`~.driver.DriverParams`; every switch is an event located on the dense output:

    departure:  brakes hold until the ramped traction exceeds r0 + g, then RAMP -> TRACTION
    at target:  HOLD (hold style) or COAST down by the band, TRACTION back (cycles style: at least
                cycle_min_accel net where the re-acceleration starts, up to the full envelope)
    ceiling up: ramped re-acceleration (tail clear of the lower limit)
    braking:    where s + D(v) reaches a lower limit (D through the ATB-EG steps, b_limit per step)
                or the stop (b_stop; the stop brake is the closed loop v^2 / 2d, exact to the metre)
    final coast: from the planned coast point on (see :func:`plan_coast_point`)

The track force and tunnel knots are integrator stops in the phases where the motion depends on
them; holding and braking are exact polynomials, so those steps are long.
"""

from __future__ import annotations

import math
from bisect import bisect_right
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import brentq

from ..physics import KMH
from .driver import BrakeSteps, DriverParams
from .integrate import Event, StepRecord, integrate
from .limits import SpeedCeiling
from .model import MotionModel
from .phases import Brake, Coast, Hold, Phase, Ramp, Stand, StopBrake, Traction

_V_STOPPED = 0.01  # m/s: below this the stop brake is finished in closed form
_MAX_STEP = 120.0  # s
MAX_BAND_SHARE = 0.5  # a cycle's coast goes at most this share of the ceiling below it
_RTOL = 1e-8


@dataclass
class Target:
    """A braking target: reach v_low (m/s) by s_m; kind 'limit' or 'stop'."""

    s_m: float
    v_low: float
    kind: str


@dataclass
class DriveResult:
    """The integrated run: piecewise polynomial steps tagged with the driver phase of each."""

    record: StepRecord
    phases: list[Phase]
    model: MotionModel
    t_departure: float
    t_arrival: float
    t_end: float
    s_start: float
    s_stop: float
    s_coast: float
    events: list[tuple[float, str]] = field(default_factory=list)

    def evaluate(self, t) -> dict[str, np.ndarray]:
        """Truth at the times t (s since the recording start): s, v, a, u, regime, phase index."""
        t = np.asarray(t, dtype=float)
        s, v, idx = self.record.evaluate(t)
        seg = self.record.arrays()["seg"][idx]
        a = np.empty(t.shape)
        u = np.empty(t.shape)
        regime = np.empty(t.shape, dtype=np.uint8)
        phases = self.phases
        flat_t, flat_s, flat_v, flat_seg = t.ravel(), s.ravel(), v.ravel(), seg.ravel()
        fa, fu, fr = a.reshape(-1), u.reshape(-1), regime.reshape(-1)
        for i in range(flat_t.size):
            ph = phases[flat_seg[i]]
            ti, si, vi = float(flat_t[i]), float(flat_s[i]), float(flat_v[i])
            fu[i] = ph.effort(ti, si, vi)
            fa[i] = ph.accel(ti, si, vi)
            fr[i] = ph.regime
        return {"s": s, "v": v, "a": a, "u": u, "regime": regime, "phase": seg}


class Drive:
    """One run from a standstill at s_start to a standstill at s_stop."""

    def __init__(
        self,
        model: MotionModel,
        ceiling: SpeedCeiling,
        driver: DriverParams,
        s_start: float,
        s_stop: float,
        *,
        pre_roll_s: float = 0.0,
        post_roll_s: float = 0.0,
        rtol: float = _RTOL,
    ) -> None:
        driver.validate()
        self.model, self.driver = model, driver
        self.s0, self.s1 = float(s_start), float(s_stop)
        self.pre_roll, self.post_roll, self.rtol = float(pre_roll_s), float(post_roll_s), rtol
        theta = driver.theta_cruise
        self.cb = ceiling.breaks
        self.cv = [theta * v for v in ceiling.values]
        self.rises = ceiling.rises()
        self.targets = [Target(d.s_m, theta * d.v_low, "limit") for d in ceiling.drops()]
        self.targets.append(Target(self.s1, 0.0, "stop"))
        self.steps = BrakeSteps(driver.brake_steps_ms(), driver.b_limit)
        self.knots = [k for k in model.terms.bends if self.s0 - 1.0 < k < self.s1 + 1.0]
        self.band = driver.cycle_band_kmh * KMH
        self.min_coast = driver.min_coast_speed_kmh * KMH
        self.final = False
        self.creep = False
        self.s_coast = (
            plan_coast_point(self, driver.coast_before_brake_s) if driver.coast_before_brake_s > 0 else math.inf
        )
        self.record = StepRecord()
        self.phases: list[Phase] = []
        self.log: list[tuple[float, str]] = []

    # -- lookups -----------------------------------------------------------------------------
    def c_at(self, s: float) -> float:
        return self.cv[max(bisect_right(self.cb, s) - 1, 0)]

    def brake_margin(self, j: int, s: float, v: float) -> float:
        """>= 0 once braking for target j must start."""
        tg = self.targets[j]
        if tg.kind == "stop":
            return s + v * v / (2.0 * self.driver.b_stop) - tg.s_m
        return s + self.steps.distance(v, tg.v_low) - tg.s_m - 1e-6

    def ahead(self, s: float) -> list[int]:
        """Targets still ahead (with the same 1 um tolerance as the ceiling breaks)."""
        return [j for j, tg in enumerate(self.targets) if tg.s_m > s + 1e-6]

    def rise_ahead(self, s: float) -> bool:
        return any(s + 1e-9 < r < self.s1 for r in self.rises)

    # -- phase changes -----------------------------------------------------------------------
    def at_target(self) -> Phase:
        m = self.model
        if self.final and not self.creep:
            return Coast(m, final=True)
        if self.driver.cruise_style == "hold" or self.creep or self.final:
            return Hold(m)
        return Coast(m, final=False)

    def reaccel(self, t: float, u0: float, fraction: float) -> Phase:
        if self.driver.reaccel_ramp_s > 0.0:
            return Ramp(self.model, t, self.driver.reaccel_ramp_s, u0, fraction)
        return Traction(self.model, fraction)

    def band_floor(self, c: float) -> float:
        """Where a cycle's coast below the ceiling `c` ends (m/s): the band below it, at most half of `c`. A band
        wider than the ceiling (6-15 km/h under a 10 km/h crawl to a signal) would coast the train to a stand
        and backwards."""
        return c - min(self.band, MAX_BAND_SHARE * c)

    def cycle_fraction(self, t: float, s: float, v: float) -> float:
        """Fraction of the envelope for a cycle's re-acceleration: the driver's, raised (up to the full envelope)
        so that the net acceleration where it starts is at least ``cycle_min_accel``."""
        m = self.model
        env = m.envelope(v)
        need = (m.opposing(t, s, v) + self.driver.cycle_min_accel) / env if env > 0.0 else 1.0
        return max(self.driver.cycle_traction_fraction, min(1.0, need))

    def brake_for(self, j: int, s: float, v: float) -> Phase:
        tg = self.targets[j]
        if tg.kind == "stop":
            return StopBrake(self.model, tg.s_m, self.driver.b_stop, s, v)
        return Brake(self.model, self.steps, j, tg.v_low)

    def after_brake(self, s: float) -> Phase:
        if not self.final and s >= self.s_coast - 1e-9:
            self.final = True
        if self.final:
            return Coast(self.model, final=True) if self.rise_ahead(s) else Hold(self.model)
        return self.at_target()

    def immediate(self, ph: Phase, t: float, s: float, v: float) -> Phase | None:
        """A phase switch due at once at (t, s, v), or None."""
        m = self.model
        if isinstance(ph, Brake):
            return self.after_brake(s) if v <= ph.v_low + 1e-9 else None
        if isinstance(ph, (StopBrake, Stand)):
            return None
        best, arg = -math.inf, -1
        for j in self.ahead(s):
            e = self.brake_margin(j, s, v)
            if e >= 0.0 and e > best:
                best, arg = e, j
        if arg >= 0:
            return self.brake_for(arg, s, v)
        if not self.final and s >= self.s_coast:
            self.final = True
            return Coast(m, final=True)
        # the ceiling here or 1 m ahead, whichever is lower: a brake that ends a hair before its
        # limit board must not look like a rise
        c = min(self.c_at(s + 1e-6), self.c_at(s + 1.0))
        if isinstance(ph, (Ramp, Traction)):
            if v >= c - 1e-9 and m.opposing(t, s, v) <= m.envelope(v):
                return self.at_target()
        elif isinstance(ph, Hold):
            if m.opposing(t, s, v) > m.envelope(v):
                return Traction(m, 1.0)
            if c > v + 1e-6:
                return self.reaccel(t, ph.effort(t, s, v), self.driver.traction_fraction)
        elif isinstance(ph, Coast):
            if v > c + 1e-9:
                return Hold(m)
            if not ph.final and v <= self.band_floor(c):
                return self.reaccel(t, 0.0, self.cycle_fraction(t, s, v))
            if ph.final and v < self.min_coast:
                self.creep = True
                return self.reaccel(t, 0.0, self.driver.traction_fraction)
        return None

    def events(self, ph: Phase, s: float) -> list[Event]:
        m = self.model
        ev: list[Event] = []
        if isinstance(ph, StopBrake):
            return [Event(lambda _t, _s, v: _V_STOPPED - v, "stopped")]
        if isinstance(ph, Brake):
            ev.append(Event(lambda _t, _s, v, lo=ph.v_low: lo - v, "reached"))
            for j in self.ahead(s):
                if j != ph.target:
                    ev.append(Event(lambda _t, s_, v, j=j: self.brake_margin(j, s_, v), ("brake", j)))
            for bound in self.steps.bounds:
                ev.append(Event(lambda _t, _s, v, b=bound: b - v, None, terminal=False))
            return ev
        for j in self.ahead(s):
            ev.append(Event(lambda _t, s_, v, j=j: self.brake_margin(j, s_, v), ("brake", j)))
        if not self.final and math.isfinite(self.s_coast) and s < self.s_coast:
            ev.append(Event(lambda _t, s_, _v: s_ - self.s_coast, "coast_point"))
        # the ceiling is constant within one integration: every break ends it (a terminal ya-stop)
        c = self.c_at(s + 1e-6)
        if isinstance(ph, (Ramp, Traction)):
            ev.append(Event(lambda _t, _s, v: v - c, "target"))
            ev.append(Event(lambda _t, _s, v: 0.01 - v, "stall"))
            ev.append(Event(lambda _t, _s, v: v - m.transition_speed, None, terminal=False))
            if isinstance(ph, Ramp):
                end = ph.t0 + ph.ramp_s
                ev.append(Event(lambda t, _s, _v: t - end, "ramp_end"))
        elif isinstance(ph, Hold):
            ev.append(Event(lambda t, s_, v: m.opposing(t, s_, v) - m.envelope(v), "cant_hold"))
        elif isinstance(ph, Coast):
            # armed just above the target: a coast that starts at the target speed downhill must trip it
            ev.append(Event(lambda _t, _s, v: v - c - 1e-7, "overspeed"))
            if ph.final:
                if self.min_coast > 0:
                    ev.append(Event(lambda _t, _s, v: self.min_coast - v, "min_speed"))
            else:
                floor = self.band_floor(c)
                ev.append(Event(lambda _t, _s, v: floor - v, "band_low"))
        return ev

    def transition(self, ph: Phase, tag, t: float, s: float, v: float) -> Phase:
        m = self.model
        if isinstance(tag, tuple) and tag[0] == "brake":
            return self.brake_for(tag[1], s, v)
        if tag == "reached":
            return self.after_brake(s)
        if tag == "ramp_end":
            return Traction(m, ph.fraction)  # type: ignore[attr-defined]
        if tag == "target":
            return self.at_target() if m.opposing(t, s, v) <= m.envelope(v) else ph
        if tag == "coast_point":
            self.final = True
            return Coast(m, final=True)
        if tag == "cant_hold":
            return Traction(m, 1.0)
        if tag == "overspeed":
            return Hold(m)
        if tag == "band_low":
            return self.reaccel(t, 0.0, self.cycle_fraction(t, s, v))
        if tag == "min_speed":
            self.creep = True
            return self.reaccel(t, 0.0, self.driver.traction_fraction)
        if tag == "stall":
            raise RuntimeError(f"the train stalls at s={s:.0f} m (traction below resistance + gradient)")
        return ph  # a ceiling break ("ya_stop"): immediate() decides

    # -- the run -----------------------------------------------------------------------------
    def _push(self, ph: Phase) -> int:
        self.phases.append(ph)
        return len(self.phases) - 1

    def run(self) -> DriveResult:
        m, d = self.model, self.driver
        s, v = self.s0, 0.0
        t = self.pre_roll
        if t > 0:
            self.record.add_poly(0.0, t, s, 0.0, (0.0,) * 4, (0.0,) * 4, self._push(Stand(m)))
        t_dep = t
        self.log.append((t, "departure"))
        resist0 = m.opposing(t, s, 0.0)
        pull0 = d.traction_fraction * m.envelope(0.0)
        if pull0 <= resist0:
            raise RuntimeError(f"the train cannot start at s={s:.0f} m: traction {pull0:.3g} <= {resist0:.3g} N/kg")
        if d.start_ramp_s > 0:
            t_move = t + d.start_ramp_s * max(resist0, 0.0) / pull0
            if t_move > t:
                seg = self._push(Ramp(m, t, d.start_ramp_s, 0.0, d.traction_fraction, standing=True))
                self.record.add_poly(t, t_move, s, 0.0, (0.0,) * 4, (0.0,) * 4, seg)
            ph: Phase = Ramp(m, t_dep, d.start_ramp_s, 0.0, d.traction_fraction)
            t = t_move
        else:
            ph = Traction(m, d.traction_fraction)
        h = 1.0
        for _ in range(20000):
            for _settle in range(20):
                nxt = self.immediate(ph, t, s, v)
                if nxt is None:
                    break
                ph = nxt
            seg = self._push(ph)
            # steps end on the ceiling breaks (terminal: the driver decides there) and, where the motion
            # depends on them, on the knots of g(s) and the tunnel fraction
            breaks = [b for b in self.cb if b > s + 1e-6]
            stops = sorted(set(breaks).union(k for k in self.knots if k > s)) if ph.ode else breaks
            out = integrate(
                ph.rhs(),
                t,
                s,
                v,
                t + 4 * 3600.0,
                h=h,
                rtol=self.rtol,
                atol_a=1e-6,
                atol_b=1e-9,
                max_step=_MAX_STEP,
                events=self.events(ph, s),
                ya_stops=stops,
                ya_terminal=set(breaks),
                record=self.record,
                seg=seg,
            )
            if out.tag is None:
                raise RuntimeError(f"the run did not reach the stop within 4 h (at s={out.ya:.0f} m)")
            t, s, v, h = out.x, out.ya, out.yb, out.h
            self.log.append((t, f"{ph.name}:{out.tag}"))
            if v < -1e-6:
                raise RuntimeError(f"driver model error: negative speed {v:.3g} m/s at s={s:.0f} m in {ph.name}")
            if out.tag == "stopped":
                break
            ph = self.transition(ph, out.tag, t, s, v)
        else:
            raise RuntimeError("the driver model did not terminate")
        # finish the stop in closed form (constant deceleration over the last millimetres)
        dist = max(self.s1 - s, 0.0)
        if v > 0.0 and dist > 0.0:
            b = v * v / (2.0 * dist)
            dt = 2.0 * dist / v
            self.record.add_poly(
                t, t + dt, s, v, (v * dt, -0.5 * b * dt * dt, 0.0, 0.0), (-b * dt, 0.0, 0.0, 0.0), len(self.phases) - 1
            )
            t += dt
            s = self.s1
        t_arr = t
        self.log.append((t, "arrival"))
        t_end = t + self.post_roll
        self.record.add_poly(t, max(t_end, t + 1e-9), s, 0.0, (0.0,) * 4, (0.0,) * 4, self._push(Stand(m)))
        return DriveResult(self.record, self.phases, m, t_dep, t_arr, t_end, self.s0, self.s1, self.s_coast, self.log)


def plan_coast_point(drive: Drive, coast_s: float) -> float:
    """Where to start coasting so that the coast lasts ``coast_s`` until the final braking curve.

    The coast is searched on the last stretch before the stop where the ceiling no longer rises:
    a coast trajectory is integrated backwards in time from a meeting point on the braking curve
    (speed v_m) until it reaches the cruise target; brentq solves duration(v_m) = coast_s. Where
    the stretch is too short the coast starts at its beginning (a shorter coast than planned).
    The plan ignores the wind (the driver does not know it); the realised coast length is in the
    run's summary.
    """
    m = drive.model
    rises = [r for r in drive.rises if r < drive.s1]
    s_rise = max(rises) if rises else drive.s0
    approach = [j for j, tg in enumerate(drive.targets) if tg.s_m > s_rise]
    c_plat = drive.c_at(s_rise + 1e-6)

    def meet(vm: float) -> float:
        best = math.inf
        for j in approach:
            tg = drive.targets[j]
            if tg.v_low >= vm:
                continue
            if tg.kind == "stop":
                dist = vm * vm / (2.0 * drive.driver.b_stop)
            else:
                dist = drive.steps.distance(vm, tg.v_low)
            best = min(best, tg.s_m - dist)
        return best

    opposing = m.opposing_calm

    def back(t, s, v):  # time reversed coasting
        return -v, opposing(0.0, s, v)

    c_at = drive.c_at
    t_cap = coast_s + 120.0

    def coast_from(vm: float) -> tuple[float, float]:
        sm = meet(vm)
        events = [
            Event(lambda _t, s, v: v - c_at(s) * (1.0 - 1e-9), "cruise"),
            Event(lambda _t, s, _v: s_rise - s, "rise"),
        ]
        out = integrate(
            back, 0.0, sm, vm, t_cap, h=20.0, rtol=1e-5, atol_a=1e-2, atol_b=1e-5, max_step=120.0, events=events
        )
        return out.x, out.ya

    v_hi = c_plat * 0.999
    low_targets = [drive.targets[j].v_low for j in approach]
    v_lo = max(0.25 * c_plat, max(low_targets) + 0.5 if low_targets else 0.0)
    if v_lo >= v_hi:
        return s_rise
    dur_lo, s_lo = coast_from(v_lo)
    if dur_lo <= coast_s:
        return s_lo
    vm = brentq(lambda x: coast_from(x)[0] - coast_s, v_lo, v_hi, xtol=5e-3)
    return coast_from(vm)[1]
