"""train-calib predict: every bundled bag, the truth's r(v) against the measured coasts, the --resistance sources,
and bad input (one line naming the option or file, exit 2); a run without a coast gives an empty table and a note."""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path

import numpy as np
import pytest
from repo_paths import REPO

from train_calib.cli import main
from train_calib.prediction.offline import CSV_COLUMNS, resistance_source
from train_calib.train import load_train

BAGS = REPO / "bags"
BUNDLED = sorted(p.name for p in BAGS.iterdir() if p.is_dir())
TRAINS = {"intercity_32km": "virm6", "tunnel_line_37km": "icrm"}


def _track_train(bag: str) -> tuple[str, str]:
    track = next(t for t in TRAINS if bag.startswith(t))
    return track, TRAINS[track]


def _rows(out: Path) -> list[dict[str, str]]:
    with (out / "coasts.csv").open(encoding="utf-8") as f:
        return list(csv.DictReader(f))


@pytest.mark.parametrize("bag", BUNDLED)
def test_predict_on_every_bundled_bag_with_the_truth_given(bag, tmp_path, capsys):
    """Every bag: the three models per coast, the columns of the contract; with the simulator's true r(v) as
    --resistance, every coast of at least 2 min ends within 1.5 km/h of the measured speed (measured: 1 km/h
    resolution, 0.5 km/h noise; the median over the bags is far lower, docs/prediction.md) and inside the predicted
    2 sigma."""
    track, train = _track_train(bag)
    truth = json.loads((BAGS / f"{bag}.truth.json").read_text(encoding="utf-8"))["resistance"]
    given = f"{truth['r0']!r},{truth['r1']!r},{truth['r2']!r}"
    out = tmp_path / "out"
    rc = main(["predict", str(BAGS / bag), "--track", track, "--train", train, "--out", str(out),
               "--resistance", given])  # fmt: skip
    assert rc == 0
    with (out / "coasts.csv").open(encoding="utf-8") as f:
        assert next(csv.reader(f)) == list(CSV_COLUMNS)
    rows = _rows(out)
    assert rows, "every bundled bag has a final coast"
    assert {r["model"] for r in rows} == {"train_file", "causal", "given"}
    summary = json.loads((out / "prediction.json").read_text(encoding="utf-8"))
    assert summary["coasts"] == len(rows) // 3
    assert (out / "prediction.png").stat().st_size > 10_000
    long = [r for r in rows if r["model"] == "given" and float(r["measured_duration_s"]) >= 120.0]
    assert long
    for r in long:
        err = abs(float(r["predicted_end_speed_kmh"]) - float(r["measured_end_speed_kmh"]))
        assert err < 1.5, r
        assert err <= 2.0 * float(r["predicted_end_speed_sigma_kmh"]), r
    assert set(summary["models"]) == {"train_file", "causal", "given"}
    if "tunnel" in bag:  # traction power: energy for the measured profile, the truth within 10 % of the meter
        energy = summary["traction_energy"]
        assert energy["measured_kwh"] > 0 and abs(energy["given_error_pct"]) < 10.0, energy


