"""Replay a bag's input topics through the node graph and record every output (``train-calib replay``).

The bag's ``/gnss/fix``, ``/train/speed`` and ``/train/traction_power`` messages are published as they
were recorded (the serialized bytes, in log-time order) with their recorded timing scaled by ``rate``;
``rate`` 0 publishes as fast as the graph keeps up. ``/clock`` carries the bag's time (the nodes run with
``use_sim_time``), published before the messages it covers and at most ``clock_hz`` times per second of
wall time.

Flow control, not sleeps: each input message is published only once the ingest node has handled the
previous one (lockstep on the head of the graph, so the ingest sees exactly the bag's order whatever
the DDS or the executor schedules), and no topic is allowed to fall more than ``max_lag`` messages
behind (published but not yet handled by its subscriber nodes or the recorder) — below the outputs'
history depth, so nothing is lost at any rate. At the end the graph is drained, each node gets its end
of input in chain order (the ingest releases held samples, the feature node closes the run), the nodes
publish their final /diagnostics and the recording is closed.

Nodes downstream of the head hold samples only while they wait for another graph topic (window_calib_node
joins each measurement with its regime and, on board, gives up after ``max_regime_wait`` samples): the replay
does not let such a node hold more than ``max_held`` samples while the graph still has messages in flight, and
sets ``max_regime_wait`` to REPLAY_MAX_REGIME_WAIT, so a slow node never makes another fall back on its time-out
(also with ``--processes``, where a measurement can run ahead of its regime by up to ``max_lag``), and the result
does not depend on scheduling.

window_calib_node runs when the bag has ``/train/traction_power`` (``window=None``, the default), or as
``window`` True/False forces.

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
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from . import paths
from .bagio import INPUT_TOPICS, OUTPUT_TOPICS, POWER_TOPIC, BagDamage, bag_topics, iter_bag, typestore
from .errors import BagError, ConfigError, TrainCalibError
from .isolation import MAX_DOMAIN_ID, DomainClaim, claim_domain, environment, isolated_environment
from .nodes.config import GRAPH_NODES, WINDOW_NODE
from .record import METADATA_FILE, OUTPUT_FILE, qos_dict
from .track import load_track
from .train import load_train
from .yamlcheck import load_yaml_mapping

DEFAULT_CLOCK_HZ = 20.0
MAX_CLOCK_NS = (2**31 - 1) * 1_000_000_000 + 999_999_999  # the latest time /clock carries (int32 seconds, 2038)
STARTUP_TIMEOUT_S = 60.0
STALL_TIMEOUT_S = 60.0


class ReplayError(TrainCalibError):
    """The graph could not be started or stopped making progress."""


class Interrupted(Exception):
    pass


REPLAY_MAX_REGIME_WAIT = 100000
"""window_calib_node's max_regime_wait in a replay (its upper bound): wait for every regime."""

REPLAY_DIAGNOSTICS_PERIOD_S = 60.0
"""The nodes' diagnostics_period in a replay (s of the bag's time) unless a params file sets one. Under sim time a
node publishes /diagnostics once per period of its inputs' stamps (diagnostics_schedule), the same count at any
rate. The on-board 1 s would put one status beside every sample of a 1 Hz bag and halve the graph's speed at rate
0; 10 s still cost the 4-node graph 9 points of its throughput ratio (65 against 74 % of the relay chain, make
bench's graph on the 1 Hz tunnel bag); 60 s costs under one (the statuses carry running counters, and the replay's
summary has the final ones)."""


def sets_parameter(params_files: Sequence[Path], name: str) -> bool:
    """Whether any of the ROS params files sets ``name`` (under any node's ``ros__parameters``)."""

    def found(node: Any) -> bool:
        if isinstance(node, dict):
            params = node.get("ros__parameters")
            if isinstance(params, dict) and name in params:
                return True
            return any(found(v) for v in node.values())
        return False

    return any(found(load_yaml_mapping(f, "params file")) for f in params_files)


