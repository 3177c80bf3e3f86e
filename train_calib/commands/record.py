"""Record topics to DIR/output.mcap in the rosbag2 layout (metadata.yaml beside it) until Ctrl-C.

By default every train_calib output topic and /diagnostics. The recording is closed properly on
SIGINT/SIGTERM (or after --duration), so the bag is complete and readable by rosbags, mcap and ros2 bag.
"""

from __future__ import annotations

import argparse
import signal
import sys
import threading
import time
from pathlib import Path

from ..bagio import INPUT_TOPICS, OUTPUT_TOPICS
from ..errors import ConfigError

NAME = "record"
HELP = "record the output topics (or others) to DIR/output.mcap until Ctrl-C"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", type=Path, default=Path("recording"), help="output directory (default %(default)s)")
    parser.add_argument(
        "--topics", nargs="+", metavar="TOPIC", help="topics to record (default: every output topic and /diagnostics)"
    )
    parser.add_argument("--inputs", action="store_true", help="also record the input topics")
    parser.add_argument("--duration", type=float, default=0.0, help="stop after this many seconds (0: until Ctrl-C)")
    parser.add_argument("--use-sim-time", action="store_true", help="stamp log times with /clock")


def run(args: argparse.Namespace) -> int:
    import rclpy
    from rclpy.context import Context
    from rclpy.signals import SignalHandlerOptions

    from ..nodes.runner import make_executor
    from ..record import McapBagWriter, Recorder

    known = OUTPUT_TOPICS | INPUT_TOPICS
    names = args.topics or list(OUTPUT_TOPICS) + (list(INPUT_TOPICS) if args.inputs else [])
    unknown = [t for t in names if t not in known]
    if unknown:
        raise ConfigError("record", "topics", f"unknown topic {unknown[0]} (known: {', '.join(known)})")
    topics = {t: known[t] for t in names}
    writer = McapBagWriter(args.out, topics)
    stop = threading.Event()
    previous = {s: signal.signal(s, lambda *_: stop.set()) for s in (signal.SIGINT, signal.SIGTERM)}
    context = Context()
    rclpy.init(args=[], context=context, signal_handler_options=SignalHandlerOptions.NO)
    try:
        node = rclpy.create_node("train_calib_recorder", context=context)
        # --use-sim-time: the recorder follows /clock itself (a /clock that is not a valid time is counted, not fatal)
        recorder = Recorder(node, writer, topics, sim_clock=bool(args.use_sim_time))
        executor = make_executor(context)
        executor.add_node(node)
        print(f"recording {', '.join(topics)} to {args.out}/output.mcap (Ctrl-C to stop)", file=sys.stderr, flush=True)
        end = time.monotonic() + args.duration if args.duration > 0 else float("inf")
        while not stop.is_set() and time.monotonic() < end:
            executor.spin_once(timeout_sec=0.1)
        # write what the DDS has already delivered: spin until nothing new for 0.3 s (at most 5 s)
        total, quiet, deadline = -1, time.monotonic(), time.monotonic() + 5.0
        while time.monotonic() - quiet < 0.3 and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.05)
            if sum(recorder.received.values()) != total:
                total, quiet = sum(recorder.received.values()), time.monotonic()
        executor.shutdown()
        node.destroy_node()
    finally:
        writer.close()
        rclpy.try_shutdown(context=context)
        for s, handler in previous.items():
            signal.signal(s, handler)
    total = sum(recorder.received.values())
    print(f"recorded {total} messages to {args.out}/output.mcap (+ metadata.yaml)")
    return 0
