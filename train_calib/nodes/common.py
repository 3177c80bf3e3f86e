"""Conventions every train_calib node follows (window_calib_node too): use these, do not re-invent them.

A node subclasses :class:`TrainCalibNode`, sets ``NODE_NAME`` (a key of ``config.NODE_PARAMS``) and:

* **Parameters.** Declared at construction from the node's ParamSets (``config.NODE_PARAMS``) with a
  ``ParameterDescriptor`` each: description with unit and range (``ParamSpec.doc``),
  ``FloatingPointRange``/``IntegerRange``, ``additional_constraints`` for choices, ``read_only``. The
  values (defaults, ``--params-file``, ``-p``) are checked with ``ParamSet.check`` and the ParamSet's
  cross-field ``validate``; a bad value stops the node at start with one line (``ConfigError``) and is
  refused at run time with the reason (``ros2 param set`` prints it). ``self.config(IngestConfig)``
  returns the current frozen config; ``on_parameters_changed(changed_types)`` is called after a
  successful change (apply it to the core object). An INTEGER given for a double parameter in a params
  file is taken as a double (``30`` for ``30.0``).
* **Inputs and outputs.** Inputs are raw subscriptions decoded by :mod:`cdr` into read-only views of the
  message (named tuples with its field names; 3 us instead of rclpy's 25-50 us per message), so a callback
  reads ``msg.header.stamp`` as usual but must not modify or republish ``msg``. ``self.sensor_input(...)``
  subscribes with a SensorData-compatible profile (best effort, volatile, depth ``input_depth``: it hears
  reliable and best-effort publishers); ``self.chain_input(...)`` subscribes to another train_calib node's
  output (reliable, depth ``output_depth``); ``self.output(...)`` creates a reliable, volatile publisher of
  depth ``output_depth`` and ``self.publish(topic, msg)`` sends a message, or its serialized bytes
  (``convert.*_to_cdr``), and counts. Callbacks are wrapped: receipt counted, rate measured (node clock, so
  sim time under ``use_sim_time``), an exception in the core or in the decoding of a malformed message is
  counted as a drop with reason ``error`` and logged (throttled), and the node keeps running.
* **Drops.** ``self.drop(topic, reason)`` counts a dropped sample; ``self.set_drops(topic, counter)``
  mirrors a core object's counters (the ingest counts its own).
* **Diagnostics.** ``/diagnostics`` (diagnostic_msgs/DiagnosticArray) every ``diagnostics_period`` of the
  node clock, under ``use_sim_time`` of the data's time (at most one per period of the inputs' stamps,
  ``diagnostics_schedule``: the same count at any replay rate), and once more at the end: one
  DiagnosticStatus named after the node, ``hardware_id`` ``train_calib``; values: per input topic the rate
  (Hz), received and dropped-by-reason counts; per output topic the published count; then the node's
  ``diagnostic_values()``. Level WARN when an input seen before is silent for longer than ``input_timeout``,
  or when the node's ``diagnostic_problems()`` reports one (e.g. the filter health); ERROR for problems the
  node marks as errors.
* **End of input and shutdown.** ``end_of_input()`` (override; idempotent) releases what the node holds
  and closes the current run: called at shutdown, by the in-process replay at the end of a bag, and, with
  ``report_progress`` true, when a ``std_msgs/String`` naming the node (or ``*``) arrives on
  ``/train_calib/end_of_input`` (the replay of ``--processes``).
  :func:`run_node` is the ``main()`` of every node: SIGINT/SIGTERM stop spinning, then ``finish()``
  (end of input, final /diagnostics, wait up to 2 s for reliable subscribers to acknowledge every
  output), then the node is destroyed and the context shut down: no message is cut off.
* **Replay flow control.** With ``report_progress`` true the node publishes its counters (handled per
  input topic, published and matched subscribers per output topic, ``pending``) as a
  diagnostic_msgs/DiagnosticStatus on ``/train_calib/progress`` after every input and every 0.2 s
  (steady clock); the replay uses them to pace the bag without losing a message (docs/nodes.md).

Writing a node (e.g. ``window_calib_node.py``)::

    class WindowCalibNode(TrainCalibNode):
        NODE_NAME = "window_calib_node"          # its ParamSets: config.NODE_PARAMS[NODE_NAME]

        def __init__(self, **kwargs):
            super().__init__(**kwargs)            # declares and validates every parameter
            self.core = WindowCalibrator(train, self.config(WindowConfig))
            self.output(WindowResistance, WINDOW_TOPIC)
            self.chain_input(TrackMeasurement, MEASUREMENT_TOPIC, self._on_measurement)

        def _on_measurement(self, msg):          # convert, call the core, convert back, publish
            ...
            self.publish(WINDOW_TOPIC, out)

    def main(args=None):
        return run_node(WindowCalibNode, args)

``graph.NODE_MODULES`` maps the node name to its module and class for the replay.

The pieces live in modules of their own, re-exported here: ``ros_params`` (a ParamSpec as a ROS parameter),
``qos`` (the profiles), ``diagnostics`` (``NodeDiagnostics``, the base class that builds and publishes the status),
``runner`` (``make_executor``, ``run_node``).
"""

