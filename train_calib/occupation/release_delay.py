"""The release delay of the track-detection installation, estimated from the occupation data themselves.

A track circuit or axle counter reports a section free some time d after the tail has left it (relay
drop-out, evaluation: typically 0.3-1.5 s). At the joint x between sections s_i and s_i+1 the logged gap is

    g = t_rel(s_i) - t_occ(s_i+1) = L u + d,      u: the head's mean slowness (s/m) over [x, x + L]

One run at one speed cannot tell the length L from d (a longer train and a later release look the same).
Two things can: joints passed at different speeds (L u scales with the slowness, d does not), and the
lengths the train may have (the compositions of TYPES.yaml: a run is one of them). Both enter one fit:

    d = argmin over d of  F(d) = sum over runs r of  min over compositions c of  sum_j rho((g_rj - L_c u_rj - d) / s_rj)

rho is Huber's loss; s_rj combines the noise of the times (``noise_s``: the one-second rounding of both
times and the spread of the delay itself) with the error of u at the joint. u at x + L/2 is interpolated
linearly between the mean slownesses of the section behind and the section ahead (their midpoints); while
the train accelerates or brakes that is uncertain, so s_rj grows with the change of slowness across the
joint, L |u_ahead - u_behind|. Joints without a section behind in the same leg (the first after a
stop: the train starts from standstill there) are not used. F is evaluated on a grid of d (0.01 s) and
refined by a parabola through the minimum.

Uncertainty: the jackknife over runs (it sees the differences between runs, not only the scatter of the
joints), at least the formal sigma from F's curvature. The delay is *separable* when there are joints of
at least ``min_runs`` runs, that uncertainty is at most ``max_std_s`` (0.2 s), and no other delay fits
almost as well: at one speed, d and d + (L_c - L_c') / v fit equally (a VIRM6 late by d looks like a
VIRM4 late by d + 1.35 s at 40 m/s); a second minimum of F further than 0.3 s away and within
``ALIAS_MARGIN`` (4.5, a likelihood ratio of 3 sigma) of the best says so. Not separable: no offset is
applied, and the reason says why.

One delay for the whole installation: an events file carries no detector type, and the delay belongs to
the kind of detector, not to the train. Whether the data say otherwise is checked: per released section
the mean residual over the runs against its standard error (a chi-square test of one common delay,
``common_delay_p``) and their spread (``section_spread_s``); both over their thresholds, ``sections_differ`` and the
reason say so, and the sections whose releases come systematically later or earlier show in ``sections``.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, field

import numpy as np
from scipy import stats

from ..track import Section
from .events import RunEvents
from .length import JOINT_TOLERANCE_M

MAX_STD_S = 0.2
"""Largest uncertainty (s, 1 sigma) at which the delay counts as separable from the lengths."""

GRID_S = (-1.0, 4.0, 0.01)
"""The delays tried (s): from, to, step. A release cannot come early; a negative fit says something is off."""

MAX_APPLIED_S = 4.0
"""Applied offsets are clipped to [0, MAX_APPLIED_S] s."""

HUBER_K = 1.5
"""Huber's tuning constant, in standard deviations of a joint."""

NOISE_S = 0.5
"""Noise of one gap (s): two times rounded down to the second (0.41 s) and the delay's own spread."""

ALIAS_MARGIN = 4.5
"""A second minimum of F within this much of the best (half a chi-square of 9: 3 sigma) is an alias."""

DIFFER_P = 1e-3
"""One delay for every section is rejected below this chi-square p-value ..."""

DIFFER_SPREAD_S = 0.3
"""... and when the sections' mean residuals spread by more than this (s, std). Measured on simulated fleets with
one delay: 0.05-0.24 s (the slowness interpolation's own error at sections near stations; p down to 4e-5); with
releases 1 s later on every other section: 0.35-0.54 s (p 1e-5 to 3e-17); Vasteras and the 12 km test line."""

MODEL_ERROR_FACTOR = 1.0
"""The error of the interpolated slowness at a joint, times L |u_ahead - u_behind|, in s."""


