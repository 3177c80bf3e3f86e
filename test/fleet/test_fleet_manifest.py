"""The fleet manifest: parsing, path resolution, and bad input refused in one line (exit status 2)."""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from train_calib.cli import main
from train_calib.fleet.manifest import ManifestError, read_manifest
from train_calib.paths import track_file, train_file


def write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "m.csv"
    path.write_text(text, encoding="utf-8")
    return path


def test_parse_resolves_paths_names_and_dates(tmp_path: Path) -> None:
    (tmp_path / "tracks").mkdir()
    own_track = tmp_path / "tracks" / "mine.yaml"
    own_track.write_text("name: x\n")
    path = write(
        tmp_path,
        "unit,bag,track,train,date,notes\n"
        "U1,bags/a,tracks/mine.yaml,virm6,2025-03-01,anything\n"
        "\n"
        "U2,/abs/b,intercity_32km,virm6.yaml,2025-03-02T10:00:00+01:00,\n"
        "U3,c.mcap,intercity_32km,virm6,,\n",
    )
    rows = read_manifest(path)
    assert [r.index for r in rows] == [0, 1, 2]
    assert [r.unit for r in rows] == ["U1", "U2", "U3"]
    assert rows[0].bag == "bags/a" and rows[0].bag_path == str(tmp_path / "bags" / "a")
    assert rows[0].track_path == str(own_track)
    assert rows[1].bag_path == "/abs/b"
    assert rows[1].track_path == str(track_file("intercity_32km").resolve())
    assert rows[1].train_path == str(train_file("virm6").resolve())
    assert rows[0].date_s == 1740787200.0  # 2025-03-01T00:00:00Z
    assert rows[1].date_s == 1740906000.0  # 09:00 UTC
    assert math.isnan(rows[2].date_s) and rows[2].date == "" and rows[2].driver == "" and rows[2].line == ""
    assert set(rows[0].columns()) == {"index", "bag", "track", "train", "unit", "date", "driver", "line"}


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("", "empty"),
        ("bag,track,unit\nx,y,z\n", ":1: header: missing column(s) train"),
        ("bag,track,train,unit\n", "no runs"),
        ("bag,track,train,unit\na,b,c\n", ":2: 3 fields, the header has 4"),
        ("bag,track,train,unit\na,b,c,\n", ":2: unit: empty"),
        ("bag,track,train,unit,date\na,b,c,d,2025-13-01\n", ":2: date: '2025-13-01' is not ISO 8601"),
        ("bag,track,train,unit,unit\na,b,c,d,e\n", "header: column(s) unit given twice"),
    ],
)
def test_bad_manifest_one_line(tmp_path: Path, text: str, expected: str) -> None:
    path = write(tmp_path, text)
    with pytest.raises(ManifestError) as info:
        read_manifest(path)
    message = str(info.value)
    assert message.startswith(str(path)) and expected in message and "\n" not in message


def test_cli_bad_input_exit_2(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "out"
    assert main(["fleet", str(tmp_path / "missing.csv"), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"train-calib fleet: error: {tmp_path / 'missing.csv'}: no such file"]
    path = write(tmp_path, "bag,track\na,b\n")
    assert main(["fleet", str(path), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "missing column(s) train, unit" in err[0]
    path = write(tmp_path, "bag,track,train,unit\na,b,c,d\n")
    assert main(["fleet", str(path), "--out", str(out), "--workers", "0"]) == 2
    assert "--workers: must be at least 1" in capsys.readouterr().err
    assert main(["fleet", str(path), "--out", str(out), "--tls-cert", "x.pem"]) == 2
    assert "need --scheduler tls://" in capsys.readouterr().err
    assert main(["fleet", str(path), "--out", str(out), "--scheduler", "tls://127.0.0.1:1"]) == 2
    assert "--tls-ca-file: needed with --scheduler tls://" in capsys.readouterr().err
    assert main(["fleet", str(path), "--out", str(out), "--scheduler", "http://127.0.0.1:1"]) == 2
    assert "expected tcp://HOST:PORT or tls://HOST:PORT" in capsys.readouterr().err
    with pytest.raises(SystemExit) as info:
        main(["fleet", str(path), "--out", str(out), "--workers", "2", "--scheduler", "tcp://127.0.0.1:1"])
    assert info.value.code == 2
    assert not out.exists() or not any(out.iterdir())
