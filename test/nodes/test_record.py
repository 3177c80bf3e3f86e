"""`train-calib record`: the recording is complete and readable after SIGINT or SIGTERM."""

from __future__ import annotations

import signal
import subprocess
import sys
import time

import pytest

from train_calib import bagio

pytestmark = pytest.mark.ros


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_recording_is_valid_after_a_signal(rclpy_context, tmp_path, sig):
    import rclpy
    from rclpy.duration import Duration
    from train_calib_msgs.msg import DrivingRegime

    from train_calib.nodes.common import reliable_qos

    out = tmp_path / "rec"
    proc = subprocess.Popen(
        [sys.executable, "-m", "train_calib", "record", "--out", str(out), "--topics", "/train_calib/regime"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    node = rclpy.create_node("record_test_publisher", context=rclpy_context)
    try:
        pub = node.create_publisher(DrivingRegime, "/train_calib/regime", reliable_qos(1000))
        deadline = time.monotonic() + 30
        while pub.get_subscription_count() < 1 and time.monotonic() < deadline:
            time.sleep(0.05)
        assert pub.get_subscription_count() == 1, proc.stderr.read() if proc.poll() is not None else "not matched"
        for k in range(500):
            msg = DrivingRegime(regime=k % 5, s=float(k), run_id=k)
            msg.header.stamp.sec = k
            pub.publish(msg)
        assert pub.wait_for_all_acked(Duration(seconds=10))  # in the recorder's reader, maybe not yet written
        proc.send_signal(sig)
        stdout, stderr = proc.communicate(timeout=30)
    finally:
        node.destroy_node()
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, stderr
    assert "recorded 500 messages" in stdout
    assert (out / "metadata.yaml").is_file() and (out / "output.mcap").is_file()
    messages = [m.decode() for m in bagio.iter_bag(out)]
    assert [m.run_id for m in messages] == list(range(500))
    assert [m.s for m in messages] == [float(k) for k in range(500)]
    assert bagio.bag_topics(out / "output.mcap") == {"/train_calib/regime": "train_calib_msgs/msg/DrivingRegime"}
