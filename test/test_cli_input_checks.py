"""Input the replay used to accept silently: refused, or reported, in one line naming the option, file or key, with
a non-zero exit status."""

from __future__ import annotations

import json
import shutil

import pytest
import yaml
from repo_paths import REPO

from train_calib import cli, paths

pytestmark = pytest.mark.ros

BAG = REPO / "bags" / "intercity_32km_10s_00"


def _one_line(capsys, argv: list[str], status: int) -> str:
    try:
        code = cli.main(argv)
    except SystemExit as exc:  # a usage error
        code = exc.code
    assert code == status
    err = [ln for ln in capsys.readouterr().err.splitlines() if ln.startswith("train-calib")]
    assert len(err) == 1, err
    return err[0]


@pytest.mark.parametrize("rate", ["nan", "inf", "-1", "fast"])
def test_a_rate_that_is_not_a_finite_number_at_least_0_is_refused(tmp_path, capsys, rate):
    argv = ["replay", str(BAG), "--track", "intercity_32km", "--train", "virm6", "--out", str(tmp_path), "--rate", rate]
    line = _one_line(capsys, argv, 2)
    assert "argument --rate" in line and rate in line
    assert not (tmp_path / "output.mcap").exists()


def test_a_typo_in_an_optional_track_key_stops_the_replay_naming_the_nearest_key(tmp_path, capsys):
    data = yaml.safe_load(paths.track_file("intercity_32km").read_text())
    data["tunels"] = [{"start_m": 1000.0, "end_m": 2000.0}]
    track = tmp_path / "track.yaml"
    track.write_text(yaml.safe_dump(data))
    argv = ["replay", str(BAG), "--track", str(track), "--train", "virm6", "--out", str(tmp_path / "o")]
    assert _one_line(capsys, argv, 2) == (
        f"train-calib replay: error: {track}: tunels: unknown key (did you mean tunnels?)"
    )


def test_the_wrong_track_for_the_bag_is_said_with_exit_4_after_writing_what_was_recorded(tmp_path, capsys):
    out = tmp_path / "o"
    argv = ["replay", str(BAG), "--track", "tunnel_line_37km", "--train", "virm6", "--out", str(out), "--quiet"]
    line = _one_line(capsys, argv, 4)
    assert "none of its 131 speed samples reached the filter" in line
    assert "128 of 131 GNSS fixes lie off track tunnel_line_37km: is --track the bag's line?" in line
    summary = json.loads((out / "summary.json").read_text())
    assert summary["no_samples"] in line
    assert summary["output_counts"]["/diagnostics"] > 0 and (out / "output.mcap").is_file()
    assert not (out / "report.png").exists()  # no blank report


@pytest.fixture
def bag_with_foreign_truth(tmp_path):
    """The demo bag with another tool's <bag>.truth.json beside it."""
    bag = tmp_path / "bag" / BAG.name
    shutil.copytree(BAG, bag)
    (bag.parent / f"{BAG.name}.truth.json").write_text(json.dumps({"vehicle": "VIRM", "notes": "my own truth"}))
    return bag


