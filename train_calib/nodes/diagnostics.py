"""A node's /diagnostics: :class:`NodeDiagnostics`, the base class of ``TrainCalibNode`` that builds and publishes
the status (the conventions: ``common.py``, "Diagnostics"), its levels, ``key_value`` and the input ``RateMeter``.

When it publishes under ``use_sim_time`` (ROS-free): ``diagnostics_schedule.py``.
"""

from __future__ import annotations

import math
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.node import Node

from ..diagnostics_schedule import DiagnosticsSchedule
from .config import NodeConfig
from .qos import DIAGNOSTICS_QOS
from .slots import bare, check_layout

DIAGNOSTICS_TOPIC = "/diagnostics"
HARDWARE_ID = "train_calib"

# DiagnosticStatus.level is a ROS `byte`: rclpy wants bytes of length 1; these are ints for comparisons
OK = 0
WARN = 1
ERROR = 2

check_layout(KeyValue)  # the slots key_value() fills


def key_value(key: str, value: str) -> KeyValue:
    """A diagnostic_msgs/KeyValue without the generated constructor's cost (a diagnostics array holds dozens)."""
    kv = bare(KeyValue)
    kv._key = key
    kv._value = value
    return kv


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


class NodeDiagnostics(Node):
    """The /diagnostics status of a ``TrainCalibNode`` (base class): built from the node's counters, published every
    ``diagnostics_period`` and by ``finish()``.

    The counters are ``TrainCalibNode``'s: ``_input_topics``, ``_rates``, ``_received``, ``_drops``, ``_repairs``,
    ``_publishers_by_topic``, ``_published``, and ``config(NodeConfig)``; under the schedule its inputs set
    ``_data_now_ns`` (the latest stamp) and ask ``_diag_schedule`` when a status is due.
    """

    def _init_diagnostics(self, period_s: float) -> None:
        """The publisher, the count and the first timer or schedule (``TrainCalibNode.__init__``)."""
        self.diagnostics_published = 0
        self._diag_pub = self.create_publisher(DiagnosticArray, DIAGNOSTICS_TOPIC, DIAGNOSTICS_QOS)
        # the node clock's timer on board; under sim time the data's stamps (diagnostics_schedule: rate-independent)
        self._diag_schedule: DiagnosticsSchedule | None = None
        self._data_now_ns: int | None = None  # under the schedule: the latest input stamp, the reports' time base
        self._diag_timer = None
        self._start_diagnostics(period_s)

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
