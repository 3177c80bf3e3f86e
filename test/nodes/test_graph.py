"""The node graph changes nothing: replayed bags give, message for message, the offline pipeline's numbers.

In one process (EventsExecutor and SingleThreadedExecutor), with one process per node, at rate 0 and at
a high finite rate; a separate DAS process receives every message; output.mcap reads the same with
rosbags and mcap; /diagnostics carry the drops by reason, the rates and the filter health in sim time.
The synthetic bag has traction power, so window_calib_node runs too (/train_calib/window_resistance is compared).
"""

from __future__ import annotations

import json
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml
from compare import compare, read_outputs
from msgfill import to_dict
from repo_paths import DATA
from synthetic_bag import write_bag

from train_calib import bagio
from train_calib.ingest import GNSS, SPEED
from train_calib.pipeline import run_bag
from train_calib.replay import ReplayOptions, replay
from train_calib.track import load_track
from train_calib.train import load_train

pytestmark = pytest.mark.ros

TRACK = str(DATA / "small_track.yaml")
TRAIN = str(DATA / "small_train.yaml")


@pytest.fixture(scope="module")
def bag(tmp_path_factory):
    return write_bag(tmp_path_factory.mktemp("bag") / "synthetic")


@pytest.fixture(scope="module")
def reference(bag):
    return run_bag(bag, load_track(TRACK), load_train(TRAIN))


def _replay(bag, out, **kwargs):
    return replay(ReplayOptions(bag=bag, track=TRACK, train=TRAIN, out=out, **kwargs))


@pytest.fixture(scope="module")
def one_process(bag, tmp_path_factory):
    out = tmp_path_factory.mktemp("one")
    return _replay(bag, out), read_outputs(out)


def test_one_process_replay_equals_the_offline_pipeline_message_for_message(bag, reference, one_process):
    result, outputs = one_process
    assert result.executor == "EventsExecutor"
    counts = {t: 0 for t in bagio.INPUT_TOPICS}
    for m in bagio.iter_bag(bag):
        counts[m.topic] += 1
    assert result.sent == counts  # every input message was published once
    assert result.nodes[-1] == "window_calib_node"  # the bag has /train/traction_power
    assert compare(outputs, reference) == []
    runs = len({m.run_id for m in reference.measurements})
    assert len(reference.windows) == sum(m.power_valid for m in reference.measurements) - runs  # the first: no step
    n = len(reference.measurements)
    assert n > 300 and len(reference.features) > 10
    assert len({m.run_id for m in reference.measurements}) == 2
    assert sum(f.run_complete for f in reference.features) == 2  # each run closed once


@pytest.mark.parametrize(
    "mode",
    [
        pytest.param({"processes": True}, id="one-process-per-node"),
        pytest.param({"executor": "single"}, id="single-threaded-executor"),
        pytest.param({"rate": 400.0}, id="rate-400"),
    ],
)
def test_every_mode_and_rate_gives_the_same_messages(bag, reference, tmp_path, mode):
    result = _replay(bag, tmp_path, **mode)
    assert compare(read_outputs(tmp_path), reference) == []
    if "rate" in mode:
        assert result.wall_s >= result.bag_duration_s / 400.0  # paced by the bag's timing, not as fast as possible


@pytest.mark.parametrize("mode", [{}, {"processes": True}], ids=["one-process", "one-process-per-node"])
def test_regimes_one_sample_late_give_the_pipeline_s_messages(bag, tmp_path, mode):
    """regime_node with lag_samples 1 (fixed-lag smoother): the graph publishes what run_bag computes with it (the
    held sample of each run released at the next run or the end of input; window_calib_node waits for it)."""
    from train_calib.estimation import RegimeConfig

    params = tmp_path / "lag.yaml"
    params.write_text(yaml.safe_dump({"regime_node": {"ros__parameters": {"lag_samples": 1}}}))
    _replay(bag, tmp_path / "out", params_files=(params,), **mode)
    lagged = run_bag(bag, load_track(TRACK), load_train(TRAIN), regime=RegimeConfig(lag_samples=1))
    assert compare(read_outputs(tmp_path / "out"), lagged) == []
    assert [r.stamp_ns for r in lagged.regimes] == [e.stamp_ns for e in lagged.estimates]  # each once, in order


