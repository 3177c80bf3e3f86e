"""Coasting stretches from the measured speeds: the time form's detection, steps 1-4 of the coast regression.

docs/estimator.md, "Coast regression"; :mod:`coast_regression` gives the whole method. Here:

1. **Speed noise** sigma_v from the data (:func:`speed_noise`, :func:`noise_from_differences`).
2. **Local slope** of the measured speeds over a window W (:func:`local_slopes`, :func:`slope_window`).
3. **Coasting candidates** (:func:`candidate_steps`; its C kernel and :func:`candidate_steps_python`, the reference).
4. **Stretches**: runs of candidate steps, trimmed (:func:`stretch_bounds`, :func:`bounds_of`, :func:`detect`).

At 10 s sampling over changing gradients the energy form (:mod:`coast_energy`) detects instead.
"""

from __future__ import annotations

import itertools
import math

import numpy as np

from .coast_types import POWER_NONE, POWER_UNKNOWN, CoastSettings, RunArrays, davis_value

try:
    from . import _ukf_kernel  # the C kernel of candidate_steps (setup.py builds it where a C compiler is found)
except ImportError:  # pragma: no cover - built without a compiler: the numpy path
    _ukf_kernel = None

_F8, _I8, _I1 = np.dtype(np.float64), np.dtype(np.int64), np.dtype(np.int8)
_MIN_SPEED_NOISE = 0.002  # m/s: floor of the estimated speed noise


def median(x: np.ndarray) -> float:
    """``float(np.median(x))`` of a non-empty 1-D float array without np.median's generic machinery (a third of
    its cost on the speed-noise estimate's thousand differences): the same partition, the middle value or the two
    middle ones' mean as np.mean computes it, NaN when the array holds one."""
    n = x.size
    h = n // 2
    even = n % 2 == 0
    part = np.partition(x, [h - 1, h, -1] if even else [h, -1])
    if math.isnan(part[-1]):
        return math.nan
    # np.mean's sum starts from 0.0 (a -0.0 median reads 0.0)
    return float((0.0 + part[h - 1] + part[h]) / 2.0) if even else float(0.0 + part[h])


def noise_from_differences(d2: np.ndarray, d3: np.ndarray, quantum: float) -> float:
    """Speed noise std (m/s) from second and third differences of the moving speeds: the smaller of their MADs
    (scaled by sqrt(6), sqrt(20)) -- a changing acceleration inflates the second differences at 10 s sampling, the
    third cancel a steady change -- and at least the resolution / sqrt(12)."""
    mads = [median(np.abs(d)) / 0.6745 / math.sqrt(c) for d, c in ((d2, 6.0), (d3, 20.0)) if d.size]
    robust = min(mads) if mads else 0.0
    return max(robust, quantum / math.sqrt(12.0), _MIN_SPEED_NOISE)


def speed_noise(v: np.ndarray) -> float:
    """Std of the speed measurement noise (m/s) from the data while moving (> 5 m/s): noise_from_differences."""
    if v.size < 4:
        return 0.08
    dv = np.abs(np.diff(v))
    steps = dv[dv > 1e-4]
    quantum = float(np.min(steps)) if steps.size else 0.0
    d2 = (v[2:] - 2.0 * v[1:-1] + v[:-2])[v[1:-1] > 5.0]
    d3 = (v[3:] - 3.0 * v[2:-1] + 3.0 * v[1:-2] - v[:-3])[v[1:-2] > 5.0]
    return noise_from_differences(d2, d3, quantum)


def local_slopes(
    t: np.ndarray, v: np.ndarray, run: np.ndarray, window: float, period: float = 0.0
) -> tuple[np.ndarray, np.ndarray]:
    """Centred least-squares slope of v over [t - W/2, t + W/2] within the same run (m/s^2), and 1/sqrt(Sxx) (the
    slope's standard error per unit of speed noise); NaN where the window holds < 3 samples or its samples span
    less than min(0.8 W, W - 1.5 period) (a hole in the speeds, or the end of the data)."""
    n = t.size
    if n < 3:
        return np.full(n, np.nan), np.full(n, np.nan)
    tc = t - t[0]
    # a run's samples are contiguous: bound the window inside the run with the run's own index range
    key = run.astype(float) * 1e7 + tc  # runs are ordered in time; 1e7 s separates them
    lo = key.searchsorted(key - 0.5 * window - 1e-6, side="left")
    hi = key.searchsorted(key + 0.5 * window + 1e-6, side="right") - 1
    # prefix sums of (t, t^2, v, t v) from 0, one column each (a column's cumsum is the 1-D one, the same numbers)
    sums = np.empty((n + 1, 4))
    sums[0] = 0.0
    sums[1:, 0] = tc
    sums[1:, 1] = tc * tc
    sums[1:, 2] = v
    sums[1:, 3] = tc * v
    sums = sums.cumsum(axis=0)
    st, stt, sv, stv = (sums.take(hi + 1, 0) - sums.take(lo, 0)).T  # take: sums[hi + 1] - sums[lo], faster
    cnt = (hi - lo + 1).astype(float)
    sxx = stt - st * st / np.maximum(cnt, 1.0)
    ok = (cnt >= 3) & (tc.take(hi) - tc.take(lo) >= min(0.8 * window, window - 1.5 * period)) & (sxx > 0.0)
    a = np.divide(stv - st * sv / cnt, sxx, out=np.full(n, np.nan), where=ok)
    se = np.sqrt(sxx, out=np.full(n, np.nan), where=ok)
    return a, np.divide(1.0, se, out=se, where=ok)


