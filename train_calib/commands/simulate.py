"""Simulate runs with known truth and write each as an MCAP bag (rosbag2 layout) plus truth files.

Each run drives from a station stop to the next (or --start-station/--stop-station) with a driver,
true running resistance and sensor offsets drawn from the run's own random generator, seeded with
(--seed, run index): the same command always writes the same bytes, and run k of a batch can be
regenerated alone with --first-index k --runs 1. See docs/simulator.md.
"""

from __future__ import annotations

import argparse
import shlex
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

from ..errors import TrainCalibError
from ..paths import track_file, train_file
from ..track import load_track
from ..train import Davis, TrainSpec, load_train

NAME = "simulate"
HELP = "simulate runs with known truth and write them as MCAP bags"

DEFAULT_START = "2020-03-02T07:00:00Z"
REFERENCE_DISTANCE_M = 32103.0  # the corridor of Cunillera et al. (2022), where coasting lasts 2.5-10 min


class UsageError(TrainCalibError):
    """A command-line value the user can fix (one line)."""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--track", default="intercity_32km", help="bundled track name or track file (default %(default)s)"
    )
    parser.add_argument("--train", default="virm6", help="bundled train name or train file (default %(default)s)")
    parser.add_argument("--runs", type=int, default=1, help="number of runs (default 1)")
    parser.add_argument("--seed", type=int, default=0, help="base seed; run k uses numpy default_rng([seed, k])")
    parser.add_argument("--first-index", type=int, default=0, help="index of the first run (default 0)")
    parser.add_argument("--period", type=float, default=10.0, help="GNSS and speed sample period, s (default 10)")
    parser.add_argument("--gnss-period", type=float, help="GNSS period, s (default --period)")
    parser.add_argument("--speed-period", type=float, help="speed period, s (default --period)")
    parser.add_argument("--power", action="store_true", help="record /train/traction_power")
    parser.add_argument("--power-period", type=float, help="power period, s (default --period)")
    parser.add_argument("--gnss-noise", type=float, default=4.0, help="GNSS noise per axis, m (default 4)")
    parser.add_argument("--gnss-dropout", type=float, default=0.0, help="probability of a missing fix (default 0)")
    parser.add_argument(
        "--speed-noise", type=float, default=0.5, help="speed noise (std) before rounding to --speed-quantum, km/h"
    )
    parser.add_argument(
        "--speed-quantum",
        type=float,
        default=1.0,
        help="speed resolution, km/h: the measured speed is rounded to it (default 1, the paper's; e.g. 0.01 for "
        "wheel-tachometer odometry; 0 = no rounding)",
    )
    parser.add_argument(
        "--resistance-spread",
        type=float,
        default=0.2,
        help="true r0, r1, r2 = manufacturer x (1 +- U(0.05, spread)) per run (default 0.2; 0 = exact)",
    )
    parser.add_argument("--style", choices=("mixed", "hold", "cycles"), default="mixed", help="cruising style")
    parser.add_argument(
        "--coast-min",
        type=float,
        help="shortest coast before the final brake, s (default 150 s scaled by distance / 32.1 km)",
    )
    parser.add_argument(
        "--coast-max", type=float, help="longest coast before the final brake, s (default 600 s scaled)"
    )
    parser.add_argument("--wind", action="store_true", help="head/tail wind: a slowly varying factor on r2")
    parser.add_argument(
        "--minimum-time",
        action="store_true",
        help="Besinovic's minimum-time driver (full traction, theta 1, no coasting) instead of a sampled one",
    )
    parser.add_argument("--start-station", help="station to depart from (default the first)")
    parser.add_argument("--stop-station", help="station to stop at (default the next one)")
    parser.add_argument(
        "--start-time",
        default=DEFAULT_START,
        help="recording start of run 0 (ISO 8601, UTC if no zone, or integer ns); run k starts k days later",
    )
    parser.add_argument("--out", default="sim_runs", help="output directory (default %(default)s)")
    parser.add_argument("--name", help="bag name prefix (default <track>_<period>s); bags are <prefix>_<nn>")
    parser.add_argument("--dense", action="store_true", help="also write <name>.dense.csv (truth every 0.5 s)")
    parser.add_argument("--quiet", action="store_true", help="print nothing but errors")


