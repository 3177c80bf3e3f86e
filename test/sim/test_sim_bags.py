"""Written runs: bag + truth round trip, the bundled bags (both readers, size, bit-exact regeneration)."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import numpy as np
import pytest
from sim_helpers import REPO, track, train

from train_calib import bagio
from train_calib.errors import BagError
from train_calib.paths import bags_dir
from train_calib.sim import DriverParams, SensorParams, read_truth, simulate_run, write_run

BUNDLED = sorted(p for p in bags_dir().iterdir() if p.is_dir())


def _read_with_rosbags(path):
    from rosbags.rosbag2 import Reader

    store = bagio.typestore()
    out = {}
    with Reader(path) as reader:
        for conn, stamp, raw in reader.messages():
            out.setdefault(conn.topic, []).append((stamp, store.deserialize_cdr(raw, conn.msgtype)))
    return out


def test_the_bundled_set():
    names = [p.name for p in BUNDLED]
    assert names == [f"intercity_32km_10s_0{k}" for k in range(5)] + [f"tunnel_line_37km_1s_0{k}" for k in range(2)]
    total = sum(f.stat().st_size for f in bags_dir().rglob("*") if f.is_file())
    assert total < 5 * 1024 * 1024


@pytest.mark.parametrize("bag", BUNDLED, ids=lambda p: p.name)
def test_bundled_bag_reads_with_both_libraries_and_matches_its_truth(bag):
    tf = read_truth(bag)
    with_power = tf.meta["sensors"]["power_period_s"] > 0
    expected_topics = {bagio.GNSS_TOPIC, bagio.SPEED_TOPIC} | ({bagio.POWER_TOPIC} if with_power else set())
    assert set(bagio.bag_topics(bag)) == expected_topics
    # mcap reader (bagio)
    speeds = [m.decode() for m in bagio.iter_bag(bag, [bagio.SPEED_TOPIC])]
    assert [bagio.stamp_ns(m.header) for m in speeds] == tf.truth.t_ns.tolist()
    err = np.array([m.twist.linear.x for m in speeds]) - tf.truth.v
    assert np.all(np.abs(err) < 3.0 / 3.6)
    # rosbags reader
    msgs = _read_with_rosbags(bag)
    assert len(msgs[bagio.SPEED_TOPIC]) == len(tf.truth)
    fixes = [m for _, m in msgs[bagio.GNSS_TOPIC]]
    ok = [m for m in fixes if m.status.status >= 0]
    assert len(ok) == tf.meta["summary"]["gnss_fixes"] and ok[0].position_covariance[0] == pytest.approx(16.0)
    assert all(np.isnan(m.latitude) for m in fixes if m.status.status < 0)
    assert all(stamp == bagio.stamp_ns(m.header) for stamp, m in msgs[bagio.GNSS_TOPIC])
    if with_power:
        assert len(msgs[bagio.POWER_TOPIC]) == tf.meta["summary"]["power_samples"]
    # the truth is the simulation's: the run ends at the stop
    assert tf.truth.s[-1] == pytest.approx(tf.meta["stop_s"], abs=1.0)
    assert tf.meta["resistance"] != tf.meta["train"]["manufacturer_davis"]


NO_AVX512 = {"NPY_DISABLE_CPU_FEATURES": "X86_V4 AVX512_ICL AVX512_SPR"}
"""numpy's AVX-512 loops (sin, cos, exp, ...) differ in the last bit from the AVX2 / scalar ones the bags were
written with (bags/README.md); numpy reads the variable at import, so the regeneration runs in a new process."""


def test_regeneration_is_bit_identical(tmp_path):
    ref = bags_dir() / "intercity_32km_10s_00"
    cmd = json.loads((bags_dir() / "intercity_32km_10s_00.truth.json").read_text())["command"].split()
    assert cmd[:2] == ["train-calib", "simulate"]
    run = [sys.executable, "-m", "train_calib", *cmd[1:], "--out", str(tmp_path), "--quiet"]
    done = subprocess.run(run, env={**os.environ, **NO_AVX512}, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    new = tmp_path / "intercity_32km_10s_00"
    for rel in ("metadata.yaml", "intercity_32km_10s_00.mcap"):
        assert (new / rel).read_bytes() == (ref / rel).read_bytes(), rel
    for suffix in (".truth.csv", ".truth.json"):
        name = "intercity_32km_10s_00" + suffix
        assert (tmp_path / name).read_bytes() == (bags_dir() / name).read_bytes(), name


def test_write_and_read_back_exactly(tmp_path):
    trk, trn = track("dense_corridor_14km"), train("virm4")
    rng = np.random.default_rng(12)
    run = simulate_run(
        trk,
        trn,
        driver=DriverParams.sample(rng, train=trn, coast_range_s=(60, 120)),
        sensors=SensorParams(power_period_s=2.0),
        rng=rng,
    )
    bag = write_run(run, tmp_path, "r", dense=True)
    tf = read_truth(bag)
    for name, col in run.truth.columns().items():
        assert np.array_equal(getattr(tf.truth, name), col), name
    assert tf.dense is not None and np.array_equal(tf.dense.u, run.dense.u)
    assert tf.meta["summary"]["run_time_s"] == run.meta["summary"]["run_time_s"]
    assert read_truth(bag / "r.mcap").meta["name"] == "r"  # the bare .mcap file finds its truth too
    with pytest.raises(BagError, match="already exists"):
        write_run(run, tmp_path, "r")
    with pytest.raises(BagError, match="truth file not found"):
        read_truth(tmp_path / "missing")
    (tmp_path / "r.truth.csv").write_text("t_ns,s\n1,2\n")
    with pytest.raises(BagError, match="lacks column 'v'"):
        read_truth(bag)


def test_readme_commands_match_the_bundled_runs():
    readme = (REPO / "bags" / "README.md").read_text()
    for bag in BUNDLED:
        meta = json.loads((bags_dir() / f"{bag.name}.truth.json").read_text())
        assert f"--seed {meta['seed'][0]}" in readme
        assert f"{meta['summary']['run_time_s']:.1f} s" in readme
