"""The fast running-time model of Besinovic et al. (2013), for simulation-based calibration.

The minimum-time driving strategy of the paper (Section "Microscopic speed profile model"):
accelerate with the full tractive envelope (c0 + c1 v up to the transition speed, c2 / v above,
adhesion cap) to the cruise speed theta * limit, cruise, brake with the constant deceleration
b_limit to every lower limit and with b_stop to the stop; no coasting. The limit over the train
applies (a higher limit only once the tail has cleared). Integration is over distance,

    dv/ds = (f_t(v) - r(v) - g(s)) / v,    dt/ds = 1 / v        (paper eq. 6-7)

with Dormand-Prince RK45 (:mod:`.integrate`), steps ending exactly on every knot of g(s) and of
the ceiling, and an event where the speed meets the ceiling or a braking curve. Cruising and
braking at constant deceleration are exact closed forms; only acceleration is integrated. The
first metres from standstill (v = 0 makes dv/ds singular) are integrated over time.

The realistic driver simulator (:mod:`.simulator`) runs the same physics (:class:`~.model.MotionModel`)
through the same integrator over time; with ``DriverParams.minimum_time(...)`` it reproduces this
model, which a test checks to 0.1 s.
"""

from __future__ import annotations

import math
import weakref
from bisect import bisect_left, bisect_right
from dataclasses import dataclass

import numpy as np

from ..errors import ConfigError
from ..params import ParamSet, param
from ..physics import KMH
from ..track import Track
from ..train import TrainSpec
from .integrate import Event, integrate
from .limits import SpeedCeiling
from .model import MotionModel, TrackTerms

HERMITE, UNIFORM = 0, 1
_V_SWITCH = 3.0  # m/s: from the time to the distance formulation


@dataclass(frozen=True)
class RunningTimeParams(ParamSet):
    """Parameters of the running-time model (Besinovic et al. 2013, Table 1), per unit effective mass."""

    c0: float = param(0.562, "tractive effort limit at low speed", unit="N/kg", low=0.0, low_open=True)
    c1: float = param(0.0, "linear term of the effort limit (the paper fixes 0)", unit="N/(kg m/s)", low=-1.0, high=1.0)
    c2: float = param(6.21, "tractive power limit", unit="W/kg", low=0.0, low_open=True)
    r0: float = param(1.53e-2, "Davis constant term", unit="N/kg", low=0.0)
    r1: float = param(1.939e-4, "Davis linear term", unit="N/(kg m/s)", low=0.0)
    r2: float = param(4.08e-5, "Davis quadratic term", unit="N/(kg (m/s)^2)", low=0.0)
    b_limit: float = param(0.66, "deceleration braking to a lower limit", unit="m/s^2", low=0.0, low_open=True)
    b_stop: float = param(0.66, "deceleration braking to the stop", unit="m/s^2", low=0.0, low_open=True)
    theta_cruise: float = param(1.0, "cruise speed as a fraction of the limit", low=0.3, high=1.2)
    length_m: float = param(162.0, "train length", unit="m", low=0.0, low_open=True)
    tunnel_factor: float = param(0.0, "r2 -> (1 + f) r2 inside tunnels", low=0.0)
    adhesive_mass_fraction: float = param(
        0.0, "share of the mass on driven axles; 0 = no adhesion cap", low=0.0, high=1.0
    )
    rotating_mass_factor: float = param(1.06, "gamma (for the adhesion cap)", low=1.0, high=2.0)
    max_speed_kmh: float = param(0.0, "train maximum speed; 0 = only the track limits", unit="km/h", low=0.0)

    @classmethod
    def from_train(cls, train: TrainSpec, **changes) -> RunningTimeParams:
        """The train file's values (manufacturer Davis, b_limit = b_stop = max_brake_decel), then changes."""
        base = cls(
            c0=train.max_tractive_effort,
            c2=train.max_tractive_power,
            r0=train.davis.r0,
            r1=train.davis.r1,
            r2=train.davis.r2,
            b_limit=train.max_brake_decel,
            b_stop=train.max_brake_decel,
            length_m=train.length_m,
            tunnel_factor=train.tunnel_factor,
            adhesive_mass_fraction=train.adhesive_mass_fraction,
            rotating_mass_factor=train.rotating_mass_factor,
            max_speed_kmh=train.max_speed_kmh,
        )
        return base.replace(**changes) if changes else base


