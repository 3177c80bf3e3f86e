"""Feature extraction: incremental = whole run, exact values on exact inputs, UKF features vs truth, fleet stats."""

from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
import pytest
from conftest import synthetic_run
from synthetic import Script, integrate, sample, virm_like_train

from train_calib.estimation import (
    BRAKING,
    COASTING,
    CRUISING,
    TRACTION,
    UNKNOWN,
    EstimateSeries,
    FeatureAccumulator,
    FeatureConfig,
    RegimeConfig,
    UKFConfig,
    classify_regimes,
    estimate_run,
    extract_features,
    features_per_run,
    fleet_statistics,
)
from train_calib.estimation.features import Features
from train_calib.physics import KMH


def truth_series(dense: dict) -> tuple[EstimateSeries, np.ndarray]:
    n = dense["t"].size
    est = EstimateSeries.empty(n)
    est.stamp_ns[:] = np.round(dense["t"] * 1e9).astype(np.int64)
    est.s[:], est.v[:], est.effort[:], est.acceleration[:] = dense["s"], dense["v"], dense["u"], dense["a"]
    est.dt[1:] = np.diff(dense["t"])
    return est, dense["regime"].astype(np.uint8)


def incremental(est: EstimateSeries, regimes, cfg: FeatureConfig) -> tuple[Features, list[bool]]:
    acc = FeatureAccumulator(cfg)
    changed = [acc.update(est.sample(i), int(regimes[i])) for i in range(len(est))]
    return acc.snapshot(run_complete=True), changed


def assert_same_features(a: Features, b: Features, rtol: float = 1e-9):
    for f in dataclasses.fields(Features):
        x, y = getattr(a, f.name), getattr(b, f.name)
        if isinstance(x, (np.ndarray, float)):
            np.testing.assert_allclose(x, y, rtol=rtol, atol=1e-12, equal_nan=True, err_msg=f.name)
        else:
            assert x == y, f.name


@pytest.mark.parametrize(
    "cfg",
    [
        FeatureConfig(),
        FeatureConfig(phase_merge_gap=0.0, final_coast_min_duration=0.0, cruise_min_duration=0.0, brake_window=0.0),
        FeatureConfig(phase_merge_gap=60.0, final_brake_min_duration=15.0, brake_window=30.0),
    ],
)
def test_whole_run_equals_incremental(cfg):
    train, truth, series = synthetic_run(2, 10.0)
    est = estimate_run(series, train, UKFConfig.converging())
    for regimes in (
        classify_regimes(est.effort, est.acceleration, speed=est.v),
        truth.regime,
        np.random.default_rng(0).integers(0, 5, len(est)).astype(np.uint8),
    ):
        whole = extract_features(est, regimes, cfg)
        inc, _ = incremental(est, regimes, cfg)
        assert_same_features(whole, inc)


def test_exact_features_of_the_exact_motion():
    """On the dense noise-free truth (0.1 s) the features are the script's numbers."""
    train = virm_like_train()
    script = Script(cruise_speed=130 * KMH, cruise_time=200.0, coast_until_speed=90 * KMH)
    dense = integrate(train, train.davis, script)
    est, regimes = truth_series(dense)
    cfg = FeatureConfig(brake_window=1.0)
    f = extract_features(est, regimes, cfg)
    # brake rates per ATB-EG step: the scripted 0.55 below 40, 0.45 for 40-80, 0.35 above 80 km/h
    np.testing.assert_allclose(f.brake_rate_mean[:4], [0.55, 0.45, 0.45, 0.35], atol=1e-9)
    assert f.brake_rate_count[4] == 0 and math.isnan(f.brake_rate_mean[4])
    np.testing.assert_allclose(f.brake_rate_std[:4], 0.0, atol=1e-9)
    assert f.cruise_speed == pytest.approx(130 * KMH, abs=0.02)
    assert f.cruise_speeds.size == 1
    # max effort: the envelope is flat (0.9 N/kg) below the 38 km/h transition
    assert f.max_tractive_effort == pytest.approx(0.9, abs=1e-9)
    assert f.max_tractive_effort_slope == pytest.approx(0.0, abs=1e-9)
    # max power: u * v = c2 in the power regime (50-130 km/h), up to the mid-step speed
    assert f.max_tractive_power == pytest.approx(train.max_tractive_power, rel=1e-3)
    t = dense["t"]
    coast = t[dense["regime"] == COASTING]
    brake = t[(dense["regime"] == BRAKING) & (dense["v"] >= 0.3)]  # standing (v < 0.3 m/s) is not braking
    assert f.final_coast_duration == pytest.approx(coast[-1] - coast[0], abs=0.11)
    assert f.final_brake_duration == pytest.approx(brake[-1] - brake[0], abs=0.21)
    assert f.regime_time_share.sum() == pytest.approx(1.0)
    assert f.regime_time_share[CRUISING] * f.run_time == pytest.approx(200.0, abs=0.2)


def truth_features(dense: dict, cfg: FeatureConfig) -> Features:
    est, regimes = truth_series(dense)
    return extract_features(est, regimes, cfg)


