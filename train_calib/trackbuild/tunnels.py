"""Tunnels from GNSS outages: stretches where the runs' fixes stop while the train moves on, in most runs.

Per run, an outage is a gap between consecutive fixes longer than ``gap_factor`` times the run's usual fix
interval (and at least ``min_gap_s``) during which the train moved (the speed topic goes on in a tunnel).
Where exactly the signal went is between the last fix and the one that did not come, so each run bounds
the tunnel's edges, in distance travelled by the recorded speed:

    start in [c(last fix), c(last fix) + distance over [t_last, t_last + dt]]
    end   in [c(next fix) - distance over [t_next - dt, t_next], c(next fix)]

(c: the fix's chainage on the averaged polyline, dt: the usual fix interval). Outages of the runs that
overlap form one candidate. Runs with different fix phases narrow the edges: each edge is the middle of
the intersection of the runs' bounds (of the union's middle quantiles when fix noise makes the bounds
disjoint), +- its width / sqrt(12). A candidate is a tunnel when it is seen in at least half the runs that
passed there with fixes on both sides (at least two; a single run is taken as it is), and its length is
plausible: ``min_length_m`` (100 m) to ``max_length_m`` (60 km). The others (a receiver's hiccup in one
run, a gap at a stop) are listed, not written.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .runs import RunData


@dataclass
class Outage:
    """One run's GNSS gap while moving, on the polyline's chainage (m)."""

    run: int
    start_lo_m: float  # the last fix before the gap
    start_hi_m: float  # where the next fix would have been
    end_lo_m: float  # where the fix before the next would have been
    end_hi_m: float  # the first fix after the gap

    @property
    def start_m(self) -> float:
        return 0.5 * (self.start_lo_m + self.start_hi_m)

    @property
    def end_m(self) -> float:
        return 0.5 * (self.end_lo_m + self.end_hi_m)


@dataclass
class TunnelResult:
    """Tunnels (chainage, m) with the runs that saw them, and the outages not taken, with why."""

    tunnels: list[tuple[float, float]] = field(default_factory=list)
    seen_by: list[int] = field(default_factory=list)  # runs showing each tunnel
    edge_sigma_m: list[float] = field(default_factory=list)  # 1-sigma of each tunnel's edges (the larger), m
    dropped: list[str] = field(default_factory=list)


def run_outages(
    run: RunData, chain_m: np.ndarray, index: int, gap_factor: float = 2.5, min_gap_s: float = 4.0
) -> list[Outage]:
    """The run's gaps between fixes longer than ``gap_factor`` fix intervals and ``min_gap_s``, while moving."""
    t = run.fix_t_ns.astype(float) * 1e-9
    if t.size < 3:
        return []
    dts = np.diff(t)
    dt = float(np.median(dts))
    # the speed integrated over time: distance (m) at any time, from the speed topic
    ts = run.speed_t_ns.astype(float) * 1e-9
    dist = np.concatenate(([0.0], np.cumsum(0.5 * (run.speed_ms[1:] + run.speed_ms[:-1]) * np.diff(ts))))

    def travelled(a: float, b: float) -> float:
        return float(np.interp(b, ts, dist) - np.interp(a, ts, dist))

    out = []
    for k in np.nonzero(dts > max(gap_factor * dt, min_gap_s))[0]:
        t0, t1 = t[k], t[k + 1]
        moved = travelled(t0, t1)
        if moved < 1.0 * (t1 - t0):  # slower than 1 m/s on average: standing, not driving through
            continue
        c0, c1 = float(chain_m[k]), float(chain_m[k + 1])
        out.append(Outage(index, c0, c0 + travelled(t0, t0 + dt), c1 - travelled(t1 - dt, t1), c1))
    return out


def _edge(lows: list[float], highs: list[float]) -> tuple[float, float]:
    """The middle of the intersection of [low, high] over the runs and its sd (uniform); if they do not
    intersect (fix noise), the middle of the interval between the median low and the median high."""
    lo, hi = max(lows), min(highs)
    if hi < lo:
        lo, hi = sorted((float(np.median(lows)), float(np.median(highs))))
    return 0.5 * (lo + hi), (hi - lo) / np.sqrt(12.0)


def find_tunnels(
    runs: list[RunData],
    chains_m: list[np.ndarray],
    *,
    min_length_m: float = 100.0,
    max_length_m: float = 60_000.0,
) -> TunnelResult:
    """Tunnels seen consistently across the runs (module doc); chainage on the averaged polyline, m."""
    outages = [o for k, (r, c) in enumerate(zip(runs, chains_m)) for o in run_outages(r, c, k)]
    outages.sort(key=lambda o: o.start_m)
    groups: list[list[Outage]] = []
    for o in outages:
        if groups and o.start_lo_m <= max(g.end_hi_m for g in groups[-1]):
            groups[-1].append(o)
        else:
            groups.append([o])
    result = TunnelResult()
    for g in groups:
        start, sd_start = _edge([o.start_lo_m for o in g], [o.start_hi_m for o in g])
        end, sd_end = _edge([o.end_lo_m for o in g], [o.end_hi_m for o in g])
        seen = len({o.run for o in g})
        passed = sum(  # runs with fixes before and after the stretch
            bool(np.any(c < start) and np.any(c > end)) for c in chains_m
        )
        needed = 1 if len(runs) == 1 else max(2, int(np.ceil(0.5 * passed)))
        where = f"GNSS outage at {start:.0f}-{end:.0f} m (chainage)"
        if seen < needed:
            result.dropped.append(f"{where}: in {seen} of {passed} runs, not a tunnel")
        elif not min_length_m <= end - start <= max_length_m:
            result.dropped.append(f"{where}: {end - start:.0f} m long, outside [{min_length_m:g}, {max_length_m:g}] m")
        else:
            result.tunnels.append((start, end))
            result.seen_by.append(seen)
            result.edge_sigma_m.append(float(max(sd_start, sd_end)))
    return result
