"""Replay a bag through the node graph: record every output, write summary.json and report.png.

The bag's input topics (/gnss/fix, /train/speed, optional /train/traction_power) are published with
their recorded timing scaled by --rate (0: as fast as the graph keeps up, with flow control: nothing is
lost) and /clock; the nodes run with use_sim_time in this process (one executor) or, with
--processes, each in its own process. Outputs in DIR: output.mcap + metadata.yaml (a rosbag2 bag,
DIR/output.mcap a complete MCAP file), summary.json, report.png. See docs/nodes.md.

Exit status: 0; 2 with one line when the input or the configuration is unreadable (nothing replayed); 3 with
one line when the input bag is damaged (truncated, corrupt chunks, undecodable messages: what could be read
was replayed, the outputs are complete for it, summary.json has ``input_error``); 4 with one line when every speed
sample was dropped, none reached the filter (most often the wrong --track: the fixes lie off its line; output.mcap
and summary.json, with ``no_samples``, hold what was recorded, no report.png); 130 (SIGINT) or 143
(SIGTERM) when interrupted (the outputs hold everything processed until then; a second signal aborts).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ..bagio import bag_name
from ..errors import BagError
from ..isolation import MAX_DOMAIN_ID

if TYPE_CHECKING:  # the command imports the core lazily
    from ..estimation.config import RegimeConfig

NAME = "replay"
HELP = "replay a bag through the node graph; write output.mcap, summary.json, report.png"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("bag", type=Path, help="rosbag2 directory or .mcap file with the input topics")
    parser.add_argument("--track", required=True, help="track file or bundled track name (config/tracks)")
    parser.add_argument("--train", required=True, help="train file or bundled train name (config/trains)")
    add_common_arguments(parser)
    parser.add_argument("--out", type=Path, help="output directory (default out/<bag name>)")


def playback_rate(text: str) -> float:
    """--rate: a finite number >= 0."""
    try:
        rate = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not (math.isfinite(rate) and rate >= 0):
        raise argparse.ArgumentTypeError(f"{text} is out of range: must be a finite number, at least 0")
    return rate


def domain_id(text: str) -> int:
    """--domain-id: 0..232."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not an integer") from None
    if not 0 <= value <= MAX_DOMAIN_ID:
        raise argparse.ArgumentTypeError(f"{value} is out of range: must be 0..{MAX_DOMAIN_ID}")
    return value


def add_common_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--rate",
        type=playback_rate,
        default=0.0,
        help="playback rate, 1 = real time (default 0: as fast as the graph keeps up)",
    )
    parser.add_argument("--processes", action="store_true", help="run each node in its own process")
    parser.add_argument(
        "--params-file",
        type=Path,
        action="append",
        default=[],
        metavar="F",
        help="ROS 2 params file for the nodes (repeatable; e.g. config/train_calib.yaml)",
    )
    parser.add_argument(
        "--ukf-preset",
        choices=("learning", "paper", "converging"),
        help="ukf_node parameters of a preset (docs/estimator.md): learning (the defaults: r learnt from the run's "
        "coasting), paper (Table 1, config/ukf_paper.yaml) or converging (config/ukf_converging.yaml); --params-file "
        "values still override",
    )
    parser.add_argument(
        "--window",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="run window_calib_node, the sliding-window calibration with traction power (default: when the bag has "
        "/train/traction_power; --no-window: never)",
    )
    parser.add_argument(
        "--executor",
        choices=("events", "single"),
        default="events",
        help="executor in one process (default events: rclpy's EventsExecutor)",
    )
    parser.add_argument(
        "--wait-for-subscribers",
        type=int,
        default=0,
        metavar="N",
        help="start when N other nodes (a DAS) subscribe to output topics, each subscription matched (needs --live "
        "or --domain-id)",
    )
    parser.add_argument(
        "--live",
        action="store_true",
        help="also publish the inputs, /clock and every output into your ROS environment (ROS_DOMAIN_ID, discovery "
        "range) for a DAS or rviz; the graph itself stays isolated and takes nothing in from there",
    )
    parser.add_argument(
        "--domain-id",
        type=domain_id,
        metavar="N",
        help="run the graph itself in ROS domain N with your discovery settings (not isolated: other graphs in N "
        "exchange messages with it). Default: a free domain of its own, localhost only",
    )
    parser.add_argument(
        "--truth",
        type=Path,
        metavar="FILE",
        help="simulated truth JSON with resistance r0, r1, r2 to compare with: the simulator's or a validation run's "
        "(default: <bag>.truth.json when it is the simulator's own, else <bag>.validation-truth.json; any other file "
        "there is ignored with a note)",
    )
    parser.add_argument("--overwrite", action="store_true", help="replace the outputs of a previous replay in DIR")
    parser.add_argument("--no-report", action="store_true", help="do not draw report.png")
    parser.add_argument(
        "--quiet", action="store_true", help="print only errors and the output location (the nodes log warnings only)"
    )


SIM_TRUTH_FORMAT = "train_calib.sim/"  # the "format" of the simulator's <bag>.truth.json ("train_calib.sim/1")