def test_resistance_sources(tmp_path):
    """r0,r1,r2; a summary.json (its whole-run best, with covariance); a units.parquet row (r40/80/120 solved)."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    train = load_train(REPO / "config" / "trains" / "virm6.yaml")
    g = resistance_source("0.017,0.0002,4.5e-5", train)
    assert np.allclose(g.r, [0.017, 0.0002, 4.5e-5]) and not g.covariance.any()
    best = {"learnt": True, "r0": 0.018, "r1": 1e-4, "r2": 5e-5, "covariance": np.diag([1e-6, 1e-9, 1e-12]).tolist()}
    summary = {"train": {"name": train.name}, "best": best}
    (tmp_path / "summary.json").write_text(json.dumps(summary), encoding="utf-8")
    g = resistance_source(str(tmp_path / "summary.json"), train)
    assert np.allclose(g.r, [0.018, 1e-4, 5e-5]) and g.covariance[0, 0] == 1e-6
    v = np.array([40.0, 80.0, 120.0]) / 3.6
    r = np.array([0.016, 2e-4, 4.2e-5])
    rv = r[0] + r[1] * v + r[2] * v * v
    table = pa.table({"unit": ["unit000", "unit001"], "r40": [rv[0], 1.0], "r80": [rv[1], 1.0], "r120": [rv[2], 1.0],
                      "r40_std": [1e-3, 1.0], "r80_std": [1e-3, 1.0], "r120_std": [2e-3, 1.0]})  # fmt: skip
    pq.write_table(table, tmp_path / "units.parquet")
    g = resistance_source(f"{tmp_path / 'units.parquet'}:unit000", train)
    assert np.allclose(g.r, r, rtol=1e-9)
    h = np.array([1.0, v[1], v[1] ** 2])
    assert math.isclose(math.sqrt(h @ g.covariance @ h), 1e-3, rel_tol=1e-9)


BAG = str(BAGS / "intercity_32km_10s_00")


@pytest.mark.parametrize(
    ("resistance", "expected"),
    [
        ("abc", "--resistance 'abc': expected r0,r1,r2"),
        ("0.01,0.0002", "--resistance '0.01,0.0002': expected r0,r1,r2"),
        ("0.01,nan,1e-5", "expected r0,r1,r2"),
        ("-0.01,0.0002,1e-5", "expected r0,r1,r2"),
        ("missing.json", "--resistance missing.json: file not found"),
        ("OTHER_TRAIN", "a summary of train 'ICRm', not of --train 'VIRM-VI'"),
        ("NOT_JSON", "not a readable summary.json"),
        ("units.parquet", "2 units: name one as"),
        ("units.parquet:unit999", "no unit 'unit999'"),
    ],
)
def test_bad_resistance_is_one_line_and_exit_2(resistance, expected, tmp_path, capsys):
    import pyarrow as pa
    import pyarrow.parquet as pq

    (tmp_path / "other.json").write_text(json.dumps({"train": {"name": "ICRm"}, "final": {}}), encoding="utf-8")
    (tmp_path / "bad.json").write_text("{not json", encoding="utf-8")
    pq.write_table(
        pa.table(
            {"unit": ["a", "b"], **{k: [0.1, 0.1] for k in ("r40", "r80", "r120", "r40_std", "r80_std", "r120_std")}}
        ),
        tmp_path / "units.parquet",
    )
    arg = {"OTHER_TRAIN": str(tmp_path / "other.json"), "NOT_JSON": str(tmp_path / "bad.json")}.get(resistance)
    if arg is None:
        arg = str(tmp_path / resistance) if resistance.startswith(("units", "missing")) else resistance
        expected = expected.replace("missing.json", str(tmp_path / "missing.json"))
    rc = main(["predict", BAG, "--track", "intercity_32km", "--train", "virm6", "--out", str(tmp_path / "o"),
               f"--resistance={arg}"])  # fmt: skip
    err = capsys.readouterr().err
    assert rc == 2
    assert err.count("\n") == 1 and err.startswith("train-calib predict: error: --resistance") and expected in err, err
    assert not (tmp_path / "o" / "coasts.csv").exists()  # refused before any work


def test_bad_files_and_bags_are_one_line_and_exit_2(tmp_path, capsys):
    for argv, expected in (
        (["predict", str(tmp_path / "nobag"), "--track", "intercity_32km", "--train", "virm6"], "nobag"),
        (["predict", BAG, "--track", "no_such_track", "--train", "virm6"], "no_such_track"),
        (["predict", BAG, "--track", "intercity_32km", "--train", "virm6", "--min-coast", "-1"], "--min-coast"),
    ):
        rc = main([*argv, "--out", str(tmp_path / "o")])
        err = capsys.readouterr().err
        assert rc == 2 and err.count("\n") == 1 and expected in err, err


def test_a_run_without_a_coast_gives_an_empty_table_and_a_note(tmp_path, capsys):
    """No coast as long as --min-coast: the header only, prediction.json says so, exit 0."""
    out = tmp_path / "o"
    rc = main(["predict", BAG, "--track", "intercity_32km", "--train", "virm6", "--out", str(out),
               "--min-coast", "100000"])  # fmt: skip
    assert rc == 0
    assert (out / "coasts.csv").read_text(encoding="utf-8").strip() == ",".join(CSV_COLUMNS)
    summary = json.loads((out / "prediction.json").read_text(encoding="utf-8"))
    assert summary["coasts"] == 0 and "no coast" in summary["note"]
    assert "note: no coast" in capsys.readouterr().out
