"""The node graph run for a replay: in one process (one executor) or one process per node.

Both give the replay the same view of the graph, :class:`NodeProgress` per node (input messages
handled, messages published and matched subscribers per output, samples held, end of input done),
which is all the replay's flow control needs:

* :class:`InProcessGraph` builds the nodes in the replay's own context and reads their counters
  directly (no extra messages); they are spun by the replay's executor.
* :class:`ProcessGraph` starts ``python -m train_calib.nodes.<node>`` per node with
  ``report_progress`` true and listens to ``/train_calib/progress``; SIGINT stops a node cleanly.
"""

from __future__ import annotations

import importlib
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml
from diagnostic_msgs.msg import DiagnosticStatus
from rclpy.parameter import Parameter
from std_msgs.msg import String

from ..errors import TrainCalibError
from .common import END_OF_INPUT_TOPIC, PROGRESS_TOPIC, TrainCalibNode
from .qos import CONTROL_QOS

NODE_MODULES = {
    "gnss_speed_node": ("train_calib.nodes.gnss_speed_node", "GnssSpeedNode"),
    "ukf_node": ("train_calib.nodes.ukf_node", "UkfNode"),
    "regime_node": ("train_calib.nodes.regime_node", "RegimeNode"),
    "feature_node": ("train_calib.nodes.feature_node", "FeatureNode"),
    "window_calib_node": ("train_calib.nodes.window_calib_node", "WindowCalibNode"),
}


class GraphError(TrainCalibError):
    """A node of the graph failed to start, died, or the graph stopped making progress."""


def node_class(name: str) -> type[TrainCalibNode]:
    """The node's class; GraphError (one line) when the node is unknown or its module is missing."""
    if name not in NODE_MODULES:
        raise GraphError(f"unknown node {name!r} (known: {', '.join(NODE_MODULES)})")
    module, cls = NODE_MODULES[name]
    try:
        return getattr(importlib.import_module(module), cls)
    except (ImportError, AttributeError) as exc:
        raise GraphError(f"{name} is not available: {exc.__class__.__name__}: {exc}") from None


@dataclass
class NodeProgress:
    """A node's counters as the replay sees them."""

    handled: dict[str, int] = field(default_factory=dict)  # input topic -> callbacks completed
    published: dict[str, int] = field(default_factory=dict)  # output topic -> messages published
    matched: dict[str, int] = field(default_factory=dict)  # output topic -> matched subscriptions
    pending: int = 0
    ended: bool = False


class Graph:
    """Common view: nodes in chain order and their progress."""

    names: tuple[str, ...]

    def progress(self) -> dict[str, NodeProgress]:
        raise NotImplementedError

    def ready(self) -> bool:
        """Every node reports (processes: is up and spinning)."""
        return len(self.progress()) == len(self.names)

    def settled(self, recorded: dict[str, int] | None = None) -> bool:
        """Every message a node published has been handled by the graph nodes subscribed to it (and recorded)."""
        progress = self.progress()
        if len(progress) != len(self.names):
            return False
        producer = {t: p.published[t] for p in progress.values() for t in p.published}
        for p in progress.values():
            for topic, n in p.handled.items():
                if topic in producer and n < producer[topic]:
                    return False
        if recorded is not None:
            for topic, n in producer.items():
                if recorded.get(topic, 0) < n:
                    return False
        return True

    def lag(self, recorded: dict[str, int] | None = None) -> int:
        """Largest number of messages published but not yet handled (or recorded) on any topic."""
        progress = self.progress()
        producer = {t: p.published[t] for p in progress.values() for t in p.published}
        worst = 0
        for p in progress.values():
            for topic, n in p.handled.items():
                if topic in producer:
                    worst = max(worst, producer[topic] - n)
        if recorded is not None:
            for topic, n in producer.items():
                worst = max(worst, n - recorded.get(topic, 0))
        return worst

    def subscribers_expected(self, extra: int = 1) -> dict[str, int]:
        """Output topic -> graph nodes subscribed to it + `extra` (the recorder, a DAS...)."""
        progress = self.progress()
        out = {}
        for p in progress.values():
            for topic in p.published:
                out[topic] = extra + sum(1 for q in progress.values() if topic in q.handled)
        return out

    def connected(self, extra: int = 1) -> bool:
        """Every output publisher has matched the graph's subscribers and `extra` more."""
        if not self.ready():
            return False
        expected = self.subscribers_expected(extra)
        return all(
            p.matched.get(topic, 0) >= expected[topic] for p in self.progress().values() for topic in p.published
        )

    def end_of_input(self, name: str) -> None:
        raise NotImplementedError

    def check_alive(self) -> None:
        """Raise GraphError if a node has died."""

    def finish(self) -> None:
        raise NotImplementedError

    def close(self) -> None:
        raise NotImplementedError


