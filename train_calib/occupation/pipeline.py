"""The whole method on a set of runs: lengths, compositions, unhindered filter, calibration, fits.

    events ─► length (eq. 1-2, delta) ─► composition ─► unhindered filter ─► calibration per run (DE)
                                                                                   │
                                         distributions per composition (MLE + KS) ◄┘

Runs are calibrated in parallel processes (``workers``), each with its own seed (``seed`` + its
index), so results do not depend on the number of workers.
"""

from __future__ import annotations

import dataclasses
import itertools
import os
import time
from collections.abc import Callable, Mapping, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass, field

import numpy as np

from ..track import Track
from .calibrate import CalibrationConfig, CalibrationResult, calibrate_run
from .compositions import DECISION_NAMES, TrainTypes
from .distributions import CANDIDATES, FitResult, fit_all
from .events import RunEvents
from .length import LengthEstimate, estimate_length
from .model import SimulatorModel
from .objective import build_observations
from .release_delay import ReleaseDelay, estimate_release_delay
from .sensitivity import Identifiability, Sensitivity, identifiability, one_at_a_time
from .unhindered import FilterConfig, check_run, fleet_reference, profile_reference

LENGTH_DELTAS = (0.0, 1.0, 2.0)
MIN_RUNS_FOR_FLEET_REFERENCE = 5
MIN_RUNS_FOR_FIT = 5


@dataclass
class RunOutcome:
    """What happened to one run."""

    run_id: str
    status: str  # calibrated / rejected / unassigned / failed
    reason: str
    length: LengthEstimate
    composition: str | None
    result: CalibrationResult | None = None


@dataclass
class FleetCalibration:
    """Everything the pipeline found, ready for the report."""

    outcomes: list[RunOutcome]
    lengths: dict[float, list[LengthEstimate]]  # delta -> estimates of every run
    fits: dict[str, dict[str, list[FitResult]]]  # composition -> parameter -> ranked fits
    sensitivity: dict[str, list[Sensitivity]] = field(default_factory=dict)  # composition -> rows
    identifiability: dict[str, Identifiability] = field(default_factory=dict)
    bounds: dict[str, dict[str, tuple[float, float]]] = field(default_factory=dict)  # composition -> bounds
    elapsed_s: float = 0.0
    workers: int = 1
    settings: dict = field(default_factory=dict)
    release_delay: ReleaseDelay | None = None  # with release_offset "auto": the estimate (release_delay.py)
    release_offset_s: float = 0.0  # the release offset used (s): the fixed one or the estimate applied

    def calibrated(self, composition: str | None = None) -> list[CalibrationResult]:
        return [
            o.result
            for o in self.outcomes
            if o.result is not None and (composition is None or o.composition == composition)
        ]


# -- worker side (one process per core; the track and model are set up once per process) ----------
_WORKER: dict = {}


def _init_worker(track: Track, types: TrainTypes) -> None:
    _WORKER["track"] = track
    _WORKER["types"] = types
    _WORKER["models"] = {}


def _model(composition: str) -> SimulatorModel:
    models = _WORKER["models"]
    if composition not in models:
        models[composition] = SimulatorModel(_WORKER["track"], _WORKER["types"][composition])
    return models[composition]


def _calibrate_job(job) -> CalibrationResult:
    run, composition, stops, config, seed = job
    track, types = _WORKER["track"], _WORKER["types"]
    comp = types[composition]
    obs = build_observations(
        run,
        track.sections,
        stops,
        comp.length_m,
        use_releases=config.use_releases,
        release_offset_s=config.release_offset_s,
    )
    return calibrate_run(obs, _model(composition), comp, config, seed=seed)


# -- the pipeline ------------------------------------------------------------------------------
def _model_reference(track: Track, types: TrainTypes, composition: str, stops: Sequence[float]) -> np.ndarray:
    """Section mean speeds (m/s) of the model with the composition's defaults, leg after leg."""
    model = SimulatorModel(track, types[composition])
    params = types[composition].model_params()
    legs = [(a, b, model(params, a, b)) for a, b in itertools.pairwise(stops)]
    offsets = np.concatenate(([0.0], np.cumsum([float(p.time_at(np.array([b]))[0]) for _, b, p in legs])))

    def time_at(s_m):
        s_m = np.asarray(s_m, dtype=float)
        out = np.full(s_m.shape, np.nan)
        for k, (a, b, prof) in enumerate(legs):
            inside = (s_m >= a) & (s_m <= b)
            out[inside] = offsets[k] + np.asarray(prof.time_at(s_m[inside]), dtype=float)
        return out

    return profile_reference(time_at, track.sections)


