"""A driver-advisory-system stand-in: subscribe to every train_calib output topic, print what arrived.

usage: python das_standin.py   -> prints READY, then on SIGINT/SIGTERM a JSON line
{topic: [[stamp_ns, ...], ...]} with, per message, the header stamp and a few fields.
"""

import json
import signal
import sys
import threading
import time

import rclpy
from rclpy.context import Context
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.signals import SignalHandlerOptions
from train_calib_msgs.msg import DrivingFeatures, DrivingRegime, ResistanceEstimate, TrackMeasurement, WindowResistance

TOPICS = {
    "/train_calib/measurement": (TrackMeasurement, lambda m: [m.s, m.v, m.run_id]),
    "/train_calib/resistance": (ResistanceEstimate, lambda m: [m.r0, m.r1, m.r2, float(m.covariance[12])]),
    "/train_calib/regime": (DrivingRegime, lambda m: [m.regime, m.effort]),
    "/train_calib/features": (DrivingFeatures, lambda m: [m.run_complete, list(m.regime_time_share)]),
    "/train_calib/window_resistance": (WindowResistance, lambda m: [m.ill_posed, m.r0, m.r1, m.r2]),
}


def main() -> int:
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    context = Context()
    rclpy.init(args=[], context=context, signal_handler_options=SignalHandlerOptions.NO)
    node = rclpy.create_node("das_standin", context=context)
    # transient local: every output from the first, even if this side matches the replay's publishers after it has
    # begun (docs/nodes.md, QoS)
    qos = QoSProfile(
        history=HistoryPolicy.KEEP_ALL,
        reliability=ReliabilityPolicy.RELIABLE,
        durability=DurabilityPolicy.TRANSIENT_LOCAL,
    )
    received = {t: [] for t in TOPICS}
    last = [time.monotonic()]
    for topic, (cls, fields) in TOPICS.items():

        def callback(msg, topic=topic, fields=fields):
            stamp = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
            received[topic].append([stamp, *fields(msg)])
            last[0] = time.monotonic()

        node.create_subscription(cls, topic, callback, qos)
    print("READY", flush=True)
    while not stop.is_set():
        _spin(node, context)
    quiet = time.monotonic()
    while time.monotonic() - quiet < 0.5:  # drain what is already delivered
        before = last[0]
        _spin(node, context)
        if last[0] != before:
            quiet = time.monotonic()
    print(json.dumps(received), flush=True)
    node.destroy_node()
    rclpy.try_shutdown(context=context)
    return 0


_executors = {}


def _spin(node, context):
    from rclpy.executors import SingleThreadedExecutor

    ex = _executors.get(id(node))
    if ex is None:
        ex = _executors[id(node)] = SingleThreadedExecutor(context=context)
        ex.add_node(node)
    ex.spin_once(timeout_sec=0.05)


if __name__ == "__main__":
    sys.exit(main())
