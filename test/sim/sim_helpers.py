"""Shared helpers of the simulator tests (a module, not a conftest: test dirs share one namespace)."""

from __future__ import annotations

import math
from functools import cache
from pathlib import Path

import numpy as np

from train_calib.paths import track_file, train_file
from train_calib.track import load_track
from train_calib.train import load_train

REPO = Path(__file__).resolve().parents[2]
TRACKS = ("intercity_32km", "tunnel_line_37km", "dense_corridor_14km")
TRAINS = ("virm6", "virm4", "virm10", "icrm")


@cache
def track(name: str):
    return load_track(track_file(name))


@cache
def train(name: str):
    return load_train(train_file(name))


def reference_run_time(trk, params, start_s: float, stop_s: float, ds: float = 1.0) -> float:
    """Independent fixed-step reference of Besinovic's minimum-time run: RK4 in w = v^2/2 over distance.

    Capped at the ceiling theta * limit-over-train and at the braking curves, built from the track's
    own functions (limit_over_train, track_force, tunnel_fraction) on a grid; t from the trapezoid in
    1/v, exact for uniform acceleration. Nothing of train_calib.sim is used.
    """
    n = math.ceil((stop_s - start_s) / ds)
    grid = np.linspace(start_s, stop_s, 2 * n + 1)  # nodes and midpoints
    h = (stop_s - start_s) / n
    L = params.length_m
    g = np.asarray(trk.track_force(grid, L))
    tun = np.asarray(trk.tunnel_fraction(grid, L))
    vmax = params.max_speed_kmh / 3.6 if params.max_speed_kmh > 0 else math.inf
    ceil = np.array([params.theta_cruise * min(trk.limit_over_train(float(x), L), vmax) for x in grid[::2]])
    # braking curves: head at each downward limit change, and the stop
    b = trk.speed_limit.breaks
    vals = trk.speed_limit.values
    targets = [
        (float(b[i]), params.theta_cruise * min(vals[i], vmax), params.b_limit)
        for i in range(1, len(b))
        if vals[i] < vals[i - 1] and start_s < b[i] < stop_s
    ]
    targets.append((stop_s, 0.0, params.b_stop))
    nodes = grid[::2]
    cap2 = ceil**2
    for p, vl, bb in targets:
        ahead = nodes < p
        cap2[ahead] = np.minimum(cap2[ahead], vl * vl + 2 * bb * (p - nodes[ahead]))
    cap2[-1] = 0.0

    def accel(w, k):  # k: index into grid
        v = math.sqrt(max(2.0 * w, 0.0))
        f = params.c0 + params.c1 * v
        if v > 0:
            f = min(f, params.c2 / v)
        if params.adhesive_mass_fraction > 0:
            f = min(
                f, (0.161 + 7.5 / (3.6 * v + 44.0)) * 9.81 * params.adhesive_mass_fraction / params.rotating_mass_factor
            )
        r = params.r0 + params.r1 * v + params.r2 * (1 + params.tunnel_factor * tun[k]) * v * v
        return f - r - g[k]

    w, t = 0.0, 0.0
    for i in range(n):
        k = 2 * i
        k1 = accel(w, k)
        k2 = accel(w + 0.5 * h * k1, k + 1)
        k3 = accel(w + 0.5 * h * k2, k + 1)
        k4 = accel(w + h * k3, k + 2)
        w_new = min(w + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4), 0.5 * cap2[i + 1])
        v0, v1 = math.sqrt(2 * w), math.sqrt(max(2 * w_new, 0.0))
        t += 2 * h / (v0 + v1) if v0 + v1 > 0 else 0.0
        w = w_new
    return t
