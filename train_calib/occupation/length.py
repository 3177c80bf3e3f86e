"""Train length from occupation/release times and the composition it belongs to (Besinovic eq. 1-2).

At a joint x_{i+1} between sections s_i and s_{i+1}, the head enters s_{i+1} at t_occ(s_{i+1}) and
the tail leaves s_i at t_rel(s_i): the train needs L / v to pass the joint. With the mean speed over
s_i (eq. 1)

    v_i = (x_{i+1} - x_i) / (t_occ(s_{i+1}) - t_occ(s_i))

and the release known to +-delta s, the length lies in (eq. 2)

    I_i = [v_i (t_rel(s_i) - delta - t_occ(s_{i+1})), v_i (t_rel(s_i) + delta - t_occ(s_{i+1}))]

whose middle is the estimate l_i. The time t_rel(s_i) - t_occ(s_i+1) is the head's travel over
[x_i+1, x_i+1 + L], so the best speed to multiply it with is the mean speed *ahead* of the joint,
over s_i+1 (eq. 1 applied to the next section: exact when the section is as long as the train, and
free of the acceleration bias of the speed behind the joint). ``speed`` chooses: ``"ahead"``
(default), ``"eq1"`` (over s_i, as printed) or ``"centred"`` (over s_i and s_i+1). Measured on
rounded simulated runs, eq1 underestimates long trains by about 5 m, enough to confuse VIRM10
(270 m) and ICRm (282 m); see docs/occupation.md. A run passes many joints: its length and interval are the
interquartile means over the joints of l_i and of the bounds of I_i (with one joint, eq. 2 itself).
The composition assigned is the nearest to the length among those whose length lies in the
interval, none when no composition length is inside (Fig. 6, grey); with ``strict`` also none when
several are (the paper's text: the interval is too wide to tell).

Both occupation and release times are rounded down to the second, so t_rel - t_occ errs by up to
1 s either way: delta = 1 s is the interval that covers the rounding (the paper's best value);
delta = 0 s gives point intervals that contain a composition length only by chance.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy import stats

from ..track import Section
from .events import RunEvents

SPEED_WINDOWS = ("eq1", "centred", "ahead")
"""Where the speed of eq. 2 is measured: over s_i (eq. 1), over s_i and s_i+1, or over s_i+1."""

JOINT_TOLERANCE_M = 0.5
"""Sections closer than this (m) are taken as contiguous: they share a joint."""


@dataclass
class JointEstimates:
    """Per-joint length estimates of one run (arrays over the usable joints)."""

    joint_m: np.ndarray  # position of the joint x_{i+1}, m
    section_ids: list[str]  # s_i, the section ending at the joint
    speed_ms: np.ndarray  # v_i, eq. 1
    length_m: np.ndarray  # l_i, middle of I_i
    low_m: np.ndarray  # lower bound of I_i
    high_m: np.ndarray  # upper bound of I_i


@dataclass
class LengthEstimate:
    """Length and composition of one run."""

    run_id: str
    delta_s: float
    length_m: float  # interquartile mean of the joint estimates, m (NaN without joints)
    low_m: float  # interquartile mean of the joints' lower bounds, m
    high_m: float  # interquartile mean of the joints' upper bounds, m
    n_joints: int
    composition: str | None  # assigned composition, None when not possible
    reason: str  # why (assigned / no composition / ambiguous / no usable joint)
    candidates: list[str] = field(default_factory=list)  # compositions whose length is in the interval


def joint_estimates(
    run: RunEvents,
    sections: Sequence[Section],
    delta_s: float = 1.0,
    *,
    speed: str = "ahead",
    release_offset_s: float = 0.0,
    min_speed_ms: float = 1.0,
) -> JointEstimates:
    """Eq. 1-2 at every joint where s_i, s_{i+1} are contiguous and the needed times are known.

    ``speed``: ``"ahead"`` the mean speed over s_i+1, where the head is while the train passes the
    joint; ``"eq1"`` over s_i (the paper as printed); ``"centred"`` over s_i and s_i+1 together.
    ``release_offset_s``: a known systematic release delay (s) subtracted from the release times
    (0: the paper's symmetric +-delta). Joints with a speed below
    ``min_speed_ms`` (a stop nearby) or a non-positive occupation interval are skipped.
    """
    if speed not in SPEED_WINDOWS:
        raise ValueError(f"speed must be one of {', '.join(SPEED_WINDOWS)}, got {speed!r}")
    ids = [s.id for s in sections]
    n = len(ids)
    empty = np.zeros(0)
    if n < 2:
        return JointEstimates(empty, [], empty, empty, empty, empty)
    starts = np.array([s.start_m for s in sections], dtype=float)
    ends = np.array([s.end_m for s in sections], dtype=float)
    occ = run.times("occupy", ids)
    rel = run.times("release", ids) - release_offset_s
    i = np.arange(n - 1)
    contiguous = np.abs(starts[1:] - ends[:-1]) <= JOINT_TOLERANCE_M
    if speed == "eq1":
        dist = ends[:-1] - starts[:-1]
        d_occ = occ[1:] - occ[:-1]
    else:
        j = np.minimum(i + 2, n - 1)
        has_next = (i + 2 < n) & (np.abs(starts[j] - ends[i + 1]) <= JOINT_TOLERANCE_M)
        first = i if speed == "centred" else i + 1
        dist = np.where(has_next, ends[i + 1] - starts[first], np.nan)
        d_occ = np.where(has_next, occ[j] - occ[first], np.nan)
    with np.errstate(invalid="ignore", divide="ignore"):
        v = dist / d_occ
    d_rel = rel[:-1] - occ[1:]
    ok = contiguous & np.isfinite(d_occ) & np.isfinite(d_rel) & (d_occ > 0)
    ok &= np.where(ok, v, 0.0) >= min_speed_ms
    k = np.nonzero(ok)[0]
    v = v[k]
    return JointEstimates(
        joint_m=ends[:-1][k],
        section_ids=[ids[m] for m in k],
        speed_ms=v,
        length_m=v * d_rel[k],
        low_m=np.maximum(v * (d_rel[k] - delta_s), 0.0),
        high_m=np.maximum(v * (d_rel[k] + delta_s), 0.0),
    )


def assign_composition(
    length_m: float, low_m: float, high_m: float, compositions: Mapping[str, float], *, strict: bool = False
) -> tuple[str | None, str, list[str]]:
    """(composition or None, reason, compositions whose length lies in [low, high]).

    The nearest composition to ``length_m`` among those inside the interval; none if no
    composition length is inside; with ``strict`` also none when several are (the paper's text:
    the interval is too wide to tell).
    """
    if not np.isfinite(length_m):
        return None, "no usable joint (missing events or the train stopped)", []
    inside = [name for name, length in compositions.items() if low_m <= length <= high_m]
    if not inside:
        return None, f"no composition length in [{low_m:.0f}, {high_m:.0f}] m", []
    if strict and len(inside) > 1:
        return None, f"ambiguous: {', '.join(inside)} in [{low_m:.0f}, {high_m:.0f}] m", inside
    best = min(inside, key=lambda name: abs(compositions[name] - length_m))
    return best, "assigned", inside


def estimate_length(
    run: RunEvents,
    sections: Sequence[Section],
    compositions: Mapping[str, float],
    delta_s: float = 1.0,
    *,
    speed: str = "ahead",
    strict: bool = False,
    release_offset_s: float = 0.0,
    min_speed_ms: float = 1.0,
) -> LengthEstimate:
    """Length (eq. 1-2 over all joints) and composition of one run; ``compositions``: name -> length (m).

    The run's length and interval are the interquartile means over its joints of l_i and of the
    bounds of I_i (for one joint: eq. 2 itself); trimming drops the joints where the train
    accelerates or brakes hard, and averaging over joints averages out the one-second rounding.
    """
    joints = joint_estimates(
        run, sections, delta_s, speed=speed, release_offset_s=release_offset_s, min_speed_ms=min_speed_ms
    )
    length, low, high = _iqm(joints.length_m), _iqm(joints.low_m), _iqm(joints.high_m)
    name, reason, inside = assign_composition(length, low, high, compositions, strict=strict)
    return LengthEstimate(
        run_id=run.run_id,
        delta_s=delta_s,
        length_m=length,
        low_m=low,
        high_m=high,
        n_joints=int(joints.length_m.size),
        composition=name,
        reason=reason,
        candidates=inside,
    )


@dataclass
class AssignmentAccuracy:
    """Composition assignment against the known truth."""

    delta_s: float
    n_runs: int
    n_assigned: int
    n_correct: int
    n_wrong: int
    confusion: dict[str, dict[str, int]]  # truth -> assigned (or "none") -> count
    length_error_m: dict[str, float]  # median and 95th percentile of |l - L_true|

    @property
    def assigned_share(self) -> float:
        return self.n_assigned / self.n_runs if self.n_runs else float("nan")

    @property
    def correct_share(self) -> float:
        """Correct assignments over all runs (unassigned runs count as not correct)."""
        return self.n_correct / self.n_runs if self.n_runs else float("nan")

    @property
    def precision(self) -> float:
        """Correct assignments over assigned runs."""
        return self.n_correct / self.n_assigned if self.n_assigned else float("nan")


def assignment_accuracy(
    estimates: Iterable[LengthEstimate], truth: Mapping[str, str], lengths: Mapping[str, float]
) -> AssignmentAccuracy:
    """Compare assigned compositions with ``truth`` (run id -> composition name)."""
    est = [e for e in estimates if e.run_id in truth]
    confusion: dict[str, dict[str, int]] = {}
    n_assigned = n_correct = 0
    errors = []
    for e in est:
        true = truth[e.run_id]
        got = e.composition or "none"
        row = confusion.setdefault(true, {})
        row[got] = row.get(got, 0) + 1
        if e.composition is not None:
            n_assigned += 1
            n_correct += int(e.composition == true)
        if np.isfinite(e.length_m) and true in lengths:
            errors.append(abs(e.length_m - lengths[true]))
    err = np.array(errors)
    stats = {"median": float(np.median(err)), "p95": float(np.percentile(err, 95))} if err.size else {}
    delta = est[0].delta_s if est else float("nan")
    return AssignmentAccuracy(delta, len(est), n_assigned, n_correct, n_assigned - n_correct, confusion, stats)


def _iqm(values: np.ndarray) -> float:
    """Interquartile mean (25 % trimmed each side), NaN when empty."""
    if values.size == 0:
        return float("nan")
    return float(stats.trim_mean(values, 0.25))
