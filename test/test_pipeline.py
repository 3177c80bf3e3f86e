"""The offline pipeline: the chain of the nodes without ROS, checked against the estimator's and the window
calibration's whole-run APIs."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from train_calib import paths
from train_calib.estimation import (
    COASTING,
    TRACTION,
    UKFConfig,
    classify_regimes,
    estimate_run,
    features_per_run,
)
from train_calib.measurement import MeasurementSeries
from train_calib.pipeline import FeatureStream, bag_messages, run_bag, run_measurements
from train_calib.track import load_track
from train_calib.train import load_train

BAG = paths.bags_dir() / "intercity_32km_10s_01"


@pytest.fixture(scope="module")
def track_train():
    if not BAG.is_dir():
        pytest.skip(f"{BAG} not bundled yet")
    return load_track(paths.track_file("intercity_32km")), load_train(paths.train_file("virm6"))


@pytest.fixture(scope="module")
def measurements(track_train):
    """The bag through the ingest alone, in the replay's order."""
    from train_calib.pipeline import Pipeline

    track, train = track_train
    p = Pipeline(track, train)
    for topic, msg in bag_messages(BAG):
        p.add_message(topic, msg)
    return p.end_of_input().measurements


@pytest.mark.parametrize("preset", ["paper", "converging"])
def test_chain_equals_the_whole_run_apis_of_the_estimator(track_train, measurements, preset):
    """Per-sample chain == estimate_run (UKF), classify_regimes (vectorised rule), features_per_run."""
    _, train = track_train
    cfg = UKFConfig.preset(preset)
    out = run_measurements(measurements, train, ukf=cfg)
    series = estimate_run(MeasurementSeries.from_measurements(measurements), train, cfg)
    assert len(out.estimates) == len(series) == len(measurements) > 100
    for name in ("s", "v", "r0", "r1", "r2", "effort", "acceleration", "nis", "health"):
        assert np.array_equal([getattr(e, name) for e in out.estimates], getattr(series, name)), name
    assert np.array_equal(np.array([e.covariance for e in out.estimates]), series.covariance)
    w = series.resistance + series.track_force  # the force the effort works against (regime_node passes it)
    regimes, phases = classify_regimes(
        series.effort, series.acceleration, speed=series.v, effort_known=series.effort_known, opposing_force=w,
        speed_measured=series.v_measured, time=series.stamp_ns * 1e-9, phase=True,
    )  # fmt: skip
    assert np.array_equal([r.regime for r in out.regimes], regimes)
    assert np.array_equal([r.phase for r in out.regimes], phases)
    assert {TRACTION, COASTING} <= set(regimes.tolist())
    closing = [f for f in out.features if f.run_complete]
    whole = features_per_run(series, phases)  # the features follow the paper's phase
    assert len(closing) == len(whole) == len(set(series.run_id.tolist()))
    for got, want in zip(closing, whole):
        for name in ("run_time", "run_distance", "max_tractive_effort", "max_tractive_power", "cruise_speed",
                     "final_coast_duration", "final_brake_duration"):  # fmt: skip
            assert getattr(got, name) == pytest.approx(getattr(want, name), rel=1e-9, abs=1e-12, nan_ok=True), name
        assert np.allclose(got.regime_time_share, want.regime_time_share, rtol=1e-9, atol=1e-12)
        assert np.allclose(got.brake_rate_mean, want.brake_rate_mean, rtol=1e-9, equal_nan=True)


def test_run_bag_is_ingest_then_chain(track_train, measurements):
    track, train = track_train
    out = run_bag(BAG, track, train)
    assert [m.stamp_ns for m in out.measurements] == [m.stamp_ns for m in measurements]
    assert out.ingest_stats.published == len(measurements)
    dropped = out.ingest_stats.dropped_total()
    assert (
        out.ingest_stats.received["speed"]
        == out.ingest_stats.accepted["speed"]
        + out.ingest_stats.dropped["speed"].total()
        - out.ingest_stats.dropped["speed"]["no_position"]
    )
    assert dropped == sum(sum(c.values()) for c in out.ingest_stats.dropped.values())