VALIDATION_TRUTH_SUFFIX = ".validation-truth.json"  # ../shared/validation/README.md: r0, r1, r2 at the top level


def read_truth_file(path: Path) -> dict[str, Any]:
    """The simulated resistance of a truth JSON: the simulator's (``{"resistance": {"r0", "r1", "r2"}, ...}``) or a
    validation truth (``NAME.validation-truth.json``: ``r0``, ``r1``, ``r2`` in N/kg at the top level); BagError (one
    line) when it has none."""
    try:
        meta = json.loads(path.read_text(encoding="utf-8"))
        resistance = meta["resistance"] if isinstance(meta, dict) and "resistance" in meta else meta
        values = {k: float(resistance[k]) for k in ("r0", "r1", "r2")}
    except FileNotFoundError:
        raise BagError(f"{path}: truth file not found") from None
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise BagError(
            f"{path}: not a truth file with resistance r0, r1, r2: {exc.__class__.__name__}: {exc}"
        ) from None
    return {**values, "file": str(path), "meta": meta}


def load_truth(
    bag: Path, truth_file: Path | None = None, note: Callable[[str], None] | None = None
) -> dict[str, Any] | None:
    """The simulated truth: `truth_file` when given (--truth; BagError when it holds none), else ``<bag>.truth.json``
    when it is the simulator's own (``"format": "train_calib.sim/N"`` with the resistance), else
    ``<bag>.validation-truth.json`` (the validation runs' truth), else None. Any other file beside the bag never
    stops a replay: it is ignored with a one-line `note`."""
    from ..sim.truthio import truth_paths

    if truth_file is not None:
        return read_truth_file(Path(truth_file))
    path = truth_paths(bag)[1]
    validation = path.with_name(path.name.removesuffix(".truth.json") + VALIDATION_TRUTH_SUFFIX)
    if not path.is_file():
        if not validation.is_file():
            return None
        path = validation
    try:
        meta = json.loads(path.read_text(encoding="utf-8"))
        known = path == validation or (
            isinstance(meta, dict) and str(meta.get("format", "")).startswith(SIM_TRUTH_FORMAT)
        )
        truth = read_truth_file(path) if known else None
    except (OSError, ValueError, BagError) as exc:
        known, truth = False, None
        reason = str(exc).removeprefix(f"{path}: ")
    else:
        reason = "not the simulator's truth format" if not known else ""
    if truth is None and note is not None:
        note(f"note: {path}: {reason or 'unreadable'}; ignored (--truth FILE gives the truth)")
    return truth


def regime_parameters(params_files: list[str]) -> RegimeConfig:
    """regime_node's parameters from the ``--params-file`` files, as the nodes read them (a later file's value wins),
    for the whole run's regimes in summary.json (the defaults where no file sets one)."""
    from dataclasses import fields, replace

    from ..estimation.config import RegimeConfig
    from ..fleet.params import load_fleet_params

    default = config = RegimeConfig()
    for path in params_files:
        given = load_fleet_params(path).configs.get("regime")
        if given is not None:  # the values the file sets (those that differ from the defaults)
            names = [f.name for f in fields(given) if getattr(given, f.name) != getattr(default, f.name)]
            config = replace(config, **{name: getattr(given, name) for name in names})
    return config


def execute(args: argparse.Namespace, out: Path, track: str, train: str) -> dict[str, Any]:
    """Replay, then summary.json and report.png; returns the summary."""
    from .. import paths
    from ..replay import ReplayOptions, replay
    from ..report import write_report
    from ..summary import read_outputs, summarize, write_summary
    from ..track import load_track
    from ..train import load_train

    log = (lambda text: None) if args.quiet else (lambda text: print(text, file=sys.stderr, flush=True))
    truth = load_truth(args.bag, args.truth, note=log)
    with tempfile.TemporaryDirectory(prefix="train_calib_preset_") as tmp:
        params_files = tuple(args.params_file)
        if args.ukf_preset:
            preset = Path(tmp) / f"ukf_{args.ukf_preset}.yaml"
            preset.write_text(preset_params_yaml(args.ukf_preset), encoding="utf-8")
            params_files = (preset, *params_files)
            log(f"ukf_node: preset {args.ukf_preset}")
        result = replay(
            ReplayOptions(
                bag=args.bag,
                track=track,
                train=train,
                out=out,
                rate=args.rate,
                processes=args.processes,
                params_files=params_files,
                window=args.window,
                executor=args.executor,
                wait_for_subscribers=args.wait_for_subscribers,
                overwrite=args.overwrite,
                log=log,
                domain_id=args.domain_id,
                live=args.live,
                quiet_nodes=args.quiet,
            )
        )
    train_spec = load_train(paths.train_file(train))
    outputs = read_outputs(result.output_bag)
    regime_config = regime_parameters(args.params_file)
    truth_values = {k: truth[k] for k in ("r0", "r1", "r2")} if truth else None
    summary = summarize(
        outputs,
        train=train_spec,
        truth=truth_values,
        regime=regime_config,
        extra={
            "bag": str(args.bag),
            "track": track,
            "train_file": train,
            "mode": result.mode,
            "executor": result.executor,
            "rate": args.rate,
            "ukf_preset": configuration_name(args),
            "nodes": list(result.nodes),
            "wall_time_s": round(result.wall_s, 3),
            "bag_duration_s": round(result.bag_duration_s, 3),
            "interrupted": result.interrupted,
            "signal": result.signal,
            "input_error": result.input_error,
            "input_undecodable": result.undecodable,
            "input_counts": result.sent,
            "truth_file": truth["file"] if truth else None,
            "ros_domain_id": result.domain_id,
            "isolated": result.isolated,
            "live": result.live,
        },
    )
    summary["no_samples"] = no_samples_error(args.bag, track, result.sent, result.recorded, summary, result.interrupted)
    write_summary(out / "summary.json", summary)
    if summary["no_samples"]:
        log("report.png not drawn: no sample reached the filter")
    elif not args.no_report:
        title = f"{bag_name(args.bag)}: {train_spec.name}, UKF estimate (layout of Cunillera et al. 2022, Fig. 3 and 6)"
        try:
            write_report(
                out / "report.png",
                outputs,
                train_spec,
                track=load_track(paths.track_file(track)),
                truth=truth_values,
                title=title,
                best=summary.get("best"),
                configuration=summary.get("ukf_preset", ""),
            )
        except Exception as exc:  # a plot must not cost the outputs (e.g. an interrupted replay with no estimate)
            log(f"report.png not drawn: {exc.__class__.__name__}: {exc}")
    log(
        f"replayed {sum(result.sent.values())} input messages in {result.wall_s:.1f} s "
        f"({result.mode}, {result.executor}); recorded {sum(result.recorded.values())} output messages"
    )
    return summary


