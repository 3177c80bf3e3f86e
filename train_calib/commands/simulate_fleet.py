"""Simulate a fleet with known truth: units with their own running resistance drifting over a year and a few
faulty units whose resistance rises; writes the bags, DIR/manifest.csv (for ``train-calib fleet``) and
DIR/fleet_truth.json. See docs/fleet.md and ``train_calib.fleet.simulate``.
"""

from __future__ import annotations

import argparse

from ..errors import TrainCalibError

NAME = "simulate-fleet"
HELP = "simulate a fleet (units drifting over a year, a few faulty) with a manifest for train-calib fleet"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from ..fleet.simulate import FleetSpec

    d = FleetSpec()
    parser.add_argument("--out", required=True, metavar="DIR", help="output directory (must not hold a fleet)")
    parser.add_argument("--units", type=int, default=d.units, help="units (default %(default)s)")
    parser.add_argument("--faulty", type=int, default=d.faulty, help="faulty units (default %(default)s)")
    parser.add_argument("--runs-per-unit", type=int, default=d.runs_per_unit, help="default %(default)s")
    parser.add_argument("--seed", type=int, default=d.seed, help="default %(default)s")
    parser.add_argument("--track", default=d.track, help="bundled track (default %(default)s)")
    parser.add_argument("--train", default=d.train, help="bundled train (default %(default)s)")
    parser.add_argument("--period", type=float, default=d.period_s, help="GNSS and speed period, s (default 10)")
    parser.add_argument("--start", default=d.start, help="first day, ISO 8601 (default %(default)s)")
    parser.add_argument("--days", type=float, default=d.days, help="days covered (default %(default)s)")
    parser.add_argument("--fault-rise", type=float, default=d.fault_rise,
                        help="faulty units' rise of r(v) over a year, fraction (default %(default)s)")  # fmt: skip
    parser.add_argument("--quiet", action="store_true", help="print nothing but errors")


class UsageError(TrainCalibError):
    """A command-line value the user can fix."""


def run(args: argparse.Namespace) -> int:
    from pathlib import Path

    from ..fleet.simulate import FleetSpec, simulate_fleet

    if args.units < 1 or not 0 <= args.faulty <= args.units:
        raise UsageError(
            f"--units/--faulty: need units >= 1 and 0 <= faulty <= units, found {args.units}/{args.faulty}"
        )
    if args.runs_per_unit < 1:
        raise UsageError(f"--runs-per-unit: must be at least 1, found {args.runs_per_unit}")
    if not 0.01 <= args.period <= 600.0:
        raise UsageError(f"--period: must be within [0.01, 600] s, found {args.period:g}")
    if (Path(args.out) / "manifest.csv").exists():
        raise UsageError(f"{Path(args.out) / 'manifest.csv'}: already exists (choose another --out)")
    spec = FleetSpec(units=args.units, faulty=args.faulty, runs_per_unit=args.runs_per_unit, seed=args.seed,
                     track=args.track, train=args.train, period_s=args.period, start=args.start, days=args.days,
                     fault_rise=args.fault_rise)  # fmt: skip
    manifest = simulate_fleet(args.out, spec, quiet=args.quiet)
    if not args.quiet:
        print(f"{manifest}: {spec.units * spec.runs_per_unit} runs of {spec.units} units ({spec.faulty} faulty)")
    return 0