@dataclass
class RunJoints:
    """The joints of one run usable for the delay (arrays over the joints)."""

    run_id: str
    joint_m: np.ndarray  # x, m
    section_ids: list[str]  # s_i, the section released at the joint
    gap_s: np.ndarray  # t_rel(s_i) - t_occ(s_i+1), s
    slowness_behind: np.ndarray  # mean slowness over s_i, s/m
    slowness_ahead: np.ndarray  # mean slowness over s_i+1, s/m
    mid_behind_m: np.ndarray  # midpoint of s_i, m
    mid_ahead_m: np.ndarray  # midpoint of s_i+1, m

    def slowness(self, length_m: float) -> np.ndarray:
        """Slowness (s/m) at x + L/2, linear between the sections' midpoints (constant beyond)."""
        frac = np.clip(
            (self.joint_m + 0.5 * length_m - self.mid_behind_m) / (self.mid_ahead_m - self.mid_behind_m), 0, 1
        )
        return self.slowness_behind + frac * (self.slowness_ahead - self.slowness_behind)

    def sigma(self, length_m: float, noise_s: float = NOISE_S) -> np.ndarray:
        """Standard deviation (s) of each gap about L u + d: time noise and the slowness' uncertainty."""
        model = MODEL_ERROR_FACTOR * length_m * np.abs(self.slowness_ahead - self.slowness_behind)
        return np.sqrt(noise_s**2 + model**2)


@dataclass
class ReleaseDelay:
    """The estimated release delay and how well the data determine it (all times in s)."""

    delay_s: float  # the fitted d (NaN without data)
    std_s: float  # its uncertainty, 1 sigma: max of the jackknife over runs and the formal one
    separable: bool  # the data tell the delay from the lengths
    applied_s: float  # the offset used: clip(delay, 0, MAX_APPLIED_S) if separable, else 0
    reason: str  # one line: what was found, or why the delay cannot be separated
    n_runs: int
    n_joints: int
    formal_std_s: float  # from the curvature of F
    jackknife_std_s: float  # over runs (NaN with fewer than 3 runs)
    alias_delay_s: float  # the second-best minimum of F (NaN if none)
    alias_cost: float  # F there minus F at the best (inf if none)
    residual_std_s: float  # robust scale of the joints' residuals at the best delay
    speed_spread: float  # relative spread (std / mean) of the joints' slowness within the runs
    sections: dict[str, dict[str, float]] = field(default_factory=dict)  # section -> mean residual, its std, n
    common_delay_p: float = float("nan")  # chi-square p-value of one delay for every section
    section_spread_s: float = float("nan")  # std of the sections' mean residuals (sections with >= 3 joints), s
    sections_differ: bool = False  # common_delay_p < DIFFER_P and section_spread_s > DIFFER_SPREAD_S

    def as_dict(self) -> dict:
        return asdict(self)


def run_joints(run: RunEvents, sections: Sequence[Section], stops_m: Sequence[float]) -> RunJoints:
    """The joints of one run with a release behind, an occupation ahead and sections on both sides in one leg."""
    ids = [s.id for s in sections]
    starts = np.array([s.start_m for s in sections], dtype=float)
    ends = np.array([s.end_m for s in sections], dtype=float)
    occ = run.times("occupy", ids)
    rel = run.times("release", ids)
    stops = np.sort(np.asarray(stops_m, dtype=float))
    leg = np.searchsorted(stops, starts, side="right")  # a section starting at a stop is in the leg after it
    n = len(ids)
    i = np.arange(max(n - 2, 0))  # the joint s_i | s_i+1 needs occupations of s_i, s_i+1 and s_i+2
    ok = (np.abs(starts[i + 1] - ends[i]) <= JOINT_TOLERANCE_M) & (
        np.abs(starts[i + 2] - ends[i + 1]) <= JOINT_TOLERANCE_M
    )
    ok &= (leg[i] == leg[i + 1]) & (leg[i + 1] == leg[i + 2])
    t_b, t_j, t_a = occ[i], occ[i + 1], occ[i + 2]
    gap = rel[i] - t_j
    with np.errstate(invalid="ignore"):
        ok &= np.isfinite(t_b) & np.isfinite(t_j) & np.isfinite(t_a) & np.isfinite(gap)
        ok &= (t_j > t_b) & (t_a > t_j) & (gap > 0)
    k = i[ok]
    return RunJoints(
        run_id=run.run_id,
        joint_m=starts[k + 1],
        section_ids=[ids[m] for m in k],
        gap_s=gap[ok],
        slowness_behind=(occ[k + 1] - occ[k]) / (starts[k + 1] - starts[k]),
        slowness_ahead=(occ[k + 2] - occ[k + 1]) / (starts[k + 2] - starts[k + 1]),
        mid_behind_m=0.5 * (starts[k] + starts[k + 1]),
        mid_ahead_m=0.5 * (starts[k + 1] + starts[k + 2]),
    )


