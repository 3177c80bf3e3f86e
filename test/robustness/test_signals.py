"""SIGINT or SIGTERM in the middle of ``train-calib replay``: in one process and with one process per node.

The replay stops publishing inputs, lets the graph handle what it has received and close its runs, records
the final /diagnostics and closes the recording: output.mcap is complete and readable (rosbags and bagio,
metadata.yaml beside it), holds every message each node published (its final /diagnostics counts match the
recording, and each node handled everything the one before it published), summary.json is written with
``interrupted`` and the signal, and the exit status is 128 + the signal (130 SIGINT, 143 SIGTERM).
"""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time
from collections import Counter
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))
from faultlib import TRAIN_FILE, make_scenario, write_bag

from train_calib import bagio
from train_calib.summary import read_outputs

pytestmark = pytest.mark.ros


@pytest.fixture(scope="module")
def setup(tmp_path_factory):
    d = tmp_path_factory.mktemp("signals")
    sc = make_scenario(d)
    return sc, write_bag(d / "bag", sc.events)


@pytest.mark.parametrize(
    ("sig", "mode"),
    [(signal.SIGINT, []), (signal.SIGTERM, ["--processes"])],
    ids=["SIGINT-one-process", "SIGTERM-processes"],
)
def test_interrupted_replay_leaves_complete_outputs_holding_everything_processed(setup, tmp_path, sig, mode):
    sc, bag = setup
    out = tmp_path / "out"
    argv = [sys.executable, "-m", "train_calib", "replay", str(bag), "--track", str(sc.track_path)]
    argv += ["--train", str(TRAIN_FILE), "--out", str(out), "--rate", "40", "--no-report", *mode]
    proc = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        for line in proc.stderr:  # the replay logs when the graph is up and the inputs start
            if line.startswith("replaying "):
                break
        time.sleep(3.0)  # the bag lasts 19 s at rate 40
        assert proc.poll() is None
        proc.send_signal(sig)
        _, stderr = proc.communicate(timeout=90)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 128 + sig, stderr
    assert "Traceback" not in stderr
    summary = json.loads((out / "summary.json").read_text())
    assert summary["interrupted"] is True and summary["signal"] == sig
    recorded = Counter(m.topic for m in bagio.iter_bag(out))  # complete: raises on any damage
    assert summary["output_counts"] == dict(recorded)
    from rosbags.rosbag2 import Reader

    with Reader(out) as reader:  # metadata.yaml: a rosbag2 bag directory
        assert reader.message_count == sum(recorded.values())
    sent = sum(summary["input_counts"].values())
    assert 50 < sent < len(sc.events)  # interrupted in the middle
    # every message a node published is in the recording, and each node handled all the previous one published
    last = read_outputs(out).diagnostics
    published = {
        topic: int(values[f"{topic} published"])
        for values in last.values()
        for topic in bagio.OUTPUT_TOPICS
        if f"{topic} published" in values
    }
    assert published == {t: recorded[t] for t in published}
    chain = {"ukf_node": "/train_calib/measurement", "regime_node": "/train_calib/resistance"}
    chain["feature_node"] = "/train_calib/regime"
    for consumer, topic in chain.items():
        assert int(last[consumer][f"{topic} received"]) == recorded[topic]
    received = sum(int(last["gnss_speed_node"][f"{t} received"]) for t in ("/gnss/fix", "/train/speed"))
    assert received == sent
    assert (
        recorded["/train_calib/measurement"] == recorded["/train_calib/resistance"] == recorded["/train_calib/regime"]
    )
    features = [m.decode() for m in bagio.iter_bag(out, ["/train_calib/features"])]
    assert features and features[-1].run_complete  # the interrupted run was closed
