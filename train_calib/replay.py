"""Replay a bag's input topics through the node graph and record every output (``train-calib replay``).

``Replay(options).run()`` checks the options and loads the inputs (:mod:`train_calib.replay_inputs`), opens the
publishers and the recording, starts the graph, streams the bag through it with the flow control of
:mod:`train_calib.replay_flow` (the bag's timing, ``/clock``, lockstep on the head of the graph, end of input) and
closes everything. The names other modules use (``__all__``, ``sets_parameter``) import from here as before.

Isolation: by default the graph (nodes, replay, recorder) runs in a ROS domain of its own with localhost-only
discovery (:mod:`train_calib.isolation`: an id no other replay, train_calib test run or participant on the host
uses, claimed for the replay's life; the node processes of ``processes=True`` get the same environment), so
concurrent replays, and a live graph on the host or the network, never exchange messages with it and the recorder
keeps only what its own nodes published. ``live=True`` also publishes into the caller's environment (its
``ROS_DOMAIN_ID`` and discovery settings): the inputs and ``/clock`` as they are replayed and every output as the
recorder receives it, from a second context; nothing from there enters the graph. ``domain_id=N`` runs the graph
itself in domain N with the caller's discovery settings (no isolation: for tools attached to that domain).

Nodes run in this process on one executor (the rclpy EventsExecutor when available, else the
SingleThreadedExecutor), or each in its own process (``processes=True``), watched through
``/train_calib/progress``. The EventsExecutor is the default because it is the faster one for this graph:
3.6-5x the samples per second of the SingleThreadedExecutor at rate 0 (bench/bench_graph.py; the measurements
and the reason are in :func:`train_calib.nodes.runner.make_executor`).
"""

from __future__ import annotations

import signal
import threading
import time
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from .bagio import OUTPUT_TOPICS
from .errors import ConfigError
from .isolation import MAX_DOMAIN_ID, DomainClaim, claim_domain, environment, isolated_environment
from .record import OUTPUT_FILE, qos_dict
from .replay_flow import FlowControl, Interrupted, ReplayError
from .replay_inputs import (
    BagInputs,
    ReplayOptions,
    ReplayResult,
    graph_nodes,
    load_inputs,
    prepare_out,
    resolve_inputs,
    sets_parameter,
)
from .yamlcheck import load_yaml_mapping

REPLAY_MAX_REGIME_WAIT = 100000
"""window_calib_node's max_regime_wait in a replay (its upper bound): wait for every regime."""

REPLAY_DIAGNOSTICS_PERIOD_S = 60.0
"""The nodes' diagnostics_period in a replay (s of the bag's time) unless a params file sets one. Under sim time a
node publishes /diagnostics once per period of its inputs' stamps (diagnostics_schedule), the same count at any
rate. The on-board 1 s would put one status beside every sample of a 1 Hz bag and halve the graph's speed at rate
0; 10 s still cost the 4-node graph 9 points of its throughput ratio (65 against 74 % of the relay chain, make
bench's graph on the 1 Hz tunnel bag); 60 s costs under one (the statuses carry running counters, and the replay's
summary has the final ones)."""

LIVE_ACK_TIMEOUT_S = 10.0
"""With --live: the longest wait (s) for the subscribers in the caller's environment to acknowledge the outputs."""


@dataclass
class _Progress:
    """How far a replay's streaming got (the clean-up after an exception reads it too)."""

    sent: Counter[str] = field(default_factory=Counter)  # inputs published, per topic
    interrupted: bool = False
    max_behind: float = 0.0  # s: the furthest a message was published after its due time
    stream_s: float = 0.0  # s: wall time from the first input published to the graph having handled the last
    stream_cpu_s: float = 0.0  # s: CPU time of this process over the same span


