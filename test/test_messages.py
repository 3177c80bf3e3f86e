"""Each train_calib_msgs message travels with all fields intact: in one process and between processes."""

from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path

import pytest
from msgfill import fill, message_class, to_dict
from repo_paths import REPO

pytestmark = pytest.mark.ros

MESSAGES = sorted(f"train_calib_msgs/msg/{p.stem}" for p in (REPO / "msg_defs" / "msg").glob("*.msg"))


def test_interface_contract_messages_exist():
    for name in ("TrackMeasurement", "ResistanceEstimate", "DrivingRegime", "DrivingFeatures", "TractionPower"):
        assert f"train_calib_msgs/msg/{name}" in MESSAGES
    regime = message_class("train_calib_msgs/msg/DrivingRegime")
    assert (regime.UNKNOWN, regime.TRACTION, regime.CRUISING, regime.COASTING, regime.BRAKING) == (0, 1, 2, 3, 4)
    estimate = message_class("train_calib_msgs/msg/ResistanceEstimate")()
    assert len(estimate.covariance) == 25


@pytest.mark.parametrize("type_name", MESSAGES)
def test_message_between_two_nodes_in_one_process(type_name, rclpy_context):
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.qos import QoSProfile, ReliabilityPolicy

    cls = message_class(type_name)
    sent = fill(cls())
    assert sent != cls(), "the filled message must differ from the default"
    qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
    pub_node = rclpy.create_node("pub", context=rclpy_context)
    sub_node = rclpy.create_node("sub", context=rclpy_context)
    received = []
    sub_node.create_subscription(cls, "/test/msg", received.append, qos)
    publisher = pub_node.create_publisher(cls, "/test/msg", qos)
    executor = SingleThreadedExecutor(context=rclpy_context)
    executor.add_node(pub_node)
    executor.add_node(sub_node)
    deadline = time.monotonic() + 20.0
    while not received and time.monotonic() < deadline:
        publisher.publish(sent)
        executor.spin_once(timeout_sec=0.05)
    executor.shutdown()
    assert received, f"{type_name} not received within 20 s"
    assert received[0] == sent
    assert to_dict(received[0]) == to_dict(sent)


@pytest.mark.parametrize("type_name", MESSAGES)
def test_message_to_a_subscriber_in_another_process(type_name, rclpy_context):
    import rclpy
    from rclpy.qos import QoSProfile, ReliabilityPolicy

    cls = message_class(type_name)
    sent = fill(cls())
    topic = f"/test/xproc/{type_name.rsplit('/', 1)[1].lower()}"
    echo = subprocess.Popen(
        [sys.executable, str(Path(__file__).with_name("msg_echo.py")), type_name, topic],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        cwd=Path(__file__).parent,
    )
    try:
        assert echo.stdout.readline().strip() == "READY", echo.stderr.read()
        node = rclpy.create_node("xproc_pub", context=rclpy_context)
        publisher = node.create_publisher(cls, topic, QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE))
        deadline = time.monotonic() + 30.0
        while echo.poll() is None and time.monotonic() < deadline:
            publisher.publish(sent)
            time.sleep(0.05)
        out, err = echo.communicate(timeout=10)
    finally:
        if echo.poll() is None:
            echo.kill()
    assert echo.returncode == 0, err
    received = json.loads(out.strip().splitlines()[-1])
    assert received == json.loads(json.dumps(to_dict(sent)))