class Profile:
    """A speed profile v(s) and the head's passage times t(s) between two stops.

    Knots ``s, t, v`` (m, s, m/s); between knots i and i+1 ``kind[i]`` is HERMITE (an integrated
    acceleration step: cubic Hermite in t(s) with dt/ds = 1/v at both ends, 4th order) or UNIFORM
    (constant acceleration: cruising, braking, the first metres; exact).
    """

    def __init__(self, s, t, v, kind, length_m: float) -> None:
        self.s = np.asarray(s, dtype=float)
        self.t = np.asarray(t, dtype=float)
        self.v = np.asarray(v, dtype=float)
        self.kind = np.asarray(kind, dtype=np.int8)
        self.length_m = float(length_m)

    @property
    def start_s(self) -> float:
        return float(self.s[0])

    @property
    def stop_s(self) -> float:
        return float(self.s[-1])

    @property
    def run_time(self) -> float:
        """Time from departure to the stop, s."""
        return float(self.t[-1])

    def _locate(self, s_m):
        s = np.asarray(s_m, dtype=float)
        idx = np.clip(np.searchsorted(self.s, s, side="right") - 1, 0, self.s.size - 2)
        s0, s1 = self.s[idx], self.s[idx + 1]
        ds = np.clip(s, s0, s1) - s0
        return s, idx, ds, s1 - s0

    def time_at(self, s_m) -> np.ndarray:
        """Time (s after departure) at which the head passes s; NaN outside [start_s, stop_s]."""
        s, idx, ds, h = self._locate(s_m)
        t0, t1, v0, v1 = self.t[idx], self.t[idx + 1], self.v[idx], self.v[idx + 1]
        with np.errstate(divide="ignore", invalid="ignore"):
            th = ds / h
            h00 = (1 + 2 * th) * (1 - th) ** 2
            h10 = th * (1 - th) ** 2
            h01 = th * th * (3 - 2 * th)
            h11 = th * th * (th - 1)
            herm = h00 * t0 + h10 * h / v0 + h01 * t1 + h11 * h / v1
            a = (v1 * v1 - v0 * v0) / (2 * h)
            uni = t0 + 2 * ds / (v0 + np.sqrt(np.maximum(v0 * v0 + 2 * a * ds, 0.0)))
        out = np.where(self.kind[idx] == HERMITE, herm, uni)
        out = np.where(ds == 0, t0, out)
        return np.where((s >= self.s[0]) & (s <= self.s[-1]), out, np.nan)

    def speed_at(self, s_m) -> np.ndarray:
        """Speed (m/s) of the head at s (v^2 interpolated linearly between knots); NaN outside the run."""
        s, idx, ds, h = self._locate(s_m)
        v0, v1 = self.v[idx], self.v[idx + 1]
        with np.errstate(divide="ignore", invalid="ignore"):
            th = np.where(h > 0, ds / h, 0.0)
        # v^2 linear in s: exact at constant acceleration, second order within integrated steps
        out = np.sqrt(np.maximum(v0 * v0 + (v1 * v1 - v0 * v0) * th, 0.0))
        return np.where((s >= self.s[0]) & (s <= self.s[-1]), out, np.nan)

    def tail_time_at(self, s_m) -> np.ndarray:
        """Time at which the tail passes s (the head is at s + L); NaN if it never does."""
        return self.time_at(np.asarray(s_m, dtype=float) + self.length_m)

    def occupation_release(self, start_m, end_m) -> tuple[np.ndarray, np.ndarray]:
        """Occupation (head enters start_m) and release (tail clears end_m) times of sections, s."""
        return self.time_at(start_m), self.tail_time_at(end_m)


