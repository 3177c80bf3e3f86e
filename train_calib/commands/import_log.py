"""Import recorded logs (CSV, NMEA 0183, GPX 1.1) into an MCAP bag (rosbag2 layout) with the input topics.

Speed and position may come in separate files and at different rates: give every file of the run. Bad rows are
listed with their line and reason and skipped; the import says how many rows it used. The speed is checked against
the change of position: a unit mix-up (m/s vs km/h, knots) is refused. See docs/import.md.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from ..errors import TrainCalibError

NAME = "import"
HELP = "import CSV, NMEA 0183 or GPX logs into an MCAP bag with the input topics"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("logs", nargs="+", metavar="LOG", help="log file(s) of one run")
    parser.add_argument("--out", required=True, help="output bag (rosbag2 directory, must not exist)")
    parser.add_argument("--format", choices=("csv", "nmea", "gpx"), help="format of every LOG (default: detected)")
    parser.add_argument(
        "--columns",
        help="CSV column names: NAME=COLUMN,... for time, lat, lon, alt, speed, speed_kmh, speed_ms, "
        "power_consumed_w, power_regenerated_w",
    )
    parser.add_argument(
        "--speed-unit", choices=("kmh", "ms", "knots", "mph"), help="unit of the CSV speed column (overrides its name)"
    )
    parser.add_argument("--time-unit", choices=("s", "ms"), default="s", help="unit of numeric CSV times (default s)")
    parser.add_argument(
        "--start-time",
        default="2020-01-01T00:00:00Z",
        help="origin of numeric CSV times below 1e8 s (ISO 8601 with zone; default %(default)s)",
    )
    parser.add_argument("--gnss-sigma", type=float, default=5.0, help="GNSS 1-sigma written with each fix, m")
    parser.add_argument(
        "--no-speed-check", action="store_true", help="write the bag even if the speed contradicts the positions"
    )
    parser.add_argument("--quiet", action="store_true", help="print only errors and the final count")


class UsageError(TrainCalibError):
    """A command-line value the user can fix (one line)."""


def run(args: argparse.Namespace) -> int:
    from ..importers.convert import ImportOptions, import_logs
    from ..importers.csvlog import parse_columns
    from ..importers.timefmt import TimeError, parse_iso_ns

    if not 0.0 < args.gnss_sigma <= 1000.0:
        raise UsageError(f"--gnss-sigma: must be within (0, 1000] m, found {args.gnss_sigma:g}")
    try:
        start_ns = parse_iso_ns(args.start_time)
    except TimeError as exc:
        raise UsageError(f"--start-time: {exc}") from None
    out = Path(args.out)
    if out.exists():
        raise UsageError(f"{out}: output bag already exists")
    options = ImportOptions(
        fmt=args.format,
        columns=parse_columns(args.columns),
        speed_unit=args.speed_unit,
        time_unit=args.time_unit,
        start_ns=start_ns,
        gnss_sigma_m=args.gnss_sigma,
        speed_check=not args.no_speed_check,
    )
    lines: list[str] = []
    result = import_logs([Path(p) for p in args.logs], out, options, say=lines.append)
    for line in lines if not args.quiet else lines[-1:]:
        print(line)
    if result.speed_check.verdict == "refuse":
        print("warning: written despite the speed check (--no-speed-check)")
    return 0