@pytest.fixture(scope="module")
def synthetic(tmp_path_factory):
    """The nodes tests' synthetic bag (1 Hz, traction power, two runs) without bad samples, its track and train."""
    import sys
    from pathlib import Path

    from repo_paths import DATA

    sys.path.insert(0, str(Path(__file__).parent / "nodes"))
    from synthetic_bag import write_bag

    bag = write_bag(tmp_path_factory.mktemp("synthetic") / "bag", bad=False)
    return bag, load_track(DATA / "small_track.yaml"), load_train(DATA / "small_train.yaml")


def test_regimes_get_effort_known_and_the_opposing_force(synthetic):
    """regime_node's call (classify_estimate): with traction power and the converging filter the effort is known on
    many samples, and the keywords change the regimes (so they are really passed)."""
    bag, track, train = synthetic
    out = run_bag(bag, track, train, ukf=UKFConfig.converging(), window=False)
    e = out.estimates
    effort, accel, v = ([getattr(x, n) for x in e] for n in ("effort", "acceleration", "v"))
    known = [x.effort_known for x in e]
    w = [x.resistance + x.track_force for x in e]
    _, with_keywords = classify_regimes(effort, accel, speed=v, effort_known=known, opposing_force=w, phase=True)
    assert [r.phase for r in out.regimes] == with_keywords.tolist()
    _, plain = classify_regimes(effort, accel, speed=v, phase=True)
    assert sum(known) > 50 and np.count_nonzero(plain != with_keywords) > 10  # measured: 87 known, 27 differ


def test_window_calibration_after_the_regime_equals_calibrate_series(synthetic, tmp_path):
    """Pipeline's window results (window_calib_node's) == WindowCalibrator over the measurements with the pipeline's
    regimes; without power there are none, and window=False leaves it out."""
    from synthetic_bag import write_bag

    from train_calib.window import WindowConfig, calibrate_series

    bag, track, train = synthetic
    config = WindowConfig(window_length=30.0, gof="sae", max_relative_error=1e3)  # the kinematic profile: noise
    out = run_bag(bag, track, train, window=config)
    assert len(out.estimates) == len(out.measurements)  # no measurement rejected: one regime each
    series = MeasurementSeries.from_measurements(out.measurements)
    expected = calibrate_series(series, train, config, regimes=[r.phase for r in out.regimes])  # the node's input
    assert len(out.windows) == len(expected) > 300
    for got, want in zip(out.windows, expected):  # every field exactly, NaN equal to NaN
        for f in dataclasses.fields(got):
            x, y = np.asarray(getattr(got, f.name)), np.asarray(getattr(want, f.name))
            assert x.shape == y.shape and np.all((x == y) | (x != x) & (y != y)), f.name
    assert any(not f.ill_posed for f in out.windows)
    assert run_bag(bag, track, train, window=False).windows == []
    assert run_bag(write_bag(tmp_path / "nopower", power=False, bad=False), track, train).windows == []


class _Sample:
    def __init__(self, t, run_id, v=20.0, effort=0.0, acceleration=0.0):
        self.stamp_ns, self.run_id, self.s, self.v = int(t * 1e9), run_id, 20.0 * t, v
        self.effort, self.acceleration = effort, acceleration


def test_feature_stream_publishes_on_regime_changes_and_closes_each_run_once():
    stream = FeatureStream()
    regimes = [TRACTION, TRACTION, COASTING, COASTING, TRACTION]
    published = []
    for k, regime in enumerate(regimes):
        published.append(len(stream.update(_Sample(k, 0), regime)))
    assert published == [1, 0, 1, 0, 1]  # first sample of the run, then each change
    # a new run closes the previous one first (run_complete), then starts the new run
    first_of_next = stream.update(_Sample(10, 1), TRACTION)
    assert [f.run_complete for f in first_of_next] == [True, False]
    assert first_of_next[0].run_id == 0 and first_of_next[0].stamp_ns == int(4e9)
    assert first_of_next[1].run_id == 1
    end = stream.end_of_input()
    assert [(f.run_id, f.run_complete) for f in end] == [(1, True)]
    assert stream.end_of_input() == []  # once
    assert stream.runs_completed == 2