@dataclass
class ReplayOptions:
    bag: Path
    track: str  # path or bundled name
    train: str  # path or bundled name
    out: Path
    rate: float = 0.0  # 0: as fast as the graph keeps up
    processes: bool = False
    params_files: tuple[Path, ...] = ()
    nodes: tuple[str, ...] = GRAPH_NODES
    window: bool | None = None  # window_calib_node: None = when the bag has /train/traction_power; True/False force
    clock_hz: float = DEFAULT_CLOCK_HZ
    executor: str = "events"  # in one process: events or single
    wait_for_subscribers: int = 0  # extra subscribers (e.g. a DAS) every output must have before starting
    max_lag: int = 200
    max_held: int = 10  # samples a node downstream of the head may hold while the graph has messages in flight
    overwrite: bool = False
    log: Callable[[str], None] | None = None
    on_input: Callable[[str, int, int], None] | None = None  # (topic, stamp... log time ns, wall ns) hook
    extra_nodes: Callable[[Any], Sequence[Any]] | None = None  # context -> nodes to spin with the graph
    until_s: float | None = None  # replay only the first `until_s` seconds of bag time
    graph_factory: Callable[..., Any] | None = None  # (context, names, overrides, params_files) -> Graph (benchmarks)
    domain_id: int | None = None  # None: a domain of its own, localhost only (isolated); N: the graph in domain N
    live: bool = False  # also publish the inputs, /clock and the outputs into the caller's environment
    quiet_nodes: bool = False  # the nodes log warnings and errors only (no [INFO] lines; --quiet)


@dataclass
class ReplayResult:
    out: Path
    output_bag: Path
    sent: dict[str, int]
    recorded: dict[str, int]
    wall_s: float
    bag_duration_s: float
    mode: str
    executor: str
    nodes: tuple[str, ...] = ()
    interrupted: bool = False
    max_behind_s: float = 0.0  # finite rate: the furthest a message was published after its due time
    stream_s: float = 0.0  # wall time from the first input published to the graph having handled the last
    stream_cpu_s: float = 0.0  # CPU time of this process over the same span (all threads)
    drops: dict[str, dict[str, dict[str, int]]] = field(default_factory=dict)
    input_error: str | None = None  # the input bag was damaged: replayed what could be read (exit status 3)
    undecodable: dict[str, int] = field(default_factory=dict)
    signal: int | None = None  # the signal that interrupted the replay (SIGINT 2, SIGTERM 15)
    domain_id: int | None = None  # the ROS domain the graph ran in
    isolated: bool = True  # the graph ran in a domain of its own, localhost only
    live: bool = False  # inputs, /clock and outputs were also published into the caller's environment


@dataclass
class BagInputs:
    topics: dict[str, str]  # input topic -> type present in the bag
    messages: list[tuple[str, int, bytes]]  # (topic, log time ns, CDR) in log-time order
    error: str | None = None  # the bag is damaged: what was wrong (messages hold what could be read)
    undecodable: dict[str, int] = field(default_factory=dict)  # topic -> messages left out (not valid CDR)

    @property
    def duration_s(self) -> float:
        return (self.messages[-1][1] - self.messages[0][1]) * 1e-9 if self.messages else 0.0


def load_inputs(bag: str | Path) -> BagInputs:
    """The bag's input messages; BagError (one line) for an unreadable bag or one without inputs."""
    topics = bag_topics(bag)
    present = {}
    for topic, expected in INPUT_TOPICS.items():
        if topic in topics:
            if topics[topic] != expected:
                raise BagError(f"{bag}: topic {topic} has type {topics[topic]}, expected {expected}")
            present[topic] = expected
    if "/train/speed" not in present or "/gnss/fix" not in present:
        missing = [t for t in ("/gnss/fix", "/train/speed") if t not in present]
        raise BagError(f"{bag}: no {' and no '.join(missing)} topic (found: {', '.join(sorted(topics)) or 'none'})")
    store = typestore()
    messages: list[tuple[str, int, bytes]] = []
    undecodable: Counter[str] = Counter()
    absurd = 0  # messages with a log time /clock cannot carry
    error = None
    try:
        for m in iter_bag(bag, present):
            if not 0 <= m.log_time_ns <= MAX_CLOCK_NS:  # /clock could not carry it (int32 seconds): a damaged bag
                undecodable[m.topic] += 1
                absurd += 1
                continue
            try:  # a message the nodes could not deserialize is left out and counted (a damaged bag)
                store.deserialize_cdr(m.data, present[m.topic])
            except Exception:
                undecodable[m.topic] += 1
                continue
            messages.append((m.topic, m.log_time_ns, m.data))
    except BagDamage as exc:
        error = str(exc)
    if not messages:
        raise BagError(error or f"{bag}: the input topics hold no messages")
    if undecodable and error is None:
        invalid = sum(undecodable.values()) - absurd
        parts = [f"{invalid} input messages are not valid CDR"] if invalid else []
        parts += [f"{absurd} input messages have a log time /clock cannot carry (after 2038)"] if absurd else []
        error = f"{bag}: {' and '.join(parts)} and were left out"
    return BagInputs(present, messages, error, dict(undecodable))