class Replay(FlowControl):
    """One replay: ``Replay(options).run()``."""

    def __init__(self, options: ReplayOptions) -> None:
        self.o = options
        self._stop = threading.Event()
        self._signum: int | None = None
        self._last_sent_ns = 0
        self._log = options.log or (lambda text: None)

    # -- the run ------------------------------------------------------------------------------
    def run(self) -> ReplayResult:
        import rclpy
        from rclpy.context import Context
        from rclpy.signals import SignalHandlerOptions

        o = self.o
        if not o.rate >= 0 or o.rate == float("inf"):  # also NaN
            raise ConfigError("replay", "rate", f"{o.rate:g} is out of range: must be a finite number, at least 0")
        if o.domain_id is not None and not 0 <= o.domain_id <= MAX_DOMAIN_ID:
            raise ConfigError("replay", "domain_id", f"{o.domain_id} is out of range: must be 0..{MAX_DOMAIN_ID}")
        if o.wait_for_subscribers and o.domain_id is None and not o.live:
            raise ConfigError(
                "replay",
                "wait_for_subscribers",
                "an isolated replay has no subscribers but its own: add --live (or --domain-id N)",
            )
        for f in o.params_files:
            load_yaml_mapping(f, "params file")
        inputs = load_inputs(o.bag)
        self.node_names = graph_nodes(o.nodes, o.window, inputs.topics)
        if o.until_s is not None:
            end = inputs.messages[0][1] + int(o.until_s * 1e9)
            inputs = BagInputs(inputs.topics, [m for m in inputs.messages if m[1] <= end])
        track_path, train_path = resolve_inputs(o.track, o.train)
        prepare_out(o.out, o.overwrite)

        claim: DomainClaim | None = None
        if o.domain_id is None:
            claim = claim_domain()
            self.graph_env = isolated_environment(claim.domain_id)
        else:
            self.graph_env = {"ROS_DOMAIN_ID": str(o.domain_id)}
        self.domain_id = int(self.graph_env["ROS_DOMAIN_ID"] or 0)
        context = Context()
        live_context = None
        try:
            with environment(self.graph_env):  # rcl reads the domain and discovery settings at init
                rclpy.init(
                    args=[], context=context, domain_id=self.domain_id, signal_handler_options=SignalHandlerOptions.NO
                )
            if o.live:  # the caller's own environment
                live_context = Context()
                rclpy.init(args=[], context=live_context, signal_handler_options=SignalHandlerOptions.NO)
            previous = {s: signal.signal(s, self._on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
            try:
                return self._run(context, inputs, track_path, train_path, live_context)
            finally:
                for s, handler in previous.items():
                    signal.signal(s, handler)
        finally:
            if live_context is not None:
                rclpy.try_shutdown(context=live_context)
            rclpy.try_shutdown(context=context)
            if claim is not None:
                claim.release()

    def _on_signal(self, signum: int, frame: Any) -> None:
        if self._stop.is_set():
            raise KeyboardInterrupt
        self._signum = signum
        self._stop.set()

    def _run(
        self, context: Any, inputs: BagInputs, track_path: Path, train_path: Path, live_context: Any = None
    ) -> ReplayResult:
        """The replay in an initialised context: open the publishers and the recording, start the graph, stream the
        inputs through it, close everything; the result."""
        o = self.o
        rec_node, writer, executor_name = self._open_endpoints(context, inputs, live_context)
        graph = None
        extra: list[Any] = []
        wall0 = time.monotonic()
        progress = _Progress()
        restore_levels = self._quiet_nodes() if o.quiet_nodes and not o.processes else {}
        try:
            graph = self._start_graph(context, track_path, train_path)
            extra += list(o.extra_nodes(context)) if o.extra_nodes is not None else []
            for n in (self.node, rec_node, *getattr(graph, "nodes", {}).values(), *extra):
                self.executor.add_node(n)
            self._stream(graph, inputs, progress)
        except BaseException:
            writer.close()
            if not progress.sent and not progress.interrupted:  # failed before the first input: no empty recording
                writer.path.unlink(missing_ok=True)
                writer.metadata_path.unlink(missing_ok=True)
            raise
        finally:
            writer.close()
            self._tear_down(graph, extra, rec_node, restore_levels)
        return self._result(inputs, writer, graph, executor_name, progress, time.monotonic() - wall0)

    def _open_endpoints(self, context: Any, inputs: BagInputs, live_context: Any) -> tuple[Any, Any, str]:
        """The replay's node and publishers (inputs, /clock), the executor, the recorder with its bag writer, and
        with ``live`` the publishers into the caller's environment: (recorder node, writer, executor name)."""
        import rclpy
        from builtin_interfaces.msg import Time
        from rosgraph_msgs.msg import Clock

        from .nodes.qos import reliable_qos
        from .record import McapBagWriter, Recorder, message_class

        self.node = rclpy.create_node("train_calib_replay", context=context)
        # the recorder follows /clock itself (sim_clock): a /clock it cannot read is counted, never fatal
        rec_node = rclpy.create_node("train_calib_recorder", context=context)
        self.executor, executor_name = self._make_executor(context)
        qos = reliable_qos(1000)
        self.pubs = {t: self.node.create_publisher(message_class(ty), t, qos) for t, ty in inputs.topics.items()}
        self.clock_pub = self.node.create_publisher(Clock, "/clock", reliable_qos(10))
        self._clock_msg, self._time_msg = Clock, Time
        out_qos = {t: qos_dict(depth=1000) for t in OUTPUT_TOPICS} | {"/diagnostics": qos_dict(depth=100)}
        writer = McapBagWriter(self.o.out, OUTPUT_TOPICS, qos=out_qos)
        self._open_live(live_context, inputs)
        self.recorder = Recorder(rec_node, writer, OUTPUT_TOPICS, forward=self.live_outputs or None, sim_clock=True)
        return rec_node, writer, executor_name

    def _open_live(self, live_context: Any, inputs: BagInputs) -> None:
        """With a live context (``live``), a second node in the caller's environment: publishes the inputs, /clock
        and the outputs there, never subscribes."""
        import rclpy
        from rclpy.qos import DurabilityPolicy
        from rosgraph_msgs.msg import Clock

        from .nodes.qos import reliable_qos
        from .record import message_class

        self.live_node = None
        self.live_pubs: dict[str, Any] = {}
        self.live_outputs: dict[str, Any] = {}
        if live_context is None:
            return
        qos = reliable_qos(1000)
        self.live_node = rclpy.create_node("train_calib_replay_live", context=live_context)
        self.live_pubs = {
            t: self.live_node.create_publisher(message_class(ty), t, qos) for t, ty in inputs.topics.items()
        }
        self.live_pubs["/clock"] = self.live_node.create_publisher(Clock, "/clock", reliable_qos(10))
        # transient local: a subscriber that asks for it gets every output from the first, whichever side of the
        # discovery matched first (a volatile one gets those published after it matched our publisher)
        kept = reliable_qos(1000, DurabilityPolicy.TRANSIENT_LOCAL)
        self.live_outputs = {
            t: self.live_node.create_publisher(message_class(ty), t, kept) for t, ty in OUTPUT_TOPICS.items()
        }

    def _start_graph(self, context: Any, track_path: Path, train_path: Path) -> Any:
        """The node graph (the options' factory, one process per node, or all in this process), in ``self.graph``."""
        from .nodes.graph import InProcessGraph, ProcessGraph

        o = self.o
        overrides = {"track_file": str(track_path), "train_file": str(train_path), "use_sim_time": True}
        # in a replay every regime comes (flow control, end of input): window_calib_node never gives up waiting for
        # one, whatever the processes' scheduling (with --processes a measurement may run up to max_lag ahead of its
        # regime, more than the on-board max_regime_wait)
        overrides["max_regime_wait"] = REPLAY_MAX_REGIME_WAIT
        if not sets_parameter(o.params_files, "diagnostics_period"):  # a rate-independent /diagnostics volume
            overrides["diagnostics_period"] = REPLAY_DIAGNOSTICS_PERIOD_S
        if o.graph_factory is not None:
            graph = o.graph_factory(context, self.node_names, overrides, o.params_files)
        elif o.processes:
            graph = ProcessGraph(
                self.node,
                self.node_names,
                overrides | {"report_progress": True},
                o.params_files,
                env_changes=self.graph_env,
                log_level="warn" if o.quiet_nodes else None,
            )
        else:
            graph = InProcessGraph(context, self.node_names, overrides, o.params_files)
        self.graph = graph
        return graph

    def _stream(self, graph: Any, inputs: BagInputs, progress: _Progress) -> None:
        """Wait for the graph, publish every input, let the graph handle them and close the runs (on an interruption:
        what was published), then the last /clock and the graph's end."""
        o = self.o
        self._publish_clock(inputs.messages[0][1])
        try:
            self._wait_connected(graph)
        except Interrupted:
            progress.interrupted = True
        self._log(
            f"replaying {len(inputs.messages)} messages ({inputs.duration_s:.0f} s of bag time) through "
            f"{', '.join(graph.names)} ({'one process per node' if o.processes else 'one process'}, "
            f"rate {'max' if o.rate == 0 else f'{o.rate:g}x'}; {self._where()})"
        )
        try:
            if progress.interrupted:
                raise Interrupted
            self._publish_and_settle(graph, inputs, progress)
        except Interrupted:
            progress.interrupted = True
            self._log("interrupted: the graph handles what it has received, then the recording is closed")
            try:  # no new input: what was published flows through and each run is closed, as at the end
                self._end_of_input(graph, progress.sent, interruptible=False, timeout_s=10.0)
            except ReplayError as exc:
                self._log(f"the graph did not drain after the interruption: {exc}")
        self._publish_clock(self._last_sent_ns if progress.interrupted else inputs.messages[-1][1], force=True)
        try:
            self._finish(graph)
        except ReplayError:
            if not progress.interrupted:
                raise
            self._log("the graph did not finish cleanly after the interruption; the recording is closed")

    def _publish_and_settle(self, graph: Any, inputs: BagInputs, progress: _Progress) -> None:
        """Publish every input, wait until the graph has handled the last (the stream time), then end the input."""
        stream0, cpu0 = time.monotonic(), time.process_time()
        progress.max_behind = self._publish_all(graph, inputs, progress.sent)
        self._spin_until(
            lambda: graph.settled(self.recorder.received), lambda: "the graph to handle the last input", graph
        )
        progress.stream_s, progress.stream_cpu_s = time.monotonic() - stream0, time.process_time() - cpu0
        self._end_of_input(graph, progress.sent)

    def _tear_down(self, graph: Any, extra: list[Any], rec_node: Any, restore_levels: dict[str, Any]) -> None:
        """Close the graph, the executor and the nodes; restore the loggers' levels."""
        from rclpy.logging import set_logger_level

        if graph is not None:
            for n in getattr(graph, "nodes", {}).values():
                self.executor.remove_node(n)
            graph.close()
        self.executor.shutdown()
        for n in extra:
            n.destroy_node()
        rec_node.destroy_node()
        self.node.destroy_node()
        if self.live_node is not None:
            self._wait_live_acknowledged()
            self.live_node.destroy_node()
        for name, level in restore_levels.items():
            set_logger_level(name, level)

    def _wait_live_acknowledged(self, timeout_s: float = LIVE_ACK_TIMEOUT_S) -> None:
        """With ``live``: before its publishers go, every output forwarded into the caller's environment is
        acknowledged by the reliable subscribers there (a DAS), or ``timeout_s`` has passed; a topic left
        unacknowledged is logged. Without the wait the last messages (each run's features, at its end) could go
        with the publisher."""
        from rclpy.duration import Duration

        deadline = time.monotonic() + timeout_s
        late = [
            topic
            for topic, publisher in self.live_outputs.items()
            if not publisher.wait_for_all_acked(Duration(seconds=max(deadline - time.monotonic(), 0.0)))
        ]
        if late:
            topics = ", ".join(late)
            self._log(f"not acknowledged after {timeout_s:g} s by the subscribers in your environment: {topics}")

    def _result(
        self, inputs: BagInputs, writer: Any, graph: Any, executor_name: str, progress: _Progress, wall_s: float
    ) -> ReplayResult:
        o = self.o
        interrupted = progress.interrupted
        return ReplayResult(
            out=o.out,
            output_bag=o.out / OUTPUT_FILE,
            sent=dict(progress.sent),
            recorded=dict(writer.counts),
            wall_s=wall_s,
            bag_duration_s=inputs.duration_s,
            mode="processes" if o.processes else "one process",
            executor=executor_name,
            nodes=tuple(graph.names),
            interrupted=interrupted,
            max_behind_s=progress.max_behind,
            stream_s=progress.stream_s,
            stream_cpu_s=progress.stream_cpu_s,
            input_error=inputs.error,
            undecodable=dict(inputs.undecodable),
            signal=self._signum if interrupted else None,
            domain_id=self.domain_id,
            isolated=o.domain_id is None,
            live=o.live,
        )

    def _quiet_nodes(self) -> dict[str, Any]:
        """The in-process nodes' loggers at WARN; returns their levels before, to restore."""
        import rclpy.logging

        before = {}
        for name in self.node_names:
            before[name] = rclpy.logging.get_logger_level(name)
            rclpy.logging.set_logger_level(name, rclpy.logging.LoggingSeverity.WARN)
        return before

    def _where(self) -> str:
        """Where the graph runs, for the log."""
        o = self.o
        where = (
            f"ROS domain {self.domain_id} of its own, localhost only"
            if o.domain_id is None
            else f"ROS domain {self.domain_id}, not isolated"
        )
        return where + ("; inputs, /clock and outputs also published to your environment (--live)" if o.live else "")

    def _make_executor(self, context: Any) -> tuple[Any, str]:
        from .nodes.runner import make_executor

        executor = make_executor(context, self.o.executor)
        return executor, type(executor).__name__


def replay(options: ReplayOptions) -> ReplayResult:
    return Replay(options).run()


__all__ = [
    "BagInputs",
    "ReplayError",
    "ReplayOptions",
    "ReplayResult",
    "graph_nodes",
    "load_inputs",
    "replay",
    "resolve_inputs",
]
