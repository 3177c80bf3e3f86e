"""The runs' fixes averaged into one polyline along the running direction, and the stops on it.

1. A reference from the first run: its moving fixes, median-filtered (5 fixes) against multipath, thinned to
   >= 20 m apart.
2. Every run's fixes projected on the reference (chainage c, m). A run whose chainage falls over time (a
   least-squares slope) was driven the other way: it is played backwards (``RunData.reversed_in_time``), so
   that every run runs the first one's way for the averaging, the stops and the tunnels.
3. East and north as functions of c by a local linear fit over a window of +-``window`` m (Gaussian weights),
   evaluated every ``spacing`` m; twice, the second time on the first result.
4. Chainage of the result = its chord lengths.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.ndimage import median_filter

from ..geodesy import LocalFrame
from .runs import RunData, stop_intervals

EXTRAPOLATION_BASE_M = 100.0  # the straight extension beyond the ends follows the last 100 m
MOVING_MS = 1.0  # fixes below this speed do not shape the reference (they cluster at stops)


@dataclass
class Polyline:
    """East/north vertices (m, local frame) and their chainage (m, from 0)."""

    en: np.ndarray  # (n, 2)

    @property
    def s(self) -> np.ndarray:
        return np.concatenate(([0.0], np.cumsum(np.hypot(*np.diff(self.en, axis=0).T))))

    def project(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Chainage (m) and signed cross-track distance (m, left positive) of each point's nearest polyline point."""
        a = self.en[:-1]
        d = np.diff(self.en, axis=0)
        len2 = np.maximum((d * d).sum(axis=1), 1e-12)
        s0 = self.s[:-1]
        seg_len = np.sqrt(len2)
        out_s = np.empty(len(points))
        out_x = np.empty(len(points))
        for k in range(0, len(points), 512):  # blocks: points x segments
            p = points[k : k + 512]
            rel = p[:, None, :] - a[None, :, :]
            t = np.clip((rel * d[None]).sum(axis=2) / len2[None], 0.0, 1.0)
            near = a[None] + t[..., None] * d[None]
            dist2 = ((p[:, None, :] - near) ** 2).sum(axis=2)
            i = np.argmin(dist2, axis=1)
            rows = np.arange(len(p))
            out_s[k : k + 512] = s0[i] + t[rows, i] * seg_len[i]
            cross = d[i, 0] * rel[rows, i, 1] - d[i, 1] * rel[rows, i, 0]
            out_x[k : k + 512] = np.sign(cross) * np.sqrt(dist2[rows, i])
        return out_s, out_x

    def at(self, s_m: np.ndarray) -> np.ndarray:
        """Points at chainage s (linear along the polyline, straight extrapolation beyond the ends), (n, 2) m."""
        s = self.s
        s_m = np.asarray(s_m, dtype=float)
        inside = np.stack([np.interp(s_m, s, self.en[:, 0]), np.interp(s_m, s, self.en[:, 1])], axis=1)
        k = min(int(np.searchsorted(s, EXTRAPOLATION_BASE_M)), s.size - 1)  # direction over the first/last 100 m
        j = max(int(np.searchsorted(s, s[-1] - EXTRAPOLATION_BASE_M)) - 1, 0)
        head = (self.en[k] - self.en[0]) / max(s[k] - s[0], 1e-9)
        tail = (self.en[-1] - self.en[j]) / max(s[-1] - s[j], 1e-9)
        before, after = s_m < 0.0, s_m > s[-1]
        inside[before] = self.en[0] + s_m[before, None] * head
        inside[after] = self.en[-1] + (s_m[after, None] - s[-1]) * tail
        return inside


def _thin(points: np.ndarray, min_step_m: float) -> np.ndarray:
    keep = [0]
    for i in range(1, len(points)):
        if np.hypot(*(points[i] - points[keep[-1]])) >= min_step_m:
            keep.append(i)
    return points[keep]


def reference(run: RunData, frame: LocalFrame) -> Polyline:
    """The first run's moving fixes, median-filtered over 5 fixes and thinned to >= 20 m."""
    en = run.enu(frame)
    moving = run.speed_at(run.fix_t_ns) >= MOVING_MS
    pts = en[moving] if moving.sum() >= 3 else en
    pts = np.stack([median_filter(pts[:, 0], 5, mode="nearest"), median_filter(pts[:, 1], 5, mode="nearest")], 1)
    pts = _thin(pts, 20.0)
    if len(pts) < 2:
        raise ValueError(f"{run.source}: the fixes do not move (a track needs a run along it)")
    return Polyline(pts)


