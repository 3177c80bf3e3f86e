"""Occupation/release events of a train from its head trajectory s(t), as a train describer logs them.

The head enters section k when s_head = start_k (occupation); the tail leaves it when
s_head - L = end_k (release). The describer sees the release after the track circuit's release
delay and logs both kinds rounded down to the full second (Besinovic et al. 2013, Input data).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ..track import Section
from .events import RunEvents


def first_passage_times(t_s: np.ndarray, s_m: np.ndarray, positions_m: np.ndarray) -> np.ndarray:
    """First time (s) the trajectory reaches each position, linear between samples; NaN if never.

    ``t_s`` increasing, ``s_m`` the head position (m) at those times (standstill allowed).
    Positions at or before s_m[0] are reached at t_s[0].
    """
    t = np.asarray(t_s, dtype=float)
    s = np.maximum.accumulate(np.asarray(s_m, dtype=float))
    p = np.asarray(positions_m, dtype=float)
    idx = np.searchsorted(s, p, side="left")  # first sample with s >= p
    out = np.full(p.shape, np.nan)
    reached = idx < s.size
    at_start = reached & (idx == 0)
    out[at_start] = t[0]
    inner = reached & (idx > 0)
    i = idx[inner]
    s0, s1 = s[i - 1], s[i]
    frac = (p[inner] - s0) / np.where(s1 > s0, s1 - s0, 1.0)
    out[inner] = t[i - 1] + frac * (t[i] - t[i - 1])
    return out


def occupation_events(
    t_s: np.ndarray,
    s_head_m: np.ndarray,
    length_m: float,
    sections: Sequence[Section],
    *,
    run_id: str = "run",
    t0_s: float = 0.0,
    release_delay_s: float = 0.0,
    release_jitter_s: float = 0.0,
    rng: np.random.Generator | None = None,
    round_down: bool = True,
) -> RunEvents:
    """The events a train describer logs for one run.

    - occupation of every section whose start the head passes during the run (not the one it
      stands in at the first sample);
    - release of every section whose end the tail (s_head - length) passes during the run,
      delayed by ``release_delay_s`` plus a uniform random ``[0, release_jitter_s]`` s;
    - times are ``t0_s + t`` (s), rounded down to the full second unless ``round_down`` is False.
    """
    if length_m <= 0:
        raise ValueError(f"train length must be positive, got {length_m}")
    starts = np.array([sec.start_m for sec in sections], dtype=float)
    ends = np.array([sec.end_m for sec in sections], dtype=float)
    s = np.asarray(s_head_m, dtype=float)
    s_first, s_last = float(s[0]), float(np.max(s))
    occ = first_passage_times(t_s, s, starts)
    occ_ok = (starts > s_first) & (starts <= s_last) & np.isfinite(occ)
    tail_at = ends + length_m
    rel = first_passage_times(t_s, s, tail_at)
    rel_ok = (tail_at > s_first) & (tail_at <= s_last) & np.isfinite(rel)
    delay = np.full(ends.shape, float(release_delay_s))
    if release_jitter_s > 0:
        gen = rng if rng is not None else np.random.default_rng()
        delay = delay + gen.uniform(0.0, release_jitter_s, size=ends.shape)
    occ = t0_s + occ
    rel = t0_s + rel + delay
    if round_down:
        occ, rel = np.floor(occ), np.floor(rel)
    run = RunEvents(run_id)
    for k, sec in enumerate(sections):
        if occ_ok[k]:
            run.occupy[sec.id] = float(occ[k])
        if rel_ok[k]:
            run.release[sec.id] = float(rel[k])
    return run
