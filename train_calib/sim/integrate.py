"""Dormand-Prince 5(4) (RK45) for a two-component state, in plain Python floats.

Both running-time formulations of the simulator have a state of two numbers: over time
``x = t, y = (s, v)`` and over distance ``x = s, y = (t, v)``. Unrolling the method for two
components in scalar arithmetic is several times faster than a general vector solver (scipy's
``solve_ivp`` costs ~100 us per step in overhead alone), which is what makes a 32 km trajectory
cost milliseconds.

Features: adaptive step (Hairer's error norm and step-size controller, the same tableau and
dense output as ``scipy.integrate.RK45``), events located on the 4th-order dense output (Illinois
regula falsi), terminal events (return to the caller: a driver phase switch) and non-terminal
ones (the step is cut there and integration goes on: a kink of the right-hand side such as the
effort/power transition speed), positions ``x_stops`` the steps must end on exactly (knots of the
track force in the distance formulation) and values of the first state component ``ya_stops``
located like events (the same knots in the time formulation). Accepted steps can be recorded with
their dense-output coefficients (:class:`StepRecord`) so the trajectory is known at any x.
"""

from __future__ import annotations

from bisect import bisect_right
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

# Dormand-Prince tableau (Hairer, Norsett & Wanner, Solving ODE I; scipy's RK45).
_A21 = 1 / 5
_A31, _A32 = 3 / 40, 9 / 40
_A41, _A42, _A43 = 44 / 45, -56 / 15, 32 / 9
_A51, _A52, _A53, _A54 = 19372 / 6561, -25360 / 2187, 64448 / 6561, -212 / 729
_A61, _A62, _A63, _A64, _A65 = 9017 / 3168, -355 / 33, 46732 / 5247, 49 / 176, -5103 / 18656
_B1, _B3, _B4, _B5, _B6 = 35 / 384, 500 / 1113, 125 / 192, -2187 / 6784, 11 / 84
_C2, _C3, _C4, _C5 = 1 / 5, 3 / 10, 4 / 5, 8 / 9
_E1, _E3, _E4, _E5, _E6, _E7 = -71 / 57600, 71 / 16695, -71 / 1920, 17253 / 339200, -22 / 525, 1 / 40

# Dense output: y(x0 + theta h) = y0 + h * sum_i k_i * (P[i] . [theta, theta^2, theta^3, theta^4]).
DENSE_P = np.array(
    [
        [1, -8048581381 / 2820520608, 8663915743 / 2820520608, -12715105075 / 11282082432],
        [0, 0, 0, 0],
        [0, 131558114200 / 32700410799, -68118460800 / 10900136933, 87487479700 / 32700410799],
        [0, -1754552775 / 470086768, 14199869525 / 1410260304, -10690763975 / 1880347072],
        [0, 127303824393 / 49829197408, -318862633887 / 49829197408, 701980252875 / 199316789632],
        [0, -282668133 / 205662961, 2019193451 / 616988883, -1453857185 / 822651844],
        [0, 40617522 / 29380423, -110615467 / 29380423, 69997945 / 29380423],
    ]
)
_P = DENSE_P.tolist()

_SAFETY, _MIN_FACTOR, _MAX_FACTOR = 0.9, 0.2, 10.0

RHS = Callable[[float, float, float], tuple[float, float]]
EventFn = Callable[[float, float, float], float]


class IntegrationError(RuntimeError):
    """The step size underflowed or the right-hand side returned a non-finite value."""


@dataclass(frozen=True)
class Event:
    """Triggers where ``fn(x, ya, yb)`` goes from negative to zero or positive.

    A function already >= 0 at the start of an integration is ignored until it has been negative.
    Terminal events end the integration (``tag`` is returned); others only cut the step.
    """

    fn: EventFn
    tag: object = None
    terminal: bool = True


@dataclass
class Outcome:
    """Where an integration stopped: ``tag`` of the terminal event, or None at ``x_end``."""

    x: float
    ya: float
    yb: float
    fa: float
    fb: float
    h: float  # suggested next step
    tag: object = None
    steps: int = 0


