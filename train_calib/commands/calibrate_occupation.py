"""Calibrate the running-time model of every train run from track occupation/release data.

Besinovic et al. (2013): per run, the train length from occupation/release times (eq. 1-2) assigns
a composition of TYPES.yaml; runs hindered by other trains are dropped (with the reason); each
remaining run is calibrated by differential evolution over (c0, c2, r0, r2, b_limit, theta_cruise),
minimising the sum of absolute passage-time errors (eq. 8) of the running-time model; per
composition the calibrated parameters get maximum-likelihood distributions chosen by the
Kolmogorov-Smirnov statistic (Table 4, Figs. 7-9). Runs are calibrated in parallel (--workers).

Writes to --out: runs.csv, residuals.csv, lengths.csv, distributions.csv/.md, sensitivity.csv,
summary.json (also printed), plots/ (per-run Fig. 5, per-composition Figs. 7-9, Fig. 6, Fig. 10)
and, with --truth, truth_comparison.csv; with --robustness N, robustness.md/.csv (Table 3).
See docs/occupation.md for the file formats.
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import math
import sys
import time
from pathlib import Path

from ..errors import TrainCalibError
from ..occupation import plots, report
from ..occupation.calibrate import CalibrationConfig
from ..occupation.compositions import load_train_types
from ..occupation.events import load_events
from ..occupation.fleet import load_truth
from ..occupation.length import SPEED_WINDOWS
from ..occupation.model import SimulatorModel
from ..occupation.objective import build_observations
from ..occupation.pipeline import available_workers, calibrate_fleet, default_stops
from ..occupation.robustness import repeated_calibrations
from ..occupation.unhindered import FilterConfig
from ..paths import track_file
from ..track import load_track

NAME = "calibrate-occupation"
HELP = "calibrate the running-time model per run from track occupation/release events (Besinovic et al.)"


class UsageError(TrainCalibError):
    """A command-line value the user can fix (one line)."""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("events", help="occupation/release events CSV (run_id,section_id,event,time)")
    parser.add_argument("--track", required=True, help="bundled track name or track file (with sections)")
    parser.add_argument("--train-types", required=True, help="TYPES.yaml: compositions, defaults, bounds")
    parser.add_argument("--out", required=True, help="output directory")
    parser.add_argument("--delta", type=float, default=1.0, help="release time tolerance of eq. 2, s (default 1)")
    parser.add_argument("--workers", type=int, default=0, help="parallel processes (default: all cores)")
    parser.add_argument("--seed", type=int, default=0, help="base seed; run k uses seed + k (default 0)")
    parser.add_argument("--truth", help="truth.csv of simulate-occupation: compare with the known parameters")
    parser.add_argument("--stops", help="comma-separated station names where runs stop (default every station)")
    parser.add_argument(
        "--length-speed",
        choices=SPEED_WINDOWS,
        default="ahead",
        help="speed of eq. 2: over the section ahead of the joint (default), behind it (eq1) or both",
    )
    parser.add_argument(
        "--strict-length",
        action="store_true",
        help="no composition when several lengths fall in the interval (the paper's text)",
    )
    parser.add_argument("--use-releases", action="store_true", help="fit release passages too (tail at section end)")
    parser.add_argument(
        "--release-offset",
        default="0",
        help="release delay of the detectors to subtract, s, or 'auto': estimate it from the data (default 0)",
    )
    parser.add_argument("--popsize", type=int, default=CalibrationConfig.popsize, help="DE population per variable")
    parser.add_argument("--maxiter", type=int, default=CalibrationConfig.maxiter, help="DE generations at most")
    parser.add_argument("--atol", type=float, default=CalibrationConfig.atol, help="DE convergence: objective std, s")
    parser.add_argument("--dip", type=float, default=FilterConfig.dip, help="filter: relative speed dip (default 0.25)")
    parser.add_argument("--run-plots", type=int, default=4, help="per-run figures per composition (default 4; 0 none)")
    parser.add_argument("--robustness", type=int, default=0, help="also calibrate one run N times (Table 3)")
    parser.add_argument("--robustness-run", help="the run for --robustness (default the first calibrated)")
    parser.add_argument("--limit", type=int, default=0, help="use only the first N runs of the file (0: all)")


def run(args: argparse.Namespace) -> int:
    t0 = time.perf_counter()
    track = load_track(track_file(args.track))
    if len(track.sections) < 2:
        raise UsageError(f"{track.source}: sections: the track needs track sections for occupation data")
    stops = _stops(track, args.stops)
    if args.delta < 0:
        raise UsageError(f"--delta must be >= 0, got {args.delta}")
    types = load_train_types(args.train_types)
    runs = load_events(args.events, [s.id for s in track.sections])
    if args.limit > 0:
        runs = dict(list(runs.items())[: args.limit])
    truth = load_truth(args.truth) if args.truth else None
    auto_offset, offset = _release_offset(args.release_offset)
    workers = args.workers if args.workers > 0 else available_workers()
    config = CalibrationConfig.from_mapping(
        {
            "popsize": args.popsize,
            "maxiter": args.maxiter,
            "atol": args.atol,
            "use_releases": bool(args.use_releases),
            "release_offset_s": offset,
        },
        source="command line",
    )
    filter_config = FilterConfig.from_mapping({"dip": args.dip}, source="command line")

    def progress(message: str) -> None:
        print(f"[{time.perf_counter() - t0:7.1f} s] {message}", file=sys.stderr, flush=True)

    fleet = calibrate_fleet(
        runs,
        track,
        types,
        stops_m=stops,
        delta_s=args.delta,
        length_speed=args.length_speed,
        strict_length=args.strict_length,
        filter_config=filter_config,
        calibration=config,
        seed=args.seed,
        workers=workers,
        progress=progress,
        auto_release_offset=auto_offset,
    )
    config = dataclasses.replace(config, release_offset_s=fleet.release_offset_s)  # the estimate with "auto"
    out = Path(args.out)
    (out / "plots").mkdir(parents=True, exist_ok=True)
    observations = {
        o.run_id: build_observations(
            runs[o.run_id],
            track.sections,
            stops,
            types[o.composition].length_m,
            use_releases=config.use_releases,
            release_offset_s=config.release_offset_s,
        )
        for o in fleet.outcomes
        if o.result is not None
    }
    report.write_runs_csv(out / "runs.csv", fleet)
    report.write_residuals_csv(out / "residuals.csv", fleet, observations)
    report.write_lengths_csv(out / "lengths.csv", fleet)
    report.write_distributions(out, fleet)
    report.write_sensitivity_csv(out / "sensitivity.csv", fleet)
    if truth is not None:
        report.write_truth_csv(out / "truth_comparison.csv", fleet, truth)

    progress("plots")
    models = {}
    for comp in types.names:
        results = fleet.calibrated(comp)
        if not results:
            continue
        models[comp] = SimulatorModel(track, types[comp])
        for r in results[: max(0, args.run_plots)]:
            plots.run_figure(
                out / "plots" / f"run_{_safe(r.run_id)}.png", track, observations[r.run_id], r, models[comp]
            )
        if comp in fleet.fits:
            plots.distribution_figure(
                out / "plots" / f"distributions_{_safe(comp)}.png",
                comp,
                results,
                fleet.fits[comp],
                types[comp].defaults,
                truth,
            )
    plots.length_figure(out / "plots" / "lengths.png", fleet.lengths, types)
    if any(fleet.calibrated(c) for c in types.names):
        plots.ranges_figure(out / "plots" / "ranges.png", {c: fleet.calibrated(c) for c in types.names}, types, truth)

    data = report.summary(fleet, types, truth)
    if args.robustness > 0:
        data["robustness"] = _robustness(args, fleet, runs, track, types, stops, config, workers, out, progress)
    data["events_file"] = str(args.events)
    data["track"] = track.name
    data["train_types"] = types.name
    report.write_summary(out / "summary.json", data)
    print(report.summary_text(data))
    print(f"outputs in {out}/ (runs.csv, distributions.md, summary.json, plots/)")
    return 0


def _robustness(args, fleet, runs, track, types, stops, config, workers, out: Path, progress) -> dict:
    calibrated = fleet.calibrated()
    if not calibrated:
        raise UsageError("--robustness needs at least one calibrated run")
    if args.robustness_run:
        match = [r for r in calibrated if r.run_id == args.robustness_run]
        if not match:
            raise UsageError(f"--robustness-run {args.robustness_run!r} is not a calibrated run")
        base = match[0]
    else:
        base = calibrated[0]
    comp = types[base.composition]
    obs = build_observations(
        runs[base.run_id],
        track.sections,
        stops,
        comp.length_m,
        use_releases=config.use_releases,
        release_offset_s=config.release_offset_s,
    )
    progress(f"robustness: {args.robustness} calibrations of {base.run_id}")
    rob = repeated_calibrations(
        obs, SimulatorModel(track, comp), comp, config, n=args.robustness, first_seed=args.seed + 1000, workers=workers
    )
    (out / "robustness.md").write_text(rob.as_markdown() + "\n", encoding="utf-8")
    with (out / "robustness.csv").open("w", newline="", encoding="utf-8") as f:
        w = csv.writer(f, lineterminator="\n")
        w.writerow(["parameter", "default", "mean", "std", "std_pct"])
        for r in rob.rows:
            w.writerow([r.name, f"{r.default:.8g}", f"{r.mean:.8g}", f"{r.std:.8g}", f"{r.cv_pct:.4g}"])
    return {
        "run_id": base.run_id,
        "n": len(rob.results),
        "rows": {r.name: {"default": r.default, "mean": r.mean, "std": r.std, "std_pct": r.cv_pct} for r in rob.rows},
    }


def _release_offset(text: str) -> tuple[bool, float]:
    """(estimate from the data, fixed offset in s) from --release-offset."""
    if text.strip().lower() == "auto":
        return True, 0.0
    try:
        value = float(text)
    except ValueError:
        raise UsageError(f"--release-offset: expected seconds or 'auto', got {text!r}") from None
    if not math.isfinite(value) or not -5.0 <= value <= 10.0:
        raise UsageError(f"--release-offset: {value:g} s is outside [-5, 10] s")
    return False, value


def _stops(track, names: str | None) -> list[float]:
    if not names:
        stops = default_stops(track)
    else:
        by_name = {st.name: st.s_m for st in track.stations}
        wanted = [n.strip() for n in names.split(",") if n.strip()]
        unknown = [n for n in wanted if n not in by_name]
        if unknown:
            raise UsageError(f"--stops: no station {', '.join(map(repr, unknown))} (stations: {', '.join(by_name)})")
        stops = sorted(by_name[n] for n in wanted)
    if len(stops) < 2:
        raise UsageError(f"{track.source}: stations: runs need at least two stops, found {len(stops)}")
    return stops


def _safe(name: str) -> str:
    return "".join(c if c.isalnum() or c in "-_." else "_" for c in name)