def _check(condition: bool, option: str, problem: str) -> None:
    if not condition:
        raise UsageError(f"{option}: {problem}")


def _start_ns(text: str) -> int:
    if text.strip().lstrip("-").isdigit():
        return int(text)
    try:
        stamp = datetime.fromisoformat(text.strip().replace("Z", "+00:00"))
    except ValueError:
        raise UsageError(f"--start-time: {text!r} is neither ISO 8601 nor integer nanoseconds") from None
    if stamp.tzinfo is None:
        stamp = stamp.replace(tzinfo=timezone.utc)
    return int(stamp.timestamp()) * 1_000_000_000 + stamp.microsecond * 1000


def true_resistance(train: TrainSpec, spread: float, rng: np.random.Generator) -> Davis:
    """Manufacturer values times 1 +- U(min(0.05, spread), spread), sign random, per coefficient."""
    if spread <= 0.0:
        return train.davis
    lo = min(0.05, spread)
    factors = 1.0 + rng.choice([-1.0, 1.0], size=3) * rng.uniform(lo, spread, size=3)
    r0, r1, r2 = (c * f for c, f in zip(train.davis.as_tuple(), factors))
    return Davis(float(r0), float(r1), float(r2))


def _label(period: float) -> str:
    return f"{period:g}s"


def run(args: argparse.Namespace) -> int:
    from ..sim import DriverParams, SensorParams, simulate_run, write_run
    from ..sim.simulator import resolve_stations

    _check(args.runs >= 1, "--runs", f"must be at least 1, found {args.runs}")
    _check(args.first_index >= 0, "--first-index", f"must be at least 0, found {args.first_index}")
    _check(args.seed >= 0, "--seed", f"must be at least 0, found {args.seed}")
    for option, value in (
        ("--period", args.period),
        ("--gnss-period", args.gnss_period),
        ("--speed-period", args.speed_period),
        ("--power-period", args.power_period),
    ):
        if value is not None:
            _check(0.01 <= value <= 600.0, option, f"must be within [0.01, 600] s, found {value:g}")
    _check(args.gnss_noise >= 0.0, "--gnss-noise", f"must be at least 0 m, found {args.gnss_noise:g}")
    _check(args.speed_noise >= 0.0, "--speed-noise", f"must be at least 0 km/h, found {args.speed_noise:g}")
    _check(
        0.0 <= args.speed_quantum <= 10.0,
        "--speed-quantum",
        f"must be within [0, 10] km/h, found {args.speed_quantum:g}",
    )
    _check(0.0 <= args.gnss_dropout <= 1.0, "--gnss-dropout", f"must be within [0, 1], found {args.gnss_dropout:g}")
    _check(
        0.0 <= args.resistance_spread <= 0.9,
        "--resistance-spread",
        f"must be within [0, 0.9], found {args.resistance_spread:g}",
    )
    if args.power_period is not None:
        _check(args.power, "--power-period", "needs --power")
    start_ns = _start_ns(args.start_time)

    track = load_track(track_file(args.track))
    train = load_train(train_file(args.train))
    _, s0, _, s1 = resolve_stations(track, args.start_station, args.stop_station)
    scale = min(1.0, (s1 - s0) / REFERENCE_DISTANCE_M)
    coast_min = args.coast_min if args.coast_min is not None else 150.0 * scale
    coast_max = args.coast_max if args.coast_max is not None else 600.0 * scale
    _check(coast_min >= 0.0, "--coast-min", f"must be at least 0 s, found {coast_min:g}")
    _check(
        coast_max >= coast_min, "--coast-max", f"must be at least --coast-min ({coast_min:g} s), found {coast_max:g}"
    )

    period = args.period
    sensors = SensorParams(
        gnss_period_s=args.gnss_period or period,
        speed_period_s=args.speed_period or period,
        power_period_s=(args.power_period or period) if args.power else 0.0,
        gnss_noise_m=args.gnss_noise,
        gnss_dropout=args.gnss_dropout,
        speed_noise_kmh=args.speed_noise,
        speed_quantum_kmh=args.speed_quantum,
    )
    prefix = args.name or f"{track.name}_{_label(period)}"
    out = Path(args.out)
    names = [f"{prefix}_{k:02d}" for k in range(args.first_index, args.first_index + args.runs)]
    for name in names:
        for suffix in ("", ".truth.csv", ".truth.json"):
            if (out / f"{name}{suffix}").exists():
                raise UsageError(f"{out / (name + suffix)}: already exists (remove it or choose another --out/--name)")
    styles = ("hold", "cycles") if args.style == "mixed" else (args.style,)
    for k, name in zip(range(args.first_index, args.first_index + args.runs), names):
        rng = np.random.default_rng([args.seed, k])
        resistance = true_resistance(train, args.resistance_spread, rng)
        if args.minimum_time:
            driver = DriverParams.minimum_time(b_limit=train.max_brake_decel, b_stop=train.max_brake_decel)
        else:
            driver = DriverParams.sample(
                rng, train=train, coast_range_s=(coast_min, coast_max), styles=styles, wind=args.wind
            )
        sim = simulate_run(
            track,
            train,
            driver=driver,
            sensors=sensors,
            rng=rng,
            resistance=resistance,
            start_station=args.start_station,
            stop_station=args.stop_station,
            start_time_ns=start_ns + k * 86_400_000_000_000,
            seed=[args.seed, k],
        )
        sim.meta["command"] = _command_line(args, k)
        bag = write_run(sim, out, name, dense=args.dense)
        if not args.quiet:
            summ = sim.meta["summary"]
            print(
                f"{bag}: {summ['run_time_s']:.1f} s over {summ['distance_m'] / 1000:.3f} km, "
                f"{driver.cruise_style} at {driver.theta_cruise:.3f} x limit, "
                f"final coast {summ['final_coast_s']:.0f} s, "
                f"true r0 {resistance.r0:.4g} r1 {resistance.r1:.4g} r2 {resistance.r2:.4g}, "
                f"{summ['gnss_fixes']} fixes, {summ['speed_samples']} speeds, {summ['power_samples']} powers"
            )
    return 0


