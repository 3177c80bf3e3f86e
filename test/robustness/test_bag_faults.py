"""Damaged bags: a clear error, and what could be read is replayed with valid, complete outputs.

``train-calib replay`` on a truncated recording, a corrupt chunk or messages that are not valid CDR replays
every message that can still be read (train_calib.mcap_salvage), writes output.mcap and summary.json for
them (``input_error`` says what was wrong) and exits with status 3 and one line naming the file. Missing
input topics or an input topic of the wrong type: status 2, nothing written. Topics of unknown types besides
the inputs are ignored.
"""

from __future__ import annotations

import json
import sys
from collections import Counter
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "nodes"))
from compare import compare, read_outputs
from faultlib import GNSS, SPEED, TRAIN_FILE, _message, make_scenario, write_bag

from train_calib import bagio, cli
from train_calib.bagio import BagDamage
from train_calib.pipeline import Pipeline

pytestmark = pytest.mark.ros


@pytest.fixture(scope="module")
def setup(tmp_path_factory):
    d = tmp_path_factory.mktemp("bags")
    sc = make_scenario(d)
    events = [e for e in sc.events if e.t < 400.0]
    bag = write_bag(d / "bag", events)
    return d, sc, events, bag


def _replay(capsys, bag, sc, out) -> tuple[int, list[str], dict]:
    argv = ["replay", str(bag), "--track", str(sc.track_path), "--train", str(TRAIN_FILE)]
    code = cli.main([*argv, "--out", str(out), "--quiet", "--no-report"])
    err = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip() and not ln.startswith("[INFO]")]
    summary = json.loads((out / "summary.json").read_text()) if (out / "summary.json").exists() else {}
    return code, err, summary


def _core(bag, sc):
    """The core chain on what can be read of the bag (the salvaged messages), as the graph must see it."""
    pipeline = Pipeline(sc.track, sc.train)
    try:
        for m in bagio.iter_bag(bag, bagio.INPUT_TOPICS):
            try:
                msg = m.decode()
            except Exception:
                continue
            pipeline.add_message(m.topic, msg)
    except BagDamage:
        pass
    return pipeline.end_of_input()


def _check_outputs(out: Path, reference) -> None:
    """output.mcap is a complete MCAP (no damage), holds what the core chain makes of the readable inputs, and
    summary.json counts exactly what it holds."""
    recorded = Counter(m.topic for m in bagio.iter_bag(out))  # raises on any damage
    assert compare(read_outputs(out), reference) == []
    summary = json.loads((out / "summary.json").read_text())
    assert summary["output_counts"] == dict(recorded)
    assert recorded["/train_calib/resistance"] == len(reference.estimates) > 0


@pytest.mark.parametrize("fraction", [0.4, 0.8, 0.9995])
def test_truncated_recording_replays_what_it_holds(setup, capsys, tmp_path, fraction):
    _, sc, events, bag = setup
    (file,) = bagio.mcap_files(bag)
    data = file.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: int(len(data) * fraction)])
    code, err, summary = _replay(capsys, cut, sc, tmp_path / "out")
    readable = sum(summary["input_counts"].values())
    if fraction < 0.999:  # cut inside the data: status 3, one line naming the file
        assert code == 3 and len(err) == 1 and err[0].startswith(f"train-calib replay: error: {cut}: damaged MCAP")
        assert summary["input_error"].startswith(f"{cut}: damaged MCAP")
        assert 0.8 * fraction * len(events) < readable < len(events)
    else:  # cut in the summary section after the data: every message is there
        assert code == 0 and summary["input_error"] is None and readable == len(events)
    _check_outputs(tmp_path / "out", _core(cut, sc))


def test_corrupt_chunk_replays_the_records_before_the_damage(setup, capsys, tmp_path):
    _, sc, events, bag = setup
    (file,) = bagio.mcap_files(bag)
    data = bytearray(file.read_bytes())
    middle = len(data) // 2
    data[middle : middle + 64] = b"\xab" * 64
    bad = tmp_path / "corrupt.mcap"
    bad.write_bytes(bytes(data))
    code, err, summary = _replay(capsys, bad, sc, tmp_path / "out")
    assert code == 3 and len(err) == 1 and "damaged MCAP" in err[0] and str(bad) in err[0]
    assert 0.3 * len(events) < sum(summary["input_counts"].values()) < len(events)
    _check_outputs(tmp_path / "out", _core(bad, sc))


