"""Besinovic's minimum-time running-time model for a whole population of parameter vectors at once.

The same model as :func:`~.running_time.running_time_profile` (full tractive envelope to theta x
limit, cruise, b_limit to every lower limit, b_stop to the stop, no coasting), computed for n
parameter vectors in one call with numpy, for population-based optimisers
(``scipy.optimize.differential_evolution(..., vectorized=True)``): one call per generation.

Formulation (exact, not a grid approximation). In w = v^2/2 over distance the profile is

    w(s) = min( cap(s), E_1(s), E_2(s), ... )

- cap(s) = min(ceiling, braking curves): the ceiling (theta x limit over the train)^2 / 2 is
  piecewise constant, each braking curve w_j + b_j (p_j - s) a straight line; so cap is piecewise
  linear and its time integral is closed-form (uniform acceleration on every piece).
- E_k are maximum-effort trajectories dw/ds = envelope(v) - r(v) - g(s), each started where the
  train leaves the cap: at the departure (w = 0), at every rise of the ceiling (at the old ceiling)
  and where the envelope can no longer hold the ceiling speed on a gradient ("hold-fail" points,
  found in closed form: the holding margin is piecewise linear in s). Every E_k is an upper bound
  of the true profile after its start (same ODE, comparison theorem) and the true profile is on one
  of them wherever it is below the cap, hence the minimum. E_k is only needed until it first
  crosses the cap; two E never cross each other, so an E that starts inside another's range is
  dominated and dropped.

All E_k of all parameter vectors ("lanes") are integrated together, one numpy operation per stage
for all lanes, with Dormand-Prince 5(4) and a step size per lane (Hairer's controller, as
:mod:`.integrate`), error control on both u and t. The independent variable is sigma = sqrt(s - x_o)
and the state (u, t) with u = sqrt(w) = v / sqrt(2): from a standstill (x_o = the departure) both
du/dsigma = sigma a / u and dt/dsigma = sqrt(2) sigma / u are regular (u ~ sqrt(a0) sigma), so no
time-domain phase is needed; a lane that starts moving has its origin 50 m behind its start. Steps
end exactly on every bend of g(s) and tunnel(s) and on the ceiling rises; each lane is on one smooth
branch of the envelope and a step that crosses the transition speed is cut there on its dense output
(as the scalar model does), so no step straddles a kink. The crossing with the cap is located on
the dense output afterwards; passage times inside a step come from the dense output of t (4th
order), not from an interpolant.

Cost: one call for 48 parameter vectors on the 14.3 km corridor takes about 10 ms (25-40 lockstep
steps), against 48 x 1-1.7 ms for the scalar model. Agreement with the scalar model at its own
knots (rtol 1e-10), test/sim/test_sim_running_time_batch.py: <= 8e-5 s on the bundled tracks (1-3e-5
s typical), 4e-4 s with the adhesion cap (whose kinks neither model cuts steps at).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from ..errors import ConfigError
from ..physics import KMH
from ..track import Track
from .integrate import DENSE_P
from .running_time import RunningTimeParams, _prepared

BATCH_FIELDS: tuple[str, ...] = ("c0", "c1", "c2", "r0", "r1", "r2", "b_limit", "b_stop", "theta_cruise")
"""Parameters that may differ between the members of a batch (the others are shared)."""

_SQRT2 = math.sqrt(2.0)
_ORIGIN_M = 50.0  # m: sigma origin behind the start of a lane that starts moving
_STALL_W = 0.02  # m^2/s^2: w below this while decelerating is a stall (v < 0.2 m/s), as the scalar model
_ATOL = 1e-6
_MAX_ITER = 20000
_FAIL_START, _FAIL_STALL, _FAIL_STEP = 1, 2, 3
_ONES = np.ones(4096)  # read-only
_ONES.flags.writeable = False

# Dormand-Prince 5(4) tableau (the same as .integrate)
_C = (0.0, 1 / 5, 3 / 10, 4 / 5, 8 / 9, 1.0, 1.0)
_A = (
    (),
    (1 / 5,),
    (3 / 40, 9 / 40),
    (44 / 45, -56 / 15, 32 / 9),
    (19372 / 6561, -25360 / 2187, 64448 / 6561, -212 / 729),
    (9017 / 3168, -355 / 33, 46732 / 5247, 49 / 176, -5103 / 18656),
    (35 / 384, 0.0, 500 / 1113, 125 / 192, -2187 / 6784, 11 / 84),
)
_E = np.array([-71 / 57600, 0.0, 71 / 16695, -71 / 1920, 17253 / 339200, -22 / 525, 1 / 40])
_A_ROWS = [np.array(row) for row in _A]


def _envelope(v, c0, c1, c2, adh, any_c1_negative: bool):
    """Besinovic eq. 4 (c0 + c1 v up to the transition speed, c2 / v above), capped by adhesion; N/kg.

    ``adh`` = g m_adh / (gamma m) (0: no cap). Arrays broadcast; v >= 0.
    """
    with np.errstate(divide="ignore"):
        hyper = c2 / v
    if any_c1_negative:
        disc = c0 * c0 + 4.0 * c1 * c2
        with np.errstate(divide="ignore", invalid="ignore"):
            vt = np.where(
                c1 == 0.0, c2 / c0, np.where(disc >= 0.0, (-c0 + np.sqrt(np.maximum(disc, 0.0))) / (2.0 * c1), np.inf)
            )
        f = np.maximum(np.where(v <= vt, c0 + c1 * v, hyper), 0.0)
    else:
        f = np.minimum(c0 + c1 * v, hyper)
    if np.any(adh > 0.0):
        f = np.minimum(f, np.where(adh > 0.0, (0.161 + 7.5 / (3.6 * v + 44.0)) * adh, np.inf))
    return f


class _Leg:
    """What does not depend on the parameter vectors: knots, g(s) pieces, the ceiling and its targets."""

    def __init__(self, track: Track, length_m: float, start: float, stop: float, v_max: float) -> None:
        prep = _prepared(track, length_m, start, stop, v_max)
        terms, ceiling = prep.terms, prep.ceiling
        self.start, self.stop = start, stop
        self.breaks = np.asarray(ceiling.breaks, dtype=float)  # [start, b1, ...]: segment i starts at breaks[i]
        self.levels = np.asarray(ceiling.values, dtype=float)  # m/s, theta = 1
        self.rise_index = [i for i in range(1, self.breaks.size) if self.levels[i] > self.levels[i - 1]]
        self.drop_index = [i for i in range(1, self.breaks.size) if self.levels[i] < self.levels[i - 1]]
        # braking targets: the drops (b_limit) and the stop (b_stop)
        self.target_s = np.array([*(self.breaks[i] for i in self.drop_index), stop])
        self.target_v = np.array([*(self.levels[i] for i in self.drop_index), 0.0])
        # knots every integration step ends on: bends of g(s) / tunnel(s) and the rises; the stop last
        bends = [k for k in terms.bends_between(start, stop)]
        knots = sorted({*bends, *(float(self.breaks[i]) for i in self.rise_index)})
        self.knots = np.array([*knots, stop], dtype=float)
        left = np.concatenate(([start], self.knots[:-1]))
        g_l, g_r = terms.g_vec(left), terms.g_vec(self.knots)
        t_l, t_r = terms.tunnel_vec(left), terms.tunnel_vec(self.knots)
        width = self.knots - left
        # g on the piece ending at knots[i]: g_left[i] + g_slope[i] (s - left[i]) (exact: no bend inside)
        self.left = left
        self.g_left, self.g_slope = g_l, (g_r - g_l) / width
        self.tun_left, self.tun_slope = t_l, (t_r - t_l) / width
        self.has_tunnel = bool(np.any(t_l != 0.0) or np.any(t_r != 0.0))
        self.g_start = float(terms.g_at(start))
        # positions where the holding margin is evaluated: each ceiling segment's ends and the bends inside
        pos, seg = [], []
        for i in range(self.breaks.size):
            a = float(self.breaks[i])
            b = float(self.breaks[i + 1]) if i + 1 < self.breaks.size else stop
            pts = [a, *(k for k in bends if a < k < b), b]
            pos.extend(pts)
            seg.extend([i] * len(pts))
        self.hold_pos = np.array(pos)
        self.hold_seg = np.array(seg)
        self.hold_g = terms.g_vec(self.hold_pos)
        self.hold_tun = terms.tunnel_vec(self.hold_pos)
        self.hold_pair = np.nonzero(self.hold_seg[:-1] == self.hold_seg[1:])[0]  # (k, k + 1) in one segment
        first = np.concatenate(([True], self.hold_seg[1:] != self.hold_seg[:-1]))
        drops = set(self.drop_index)
        self.hold_first = np.array([k for k in np.nonzero(first)[0] if int(self.hold_seg[k]) in drops], dtype=int)


_LEGS: dict[tuple, tuple[object, _Leg]] = {}


def _leg(track: Track, length_m: float, start: float, stop: float, v_max: float) -> _Leg:
    key = (id(track), length_m, start, stop, v_max)
    hit = _LEGS.get(key)
    if hit is not None and hit[0] is track:
        return hit[1]
    leg = _Leg(track, length_m, start, stop, v_max)
    if len(_LEGS) > 64:
        _LEGS.clear()
    _LEGS[key] = (track, leg)
    return leg


@dataclass
class _Lanes:
    """Maximum-effort trajectories, one per (member, start point), and their accepted steps."""

    member: np.ndarray  # (N,) member of each lane
    x0: np.ndarray  # (N,) start position, m
    xo: np.ndarray  # (N,) origin of sigma = sqrt(s - xo), m
    w0: np.ndarray  # (N,) start w, m^2/s^2
    y: np.ndarray  # (N,) where the lane first crosses the cap (m); stop if it never does
    t_end: np.ndarray  # (N,) time from x0 to y along the lane, s
    # accepted steps, lane after lane: sigma at the start, step, w at the start, w dense-output coefficients
    step_lane: np.ndarray
    step_sig: np.ndarray
    step_h: np.ndarray
    step_u: np.ndarray  # u = sqrt(w) at the start
    step_q: np.ndarray  # (n_steps, 4): dense output of u
    step_t: np.ndarray  # time from x0 to the step's start, s
    step_qt: np.ndarray  # (n_steps, 4): dense output of t
    step_first: np.ndarray  # (N + 1,) index of each lane's first step
    iterations: int


def _cap_w_t(cap: dict, rows: np.ndarray, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(w, T) of the piecewise-linear cap (in w = v^2/2) at positions s of members rows: w and the time from the
    start (closed form on each linear piece)."""
    cs, cw, ct, key = cap["s"], cap["w"], cap["t"], cap["key"]
    k = cs.shape[1]
    j = np.searchsorted(key, rows * _KEY + s, side="right") - 1
    j = np.clip(j - rows * k, 0, k - 2) + rows * k
    sa, sb = cs.ravel()[j], cs.ravel()[j + 1]
    wa, wb = cw.ravel()[j], cw.ravel()[j + 1]
    with np.errstate(divide="ignore", invalid="ignore"):
        frac = np.where(sb > sa, (s - sa) / (sb - sa), 0.0)
        w = np.maximum(wa + (wb - wa) * frac, 0.0)
        dt = np.where(s > sa, 2.0 * (s - sa) / (np.sqrt(2.0 * wa) + np.sqrt(2.0 * w)), 0.0)
    return w, ct.ravel()[j] + dt