def graph_nodes(nodes: Sequence[str], window: bool | None, input_topics: Iterable[str]) -> tuple[str, ...]:
    """The nodes to start: `nodes`, plus window_calib_node when `window` is True, or None and the bag has traction
    power; without it when `window` is False."""
    wanted = (POWER_TOPIC in set(input_topics)) if window is None else window
    base = tuple(n for n in nodes if n != WINDOW_NODE)
    return (*base, WINDOW_NODE) if wanted else base


def resolve_inputs(track: str, train: str) -> tuple[Path, Path]:
    """Paths of the track and train files (a path or a bundled name); loads them to fail early in one line."""
    track_path, train_path = paths.track_file(track), paths.train_file(train)
    load_track(track_path)
    load_train(train_path)
    return track_path, train_path


def prepare_out(out: Path, overwrite: bool) -> None:
    """Create the output directory; refuse (or with overwrite, remove) the files a replay writes."""
    products = [OUTPUT_FILE, METADATA_FILE, "summary.json", "report.png"]
    existing = [out / p for p in products if (out / p).exists()]
    if existing and not overwrite:
        raise BagError(f"{existing[0]}: already exists (use --overwrite or another --out)")
    for path in existing:
        path.unlink()
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise BagError(f"{out}: cannot create the output directory: {exc.strerror or exc}") from None


@dataclass
class _Progress:
    """How far a replay's streaming got (the clean-up after an exception reads it too)."""

    sent: Counter[str] = field(default_factory=Counter)  # inputs published, per topic
    interrupted: bool = False
    max_behind: float = 0.0  # s: the furthest a message was published after its due time
    stream_s: float = 0.0  # s: wall time from the first input published to the graph having handled the last
    stream_cpu_s: float = 0.0  # s: CPU time of this process over the same span


