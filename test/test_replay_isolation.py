"""Replays are isolated by default: concurrent replays on one host never exchange messages.

Each replay's graph runs in a ROS domain of its own (claimed with a lock file, so concurrent replays never share
one) with localhost-only discovery; ``--live`` forwards its inputs, /clock and outputs into the caller's
environment. The replays here run in one and the same environment (this pytest run's), as parallel CI jobs or two
terminals on a laptop would.
"""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from repo_paths import REPO

pytestmark = pytest.mark.ros

BAG = REPO / "bags" / "intercity_32km_10s_00"
COMMAND = ["replay", str(BAG), "--track", "intercity_32km", "--train", "virm6", "--no-report", "--quiet"]
RATE = "200"  # the bag's 1302 s in about 6.5 s: the replays overlap for most of their run


def _start(out: Path, *extra: str) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-m", "train_calib", *COMMAND, "--out", str(out), *extra],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


def _outputs(proc: subprocess.Popen, out: Path) -> tuple[dict[str, int], dict[str, float]]:
    _, stderr = proc.communicate(timeout=240)
    assert proc.returncode == 0, stderr
    summary = json.loads((out / "summary.json").read_text())
    final = {k: summary["final"][k]["value"] for k in ("r0", "r1", "r2")}
    # /diagnostics is periodic (its count depends on the wall time at a finite rate): every other topic is compared
    counts = {t: n for t, n in summary["output_counts"].items() if t != "/diagnostics"}
    return counts, final


@pytest.fixture(scope="module")
def alone(tmp_path_factory):
    """The demo bag's outputs replayed alone."""
    out = tmp_path_factory.mktemp("alone")
    result = _outputs(_start(out, "--rate", RATE), out)
    assert result[0]["/train_calib/resistance"] == 131
    return result


def test_concurrent_replays_each_give_exactly_their_outputs_alone(alone, tmp_path):
    """Three at once in one environment, one of them with a process per node (before isolation, three at once
    exchanged messages and one ended in a LinAlgError; a replay sharing a domain recorded 406 measurements for the
    bag's 131)."""
    extra = {"run0": (), "run1": (), "processes": ("--processes",)}
    procs = {name: _start(tmp_path / name, "--rate", RATE, *args) for name, args in extra.items()}
    for name, proc in procs.items():
        counts, final = _outputs(proc, tmp_path / name)
        assert counts == alone[0], name
        assert final == alone[1], name
    summary = json.loads((tmp_path / "processes" / "summary.json").read_text())
    assert summary["isolated"] is True and summary["live"] is False
    assert summary["ros_domain_id"] != int(os.environ["ROS_DOMAIN_ID"])


def test_claimed_domains_differ_and_skip_a_domain_in_use_on_the_host(rclpy_context):
    import rclpy

    from train_calib.isolation import claim_domain, domain_in_use_on_host, isolated_environment

    own = int(os.environ["ROS_DOMAIN_ID"])  # this test run's (conftest), a context of it is up
    node = rclpy.create_node("holder", context=rclpy_context)
    try:
        assert domain_in_use_on_host(own)
        with claim_domain() as first, claim_domain() as second:
            assert len({first.domain_id, second.domain_id, own}) == 3
            assert not domain_in_use_on_host(first.domain_id)
        env = isolated_environment(first.domain_id)
        assert env["ROS_DOMAIN_ID"] == str(first.domain_id) and env["ROS_AUTOMATIC_DISCOVERY_RANGE"] == "LOCALHOST"
    finally:
        node.destroy_node()


def test_waiting_for_subscribers_in_an_isolated_replay_is_refused_in_one_line(tmp_path, capsys):
    from train_calib import cli

    argv = [*COMMAND, "--out", str(tmp_path / "o"), "--wait-for-subscribers", "1"]
    assert cli.main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "wait_for_subscribers" in err[0] and "--live" in err[0], err
    assert not (tmp_path / "o" / "output.mcap").exists()


def test_beside_a_live_graph_the_default_and_the_live_replay_give_their_outputs_alone(alone, tmp_path):
    """A replay with --domain-id of this environment is the live graph (the inputs and outputs of the bag published
    in the caller's domain, as before isolation); --live publishes into it too, and takes nothing in."""
    live_graph = _start(tmp_path / "graph", "--rate", "100", "--domain-id", os.environ["ROS_DOMAIN_ID"])
    procs = {
        "default": _start(tmp_path / "default", "--rate", RATE),
        "live": _start(tmp_path / "live", "--rate", RATE, "--live"),
    }
    try:
        for name, proc in procs.items():
            assert _outputs(proc, tmp_path / name) == alone, name
    finally:
        live_graph.kill()
        live_graph.communicate()
    summary = json.loads((tmp_path / "live" / "summary.json").read_text())
    assert summary["isolated"] is True and summary["live"] is True


def _readme_das() -> str:
    readme = (REPO / "README.md").read_text()
    (das,) = [b for b in re.findall(r"```python\n(.*?)```", readme, flags=re.S) if "class Das" in b]
    return das


def test_the_readme_s_das_gets_every_message_of_a_live_replay_from_the_first_and_exits_quietly(tmp_path):
    """The README's DAS (two topics) and its replay command: --live --wait-for-subscribers 1 starts once it has
    subscribed, it receives every regime and resistance message, and Ctrl-C ends it without a traceback."""
    script = tmp_path / "das.py"
    script.write_text(_readme_das())
    printed = tmp_path / "das.out"
    das = subprocess.Popen(
        [sys.executable, "-u", str(script)], stdout=printed.open("w"), stderr=subprocess.PIPE, text=True
    )
    try:
        readme = (REPO / "README.md").read_text()
        (command,) = [
            ln for ln in readme.splitlines() if "--live --wait-for-subscribers 1" in ln and ln.startswith("train")
        ]
        argv = command.split()[1:]
        argv[argv.index("--rate") + 1] = "200"  # the bag in 6.5 s rather than 65
        replay = subprocess.run(
            [sys.executable, "-m", "train_calib", *argv, "--out", str(tmp_path / "o"), "--no-report", "--quiet"],
            capture_output=True,
            text=True,
            timeout=240,
            cwd=REPO,
        )
        assert replay.returncode == 0, replay.stderr
        deadline = time.monotonic() + 30.0  # the last messages on their way (seconds on a loaded machine)
        while time.monotonic() < deadline and printed.read_text().count("regime ") < 131:
            time.sleep(0.2)
    finally:
        das.send_signal(signal.SIGINT)
        _, err = das.communicate(timeout=30)
    assert das.returncode == 0 and "Traceback" not in err, err
    lines = printed.read_text().splitlines()
    assert sum(ln.startswith("regime ") for ln in lines) == 131
    assert sum(ln.startswith("r(v) = ") for ln in lines) == 131
