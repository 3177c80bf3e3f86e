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
"""

from __future__ import annotations

import math
import os
import signal
import sys
import threading
from collections import Counter
from collections.abc import Callable, Iterable, Sequence
from typing import Any

import rclpy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor, SetParametersResult
from rclpy.clock import Clock, ClockType
from rclpy.context import Context
from rclpy.duration import Duration
from rclpy.exceptions import (
    InvalidParameterTypeException,
    InvalidParameterValueException,
    ParameterException,
)
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.serialization import deserialize_message
from rclpy.signals import SignalHandlerOptions
from std_msgs.msg import String

from ..diagnostics_schedule import DiagnosticsSchedule
from ..errors import ConfigError
from ..params import ParamSet, ParamSpec
from . import cdr
from .config import NODE_PARAMS, NodeConfig
from .slots import bare, check_layout

DIAGNOSTICS_TOPIC = "/diagnostics"
PROGRESS_TOPIC = "/train_calib/progress"
END_OF_INPUT_TOPIC = "/train_calib/end_of_input"
HARDWARE_ID = "train_calib"
ERROR_REASON = "error"
PROGRESS_PERIOD_S = 0.2
FINISH_ACK_TIMEOUT_S = 2.0
RCLPY_DESERIALIZE_ENV = "TRAIN_CALIB_RCLPY_DESERIALIZE"  # 1: inputs decoded by rclpy, not by cdr (a debugging aid)

# DiagnosticStatus.level is a ROS `byte`: rclpy wants bytes of length 1; these are ints for comparisons
OK = 0
WARN = 1
ERROR = 2

_INT64_MAX = 2**63 - 1
RCLError = _rclpy.RCLError

check_layout(KeyValue)  # the slots key_value() fills


def key_value(key: str, value: str) -> KeyValue:
    """A diagnostic_msgs/KeyValue without the generated constructor's cost (a diagnostics array holds dozens)."""
    kv = bare(KeyValue)
    kv._key = key
    kv._value = value
    return kv


# -- QoS --------------------------------------------------------------------------------------------


def sensor_qos(depth: int) -> QoSProfile:
    """Inputs from the on-board stack: best effort (hears reliable and best-effort publishers), volatile."""
    return QoSProfile(
        history=HistoryPolicy.KEEP_LAST,
        depth=depth,
        reliability=ReliabilityPolicy.BEST_EFFORT,
        durability=DurabilityPolicy.VOLATILE,
    )


def reliable_qos(depth: int) -> QoSProfile:
    """Outputs and the subscriptions between train_calib nodes: reliable, volatile, keep last `depth`."""
    return QoSProfile(
        history=HistoryPolicy.KEEP_LAST,
        depth=depth,
        reliability=ReliabilityPolicy.RELIABLE,
        durability=DurabilityPolicy.VOLATILE,
    )


DIAGNOSTICS_QOS = reliable_qos(100)
CONTROL_QOS = reliable_qos(100)


# -- parameters -------------------------------------------------------------------------------------


def descriptor_for(spec: ParamSpec) -> ParameterDescriptor:
    """The ROS parameter descriptor of a ParamSet field: description, range, choices, read-only."""
    d = ParameterDescriptor(description=spec.doc, read_only=bool(spec.read_only))
    if spec.kind is float and (spec.low is not None or spec.high is not None):
        d.floating_point_range = [
            FloatingPointRange(
                from_value=-math.inf if spec.low is None else float(spec.low),
                to_value=math.inf if spec.high is None else float(spec.high),
                step=0.0,
            )
        ]
    elif spec.kind is int and (spec.low is not None or spec.high is not None):
        d.integer_range = [
            IntegerRange(
                from_value=-_INT64_MAX if spec.low is None else math.ceil(spec.low),
                to_value=_INT64_MAX if spec.high is None else math.floor(spec.high),
                step=0,
            )
        ]
    constraints = []
    if spec.low_open and spec.low is not None:
        constraints.append(f"must be greater than {spec.low:g}")
    if spec.choices:
        constraints.append("one of: " + ", ".join(spec.choices))
    if spec.kind is tuple and (spec.low is not None or spec.high is not None):
        constraints.append("every element " + spec.doc.rsplit("range ", 1)[-1])
    d.additional_constraints = "; ".join(constraints)
    return d


def _ros_value(spec: ParamSpec, value: Any) -> Any:
    if spec.kind is tuple:
        return [float(v) for v in value]
    return value


def _coerced_override(spec: ParamSpec, override: Parameter) -> Parameter:
    """An INTEGER (array) override of a double (array) parameter, as a double: `30` in a params file."""
    if spec.kind is float and override.type_ == Parameter.Type.INTEGER:
        return Parameter(override.name, Parameter.Type.DOUBLE, float(override.value))
    if spec.kind is tuple and override.type_ == Parameter.Type.INTEGER_ARRAY:
        return Parameter(override.name, Parameter.Type.DOUBLE_ARRAY, [float(v) for v in override.value])
    return override


class RateMeter:
    """Messages per second between two reports, in the reports' time base: the node clock, or under use_sim_time
    the inputs' stamps (the data's time, as the diagnostics schedule).

    Counting costs nothing per message (no clock read); the time of the last message is known to the
    report period, which is all the input-timeout check needs.
    """

    __slots__ = ("count", "last_ns", "rate", "since_ns")

    def __init__(self) -> None:
        self.count = 0
        self.last_ns: int | None = None  # node clock of the report that first saw the latest messages
        self.since_ns: int | None = None
        self.rate = math.nan

    def take(self, now_ns: int) -> float:
        """Rate since the previous take (Hz); the previous value while no node time has passed."""
        if self.count:
            self.last_ns = now_ns
        if self.since_ns is not None and now_ns > self.since_ns:
            self.rate = self.count / ((now_ns - self.since_ns) * 1e-9)
        elif self.since_ns is not None:
            return self.rate
        self.count = 0
        self.since_ns = now_ns
        return self.rate


