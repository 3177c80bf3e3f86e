"""Predict every coast of a recorded run from its measured start (s, v) to its measured end position, with the
train file's r(v), the run's causal estimate at the coast's start and optionally a given resistance; compare with
the bag. Writes DIR/coasts.csv (one row per coast and model), DIR/prediction.json (per-model medians, traction
energy with traction power) and DIR/prediction.png. docs/prediction.md.
"""

from __future__ import annotations

import argparse
from pathlib import Path

NAME = "predict"
HELP = "predict every coast of a recorded run per model (train file, causal estimate, --resistance) against the bag"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("bag", type=Path, help="rosbag2 directory or .mcap file with the input topics")
    parser.add_argument("--track", required=True, help="track file or bundled track name (config/tracks)")
    parser.add_argument("--train", required=True, help="train file or bundled train name (config/trains)")
    parser.add_argument("--out", required=True, type=Path, metavar="DIR", help="output directory")
    parser.add_argument(
        "--resistance",
        metavar="SOURCE",
        help="the 'given' model: r0,r1,r2 (N/kg, N/(kg m/s), N/(kg (m/s)^2)), another replay's summary.json, or a "
        "fleet's units.parquet[:UNIT]",
    )
    parser.add_argument("--min-coast", type=float, default=30.0, metavar="S",
                        help="shortest coast predicted, s (default %(default)s)")  # fmt: skip
    parser.add_argument("--edge-fit", type=float, default=30.0, metavar="S",
                        help="start speed of a coast: a line through its measured speeds over its first S seconds; "
                        "0: the first sample alone (default %(default)s)")  # fmt: skip
    parser.add_argument("--quiet", action="store_true", help="print nothing but errors")


def run(args: argparse.Namespace) -> int:
    import json
    import math

    from .. import paths
    from ..estimation.config import UKFConfig
    from ..pipeline import run_bag
    from ..prediction.offline import (
        ResistanceSourceError,
        find_coasts,
        model_stats,
        plot,
        predict_coasts,
        resistance_source,
        traction_energy,
        write_csv,
    )
    from ..track import load_track
    from ..train import load_train

    for option, value in (("--min-coast", args.min_coast), ("--edge-fit", args.edge_fit)):
        if not (math.isfinite(value) and value >= 0.0):
            raise ResistanceSourceError(f"{option}: must be a non-negative number of seconds, found {value}")
    track = load_track(paths.track_file(args.track))
    train = load_train(paths.train_file(args.train))
    given = resistance_source(args.resistance, train) if args.resistance is not None else None
    out_dir: Path = args.out
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ResistanceSourceError(f"--out {out_dir}: cannot create ({exc.strerror})") from None
    ukf = UKFConfig()
    output = run_bag(args.bag, track, train, ukf=ukf)
    coasts = find_coasts(output, args.min_coast, edge_fit_s=args.edge_fit)
    rows = predict_coasts(coasts, track, train, given, ukf=ukf)
    write_csv(out_dir / "coasts.csv", rows)
    summary = {
        "bag": str(args.bag),
        "track": track.name,
        "train": train.name,
        "min_coast_s": args.min_coast,
        "edge_fit_s": args.edge_fit,
        "coasts": len(coasts),
        "models": model_stats(rows),
        "models_coasts_2min": model_stats(rows, 120.0),
        "given": None
        if given is None
        else {"source": given.source, "r0": given.r[0], "r1": given.r[1], "r2": given.r[2]},
        "traction_energy": traction_energy(output, train, given),
    }
    if not coasts:
        summary["note"] = f"no coast of at least {args.min_coast:g} s in the run: the table is empty"
    (out_dir / "prediction.json").write_text(json.dumps(summary, indent=1) + "\n", encoding="utf-8")
    plot(out_dir / "prediction.png", rows, f"{Path(args.bag).name}: {len(coasts)} coasts")
    if not args.quiet:
        print(f"{out_dir / 'coasts.csv'}: {len(coasts)} coasts x {2 + (given is not None)} models")
        if not coasts:
            print(f"note: {summary['note']}")
        for name, st in summary["models"].items():
            print(f"  {name:10s} end speed error median {st['end_speed_error_kmh_median']:.2f} km/h "
                  f"(p90 {st['end_speed_error_kmh_p90']:.2f}), duration {st['duration_error_pct_median']:.1f} %, "
                  f"inside 2 sigma {st['inside_2sigma_share'] * 100:.0f} %")  # fmt: skip
        energy = summary["traction_energy"]
        if energy:
            parts = ", ".join(f"{m} {energy[f'{m}_kwh']:.1f}" for m in ("train_file", "causal", "given")
                              if f"{m}_kwh" in energy)  # fmt: skip
            print(f"  traction energy: metered {energy['measured_kwh']:.1f} kWh; for the measured profile {parts} kWh")
    return 0