class Replay:
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
        self.live_outputs = {
            t: self.live_node.create_publisher(message_class(ty), t, reliable_qos(1000))
            for t, ty in OUTPUT_TOPICS.items()
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
            self.live_node.destroy_node()
        for name, level in restore_levels.items():
            set_logger_level(name, level)

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

    # -- pieces -----------------------------------------------------------------------------------
    def _publish_clock(self, t_ns: int, force: bool = False) -> None:
        now = time.monotonic()
        if not force and now - getattr(self, "_clock_wall", -1e9) < 1.0 / self.o.clock_hz:
            return
        if t_ns <= getattr(self, "_clock_ns", -1) and not force:
            return
        self._clock_wall, self._clock_ns = now, t_ns
        msg = self._clock_msg(clock=self._time_msg(sec=int(t_ns // 1_000_000_000), nanosec=int(t_ns % 1_000_000_000)))
        self.clock_pub.publish(msg)
        if self.live_pubs:
            self.live_pubs["/clock"].publish(msg)

    def _spin_until(
        self,
        condition: Callable[[], bool],
        what: Callable[[], str],
        graph: Any,
        timeout_s: float = STALL_TIMEOUT_S,
        interruptible: bool = True,
    ) -> None:
        """Spin the executor until `condition`; ReplayError if nothing moves for `timeout_s`; Interrupted on
        SIGINT/SIGTERM when `interruptible`."""
        if condition():
            return
        spin = self.executor.spin_once
        stop = self._stop
        started = time.monotonic()
        last_check = started
        signature = None
        moved = started
        while not condition():
            if interruptible and stop.is_set():
                raise Interrupted
            spin(timeout_sec=0.05)
            now = time.monotonic()
            if now - last_check > 0.5:  # rarely: liveness of the node processes and a stall check
                last_check = now
                graph.check_alive()
                current = self._signature(graph)
                if current != signature:
                    signature, moved = current, now
                elif now - moved > timeout_s:
                    raise ReplayError(f"the graph made no progress for {timeout_s:.0f} s while waiting for {what()}")

    def _signature(self, graph: Any) -> tuple:
        progress = graph.progress()
        return (
            tuple(
                sorted(
                    (n, tuple(sorted(p.handled.items())), tuple(sorted(p.published.items())))
                    for n, p in progress.items()
                )
            ),
            tuple(sorted(self.recorder.received.items())),
        )

    def _wait_connected(self, graph: Any) -> None:
        """Spin until every node is up and every subscription of the graph and the recorder is matched; with
        ``wait_for_subscribers`` N, also until N other nodes (a DAS: in the caller's environment with --live, else
        in the graph's domain) subscribe to output topics and each of their subscriptions is matched."""
        wanted = self.o.wait_for_subscribers
        live = self.live_node is not None
        n_nodes = len(graph.names)
        own = {*graph.names, "train_calib_recorder", "train_calib_replay", "train_calib_replay_live"}
        probe = self.live_node if live else self.node
        where = "in your environment" if live else f"in ROS domain {self.domain_id}"

        def outputs() -> list[str]:
            return sorted({t for p in graph.progress().values() for t in p.published})

        def others(topic: str) -> list[Any]:
            return [i for i in probe.get_subscriptions_info_by_topic(topic) if i.node_name not in own]

        def matched_by_others(topic: str) -> int:
            if live:
                return self.live_outputs[topic].get_subscription_count() if topic in self.live_outputs else 0
            expected = graph.subscribers_expected(1)[topic]  # the graph's own subscribers and the recorder
            return min(p.matched.get(topic, 0) for p in graph.progress().values() if topic in p.published) - expected

        def not_yet_discovered(nodes: set[tuple[str, str]], subscriptions: dict[str, list[Any]]) -> list[str]:
            """Output topics a subscriber node declares (its node's graph entry) whose subscription this process
            has not discovered yet: that topic's check below would pass with no subscription to match."""
            lacking = []
            for namespace, name in sorted(nodes):
                try:
                    declared = probe.get_subscriber_names_and_types_by_node(name, namespace)
                except Exception:  # the node left, or its graph entry is not there yet: its subscriptions decide
                    continue
                for topic, _ in declared:
                    infos = subscriptions.get(topic)
                    if infos is not None and not any(
                        i.node_name == name and i.node_namespace == namespace for i in infos
                    ):
                        lacking.append(f"{topic} ({namespace.rstrip('/')}/{name}'s subscription {where})")
            return lacking

        def das_lacking() -> list[str]:
            if not wanted:
                return []
            subscriptions = {t: others(t) for t in outputs()}
            nodes = {(i.node_namespace, i.node_name) for infos in subscriptions.values() for i in infos}
            lacking = [f"{len(nodes)} of {wanted} subscriber nodes {where}"] if len(nodes) < wanted else []
            lacking += not_yet_discovered(nodes, subscriptions)
            for topic, infos in subscriptions.items():
                if infos and matched_by_others(topic) < len(infos):
                    lacking.append(f"{topic} ({matched_by_others(topic)} of {len(infos)} subscriptions {where})")
            return lacking

        def ready() -> bool:
            return (
                len(graph.progress()) == n_nodes
                and graph.connected(1)
                and all(p.get_subscription_count() >= 1 for p in self.pubs.values())
                and not das_lacking()
            )

        def what() -> str:
            progress = graph.progress()
            missing = [n for n in graph.names if n not in progress]
            if missing:
                return f"nodes to start: {', '.join(missing)}"
            expected = graph.subscribers_expected(1)
            lacking = [
                f"{t} ({p.matched.get(t, 0)} of {expected[t]} subscribers)"
                for p in progress.values()
                for t in p.published
                if p.matched.get(t, 0) < expected[t]
            ]
            return "subscribers to match: " + ", ".join(lacking + das_lacking())

        self._spin_until(ready, what, graph, timeout_s=STARTUP_TIMEOUT_S)

    def _publish_all(self, graph: Any, inputs: BagInputs, sent: Counter) -> float:
        o = self.o
        ingest = "gnss_speed_node"
        handled = self._handled_reader(graph, ingest)
        held = self._held_reader(graph, [n for n in graph.names if n != ingest])
        recorded = self.recorder.received
        t0 = inputs.messages[0][1]
        wall0 = time.monotonic()
        max_behind = 0.0
        check_lag_every = 1 if o.processes else 64
        live_pubs = self.live_pubs
        for k, (topic, t_ns, data) in enumerate(inputs.messages):
            if self._stop.is_set():
                raise Interrupted
            if o.rate > 0:
                due = wall0 + (t_ns - t0) * 1e-9 / o.rate
                while (now := time.monotonic()) < due:
                    self._publish_clock(t0 + int((now - wall0) * o.rate * 1e9))
                    self.executor.spin_once(timeout_sec=min(due - now, 1.0 / o.clock_hz))
                max_behind = max(max_behind, time.monotonic() - due)
            self._publish_clock(t_ns)
            if (k % check_lag_every == 0 and graph.lag(recorded) > o.max_lag) or held() > o.max_held:
                self._spin_until(
                    lambda: (
                        graph.lag(recorded) <= o.max_lag // 2 and (held() <= o.max_held // 2 or graph.settled(recorded))
                    ),
                    lambda: f"the graph to catch up (lag {graph.lag(recorded)}, {held()} samples held)",
                    graph,
                )
            self.pubs[topic].publish(data)
            if live_pubs:
                live_pubs[topic].publish(data)
            sent[topic] += 1
            self._last_sent_ns = t_ns
            if o.on_input is not None:
                o.on_input(topic, t_ns, time.perf_counter_ns())
            target = sent[topic]
            self._spin_until(
                lambda topic=topic, target=target: handled(topic) >= target,
                lambda topic=topic, target=target: f"{ingest} to handle {topic} message {target}",
                graph,
            )
        return max_behind

    def _handled_reader(self, graph: Any, name: str) -> Callable[[str], int]:
        nodes = getattr(graph, "nodes", None)
        if nodes is not None:  # in one process: read the counter directly
            counter = nodes[name].handled
            return lambda topic: counter[topic]

        def from_progress(topic: str) -> int:
            progress = graph.progress().get(name)
            return 0 if progress is None else progress.handled.get(topic, 0)

        return from_progress

    def _held_reader(self, graph: Any, names: Sequence[str]) -> Callable[[], int]:
        """The largest number of samples held by one of `names` (waiting for another graph topic)."""
        nodes = getattr(graph, "nodes", None)
        if nodes is not None:
            watched = [nodes[n] for n in names if n in nodes]
            return lambda: max((node.pending for node in watched), default=0)

        def from_progress() -> int:
            progress = graph.progress()
            return max((progress[n].pending for n in names if n in progress), default=0)

        return from_progress

    def _end_of_input(
        self, graph: Any, sent: Counter, interruptible: bool = True, timeout_s: float = STALL_TIMEOUT_S
    ) -> None:
        """Every input sent handled by the ingest and everything published handled downstream (and recorded),
        then each node's end of input in chain order, each settled before the next."""
        recorded = self.recorder.received
        handled = self._handled_reader(graph, "gnss_speed_node")
        self._spin_until(
            lambda: all(handled(t) >= n for t, n in sent.items()) and graph.settled(recorded),
            lambda: "the graph to handle the last input",
            graph,
            timeout_s=timeout_s,
            interruptible=interruptible,
        )
        for name in graph.names:
            graph.end_of_input(name)
            self._spin_until(
                lambda name=name: (
                    graph.progress().get(name) is not None and graph.progress()[name].ended and graph.settled(recorded)
                ),
                lambda name=name: f"{name} to handle its end of input",
                graph,
                timeout_s=timeout_s,
                interruptible=interruptible,
            )

    def _finish(self, graph: Any) -> None:
        """Final /diagnostics from every node, then everything recorded."""
        if self.o.processes:
            graph.finish()
            self._drain()
            return
        graph.finish()
        expected = graph.diagnostics_published()
        self._spin_until(
            lambda: self.recorder.received["/diagnostics"] >= expected and graph.settled(self.recorder.received),
            lambda: "the recorder to receive the final /diagnostics",
            graph,
            timeout_s=10.0 if self._stop.is_set() else STALL_TIMEOUT_S,
            interruptible=False,
        )

    def _drain(self, quiet_s: float = 0.3) -> None:
        """Spin until the recorder has received nothing new for `quiet_s` (after the node processes exited)."""
        last = sum(self.recorder.received.values())
        quiet_since = time.monotonic()
        while time.monotonic() - quiet_since < quiet_s:
            self.executor.spin_once(timeout_sec=0.05)
            total = sum(self.recorder.received.values())
            if total != last:
                last, quiet_since = total, time.monotonic()


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