def slope_window(settings: CoastSettings, sigma_v: float, period: float, prior: np.ndarray, v_max: float) -> float:
    """Window (s) whose slope standard error is coast_slope_precision of r(v_max / 2)."""
    r_ref = max(float(davis_value(prior, 0.5 * v_max)), 1e-4)
    w = (sigma_v * sigma_v * 12.0 * period / (settings.coast_slope_precision * r_ref) ** 2) ** (1.0 / 3.0)
    lower = max(settings.coast_window_min, settings.coast_window_samples * period)
    return float(min(max(w, lower), max(lower, 90.0)))  # np.clip's numbers on scalars


def candidate_steps(
    arr: RunArrays, settings: CoastSettings, prior: np.ndarray, sigma_v: float, window: float, period: float
) -> tuple[np.ndarray, np.ndarray]:
    """(speed steps, power steps): step i (sample i-1 to i) may be coasting, both ends candidates, same run, no gap.
    Speed steps: samples without a power measurement that pass the speed test (module docstring, step 3). Power
    steps: samples whose power shows neither traction nor regeneration (``power_decides``), with the apparent
    resistance not beyond 1.6 coast_ratio_max (a brake without electric braking). Samples whose power shows
    traction or electric braking are never candidates.

    In C where the package was built with a compiler (``_ukf_kernel.coast_candidates``: :func:`local_slopes` and
    :func:`candidate_steps_python` sample by sample, the same operations, the same booleans; the 236 detections of
    the 4 bench 1 Hz runs: 80 -> 8 us each), for float64 t, v, g, int64 run ids, int8 power states and run ids
    rising with t; else (and without the kernel) :func:`candidate_steps_python`."""
    t, v, g, run, power = arr.t, arr.v, arr.g, arr.run, arr.power
    if (
        _ukf_kernel is not None
        and t.dtype == _F8 and v.dtype == _F8 and g.dtype == _F8 and run.dtype == _I8
        and (power is None or power.dtype == _I1)
        and t.flags.c_contiguous and v.flags.c_contiguous and g.flags.c_contiguous and run.flags.c_contiguous
        and (power is None or power.flags.c_contiguous)
        and v.size == t.size and g.size == t.size and run.size == t.size and (power is None or power.size == t.size)
    ):  # fmt: skip
        n = t.size
        by_speed, by_power = np.empty(n, dtype=bool), np.empty(n, dtype=bool)
        r0, r1, r2 = (float(x) for x in prior)
        params = (float(window), min(0.8 * window, window - 1.5 * period), r0, r1, r2, settings.coast_ratio_min,
                  settings.coast_ratio_max, settings.coast_hold_sigmas, float(sigma_v), settings.coast_min_speed,
                  1.0 if settings.power_decides else 0.0, 1.6 * settings.coast_ratio_max,
                  min(settings.max_gap, 2.5 * period))  # fmt: skip
        if _ukf_kernel.coast_candidates(t, v, g, run, power, by_speed, by_power, params):
            return by_speed, by_power
    return candidate_steps_python(arr, settings, prior, sigma_v, window, period)


