"""train-calib fleet --params-file: a ROS 2 params file (the nodes' format) applied to every run, checked in one
line (file, key, nearest valid name, exit status 2) before anything runs, and its sha256 part of the resume key."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import pandas as pd
import pytest

from train_calib.cli import main
from train_calib.estimation.config import RegimeConfig, UKFConfig
from train_calib.fleet.params import load_fleet_params
from train_calib.fleet.row import TIMING_COLUMNS, process_run, run_key
from train_calib.paths import track_file, train_file
from train_calib.pipeline import run_bag
from train_calib.track import load_track
from train_calib.train import load_train

REPO = Path(__file__).resolve().parents[2]
BAGS = [REPO / "bags" / f"intercity_32km_10s_0{k}" for k in (0, 1)]
DEFAULTS = REPO / "config" / "train_calib.yaml"
CHANGED = "ukf_node:\n  ros__parameters:\n    prior_scale_std: 0.05\n"  # a tighter prior of r (default 0.18)


def job(bag: Path, params: Path | None = None) -> dict:
    out = {"index": 0, "bag": str(bag), "bag_path": str(bag), "track_path": str(track_file("intercity_32km")),
           "train_path": str(train_file("virm6")), "unit": "u"}  # fmt: skip
    if params is not None:
        p = load_fleet_params(params)
        out |= {"configs": p.configs, "params_sha256": p.sha256}
    return out


def test_params_file_applied_to_the_run(tmp_path: Path) -> None:
    changed = tmp_path / "changed.yaml"
    changed.write_text(CHANGED)
    p = load_fleet_params(changed)
    assert p.sha256 == hashlib.sha256(CHANGED.encode()).hexdigest() and set(p.configs) == {"ukf"}
    assert p.configs["ukf"] == UKFConfig().replace(prior_scale_std=0.05)
    plain, with_defaults, with_changed = (process_run(job(BAGS[0], f)) for f in (None, DEFAULTS, changed))
    assert plain["status"] == with_defaults["status"] == with_changed["status"] == "ok"
    # the nodes' defaults file: every value as without a file, only the key differs
    skip = {"run_key", *TIMING_COLUMNS}
    same = [k for k in plain if k not in skip]
    assert [plain[k] for k in same] == [with_defaults[k] for k in same]
    assert len({plain["run_key"], with_defaults["run_key"], with_changed["run_key"]}) == 3
    # the changed file: the row is the pipeline's with that UKF configuration, and differs from the default's
    out = run_bag(BAGS[0], load_track(track_file("intercity_32km")), load_train(train_file("virm6")),
                  ukf=UKFConfig().replace(prior_scale_std=0.05))  # fmt: skip
    assert with_changed["r0"] == out.final.r0 and with_changed["best_r1"] == out.best.r[1]
    assert abs(with_changed["r80"] / plain["r80"] - 1) > 0.005 and with_changed["final_r80"] != plain["final_r80"]
    assert with_changed["run_key"] == run_key(BAGS[0], track_file("intercity_32km"), train_file("virm6"), p.sha256)


def test_wildcard_and_node_sections(tmp_path: Path) -> None:
    path = tmp_path / "p.yaml"
    path.write_text("/**:\n  ros__parameters:\n    effort_tolerance: 0.03\n    diagnostics_period: 2.0\n"
                    "/regime_node:\n  ros__parameters:\n    effort_tolerance: 0.04\n")  # fmt: skip
    configs = load_fleet_params(path).configs
    # regime_node's own section wins; window_calib_node's effort_tolerance (WindowConfig) takes the wildcard's
    assert configs["regime"] == RegimeConfig().replace(effort_tolerance=0.04)
    assert configs["window"].effort_tolerance == 0.03 and set(configs) == {"regime", "window"}


BAD = {
    "unknown key": ("regime_node:\n  ros__parameters:\n    effort_tolerence: 0.03\n",
                    "regime_node.ros__parameters.effort_tolerence: unknown key (did you mean effort_tolerance?)"),
    "unknown node": ("ukf_nod:\n  ros__parameters:\n    meas_std_s: 5.0\n",
                     "ukf_nod: unknown key (did you mean ukf_node?)"),
    "unknown key of the wildcard": ("/**:\n  ros__parameters:\n    prior_scale_sdt: 0.1\n",
                                    "/**.ros__parameters.prior_scale_sdt: unknown key (did you mean prior_scale_std?)"),
    "bad value of the wildcard": ("/**:\n  ros__parameters:\n    prior_scale_std: 9.0\n",
                                  "/**.ros__parameters.prior_scale_std: 9 is out of range: must be at most 5"),
    "not ros__parameters": ("ukf_node:\n  ros_parameters:\n    meas_std_s: 5.0\n",
                            "ukf_node.ros_parameters: unknown key (did you mean ros__parameters?)"),
    "out of range": ("ukf_node:\n  ros__parameters:\n    meas_std_s: -1.0\n",
                     "ukf_node.ros__parameters.meas_std_s: -1 m is out of range: must be greater than 0 m"),
    "wrong type": ("ukf_node:\n  ros__parameters:\n    meas_std_s: four\n",
                   "ukf_node.ros__parameters.meas_std_s: expected a number, found str 'four'"),
    "bad yaml": ("ukf_node: [\n", "invalid YAML"),
}  # fmt: skip


@pytest.mark.parametrize("fault", list(BAD))
def test_bad_params_file_one_line_exit_2(tmp_path: Path, capsys: pytest.CaptureFixture[str], fault: str) -> None:
    text, problem = BAD[fault]
    params = tmp_path / "bad.yaml"
    params.write_text(text)
    manifest = tmp_path / "m.csv"
    manifest.write_text(f"bag,track,train,unit\n{BAGS[0]},intercity_32km,virm6,u1\n")
    out = tmp_path / "out"
    assert main(["fleet", str(manifest), "--out", str(out), "--params-file", str(params), "--quiet"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"train-calib fleet: error: {params}: ") and problem in err[0], err
    assert not out.exists()  # refused before anything runs


def test_missing_params_file(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    manifest = tmp_path / "m.csv"
    manifest.write_text(f"bag,track,train,unit\n{BAGS[0]},intercity_32km,virm6,u1\n")
    none = tmp_path / "none.yaml"
    assert main(["fleet", str(manifest), "--out", str(tmp_path / "o"), "--params-file", str(none), "--quiet"]) == 2
    assert capsys.readouterr().err.strip() == f"train-calib fleet: error: {none}: params file not found"


def test_params_sha256_joins_the_resume_key(tmp_path: Path) -> None:
    """No file, then a file: all recomputed; the same file again: all resumed; its content changed: recomputed."""
    manifest = tmp_path / "m.csv"
    manifest.write_text("bag,track,train,unit\n" + "".join(f"{b},intercity_32km,virm6,u{k}\n" for k, b in
                                                            enumerate(BAGS)))  # fmt: skip
    params = tmp_path / "p.yaml"
    out = tmp_path / "out"

    def fleet(*extra: str) -> dict:
        assert main(["fleet", str(manifest), "--out", str(out), "--workers", "1", "--quiet", *extra]) == 0
        return json.loads((out / "fleet.json").read_text())

    plain = fleet()
    assert plain["computed"] == 2 and plain["params_sha256"] is None
    params.write_text(CHANGED)
    first = fleet("--resume", "--params-file", str(params))
    assert first["computed"] == 2 and first["resumed"] == 0
    assert first["params_sha256"] == hashlib.sha256(CHANGED.encode()).hexdigest()
    rows = pd.read_parquet(out / "runs.parquet")
    again = fleet("--resume", "--params-file", str(params))
    assert again["computed"] == 0 and again["resumed"] == 2
    pd.testing.assert_frame_equal(rows, pd.read_parquet(out / "runs.parquet"), check_exact=True)
    params.write_text(CHANGED.replace("0.05", "0.4"))
    changed = fleet("--resume", "--params-file", str(params))
    assert changed["computed"] == 2 and changed["resumed"] == 0
    assert (pd.read_parquet(out / "runs.parquet")["final_r80"] != rows["final_r80"]).all()
