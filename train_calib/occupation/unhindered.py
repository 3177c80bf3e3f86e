"""Keep unhindered runs only: drop runs with unexpected stops or decelerations, recording why.

Besinovic et al. calibrate against unhindered trains only, so that parameter variation reflects
the train and its driver, not conflicts with other trains. From occupation data alone a hindrance
shows as a *valley* in the section mean speeds between two scheduled stops: the train slows down
well below what it did before and does again after, more than the reference (unhindered) speed
profile explains. Braking into a scheduled stop, coasting before it, or accelerating out of it is
monotone and is not a valley.

Per run, with v_i the mean head speed over section i (eq. 1) and v_ref,i a reference (the fleet
median per section, or a running-time model with default parameters):

    q_i = v_i / v_ref,i                     (ratio to the reference)
    valley: q_i^hi < (1 - dip) * min(max_{j<i} q_j^lo, max_{j>i} q_j^lo)   (j in the same leg)

where ^hi/^lo are the bounds allowed by the one-second rounding of the occupation times (so short
sections do not raise false alarms). A valley whose speed is below ``stop_speed_kmh`` is an
unexpected stop, else an unexpected deceleration. Data inconsistencies (too few events, gaps,
times going backwards, a release before its occupation) also reject a run, with the reason.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from ..params import ParamSet, param
from ..physics import KMH
from ..track import Section
from .events import RunEvents

ROUNDING_S = 1.0
"""Occupation times are whole seconds: a section time errs by up to this much either way."""


@dataclass(frozen=True)
class FilterConfig(ParamSet):
    """Thresholds of the unhindered-run filter."""

    dip: float = param(0.25, "relative speed drop that makes a valley (vs the higher of both sides)", low=0.0, high=1.0)
    stop_speed_kmh: float = param(
        20.0,
        "valley mean speed below which it is an unexpected stop (a stop in a ~300 m section leaves at most ~20 km/h)",
        unit="km/h",
        low=0.0,
    )
    min_occupations: int = param(5, "fewest occupation events a run needs", low=2)
    max_missing_share: float = param(
        0.1, "largest share of sections without occupation between the first and the last", low=0.0, high=1.0
    )


@dataclass
class SectionSpeeds:
    """Mean head speed per section of one run (eq. 1), NaN where unknown."""

    speed_ms: np.ndarray
    low_ms: np.ndarray  # with the section time 1 s longer
    high_ms: np.ndarray  # with the section time 1 s shorter (inf if that leaves <= 0 s)


@dataclass
class FilterResult:
    run_id: str
    reasons: list[str] = field(default_factory=list)

    @property
    def unhindered(self) -> bool:
        return not self.reasons


def section_speeds(run: RunEvents, sections: Sequence[Section]) -> SectionSpeeds:
    """v_i = (start_{i+1} - start_i) / (t_occ(i+1) - t_occ(i)) with its rounding bounds."""
    ids = [s.id for s in sections]
    starts = np.array([s.start_m for s in sections], dtype=float)
    occ = run.times("occupy", ids)
    n = len(ids)
    speed = np.full(n, np.nan)
    low = np.full(n, np.nan)
    high = np.full(n, np.nan)
    if n >= 2:
        dist = np.diff(starts)
        dt = np.diff(occ)
        with np.errstate(invalid="ignore", divide="ignore"):
            speed[:-1] = np.where(dt > 0, dist / dt, np.nan)
            low[:-1] = np.where(dt > 0, dist / (dt + ROUNDING_S), np.nan)
            high[:-1] = np.where(dt > ROUNDING_S, dist / (dt - ROUNDING_S), np.where(dt > 0, np.inf, np.nan))
    return SectionSpeeds(speed, low, high)


def fleet_reference(runs: Iterable[RunEvents], sections: Sequence[Section]) -> np.ndarray:
    """Median over runs of the section mean speeds (m/s), NaN where no run has one."""
    table = np.array([section_speeds(r, sections).speed_ms for r in runs])
    if table.size == 0:
        return np.full(len(sections), np.nan)
    out = np.full(len(sections), np.nan)
    known = np.isfinite(table).any(axis=0)
    out[known] = np.nanmedian(table[:, known], axis=0)
    return out


def profile_reference(time_at, sections: Sequence[Section]) -> np.ndarray:
    """Section mean speeds (m/s) of a reference head trajectory given as ``time_at(s_array)`` (s)."""
    starts = np.array([s.start_m for s in sections], dtype=float)
    t = np.asarray(time_at(starts), dtype=float)
    out = np.full(len(sections), np.nan)
    with np.errstate(invalid="ignore", divide="ignore"):
        out[:-1] = np.where(np.diff(t) > 0, np.diff(starts) / np.diff(t), np.nan)
    return out


def check_run(
    run: RunEvents,
    sections: Sequence[Section],
    stops_m: Sequence[float],
    reference_ms: np.ndarray | None,
    config: FilterConfig | None = None,
) -> FilterResult:
    """Why ``run`` is not usable for calibration (empty reasons: unhindered).

    ``stops_m``: scheduled stop positions (head, m); a section containing one is slow by design and
    separates legs. ``reference_ms``: reference mean speed per section (``fleet_reference`` or
    ``profile_reference``); without one only the data checks run.
    """
    cfg = config or FilterConfig()
    result = FilterResult(run.run_id)
    ids = [s.id for s in sections]
    occ = run.times("occupy", ids)
    rel = run.times("release", ids)
    have = np.nonzero(np.isfinite(occ))[0]
    if have.size < cfg.min_occupations:
        result.reasons.append(f"too few occupation events: {have.size} < {cfg.min_occupations}")
        return result
    first, last = int(have[0]), int(have[-1])
    span = last - first + 1
    missing = span - have.size
    if missing > cfg.max_missing_share * span:
        gap = [ids[i] for i in range(first, last + 1) if not np.isfinite(occ[i])]
        result.reasons.append(
            f"incomplete: {missing} of {span} sections without occupation ({', '.join(gap[:5])}"
            f"{', ...' if len(gap) > 5 else ''})"
        )
    seq = occ[have]
    back = np.nonzero(np.diff(seq) < 0)[0]
    if back.size:
        i = int(have[back[0] + 1])
        result.reasons.append(
            f"occupation times go backwards at section {ids[i]} ({seq[back[0] + 1]:g} s after {seq[back[0]]:g} s)"
        )
    bad_rel = np.nonzero(np.isfinite(occ) & np.isfinite(rel) & (rel < occ))[0]
    if bad_rel.size:
        i = int(bad_rel[0])
        result.reasons.append(f"release before occupation in section {ids[i]} ({rel[i]:g} s < {occ[i]:g} s)")
    if result.reasons or reference_ms is None:
        return result
    result.reasons.extend(_valleys(run, sections, stops_m, np.asarray(reference_ms, dtype=float), cfg))
    return result


def filter_runs(
    runs: Mapping[str, RunEvents],
    sections: Sequence[Section],
    stops_m: Sequence[float],
    reference_ms: np.ndarray | None,
    config: FilterConfig | None = None,
) -> tuple[list[str], dict[str, list[str]]]:
    """(ids of unhindered runs, {rejected id: reasons})."""
    kept, rejected = [], {}
    for run_id, run in runs.items():
        res = check_run(run, sections, stops_m, reference_ms, config)
        if res.unhindered:
            kept.append(run_id)
        else:
            rejected[run_id] = res.reasons
    return kept, rejected


def _valleys(
    run: RunEvents, sections: Sequence[Section], stops_m: Sequence[float], ref: np.ndarray, cfg: FilterConfig
) -> list[str]:
    sp = section_speeds(run, sections)
    starts = np.array([s.start_m for s in sections], dtype=float)
    nxt = np.append(starts[1:], np.inf)
    stops = np.asarray(sorted(stops_m), dtype=float)
    # section i spans [start_i, start_{i+1}) for the speed; it holds a stop if one lies inside
    holds_stop = np.array([np.any((stops >= a) & (stops < b)) for a, b in zip(starts, nxt)])
    leg = np.searchsorted(stops, starts, side="right")
    with np.errstate(invalid="ignore", divide="ignore"):
        q_lo = sp.low_ms / ref
        q_hi = sp.high_ms / ref
        q = sp.speed_ms / ref
    usable = np.isfinite(q_lo) & ~holds_stop
    reasons = []
    i_all = np.nonzero(usable)[0]
    flagged: list[int] = []
    for i in i_all:
        same = usable & (leg == leg[i])
        before = q_lo[:i][same[:i]]
        after = q_lo[i + 1 :][same[i + 1 :]]
        if before.size == 0 or after.size == 0:
            continue
        level = min(float(np.max(before)), float(np.max(after)))
        if q_hi[i] < (1.0 - cfg.dip) * level:
            flagged.append(int(i))
    # group consecutive flagged sections into one hindrance each
    groups: list[list[int]] = []
    for i in flagged:
        if groups and i - groups[-1][-1] == 1:
            groups[-1].append(i)
        else:
            groups.append([i])
    for g in groups:
        worst = min(g, key=lambda k: q[k])
        v_kmh = sp.speed_ms[worst] / KMH
        where = sections[g[0]].id if len(g) == 1 else f"{sections[g[0]].id}-{sections[g[-1]].id}"
        kind = "unexpected stop" if sp.high_ms[worst] < cfg.stop_speed_kmh * KMH else "unexpected deceleration"
        reasons.append(
            f"{kind} in section {where}: {v_kmh:.0f} km/h, {q[worst]:.0%} of the reference {ref[worst] / KMH:.0f} km/h"
        )
    return reasons