from __future__ import annotations

import os
from collections import Counter
from collections.abc import Callable, Iterable, Sequence
from typing import Any

from diagnostic_msgs.msg import DiagnosticStatus
from rcl_interfaces.msg import SetParametersResult
from rclpy.clock import Clock, ClockType
from rclpy.context import Context
from rclpy.duration import Duration
from rclpy.exceptions import (
    InvalidParameterTypeException,
    InvalidParameterValueException,
    ParameterException,
)
from rclpy.parameter import Parameter
from rclpy.qos import QoSProfile
from rclpy.serialization import deserialize_message
from std_msgs.msg import String

from ..errors import ConfigError
from ..params import ParamSet, ParamSpec
from . import cdr
from .config import NODE_PARAMS, NodeConfig
from .diagnostics import DIAGNOSTICS_TOPIC, ERROR, HARDWARE_ID, OK, WARN, NodeDiagnostics, RateMeter, key_value
from .qos import CONTROL_QOS, DIAGNOSTICS_QOS, reliable_qos, sensor_qos
from .ros_params import check_params_files, coerced_override, descriptor_for, ros_value
from .runner import RCLError, make_executor, run_node

PROGRESS_TOPIC = "/train_calib/progress"
END_OF_INPUT_TOPIC = "/train_calib/end_of_input"
ERROR_REASON = "error"
PROGRESS_PERIOD_S = 0.2
FINISH_ACK_TIMEOUT_S = 2.0
RCLPY_DESERIALIZE_ENV = "TRAIN_CALIB_RCLPY_DESERIALIZE"  # 1: inputs decoded by rclpy, not by cdr (a debugging aid)


# -- the node base class ----------------------------------------------------------------------------