class InProcessGraph(Graph):
    """The nodes in the caller's context, spun by the caller's executor."""

    def __init__(
        self,
        context: Any,
        names: Sequence[str],
        overrides: dict[str, Any],
        params_files: Sequence[Path] = (),
    ) -> None:
        self.names = tuple(names)
        self.nodes: dict[str, TrainCalibNode] = {}
        cli: list[str] = []
        for f in params_files:
            cli += ["--params-file", str(f)]
        try:
            for name in self.names:
                self.nodes[name] = node_class(name)(
                    context=context,
                    cli_args=["--ros-args", *cli] if cli else None,
                    parameter_overrides=[Parameter(k, value=v) for k, v in overrides.items()],
                )
        except BaseException:
            self.close()
            raise

    def progress(self) -> dict[str, NodeProgress]:
        out = {}
        for name, node in self.nodes.items():
            pubs = node.output_publishers()
            out[name] = NodeProgress(
                handled={t: node.handled[t] for t in node.input_topics},
                published={t: node.published[t] for t in pubs},
                matched={t: pub.get_subscription_count() for t, pub in pubs.items()},
                pending=node.pending,
                ended=node.ended,
            )
        return out

    def end_of_input(self, name: str) -> None:
        self.nodes[name].mark_ended()

    def diagnostics_published(self) -> int:
        return sum(node.diagnostics_published for node in self.nodes.values())

    def finish(self) -> None:
        for node in self.nodes.values():
            node.finish()

    def close(self) -> None:
        for node in self.nodes.values():
            node.destroy_node()
        self.nodes.clear()


class ProcessGraph(Graph):
    """One process per node, watched through /train_calib/progress."""

    def __init__(
        self,
        node: Any,
        names: Sequence[str],
        overrides: dict[str, Any],
        params_files: Sequence[Path] = (),
        log_dir: Path | None = None,
        env_changes: Mapping[str, str | None] | None = None,
        log_level: str | None = None,
    ) -> None:
        """`env_changes`: the node processes' environment against os.environ (None values removed), e.g. the
        replay's own ROS domain (:func:`train_calib.isolation.isolated_environment`); `log_level`: the nodes'
        ``--log-level`` (e.g. ``warn``)."""
        from ..isolation import applied

        self.names = tuple(names)
        self._progress: dict[str, NodeProgress] = {}
        self._node = node
        self._sub = node.create_subscription(DiagnosticStatus, PROGRESS_TOPIC, self._on_progress, CONTROL_QOS)
        self._eoi = node.create_publisher(String, END_OF_INPUT_TOPIC, CONTROL_QOS)
        self._tmp = tempfile.TemporaryDirectory(prefix="train_calib_graph_")
        replay_params = Path(self._tmp.name) / "replay_params.yaml"
        replay_params.write_text(yaml.safe_dump({"/**": {"ros__parameters": dict(overrides)}}), encoding="utf-8")
        self.procs: dict[str, subprocess.Popen] = {}
        self._logs: dict[str, Path] = {}
        log_dir = Path(log_dir or self._tmp.name)
        for name in self.names:
            node_class(name)  # fail early, in one line, for a missing node
        env = applied(env_changes or {})
        try:
            for name in self.names:
                cmd = [sys.executable, "-m", NODE_MODULES[name][0], "--ros-args"]
                if log_level:
                    cmd += ["--log-level", log_level]
                for f in (*params_files, replay_params):
                    cmd += ["--params-file", str(f)]
                log = log_dir / f"{name}.log"
                self._logs[name] = log
                with open(log, "wb") as stream:
                    self.procs[name] = subprocess.Popen(
                        cmd, stdout=stream, stderr=subprocess.STDOUT, env=env, start_new_session=True
                    )
        except BaseException:
            self.close()
            raise

    def _on_progress(self, msg: DiagnosticStatus) -> None:
        if msg.name not in self.names:
            return
        p = NodeProgress()
        for kv in msg.values:
            kind, _, topic = kv.key.partition(":")
            if kind == "in":
                p.handled[topic] = int(kv.value)
            elif kind == "out":
                p.published[topic] = int(kv.value)
            elif kind == "matched":
                p.matched[topic] = int(kv.value)
            elif kv.key == "pending":
                p.pending = int(kv.value)
            elif kv.key == "ended":
                p.ended = kv.value == "1"
        self._progress[msg.name] = p

    def progress(self) -> dict[str, NodeProgress]:
        return self._progress

    def connected(self, extra: int = 1) -> bool:
        return super().connected(extra) and self._eoi.get_subscription_count() >= len(self.names)

    def end_of_input(self, name: str) -> None:
        self._eoi.publish(String(data=name))

    def check_alive(self) -> None:
        for name, proc in self.procs.items():
            code = proc.poll()
            if code is not None:
                raise GraphError(f"{name} exited with status {code}: {self.last_log_line(name)}")

    def last_log_line(self, name: str) -> str:
        try:
            lines = [ln for ln in self._logs[name].read_text(errors="replace").splitlines() if ln.strip()]
        except OSError:
            return "(no log)"
        errors = [ln for ln in lines if "error" in ln.lower()]
        return (errors or lines or ["(no output)"])[-1].strip()

    def finish(self, timeout_s: float = 15.0) -> None:
        """SIGINT every node (each publishes its final diagnostics and flushes), wait for them to exit."""
        for proc in self.procs.values():
            if proc.poll() is None:
                proc.send_signal(signal.SIGINT)
        deadline = time.monotonic() + timeout_s
        for proc in self.procs.values():
            try:
                proc.wait(timeout=max(0.1, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()

    def alive(self) -> Iterable[str]:
        return [n for n, p in self.procs.items() if p.poll() is None]

    def close(self) -> None:
        for proc in self.procs.values():
            if proc.poll() is None:
                proc.kill()
                proc.wait()
        self._node.destroy_subscription(self._sub)
        self._node.destroy_publisher(self._eoi)
        self._tmp.cleanup()


__all__ = ["NODE_MODULES", "Graph", "GraphError", "InProcessGraph", "NodeProgress", "ProcessGraph", "node_class"]
