"""Replay the bundled default bag through the full node graph and print what the nodes found.

The bag (bags/intercity_32km_10s_00: a simulated VIRM-VI run on the 32 km intercity line, 10 s sampling
as in Cunillera et al. 2022) is replayed as fast as the graph keeps up; the summary compares the
running-resistance estimate with the manufacturer values and with the simulated truth beside the bag,
and lists the regime shares and driving features. Outputs go to demo_output/ (or --out).

The UKF runs the ``converging`` preset (config/ukf_converging.yaml): with the paper's Table 1 settings (the node
defaults, ``--ukf-preset paper``) the estimate stays at the train file's values, so a demo would show nothing learnt.
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
DEFAULT_UKF_PRESET = "converging"
PRESET_NOTE = {
    "converging": "UKF preset: converging (config/ukf_converging.yaml), which learns r0, r1, r2 from the run; the "
    "paper's Table 1 settings (the node defaults) keep them at the train file's values. --ukf-preset paper gives "
    "Table 1.",
    "paper": "UKF preset: paper (Cunillera et al. 2022, Table 1; the node defaults): r0, r1, r2 stay near the train "
    "file's values. --ukf-preset converging learns them.",
}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--bag", default=DEFAULT_BAG, help="bundled bag name or a bag path (default %(default)s)")
    parser.add_argument("--out", type=Path, default=Path("demo_output"), help="output directory (default %(default)s)")
    add_common_arguments(parser)
    parser.set_defaults(overwrite=True, ukf_preset=DEFAULT_UKF_PRESET)


def run(args: argparse.Namespace) -> int:
    from ..summary import format_summary

    bag = Path(args.bag)
    if not bag.exists():
        bag = paths.bags_dir() / args.bag
    if not bag.exists():
        raise BagError(f"{bag}: bundled bag not found (run `train-calib simulate` or pass --bag)")
    args.bag = bag
    truth = load_truth(bag)
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


def _bundled(file_name: str | None, default: str, resolve) -> str:
    if file_name:
        stem = Path(file_name).stem
        if resolve(stem).exists():
            return stem
    return default
