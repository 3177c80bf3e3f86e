"""Build a track file from recorded runs' GNSS (geometry, stations) and a profile (gradients, limits, curves).

The fixes of every run (same running direction) are averaged into one polyline; the stops found in the runs are
the stations. The profile -- a TTOBench track JSON, or CSV tables ``s_m,permille``, ``s_m,kmh``, ``s_m,radius_m``
-- is mapped onto it through the stops (all of them when the counts agree, else the first and last). Without a
profile the gradients come from the recorded GNSS altitude, smoothed, with their uncertainty written in the file.
See docs/import.md.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from ..errors import TrainCalibError

NAME = "build-track"
HELP = "build a track file from recorded GNSS and a gradient/limit profile"


class UsageError(TrainCalibError):
    """A command-line value the user can fix (one line)."""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--gnss", nargs="+", required=True, metavar="BAG", help="bags of runs along the line")
    parser.add_argument(
        "--profile", nargs="+", default=[], metavar="FILE", help="TTOBench track JSON and/or CSV tables"
    )
    parser.add_argument("--name", required=True, help="track name")
    parser.add_argument("--out", required=True, help="track file to write (YAML; must not exist)")
    parser.add_argument(
        "--profile-stops",
        help="positions of the stops in a CSV profile's s_m, comma-separated (default: s_m 0 = the first stop)",
    )
    parser.add_argument("--margin", type=float, default=300.0, help="track before the first/after the last stop, m")
    parser.add_argument("--grade-step", type=float, default=400.0, help="altitude gradient segment, m (no profile)")


def run(args: argparse.Namespace) -> int:
    from ..track import load_track
    from ..trackbuild.build import BuildOptions, build_track, track_yaml_text

    out = Path(args.out)
    if out.exists():
        raise UsageError(f"{out}: already exists")
    if not 0.0 <= args.margin <= 5000.0:
        raise UsageError(f"--margin: must be within [0, 5000] m, found {args.margin:g}")
    if not 50.0 <= args.grade_step <= 10000.0:
        raise UsageError(f"--grade-step: must be within [50, 10000] m, found {args.grade_step:g}")
    stops = None
    if args.profile_stops:
        try:
            stops = [float(x) for x in args.profile_stops.split(",")]
        except ValueError:
            raise UsageError(f"--profile-stops: {args.profile_stops!r} is not comma-separated numbers") from None
    options = BuildOptions(args.name, margin_m=args.margin, grade_step_m=args.grade_step, profile_stops=stops)
    built = build_track([Path(b) for b in args.gnss], [Path(p) for p in args.profile], options)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(track_yaml_text(built), encoding="utf-8")
    try:
        track = load_track(out)
    except TrainCalibError:
        out.rename(out.with_suffix(out.suffix + ".rejected"))
        raise
    for line in built.comments:
        if not line.startswith("per segment"):
            print(line)
    print(f"{out}: {track.name}: {track.length_m / 1000:.3f} km, {len(track.stations)} stations, "
          f"{track.gradient.breaks.size} gradient steps, {track.speed_limit.breaks.size} limits")  # fmt: skip
    return 0