def test_a_truth_file_beside_the_bag_that_is_not_the_simulator_s_never_blocks_a_replay(
    bag_with_foreign_truth, tmp_path, capsys
):
    out = tmp_path / "o"
    argv = ["replay", str(bag_with_foreign_truth), "--track", "intercity_32km", "--train", "virm6", "--out", str(out)]
    assert cli.main([*argv, "--no-report"]) == 0
    notes = [ln for ln in capsys.readouterr().err.splitlines() if ln.startswith("note:")]
    assert len(notes) == 1 and "truth.json: not the simulator's truth format; ignored" in notes[0], notes
    assert json.loads((out / "summary.json").read_text())["truth_file"] is None
    # given with --truth, the simulator's file is used
    given = BAG.parent / f"{BAG.name}.truth.json"
    assert cli.main([*argv, "--no-report", "--overwrite", "--quiet", "--truth", str(given)]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["truth_file"] == str(given)
    assert summary["final"]["r0"]["truth"] == json.loads(given.read_text())["resistance"]["r0"]


def test_a_truth_file_given_without_resistance_is_refused_in_one_line(bag_with_foreign_truth, tmp_path, capsys):
    foreign = bag_with_foreign_truth.parent / f"{BAG.name}.truth.json"
    argv = ["replay", str(BAG), "--track", "intercity_32km", "--train", "virm6", "--out", str(tmp_path / "o")]
    line = _one_line(capsys, [*argv, "--truth", str(foreign)], 2)
    assert f"{foreign}: not a truth file with resistance r0, r1, r2" in line


def test_a_validation_truth_beside_the_bag_is_used_and_a_broken_one_noted(tmp_path, capsys):
    """<bag>.validation-truth.json (../shared/validation: r0, r1, r2 at the top level) is the truth when the
    simulator's <bag>.truth.json is absent; without r0, r1, r2 it is noted and the replay goes on."""
    bag = tmp_path / "bag" / BAG.name
    shutil.copytree(BAG, bag)
    resistance = json.loads((BAG.parent / f"{BAG.name}.truth.json").read_text())["resistance"]
    validation = bag.parent / f"{BAG.name}.validation-truth.json"
    validation.write_text(json.dumps({**{k: resistance[k] for k in ("r0", "r1", "r2")}, "style": "pi"}))
    out = tmp_path / "o"
    argv = ["replay", str(bag), "--track", "intercity_32km", "--train", "virm6", "--out", str(out), "--no-report"]
    assert cli.main([*argv, "--quiet"]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["truth_file"] == str(validation)
    assert summary["final"]["r0"]["truth"] == resistance["r0"]
    validation.write_text(json.dumps({"r0": 0.01, "style": "pi"}))
    assert cli.main([*argv, "--overwrite"]) == 0
    notes = [ln for ln in capsys.readouterr().err.splitlines() if ln.startswith("note:")]
    assert len(notes) == 1 and "validation-truth.json: not a truth file with resistance r0, r1, r2" in notes[0]
    assert json.loads((out / "summary.json").read_text())["truth_file"] is None


def test_demo_with_a_missing_bag_names_it_and_lists_the_bundled_bags(capsys):
    line = _one_line(capsys, ["demo", "--bag", "intercity_99"], 2)
    assert line.startswith("train-calib demo: error: --bag intercity_99: no such bag")
    assert "bundled: intercity_32km_10s_00, intercity_32km_10s_01" in line and "tunnel_line_37km_1s_00" in line


def _replay_stderr(tmp_path, *extra: str) -> str:
    import subprocess
    import sys

    argv = ["replay", str(BAG), "--track", "intercity_32km", "--train", "virm6", "--out", str(tmp_path), "--no-report"]
    proc = subprocess.run(
        [sys.executable, "-m", "train_calib", *argv, "--overwrite", *extra], capture_output=True, text=True, timeout=180
    )
    assert proc.returncode == 0, proc.stderr
    return proc.stderr


def test_every_node_logs_one_line_at_start_and_quiet_silences_them(tmp_path):
    info = [ln for ln in _replay_stderr(tmp_path).splitlines() if "[INFO]" in ln]
    nodes = ("gnss_speed_node", "ukf_node", "regime_node", "feature_node")
    assert sorted(ln.split("] [", 2)[2].split("]")[0] for ln in info) == sorted(nodes), info
    assert "]: method " in next(ln for ln in info if "[regime_node]" in ln)
    assert "brake steps 0, 40, 60, 80, 130 km/h" in next(ln for ln in info if "[feature_node]" in ln)
    quiet = _replay_stderr(tmp_path, "--quiet")
    assert "[INFO]" not in quiet and quiet.strip() == "", quiet
