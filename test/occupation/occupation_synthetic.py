"""Closed-form kinematic trajectories for the occupation tests, independent of train_calib.sim.

``kinematic_run`` is the classic minimum of a forward pass (constant acceleration a) and a backward
pass (constant braking b) under a speed cap, on a 1 m grid; each grid step is uniformly
accelerated, so dt = 2 ds / (v_i + v_i+1) is exact and t(s) is the exact time of that motion.
"""

from __future__ import annotations

import numpy as np

from train_calib.track import Section


def kinematic_run(
    length_m: float,
    cap_ms,
    *,
    accel: float = 0.5,
    brake: float = 0.5,
    ds: float = 1.0,
    dwell: tuple[float, float] | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(t, s, v) of a run from standstill at 0 to standstill at ``length_m``.

    ``cap_ms``: speed cap, a number or a function of s (m/s). ``dwell``: (s_m, seconds) an extra
    stop of that duration at s_m (the cap there is brought to 0 and the time is added).
    """
    s = np.arange(0.0, length_m + ds / 2, ds)
    cap = np.full(s.shape, float(cap_ms)) if np.isscalar(cap_ms) else np.asarray(cap_ms(s), dtype=float)
    cap[0] = cap[-1] = 0.0
    if dwell is not None:
        cap[np.argmin(np.abs(s - dwell[0]))] = 0.0
    v = cap.copy()
    for i in range(1, s.size):  # forward: accelerate
        v[i] = min(v[i], np.sqrt(v[i - 1] ** 2 + 2 * accel * ds))
    for i in range(s.size - 2, -1, -1):  # backward: brake
        v[i] = min(v[i], np.sqrt(v[i + 1] ** 2 + 2 * brake * ds))
    dt = 2 * ds / (v[:-1] + v[1:])
    t = np.concatenate(([0.0], np.cumsum(dt)))
    if dwell is not None:
        t[s > dwell[0]] += dwell[1]
    return t, s, v


def even_sections(length_m: float, n: int, prefix: str = "S") -> list[Section]:
    """n contiguous sections of equal length covering [0, length_m]."""
    edges = np.linspace(0.0, length_m, n + 1)
    return [Section(f"{prefix}{k:02d}", float(edges[k]), float(edges[k + 1])) for k in range(n)]
