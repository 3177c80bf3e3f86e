"""A replay's flow control: ``/clock``, the inputs published in lockstep with the head of the graph, the waits,
the end of input and the drain (:class:`FlowControl`, the base of :class:`train_calib.replay.Replay`).

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
sets ``max_regime_wait`` to ``replay.REPLAY_MAX_REGIME_WAIT``, so a slow node never makes another fall back on
its time-out (also with ``--processes``, where a measurement can run ahead of its regime by up to ``max_lag``), and
the result does not depend on scheduling.
"""

from __future__ import annotations

import threading
import time
from collections import Counter
from collections.abc import Callable, Sequence
from typing import Any

from .errors import TrainCalibError
from .replay_inputs import BagInputs, ReplayOptions

STARTUP_TIMEOUT_S = 60.0
STALL_TIMEOUT_S = 60.0


class ReplayError(TrainCalibError):
    """The graph could not be started or stopped making progress."""


class Interrupted(Exception):
    pass


class FlowControl:
    """The publishing and the waits of a replay (module docstring). :class:`train_calib.replay.Replay`, its subclass,
    opens what they use: the attributes below."""

    o: ReplayOptions
    _stop: threading.Event  # set by SIGINT/SIGTERM
    _last_sent_ns: int  # log time of the last input published
    domain_id: int  # the ROS domain the graph runs in
    node: Any  # the replay's node
    executor: Any  # the replay's executor
    pubs: dict[str, Any]  # input topic -> publisher
    clock_pub: Any
    _clock_msg: Any  # rosgraph_msgs Clock
    _time_msg: Any  # builtin_interfaces Time
    recorder: Any  # record.Recorder: messages received per output topic
    live_node: Any  # with live: the node in the caller's environment, else None
    live_pubs: dict[str, Any]  # with live: input topics and /clock -> publisher there
    live_outputs: dict[str, Any]  # with live: output topic -> publisher there
    # _clock_wall, _clock_ns: the last /clock published (wall time, bag time), set by _publish_clock

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