class TrainCalibNode(NodeDiagnostics):
    """Base of the train_calib nodes: parameters, counted inputs/outputs, diagnostics, end of input."""

    NODE_NAME = ""

    def __init__(
        self,
        *,
        context: Context | None = None,
        cli_args: Sequence[str] | None = None,
        parameter_overrides: Sequence[Parameter] | None = None,
        node_name: str | None = None,
        namespace: str | None = None,
    ) -> None:
        super().__init__(
            node_name or self.NODE_NAME,
            context=context,
            cli_args=list(cli_args) if cli_args is not None else None,
            namespace=namespace,
            parameter_overrides=list(parameter_overrides) if parameter_overrides else None,
        )
        self._param_sets = NODE_PARAMS[self.NODE_NAME]
        self._owner: dict[str, type[ParamSet]] = {}
        self._configs: dict[type[ParamSet], ParamSet] = {}
        try:
            self._declare_parameters()
        except BaseException:
            self.destroy_node()
            raise
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self.add_post_set_parameters_callback(self._after_set_parameters)

        node_cfg = self.config(NodeConfig)
        self._in_depth = node_cfg.input_depth
        self._out_depth = node_cfg.output_depth
        self._received: Counter[str] = Counter()
        self._handled: Counter[str] = Counter()
        self._published: Counter[str] = Counter()
        self._drops: dict[str, Counter[str]] = {}
        self._repairs: dict[str, Counter[str]] = {}
        self._rates: dict[str, RateMeter] = {}
        self._publishers_by_topic: dict[str, Any] = {}
        self._input_topics: list[str] = []
        self._ended = False
        self._finished = False
        self._init_diagnostics(node_cfg.diagnostics_period)
        self._progress_pub = None
        if node_cfg.report_progress:  # replay control: progress out, end of input in
            self._eoi_sub = self.create_subscription(String, END_OF_INPUT_TOPIC, self._on_end_of_input, CONTROL_QOS)
            self._progress_pub = self.create_publisher(DiagnosticStatus, PROGRESS_TOPIC, CONTROL_QOS)
            self._progress_timer = self.create_timer(
                PROGRESS_PERIOD_S, self.publish_progress, clock=Clock(clock_type=ClockType.STEADY_TIME)
            )

    # -- parameters -------------------------------------------------------------------------------
    def _declare_parameters(self) -> None:
        where = f"{self.get_fully_qualified_name()} parameters"
        specs: list[tuple[type[ParamSet], ParamSpec]] = []
        for owner in self._param_sets:
            for spec in owner.specs():
                if spec.name in self._owner:
                    raise ConfigError(where, spec.name, f"declared by two parameter sets of {self.NODE_NAME}")
                self._owner[spec.name] = owner
                specs.append((owner, spec))
        overrides = getattr(self, "_parameter_overrides", {})  # rclpy's: --params-file, -p, parameter_overrides
        for owner, spec in specs:
            if spec.name in overrides:
                overrides[spec.name] = coerced_override(spec, overrides[spec.name])
            try:
                self.declare_parameter(spec.name, ros_value(spec, spec.default), descriptor_for(spec))
            except (InvalidParameterTypeException, InvalidParameterValueException) as exc:
                # the ParamSet's reason (units, open bounds) when it has one, else rclpy's
                value = overrides[spec.name].value if spec.name in overrides else spec.default
                _, reason = owner.check(spec.name, tuple(value) if spec.kind is tuple else value)
                if reason is None:
                    text = str(exc).rsplit(f": {spec.name}", 1)[0]
                    reason = text.split("Reason: ", 1)[-1]
                raise ConfigError(where, spec.name, reason) from None
            except ParameterException as exc:
                raise ConfigError(where, spec.name, str(exc)) from None
        for owner in self._param_sets:
            values = {s.name: self.get_parameter(s.name).value for s in owner.specs()}
            self._configs[owner] = owner.from_mapping(values, source=where)

    def config(self, cls: type[ParamSet]) -> Any:
        """The current value of one of the node's ParamSets."""
        return self._configs[cls]

    def _candidate_configs(self, params: Iterable[Parameter]) -> dict[type[ParamSet], ParamSet]:
        """The configs with `params` applied; raises ConfigError with the reason for a bad value."""
        changes: dict[type[ParamSet], dict[str, Any]] = {}
        for p in params:
            owner = self._owner.get(p.name)
            if owner is None:
                continue  # e.g. use_sim_time: rclpy's own
            value = p.value
            if owner.spec(p.name).kind is tuple and value is not None:
                value = tuple(value)
            changes.setdefault(owner, {})[p.name] = value
        out = {}
        for owner, values in changes.items():
            out[owner] = self._configs[owner].replace(**values)  # check + validate: ConfigError
        return out

    def _on_set_parameters(self, params: list[Parameter]) -> SetParametersResult:
        try:
            candidates = self._candidate_configs(params)
            for owner, cfg in candidates.items():
                reason = self.check_config(cfg)
                if reason:
                    raise ConfigError(owner.__name__, "", reason)
        except ConfigError as exc:
            reason = f"{exc.key}: {exc.problem}" if exc.key else exc.problem
            return SetParametersResult(successful=False, reason=reason)
        return SetParametersResult(successful=True)

    def _after_set_parameters(self, params: list[Parameter]) -> None:
        candidates = self._candidate_configs(params)
        self._configs.update(candidates)
        if candidates:
            self.on_parameters_changed(set(candidates))
        if NodeConfig in candidates:
            self._start_diagnostics(self.config(NodeConfig).diagnostics_period)

    def check_config(self, cfg: ParamSet) -> str | None:
        """Node-specific check of a changed config (e.g. a station must exist); a reason refuses it."""
        return None

    def on_parameters_changed(self, changed: set[type[ParamSet]]) -> None:
        """Apply changed configs to the core objects (override)."""

    # -- inputs, outputs, drops -------------------------------------------------------------------
    def sensor_input(self, msg_type: Any, topic: str, callback: Callable[[Any], None]) -> Any:
        """Subscription to an on-board sensor topic (SensorData-compatible QoS)."""
        return self._input(msg_type, topic, callback, sensor_qos(self._in_depth))

    def chain_input(self, msg_type: Any, topic: str, callback: Callable[[Any], None]) -> Any:
        """Subscription to another train_calib node's output (reliable)."""
        return self._input(msg_type, topic, callback, reliable_qos(self._out_depth))

    def _input(self, msg_type: Any, topic: str, callback: Callable[[Any], None], qos: QoSProfile) -> Any:
        self._input_topics.append(topic)
        self._rates[topic] = RateMeter()
        self._drops.setdefault(topic, Counter())
        logger = self.get_logger()
        received, handled, drops, rate = self._received, self._handled, self._drops[topic], self._rates[topic]
        decode = self.input_decoder(msg_type)

        def handler(data: bytes) -> None:
            received[topic] += 1
            rate.count += 1
            msg = None
            try:
                msg = decode(data)
                callback(msg)
            except Exception as exc:  # a bad sample or a core failure must not stop the node
                drops[ERROR_REASON] += 1
                logger.error(f"{topic}: sample dropped: {exc.__class__.__name__}: {exc}", throttle_duration_sec=5.0)
            handled[topic] += 1
            schedule = self._diag_schedule
            if schedule is not None and msg is not None:
                stamp = getattr(getattr(msg, "header", None), "stamp", None)  # every input has a header; be safe
                if stamp is not None:
                    self._data_now_ns = stamp_ns = stamp.sec * 1_000_000_000 + stamp.nanosec
                    if schedule.due(stamp_ns):
                        self.publish_diagnostics()
            if self._progress_pub is not None:
                self.publish_progress()

        return self.create_subscription(msg_type, topic, handler, qos, raw=True)

    @staticmethod
    def input_decoder(msg_type: Any) -> Callable[[bytes], Any]:
        """The decoding of an input's serialized messages: a view with the message's fields (``cdr``), or with
        ``TRAIN_CALIB_RCLPY_DESERIALIZE=1`` in the environment rclpy's own message object (both read alike)."""
        if os.environ.get(RCLPY_DESERIALIZE_ENV, "") not in ("", "0"):
            return lambda data: deserialize_message(data, msg_type)
        return cdr.layout(msg_type).decode

    def output(self, msg_type: Any, topic: str) -> Any:
        publisher = self.create_publisher(msg_type, topic, reliable_qos(self._out_depth))
        self._publishers_by_topic[topic] = publisher
        self._published[topic] += 0
        return publisher

    def publish(self, topic: str, msg: Any) -> None:
        self._publishers_by_topic[topic].publish(msg)
        self._published[topic] += 1

    def drop(self, topic: str, reason: str) -> None:
        self._drops.setdefault(topic, Counter())[reason] += 1

    def set_drops(self, topic: str, counts: Counter | dict[str, int]) -> None:
        """Mirror a core object's drop counters for a topic (keeps the node's own ``error`` count)."""
        current = self._drops.setdefault(topic, Counter())
        for reason, n in counts.items():
            current[reason] = n

    def set_repairs(self, topic: str, counts: Counter | dict[str, int]) -> None:
        """Mirror a core object's counters of samples used after a repair (``<topic> repaired <reason>``)."""
        current = self._repairs.setdefault(topic, Counter())
        for reason, n in counts.items():
            current[reason] = n

    # -- counters (replay flow control, tests) ---------------------------------------------------------
    @property
    def handled(self) -> Counter:
        """Input messages whose callback has completed, per topic."""
        return self._handled

    @property
    def published(self) -> Counter:
        """Messages published, per output topic."""
        return self._published

    @property
    def drops(self) -> dict[str, Counter]:
        self.refresh_counters()
        return self._drops

    @property
    def pending(self) -> int:
        """Samples held by the node (released by more input or end_of_input)."""
        return 0

    @property
    def input_topics(self) -> list[str]:
        return list(self._input_topics)

    @property
    def ended(self) -> bool:
        """end_of_input was requested through the end-of-input topic or mark_ended()."""
        return self._ended

    def mark_ended(self) -> None:
        self.end_of_input()
        self._ended = True

    def output_publishers(self) -> dict[str, Any]:
        return dict(self._publishers_by_topic)

    def publish_progress(self) -> None:
        if self._progress_pub is None:
            return
        handled, published = self._handled, self._published
        values = [key_value(f"in:{t}", str(handled[t])) for t in self._input_topics]
        for topic, pub in self._publishers_by_topic.items():
            values.append(key_value(f"out:{topic}", str(published[topic])))
            values.append(key_value(f"matched:{topic}", str(pub.get_subscription_count())))
        values.append(key_value("pending", str(self.pending)))
        values.append(key_value("ended", "1" if self._ended else "0"))
        self._progress_pub.publish(DiagnosticStatus(name=self.get_name(), hardware_id=HARDWARE_ID, values=values))

    # -- end of input and shutdown ------------------------------------------------------------------
    def _on_end_of_input(self, msg: String) -> None:
        if msg.data in ("*", self.get_name()):
            self.end_of_input()
            self._ended = True
            if self._progress_pub is not None:
                self.publish_progress()

    def end_of_input(self) -> None:
        """Release held samples and close the current run (override; must be idempotent)."""

    def finish(self, ack_timeout_s: float = FINISH_ACK_TIMEOUT_S) -> None:
        """End of input, a final /diagnostics, then wait for reliable subscribers to acknowledge outputs."""
        if self._finished:
            return
        self._finished = True
        try:
            self.end_of_input()
        except Exception as exc:
            self.get_logger().error(f"end of input failed: {exc.__class__.__name__}: {exc}")
        self.publish_diagnostics()
        if self._progress_pub is not None:
            self.publish_progress()
        for pub in [*self._publishers_by_topic.values(), self._diag_pub]:
            pub.wait_for_all_acked(Duration(seconds=ack_timeout_s))


__all__ = [
    "CONTROL_QOS",
    "DIAGNOSTICS_QOS",
    "DIAGNOSTICS_TOPIC",
    "END_OF_INPUT_TOPIC",
    "ERROR",
    "ERROR_REASON",
    "FINISH_ACK_TIMEOUT_S",
    "HARDWARE_ID",
    "OK",
    "PROGRESS_PERIOD_S",
    "PROGRESS_TOPIC",
    "RCLPY_DESERIALIZE_ENV",
    "WARN",
    "NodeDiagnostics",
    "RCLError",
    "RateMeter",
    "TrainCalibNode",
    "check_params_files",
    "descriptor_for",
    "key_value",
    "make_executor",
    "reliable_qos",
    "run_node",
    "sensor_qos",
]
