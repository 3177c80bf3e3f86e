"""Proof against truth on runs of the product simulator (train_calib.sim): intercity 32 km, virm6, true Davis
coefficients 5-20 % off the train file's, drivers drawn from the papers' ranges, paper sensors (10 s, 4 m,
1 km/h) and 1 Hz (with pantograph power). Bounds are the measured values (docs/estimator.md) with margin.
"""

from __future__ import annotations

import numpy as np
import pytest
from conftest import simulated_run, wrong_prior

from train_calib.estimation import (
    EstimateSeries,
    FeatureConfig,
    RegimeConfig,
    UKFConfig,
    classify_regimes,
    estimate_run,
    extract_features,
)
from train_calib.physics import KMH

pytest.importorskip("train_calib.sim")


def r_errors(est, truth) -> np.ndarray:
    d = est.final_davis()
    return np.array([(d(v * KMH) - truth(v * KMH)) / truth(v * KMH) for v in (40.0, 80.0, 120.0)])


def dense_truth_series(dense) -> EstimateSeries:
    out = EstimateSeries.empty(len(dense))
    out.stamp_ns[:] = dense.t_ns
    out.s[:], out.v[:], out.effort[:], out.acceleration[:] = dense.s, dense.v, dense.u, dense.a
    out.dt[1:] = np.diff(dense.t_ns) * 1e-9
    return out


@pytest.mark.parametrize("period, power, bound80, bound120", [(10.0, False, 0.10, 0.08), (1.0, True, 0.04, 0.03)])
def test_converging_preset_corrects_a_20_percent_wrong_prior(period, power, bound80, bound120):
    """From the truth x (1 +- 20 %): r(v) at 80 and 120 km/h within the bounds at the end of the run.

    Measured (12 runs, bench_whole_run.py): 10 s mean |error| 2.0 % / 1.8 % (max 8 %); 1 Hz with power
    1.1 % / 0.7 %. The paper's Table 1 filter stays at the prior (its r covariances are ~1e-4 relative).
    """
    errs, paper_moves = [], []
    for k in range(4):
        _run, ms, truth, train = simulated_run(k, period, power)
        prior = wrong_prior(truth, k)
        errs.append(r_errors(estimate_run(ms, train, UKFConfig.converging(), initial=prior), truth))
        paper = estimate_run(ms, train, UKFConfig(), initial=prior).final_davis()
        paper_moves.append(max(abs(a / b - 1.0) for a, b in zip(paper.as_tuple(), prior.as_tuple())))
    errs = np.abs(np.array(errs))
    assert errs[:, 1].max() < bound80 and errs[:, 2].max() < bound120
    assert max(paper_moves) < 0.01


def test_known_effort_is_what_makes_r_identifiable():
    """Converging preset without exploiting known effort (computed effort, r a consider parameter) learns nothing;
    with the paper's coupling and wide prior covariances it wanders (the identifiability caution)."""
    _run, ms, truth, train = simulated_run(1, 10.0)
    prior = wrong_prior(truth, 0)
    frozen = estimate_run(ms, train, UKFConfig.converging(effort_mode="computed"), initial=prior)
    assert frozen.final_davis() == prior
    known = r_errors(estimate_run(ms, train, UKFConfig.converging(), initial=prior), truth)
    assert np.abs(known[1:]).max() < 0.08 < np.abs(r_errors(frozen, truth)[1:]).min()


@pytest.mark.parametrize("period", [10.0, 1.0])
def test_regimes_against_the_rule_on_the_true_signals(period):
    """Estimated regimes agree with the rule applied to the TRUE effort and acceleration (measured 88-91 %);
    against the simulator's driver-intent labels the rule itself is the ceiling (78-86 %, docs)."""
    cm_rule = cm_label = 0
    total = 0
    rcfg = RegimeConfig(hold_detection=True)
    for k in range(3):
        run, ms, _truth, train = simulated_run(k, period)
        est = estimate_run(ms, train, UKFConfig.converging())
        reg = classify_regimes(est.effort, est.acceleration, rcfg, speed=est.v)
        t = run.truth
        rule = classify_regimes(t.u, t.a, rcfg, speed=t.v)
        cm_rule += int(np.sum(rule == reg))
        cm_label += int(np.sum(t.regime == reg))
        total += reg.size
    assert cm_rule / total > (0.84 if period > 5 else 0.87)
    assert cm_label / total > 0.50  # measured 55 % (10 s) and 61 % (1 Hz) on these three runs (two drive cycles)


@pytest.mark.parametrize("period, power", [(10.0, False), (1.0, True)])
def test_features_against_truth(period, power):
    """Brake rate per step within 0.05 m/s^2, cruise speed within 2 km/h (runs holding the speed), max power
    within 10 % where the driver reached at least 70 % of the train's, final brake within one sample period at
    10 s (3 s at 1 Hz)."""
    fcfg = FeatureConfig()
    rcfg = RegimeConfig(hold_detection=True)
    for k in range(3):
        run, ms, _truth, train = simulated_run(k, period, power)
        est = estimate_run(ms, train, UKFConfig.converging())
        f = extract_features(est, classify_regimes(est.effort, est.acceleration, rcfg, speed=est.v), fcfg)
        ft = extract_features(dense_truth_series(run.dense), run.dense.regime, fcfg)
        both = (f.brake_rate_count > 0) & (ft.brake_rate_count > 0)
        assert np.all(np.abs(f.brake_rate_mean - ft.brake_rate_mean)[both] < 0.05)
        if run.meta["driver"]["cruise_style"] == "hold":
            assert abs(f.cruise_speed - ft.cruise_speed) < 2 * KMH
        if ft.max_tractive_power > 0.7 * train.max_tractive_power:  # the driver reached (near) the maximum
            assert abs(f.max_tractive_power / ft.max_tractive_power - 1.0) < 0.10
        assert abs(f.final_brake_duration - ft.final_brake_duration) <= max(period, 3.0) + 1e-6