def smooth(chainage: np.ndarray, en: np.ndarray, window_m: float, spacing_m: float) -> Polyline:
    """Local linear fit of east and north against chainage (Gaussian weights, sigma window/2) every spacing m."""
    lo, hi = float(np.min(chainage)), float(np.max(chainage))
    grid = np.linspace(lo, hi, max(int(np.ceil((hi - lo) / spacing_m)) + 1, 2))
    order = np.argsort(chainage)
    c, p = chainage[order], en[order]
    out = np.empty((grid.size, 2))
    supported = np.zeros(grid.size, dtype=bool)
    sigma = window_m / 2.0
    for k, g in enumerate(grid):
        i0, i1 = np.searchsorted(c, [g - 2 * window_m, g + 2 * window_m])
        cc, pp = c[i0:i1] - g, p[i0:i1]
        # a fit needs points on both sides within the window; elsewhere (GNSS gaps: tunnels) interpolate below
        supported[k] = bool(np.any((cc <= 0) & (cc >= -window_m)) and np.any((cc >= 0) & (cc <= window_m)))
        supported[k] |= k in (0, grid.size - 1) and cc.size >= 2  # the ends: a one-sided fit
        if not supported[k] or cc.size < 2:
            supported[k] = False
            continue
        w = np.exp(-0.5 * (cc / sigma) ** 2) + 1e-12
        a = np.stack([np.ones_like(cc), cc], axis=1) * np.sqrt(w)[:, None]
        coef, *_ = np.linalg.lstsq(a, pp * np.sqrt(w)[:, None], rcond=None)
        out[k] = coef[0]
    for end, point in ((0, p[0]), (-1, p[-1])):
        if not supported[end]:
            supported[end], out[end] = True, point
    for j in (0, 1):
        out[~supported, j] = np.interp(grid[~supported], grid[supported], out[supported, j])
    return Polyline(out)


@dataclass
class AveragedGeometry:
    """The averaged polyline, each run's fix chainage on it, and the stops (chainage, m) found in the runs."""

    polyline: Polyline
    frame: LocalFrame
    fix_chainage: list[np.ndarray]  # per run (as in ``runs``), m
    stops_m: np.ndarray
    stops_per_run: list[int]
    cross_track_rms_m: float
    window_m: float
    runs: list[RunData]  # the runs, those driven the other way played backwards
    reversed_runs: list[int]  # indices of those


def average_runs(runs: list[RunData], spacing_m: float = 25.0) -> AveragedGeometry:
    """One polyline from every run's fixes (see the module doc)."""
    frame = LocalFrame(float(np.median(runs[0].lat)), float(np.median(runs[0].lon)))
    ref = reference(runs[0], frame)
    runs, flipped = list(runs), []
    for k in range(1, len(runs)):  # a run driven the other way: its fixes' chainage falls over time
        c, _ = ref.project(runs[k].enu(frame))
        if np.polyfit(runs[k].fix_t_ns.astype(float) * 1e-9, c, 1)[0] < 0:
            runs[k] = runs[k].reversed_in_time()
            flipped.append(k)
    pts = [r.enu(frame) for r in runs]
    spacing = np.median(np.concatenate([np.hypot(*np.diff(p, axis=0).T) for p in pts]))
    window = float(max(60.0, 2.0 * spacing / np.sqrt(len(runs))))
    poly = ref
    keep = np.ones(sum(len(p) for p in pts), dtype=bool)
    for _ in range(3):
        chain, cross = zip(*(poly.project(p) for p in pts))
        offset = np.abs(np.concatenate(cross))
        keep = offset <= max(10.0, 4.0 * 1.4826 * float(np.median(offset)))  # multipath outliers out
        poly = smooth(np.concatenate(chain)[keep], np.concatenate(pts)[keep], window, spacing_m)
    chain, cross = zip(*(poly.project(p) for p in pts))
    rms = float(np.sqrt(np.median(np.concatenate(cross) ** 2)))
    stops, counts = find_stops(runs, list(chain))
    return AveragedGeometry(poly, frame, list(chain), stops, counts, rms, window, runs, flipped)


def find_stops(runs: list[RunData], chain: list[np.ndarray], merge_m: float = 150.0) -> tuple[np.ndarray, list[int]]:
    """Chainage of the standstills of every run (fix chainage interpolated to the standstill's middle time),
    merged across runs within ``merge_m`` (median); with the count per run."""
    found: list[float] = []
    counts: list[int] = []
    for run, c in zip(runs, chain):
        c_mono = np.maximum.accumulate(median_filter(c, 5, mode="nearest"))
        t = run.fix_t_ns.astype(float)
        mids = [0.5 * (a + b) for a, b in stop_intervals(run)]
        found += [float(np.interp(m, t, c_mono)) for m in mids]
        counts.append(len(mids))
    found.sort()
    clusters: list[list[float]] = []
    for s in found:
        if clusters and s - clusters[-1][-1] <= merge_m:
            clusters[-1].append(s)
        else:
            clusters.append([s])
    return np.array([float(np.median(c)) for c in clusters]), counts