class ProfileBatch:
    """Minimum-time profiles of n parameter vectors between two stops (see the module docstring).

    ``ok[i]`` is False where member i cannot be run (``error[i]`` says why: cannot start, stalls);
    its times are NaN. Positions passed to :meth:`time_at` / :meth:`speed_at` are shared (shape (m,))
    or per member (shape (n, m)); results have shape (n, m).
    """

    def __init__(self, leg: _Leg, n: int, length_m: float, ok, error, lanes: _Lanes | None, cap, grid) -> None:
        self._leg = leg
        self.n = n
        self.length_m = float(length_m)
        self.ok = ok
        self.error = error
        self._lanes = lanes
        self._cap = cap  # dict of per-member cap knots
        self._grid = grid  # (n, L) lane index of each member's lanes sorted by start (-1 = none), active mask
        self.start_s, self.stop_s = leg.start, leg.stop
        self.run_time = self.time_at(np.array([leg.stop]))[:, 0]

    @property
    def iterations(self) -> int:
        """Integration steps of the longest lane (the cost of the call grows with it)."""
        return self._lanes.iterations if self._lanes is not None else 0

    # -- cap ----------------------------------------------------------------------------------
    def _cap_eval(self, rows: np.ndarray, s: np.ndarray):
        """(w, T) of the cap at positions s of members rows (same shapes): w and the time from the start."""
        return _cap_w_t(self._cap, rows, s)

    # -- lanes ---------------------------------------------------------------------------------
    def _lane_eval(self, lane: np.ndarray, s: np.ndarray):
        """(w, t) along lanes at positions s inside their ranges; t from the lane's start."""
        L = self._lanes
        sig = np.sqrt(np.maximum(s - L.xo[lane], 0.0))
        first, last = L.step_first[lane], L.step_first[lane + 1] - 1
        j = np.searchsorted(L.step_lane * _SIGKEY + L.step_sig, lane * _SIGKEY + sig, side="right") - 1
        j = np.clip(j, first, last)
        th = np.clip((sig - L.step_sig[j]) / L.step_h[j], 0.0, 1.0)
        return _poly(L.step_u[j], L.step_q[j], th) ** 2, _poly(L.step_t[j], L.step_qt[j], th)

    def _evaluate(self, s_m, rows=None):
        """(w, t) at positions s of the members ``rows`` (all by default); shape (len(rows), m)."""
        leg = self._leg
        rows = np.arange(self.n) if rows is None else np.atleast_1d(np.asarray(rows, dtype=int))
        s = np.asarray(s_m, dtype=float)
        if s.ndim == 1:
            s = np.broadcast_to(s, (rows.size, s.size))
        if s.ndim != 2 or s.shape[0] != rows.size:
            raise ValueError(f"positions must have shape (m,) or ({rows.size}, m), found {s.shape}")
        r2 = np.broadcast_to(rows[:, None], s.shape)
        inside = (s >= leg.start) & (s <= leg.stop)
        sc = np.clip(s, leg.start, leg.stop)
        wcap, tcap = self._cap_eval(r2.ravel(), sc.ravel())
        w, t = wcap.reshape(s.shape), tcap.reshape(s.shape)
        g = self._grid
        if g is not None and g["lane"].shape[1]:
            lane, active, x, y, d = (g[k][rows] for k in ("lane", "active", "x", "y", "d"))
            after = active[:, None, :] & (y[:, None, :] <= sc[:, :, None])
            t = t + np.sum(np.where(after, d[:, None, :], 0.0), axis=2)
            within = active[:, None, :] & (x[:, None, :] <= sc[:, :, None]) & (sc[:, :, None] < y[:, None, :])
            hit = within.any(axis=2)
            if hit.any():
                r, _ = np.nonzero(hit)
                col = np.argmax(within, axis=2)[hit]
                wl, tl = self._lane_eval(lane[r, col], sc[hit])
                # on a lane: the time at its start (cap time + earlier lanes' extra time) + the lane's time
                _, tx = self._cap_eval(rows[r], x[r, col])
                t[hit] += tx + tl - tcap.reshape(s.shape)[hit]
                w[hit] = wl
        bad = ~self.ok[rows][:, None] | ~inside
        return np.where(bad, np.nan, w), np.where(bad, np.nan, t)

    def time_at(self, s_m) -> np.ndarray:
        """Time (s after departure) at which the head passes s; NaN outside the run or for failed members."""
        return self._evaluate(s_m)[1]

    def speed_at(self, s_m) -> np.ndarray:
        """Speed of the head at s, m/s; NaN outside the run or for failed members."""
        return np.sqrt(2.0 * self._evaluate(s_m)[0])

    def tail_time_at(self, s_m) -> np.ndarray:
        """Time at which the tail passes s (the head is at s + L)."""
        return self.time_at(np.asarray(s_m, dtype=float) + self.length_m)

    def member(self, i: int) -> BatchMember:
        """Member i with the interface of a scalar :class:`~.running_time.Profile` (time_at, speed_at, ...)."""
        if not 0 <= i < self.n:
            raise IndexError(f"member {i} of {self.n}")
        return BatchMember(self, i)

    def __len__(self) -> int:
        return self.n