def default_stops(track: Track) -> list[float]:
    """Every station of the track is a scheduled stop (head position, m)."""
    return sorted(st.s_m for st in track.stations)


def calibrate_fleet(
    runs: Mapping[str, RunEvents],
    track: Track,
    types: TrainTypes,
    *,
    stops_m: Sequence[float] | None = None,
    delta_s: float = 1.0,
    length_speed: str = "ahead",
    strict_length: bool = False,
    filter_config: FilterConfig | None = None,
    calibration: CalibrationConfig | None = None,
    seed: int = 0,
    workers: int = 1,
    candidates: Sequence[str] = CANDIDATES,
    progress: Callable[[str], None] | None = None,
    auto_release_offset: bool = False,
) -> FleetCalibration:
    """Lengths, compositions, filter, per-run calibration, distribution fits (see the module docstring).

    The release offset (``calibration.release_offset_s``, s) is subtracted from every release time, for the
    lengths and, with ``use_releases``, in the objective. ``auto_release_offset``: estimate it from the data
    instead (:func:`release_delay.estimate_release_delay`; 0 when the data cannot separate it).
    """
    t_start = time.perf_counter()
    cfg = calibration or CalibrationConfig()
    stops = list(stops_m) if stops_m is not None else default_stops(track)
    sections = track.sections
    lengths_table = types.lengths()
    ids = list(runs)
    delay = None
    if auto_release_offset:
        delay = estimate_release_delay(runs, sections, stops, lengths_table)
        cfg = dataclasses.replace(cfg, release_offset_s=delay.applied_s)
        if progress:
            progress(delay.reason)
    offset = cfg.release_offset_s
    lengths = {
        d: [
            estimate_length(
                runs[r], sections, lengths_table, d, speed=length_speed, strict=strict_length, release_offset_s=offset
            )
            for r in ids
        ]
        for d in sorted({*LENGTH_DELTAS, float(delta_s)})
    }
    chosen = {e.run_id: e for e in lengths[float(delta_s)]}

    # unhindered filter: fleet median as reference, or the model with the composition's defaults
    reference = fleet_reference(runs.values(), sections) if len(runs) >= MIN_RUNS_FOR_FLEET_REFERENCE else None
    model_refs: dict[str, np.ndarray] = {}
    outcomes: dict[str, RunOutcome] = {}
    jobs = []
    for index, run_id in enumerate(ids):
        est = chosen[run_id]
        comp = est.composition
        ref = reference
        if ref is None and comp is not None:
            if comp not in model_refs:
                model_refs[comp] = _model_reference(track, types, comp, stops)
            ref = model_refs[comp]
        check = check_run(runs[run_id], sections, stops, ref, filter_config)
        if not check.unhindered:
            outcomes[run_id] = RunOutcome(run_id, "rejected", "; ".join(check.reasons), est, comp)
            continue
        if comp is None:
            outcomes[run_id] = RunOutcome(run_id, "unassigned", est.reason, est, None)
            continue
        outcomes[run_id] = RunOutcome(run_id, "pending", "", est, comp)
        jobs.append((runs[run_id], comp, stops, cfg, seed + index))

    n_jobs = len(jobs)
    if progress:
        progress(
            f"{len(ids)} runs: {n_jobs} to calibrate, "
            f"{sum(o.status == 'rejected' for o in outcomes.values())} rejected (hindered or bad data), "
            f"{sum(o.status == 'unassigned' for o in outcomes.values())} without composition; "
            f"{workers} worker{'s' if workers != 1 else ''}"
        )
    done = 0

    def finish(run_id: str, result: CalibrationResult | None, error: str = "") -> None:
        nonlocal done
        done += 1
        out = outcomes[run_id]
        if result is None:
            out.status, out.reason = "failed", error
        else:
            out.status, out.reason, out.result = "calibrated", "", result
        if progress:
            what = f"objective {result.objective_s:.1f} s, {result.elapsed_s:.1f} s" if result else f"failed: {error}"
            progress(f"[{done}/{n_jobs}] {run_id} ({out.composition}): {what}")

    workers = max(1, int(workers))
    if workers > 1 and n_jobs > 1:
        with ProcessPoolExecutor(max_workers=workers, initializer=_init_worker, initargs=(track, types)) as pool:
            futures = {pool.submit(_calibrate_job, job): job[0].run_id for job in jobs}
            for fut in as_completed(futures):
                try:
                    finish(futures[fut], fut.result())
                except Exception as exc:  # one bad run must not lose the fleet
                    finish(futures[fut], None, f"{type(exc).__name__}: {exc}")
    else:
        _init_worker(track, types)
        for job in jobs:
            try:
                finish(job[0].run_id, _calibrate_job(job))
            except Exception as exc:
                finish(job[0].run_id, None, f"{type(exc).__name__}: {exc}")

    fleet = FleetCalibration(
        outcomes=[outcomes[r] for r in ids],
        lengths=lengths,
        fits={},
        bounds={c.name: dict(c.bounds) for c in types.compositions},
        workers=workers,
        release_delay=delay,
        release_offset_s=offset,
        settings={
            "delta_s": float(delta_s),
            "length_speed": length_speed,
            "strict_length": strict_length,
            "stops_m": stops,
            "seed": seed,
            "calibration": cfg.as_dict(),
            "filter": (filter_config or FilterConfig()).as_dict(),
            "reference": "fleet median" if reference is not None else "model with defaults",
            "release_offset": "auto" if auto_release_offset else offset,
        },
    )
    for comp in types.names:
        results = fleet.calibrated(comp)
        if len(results) >= MIN_RUNS_FOR_FIT:
            fleet.fits[comp] = {name: fit_all([r.params[name] for r in results], candidates) for name in DECISION_NAMES}
        if results:  # sensitivity and identifiability at the median run's calibrated parameters
            median_run = sorted(results, key=lambda r: r.objective_s)[len(results) // 2]
            model = SimulatorModel(track, types[comp])
            obs = build_observations(
                runs[median_run.run_id],
                track.sections,
                stops,
                types[comp].length_m,
                use_releases=cfg.use_releases,
                release_offset_s=cfg.release_offset_s,
            )
            positions = [obs.position_m[obs.leg == k] for k in range(len(obs.legs))]
            fleet.sensitivity[comp] = one_at_a_time(model, median_run.params, obs.legs, positions)
            fleet.identifiability[comp] = identifiability(obs, model, median_run.params)
    fleet.elapsed_s = time.perf_counter() - t_start
    return fleet


def available_workers() -> int:
    """Cores this process may use."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover - not Linux
        return os.cpu_count() or 1


def at_bound_share(values: np.ndarray, bounds: tuple[float, float] | None, rel: float = 0.01) -> float:
    """Share of values within ``rel`` of the box width from either bound (NaN without bounds)."""
    if bounds is None or values.size == 0:
        return float("nan")
    lo, hi = bounds
    tol = rel * (hi - lo)
    return float(np.mean((values <= lo + tol) | (values >= hi - tol)))


def summary_numbers(fleet: FleetCalibration) -> dict:
    """Counts and per-composition ranges (Table 4) for the summary."""
    counts: dict[str, int] = {}
    for o in fleet.outcomes:
        counts[o.status] = counts.get(o.status, 0) + 1
    ranges = {}
    for comp in sorted({o.composition for o in fleet.outcomes if o.result is not None}):
        results = fleet.calibrated(comp)
        ranges[comp] = {"runs": len(results)}
        for name in DECISION_NAMES:
            vals = np.array([r.params[name] for r in results])
            ranges[comp][name] = {
                "min": float(vals.min()),
                "median": float(np.median(vals)),
                "max": float(vals.max()),
                "at_bound_share": at_bound_share(vals, fleet.bounds.get(comp, {}).get(name)),
            }
        ranges[comp].update(
            {
                "objective_s": float(np.median([r.objective_s for r in results])),
                "mean_abs_residual_s": float(np.median([r.mean_abs_residual_s for r in results])),
            }
        )
    return {"counts": counts, "ranges": ranges}