def test_the_converging_preset_gives_the_pipeline_s_messages(bag, tmp_path):
    """With the converging filter (known effort from the speeds and from the traction power) the estimates carry
    every effort source, regime_node passes them on, and feature_node locates the phase changes on them: the graph
    still publishes what run_bag computes."""
    from train_calib.commands.replay import preset_params_yaml
    from train_calib.estimation import EFFORT_COMPUTED, EFFORT_POWER, EFFORT_POWER_COASTING, UKFConfig

    params = tmp_path / "converging.yaml"
    params.write_text(preset_params_yaml("converging"))
    _replay(bag, tmp_path / "out", params_files=(params,))
    converging = run_bag(bag, load_track(TRACK), load_train(TRAIN), ukf=UKFConfig.converging())
    assert {EFFORT_COMPUTED, EFFORT_POWER, EFFORT_POWER_COASTING} <= {e.effort_source for e in converging.estimates}
    outputs = read_outputs(tmp_path / "out")
    assert compare(outputs, converging) == []
    # the synthetic bag's power never regenerates, its second run brakes with the power at 0: ukf_node says so
    messages = {s.message for d in outputs["/diagnostics"] for s in d.status if s.name.startswith("ukf_node")}
    assert any("braking without regenerated power" in m and "power_coasting false" in m for m in messages)


def _decoded_with_mcap(path: Path) -> dict[str, list]:
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    out: dict[str, list] = {}
    with open(path, "rb") as f:
        for _, channel, _, msg in make_reader(f, decoder_factories=[DecoderFactory()]).iter_decoded_messages():
            out.setdefault(channel.topic, []).append(msg)
    return out


def _mcap_dict(msg):
    if hasattr(msg, "__slots__") and not isinstance(msg, (list, tuple)):
        return {k: _mcap_dict(getattr(msg, k)) for k in msg.__slots__}
    if isinstance(msg, (list, tuple, np.ndarray)):
        return [_mcap_dict(x) for x in msg]
    if isinstance(msg, bytes):
        return list(msg)
    return msg


def _plain(d):
    if isinstance(d, dict):  # constants (OK, WARN, ...) are not fields
        return {k: _plain(v) for k, v in d.items() if not k.isupper()}
    if isinstance(d, list):
        return [_plain(v) for v in d]
    if isinstance(d, bytes):
        return list(d)
    if isinstance(d, float) and d != d:
        return "nan"
    return d