class BatchMember:
    """One member of a :class:`ProfileBatch`, usable where a scalar Profile is (same methods, 1-D results)."""

    def __init__(self, batch: ProfileBatch, i: int) -> None:
        self._batch, self.index = batch, i
        self.length_m = batch.length_m
        self.start_s, self.stop_s = batch.start_s, batch.stop_s
        self.ok, self.error = bool(batch.ok[i]), batch.error[i]

    @property
    def run_time(self) -> float:
        return float(self._batch.run_time[self.index])

    def _at(self, s_m, k: int) -> np.ndarray:
        s = np.asarray(s_m, dtype=float)
        return self._batch._evaluate(s.reshape(-1), [self.index])[k][0].reshape(s.shape)

    def time_at(self, s_m) -> np.ndarray:
        return self._at(s_m, 1)

    def speed_at(self, s_m) -> np.ndarray:
        return np.sqrt(2.0 * self._at(s_m, 0))

    def tail_time_at(self, s_m) -> np.ndarray:
        return self.time_at(np.asarray(s_m, dtype=float) + self.length_m)

    def occupation_release(self, start_m, end_m) -> tuple[np.ndarray, np.ndarray]:
        return self.time_at(start_m), self.tail_time_at(end_m)


_KEY = 1.0e6  # row key spacing for searches over per-member knots (tracks shorter than 1000 km)
_SIGKEY = 1.0e4  # lane key spacing over sigma = sqrt(s - x0) (< 1000 for tracks shorter than 1000 km)


@functools.cache
def _limits() -> dict[str, tuple]:
    """Valid ranges of the per-member parameters (RunningTimeParams' declarations)."""
    return {sp.name: (sp.low, sp.low_open, sp.high) for sp in RunningTimeParams.specs() if sp.name in BATCH_FIELDS}