def no_samples_error(
    bag: Path,
    track: str,
    sent: dict[str, int],
    recorded: dict[str, int],
    summary: dict[str, Any],
    interrupted: bool,
) -> str | None:
    """One line when the bag's speed samples were sent and none became a measurement (every one dropped: most
    often the wrong --track, the fixes off its line), else None."""
    speed = sent.get("/train/speed", 0)
    if interrupted or not speed or recorded.get("/train_calib/measurement", 0):
        return None
    ingest = summary.get("dropped", {}).get("gnss_speed_node", {})
    fixes = sent.get("/gnss/fix", 0)
    off = ingest.get("/gnss/fix", {}).get("off_track", 0)
    reasons = "; ".join(
        f"{topic} " + ", ".join(f"{r} {n}" for r, n in sorted(counts.items()))
        for topic, counts in sorted(ingest.items())
        if counts
    )
    line = f"{bag}: none of its {speed} speed samples reached the filter (dropped: {reasons or 'none counted'})"
    if off and off >= fixes // 2:
        line += f"; {off} of {fixes} GNSS fixes lie off track {track}: is --track the bag's line?"
    return line


def preset_params_yaml(name: str) -> str:
    """A params file with every UKFConfig parameter of ukf_node in a preset (config/ukf_<name>.yaml's values)."""
    from ..nodes.config import ukf_preset_yaml

    return ukf_preset_yaml(name)


def configuration_name(args: argparse.Namespace) -> str:
    """Which UKF configuration ran: the preset (``learning`` at the defaults), and whether params files override."""
    name = args.ukf_preset or "learning"
    return name + (" + --params-file" if getattr(args, "params_file", None) else "")


EXIT_OK = 0
EXIT_ERROR = 2  # unreadable input or configuration: nothing was replayed (one line on stderr)
EXIT_DAMAGED_INPUT = 3  # the input bag is damaged: what could be read was replayed, the outputs are complete for it
EXIT_NO_SAMPLES = 4  # every speed sample was dropped (e.g. the wrong --track): the outputs hold what was recorded


def exit_status(summary: dict[str, Any]) -> int:
    """0; 3 for a damaged input bag (outputs valid for what was read); 128 + signal when interrupted (130 SIGINT,
    143 SIGTERM: the outputs are valid and hold everything processed until then)."""
    if summary.get("interrupted"):
        return 128 + int(summary.get("signal") or 2)
    if summary.get("input_error"):
        return EXIT_DAMAGED_INPUT
    if summary.get("no_samples"):
        return EXIT_NO_SAMPLES
    return EXIT_OK


def report_input_error(command: str, summary: dict[str, Any]) -> None:
    if summary.get("input_error"):
        print(f"train-calib {command}: error: {summary['input_error']}", file=sys.stderr)
    elif summary.get("no_samples"):
        print(f"train-calib {command}: error: {summary['no_samples']}", file=sys.stderr)


def run(args: argparse.Namespace) -> int:
    from ..summary_text import format_summary

    out = args.out or Path("out") / bag_name(args.bag)
    summary = execute(args, out, args.track, args.train)
    if not args.quiet:
        print(format_summary(summary))
    print(
        f"outputs: {out}/output.mcap (+ metadata.yaml), {out}/summary.json"
        + ("" if args.no_report or summary.get("no_samples") else f", {out}/report.png")
    )
    report_input_error(NAME, summary)
    return exit_status(summary)