@pytest.mark.parametrize("period", [10.0, 1.0])
def test_features_of_the_estimate_against_truth(period):
    """UKF estimates -> regimes -> features, vs the same features of the truth (tolerances of the issue)."""
    train = virm_like_train()
    script = Script(cruise_time=250.0, coast_until_speed=85 * KMH)
    dense = integrate(train, train.davis, script)
    cfg = FeatureConfig()
    f_true = truth_features(dense, cfg)
    for seed in range(3):
        _truth, series = sample(dense, period, np.random.default_rng(seed), train.davis, speed_noise_std=0.14)
        est = estimate_run(series, train, UKFConfig.converging())
        regimes = classify_regimes(est.effort, est.acceleration, RegimeConfig(hold_detection=True), speed=est.v)
        f = extract_features(est, regimes, cfg)
        both = (f.brake_rate_count > 0) & (f_true.brake_rate_count > 0)
        assert both.sum() >= (1 if period > 5 else 3)  # at 10 s a 20 km/h step holds few clean samples
        assert np.all(np.abs(f.brake_rate_mean - f_true.brake_rate_mean)[both] < 0.05)
        assert abs(f.cruise_speed - f_true.cruise_speed) < 2 * KMH
        assert abs(f.max_tractive_power - f_true.max_tractive_power) < 0.1 * f_true.max_tractive_power
        # one sample period at 10 s; at 1 Hz the 10 s acceleration window delays a phase change by up to half of it
        # (measured: coast -5.4..-0.4 s, brake -2.4..1.6 s over six seeds)
        assert abs(f.final_coast_duration - f_true.final_coast_duration) <= max(period, 6.0) + 1e-6
        assert abs(f.final_brake_duration - f_true.final_brake_duration) <= max(period, 3.0) + 1e-6


def test_no_data_gives_nan_and_zero_counts():
    acc = FeatureAccumulator()
    f = acc.snapshot()
    assert math.isnan(f.max_tractive_effort) and f.max_tractive_effort_count == 0
    assert math.isnan(f.max_tractive_power) and f.max_tractive_power_count == 0
    assert f.brake_rate_count.tolist() == [0] * 5 and np.isnan(f.brake_rate_mean).all()
    assert f.brake_step_high[-1] == math.inf and f.brake_step_low[0] == 0.0
    assert f.regime_time_share.tolist() == [0.0] * 5 and f.cruise_speeds.size == 0
    assert math.isnan(f.final_coast_duration) and math.isnan(f.cruise_speed)
    json.dumps(f.as_dict())  # NaN/inf-free except inf step bound -> allowed by json


def test_update_reports_regime_changes_and_new_runs():
    train, truth, series = synthetic_run(2, 10.0)
    est = estimate_run(series, train, UKFConfig())
    _, changed = incremental(est, truth.regime, FeatureConfig())
    eff = truth.regime.copy()
    v_mid = np.r_[est.v[0], 0.5 * (est.v[1:] + est.v[:-1])]
    eff[v_mid < 0.3] = UNKNOWN
    expected = [True] + [bool(a != b) for a, b in zip(eff[1:], eff[:-1])]
    assert changed == expected
    acc = FeatureAccumulator()
    acc.update(est.sample(5), TRACTION)
    first_of_next = dataclasses.replace(est.sample(6), run_id=7)
    assert acc.update(first_of_next, TRACTION) is True
    assert acc.snapshot().run_id == 7 and acc.snapshot().run_time == 0.0


def test_features_per_run_and_input_checks():
    train, truth, series = synthetic_run(2, 10.0)
    est = estimate_run(series, train, UKFConfig())
    n = len(est)
    two = EstimateSeries(**{f.name: np.concatenate([getattr(est, f.name)] * 2) for f in dataclasses.fields(est)})
    two.stamp_ns[n:] += two.stamp_ns[n - 1] + 10**12
    two.run_id[n:] = 3
    regimes = np.concatenate([truth.regime] * 2)
    runs = features_per_run(two, regimes)
    assert [r.run_id for r in runs] == [0, 3]
    assert_same_features(runs[0], extract_features(est, truth.regime))
    with pytest.raises(ValueError, match="several run_ids"):
        extract_features(two, regimes)
    with pytest.raises(ValueError, match="shape"):
        extract_features(est, regimes)


def test_fleet_statistics():
    runs = []
    for i, coast in enumerate([100.0, 200.0, 300.0, math.nan]):
        f = Features(run_id=i, final_coast_duration=coast, max_tractive_power=5.0 + i)
        f.brake_step_low = np.array([0.0, 10.0])
        f.brake_step_high = np.array([10.0, np.inf])
        f.brake_rate_mean = np.array([0.5, 0.3 + 0.1 * i])
        f.regime_time_share = np.array([0.0, 0.2, 0.2, 0.5, 0.1])
        f.cruise_speeds = np.array([30.0 + i])
        runs.append(f)
    st = fleet_statistics(runs, bins=4)
    coast = st["final_coast_duration"]
    assert coast.count == 3 and coast.mean == pytest.approx(200.0) and coast.std == pytest.approx(100.0)
    assert coast.cv == pytest.approx(0.5) and coast.minimum == 100.0 and coast.maximum == 300.0
    assert coast.hist_counts.sum() == 3 and coast.hist_edges.size == 5
    power = st["max_tractive_power"]
    assert power.count == 4 and power.mean == pytest.approx(6.5)
    assert st["brake_rate_0_36kmh"].mean == pytest.approx(0.5) and st["brake_rate_0_36kmh"].cv == 0.0
    assert st["brake_rate_36_infkmh"].count == 4
    assert st["time_share_coasting"].mean == pytest.approx(0.5)
    assert st["cruise_speeds_all"].count == 4
    assert st["cruise_speed"].count == 0 and math.isnan(st["cruise_speed"].mean)
    assert "| final_coast_duration | s | 3 | 200 |" in st.table()
    assert fleet_statistics([]).runs == 0
