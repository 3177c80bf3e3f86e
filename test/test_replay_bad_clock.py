"""A bag whose log time /clock cannot carry, and a /clock before 1970, never kill the recorder or the replay."""

from __future__ import annotations

import json
import subprocess
import sys
import time

import pytest
from repo_paths import REPO

from train_calib import bagio
from train_calib.bagio import BagWriter, bag_topics, iter_bag

pytestmark = pytest.mark.ros

BAG = REPO / "bags" / "intercity_32km_10s_00"
ABSURD_NS = 3 * 10**18  # 2065: beyond the int32 seconds of /clock, which wrapped to a negative time


def test_a_log_time_clock_cannot_carry_is_counted_and_the_replay_goes_on(tmp_path):
    topics = {t: ty for t, ty in bag_topics(BAG).items() if t in bagio.INPUT_TOPICS}
    bad = tmp_path / "bad"
    with BagWriter(bad, topics) as writer:
        for k, m in enumerate(iter_bag(BAG, topics)):
            writer.write_raw(m.topic, m.data, ABSURD_NS if k == 39 else m.log_time_ns)
    out = tmp_path / "o"
    argv = ["replay", str(bad), "--track", "intercity_32km", "--train", "virm6", "--out", str(out), "--no-report"]
    proc = subprocess.run(
        [sys.executable, "-m", "train_calib", *argv, "--quiet"],
        capture_output=True,
        text=True,
        timeout=180,
    )
    assert proc.returncode == 3, proc.stderr  # a damaged bag: what could be read was replayed
    assert "Traceback" not in proc.stderr and "FATAL" not in proc.stderr, proc.stderr
    summary = json.loads((out / "summary.json").read_text())
    assert sum(summary["input_undecodable"].values()) == 1
    assert summary["input_error"].endswith(
        "1 input messages have a log time /clock cannot carry (after 2038) and were left out"
    )
    assert summary["output_counts"]["/train_calib/resistance"] >= 130


def test_the_recorder_counts_a_clock_before_1970_and_records_on(rclpy_context, tmp_path):
    import rclpy
    from builtin_interfaces.msg import Time
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from rosgraph_msgs.msg import Clock
    from train_calib_msgs.msg import DrivingRegime

    from train_calib.nodes.common import reliable_qos
    from train_calib.record import McapBagWriter, Recorder

    topic = "/train_calib/regime"
    writer = McapBagWriter(tmp_path, {topic: bagio.OUTPUT_TOPICS[topic]})
    rec_node = rclpy.create_node("rec", context=rclpy_context)
    recorder = Recorder(rec_node, writer, {topic: bagio.OUTPUT_TOPICS[topic]}, sim_clock=True)
    pub_node = rclpy.create_node("pub", context=rclpy_context)
    clock = pub_node.create_publisher(Clock, "/clock", QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE))
    regime = pub_node.create_publisher(DrivingRegime, topic, reliable_qos(10))
    executor = SingleThreadedExecutor(context=rclpy_context)
    executor.add_node(rec_node)

    def spin_until(condition, timeout_s: float = 10.0) -> None:
        deadline = time.monotonic() + timeout_s
        while not condition() and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.05)
        assert condition()

    spin_until(lambda: clock.get_subscription_count() >= 1 and regime.get_subscription_count() >= 1)
    try:
        clock.publish(Clock(clock=Time(sec=100, nanosec=5)))
        spin_until(lambda: recorder._sim_ns == 100 * 10**9 + 5)
        clock.publish(Clock(clock=Time(sec=-5, nanosec=0)))  # what a wrapped /clock looks like
        spin_until(lambda: recorder.undecodable["/clock"] == 1)
        regime.publish(DrivingRegime(regime=3))
        spin_until(lambda: recorder.received[topic] == 1)
    finally:
        writer.close()
        executor.shutdown()
        rec_node.destroy_node()
        pub_node.destroy_node()
    (message,) = list(iter_bag(tmp_path))
    assert message.log_time_ns == 100 * 10**9 + 5  # the last valid /clock
