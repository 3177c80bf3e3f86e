"""Coasting predictions: from (s, v) with u = 0 along the track, speed and time at given positions, with sigma.

Per unit effective mass (N/kg = m/s^2), over distance, with w = v^2 / 2 (m^2/s^2):

    dw/ds = -(r0 + r1 v + (1 + f_tun tunnel(s)) r2 v^2) - g(s)

g(s) is the track force over the train length (:class:`train_calib.sim.model.TrackTerms`: exact, piecewise linear),
so its integral G(s) is exact and piecewise quadratic. The integrator carries W = w + G(s) (dW/ds = -r(v), smooth:
no kink of g lands inside a step's error) with classical RK4 on a grid whose nodes include every target, and the
time t = int ds / v with Simpson's rule on the same grid (midpoint speed from the step's Hermite interpolant).
Every lane (a sigma point, a model) runs in one numpy array. A lane whose speed falls to ``V_STOP_MS`` has stopped:
its speed is 0 from there on and its time NaN (it never reaches the target).

Sigma: the unscented (cubature) transform over (v0, r0, r1, r2) with the 4x4 covariance of the published estimate
(rows/columns v, r0, r1, r2 of its 5x5): 2n points at +-sqrt(n) times the covariance's square root, the mean
prediction from the centre point, the sigma as the points' spread (``test/prediction`` checks it against Monte Carlo).
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import numpy as np

from ..sim.model import TrackTerms

V_STOP_MS = 0.3
"""Speed (m/s) below which a coasting lane counts as stopped."""


class GradientIntegral:
    """G(s) = integral of g from 0 to s (N/kg m = m^2/s^2) of a TrackTerms' piecewise-linear g, exact."""

    def __init__(self, terms: TrackTerms) -> None:
        self.terms = terms
        k, g = terms.knots, terms.g
        dk = np.diff(k)
        self._k = k
        self._g = g
        self._slope = np.append(np.diff(g) / np.where(dk > 0, dk, 1.0), 0.0)
        self._cum = np.concatenate(([0.0], np.cumsum(0.5 * (g[:-1] + g[1:]) * dk)))

    def __call__(self, s_m: np.ndarray) -> np.ndarray:
        s = np.asarray(s_m, dtype=float)
        i = np.clip(np.searchsorted(self._k, s, side="right") - 1, 0, self._k.size - 1)
        x = s - self._k[i]
        below = s < self._k[0]  # constant g before the first knot and after the last
        out = self._cum[i] + self._g[i] * x + 0.5 * self._slope[i] * x * x
        return np.where(below, self._g[0] * (s - self._k[0]), out)


@dataclass
class CoastResult:
    """Per lane and target: speed (m/s; 0 once stopped) and time from the start (s; NaN if it stopped before)."""

    v_ms: np.ndarray  # (lanes, targets)
    t_s: np.ndarray  # (lanes, targets)


def grid(s0_m: float, targets_m: np.ndarray, ds_max_m: float, max_steps: int) -> tuple[np.ndarray, np.ndarray]:
    """Nodes from s0 to the last target with every target a node, steps <= ds_max (coarser beyond max_steps);
    returns (nodes, index of each target among the nodes)."""
    ends = np.concatenate(([s0_m], np.asarray(targets_m, dtype=float)))
    total = ends[-1] - s0_m
    ds = max(ds_max_m, total / max(max_steps, 1))
    nodes = [np.array([s0_m])]
    for a, b in itertools.pairwise(ends):
        n = max(math.ceil((b - a) / ds), 1) if b > a else 0
        if n:
            nodes.append(a + (b - a) * np.arange(1, n + 1) / n)
    x = np.concatenate(nodes)
    idx = np.searchsorted(x, np.asarray(targets_m, dtype=float) - 1e-9)
    return x, np.minimum(idx, x.size - 1)