def _as_arrays(base: RunningTimeParams, values: Mapping[str, object]) -> tuple[int, dict[str, np.ndarray]]:
    unknown = set(values) - set(BATCH_FIELDS)
    if unknown:
        raise ConfigError(
            "running_time_batch",
            sorted(unknown)[0],
            f"cannot vary within a batch (per-member: {', '.join(BATCH_FIELDS)})",
        )
    arrays = {k: np.atleast_1d(np.asarray(v, dtype=float)) for k, v in values.items()}
    sizes = {a.size for a in arrays.values()} - {1}
    if len(sizes) > 1:
        raise ValueError(f"per-member parameters have different lengths {sorted(sizes)}")
    n = sizes.pop() if sizes else 1
    out = {}
    for name in BATCH_FIELDS:
        a = arrays.get(name, np.array([getattr(base, name)], dtype=float))
        a = np.broadcast_to(a.ravel(), (n,)).astype(float)
        low, low_open, high = _limits()[name]
        bad = ~np.isfinite(a)
        if low is not None:
            bad |= (a <= low) if low_open else (a < low)
        if high is not None:
            bad |= a > high
        if bad.any():
            k = int(np.argmax(bad))
            raise ConfigError("running_time_batch", name, f"member {k}: {a[k]!r} is out of range")
        out[name] = a
    return n, out


def running_time_batch(
    track: Track,
    base: RunningTimeParams,
    start_s: float,
    stop_s: float,
    *,
    rtol: float = 1e-7,
    **values,
) -> ProfileBatch:
    """Minimum-time profiles of n parameter vectors from a standstill at start_s to a stop at stop_s.

    ``base`` gives the shared parameters (length, tunnel factor, adhesion, maximum speed) and the
    defaults; keyword arrays of length n (any of :data:`BATCH_FIELDS`) give the per-member values,
    e.g. ``running_time_batch(track, base, 250, 14550, c0=c0s, c2=c2s, theta_cruise=thetas)``.
    """
    if not stop_s > start_s:
        raise ConfigError(track.name, "stop_s", f"must be beyond start_s ({start_s:g} m), found {stop_s:g} m")
    n, p = _as_arrays(base, values)
    v_max = base.max_speed_kmh * KMH if base.max_speed_kmh > 0 else math.inf
    leg = _leg(track, base.length_m, float(start_s), float(stop_s), v_max)
    adh = np.full(n, 9.81 * base.adhesive_mass_fraction / base.rotating_mass_factor)
    c1neg = bool(np.any(p["c1"] < 0.0))
    theta = p["theta_cruise"]
    ft = base.tunnel_factor

    ok = np.ones(n, dtype=bool)
    fail = np.zeros(n, dtype=int)
    # cannot start: effort at standstill <= resistance + gradient
    f0 = _envelope(np.zeros(n), p["c0"], p["c1"], p["c2"], adh, c1neg)
    a0 = f0 - p["r0"] - leg.g_start
    fail[a0 <= 0.0] = _FAIL_START
    ok &= a0 > 0.0

    cap = _cap_knots(leg, theta, p["b_limit"], p["b_stop"])
    lanes_x0, lanes_w0, lanes_m = _lane_starts(leg, p, theta, adh, c1neg, ft)
    # valid lanes start at or below the cap (right limit) and belong to members that can start
    cap_right = _cap_at(leg, theta[lanes_m], p["b_limit"][lanes_m], p["b_stop"][lanes_m], lanes_x0, right=True)
    valid = (lanes_w0 <= cap_right * (1.0 + 1e-12) + 1e-12) & ok[lanes_m]
    lanes_x0, lanes_w0, lanes_m = lanes_x0[valid], lanes_w0[valid], lanes_m[valid]
    lanes = None
    grid = None
    if lanes_m.size:
        lanes, lane_fail = _integrate(leg, p, adh, c1neg, ft, theta, lanes_m, lanes_x0, lanes_w0, rtol)
        failed = lane_fail > 0
        np.maximum.at(fail, lanes.member[failed], lane_fail[failed])
        ok &= fail == 0
        grid = _lane_grid(n, lanes, cap)
    error = [_reason(fail[i], track, leg) if fail[i] else "" for i in range(n)]
    return ProfileBatch(leg, n, base.length_m, ok, error, lanes, cap, grid)


def _reason(code: int, track: Track, leg: _Leg) -> str:
    if code == _FAIL_START:
        return f"the train cannot start at s={leg.start:g} m: effort <= resistance + gradient"
    if code == _FAIL_STALL:
        return "the train stalls (effort below resistance + gradient)"
    return f"running-time model did not terminate on {track.name}"


# -- the cap: ceiling and braking curves, piecewise linear in w --------------------------------------
def _cap_at(leg: _Leg, theta, b_limit, b_stop, s, *, right: bool):
    """Cap w(s) for per-lane parameters; at a ceiling break the value after (right) or before it."""
    i = np.searchsorted(leg.breaks, s, side="right" if right else "left") - 1
    i = np.clip(i, 0, leg.breaks.size - 1)
    wc = 0.5 * (theta * leg.levels[i]) ** 2
    ntg = leg.target_s.size
    b = np.where(np.arange(ntg) < ntg - 1, b_limit[:, None], b_stop[:, None])
    wt = 0.5 * (theta[:, None] * leg.target_v[None, :]) ** 2
    d = leg.target_s[None, :] - s[:, None]
    ahead = d > 0.0 if right else d >= 0.0
    wb = np.where(ahead, wt + b * d, np.inf)
    return np.minimum(wc, wb.min(axis=1))