def test_output_mcap_reads_the_same_with_rosbags_and_mcap(one_process, tmp_path):
    from rosbags.rosbag2 import Reader

    result, _ = one_process
    directory = result.output_bag.parent
    assert result.output_bag.is_file() and result.output_bag.name == "output.mcap"
    meta = yaml.safe_load((directory / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert meta["relative_file_paths"] == ["output.mcap"] and meta["storage_identifier"] == "mcap"
    with Reader(directory) as reader:
        store = bagio.typestore()
        by_rosbags: dict[str, list] = {}
        for connection, _, raw in reader.messages():
            by_rosbags.setdefault(connection.topic, []).append(store.deserialize_cdr(raw, connection.msgtype))
        assert reader.message_count == sum(result.recorded.values())
    by_mcap = _decoded_with_mcap(result.output_bag)
    assert {t: len(v) for t, v in by_mcap.items()} == {t: n for t, n in result.recorded.items() if n}
    assert {t: len(v) for t, v in by_rosbags.items()} == {t: len(v) for t, v in by_mcap.items()}
    for topic, messages in by_mcap.items():
        a = sorted((_plain(to_dict(m)) for m in by_rosbags[topic]), key=json.dumps)
        b = sorted((_plain(_mcap_dict(m)) for m in messages), key=json.dumps)
        assert a == b, topic
    counts = {t["topic_metadata"]["name"]: t["message_count"] for t in meta["topics_with_message_count"]}
    assert counts == result.recorded
    # every channel carries the full message definition
    from mcap.reader import make_reader

    with open(result.output_bag, "rb") as f:
        summary = make_reader(f).get_summary()
    definition = next(s for s in summary.schemas.values() if s.name == "train_calib_msgs/msg/ResistanceEstimate")
    assert b"float64[25] covariance" in definition.data and b"MSG: builtin_interfaces/Time" in definition.data


def test_diagnostics_report_drops_by_reason_rates_and_filter_health_in_sim_time(bag, reference, one_process):
    _, outputs = one_process
    stats = reference.ingest_stats
    diag = outputs["/diagnostics"]
    last = {}
    for array in diag:
        for status in array.status:
            last[status.name] = (array.header, status)
    assert set(last) == {"gnss_speed_node", "ukf_node", "regime_node", "feature_node", "window_calib_node"}
    _, gnss = last["gnss_speed_node"]
    values = {kv.key: kv.value for kv in gnss.values}
    drops = {k: int(v) for k, v in values.items() if " dropped " in k}
    expected = {f"/gnss/fix dropped {r}": n for r, n in stats.dropped[GNSS].items()}
    expected |= {f"/train/speed dropped {r}": n for r, n in stats.dropped[SPEED].items()}
    assert drops == expected
    assert expected == {
        "/gnss/fix dropped nan": 1,
        "/gnss/fix dropped no_fix": 1,
        "/train/speed dropped nan": 1,
        "/train/speed dropped negative_speed": 1,
        "/train/speed dropped stale": 1,
    }
    assert float(values["/train/speed rate (Hz)"]) == pytest.approx(1.0, rel=0.5)  # 1 Hz in bag (sim) time
    assert int(values["/train_calib/measurement published"]) == len(reference.measurements)
    _, ukf = last["ukf_node"]
    ukf_values = {kv.key: kv.value for kv in ukf.values}
    assert ukf_values["filter health"] in ("ok", "repaired", "degraded", "reset")
    assert int(ukf_values["filter updates"]) == len(reference.estimates)
    _, window = last["window_calib_node"]
    window_values = {kv.key: kv.value for kv in window.values}
    well = sum(not f.ill_posed for f in reference.windows)
    assert int(window_values["windows well posed"]) == well
    assert int(window_values["windows ill posed"]) == len(reference.windows) - well
    assert int(window_values["/train_calib/window_resistance published"]) == len(reference.windows)
    _, regime = last["regime_node"]
    assert {kv.key: kv.value for kv in regime.values}["method"] == "imm"
    # use_sim_time: diagnostics are stamped with the bag's clock, not the wall clock
    first = reference.measurements[0].stamp_ns
    stamps = [bagio.stamp_ns(a.header) for a in diag]
    assert min(stamps) >= first - 10**9 and max(stamps) <= reference.measurements[-1].stamp_ns + 10**9


def test_a_separate_das_process_receives_every_message(bag, reference, tmp_path):
    das = subprocess.Popen(
        [sys.executable, str(Path(__file__).with_name("das_standin.py"))],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        cwd=Path(__file__).parent,
    )
    try:
        assert das.stdout.readline().strip() == "READY", das.stderr.read()
        result = _replay(bag, tmp_path, wait_for_subscribers=1, live=True)
        das.send_signal(signal.SIGINT)
        out, _ = das.communicate(timeout=30)
    finally:
        if das.poll() is None:
            das.kill()
    received = json.loads(out.strip().splitlines()[-1])
    stamps = {  # what the graph published, per topic, to name what a failure lost
        "/train_calib/resistance": [e.stamp_ns for e in reference.estimates],
        "/train_calib/features": [f.stamp_ns for f in reference.features],
    }
    missing = {t: sorted(set(s) - {r[0] for r in received.get(t, [])}) for t, s in stamps.items()}
    assert {t: len(v) for t, v in received.items()} == {t: result.recorded[t] for t in received}, missing
    assert [r[0] for r in received["/train_calib/resistance"]] == [e.stamp_ns for e in reference.estimates]
    assert [r[1:4] for r in received["/train_calib/resistance"]] == [[e.r0, e.r1, e.r2] for e in reference.estimates]
    assert [r[1] for r in received["/train_calib/regime"]] == [r.regime for r in reference.regimes]
    assert [r[1] for r in received["/train_calib/features"]] == [f.run_complete for f in reference.features]
    assert [r[:2] for r in received["/train_calib/window_resistance"]] == [
        [f.stamp_ns, f.ill_posed] for f in reference.windows
    ]


def test_params_file_reaches_the_nodes_and_carry_over_keeps_the_resistance_at_a_new_run(bag, tmp_path):
    from train_calib.commands.replay import preset_params_yaml
    from train_calib.estimation import UKFConfig

    params = tmp_path / "keep.yaml"
    params.write_text(preset_params_yaml("converging").replace("carry_over: reset", "carry_over: keep"))
    cfg = UKFConfig.converging(carry_over="keep")
    reference = run_bag(bag, load_track(TRACK), load_train(TRAIN), ukf=cfg)
    _replay(bag, tmp_path / "out", params_files=(params,))
    assert compare(read_outputs(tmp_path / "out"), reference) == []
    estimates = reference.estimates
    k = next(i for i, e in enumerate(estimates) if e.run_id == 1)
    before, after = estimates[k - 1], estimates[k]
    assert before.r0 != load_train(TRAIN).davis.r0  # the filter moved during run 0
    assert (after.r0, after.r1, after.r2) == (before.r0, before.r1, before.r2)  # and kept it into run 1
    assert after.covariance[2, 2] == pytest.approx(before.covariance[2, 2] * cfg.carry_over_inflation, rel=1e-9)
