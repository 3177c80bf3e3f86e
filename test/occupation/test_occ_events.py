"""The occupation CSV format: round trip, ISO times, and one-line errors naming file and line."""

from __future__ import annotations

import pytest

from train_calib.errors import ConfigError
from train_calib.occupation.events import RunEvents, load_events, write_events

SECTIONS = ["S1", "S2", "S3"]


def _write(tmp_path, text: str):
    path = tmp_path / "events.csv"
    path.write_text(text, encoding="utf-8")
    return path


def test_round_trip(tmp_path):
    runs = [
        RunEvents("a", occupy={"S2": 100.0, "S3": 130.0}, release={"S1": 112.0, "S2": 141.0}),
        RunEvents("b,quoted", occupy={"S2": 7.5}, release={}),
    ]
    path = write_events(tmp_path / "out" / "ev.csv", runs, comments=["made by a test"])
    loaded = load_events(path, SECTIONS)
    assert list(loaded) == ["a", "b,quoted"]
    assert loaded["a"].occupy == {"S2": 100.0, "S3": 130.0}
    assert loaded["a"].release == {"S1": 112.0, "S2": 141.0}
    assert loaded["b,quoted"].occupy == {"S2": 7.5}
    assert path.read_text().startswith("# made by a test\nrun_id,section_id,event,time\n")


def test_iso_times_extra_columns_and_any_order(tmp_path):
    path = _write(
        tmp_path,
        "train,run_id,time,event,section_id\n"
        "1913,r1,2010-04-12T07:12:40,release,S1\n"
        "1913,r1,2010-04-12T07:12:33,occupy,S2\n",
    )
    run = load_events(path, SECTIONS)["r1"]
    assert run.release["S1"] - run.occupy["S2"] == pytest.approx(7.0)
    assert run.times("occupy", SECTIONS)[1] == run.occupy["S2"]
    assert run.first_time() == run.occupy["S2"]


@pytest.mark.parametrize(
    ("body", "where", "problem"),
    [
        ("r,S9,occupy,1\n", "line 2", "section 'S9' is not a section of the track"),
        ("r,S1,enter,1\n", "line 2", "event 'enter' is not one of occupy, release"),
        ("r,S1,occupy,1\nr,S1,occupy,2\n", "line 3", "duplicate occupy of section 'S1' in run 'r'"),
        ("r,S1,occupy,noon\n", "line 2", "is neither seconds nor an ISO 8601 timestamp"),
        ("r,S1,occupy,nan\n", "line 2", "is neither seconds nor an ISO 8601 timestamp"),
        ("r,S1,occupy,5\nr,S2,occupy,2010-04-12T07:00:00\n", "line 3", "mixes ISO 8601 timestamps with seconds"),
        ("r,S1,occupy\n", "line 2", "expected at least 4 columns, found 3"),
        (",S1,occupy,1\n", "line 2", "empty run_id"),
    ],
)
def test_bad_rows_refused_with_line(tmp_path, body, where, problem):
    path = _write(tmp_path, "run_id,section_id,event,time\n" + body)
    with pytest.raises(ConfigError) as err:
        load_events(path, SECTIONS)
    message = str(err.value)
    assert message.startswith(f"{path}: {where}: ")
    assert problem in message
    assert "\n" not in message


def test_bad_files(tmp_path):
    with pytest.raises(ConfigError, match="occupation events file not found"):
        load_events(tmp_path / "none.csv")
    with pytest.raises(ConfigError, match="line 1: header lacks column"):
        load_events(_write(tmp_path, "run,section_id,event,time\n"))
    with pytest.raises(ConfigError, match="empty file"):
        load_events(_write(tmp_path, "# only a comment\n"))
    with pytest.raises(ConfigError, match="no events after the header"):
        load_events(_write(tmp_path, "run_id,section_id,event,time\n"))
    path = tmp_path / "latin1.csv"
    path.write_bytes("run_id,section_id,event,time\nr\xe9,S1,occupy,1\n".encode("latin-1"))
    with pytest.raises(ConfigError, match="not UTF-8"):
        load_events(path)


def test_unknown_sections_allowed_without_track(tmp_path):
    runs = load_events(_write(tmp_path, "run_id,section_id,event,time\nr,ANY,occupy,3\n"))
    assert runs["r"].occupy == {"ANY": 3.0}
