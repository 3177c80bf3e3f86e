"""Observed passage times of one run and the calibration objective (Besinovic eq. 8).

Observations are head passages: an occupation of section k is the head at start_k; a release
(optional) is the tail at end_k, i.e. the head at end_k + L, seen ``release_offset_s`` late. A run
is split into legs between scheduled stops; each leg starts and ends at standstill (eq. 19) and is
simulated on its own.

The departure time of a leg is not in the data (a train describer logs no departure), so each leg
gets a free time offset. For the sum of absolute errors the best offset is the median of the
residuals, so the objective is exact and needs no extra decision variable:

    J(beta) = sum_legs sum_i | r_i - median_leg(r) |,   r_i = t_i^observed - t_i^simulated(beta)

With a known departure time the offset could be fixed instead; without it, whatever shifts all
passages of a leg by the same amount (how fast the train leaves the first metres) is only seen
through the differences between the first passages — the reason c0 is the least identifiable
parameter (see docs/occupation.md).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from ..track import Section
from .events import RunEvents

ProfileModel = Callable[[Mapping[str, float], float, float], object]
"""model(params, start_m, stop_m) -> profile with ``time_at(s_array)``: head passage times (s) from
the departure at start_m, for a run from standstill at start_m to standstill at stop_m."""


@dataclass
class Observations:
    """Head passages of one run, grouped into legs between stops."""

    run_id: str
    position_m: np.ndarray  # head position of each passage, m
    time_s: np.ndarray  # observed time, s (release times already corrected by the known offset)
    kind: np.ndarray  # "occupy" / "release"
    section_id: np.ndarray  # section of each passage
    leg: np.ndarray  # leg index of each passage
    legs: list[tuple[float, float]]  # (start_m, stop_m) of each leg that has passages

    def __len__(self) -> int:
        return int(self.position_m.size)

    @property
    def n_occupations(self) -> int:
        return int(np.count_nonzero(self.kind == "occupy"))


def build_observations(
    run: RunEvents,
    sections: Sequence[Section],
    stops_m: Sequence[float],
    length_m: float,
    *,
    use_releases: bool = False,
    release_offset_s: float = 0.0,
) -> Observations:
    """The passages of ``run`` that fall strictly inside a leg (stop_k, stop_{k+1}].

    ``stops_m``: the scheduled stops of the run (head positions, m), origin and destination included.
    """
    stops = np.asarray(sorted(stops_m), dtype=float)
    if stops.size < 2:
        raise ValueError("a run needs at least two stops (origin and destination)")
    pos, times, kinds, sids = [], [], [], []
    for sec in sections:
        if sec.id in run.occupy:
            pos.append(sec.start_m)
            times.append(run.occupy[sec.id])
            kinds.append("occupy")
            sids.append(sec.id)
        if use_releases and sec.id in run.release:
            pos.append(sec.end_m + length_m)
            times.append(run.release[sec.id] - release_offset_s)
            kinds.append("release")
            sids.append(sec.id)
    position = np.array(pos, dtype=float)
    time = np.array(times, dtype=float)
    leg_of = np.searchsorted(stops, position, side="left") - 1  # stop_k < s <= stop_{k+1}
    inside = (leg_of >= 0) & (leg_of < stops.size - 1)
    order = np.lexsort((time[inside], position[inside]))
    position, time = position[inside][order], time[inside][order]
    kind = np.array(kinds, dtype=object)[inside][order]
    section_id = np.array(sids, dtype=object)[inside][order]
    leg_of = leg_of[inside][order]
    used = sorted(set(leg_of.tolist()))
    remap = {old: new for new, old in enumerate(used)}
    legs = [(float(stops[k]), float(stops[k + 1])) for k in used]
    leg = np.array([remap[k] for k in leg_of], dtype=int)
    return Observations(run.run_id, position, time, kind, section_id, leg, legs)


@dataclass
class Evaluation:
    """The objective at one parameter vector with its parts."""

    objective_s: float  # sum of absolute errors after the per-leg offsets, s
    simulated_s: np.ndarray  # simulated passage times on the observed clock (offset applied), s
    residual_s: np.ndarray  # observed - simulated, s
    departure_s: np.ndarray  # estimated departure time of each leg on the observed clock, s
    running_time_s: np.ndarray  # simulated stop-to-stop running time of each leg, s


def evaluate(obs: Observations, model: ProfileModel, params: Mapping[str, float]) -> Evaluation:
    """Simulate every leg with ``params`` and compare with the observations (eq. 8)."""
    sim = np.empty_like(obs.time_s)
    departures = np.empty(len(obs.legs))
    running = np.empty(len(obs.legs))
    total = 0.0
    for k, (start, stop) in enumerate(obs.legs):
        mask = obs.leg == k
        profile = model(params, start, stop)
        t_rel = np.asarray(profile.time_at(obs.position_m[mask]), dtype=float)
        running[k] = float(np.asarray(profile.time_at(np.array([stop])), dtype=float)[0])
        r = obs.time_s[mask] - t_rel
        if not np.all(np.isfinite(r)):
            total = np.inf
            departures[k] = np.nan
            sim[mask] = np.nan
            continue
        shift = float(np.median(r))
        departures[k] = shift
        sim[mask] = t_rel + shift
        total += float(np.sum(np.abs(r - shift)))
    return Evaluation(total, sim, obs.time_s - sim, departures, running)


def objective_batch(obs: Observations, model, params: Mapping[str, object]) -> np.ndarray:
    """J(beta) for n parameter vectors at once (``params`` values: arrays of length n or numbers), s.

    ``model.batch(params, start_m, stop_m)`` gives the profiles (:meth:`.model.SimulatorModel.batch`);
    inf where the model cannot run a leg.
    """
    total = None
    for k, (start, stop) in enumerate(obs.legs):
        mask = obs.leg == k
        t_rel = model.batch(params, start, stop).time_at(obs.position_m[mask])  # (n, passages)
        r = obs.time_s[mask][None, :] - t_rel
        with np.errstate(invalid="ignore"):
            part = np.sum(np.abs(r - np.median(r, axis=1, keepdims=True)), axis=1)
        part[~np.all(np.isfinite(r), axis=1)] = np.inf
        total = part if total is None else total + part
    return total


def objective(obs: Observations, model: ProfileModel, params: Mapping[str, float]) -> float:
    """J(beta): sum of absolute passage-time errors, s (inf if the model cannot run the leg)."""
    total = 0.0
    for k, (start, stop) in enumerate(obs.legs):
        mask = obs.leg == k
        t_rel = np.asarray(model(params, start, stop).time_at(obs.position_m[mask]), dtype=float)
        r = obs.time_s[mask] - t_rel
        if not np.all(np.isfinite(r)):
            return float("inf")
        total += float(np.sum(np.abs(r - np.median(r))))
    return total
