"""Configuration faults are refused at start with one line naming the file, the key and the problem.

For ``train-calib replay`` (exit status 2, nothing written) and for the node executables (exit status 2):
a track, train or params file with a missing key, a wrong type, a value outside its physical range, unsorted
positions, an empty geometry, or that cannot be read at all.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
import yaml

sys.path.insert(0, str(Path(__file__).resolve().parent))
from faultlib import TRAIN_FILE, make_scenario, write_bag

from train_calib import cli

pytestmark = pytest.mark.ros


@pytest.fixture(scope="module")
def setup(tmp_path_factory):
    d = tmp_path_factory.mktemp("config")
    sc = make_scenario(d)
    bag = write_bag(d / "bag", sc.events[:200])
    return d, bag, yaml.safe_load(sc.track_path.read_text()), yaml.safe_load(TRAIN_FILE.read_text())


def _track_faults(track):
    def unsorted(t):
        t["gradients"][1]["s_m"], t["gradients"][2]["s_m"] = t["gradients"][2]["s_m"], t["gradients"][1]["s_m"]

    def missing(t):
        del t["speed_limits"]

    def wrong_type(t):
        t["length_m"] = "twenty km"

    def out_of_range(t):
        t["gradients"][1]["permille"] = 400.0

    def empty_geometry(t):
        t["geometry"] = []

    return {
        "missing key": (missing, "speed_limits: missing required key"),
        "wrong type": (wrong_type, "length_m: expected a number in m, found str 'twenty km'"),
        "out of range": (
            out_of_range,
            "gradients[1].permille: 400 permille is out of range: must be at most 100 permille",
        ),
        "unsorted": (unsorted, "gradients[2].s_m: positions must be strictly increasing: 4000 follows 9000"),
        "empty geometry": (empty_geometry, "geometry: needs at least 2 entries, found an empty list"),
    }


def _train_faults():
    def missing(t):
        del t["davis"]["r1"]

    def wrong_type(t):
        t["mass_t"] = [400]

    def out_of_range(t):
        t["max_brake_decel"] = 9.0

    def negative(t):
        t["davis"]["r0"] = -0.001

    return {
        "missing key": (missing, "davis.r1: missing required key"),
        "wrong type": (wrong_type, "mass_t: expected a number in t, found list [400]"),
        "out of range": (out_of_range, "max_brake_decel: 9 m/s^2 is out of range: must be at most 3 m/s^2"),
        "negative resistance": (negative, "davis.r0: -0.001 N/kg is out of range: must be at least 0 N/kg"),
    }


PARAMS_FAULTS = {
    "wrong type": ("ukf_node:\n  ros__parameters:\n    meas_std_s: four\n", "meas_std_s: expected a number"),
    "out of range": (
        "gnss_speed_node:\n  ros__parameters:\n    max_speed: -5.0\n",
        "max_speed: -5 m/s is out of range: must be greater than 0 m/s",
    ),
    "inconsistent": (
        "gnss_speed_node:\n  ros__parameters:\n    standstill_speed: 200.0\n",
        "standstill_speed: 200 m/s must be below max_speed (100 m/s)",
    ),
    "not a mapping": ("- just\n- a list\n", "expected a mapping of keys at the top level, found list"),
    "invalid yaml": ("ukf_node: {ros__parameters: {meas_std_s: [1.0\n", "invalid YAML"),
}


def _one_line(capsys, argv) -> str:
    assert cli.main(argv) == 2
    err = [line for line in capsys.readouterr().err.splitlines() if line.strip() and not line.startswith("[INFO]")]
    assert len(err) == 1, err
    return err[0]


@pytest.mark.parametrize("fault", list(_track_faults({})))
def test_replay_refuses_a_bad_track_file_in_one_line(setup, capsys, fault):
    d, bag, track, _ = setup
    mutate, problem = _track_faults(track)[fault]
    bad = yaml.safe_load(yaml.safe_dump(track))
    mutate(bad)
    path = d / f"track_{fault.replace(' ', '_')}.yaml"
    path.write_text(yaml.safe_dump(bad))
    out = d / f"out_track_{fault.replace(' ', '_')}"
    line = _one_line(capsys, ["replay", str(bag), "--track", str(path), "--train", str(TRAIN_FILE), "--out", str(out)])
    assert line == f"train-calib replay: error: {path}: {problem}"
    assert not out.exists() or not any(out.iterdir())  # nothing written


@pytest.mark.parametrize("fault", list(_train_faults()))
def test_replay_refuses_a_bad_train_file_in_one_line(setup, capsys, fault):
    d, bag, _, train = setup
    mutate, problem = _train_faults()[fault]
    bad = yaml.safe_load(yaml.safe_dump(train))
    mutate(bad)
    path = d / f"train_{fault.replace(' ', '_')}.yaml"
    path.write_text(yaml.safe_dump(bad))
    track = d / "robust_track.yaml"
    line = _one_line(capsys, ["replay", str(bag), "--track", str(track), "--train", str(path), "--out", str(d / "o")])
    assert line == f"train-calib replay: error: {path}: {problem}"


@pytest.mark.parametrize("fault", list(PARAMS_FAULTS))
def test_replay_refuses_a_bad_params_file_in_one_line(setup, capsys, fault):
    d, bag, _, _ = setup
    text, problem = PARAMS_FAULTS[fault]
    path = d / f"params_{fault.replace(' ', '_')}.yaml"
    path.write_text(text)
    out = d / f"out_params_{fault.replace(' ', '_')}"
    track = d / "robust_track.yaml"
    argv = ["replay", str(bag), "--track", str(track), "--train", str(TRAIN_FILE), "--out", str(out)]
    line = _one_line(capsys, [*argv, "--params-file", str(path)])
    assert line.startswith("train-calib replay: error: ") and problem in line
    assert str(path) in line or "parameters" in line  # the file, or the node's parameters it was applied to
    assert not (out / "output.mcap").exists()


def test_replay_refuses_unreadable_files_in_one_line(setup, capsys, tmp_path):
    d, bag, _, _ = setup
    track = d / "robust_track.yaml"
    binary = tmp_path / "binary.yaml"
    binary.write_bytes(b"\xff\xfe\x00 not text")
    cases = [
        (
            ["--track", str(tmp_path / "none.yaml"), "--train", str(TRAIN_FILE)],
            f"{tmp_path / 'none.yaml'}: track file not found",
        ),
        (
            ["--track", str(tmp_path), "--train", str(TRAIN_FILE)],
            f"{tmp_path}: cannot read track file: IsADirectoryError",
        ),
        (["--track", str(track), "--train", str(binary)], f"{binary}: cannot read train file: UnicodeDecodeError"),
    ]
    for args, expected in cases:
        line = _one_line(capsys, ["replay", str(bag), *args, "--out", str(tmp_path / "o")])
        assert line.startswith(f"train-calib replay: error: {expected}"), line


@pytest.mark.parametrize(
    ("node", "args", "expected"),
    [
        (
            "gnss_speed_node",
            ["-p", "track_file:={track}"],
            "gnss_speed_node: error: {track}: geometry: needs at least 2 entries, found an empty list",
        ),
        ("ukf_node", ["--params-file", "{params}"], "ukf_node: error: {params}: params file not found"),
        (
            "ukf_node",
            ["-p", "train_file:={train}"],
            "ukf_node: error: {train}: max_brake_decel: 9 m/s^2 is out of range: must be at most 3 m/s^2",
        ),
    ],
    ids=["gnss_speed_node-empty-geometry", "ukf_node-missing-params-file", "ukf_node-train-out-of-range"],
)
def test_node_executables_refuse_bad_configuration_in_one_line(setup, tmp_path, node, args, expected):
    _, _, track, train = setup
    bad_track = yaml.safe_load(yaml.safe_dump(track))
    bad_track["geometry"] = []
    (tmp_path / "track.yaml").write_text(yaml.safe_dump(bad_track))
    bad_train = yaml.safe_load(yaml.safe_dump(train))
    bad_train["max_brake_decel"] = 9.0
    (tmp_path / "train.yaml").write_text(yaml.safe_dump(bad_train))
    names = {"track": tmp_path / "track.yaml", "train": tmp_path / "train.yaml", "params": tmp_path / "none.yaml"}
    argv = [a.format(**names) for a in args]
    proc = subprocess.run(
        [sys.executable, "-m", f"train_calib.nodes.{node}", "--ros-args", *argv],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert proc.returncode == 2
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip()]
    assert lines == [expected.format(**names)], proc.stderr
