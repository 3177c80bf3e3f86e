"""`train-calib replay` and `demo`: outputs, summary.json, report.png, one-line errors, bundled bags."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest
from repo_paths import DATA, REPO

sys.path.insert(0, str(Path(__file__).parent / "nodes"))
from compare import compare, read_outputs
from synthetic_bag import write_bag

from train_calib import bagio, cli, paths
from train_calib.estimation.records import EFFORT_SOURCES
from train_calib.pipeline import run_bag, whole_run_regimes
from train_calib.regime_codes import REGIME_NAMES
from train_calib.summary import window_fit_from_msg
from train_calib.track import load_track
from train_calib.train import load_train

pytestmark = pytest.mark.ros

TRACK = str(DATA / "small_track.yaml")
TRAIN = str(DATA / "small_train.yaml")


@pytest.fixture(scope="module")
def bag(tmp_path_factory):
    return write_bag(tmp_path_factory.mktemp("bag") / "synthetic")


def _error_line(capsys, argv) -> str:
    assert cli.main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    return err[0]


def test_unreadable_inputs_exit_2_with_one_line_naming_the_problem(bag, tmp_path, capsys):
    base = ["replay", "--track", TRACK, "--train", TRAIN, "--out", str(tmp_path / "o")]
    line = _error_line(capsys, ["replay", str(tmp_path / "nothing"), *base[1:]])
    assert "nothing: no such bag" in line
    garbage = tmp_path / "garbage.mcap"
    garbage.write_bytes(b"\x00not an mcap file")
    assert "garbage.mcap: not a readable MCAP file" in _error_line(capsys, ["replay", str(garbage), *base[1:]])
    line = _error_line(capsys, ["replay", str(bag), "--track", "/no/track.yaml", "--train", TRAIN])
    assert line.endswith("/no/track.yaml: track file not found")
    bad_params = tmp_path / "p.yaml"
    bad_params.write_text("ukf_node: [unclosed\n")
    line = _error_line(capsys, ["replay", str(bag), *base[1:], "--params-file", str(bad_params)])
    assert "p.yaml: invalid YAML" in line
    # a params file value the node refuses: the graph does not start, the reason is given
    refused = tmp_path / "r.yaml"
    refused.write_text("regime_node:\n  ros__parameters:\n    effort_tolerance: -1.0\n")
    line = _error_line(capsys, ["replay", str(bag), *base[1:], "--params-file", str(refused), "--overwrite"])
    assert "effort_tolerance" in line
    from train_calib import bagio

    speedless = tmp_path / "speedless"
    with bagio.BagWriter(speedless, {bagio.GNSS_TOPIC: bagio.INPUT_TOPICS[bagio.GNSS_TOPIC]}) as writer:
        fix = bagio.msg_class("sensor_msgs/msg/NavSatFix")(
            header=bagio.make_header(1), status=bagio.msg_class("sensor_msgs/msg/NavSatStatus")(status=0, service=1),
            latitude=52.0, longitude=5.0, altitude=0.0, position_covariance=np.zeros(9), position_covariance_type=0,
        )  # fmt: skip
        writer.write(bagio.GNSS_TOPIC, fix, 1)
    assert "no /train/speed topic" in _error_line(capsys, ["replay", str(speedless), *base[1:]])


def test_replay_writes_output_bag_summary_and_report(bag, tmp_path, capsys):
    out = tmp_path / "out"
    argv = ["replay", str(bag), "--track", TRACK, "--train", TRAIN, "--out", str(out), "--quiet"]
    assert cli.main(argv) == 0
    stdout = capsys.readouterr().out
    assert f"{out}/output.mcap" in stdout
    assert {p.name for p in out.iterdir()} == {"output.mcap", "metadata.yaml", "summary.json", "report.png"}
    summary = json.loads((out / "summary.json").read_text())
    reference = run_bag(bag, load_track(TRACK), load_train(TRAIN))
    final = reference.estimates[-1]
    for c in ("r0", "r1", "r2"):
        entry = summary["final"][c]
        assert entry["value"] == getattr(final, c)
        assert entry["manufacturer"] == getattr(load_train(TRAIN).davis, c)
    i = {"r0": 2, "r1": 3, "r2": 4}
    assert [summary["final"][c]["std"] for c in i] == [float(final.covariance[k, k]) ** 0.5 for k in i.values()]
    assert [r["run_id"] for r in summary["runs"]] == [0, 1]
    closing = [f for f in reference.features if f.run_complete]
    for run, f in zip(summary["runs"], closing):
        assert run["features"]["run_complete"] is True
        assert run["features"]["run_time"] == f.run_time
        assert run["features"]["regime_time_share"] == pytest.approx(list(f.regime_time_share))
    for run in summary["runs"]:  # the effort sources of the run's estimates, by name (no power in this bag)
        sources = [e.effort_source for e in reference.estimates if e.run_id == run["run_id"]]
        assert run["effort_sources"] == {name: sources.count(code) for code, name in enumerate(EFFORT_SOURCES)}
        assert sum(run["effort_sources"].values()) == run["samples"]
        assert run["effort_sources"]["computed"] + run["effort_known_samples"] == run["samples"]
    shares = summary["regime_share"]
    assert sum(shares.values()) == pytest.approx(1.0)
    assert summary["dropped"]["gnss_speed_node"] == {
        "/gnss/fix": {"nan": 1, "no_fix": 1},
        "/train/speed": {"nan": 1, "negative_speed": 1, "stale": 1},
    }
    assert summary["dropped_total"] == 5
    n = len(reference.measurements)
    counts = summary["output_counts"]
    assert counts["/train_calib/measurement"] == counts["/train_calib/resistance"] == counts["/train_calib/regime"] == n
    assert counts["/train_calib/features"] == len(reference.features)
    # the bag has traction power: window_calib_node ran and summary.json has its results
    assert summary["nodes"][-1] == "window_calib_node"
    window = summary["window"]
    assert window["messages"] == counts["/train_calib/window_resistance"] == len(reference.windows)
    well = [f for f in reference.windows if not f.ill_posed]
    assert (window["well_posed"], window["ill_posed"]) == (len(well), len(reference.windows) - len(well))
    assert (window["window_length_s"], window["gof"]) == (60.0, "rmse")
    assert sum(st["windows"] + st["ill_posed"] for st in window["by_regime"].values()) == window["messages"]
    assert summary["input_counts"] == {"/gnss/fix": 340, "/train/speed": 341, "/train/traction_power": 340}
    png = (out / "report.png").read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n"
    width, height = int.from_bytes(png[16:20], "big"), int.from_bytes(png[20:24], "big")
    assert (width, height) == (1350, 2118)  # seven panels against time (power), the profile along s, r(v)
    # summary.json: the configuration, the on-board r(v) with sigma, the whole run's best estimate
    assert summary["ukf_preset"] == "learning"
    for kmh in ("40", "80", "120"):
        on_board, best = summary["final"]["resistance_at_kmh"][kmh], summary["best"]["resistance_at_kmh"][kmh]
        assert on_board["std"] > 0.0 and best["std"] > 0.0
        assert abs(best["value"] - reference.best.resistance(int(kmh) / 3.6)[0]) < 1e-12
    assert summary["best"]["coasting_stretches"] == len(reference.best.stretches)
    # the whole run's regimes: the offline pipeline's (pipeline.whole_run_regimes) from the recorded topics
    whole = [r.regime for r in whole_run_regimes(reference, load_train(TRAIN))]
    on_board = [r.regime for r in reference.regimes]
    regimes = summary["regimes"]
    assert regimes["whole_run"] == {name: whole.count(code) for code, name in enumerate(REGIME_NAMES)}
    assert regimes["on_board"] == {name: on_board.count(code) for code, name in enumerate(REGIME_NAMES)}
    assert regimes["samples_relabelled"] == sum(a != b for a, b in zip(whole, on_board))
    assert regimes["on_board_lag_samples"] == 1  # the default: regime_node publishes one sample late
    # a second replay into the same directory is refused unless --overwrite
    assert cli.main(argv) == 2
    assert "output.mcap: already exists" in capsys.readouterr().err
    assert cli.main([*argv, "--overwrite", "--no-report", "--no-window"]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert "window" not in summary and "/train_calib/window_resistance" not in summary["output_counts"]
    assert summary["nodes"] == ["gnss_speed_node", "ukf_node", "regime_node", "feature_node"]


def test_graph_nodes_start_the_window_node_with_traction_power():
    from train_calib.replay import graph_nodes

    base = ("gnss_speed_node", "ukf_node", "regime_node", "feature_node")
    window = (*base, "window_calib_node")
    assert graph_nodes(base, None, ["/gnss/fix", "/train/speed"]) == base
    assert graph_nodes(base, None, ["/gnss/fix", "/train/speed", "/train/traction_power"]) == window
    assert graph_nodes(window, False, ["/train/traction_power"]) == base  # --no-window
    assert graph_nodes(base, True, ["/gnss/fix"]) == window  # --window: forced (inactive without power)


def _bundled_bags() -> list[Path]:
    folder = paths.bags_dir()
    return (
        sorted(p for p in folder.iterdir() if p.is_dir() and (p / "metadata.yaml").is_file()) if folder.is_dir() else []
    )


@pytest.fixture(scope="module")
def replayed(tmp_path_factory):
    """bundled bag -> (graph outputs as messages, the offline pipeline's), each replayed once per module."""
    from train_calib.commands.replay import load_truth
    from train_calib.replay import ReplayOptions, replay

    cache: dict[Path, tuple] = {}

    def get(bundled: Path):
        if bundled not in cache:
            truth = load_truth(bundled)
            assert truth is not None, f"{bundled}: no truth file beside the bundled bag"
            track = paths.track_file(Path(truth["meta"]["track"]["file"]).stem)
            train = paths.train_file(Path(truth["meta"]["train"]["file"]).stem)
            out = tmp_path_factory.mktemp(bundled.name)
            result = replay(ReplayOptions(bag=bundled, track=str(track), train=str(train), out=out))
            reference = run_bag(bundled, load_track(track), load_train(train))
            cache[bundled] = (result, read_outputs(out), reference, truth)
        return cache[bundled]

    return get


@pytest.mark.parametrize("bundled", _bundled_bags(), ids=lambda p: p.name)
def test_each_bundled_bag_through_the_graph_equals_the_offline_pipeline(bundled, replayed):
    result, outputs, reference, _ = replayed(bundled)
    assert len(reference.estimates) > 50
    assert compare(outputs, reference) == []
    assert result.recorded["/train_calib/resistance"] == len(reference.estimates)
    with_power = "/train/traction_power" in result.sent
    assert ("window_calib_node" in result.nodes) == with_power  # started by the bag's traction power
    assert (result.recorded.get("/train_calib/window_resistance", 0) > 0) == with_power


def _relative_errors(fits, truth, kmh=(40.0, 80.0, 120.0)) -> np.ndarray:
    """|r(v) / r_true(v) - 1| at the reference speeds, one row per window."""
    v = np.asarray(kmh) / 3.6
    true = truth["r0"] + truth["r1"] * v + truth["r2"] * v**2
    return np.array([np.abs((f.r0 + f.r1 * v + f.r2 * v**2) / true - 1.0) for f in fits]).reshape(-1, len(kmh))


def test_fine_speed_bag_gives_well_posed_window_results_close_to_the_truth(replayed):
    """tunnel_line_37km_1s_01 (speed to 0.01 km/h, 1 Hz, power): window_calib_node publishes well-posed windows
    (measured: 15 of 1388, all in traction, RMSE 60 s) whose r(v) is within 15.5 / 6.0 / 18.7 % of the truth at
    40 / 80 / 120 km/h (median 2.3 / 3.2 / 17.3 %). The same line with the 1 km/h speed (_00): none."""
    fine, coarse = paths.bags_dir() / "tunnel_line_37km_1s_01", paths.bags_dir() / "tunnel_line_37km_1s_00"
    if not fine.is_dir():
        pytest.skip(f"{fine} not bundled")
    speeds = [m.decode().twist.linear.x * 3.6 for m in bagio.iter_bag(fine, [bagio.SPEED_TOPIC])]
    assert np.allclose(np.round(np.array(speeds) / 0.01) * 0.01, speeds, rtol=0, atol=1e-9)  # --speed-quantum 0.01
    _, outputs, reference, truth = replayed(fine)
    windows = [window_fit_from_msg(m) for m in outputs["/train_calib/window_resistance"]]
    well = [f for f in windows if not f.ill_posed]
    assert len(windows) == len(reference.windows) > 1000 and len(well) >= 8
    errors = _relative_errors(well, truth)
    assert np.all(errors < 0.25), errors.max(axis=0)  # every published window
    assert np.median(errors[:, 1]) < 0.06  # r(80 km/h)
    assert {f.regime for f in well} == {1}  # traction: the departures and re-accelerations
    _, coarse_outputs, _, _ = replayed(coarse)
    assert coarse_outputs["/train_calib/window_resistance"] and not any(
        not m.ill_posed for m in coarse_outputs["/train_calib/window_resistance"]
    )


def test_bundled_bags_are_present():
    if not _bundled_bags():
        pytest.skip("no bundled bags yet in bags/")
    assert (REPO / "bags" / "intercity_32km_10s_00" / "metadata.yaml").is_file()


def test_whole_run_regimes_take_regime_node_parameters_from_the_params_files(tmp_path):
    """replay's summary.json classifies the whole run with regime_node's parameters as the nodes read them: each
    --params-file in order, a later file's value winning; the defaults where none sets one."""
    from train_calib.commands.replay import regime_parameters
    from train_calib.estimation import RegimeConfig

    first, second = tmp_path / "a.yaml", tmp_path / "b.yaml"
    first.write_text("regime_node:\n  ros__parameters:\n    imm_mean_dwell: 20.0\n    lag_samples: 1\n")
    second.write_text("/**:\n  ros__parameters:\n    imm_mean_dwell: 30.0\n")
    assert regime_parameters([]) == RegimeConfig()
    assert regime_parameters([str(first)]) == RegimeConfig(imm_mean_dwell=20.0, lag_samples=1)
    assert regime_parameters([str(first), str(second)]) == RegimeConfig(imm_mean_dwell=30.0, lag_samples=1)