class _Prepared:
    """Per (track, length, start, stop): knots, ceiling and drops (independent of the parameters)."""

    def __init__(self, track: Track, length_m: float, start_s: float, stop_s: float, v_max: float) -> None:
        self.terms = TrackTerms(track, length_m)
        self.ceiling = SpeedCeiling(track, length_m, start_s, stop_s, v_max)
        self.drops = self.ceiling.drops()
        stops = set(self.terms.bends_between(start_s, stop_s))
        stops.update(b for b in self.ceiling.breaks if start_s < b < stop_s)
        self.x_stops = sorted(stops)
        self.g_bends = [k for k in self.terms.bends if start_s - 1.0 < k < stop_s + 1.0]


_CACHE: dict[tuple, tuple[weakref.ref, _Prepared]] = {}


def _prepared(track: Track, length_m: float, start_s: float, stop_s: float, v_max: float) -> _Prepared:
    key = (id(track), length_m, start_s, stop_s, v_max)
    hit = _CACHE.get(key)
    if hit is not None and hit[0]() is track:
        return hit[1]
    prep = _Prepared(track, length_m, start_s, stop_s, v_max)
    if len(_CACHE) > 64:
        _CACHE.clear()
    _CACHE[key] = (weakref.ref(track), prep)
    return prep


def running_time_profile(
    track: Track, params: RunningTimeParams, start_s: float, stop_s: float, *, rtol: float = 1e-7
) -> Profile:
    """Minimum-time profile (Besinovic's driver) from a standstill at start_s to a stop at stop_s."""
    if not stop_s > start_s:
        raise ConfigError(track.name, "stop_s", f"must be beyond start_s ({start_s:g} m), found {stop_s:g} m")
    v_max = params.max_speed_kmh * KMH if params.max_speed_kmh > 0 else math.inf
    prep = _prepared(track, params.length_m, float(start_s), float(stop_s), v_max)
    model = MotionModel(
        prep.terms,
        c0=params.c0,
        c1=params.c1,
        c2=params.c2,
        adhesive_mass_fraction=params.adhesive_mass_fraction,
        rotating_mass_factor=params.rotating_mass_factor,
        r0=params.r0,
        r1=params.r1,
        r2=params.r2,
        tunnel_factor=params.tunnel_factor,
    )
    return _Run(model, prep, params, float(start_s), float(stop_s), rtol).profile()


