"""The README's DAS example for /train_calib/prediction runs as shown: beside prediction_node (its executable, as the
README starts it) it prints the coasting advice and the nominal time for the estimates this test publishes."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import time

import pytest
from repo_paths import REPO

pytestmark = pytest.mark.ros


def _das_block() -> str:
    readme = (REPO / "README.md").read_text(encoding="utf-8")
    (block,) = [b for b in re.findall(r"```python\n(.*?)```", readme, flags=re.S) if "import Prediction" in b]
    return block


def test_the_readme_das_prints_the_predictions(tmp_path, rclpy_context):
    import rclpy
    from train_calib_msgs.msg import ResistanceEstimate

    from train_calib.nodes.common import reliable_qos

    das_file = tmp_path / "coast_advisor.py"
    das_file.write_text(_das_block(), encoding="utf-8")
    exe = REPO / ".venv" / "bin" / "prediction_node"
    node_cmd = [str(exe)] if exe.exists() else [sys.executable, "-m", "train_calib.nodes.prediction_node"]
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    das = subprocess.Popen([sys.executable, str(das_file)], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                           text=True, env=env)  # fmt: skip
    pred = subprocess.Popen([*node_cmd, "--ros-args", "-p", "track_file:=intercity_32km", "-p", "train_file:=virm6"],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=env)  # fmt: skip
    node = rclpy.create_node("test_estimates", context=rclpy_context)
    pub = node.create_publisher(ResistanceEstimate, "/train_calib/resistance", reliable_qos(100))
    try:
        deadline = time.monotonic() + 90.0  # two processes importing rclpy, numpy, scipy on a loaded machine
        while pub.get_subscription_count() < 1 and time.monotonic() < deadline:
            time.sleep(0.2)
        assert pub.get_subscription_count() >= 1, "prediction_node did not subscribe"
        time.sleep(3.0)  # the DAS's subscription to the node's publisher
        for k in range(20):
            m = ResistanceEstimate()
            m.header.stamp.sec = 1000 + k
            m.s, m.v = 24000.0 + 35.0 * k, 35.0
            m.r0, m.r1, m.r2 = 0.0153, 1.939e-4, 4.08e-5
            m.covariance = [1.0 if i in (0, 6) else (1e-12 if i % 6 == 0 else 0.0) for i in range(25)]
            pub.publish(m)
            time.sleep(0.3)
        time.sleep(3.0)
    finally:
        node.destroy_node()
        for p in (pred, das):
            p.send_signal(signal.SIGINT)
        out, err = das.communicate(timeout=60)
        pred.wait(timeout=60)
    assert das.returncode == 0, err
    lines = out.splitlines()
    coast = [ln for ln in lines if ln.startswith("coast from here:")]
    nominal = [ln for ln in lines if ln.startswith("'s-Hertogenbosch: ")]
    assert coast and nominal, out + err
    # the limit 40 km/h at 31803 m ahead of s = 24000 m; coasting from 126 km/h the train file predicts ~70 km/h there
    assert "at the 40 km/h limit" in coast[0] and "(train file: " in coast[0]
    assert re.match(r"'s-Hertogenbosch: \d+ s nominal \(train file: \d+ s\)", nominal[0])