class StepRecord:
    """Accepted steps with their dense-output polynomials, evaluated vectorised afterwards.

    Step i covers ``[x0[i], x1[i]]`` (x1 < x0 + h when the step was cut at an event); its state is
    ``y(x) = y0 + qa . [th, th^2, th^3, th^4]`` with ``th = (x - x0) / h``. ``seg[i]`` tags the
    step with the caller's segment (driver phase) index.
    """

    def __init__(self) -> None:
        self.x0: list[float] = []
        self.x1: list[float] = []
        self.h: list[float] = []
        self.ya: list[float] = []
        self.yb: list[float] = []
        self.k: list[tuple[float, ...]] = []  # 14 numbers: (ka_1..ka_7, kb_1..kb_7)
        self.poly: list[tuple[float, ...] | None] = []  # explicit polynomial (8 numbers) instead of k
        self.seg: list[int] = []
        self._arrays: dict[str, np.ndarray] | None = None

    def __len__(self) -> int:
        return len(self.x0)

    def add_rk(self, x0: float, x1: float, h: float, ya: float, yb: float, k: tuple[float, ...], seg: int) -> None:
        self.x0.append(x0)
        self.x1.append(x1)
        self.h.append(h)
        self.ya.append(ya)
        self.yb.append(yb)
        self.k.append(k)
        self.poly.append(None)
        self.seg.append(seg)
        self._arrays = None

    def add_poly(self, x0: float, x1: float, ya: float, yb: float, qa: Sequence[float], qb: Sequence[float], seg: int):
        """An analytic piece: y = y0 + q . [th..th^4] with th = (x - x0) / (x1 - x0)."""
        h = x1 - x0
        self.x0.append(x0)
        self.x1.append(x1)
        self.h.append(h if h > 0 else 1.0)
        self.ya.append(ya)
        self.yb.append(yb)
        self.k.append((0.0,) * 14)
        self.poly.append((*qa, *qb))
        self.seg.append(seg)
        self._arrays = None

    def arrays(self) -> dict[str, np.ndarray]:
        if self._arrays is None:
            n = len(self.x0)
            h = np.asarray(self.h, dtype=float)
            k = np.asarray(self.k, dtype=float).reshape(n, 2, 7) if n else np.zeros((0, 2, 7))
            q = h[:, None, None] * (k @ DENSE_P)  # (n, 2, 4)
            for i, poly in enumerate(self.poly):
                if poly is not None:
                    q[i, 0, :] = poly[:4]
                    q[i, 1, :] = poly[4:]
            self._arrays = {
                "x0": np.asarray(self.x0, dtype=float),
                "x1": np.asarray(self.x1, dtype=float),
                "h": h,
                "y0": np.stack([np.asarray(self.ya, dtype=float), np.asarray(self.yb, dtype=float)], axis=1)
                if n
                else np.zeros((0, 2)),
                "q": q,
                "seg": np.asarray(self.seg, dtype=np.int64),
            }
        return self._arrays

    def evaluate(self, x) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(ya, yb, step index) at the positions x (clipped to the recorded range)."""
        arr = self.arrays()
        x = np.asarray(x, dtype=float)
        idx = np.clip(np.searchsorted(arr["x0"], x, side="right") - 1, 0, len(arr["x0"]) - 1)
        xc = np.clip(x, arr["x0"][idx], arr["x1"][idx])
        th = (xc - arr["x0"][idx]) / arr["h"][idx]
        powers = np.stack([th, th * th, th**3, th**4], axis=-1)
        q = arr["q"][idx]
        ya = arr["y0"][idx, 0] + np.einsum("...k,...k->...", q[..., 0, :], powers)
        yb = arr["y0"][idx, 1] + np.einsum("...k,...k->...", q[..., 1, :], powers)
        return ya, yb, idx


def _horner(y0: float, q: tuple[float, float, float, float], th: float) -> float:
    return y0 + th * (q[0] + th * (q[1] + th * (q[2] + th * q[3])))


def _coefficients(k: tuple[float, ...], h: float, off: int) -> tuple[float, float, float, float]:
    """Dense-output polynomial of one component: y0 + q0 th + q1 th^2 + q2 th^3 + q3 th^4."""
    q = [0.0, 0.0, 0.0, 0.0]
    for i in range(7):
        ki = k[off + i]
        if ki:
            p = _P[i]
            q[0] += ki * p[0]
            q[1] += ki * p[1]
            q[2] += ki * p[2]
            q[3] += ki * p[3]
    return h * q[0], h * q[1], h * q[2], h * q[3]


def _locate(fn: EventFn, x0: float, h: float, ya0: float, yb0: float, k, lo: float, hi: float, elo: float, ehi: float):
    """Theta in (lo, hi] where fn crosses zero from below (Illinois method on the dense output)."""
    a0, a1, a2, a3 = _coefficients(k, h, 0)
    b0, b1, b2, b3 = _coefficients(k, h, 7)
    side = 0
    tol = 1e-10 * max(1.0, abs(x0)) / abs(h)
    for _ in range(80):
        if hi - lo <= tol:
            break
        th = hi - ehi * (hi - lo) / (ehi - elo) if ehi != elo else 0.5 * (lo + hi)
        if not lo < th < hi:
            th = 0.5 * (lo + hi)
        e = fn(
            x0 + th * h,
            ya0 + th * (a0 + th * (a1 + th * (a2 + th * a3))),
            yb0 + th * (b0 + th * (b1 + th * (b2 + th * b3))),
        )
        if e >= 0.0:
            hi, ehi = th, e
            if side == -1:
                elo *= 0.5
            side = -1
        else:
            lo, elo = th, e
            if side == 1:
                ehi *= 0.5
            side = 1
    return hi


def integrate(
    f: RHS,
    x: float,
    ya: float,
    yb: float,
    x_end: float,
    *,
    h: float,
    rtol: float,
    atol_a: float,
    atol_b: float,
    max_step: float = np.inf,
    events: Sequence[Event] = (),
    x_stops: Sequence[float] | None = None,
    ya_stops: Sequence[float] | None = None,
    ya_terminal: frozenset[float] | set[float] = frozenset(),
    record: StepRecord | None = None,
    trace: list | None = None,
    seg: int = 0,
    fa: float | None = None,
    fb: float | None = None,
) -> Outcome:
    """Integrate y' = f(x, y) forward from x to x_end (or the first terminal event).

    ``x_stops``: sorted x values every step must end on (e.g. knots of g(s) over distance).
    ``ya_stops``: sorted values of ya (increasing along the solution) where steps are cut by root
    finding (the same knots over time); reaching one of them that is in ``ya_terminal`` ends the
    integration with the tag ``("ya_stop", value)``. ``fa, fb``: f at the start if known (FSAL reuse).
    ``record`` keeps every accepted step with its dense output; ``trace`` gets the end point
    ``(x, ya, yb)`` of every accepted step (cheaper when only the nodes are needed).
    """
    if fa is None or fb is None:
        fa, fb = f(x, ya, yb)
    ev_vals = [ev.fn(x, ya, yb) for ev in events]
    xi = bisect_right(x_stops, x + 1e-12 * max(1.0, abs(x))) if x_stops else 0
    nx = len(x_stops) if x_stops else 0
    yi = bisect_right(ya_stops, ya) if ya_stops else 0
    ny = len(ya_stops) if ya_stops else 0
    h = min(abs(h), max_step) if h > 0 else min(1.0, max_step)
    steps = 0
    forced_h: float | None = None
    while True:
        remaining = x_end - x
        if remaining <= 1e-12 * max(1.0, abs(x_end)):
            return Outcome(x, ya, yb, fa, fb, h, None, steps)
        hs = min(h, remaining)
        if forced_h is not None:  # redo of a step that crossed a kink: end just at it
            hs, forced_h = min(forced_h, remaining), None
            retried = True
        else:
            retried = False
        stop_hit = False
        if xi < nx:
            to_stop = x_stops[xi] - x
            if to_stop <= hs:
                hs, stop_hit = to_stop, True
        # stages
        a1, b1 = fa, fb
        a2, b2 = f(x + _C2 * hs, ya + hs * _A21 * a1, yb + hs * _A21 * b1)
        a3, b3 = f(x + _C3 * hs, ya + hs * (_A31 * a1 + _A32 * a2), yb + hs * (_A31 * b1 + _A32 * b2))
        a4, b4 = f(
            x + _C4 * hs,
            ya + hs * (_A41 * a1 + _A42 * a2 + _A43 * a3),
            yb + hs * (_A41 * b1 + _A42 * b2 + _A43 * b3),
        )
        a5, b5 = f(
            x + _C5 * hs,
            ya + hs * (_A51 * a1 + _A52 * a2 + _A53 * a3 + _A54 * a4),
            yb + hs * (_A51 * b1 + _A52 * b2 + _A53 * b3 + _A54 * b4),
        )
        a6, b6 = f(
            x + hs,
            ya + hs * (_A61 * a1 + _A62 * a2 + _A63 * a3 + _A64 * a4 + _A65 * a5),
            yb + hs * (_A61 * b1 + _A62 * b2 + _A63 * b3 + _A64 * b4 + _A65 * b5),
        )
        ya_new = ya + hs * (_B1 * a1 + _B3 * a3 + _B4 * a4 + _B5 * a5 + _B6 * a6)
        yb_new = yb + hs * (_B1 * b1 + _B3 * b3 + _B4 * b4 + _B5 * b5 + _B6 * b6)
        x_new = x_end if hs == remaining else (x_stops[xi] if stop_hit else x + hs)
        a7, b7 = f(x_new, ya_new, yb_new)
        ea = hs * (_E1 * a1 + _E3 * a3 + _E4 * a4 + _E5 * a5 + _E6 * a6 + _E7 * a7)
        eb = hs * (_E1 * b1 + _E3 * b3 + _E4 * b4 + _E5 * b5 + _E6 * b6 + _E7 * b7)
        sa = atol_a + rtol * max(abs(ya), abs(ya_new))
        sb = atol_b + rtol * max(abs(yb), abs(yb_new))
        err = (0.5 * ((ea / sa) ** 2 + (eb / sb) ** 2)) ** 0.5
        if err != err or not (ya_new - ya_new == 0.0 and yb_new - yb_new == 0.0):  # NaN or inf
            h = hs * _MIN_FACTOR
            if h < 1e-12 * max(1.0, abs(x)):
                raise IntegrationError(f"non-finite derivative at x={x:.6g}, y=({ya:.6g}, {yb:.6g})")
            continue
        if err > 1.0:
            h = hs * max(_MIN_FACTOR, _SAFETY * err**-0.2)
            if h < 1e-12 * max(1.0, abs(x)):
                raise IntegrationError(f"step size underflow at x={x:.6g}, y=({ya:.6g}, {yb:.6g})")
            continue
        steps += 1
        h_next = hs * (min(_MAX_FACTOR, _SAFETY * err**-0.2) if err > 0 else _MAX_FACTOR)
        if h_next > max_step:
            h_next = max_step
        # events and ya-stops on the accepted step
        k = None
        cut_th, cut_tag, cut_terminal, cut_index = 2.0, None, False, -1
        new_vals = [ev.fn(x_new, ya_new, yb_new) for ev in events]
        for i, ev in enumerate(events):
            if ev_vals[i] < 0.0 <= new_vals[i]:
                if k is None:
                    k = (a1, a2, a3, a4, a5, a6, a7, b1, b2, b3, b4, b5, b6, b7)
                th = _locate(ev.fn, x, hs, ya, yb, k, 0.0, 1.0, ev_vals[i], new_vals[i])
                if th < cut_th:
                    cut_th, cut_tag, cut_terminal, cut_index = th, ev.tag, ev.terminal, i
        knot_cut = False
        if yi < ny and ya_new > ya_stops[yi]:
            if k is None:
                k = (a1, a2, a3, a4, a5, a6, a7, b1, b2, b3, b4, b5, b6, b7)
            target = ya_stops[yi]
            th = _locate(lambda _x, a, _b, _t=target: a - _t, x, hs, ya, yb, k, 0.0, 1.0, ya - target, ya_new - target)
            if th < cut_th:
                cut_th, knot_cut = th, True
        if (knot_cut or (cut_th <= 1.0 and not cut_terminal)) and not retried and 1e-6 < cut_th < 1.0 - 1e-9:
            # a kink of the right-hand side (knot, non-terminal event) inside the step: its stages saw
            # both sides, so its dense output is poor near the kink. Redo the step to end at the kink.
            forced_h = cut_th * hs
            h = h_next
            continue
        if cut_th > 1.0:
            if record is not None:
                record.add_rk(x, x_new, hs, ya, yb, (a1, a2, a3, a4, a5, a6, a7, b1, b2, b3, b4, b5, b6, b7), seg)
            if trace is not None:
                trace.append((x_new, ya_new, yb_new))
            x, ya, yb, fa, fb, ev_vals, h = x_new, ya_new, yb_new, a7, b7, new_vals, h_next
            if stop_hit:
                xi += 1
            continue
        # cut the step at theta = cut_th (dense output)
        assert k is not None
        x_cut = x + cut_th * hs if cut_th < 1.0 else x_new
        # the same polynomial evaluation as the root finder: the cut state satisfies the event
        ya_cut = _horner(ya, _coefficients(k, hs, 0), cut_th) if cut_th < 1.0 else ya_new
        yb_cut = _horner(yb, _coefficients(k, hs, 7), cut_th) if cut_th < 1.0 else yb_new
        if record is not None:
            record.add_rk(x, x_cut, hs, ya, yb, k, seg)
        knot_tag = None
        if knot_cut:
            ya_cut = ya_stops[yi]
            if ya_cut in ya_terminal:
                knot_tag = ("ya_stop", ya_cut)
        if trace is not None:
            trace.append((x_cut, ya_cut, yb_cut))
        if knot_cut:
            while yi < ny and ya_stops[yi] <= ya_cut:
                yi += 1
        x, ya, yb = x_cut, ya_cut, yb_cut
        fa, fb = f(x, ya, yb)
        h = max(h_next, hs * (1.0 - cut_th), 1e-9)
        if not knot_cut and cut_terminal:
            return Outcome(x, ya, yb, fa, fb, h, cut_tag, steps)
        if knot_tag is not None:
            return Outcome(x, ya, yb, fa, fb, h, knot_tag, steps)
        ev_vals = [ev.fn(x, ya, yb) for ev in events]
        if not knot_cut:
            # the non-terminal event fired: make sure it is not detected again at once
            ev_vals[cut_index] = max(ev_vals[cut_index], 0.0)
        while xi < nx and x_stops[xi] <= x + 1e-12 * max(1.0, abs(x)):
            xi += 1
