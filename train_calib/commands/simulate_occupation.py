"""Simulate fleets of train runs and write the track occupation/release events a train describer logs.

Runs of every composition of TYPES.yaml drive from the first to the last station of the track with
train_calib.sim's realistic driver (sampled per run), their own Davis coefficients, and optionally
a hindrance by another train. Writes DIR/events.csv (the occupation CSV format, docs/occupation.md)
and DIR/truth.csv (the parameters each run was simulated with). Reproducible: one seed per run,
spawned from --seed, whatever --workers is. Example:

    train-calib simulate-occupation --track dense_corridor_14km \\
        --train-types config/train_types/ic_compositions.yaml --runs 50 --seed 1 --out fleet
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from ..errors import TrainCalibError
from ..occupation.compositions import load_train_types
from ..occupation.events import write_events
from ..occupation.fleet import FleetConfig, simulate_fleet, write_truth
from ..occupation.pipeline import available_workers
from ..paths import config_file, track_file
from ..track import load_track

NAME = "simulate-occupation"
HELP = "simulate fleets of runs and write their track occupation/release events with the truth"


class UsageError(TrainCalibError):
    """A command-line value the user can fix (one line)."""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--track", default="dense_corridor_14km", help="bundled track name or file (default %(default)s)"
    )
    parser.add_argument(
        "--train-types",
        default=str(config_file("train_types/ic_compositions.yaml")),
        help="TYPES.yaml of the compositions (default the bundled IC compositions)",
    )
    parser.add_argument("--compositions", help="comma-separated subset of the compositions (default all)")
    parser.add_argument("--runs", type=int, default=50, help="runs per composition (default 50)")
    parser.add_argument("--seed", type=int, default=0, help="base seed (default 0)")
    parser.add_argument(
        "--driver",
        choices=("realistic", "minimum_time"),
        default="realistic",
        help="realistic (sampled driver, default) or minimum_time (the calibration's model class, sampled c0, c2, "
        "b_limit, theta: an identifiability test)",
    )
    parser.add_argument("--hindered", type=float, default=0.0, help="share of hindered runs, 0-1 (default 0)")
    parser.add_argument("--release-delay", type=float, default=0.0, help="track-circuit release delay, s (default 0)")
    parser.add_argument("--release-jitter", type=float, default=0.0, help="extra uniform release delay [0, x] s")
    parser.add_argument("--coast-min", type=float, default=0.0, help="shortest coast before the final brake, s")
    parser.add_argument("--coast-max", type=float, default=60.0, help="longest coast before the final brake, s")
    parser.add_argument("--wind", action="store_true", help="head/tail wind on r2")
    parser.add_argument("--workers", type=int, default=0, help="processes (default: all cores)")
    parser.add_argument("--out", default="occupation_fleet", help="output directory (default %(default)s)")


def run(args: argparse.Namespace) -> int:
    if args.runs < 1:
        raise UsageError(f"--runs must be at least 1, got {args.runs}")
    if not 0.0 <= args.hindered <= 1.0:
        raise UsageError(f"--hindered must be in [0, 1], got {args.hindered}")
    track = load_track(track_file(args.track))
    if len(track.sections) < 2:
        raise UsageError(f"{track.source}: sections: the track needs track sections for occupation data")
    types = load_train_types(args.train_types)
    names = None
    if args.compositions:
        names = [n.strip() for n in args.compositions.split(",") if n.strip()]
        unknown = [n for n in names if n not in types]
        if unknown:
            raise UsageError(f"unknown composition(s) {', '.join(unknown)} (known: {', '.join(types.names)})")
    config = FleetConfig.from_mapping(
        {
            "runs_per_composition": args.runs,
            "driver": args.driver,
            "hindered_share": args.hindered,
            "release_delay_s": args.release_delay,
            "release_jitter_s": args.release_jitter,
            "coast_min_s": args.coast_min,
            "coast_max_s": args.coast_max,
            "wind": bool(args.wind),
        },
        source="command line",
    )
    workers = args.workers if args.workers > 0 else available_workers()
    t0 = time.perf_counter()

    def progress(done: int, total: int) -> None:
        if done == total or done % 10 == 0:
            print(f"simulated {done}/{total} runs ({time.perf_counter() - t0:.1f} s)", file=sys.stderr, flush=True)

    fleet = simulate_fleet(track, types, config, seed=args.seed, compositions=names, workers=workers, progress=progress)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    settings = (
        f"seed {args.seed}, {args.runs} runs per composition, {args.driver} driver, hindered share {args.hindered:g}, "
        f"release delay {args.release_delay:g} s + U(0, {args.release_jitter:g}) s, "
        f"coast {args.coast_min:g}-{args.coast_max:g} s, wind {'on' if args.wind else 'off'}"
    )
    events = write_events(
        out / "events.csv",
        [r.events for r in fleet],
        comments=[
            f"simulated by train-calib simulate-occupation: {settings}",
            f"track: {track.name}; train types: {types.name}",
        ],
    )
    truth = write_truth(out / "truth.csv", fleet)
    hindered = sum(bool(r.truth["hindrance"]) for r in fleet)
    print(f"{len(fleet)} runs ({hindered} hindered) in {time.perf_counter() - t0:.1f} s: {events} and {truth}")
    return 0