# -- the node base class ----------------------------------------------------------------------------


class TrainCalibNode(Node):
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
        self.diagnostics_published = 0
        self._diag_pub = self.create_publisher(DiagnosticArray, DIAGNOSTICS_TOPIC, DIAGNOSTICS_QOS)
        # the node clock's timer on board; under sim time the data's stamps (diagnostics_schedule: rate-independent)
        self._diag_schedule: DiagnosticsSchedule | None = None
        self._data_now_ns: int | None = None  # under the schedule: the latest input stamp, the reports' time base
        self._diag_timer = None
        self._start_diagnostics(node_cfg.diagnostics_period)
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
                overrides[spec.name] = _coerced_override(spec, overrides[spec.name])
            try:
                self.declare_parameter(spec.name, _ros_value(spec, spec.default), descriptor_for(spec))
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

    def _start_diagnostics(self, period_s: float) -> None:
        """/diagnostics every ``period_s``: a timer of the node clock, or under ``use_sim_time`` the data's time (a
        DiagnosticsSchedule asked with each input's stamp; a sim-time timer fires once per jump of /clock, so its
        count followed the replay rate)."""
        if self._diag_timer is not None:
            self._diag_timer.cancel()
            self.destroy_timer(self._diag_timer)
            self._diag_timer = None
        if self.get_parameter("use_sim_time").value:
            self._diag_schedule = DiagnosticsSchedule(period_s)
        else:
            self._diag_schedule = None
            self._diag_timer = self.create_timer(period_s, self.publish_diagnostics)

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

    # -- diagnostics ----------------------------------------------------------------------------
    def diagnostic_values(self) -> list[tuple[str, Any]]:
        """Node-specific (key, value) pairs appended to the status (override)."""
        return []

    def diagnostic_problems(self) -> list[tuple[int, str]]:
        """Node-specific (level, message) problems: WARN or ERROR (override)."""
        return []

    def refresh_counters(self) -> None:
        """Copy a core object's counters into the node's (override; called before each report)."""

    def diagnostic_status(self) -> DiagnosticStatus:
        self.refresh_counters()
        # the input rates and timeouts in the time the reports follow: the data's stamps under the schedule (the sim
        # clock lags the data at --rate 0, so a rate over it was not the data's), the node clock otherwise
        data_now = self._data_now_ns if self._diag_schedule is not None else None
        now_ns = data_now if data_now is not None else self.get_clock().now().nanoseconds
        timeout_ns = self.config(NodeConfig).input_timeout * 1e9
        values: list[KeyValue] = []
        add = values.append
        problems: list[tuple[int, str]] = []
        for topic in self._input_topics:
            meter = self._rates[topic]
            rate = meter.take(now_ns)
            add(key_value(f"{topic} rate (Hz)", "nan" if math.isnan(rate) else f"{rate:.3f}"))
            add(key_value(f"{topic} received", str(self._received[topic])))
            drops, repairs = self._drops.get(topic), self._repairs.get(topic)
            if drops:
                values += [key_value(f"{topic} dropped {reason}", str(n)) for reason, n in sorted(drops.items())]
            if repairs:
                values += [key_value(f"{topic} repaired {reason}", str(n)) for reason, n in sorted(repairs.items())]
            if meter.last_ns is not None and now_ns - meter.last_ns > timeout_ns:
                problems.append((WARN, f"no {topic} for {(now_ns - meter.last_ns) * 1e-9:.0f} s"))
        for topic in self._publishers_by_topic:
            add(key_value(f"{topic} published", str(self._published[topic])))
        values += [key_value(str(k), str(v)) for k, v in self.diagnostic_values()]
        problems.extend(self.diagnostic_problems())
        level = max((lvl for lvl, _ in problems), default=OK)
        dropped = sum(sum(c.values()) for c in self._drops.values())
        message = "; ".join(text for _, text in problems) if problems else f"OK ({dropped} samples dropped)"
        return DiagnosticStatus(
            level=bytes([level]), name=self.get_name(), message=message, hardware_id=HARDWARE_ID, values=values
        )

    def publish_diagnostics(self) -> None:
        array = DiagnosticArray()
        array.header.stamp = self.get_clock().now().to_msg()
        array.status = [self.diagnostic_status()]
        self._diag_pub.publish(array)
        self.diagnostics_published += 1


# -- main() of every node ---------------------------------------------------------------------------


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


def check_params_files(argv: Sequence[str]) -> None:
    """ConfigError (one line: file and problem) for a ``--params-file`` that cannot be read or is not a mapping."""
    from ..yamlcheck import load_yaml_mapping

    for i, arg in enumerate(argv):
        if arg == "--params-file" and i + 1 < len(argv):
            load_yaml_mapping(argv[i + 1], "params file")


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


__all__ = [
    "CONTROL_QOS",
    "DIAGNOSTICS_QOS",
    "DIAGNOSTICS_TOPIC",
    "END_OF_INPUT_TOPIC",
    "ERROR",
    "OK",
    "PROGRESS_TOPIC",
    "WARN",
    "RateMeter",
    "TrainCalibNode",
    "check_params_files",
    "descriptor_for",
    "key_value",
    "reliable_qos",
    "run_node",
    "sensor_qos",
]