def _cap_knots(leg: _Leg, theta, b_limit, b_stop) -> dict:
    """Per member: the cap's knots (s, w) sorted along the leg, and the time from the start at each."""
    n = theta.size
    nb = leg.breaks.size
    ntg = leg.target_s.size
    cols_s, cols_right = [], []
    # both sides of every ceiling break (the cap jumps up at a rise), the start and the stop
    for k in range(nb):
        for right in (True,) if k == 0 else (False, True):
            cols_s.append(np.full(n, leg.breaks[k]))
            cols_right.append(right)
    cols_s.append(np.full(n, leg.stop))
    cols_right.append(False)
    # braking lines meeting a ceiling level inside that ceiling segment, and drop lines meeting the stop line
    b = np.where(np.arange(ntg) < ntg - 1, b_limit[:, None], b_stop[:, None])  # (n, J)
    wt = 0.5 * (theta[:, None] * leg.target_v[None, :]) ** 2
    a_i = leg.breaks
    b_i = np.append(leg.breaks[1:], leg.stop)
    wc = 0.5 * (theta[:, None] * leg.levels[None, :]) ** 2  # (n, I)
    p_j = leg.target_s
    x = p_j[None, None, :] - (wc[:, :, None] - wt[:, None, :]) / b[:, None, :]  # (n, I, J)
    good = (x > a_i[None, :, None]) & (x < np.minimum(b_i[:, None], p_j[None, :])[None, :, :])
    cols_s.extend(np.where(good, x, leg.stop).reshape(n, -1).T)
    cols_right.extend([False] * (x.shape[1] * x.shape[2]))
    with np.errstate(divide="ignore", invalid="ignore"):
        xd = (b_stop[:, None] * leg.stop - wt[:, :-1] - b_limit[:, None] * p_j[None, :-1]) / (b_stop - b_limit)[:, None]
    good = np.isfinite(xd) & (xd > leg.start) & (xd < p_j[None, :-1])
    cols_s.extend(np.where(good, xd, leg.stop).T)
    cols_right.extend([False] * (ntg - 1))
    S = np.stack(cols_s, axis=1)  # (n, K)
    right = np.array(cols_right)
    W = np.empty_like(S)
    rows = np.repeat(np.arange(n), S.shape[1])
    flat_s = S.ravel()
    for side in (True, False):
        m = np.tile(right == side, n)
        if m.any():
            W.ravel()[m] = _cap_at(leg, theta[rows[m]], b_limit[rows[m]], b_stop[rows[m]], flat_s[m], right=side)
    # the stop: w = 0 (every column placed at the stop carries the stop's value)
    W[leg.stop <= S] = 0.0
    # sort by s; ties keep column order (left side before right side of a break)
    order = np.argsort(S, axis=1, kind="stable")
    S = np.take_along_axis(S, order, axis=1)
    W = np.maximum(np.take_along_axis(W, order, axis=1), 0.0)
    V = np.sqrt(2.0 * W)
    dS = np.diff(S, axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        dT = np.where(dS > 0.0, 2.0 * dS / (V[:, :-1] + V[:, 1:]), 0.0)
    T = np.concatenate((np.zeros((n, 1)), np.cumsum(dT, axis=1)), axis=1)
    key = (np.arange(n)[:, None] * _KEY + S).ravel()
    return {"s": S, "w": W, "t": T, "key": key}


# -- lane starts: departure, rises, hold-fail points ---------------------------------------------
def _lane_starts(leg: _Leg, p, theta, adh, c1neg: bool, ft: float):
    n = theta.size
    xs = [np.full(n, leg.start)]
    ws = [np.zeros(n)]
    ms = [np.arange(n)]
    for i in leg.rise_index:
        xs.append(np.full(n, leg.breaks[i]))
        ws.append(0.5 * (theta * leg.levels[i - 1]) ** 2)
        ms.append(np.arange(n))
    # hold-fail: the envelope cannot hold the ceiling speed (margin < 0) from x on
    if leg.hold_pos.size:
        v = theta[:, None] * leg.levels[leg.hold_seg][None, :]  # (n, E)
        f = _envelope(v, p["c0"][:, None], p["c1"][:, None], p["c2"][:, None], adh[:, None], c1neg)
        q = p["r2"][:, None] * (1.0 + ft * leg.hold_tun[None, :])
        margin = f - p["r0"][:, None] - p["r1"][:, None] * v - q * v * v - leg.hold_g[None, :]
        k = leg.hold_pair
        m0, m1 = margin[:, k], margin[:, k + 1]
        cross = (m0 >= 0.0) & (m1 < 0.0)
        r, c = np.nonzero(cross)
        if r.size:
            a, b = leg.hold_pos[k[c]], leg.hold_pos[k[c] + 1]
            x = a + (b - a) * m0[r, c] / (m0[r, c] - m1[r, c])
            xs.append(x)
            ws.append(0.5 * v[r, k[c]] ** 2)
            ms.append(r)
        if leg.hold_first.size:
            mf = margin[:, leg.hold_first]
            r, c = np.nonzero(mf < 0.0)
            if r.size:
                xs.append(leg.hold_pos[leg.hold_first[c]])
                ws.append(0.5 * v[r, leg.hold_first[c]] ** 2)
                ms.append(r)
    return np.concatenate(xs), np.concatenate(ws), np.concatenate(ms)


# -- the integration of all lanes together ---------------------------------------------------------
def _integrate(leg: _Leg, p, adh, c1neg, ft, theta, member, x0, w0, rtol):
    """Dormand-Prince 5(4) over sigma = sqrt(s - x0) for every lane at once, until each crosses the cap.

    State (u, t) with u = sqrt(w) = v / sqrt(2): du/dsigma = sigma a / u and dt/dsigma = sqrt(2) sigma / u
    are regular from a standstill (u ~ sqrt(a0) sigma). Each lane is on one branch of the envelope
    (c0 + c1 v below the transition speed, c2 / v above): a step that crosses the transition speed is
    cut there on its dense output and the lane switches branch, so no step straddles the kink.
    """
    order = np.lexsort((x0, member))
    member, x0, w0 = member[order], x0[order], w0[order]
    N = member.size
    # sigma = sqrt(s - xo): from a standstill xo = x0 (sigma starts at 0); a lane that starts moving gets
    # its origin _ORIGIN_M behind its start (at sigma = 0 its solution would be even in sigma, which
    # blinds the embedded error estimate of the first step)
    xo = np.where(w0 > 0.0, x0 - _ORIGIN_M, x0)
    c0, c1, c2 = p["c0"][member], p["c1"][member], p["c2"][member]
    r0, r1 = p["r0"][member], p["r1"][member]
    r2x2 = 2.0 * p["r2"][member]
    lane_adh = adh[member]
    use_adh = bool(np.any(lane_adh > 0.0))
    use_c1 = bool(np.any(c1 != 0.0))
    th_l, bl_l, bs_l = theta[member], p["b_limit"][member], p["b_stop"][member]
    has_tun = leg.has_tunnel and ft != 0.0
    u_tr = _transition_speed(c0, c1, c2) / _SQRT2
    # the cap per lane, in O(1) numpy operations per evaluation: on ceiling segment i (left-closed at a
    # break, so that a step ending on a rise still sees the old ceiling) it is
    # min(level_i, m_i - b_limit s, b_stop (stop - s)) with m_i = min over the drops ahead of
    # (w_j + b_limit p_j): the drops' braking lines are parallel
    nseg = leg.levels.size
    lev_flat = (0.5 * (th_l[:, None] * leg.levels[None, :]) ** 2).ravel()  # (N, nseg) ceiling w per lane
    ndrop = leg.target_s.size - 1
    drop_w = 0.5 * (th_l[:, None] * leg.target_v[None, :ndrop]) ** 2 + bl_l[:, None] * leg.target_s[None, :ndrop]
    m_seg = np.full((N, nseg), np.inf)
    for i in range(nseg):
        ahead = leg.target_s[:ndrop] > leg.breaks[i]
        if ahead.any():
            m_seg[:, i] = drop_w[:, ahead].min(axis=1)
    m_flat = m_seg.ravel()
    lane_base = np.arange(N) * nseg
    stop = leg.stop

    def cap_left(s, lanes=None, slope=False):
        """The cap just before s (the old ceiling at a rise) for every lane or for ``lanes`` (and dcap/ds)."""
        i = np.searchsorted(leg.breaks, s, side="left") - 1
        np.maximum(i, 0, out=i)
        if lanes is None:
            k = lane_base + i
            wc = lev_flat[k]
            wd = m_flat[k] - bl_l * s
            ws = bs_l * (stop - s)
        else:
            k = lane_base[lanes] + i
            wc = lev_flat[k]
            wd = m_flat[k] - bl_l[lanes] * s
            ws = bs_l[lanes] * (stop - s)
        cap = np.minimum(np.minimum(wc, wd), ws)
        if not slope:
            return cap
        sl = np.where(cap == ws, -(bs_l if lanes is None else bs_l[lanes]), 0.0)
        return cap, np.where((cap == wd) & (cap < ws), -(bl_l if lanes is None else bl_l[lanes]), sl)

    knots = leg.knots
    kidx = np.minimum(np.searchsorted(knots, x0, side="right"), knots.size - 1)

    def piece(idx, xs0):
        """Per-lane piece coefficients: g = cg + gb sigma^2 and tunnel = tq + tqb sigma^2."""
        gb_ = leg.g_slope[idx]
        cg_ = leg.g_left[idx] + gb_ * (xs0 - leg.left[idx])
        tqb_ = leg.tun_slope[idx]
        tq_ = leg.tun_left[idx] + tqb_ * (xs0 - leg.left[idx])
        return cg_, gb_, tq_, tqb_

    cg, gb, tq, tqb = piece(kidx, xo)
    cg = cg + r0
    q2 = r2x2 * (1.0 + ft * tq)  # 2 r2 (1 + f tunnel) = q2 + q2b sigma^2
    q2b = r2x2 * ft * tqb
    sig_k = np.sqrt(knots[kidx] - xo)

    # envelope branch per lane: f = e0 + e1 v + e2 / v
    above = w0 > 0.5 * (_SQRT2 * u_tr) ** 2

    def branch(ab, c0_, c1_, c2_):
        """(e0, e1 sqrt(2), e2 / sqrt(2)) of the branch: f = e0 + e1s u + e2s / u."""
        return np.where(ab, 0.0, c0_), np.where(ab, 0.0, c1_ * _SQRT2), np.where(ab, c2_ / _SQRT2, 0.0)

    e0, e1s, e2s = branch(above, c0, c1, c2)

    r1s = r1 * _SQRT2  # r1 v = r1s u

    def rhs(sg, uu, out_u, out_t, hs):
        """hs * (du/dsigma, dt/dsigma) into out_u, out_t (the hot loop: few numpy operations)."""
        ss = sg * sg
        iu = 1.0 / uu
        f = e0 + e2s * iu  # e0 + e1 v + e2 / v
        if use_c1:
            f += e1s * uu
            if c1neg:
                np.maximum(f, 0.0, out=f)
        if use_adh:
            f = np.minimum(f, (0.161 + 7.5 / ((3.6 * _SQRT2) * uu + 44.0)) * lane_adh)
        f -= cg
        f -= gb * ss
        f -= r1s * uu
        if has_tun:
            f -= (q2 + q2b * ss) * (uu * uu)
        else:
            f -= q2 * (uu * uu)
        hsu = hs * sg
        hsu *= iu
        np.multiply(hsu, f, out=out_u)
        np.multiply(hsu, _SQRT2, out=out_t)

    # the state: y = [u (N), t (N)], t from the lane's start
    sig = np.sqrt(x0 - xo)
    y = np.concatenate((np.sqrt(w0), np.zeros(N)))
    u = y[:N]
    alive = np.ones(N, dtype=bool)
    fail = np.zeros(N, dtype=int)
    crossed = np.zeros(N, dtype=bool)
    h = np.where(w0 > 0.0, 3.0, 4.0)  # about 16 m from a standstill, 50 m else
    rec_sig, rec_y, rec_h, rec_end, rec_send, rec_hk, rec_acc = [], [], [], [], [], [], []
    k1 = np.empty(2 * N)
    it = 0
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        # the derivative at the start; from a standstill (u = sqrt(a0) sigma at sigma = 0)
        # du/dsigma = sqrt(a0), dt/dsigma = sqrt(2 / a0)
        rhs(sig, u, k1[:N], k1[N:], np.ones(N))
        a_start = np.maximum(_envelope(np.zeros(N), c0, c1, c2, lane_adh, c1neg) - cg, 1e-300)
        k1[:N] = np.where(w0 > 0.0, k1[:N], np.sqrt(a_start))
        k1[N:] = np.where(w0 > 0.0, k1[N:], np.sqrt(2.0 / a_start))
        while alive.any():
            it += 1
            if it > _MAX_ITER:
                fail[alive] = _FAIL_STEP
                break
            dist = sig_k - sig
            hit = dist <= h
            hs = np.minimum(h, dist)
            hs2 = np.concatenate((hs, hs))
            HK = np.empty((7, 2 * N))
            np.multiply(hs2, k1, out=HK[0])
            for i in range(1, 7):
                yi = y + np.dot(_A_ROWS[i], HK[:i])
                rhs(sig + _C[i] * hs, yi[:N], HK[i, :N], HK[i, N:], hs)
            e = np.abs(np.dot(_E, HK)) / (_ATOL + rtol * np.maximum(y, yi))  # u, t >= 0
            err = np.fmin(np.maximum(e[:N], e[N:]), 1e10)  # NaN (a trial stage below u = 0): reject
            acc = (err <= 1.0) & alive
            fac = np.minimum(np.maximum(0.9 * err**-0.2, 0.2), 10.0)
            h = hs * fac
            rec_sig.append(sig.copy())
            rec_y.append(y.copy())
            rec_h.append(hs)
            rec_hk.append(HK)
            rec_acc.append(acc)
            u_old = u.copy()
            # a step that crosses the transition speed ends there (dense output; the other branch follows)
            u_new = yi[:N]
            tr = acc & ((u_new > u_tr) != above)
            end = _ONES[:N] if _ONES.size >= N else np.ones(N)
            if tr.any():
                end = np.ones(N)
                j = np.nonzero(tr)[0]
                qu = HK[:, j].T @ DENSE_P
                qt = HK[:, N + j].T @ DENSE_P
                th = np.minimum(np.maximum((u_tr[j] - u[j]) / (u_new[j] - u[j]), 0.0), 1.0)
                for _ in range(8):  # Newton on u(th) = u_tr (monotone within the step)
                    du = qu[:, 0] + th * (2.0 * qu[:, 1] + th * (3.0 * qu[:, 2] + th * 4.0 * qu[:, 3]))
                    step = (_poly(u[j], qu, th) - u_tr[j]) / du
                    th = np.minimum(np.maximum(th - step, 0.0), 1.0)
                    if np.all(np.abs(step) < 1e-13):
                        break
                end[j] = th
                yi[j] = u_tr[j]
                yi[N + j] = _poly(y[N + j], qt, th)
                above[j] = ~above[j]
                e0[j], e1s[j], e2s[j] = branch(above[j], c0[j], c1[j], c2[j])
                hit[j] = False
            rec_end.append(end)
            sig_new = sig + end * hs
            hit &= acc
            sig_new[hit] = sig_k[hit]
            np.copyto(sig, sig_new, where=acc)
            # where the lanes are (exactly on the knot after a step that ends on one: x0 + sigma^2 may
            # round to the far side of a rise, where the cap is the higher ceiling)
            s_now = xo + sig * sig
            s_now[hit] = knots[kidx[hit]]
            rec_send.append(s_now)
            acc2 = np.concatenate((acc, acc))
            np.copyto(y, yi, where=acc2)
            np.copyto(k1, HK[6] / hs2, where=acc2)
            if tr.any():  # the derivative on the new branch
                kk = np.empty(2 * N)
                rhs(sig, u, kk[:N], kk[N:], np.ones(N))
                k1[j], k1[N + j] = kk[j], kk[N + j]
            # knots: the next piece of g(s)
            if hit.any():
                at_end = hit & (kidx == knots.size - 1)
                adv = hit & ~at_end
                if adv.any():
                    kidx[adv] += 1
                    ncg, ngb, ntq, ntqb = piece(kidx[adv], xo[adv])
                    cg[adv] = ncg + r0[adv]
                    gb[adv] = ngb
                    q2[adv] = r2x2[adv] * (1.0 + ft * ntq)
                    q2b[adv] = r2x2[adv] * ft * ntqb
                    sig_k[adv] = np.sqrt(knots[kidx[adv]] - xo[adv])
                alive &= ~at_end
            # the cap
            capw = cap_left(s_now)
            w = u * u
            cr = acc & (w > capw)
            crossed |= cr
            alive &= ~cr
            st = acc & (w < _STALL_W)
            if st.any():
                st &= (u < u_old) & ~cr
                fail[st] = _FAIL_STALL
                alive &= ~st
            tiny = alive & (h < 1e-10)
            if tiny.any():
                fail[tiny] = _FAIL_STEP
                alive &= ~tiny
    lanes = _collect(
        leg, member, x0, xo, w0, crossed, rec_sig, rec_y, rec_h, rec_end, rec_send, rec_hk, rec_acc, cap_left, it
    )
    return lanes, fail


def _transition_speed(c0, c1, c2):
    """Per lane: the first crossing of c0 + c1 v and c2 / v (physics.transition_speed), m/s."""
    disc = c0 * c0 + 4.0 * c1 * c2
    with np.errstate(divide="ignore", invalid="ignore"):
        quad = (-c0 + np.sqrt(np.maximum(disc, 0.0))) / (2.0 * c1)
    return np.where(c1 == 0.0, c2 / c0, np.where(disc >= 0.0, quad, np.inf))


def _collect(
    leg, member, x0, xo, w0, crossed, rec_sig, rec_y, rec_h, rec_end, rec_send, rec_hk, rec_acc, cap_left, it
) -> _Lanes:
    """Accepted steps lane after lane, with their dense output, and each lane's crossing with the cap."""
    N = member.size
    acc = np.stack(rec_acc, axis=1)  # (N, iters)
    lane_idx, it_idx = np.nonzero(acc)
    sig = np.stack(rec_sig, axis=1)[lane_idx, it_idx]
    ys = np.stack(rec_y, axis=1)  # (2N, iters)
    u, t = ys[lane_idx, it_idx], ys[N + lane_idx, it_idx]
    h = np.stack(rec_h, axis=1)[lane_idx, it_idx]
    th_end = np.stack(rec_end, axis=1)[lane_idx, it_idx]  # < 1: the step was cut at the transition speed
    s_end = np.stack(rec_send, axis=1)[lane_idx, it_idx]  # where the step ends, m (exact on knots)
    hk = np.stack(rec_hk, axis=2)  # (7, 2N, iters)
    qu = hk[:, lane_idx, it_idx].T @ DENSE_P  # (n_steps, 4): u = u0 + th (q0 + th (q1 + ...))
    qt = hk[:, N + lane_idx, it_idx].T @ DENSE_P
    counts = np.bincount(lane_idx, minlength=N)
    first = np.concatenate(([0], np.cumsum(counts)))
    last = first[1:] - 1
    y_end = np.full(N, leg.stop)
    t_end = np.zeros(N)
    has = counts > 0
    # default: the end of the last step
    t_end[has] = _poly(t[last[has]], qt[last[has]], th_end[last[has]])
    # locate the crossing with the cap inside each crossed lane's last step (on the dense output)
    cl = np.nonzero(crossed & has)[0]
    if cl.size:
        j = last[cl]
        xs, s0, hh, uu, qq, s_hi = xo[cl], sig[j], h[j], u[j], qu[j], s_end[j]

        def f(th):
            """u(th)^2 - cap and its derivative in th."""
            sg = s0 + th * hh
            ut = _poly(uu, qq, th)
            dut = qq[:, 0] + th * (2.0 * qq[:, 1] + th * (3.0 * qq[:, 2] + th * 4.0 * qq[:, 3]))
            cw, slope = cap_left(np.minimum(xs + sg * sg, s_hi), cl, slope=True)
            return ut * ut - cw, 2.0 * ut * dut - slope * 2.0 * sg * hh

        # bracket [0, th_end]: f(0) < 0 (the lane is below the cap where its last step starts) except for a
        # lane that starts on the cap (hold-fail: it falls below at once) and may meet a steeply falling
        # braking curve in its very first step; there the first of 16 samples above the cap bounds it.
        lo, hi = np.zeros(cl.size), th_end[j].copy()
        flo, fhi = f(lo)[0], f(hi)[0]
        edge = np.nonzero(flo >= 0.0)[0]
        if edge.size:
            grid = np.linspace(0.0, 1.0, 17)[1:, None] * hi[edge][None, :]
            fs = np.empty(grid.shape)
            for r in range(grid.shape[0]):
                th_r = hi.copy()
                th_r[edge] = grid[r]
                fs[r] = f(th_r)[0][edge]
            k = np.argmax(fs > 0.0, axis=0)
            cols = np.arange(edge.size)
            hi[edge], fhi[edge] = grid[k, cols], fs[k, cols]
            lo[edge] = np.where(k > 0, grid[np.maximum(k - 1, 0), cols], 0.0)
            flo[edge] = np.where(k > 0, fs[np.maximum(k - 1, 0), cols], -1e-300)
        flo = np.minimum(flo, -1e-300)
        # safeguarded Newton in the bracket. The crossing's position hardly matters for the times (lane
        # and cap have the same speed there); it is located to 1e-4 m.
        th = lo - flo * (hi - lo) / (fhi - flo)  # regula falsi start
        conv = np.zeros(cl.size, dtype=bool)
        for _ in range(40):
            fv, fp = f(th)
            up = fv >= 0.0
            hi, fhi = np.where(up, th, hi), np.where(up, fv, fhi)
            lo, flo = np.where(up, lo, th), np.where(up, flo, fv)
            with np.errstate(divide="ignore", invalid="ignore"):
                nt = th - fv / fp
                inside = (nt > lo) & (nt < hi)
                # converged: a Newton step inside the bracket that moves s by less than 1e-4 m
                conv |= inside & (np.abs(nt - th) * (s0 + hh) * hh <= 5e-5)
                conv |= (hi - lo) * (s0 + hh) * hh <= 5e-5  # or the bracket is that narrow (a kink of the cap)
                conv |= fv == 0.0
            nt = np.where(inside, nt, 0.5 * (lo + hi))  # outside the bracket: bisection
            th = np.where(conv, np.clip(np.where(inside, th - fv / fp, th), lo, hi), nt)
            if conv.all():
                break
        hi = th
        sg = s0 + hi * hh
        y_end[cl] = np.minimum(xs + sg * sg, s_hi)
        t_end[cl] = _poly(t[j], qt[j], hi)
    return _Lanes(member, x0, xo, w0, y_end, t_end, lane_idx, sig, h, u, qu, t, qt, first, it)


def _poly(y0, q, th):
    """Dense output y0 + th (q0 + th (q1 + th (q2 + th q3))), q of shape (..., 4)."""
    return y0 + th * (q[..., 0] + th * (q[..., 1] + th * (q[..., 2] + th * q[..., 3])))


def _lane_grid(n: int, lanes: _Lanes, cap: dict) -> dict:
    """Members x lanes (sorted by start): which lanes are on the profile, and their extra time over the cap."""
    member = lanes.member
    counts = np.bincount(member, minlength=n)
    width = int(counts.max()) if counts.size else 0
    col = np.arange(member.size) - np.concatenate(([0], np.cumsum(counts)))[member]
    lane = np.full((n, width), -1)
    lane[member, col] = np.arange(member.size)
    x = np.full((n, width), np.inf)
    y = np.full((n, width), np.inf)
    x[member, col] = lanes.x0
    y[member, col] = lanes.y
    reach = np.maximum.accumulate(np.where(lane >= 0, y, -np.inf), axis=1)  # furthest end of the lanes so far
    prev = np.concatenate((np.full((n, 1), -np.inf), reach[:, :-1]), axis=1)
    active = (lane >= 0) & (x >= prev)
    d = np.zeros((n, width))
    if active.any():
        r, c = np.nonzero(active)
        ln = lane[r, c]
        # (cap time from x to y) replaced by the lane's time
        d[r, c] = lanes.t_end[ln] - (_cap_w_t(cap, r, lanes.y[ln])[1] - _cap_w_t(cap, r, lanes.x0[ln])[1])
    return {"lane": lane, "active": active, "x": x, "y": y, "d": d}