def estimate_release_delay(
    runs: Mapping[str, RunEvents],
    sections: Sequence[Section],
    stops_m: Sequence[float],
    lengths_m: Mapping[str, float],
    *,
    max_std_s: float = MAX_STD_S,
    min_runs: int = 3,
    noise_s: float = NOISE_S,
) -> ReleaseDelay:
    """One release delay for the installation from every run's joints (module docstring).

    ``lengths_m``: composition name -> length (m), the lengths a run may have.
    """
    data = [run_joints(runs[r], sections, stops_m) for r in runs]
    data = [j for j in data if j.gap_s.size > 0]
    lengths = np.array([float(v) for v in lengths_m.values()])
    if not data or lengths.size == 0:
        return _unusable("no joint with a release behind and occupations on both sides within one leg")
    grid = np.arange(GRID_S[0], GRID_S[1] + 1e-9, GRID_S[2])
    costs = np.array([_run_cost(j, lengths, grid, noise_s)[0] for j in data])  # runs x grid
    total = costs.sum(axis=0)
    best, delay = _minimum(total, grid)
    curvature = _curvature(total, best, GRID_S[2])
    formal = 1.0 / np.sqrt(curvature) if curvature > 0 else float("inf")
    jack = float("nan")
    if len(data) >= 3:
        ds = np.array([_minimum(total - c, grid)[1] for c in costs])
        jack = float(np.sqrt((ds.size - 1) / ds.size * np.sum((ds - ds.mean()) ** 2)))
    std = float(np.nanmax([formal, jack]))
    alias_d, alias_cost = _alias(total, grid, best)

    resid, per_joint_sid, spreads = [], [], []
    for j in data:
        _, choice = _run_cost(j, lengths, np.array([delay]), noise_s)
        length = lengths[choice[0]]
        r = (j.gap_s - length * j.slowness(length) - delay) / j.sigma(length, noise_s) * noise_s
        resid.append(r)
        per_joint_sid.extend(j.section_ids)
        u = j.slowness(length)
        if u.size >= 2:
            spreads.append(float(np.std(u) / np.mean(u)))
    all_resid = np.concatenate(resid)
    scale = float(1.4826 * np.median(np.abs(all_resid - np.median(all_resid))))
    per_section, p_common = _per_section(per_joint_sid, all_resid, scale)
    means = [v["mean_residual_s"] for v in per_section.values() if v["n"] >= 3]
    spread_s = float(np.std(means)) if len(means) >= 2 else float("nan")
    n_joints = int(all_resid.size)
    if np.isfinite(scale) and scale > noise_s:  # noisier than assumed: the formal sigma grows with it
        formal *= scale / noise_s
        std = float(np.nanmax([formal, jack]))
    spread = float(np.median(spreads)) if spreads else 0.0

    speeds = f"the joints' speeds vary by {100 * spread:.1f} % within a run" if spreads else "one usable joint per run"
    if len(data) < min_runs:
        separable, why = False, f"joints of {len(data)} run(s) only, fewer than {min_runs}"
    elif np.isfinite(alias_cost) and alias_cost < ALIAS_MARGIN:
        separable = False
        why = (
            f"{alias_d:.2f} s fits almost as well as {delay:.2f} s (another composition length at another delay: "
            f"{speeds})"
        )
    elif std > max_std_s:
        separable = False
        why = f"uncertainty {std:.2f} s is over {max_std_s:g} s ({speeds})"
    else:
        separable, why = True, ""
    applied = float(np.clip(delay, 0.0, MAX_APPLIED_S)) if separable else 0.0
    differ = bool(np.isfinite(p_common) and p_common < DIFFER_P and spread_s > DIFFER_SPREAD_S)
    if separable:
        reason = f"release delay {delay:.2f} +- {std:.2f} s from {n_joints} joints of {len(data)} runs"
        if differ:
            reason += (
                f" (the sections' delays differ: their mean residuals spread by {spread_s:.2f} s; "
                "release_delay.sections in summary.json)"
            )
    else:
        reason = f"release delay not separable from the train lengths: {why}; no offset applied"
    return ReleaseDelay(
        delay_s=float(delay),
        std_s=std,
        separable=separable,
        applied_s=applied,
        reason=reason,
        n_runs=len(data),
        n_joints=n_joints,
        formal_std_s=float(formal),
        jackknife_std_s=jack,
        alias_delay_s=alias_d,
        alias_cost=alias_cost,
        residual_std_s=scale,
        speed_spread=spread,
        sections=per_section,
        common_delay_p=p_common,
        section_spread_s=spread_s,
        sections_differ=differ,
    )


