"""The two commands end to end on the 6 km test line: files written, numbers consistent, bad input."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import pytest

from train_calib.cli import main
from train_calib.paths import config_file

TYPES = str(config_file("train_types/ic_compositions.yaml"))


@pytest.fixture(scope="module")
def simulated(tmp_path_factory):
    out = tmp_path_factory.mktemp("fleet")
    track = str(Path(__file__).resolve().parent / "data" / "line_6km.yaml")
    args = [
        "simulate-occupation",
        "--track",
        track,
        "--train-types",
        TYPES,
        "--compositions",
        "VIRM4,ICRm",
        "--runs",
        "4",
        "--seed",
        "3",
        "--hindered",
        "0.25",
        "--workers",
        "2",
        "--out",
        str(out),
    ]
    assert main(args) == 0
    return track, out


def test_simulate_writes_events_and_truth(simulated):
    _, out = simulated
    text = (out / "events.csv").read_text()
    assert text.startswith("# simulated by train-calib simulate-occupation: seed 3, 4 runs per composition")
    truth = list(csv.DictReader((out / "truth.csv").open()))
    assert [t["run_id"] for t in truth] == [f"VIRM4-{i:03d}" for i in range(4)] + [f"ICRm-{i:03d}" for i in range(4)]
    assert {t["length_m"] for t in truth} == {"108", "282"}
    assert any(t["hindrance"] for t in truth)


def test_calibrate_end_to_end(simulated, tmp_path, capsys):
    track, fleet = simulated
    out = tmp_path / "cal"
    args = [
        "calibrate-occupation",
        str(fleet / "events.csv"),
        "--track",
        track,
        "--train-types",
        TYPES,
        "--out",
        str(out),
        "--truth",
        str(fleet / "truth.csv"),
        "--workers",
        "2",
        "--maxiter",
        "6",
        "--run-plots",
        "1",
    ]
    assert main(args) == 0
    printed = capsys.readouterr().out
    summary = json.loads((out / "summary.json").read_text())
    truth = {t["run_id"]: t for t in csv.DictReader((fleet / "truth.csv").open())}
    hindered = {k for k, t in truth.items() if t["hindrance"]}
    runs = {r["run_id"]: r for r in csv.DictReader((out / "runs.csv").open())}
    assert set(runs) == set(truth)
    # every hindered run rejected with a reason; the others calibrated with their true composition
    for rid, row in runs.items():
        if rid in hindered:
            assert row["status"] == "rejected" and row["reason"].startswith("unexpected")
        else:
            assert row["status"] == "calibrated", row["reason"]
            assert row["composition"] == truth[rid]["composition"]
            assert 0.8 <= float(row["theta_cruise"]) <= 1.02 and float(row["objective_s"]) > 0
    assert summary["counts"]["calibrated"] == len(truth) - len(hindered)
    assert summary["filter_accuracy"] == {
        "hindered": len(hindered),
        "hindered_rejected": len(hindered),
        "unhindered_rejected": 0,
    }
    assert summary["length_accuracy"]["1"]["correct"] == len(truth)
    assert summary["length_accuracy"]["0"]["assigned"] == 0
    assert set(summary["sensitivity"]) == {"VIRM4", "ICRm"}
    residuals = list(csv.DictReader((out / "residuals.csv").open()))
    assert {r["run_id"] for r in residuals} == {k for k in truth if k not in hindered}
    for name in (
        "lengths.csv",
        "distributions.md",
        "distributions.csv",
        "sensitivity.csv",
        "truth_comparison.csv",
        "plots/lengths.png",
        "plots/ranges.png",
        "plots/run_VIRM4-000.png",
    ):
        assert (out / name).stat().st_size > 0, name
    assert "calibrated:" in printed and "length delta 1 s" in printed


def test_bad_input_is_one_line(simulated, tmp_path, capsys):
    track, _ = simulated
    bad = tmp_path / "bad.csv"
    bad.write_text("run_id,section_id,event,time\nr1,T03,occupy,10\nr1,X9,occupy,20\n")
    code = main(["calibrate-occupation", str(bad), "--track", track, "--train-types", TYPES, "--out", str(tmp_path)])
    err = capsys.readouterr().err.strip()
    assert code == 2
    assert err == f"train-calib calibrate-occupation: error: {bad}: line 3: section 'X9' is not a section of the track"
    code = main(
        [
            "calibrate-occupation",
            str(bad),
            "--track",
            track,
            "--train-types",
            TYPES,
            "--out",
            str(tmp_path),
            "--stops",
            "Nowhere",
        ]
    )
    assert code == 2 and "--stops: no station 'Nowhere'" in capsys.readouterr().err


def test_single_runs_use_the_model_as_reference(simulated):
    from train_calib.occupation.calibrate import CalibrationConfig
    from train_calib.occupation.compositions import load_train_types
    from train_calib.occupation.events import load_events
    from train_calib.occupation.pipeline import calibrate_fleet
    from train_calib.track import load_track

    track_path, fleet = simulated
    track, types = load_track(track_path), load_train_types(TYPES)
    events = load_events(fleet / "events.csv")
    truth = {t["run_id"]: t for t in csv.DictReader((fleet / "truth.csv").open())}
    for rid, t in truth.items():
        result = calibrate_fleet({rid: events[rid]}, track, types, calibration=CalibrationConfig(maxiter=1))
        (outcome,) = result.outcomes
        assert result.settings["reference"] == "model with defaults"
        assert outcome.status == ("rejected" if t["hindrance"] else "calibrated"), (rid, outcome.reason)
