"""The offline pipeline: the chain of the nodes without ROS, checked against the estimator's whole-run APIs."""

from __future__ import annotations

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
    regimes = classify_regimes(series.effort, series.acceleration, speed=series.v)
    assert np.array_equal([r.regime for r in out.regimes], regimes)
    assert {TRACTION, COASTING} <= set(regimes.tolist())
    closing = [f for f in out.features if f.run_complete]
    whole = features_per_run(series, regimes)
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
