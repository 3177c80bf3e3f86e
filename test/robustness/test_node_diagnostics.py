"""The nodes flag faults on /diagnostics and drop bad messages with a reason (in-process nodes, sim time).

gnss_speed_node: an input silent for longer than input_timeout is WARN ("no /train/speed for N s") and the WARN
clears when it returns; drop_warn_count consecutive drops of an input are WARN with the reason. ukf_node: a
TrackMeasurement it cannot use (NaN, negative or implausible speed, an older stamp) is dropped with its
reason and no estimate is published for it; an unusable variance is repaired and counted; a reset of the
filter is WARN, repeated resets ERROR.
"""

from __future__ import annotations

import math
import sys
import time
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))
from faultlib import NS, T0, make_scenario

pytestmark = pytest.mark.ros

DATA = Path(__file__).resolve().parents[1] / "data"


class Harness:
    """A node under test, a publisher node and /clock, spun by one executor."""

    def __init__(self, context, node) -> None:
        import rclpy
        from rclpy.executors import SingleThreadedExecutor
        from rosgraph_msgs.msg import Clock

        from train_calib.nodes.common import reliable_qos

        self.node = node
        self.pub_node = rclpy.create_node("fault_harness", context=context)
        self.clock = self.pub_node.create_publisher(Clock, "/clock", reliable_qos(10))
        self.pubs = {}
        self.received = []
        self.executor = SingleThreadedExecutor(context=context)
        self.executor.add_node(node)
        self.executor.add_node(self.pub_node)

    def publisher(self, msg_type, topic):
        from train_calib.nodes.common import reliable_qos

        self.pubs[topic] = self.pub_node.create_publisher(msg_type, topic, reliable_qos(100))
        return self.pubs[topic]

    def listen(self, msg_type, topic):
        from train_calib.nodes.common import reliable_qos

        self.pub_node.create_subscription(msg_type, topic, self.received.append, reliable_qos(1000))

    def wait(self, condition, timeout_s=20.0):
        deadline = time.monotonic() + timeout_s
        while not condition():
            assert time.monotonic() < deadline, "timed out"
            self.executor.spin_once(timeout_sec=0.02)

    def connect(self):
        self.wait(lambda: all(p.get_subscription_count() >= 1 for p in [self.clock, *self.pubs.values()]))

    def tick(self, t_ns: int) -> None:
        from builtin_interfaces.msg import Time
        from rosgraph_msgs.msg import Clock

        self.clock.publish(Clock(clock=Time(sec=t_ns // NS, nanosec=t_ns % NS)))
        self.wait(lambda: self.node.get_clock().now().nanoseconds >= t_ns)

    def send(self, topic, msg) -> None:
        before = self.node.handled[topic]
        self.pubs[topic].publish(msg)
        self.wait(lambda: self.node.handled[topic] > before)

    def close(self):
        self.executor.shutdown()
        self.node.destroy_node()
        self.pub_node.destroy_node()


def _speed(t_ns, v):
    from geometry_msgs.msg import TwistStamped

    msg = TwistStamped()
    msg.header.stamp.sec, msg.header.stamp.nanosec = t_ns // NS, t_ns % NS
    msg.twist.linear.x = float(v)
    return msg


def _fix(t_ns, lat, lon):
    from sensor_msgs.msg import NavSatFix

    msg = NavSatFix()
    msg.header.stamp.sec, msg.header.stamp.nanosec = t_ns // NS, t_ns % NS
    msg.latitude, msg.longitude = float(lat), float(lon)
    msg.status.status = 0  # STATUS_FIX (the Jazzy default is STATUS_UNKNOWN, -2)
    return msg


def _status(node):
    status = node.diagnostic_status()
    return status.level[0], status.message, {kv.key: kv.value for kv in status.values}


def test_gnss_speed_node_warns_on_a_silent_input_and_on_consecutive_drops_then_clears(rclpy_context, tmp_path):
    from geometry_msgs.msg import TwistStamped
    from rclpy.parameter import Parameter
    from sensor_msgs.msg import NavSatFix

    from train_calib.nodes.gnss_speed_node import GnssSpeedNode

    sc = make_scenario(tmp_path)
    node = GnssSpeedNode(
        context=rclpy_context,
        parameter_overrides=[
            Parameter("track_file", value=str(sc.track_path)),
            Parameter("train_file", value=str(sc.train_path)),
            Parameter("use_sim_time", value=True),
            Parameter("input_timeout", value=5.0),
            Parameter("drop_warn_count", value=8),
            Parameter("diagnostics_period", value=3600.0),  # the test takes the reports
        ],
    )
    h = Harness(rclpy_context, node)
    try:
        h.publisher(NavSatFix, "/gnss/fix")
        h.publisher(TwistStamped, "/train/speed")
        h.connect()
        fixes = {e.stamp_ns: e for e in sc.events if e.topic == "/gnss/fix"}
        speeds = {e.stamp_ns: e for e in sc.events if e.topic == "/train/speed"}

        def second(k, speed=True, fix=True, v=None):
            t = T0 + k * NS
            h.tick(t)
            if speed:
                h.send("/train/speed", _speed(t, speeds[t].fields["v"] if v is None else v))
            if fix:
                h.send("/gnss/fix", _fix(t, fixes[t].fields["lat"], fixes[t].fields["lon"]))
            return _status(node)

        for k in range(10):
            level, message, _ = second(k)
        assert level == 0, message
        for k in range(10, 20):  # the speed falls silent; the GNSS goes on
            level, message, _ = second(k, speed=False)
        assert level == 1 and "no /train/speed for" in message
        level, message, values = second(20)  # it returns: the WARN clears
        assert level == 0, message
        for k in range(21, 31):  # ten NaN speeds in a row
            level, message, values = second(k, v=math.nan)
        assert level == 1 and "/train/speed: the last 10 samples were dropped (nan)" in message
        assert values["/train/speed dropped nan"] == "10"
        level, message, _ = second(31)
        assert level == 0, message
    finally:
        h.close()


def test_ukf_node_drops_unusable_measurements_with_a_reason_and_flags_resets(rclpy_context):
    from rclpy.parameter import Parameter
    from rclpy.serialization import serialize_message
    from train_calib_msgs.msg import ResistanceEstimate, TrackMeasurement

    from train_calib.measurement import Measurement
    from train_calib.nodes.convert import measurement_to_msg
    from train_calib.nodes.ukf_node import UkfNode

    node = UkfNode(
        context=rclpy_context,
        parameter_overrides=[
            Parameter("train_file", value=str(DATA / "small_train.yaml")),
            Parameter("use_sim_time", value=True),
            Parameter("diagnostics_period", value=3600.0),  # the test takes the reports
        ],
    )
    h = Harness(rclpy_context, node)
    try:
        h.publisher(TrackMeasurement, "/train_calib/measurement")
        h.listen(ResistanceEstimate, "/train_calib/resistance")
        h.connect()
        h.wait(lambda: node.output_publishers()["/train_calib/resistance"].get_subscription_count() >= 1)
        t = T0
        sent = 0

        def measure(**changes):
            nonlocal t, sent
            t += NS
            m = Measurement(t, 1000.0 + 20.0 * (t - T0) / NS, 20.0, 0.01, 1.0)
            for k, v in changes.items():
                setattr(m, k, v)
            h.tick(m.stamp_ns)
            h.send("/train_calib/measurement", measurement_to_msg(m))
            sent += 1

        for _ in range(5):
            measure()
        measure(v=math.nan)
        measure(v=-1.0)
        measure(v=1.0e6)
        measure(stamp_ns=t - 10 * NS)  # older than the last one
        measure(s_variance=math.inf, v_variance=-1.0)  # used, with the configured variances
        measure(power_valid=True, power_consumed=math.nan)
        # a malformed message (serialized bytes cut short): dropped as an error, the node goes on
        whole = serialize_message(measurement_to_msg(Measurement(t + NS, 1.0, 20.0, 0.01, 1.0), "frame"))
        h.send("/train_calib/measurement", whole[:30])
        h.wait(lambda: len(h.received) >= 7)
        h.executor.spin_once(timeout_sec=0.2)
        assert len(h.received) == sent - 4  # no estimate for the four dropped
        assert all(math.isfinite(m.r0) and min(m.r0, m.r1, m.r2) >= 0.0 for m in h.received)
        level, message, values = _status(node)
        drops = {k: v for k, v in values.items() if " dropped " in k or " repaired " in k}
        assert drops == {
            "/train_calib/measurement dropped error": "1",
            "/train_calib/measurement dropped implausible": "1",
            "/train_calib/measurement dropped nan": "1",
            "/train_calib/measurement dropped negative_speed": "1",
            "/train_calib/measurement dropped out_of_order": "1",
            "/train_calib/measurement repaired invalid_value": "2",
        }
        assert level == 0, message
        # a NaN forced into the state: the filter resets (WARN), twice before the next report: ERROR
        node.estimator._h.x[1] = math.nan  # the output filter's v
        measure()
        level, message, values = _status(node)
        assert level == 1 and "filter reset 1 times" in message and values["filter health"] == "reset"
        for _ in range(2):
            node.estimator._h.x[1] = math.nan  # the output filter's v
            measure()
        level, message, _ = _status(node)
        assert level == 2 and "filter reset 2 times" in message, message
        assert all(math.isfinite(m.v) for m in h.received)
    finally:
        h.close()
