"""The process side of a node: the executor (:func:`make_executor`) and :func:`run_node`, the ``main()`` of every
node (rclpy set-up, spinning until SIGINT/SIGTERM, a clean finish, one line and exit 2 on a bad configuration)."""

from __future__ import annotations

import os
import signal
import sys
import threading
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import rclpy
from rclpy.context import Context
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.signals import SignalHandlerOptions

from ..errors import ConfigError
from .ros_params import check_params_files

if TYPE_CHECKING:
    from .common import TrainCalibNode

RCLError = _rclpy.RCLError


def make_executor(context: Context, kind: str | None = None) -> Any:
    """The executor: ``events`` (rclpy's EventsExecutor, much lower latency) when available, else ``single``
    (SingleThreadedExecutor). Chosen by `kind`, else the TRAIN_CALIB_EXECUTOR environment variable.

    Why ``events`` is the default, measured with bench/bench_graph.py (bags/tunnel_line_37km_1s_00 replayed at
    rate 0; bench/RESULTS.md, section 3, the latest figures): the four estimator nodes handle 1501 speed samples/s
    with it and 285 with ``single`` (5.3x). Against a bare rclpy relay chain with the same hops and messages on the
    same executor, the graph reaches 74 % with ``events`` (the whole graph with window_calib_node: 72 %) and 80 %
    with ``single``: the nodes' own Python work (about 0.45 ms per speed sample over the raw chain: gnss_speed_node
    0.13, ukf_node 0.13, regime_node 0.08, feature_node 0.04, window_calib_node 0.10 ms) is the same under both
    executors and weighs less against the SingleThreadedExecutor's slower chain, which rebuilds its wait set in
    Python before every callback (the bare chain: about 2.8 ms per sample with it, 0.49 ms with ``events``). So the
    lower ratio of ``events`` comes from a faster baseline, not from a slower graph: with ``events`` the graph misses
    issue 9's 80 % (74 / 72 %), and ``single`` reaches it only by cutting the throughput 5x.
    """
    kind = kind or os.environ.get("TRAIN_CALIB_EXECUTOR", "events")
    if kind == "events":
        try:
            from rclpy.experimental import EventsExecutor
        except ImportError:
            return SingleThreadedExecutor(context=context)
        # EventsExecutor enables faulthandler on sys.stderr, which needs a real file (not a capture)
        stderr = sys.stderr
        try:
            sys.stderr.fileno()
        except (AttributeError, OSError, ValueError):
            sys.stderr = sys.__stderr__
        try:
            return EventsExecutor(context=context)
        finally:
            sys.stderr = stderr
    return SingleThreadedExecutor(context=context)


def run_node(node_cls: type[TrainCalibNode], args: Sequence[str] | None = None) -> int:
    """Spin one node until SIGINT/SIGTERM, then finish it cleanly; 2 with a one-line error on bad config."""
    argv = list(args) if args is not None else list(sys.argv)
    context = Context()
    try:
        check_params_files(argv)
        rclpy.init(args=argv, context=context, signal_handler_options=SignalHandlerOptions.NO)
    except ConfigError as exc:
        print(f"{node_cls.NODE_NAME}: error: {exc}", file=sys.stderr)
        return 2
    except RCLError as exc:  # a ROS argument rcl refuses: its first line, without the C source locations
        print(f"{node_cls.NODE_NAME}: error: {str(exc).splitlines()[0].split(', at /')[0]}", file=sys.stderr)
        return 2
    stop = threading.Event()

    def on_signal(signum: int, frame: Any) -> None:
        stop.set()

    previous = {sig: signal.signal(sig, on_signal) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        try:
            node = node_cls(context=context)
        except ConfigError as exc:
            print(f"{node_cls.NODE_NAME}: error: {exc}", file=sys.stderr)
            return 2
        executor = make_executor(context)
        executor.add_node(node)
        try:
            while not stop.is_set() and context.ok():
                executor.spin_once(timeout_sec=0.1)
        except (KeyboardInterrupt, ExternalShutdownException):
            pass
        finally:
            if context.ok():
                node.finish()
            executor.shutdown()
            node.destroy_node()
        return 0
    finally:
        rclpy.try_shutdown(context=context)
        for sig, handler in previous.items():
            signal.signal(sig, handler)