def _command_line(args: argparse.Namespace, index: int) -> str:
    """The command that regenerates this one run (recorded in the truth JSON)."""
    parts = [
        "train-calib",
        "simulate",
        "--track",
        args.track,
        "--train",
        args.train,
        "--seed",
        str(args.seed),
        "--first-index",
        str(index),
        "--runs",
        "1",
        "--period",
        f"{args.period:g}",
    ]
    for option, value in (
        ("--gnss-period", args.gnss_period),
        ("--speed-period", args.speed_period),
        ("--power-period", args.power_period),
        ("--coast-min", args.coast_min),
        ("--coast-max", args.coast_max),
        ("--start-station", args.start_station),
        ("--stop-station", args.stop_station),
        ("--name", args.name),
    ):
        if value is not None:
            parts += [option, f"{value:g}" if isinstance(value, float) else str(value)]
    if args.gnss_noise != 4.0:
        parts += ["--gnss-noise", f"{args.gnss_noise:g}"]
    if args.gnss_dropout:
        parts += ["--gnss-dropout", f"{args.gnss_dropout:g}"]
    if args.speed_noise != 0.5:
        parts += ["--speed-noise", f"{args.speed_noise:g}"]
    if args.speed_quantum != 1.0:
        parts += ["--speed-quantum", f"{args.speed_quantum:g}"]
    if args.resistance_spread != 0.2:
        parts += ["--resistance-spread", f"{args.resistance_spread:g}"]
    if args.style != "mixed":
        parts += ["--style", args.style]
    if args.start_time != DEFAULT_START:
        parts += ["--start-time", args.start_time]
    for flag in ("power", "wind", "minimum_time", "dense"):
        if getattr(args, flag):
            parts.append("--" + flag.replace("_", "-"))
    return shlex.join(parts)