class _Run:
    def __init__(self, model: MotionModel, prep: _Prepared, p: RunningTimeParams, start: float, stop: float, rtol):
        self.model, self.prep, self.p = model, prep, p
        self.start, self.stop, self.rtol = start, stop, rtol
        theta = p.theta_cruise
        self.cb = prep.ceiling.breaks
        self.cv = [theta * v for v in prep.ceiling.values]
        # braking targets (p, v_low^2, b): limit drops and the stop
        self.targets = [(d.s_m, (theta * d.v_low) ** 2, p.b_limit) for d in prep.drops]
        self.targets.append((stop, 0.0, p.b_stop))
        self.S: list[float] = []
        self.T: list[float] = []
        self.V: list[float] = []
        self.K: list[int] = []

    # -- the ceiling and the braking envelope ------------------------------------------------
    def c_at(self, s: float) -> float:
        return self.cv[max(bisect_right(self.cb, s) - 1, 0)]

    def brake2(self, s: float) -> tuple[float, int]:
        """Lowest braking curve v^2 at s over the targets ahead, and its index (-1: none).

        Where two curves meet (the end of a braking piece) the steeper one is the lower just ahead:
        it is taken, or the train would follow the other past its target at too high a speed.
        """
        best, arg, best_b = math.inf, -1, 0.0
        for j, (p, vl2, b) in enumerate(self.targets):
            if p > s:
                w = vl2 + 2.0 * b * (p - s)
                tie = abs(w - best) <= 1e-9 * (1.0 + best)
                if (w < best and not tie) or (tie and b > best_b):
                    best, arg, best_b = min(w, best), j, b
        return best, arg

    def push(self, s: float, t: float, v: float, kind: int) -> None:
        if s > self.S[-1]:
            self.S.append(s)
            self.T.append(t)
            self.V.append(v)
            self.K.append(kind)
        else:  # zero-length piece: keep the latest state
            self.T[-1], self.V[-1] = t, v

    # -- phases ------------------------------------------------------------------------------
    def profile(self) -> Profile:
        self.S, self.T, self.V = [self.start], [0.0], [0.0]
        s, t, v = self._start()
        guard = 0
        while True:
            guard += 1
            if guard > 100000:
                raise RuntimeError("running-time model did not terminate")
            if s >= self.stop - 1e-9:
                raise RuntimeError(f"running-time model reached the stop at {v:.3g} m/s")
            c = self.c_at(s)
            b2, j = self.brake2(s)
            if v * v < min(c * c, b2) * (1.0 - 1e-9):
                s, t, v = self._accelerate(s, t, v)
            elif b2 <= c * c * (1.0 + 1e-9):
                s, t, v, done = self._brake(s, t, v, j)
                if done:
                    break
            else:
                s, t, v = self._cruise(s, t, v)
        return Profile(self.S, self.T, self.V, self.K, self.p.length_m)

    def _start(self) -> tuple[float, float, float]:
        """From standstill over time until v = _V_SWITCH (or the ceiling)."""
        model = self.model
        env, opp = model.envelope, model.opposing_calm
        a0 = env(0.0) - opp(0.0, self.start, 0.0)
        if a0 <= 0.0:
            raise ConfigError(
                self.p.__class__.__name__,
                "c0",
                f"the train cannot start at s={self.start:g} m: "
                f"effort {env(0.0):.4g} N/kg <= resistance + gradient {env(0.0) - a0:.4g} N/kg",
            )

        def f(_t, s, v):
            return v, env(v) - opp(0.0, s, v)

        cap = self._cap_fn()
        events = [
            Event(lambda _t, _s, v: v - _V_SWITCH, "switch"),
            Event(lambda _t, s, v: cap(s, v), "cap"),
        ]
        trace: list = []
        out = integrate(
            f,
            0.0,
            self.start,
            0.0,
            1e5,
            h=0.5,
            rtol=self.rtol,
            atol_a=1e-7,
            atol_b=1e-9,
            max_step=2.0,
            events=events,
            ya_stops=self.prep.x_stops,
            trace=trace,
        )
        for t, s, v in trace:
            self.push(s, t, v, UNIFORM)
        return out.ya, out.x, out.yb

    def _cap_fn(self):
        cb, cv, targets = self.cb, self.cv, self.targets

        def cap(s: float, v: float) -> float:
            # the cap just before s: a step that ends exactly on a rise of the ceiling must still see
            # the old ceiling there, or a crossing inside that step goes unnoticed
            c = cv[max(bisect_left(cb, s) - 1, 0)]
            best = c * c
            for p, vl2, b in targets:
                if p >= s:
                    w = vl2 + 2.0 * b * (p - s)
                    if w < best:
                        best = w
            return v * v - best

        return cap

    def _accelerate(self, s: float, t: float, v: float) -> tuple[float, float, float]:
        """Full effort over distance; the state is (t, w = v^2 / 2): dw/ds = a is smooth, also at low v."""
        model = self.model
        env, opp = model.envelope, model.opposing_calm
        sqrt = math.sqrt

        def f(s_, _t, w):
            # a trial stage may overshoot below w = 0 (near a stall): a huge dt/ds makes the step fail
            v_ = sqrt(2.0 * w) if w > 1e-12 else 1e-6
            return 1.0 / v_, env(v_) - opp(0.0, s_, v_)

        cap = self._cap_fn()
        w_tr = 0.5 * model.transition_speed**2
        events = [
            Event(lambda s_, _t, w: cap(s_, sqrt(2.0 * max(w, 0.0))), "cap"),
            Event(lambda _s, _t, w: 0.02 - w, "stall"),
            Event(lambda _s, _t, w: w - w_tr, None, terminal=False),
        ]
        trace: list = []
        out = integrate(
            f,
            s,
            t,
            0.5 * v * v,
            self.stop,
            h=50.0,
            rtol=self.rtol,
            atol_a=1e-6,
            atol_b=1e-6,
            max_step=2000.0,
            events=events,
            x_stops=self.prep.x_stops,
            trace=trace,
        )
        for s_, t_, w_ in trace:
            self.push(s_, t_, sqrt(2.0 * w_), HERMITE)
        if out.tag == "stall":
            raise ConfigError(
                self.p.__class__.__name__,
                "c2",
                f"the train stalls at s={out.x:.0f} m (effort below resistance + gradient)",
            )
        return out.x, out.ya, sqrt(2.0 * out.yb)

    def _cruise(self, s: float, t: float, v: float) -> tuple[float, float, float]:
        end = self.stop
        # next ceiling change
        for b in self.cb:
            if b > s + 1e-9:
                end = min(end, b)
                break
        # braking point of the targets below v
        v2 = v * v
        for p, vl2, b in self.targets:
            if p > s and vl2 < v2:
                end = min(end, max(s, p - (v2 - vl2) / (2.0 * b)))
        end = self._hold_limit(s, end, v)
        t_end = t + (end - s) / v
        self.push(end, t_end, v, UNIFORM)
        if end <= s:  # cannot hold here: accelerate (decelerate) with full effort from this point
            return self._accelerate(s, t, v)
        return end, t_end, v

    def _hold_limit(self, s: float, end: float, v: float) -> float:
        """First position in [s, end] where the envelope no longer holds v (else end)."""
        model, terms = self.model, self.model.terms
        fmax = model.envelope(v)
        r_open = model.r0 + model.r1 * v
        r2v2 = model.r2 * v * v

        def margin(x):
            return fmax - r_open - r2v2 * (1.0 + model.tunnel_factor * terms.tunnel_at(x)) - terms.g_at(x)

        m_prev, x_prev = margin(s), s
        if m_prev < 0.0:
            return s
        for x in [*(k for k in self.prep.g_bends if s < k < end), end]:
            m = margin(x)
            if m < 0.0:
                return x_prev + (x - x_prev) * m_prev / (m_prev - m)
            m_prev, x_prev = m, x
        return end

    def _brake(self, s: float, t: float, v: float, j: int) -> tuple[float, float, float, bool]:
        p, vl2, b = self.targets[j]
        end = p
        base_j = vl2 + 2.0 * b * p
        for k, (pk, wl2, bk) in enumerate(self.targets):
            if k == j or pk <= s:
                continue
            # curve_k^2 - curve_j^2 = A - 2 (bk - b) x; k becomes lower where that turns negative
            a_k = wl2 + 2.0 * bk * pk - base_j
            slope = -2.0 * (bk - b)
            if slope < 0.0:
                x = a_k / (2.0 * (bk - b))
                if s < x < min(end, pk):
                    end = x
        v_end = math.sqrt(max(vl2 + 2.0 * b * (p - end), 0.0)) if end < p else math.sqrt(vl2)
        t_end = t + (v - v_end) / b
        self.push(end, t_end, v_end, UNIFORM)
        done = end >= self.stop - 1e-9 and j == len(self.targets) - 1
        return end, t_end, v_end, done