def coast(
    terms: TrackTerms,
    G: GradientIntegral,
    s0_m: float,
    v0_ms: np.ndarray,
    r: np.ndarray,
    targets_m: np.ndarray,
    *,
    tunnel_factor: float = 0.0,
    ds_max_m: float = 400.0,
    max_steps: int = 60,
) -> CoastResult:
    """Coast every lane (v0 (lanes,), r (lanes, 3) = r0, r1, r2) from s0 to each target (sorted, >= s0)."""
    v0 = np.asarray(v0_ms, dtype=float)
    r = np.asarray(r, dtype=float)
    targets = np.asarray(targets_m, dtype=float)
    lanes = v0.size
    if targets.size == 0:
        return CoastResult(np.zeros((lanes, 0)), np.zeros((lanes, 0)))
    x, tidx = grid(s0_m, targets, ds_max_m, max_steps)
    h = np.diff(x)
    mid = x[:-1] + 0.5 * h
    Gx, Gm = G(x), G(mid)
    if tunnel_factor > 0.0:
        kx = 1.0 + tunnel_factor * terms.tunnel_vec(x)
        km = 1.0 + tunnel_factor * terms.tunnel_vec(mid)
    else:
        kx = np.ones_like(x)
        km = np.ones_like(mid)
    nr0, r1, r2 = -r[:, 0], r[:, 1], r[:, 2]
    G2x, G2m = (2.0 * Gx).tolist(), (2.0 * Gm).tolist()
    kx_l, km_l, h_l = kx.tolist(), km.tolist(), h.tolist()
    n = x.size
    W = np.empty((n, lanes))
    V = np.zeros((n, lanes))
    T = np.zeros((n, lanes))
    w0 = 0.5 * v0 * v0
    W[0] = w0 + Gx[0]
    V[0] = v0
    alive = v0 > V_STOP_MS
    sqrt, maximum = np.sqrt, np.maximum
    tiny = V_STOP_MS * V_STOP_MS

    def rate(Wv: np.ndarray, G2: float, k: float) -> tuple[np.ndarray, np.ndarray]:
        v = sqrt(maximum(Wv + Wv - G2, tiny))
        return nr0 - v * (r1 + k * r2 * v) if k != 1.0 else nr0 - v * (r1 + r2 * v), v

    f0, v_a = rate(W[0], G2x[0], kx_l[0])
    with np.errstate(divide="ignore", invalid="ignore"):
        for i in range(n - 1):
            hi, Wi = h_l[i], W[i]
            hh = 0.5 * hi
            k2, _ = rate(Wi + hh * f0, G2m[i], km_l[i])
            k3, _ = rate(Wi + hh * k2, G2m[i], km_l[i])
            k4, _ = rate(Wi + hi * k3, G2x[i + 1], kx_l[i + 1])
            Wn = Wi + hi / 6.0 * (f0 + 2.0 * (k2 + k3) + k4)
            f1, v_b = rate(Wn, G2x[i + 1], kx_l[i + 1])
            W_mid = 0.5 * (Wi + Wn) + hi / 8.0 * (f0 - f1)
            v_m = sqrt(maximum(W_mid + W_mid - G2m[i], 0.0))
            alive = alive & (Wn + Wn - G2x[i + 1] > tiny) & (v_m > V_STOP_MS)
            T[i + 1] = np.where(alive, T[i] + hi / 6.0 * (1.0 / v_a + 4.0 / v_m + 1.0 / v_b), np.nan)
            V[i + 1] = np.where(alive, v_b, 0.0)
            W[i + 1] = Wn
            f0, v_a = f1, v_b
            if not alive.any():  # every lane has stopped: the rest is v = 0, t NaN
                V[i + 2 :] = 0.0
                T[i + 2 :] = np.nan
                break
    return CoastResult(V[tidx].T.copy(), T[tidx].T.copy())


def sigma_points(mean: np.ndarray, covariance: np.ndarray) -> np.ndarray:
    """(2n + 1, n): the mean, then mean +- sqrt(n) columns of the covariance's symmetric square root."""
    mean = np.asarray(mean, dtype=float)
    n = mean.size
    w, U = np.linalg.eigh(0.5 * (covariance + covariance.T))
    root = U * np.sqrt(np.maximum(w, 0.0)) @ U.T * math.sqrt(n)
    return np.vstack([mean, mean + root, mean - root])


def spread(values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(centre, sigma) over axis 0 of sigma-point results (2n + 1 rows, the centre first); NaN where any is NaN."""
    centre = values[0]
    pts = values[1:]
    sigma = np.sqrt(np.mean((pts - pts.mean(axis=0)) ** 2, axis=0))
    return centre, sigma


def coast_with_sigma(
    terms: TrackTerms,
    G: GradientIntegral,
    s0_m: float,
    models: list[tuple[np.ndarray, np.ndarray]],
    targets_m: np.ndarray,
    *,
    tunnel_factor: float = 0.0,
    ds_max_m: float = 400.0,
    max_steps: int = 60,
) -> list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]]:
    """For each model (mean (v0, r0, r1, r2), 4x4 covariance): (v, v_sigma, t, t_sigma) per target; all models'
    sigma points integrate as lanes of one array."""
    pts = [sigma_points(m, P) for m, P in models]
    sizes = [p.shape[0] for p in pts]
    allp = np.vstack(pts)
    res = coast(terms, G, s0_m, allp[:, 0], allp[:, 1:], targets_m, tunnel_factor=tunnel_factor,
                ds_max_m=ds_max_m, max_steps=max_steps)  # fmt: skip
    out = []
    start = 0
    for n in sizes:
        v, vs = spread(res.v_ms[start : start + n])
        t, ts = spread(res.t_s[start : start + n])
        out.append((v, vs, t, ts))
        start += n
    return out