def candidate_steps_python(
    arr: RunArrays, settings: CoastSettings, prior: np.ndarray, sigma_v: float, window: float, period: float
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`candidate_steps` in numpy (the C kernel's reference)."""
    t, v = arr.t, arr.v
    a, se = local_slopes(t, v, arr.run, window, period)
    with np.errstate(invalid="ignore", divide="ignore"):
        ratio = -(a + arr.g) / np.maximum(davis_value(prior, v), 1e-6)
        moving = v >= settings.coast_min_speed
        by_speed = (
            (ratio >= settings.coast_ratio_min)
            & (ratio <= settings.coast_ratio_max)
            & (np.abs(a) >= settings.coast_hold_sigmas * se * sigma_v)
            & moving
            & np.isfinite(a)
        )
        by_power = None  # no power measured: no power steps
        if arr.power is not None and settings.power_decides:
            known = arr.power != POWER_UNKNOWN
            by_speed &= ~known
            by_power = (arr.power == POWER_NONE) & moving & ~(ratio > 1.6 * settings.coast_ratio_max)
    n = t.size
    joint = None  # per step i >= 1: samples i-1 and i in the same run, no gap between them
    if n > 1:
        joint = (arr.run[1:] == arr.run[:-1]) & (t[1:] - t[:-1] <= min(settings.max_gap, 2.5 * period))
    steps = []
    for cand in (by_speed, by_power):
        step = np.zeros(n, dtype=bool)
        if joint is not None and cand is not None:
            step[1:] = cand[1:] & cand[:-1] & joint
        steps.append(step)
    return steps[0], steps[1]


def stretch_bounds(
    arr: RunArrays, step: np.ndarray, trim: float, min_duration: float
) -> list[tuple[int, int, int, int]]:
    """(k0, k1, i, j) per stretch: samples k0..k1 after trimming; candidate steps i..j (untrimmed)."""
    t = arr.t
    out = []
    idx = step.nonzero()[0]
    if idx.size == 0:
        return out
    breaks = ((idx[1:] - idx[:-1]) > 1).nonzero()[0]
    starts = [int(idx[0]), *idx[breaks + 1].tolist()]
    ends = [*idx[breaks].tolist(), int(idx[-1])]
    tl = t.tolist()
    for i, j in zip(starts, ends):
        k0 = int(t.searchsorted(tl[i - 1] + trim - 1e-6))
        k1 = int(t.searchsorted(tl[j] - trim + 1e-6)) - 1
        if k1 > k0 and tl[k1] - tl[k0] >= min_duration:
            out.append((k0, k1, i, j))
    return out


def sample_period(t: np.ndarray) -> float:
    """Median sample interval (s) of the rising stamps; 1 s without one. The median of a Python sort (the same
    value as numpy's median, at a tenth of its cost on the few dozen samples a causal detection holds)."""
    d = t[1:] - t[:-1]
    d = sorted(d[d > 0.0].tolist())
    n = len(d)
    if not n:
        return 1.0
    return d[n // 2] if n % 2 else (d[n // 2 - 1] + d[n // 2]) / 2.0


def detect(
    arr: RunArrays, settings: CoastSettings, prior: np.ndarray, sigma_v: float | None = None
) -> tuple[list[tuple[int, int, int, int]], float, float]:
    """(stretch bounds, sigma_v, window) of the arrays."""
    sv = speed_noise(arr.v) if sigma_v is None else sigma_v
    period = sample_period(arr.t)
    v_max = float(np.max(arr.v)) if arr.v.size else 0.0
    window = slope_window(settings, sv, period, prior, v_max)
    by_speed, by_power = candidate_steps(arr, settings, prior, sv, window, period)
    return bounds_of(arr, by_speed, by_power, settings, window, period), sv, window


def bounds_of(
    arr: RunArrays, by_speed: np.ndarray, by_power: np.ndarray, settings: CoastSettings, window: float, period: float
) -> list[tuple[int, int, int, int]]:
    """The stretches of both kinds in time order: speed-detected ones trimmed by W/2 (the slope window smears a
    phase change over W/2; one period more was tried: tune half 1.9 -> 2.9 % median, less data), power-confirmed
    ones by one period (the power's own clock)."""
    min_duration = max(settings.coast_min_duration, 3.0 * period)
    bounds = stretch_bounds(arr, by_speed, 0.5 * window, min_duration)
    bounds += stretch_bounds(arr, by_power, period, min_duration)
    return sorted(bounds)


def monotonic_parts(arr: RunArrays) -> list[RunArrays]:
    """The arrays cut where the time does not increase (a clock reset, a repeated stamp): parts in which t rises."""
    cuts = np.flatnonzero(np.diff(arr.t) <= 0.0) + 1
    if cuts.size == 0:
        return [arr]
    edges = [0, *cuts.tolist(), arr.t.size]
    parts = []
    for a, b in itertools.pairwise(edges):
        if b - a >= 3:
            parts.append(arr.part(slice(a, b)))
    return parts
