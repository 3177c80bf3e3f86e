"""Replay the bundled default bag through the full node graph and print what the nodes found.

The bag (bags/intercity_32km_10s_00: a simulated VIRM-VI run on the 32 km intercity line, 10 s sampling
as in Cunillera et al. 2022) is replayed as fast as the graph keeps up; the summary compares the
running-resistance estimate with the manufacturer values and with the simulated truth beside the bag,
and lists the regime shares and driving features. Outputs go to demo_output/ (or --out).

The UKF runs the defaults (preset ``learning``: r from the run's coasting stretches, docs/estimator.md);
``--ukf-preset paper`` gives Table 1 (the estimate stays at the train file's values), ``--ukf-preset converging`` the
earlier learning preset.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from .. import paths
from ..errors import BagError
from .replay import add_common_arguments, execute, exit_status, load_truth, report_input_error

NAME = "demo"
HELP = "replay the bundled default bag through the node graph and print a summary"

DEFAULT_BAG = "intercity_32km_10s_00"
DEFAULT_UKF_PRESET = None  # the node defaults: preset learning
PRESET_NOTE = {
    None: "UKF preset: learning (the node defaults): r0, r1, r2 learnt from the run's coasting stretches, from the "
    "train file's values with about 19 % std of r(v). --ukf-preset paper gives Table 1.",
    "learning": "UKF preset: learning (the node defaults): r0, r1, r2 learnt from the run's coasting stretches.",
    "converging": "UKF preset: converging (config/ukf_converging.yaml): r in the UKF state, learnt from confirmed "
    "coasting and traction power.",
    "paper": "UKF preset: paper (Cunillera et al. 2022, Table 1): r0, r1, r2 stay near the train file's values.",
}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--bag", default=DEFAULT_BAG, help="bundled bag name or a bag path (default %(default)s)")
    parser.add_argument("--out", type=Path, default=Path("demo_output"), help="output directory (default %(default)s)")
    add_common_arguments(parser)
    parser.set_defaults(overwrite=True, ukf_preset=DEFAULT_UKF_PRESET)


def run(args: argparse.Namespace) -> int:
    from ..summary_text import format_summary

    bag = Path(args.bag)
    if not bag.exists():
        bag = paths.bags_dir() / args.bag
    if not bag.exists():
        raise BagError(missing_bag(str(args.bag)))
    args.bag = bag
    truth = load_truth(bag, args.truth)
    meta = truth["meta"] if truth else {}
    track = _bundled(meta.get("track", {}).get("file"), "intercity_32km", paths.track_file)
    train = _bundled(meta.get("train", {}).get("file"), "virm6", paths.train_file)
    args.overwrite = True
    if not args.quiet:
        print(
            f"train-calib demo: replaying {bag} (track {track}, train {train}) through the node graph...",
            file=sys.stderr,
            flush=True,
        )
    summary = execute(args, args.out, track, train)
    if args.ukf_preset in PRESET_NOTE:
        print(PRESET_NOTE[args.ukf_preset])
    print(format_summary(summary))
    out = args.out
    print(
        f"\nOutputs in {out}/: output.mcap (every output topic, rosbag2 layout with metadata.yaml), "
        f"summary.json" + ("" if args.no_report else ", report.png")
    )
    report_input_error(NAME, summary)
    return exit_status(summary)


def bundled_bags() -> list[str]:
    """Names of the bags in bags/ (rosbag2 directories and bare .mcap files)."""
    folder = paths.bags_dir()
    if not folder.is_dir():
        return []
    names = [p.name for p in folder.iterdir() if p.is_dir() and (p / "metadata.yaml").is_file()]
    names += [p.name for p in folder.iterdir() if p.is_file() and p.suffix == ".mcap"]
    return sorted(names)


def missing_bag(name: str) -> str:
    """One line: the --bag that was not found, and the bundled names."""
    bundled = bundled_bags()
    listed = ", ".join(bundled) if bundled else f"none in {paths.bags_dir()} (train-calib simulate makes some)"
    return f"--bag {name}: no such bag (neither a path nor a bundled name; bundled: {listed})"


def _bundled(file_name: str | None, default: str, resolve) -> str:
    if file_name:
        stem = Path(file_name).stem
        if resolve(stem).exists():
            return stem
    return default