def test_messages_that_are_not_valid_cdr_are_left_out_and_counted(setup, capsys, tmp_path):
    _, sc, events, _ = setup
    bag = tmp_path / "garbage"
    with bagio.BagWriter(bag, {t: bagio.INPUT_TOPICS[t] for t in (GNSS, SPEED)}) as writer:
        for k, e in enumerate(events):
            if e.topic == SPEED and k in (300, 302):
                writer.write_raw(SPEED, b"\x00\x01\x00\x00garbage", e.log_ns)  # valid CDR header, no message
            else:
                writer.write(e.topic, _message(e), e.log_ns)
    code, err, summary = _replay(capsys, bag, sc, tmp_path / "out")
    assert code == 3 and err == [
        f"train-calib replay: error: {bag}: 2 input messages are not valid CDR and were left out"
    ]
    assert summary["input_undecodable"] == {SPEED: 2}
    assert summary["input_counts"][SPEED] == sum(e.topic == SPEED for e in events) - 2
    _check_outputs(tmp_path / "out", _core(bag, sc))


def test_unknown_message_types_besides_the_inputs_are_ignored(setup, capsys, tmp_path):
    from train_calib.record import McapBagWriter

    _, sc, events, _ = setup
    directory = tmp_path / "mixed"
    writer = McapBagWriter(directory, {t: bagio.INPUT_TOPICS[t] for t in (GNSS, SPEED)}, file_name="mixed.mcap")
    schema = writer._writer.register_schema(name="acme_msgs/msg/Thing", encoding="ros2msg", data=b"float64 x\n")
    channel = writer._writer.register_channel(topic="/acme/thing", message_encoding="cdr", schema_id=schema)
    for k, e in enumerate(events):
        writer.write(e.topic, _message(e), e.log_ns)
        if k % 10 == 0:
            writer._writer.add_message(channel, log_time=e.log_ns, data=b"\x00\x01" + bytes(10), publish_time=e.log_ns)
    writer.close()
    code, err, summary = _replay(capsys, directory / "mixed.mcap", sc, tmp_path / "out")
    assert code == 0 and err == [] and summary["input_counts"] == {GNSS: 400, SPEED: 400}


def test_wrong_type_or_missing_input_topics_are_refused_in_one_line(setup, capsys, tmp_path):
    _, sc, events, _ = setup
    wrong = tmp_path / "wrong"
    with bagio.BagWriter(wrong, {GNSS: bagio.INPUT_TOPICS[GNSS], SPEED: "std_msgs/msg/Float64"}) as writer:
        for e in events[:20]:
            if e.topic == GNSS:
                writer.write(GNSS, _message(e), e.log_ns)
            else:
                writer.write(SPEED, bagio.msg_class("std_msgs/msg/Float64")(data=e.fields["v"]), e.log_ns)
    code, err, _ = _replay(capsys, wrong, sc, tmp_path / "o1")
    assert code == 2 and err == [
        f"train-calib replay: error: {wrong}: topic /train/speed has type std_msgs/msg/Float64, "
        "expected geometry_msgs/msg/TwistStamped"
    ]
    for keep, missing in ((GNSS, SPEED), (SPEED, GNSS)):
        only = write_bag(tmp_path / f"only_{keep.strip('/').replace('/', '_')}", [e for e in events if e.topic == keep])
        code, err, _ = _replay(capsys, only, sc, tmp_path / "o2")
        assert code == 2 and len(err) == 1 and f"no {missing} topic" in err[0]
    assert not (tmp_path / "o1" / "output.mcap").exists() and not (tmp_path / "o2" / "output.mcap").exists()


def test_a_truncated_output_recording_is_read_back_up_to_the_damage(setup, tmp_path):
    """A recording cut by a killed process (no summary, a zstd chunk cut short): the reader gives every message
    of the complete chunks and of the readable part of the cut one, then the damage."""
    from train_calib.record import McapBagWriter

    writer = McapBagWriter(tmp_path / "rec", {"/train_calib/regime": "train_calib_msgs/msg/DrivingRegime"})
    regime = bagio.msg_class("train_calib_msgs/msg/DrivingRegime")
    rng = np.random.default_rng(0)
    for k in range(20000):
        msg = regime(header=bagio.make_header(k), run_id=k, regime=int(rng.integers(5)), s=float(k), v=1.0,
                     effort=0.0, acceleration=0.0, v_measured=1.0, effort_source=0, phase=0)  # fmt: skip
        writer.write("/train_calib/regime", msg, k)
    writer._stream.flush()
    data = (tmp_path / "rec" / "output.mcap").read_bytes()  # the writer is not closed: as a killed process left it
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: int(len(data) * 0.7)])
    got = []
    with pytest.raises(BagDamage, match=r"cut\.mcap: damaged MCAP"):
        for m in bagio.iter_bag(cut):
            got.append(m.decode().run_id)
    assert got == list(range(len(got))) and len(got) > 1000