def _run_cost(j: RunJoints, lengths: np.ndarray, grid: np.ndarray, noise_s: float) -> tuple[np.ndarray, np.ndarray]:
    """Huber cost of one run over the grid of delays, at its best composition per delay; and that choice."""
    per_c = np.empty((lengths.size, grid.size))
    for c, length in enumerate(lengths):
        z = np.abs((j.gap_s - length * j.slowness(length))[:, None] - grid[None, :]) / j.sigma(length, noise_s)[:, None]
        per_c[c] = np.sum(np.where(z <= HUBER_K, 0.5 * z * z, HUBER_K * z - 0.5 * HUBER_K**2), axis=0)
    return per_c.min(axis=0), per_c.argmin(axis=0)


def _minimum(cost: np.ndarray, grid: np.ndarray) -> tuple[int, float]:
    """Index of the grid minimum and the delay refined by a parabola through it and its neighbours."""
    i = int(np.argmin(cost))
    if 0 < i < cost.size - 1:
        a, b, c = cost[i - 1], cost[i], cost[i + 1]
        den = a - 2 * b + c
        if den > 0:
            return i, float(grid[i] + 0.5 * (a - c) / den * (grid[1] - grid[0]))
    return i, float(grid[i])


def _curvature(cost: np.ndarray, i: int, step: float) -> float:
    """Second derivative of F at the minimum (1/s^2), over +-0.05 s; F is half a chi-square."""
    h = max(1, round(0.05 / step))
    if i - h < 0 or i + h >= cost.size:
        return 0.0
    return float((cost[i - h] - 2 * cost[i] + cost[i + h]) / (h * step) ** 2)


def _alias(cost: np.ndarray, grid: np.ndarray, best: int) -> tuple[float, float]:
    """The lowest other local minimum of F more than 0.3 s from the best: (delay, F there - F best)."""
    inner = np.arange(1, cost.size - 1)
    local = inner[(cost[inner] <= cost[inner - 1]) & (cost[inner] <= cost[inner + 1])]
    local = local[np.abs(grid[local] - grid[best]) > 0.3]
    if local.size == 0:
        return float("nan"), float("inf")
    k = local[np.argmin(cost[local])]
    return float(grid[k]), float(cost[k] - cost[best])


def _per_section(section_ids: Sequence[str], resid: np.ndarray, scale: float) -> tuple[dict, float]:
    """Mean residual (s) per released section, and the chi-square p-value of one delay for all of them."""
    by: dict[str, list[float]] = {}
    for sid, value in zip(section_ids, resid):
        by.setdefault(sid, []).append(float(value))
    out, chi2, dof = {}, 0.0, 0
    for sid, values in by.items():
        v = np.array(values)
        se = scale / np.sqrt(v.size) if scale > 0 else float("nan")
        out[sid] = {"mean_residual_s": float(v.mean()), "std_error_s": float(se), "n": int(v.size)}
        if v.size >= 3 and np.isfinite(se) and se > 0:
            chi2 += float(np.mean(np.clip(v, -3 * scale, 3 * scale)) / se) ** 2
            dof += 1
    p = float(stats.chi2.sf(chi2, dof)) if dof >= 2 else float("nan")
    return out, p


def _unusable(reason: str) -> ReleaseDelay:
    nan = float("nan")
    return ReleaseDelay(nan, nan, False, 0.0, f"release delay not separable: {reason}; no offset applied",
                        0, 0, nan, nan, nan, float("inf"), nan, 0.0)  # fmt: skip
