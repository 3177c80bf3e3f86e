"""Proof against truth on runs of the product simulator (train_calib.sim): intercity 32 km, virm6, true Davis
coefficients 5-20 % off the train file's, drivers drawn from the papers' ranges, paper sensors (10 s, 4 m,
1 km/h) and 1 Hz (with pantograph power); and the bundled bags. Bounds are the measured values
(docs/estimator.md) with margin.
"""

from __future__ import annotations

import numpy as np
import pytest
from estimation_cases import simulated_run, wrong_prior

from train_calib.estimation import (
    EstimateSeries,
    FeatureConfig,
    RegimeConfig,
    ResistanceEstimator,
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
        paper = estimate_run(ms, train, UKFConfig.paper(), initial=prior).final_davis()
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


def regimes_of(est, cfg: RegimeConfig | None = None):
    """The regimes as the graph publishes them, with the estimate's known-effort flag and r + g."""
    return classify_regimes(
        est.effort,
        est.acceleration,
        cfg or RegimeConfig(),
        speed=est.v,
        effort_known=est.effort_known,
        opposing_force=est.resistance + est.track_force,
    )


@pytest.mark.parametrize(
    "period, power, bound, margin, hold_bound",
    [(10.0, False, 0.87, 0.08, 0.90), (1.0, False, 0.87, 0.04, 0.92), (1.0, True, 0.93, 0.03, 0.96)],
)
def test_regimes_against_the_drivers_labels(period, power, bound, margin, hold_bound):
    """The HMM filter against the simulator's driver-phase labels, four runs (two hold, two traction/coast cycles).
    Measured: 10 s 88.6 % (hold runs 91.5, 93.8; cycles 85.5, 83.2), the paper's rule with hold detection 78.0 %;
    1 Hz 89.0 % (rule 83.4 %); 1 Hz with traction power 94.8 % (rule 89.8 %). What limits it: docs/estimator.md.
    The coasting look-ahead (coast_confirm_ahead) made r less wrong on the cycles runs, which helps the rule (it
    reads the effort a + r + g) more than the HMM: at 1 Hz 79.1 -> 83.4 % and 88.0 -> 89.0 %."""
    right = rule_right = total = 0
    for k in range(4):
        run, ms, _truth, train = simulated_run(k, period, power)
        est = estimate_run(ms, train, UKFConfig.converging())
        reg = regimes_of(est)
        labels = run.truth.regime
        if run.meta["driver"]["cruise_style"] == "hold":
            assert np.mean(reg == labels) > hold_bound
        right += int(np.sum(reg == labels))
        rule_right += int(np.sum(regimes_of(est, RegimeConfig(method="rule", hold_detection=True)) == labels))
        total += labels.size
    assert right / total > bound
    assert (right - rule_right) / total > margin


@pytest.mark.parametrize("period, power, coast_bound", [(10.0, False, 10.0), (1.0, True, 1.0), (1.0, False, 7.0)])
def test_features_against_truth(period, power, coast_bound):
    """Brake rate per step within 0.05 m/s^2, cruise speed within 2 km/h (runs holding the speed), max power within
    10 % where the driver reached at least 70 % of the train's; final brake within one sample period at 10 s (measured
    -5.5..-0.3 s) and 1 s at 1 Hz (-0.2..+0.6 s), against the simulator's exact phases (truth JSON summary); final
    coast within one sample period at 10 s (-8.8..+5.4 s) and at 1 Hz with power (-0.15..+0.9 s: its start and end
    lie in the steps where the traction power ends and the electric brake begins); on GNSS and speed alone at 1 Hz
    -0.6..+6.0 s (the start of a coast on 1 km/h speeds: the data's limit, bench/final_coast_bound.py). Brake rates
    at 1 Hz without power: max error 0.02 m/s^2 (0.18 before the rates stopped at a brake's located end)."""
    fcfg = FeatureConfig()
    for k in range(4):
        run, ms, _truth, train = simulated_run(k, period, power)
        est = estimate_run(ms, train, UKFConfig.converging())
        f = extract_features(est, regimes_of(est), fcfg)
        ft = extract_features(dense_truth_series(run.dense), run.dense.regime, fcfg)
        both = (f.brake_rate_count > 0) & (ft.brake_rate_count > 0)
        assert np.all(np.abs(f.brake_rate_mean - ft.brake_rate_mean)[both] < 0.05)
        if run.meta["driver"]["cruise_style"] == "hold":
            assert abs(f.cruise_speed - ft.cruise_speed) < 2 * KMH
        if ft.max_tractive_power > 0.7 * train.max_tractive_power:  # the driver reached (near) the maximum
            assert abs(f.max_tractive_power / ft.max_tractive_power - 1.0) < 0.10
        summary = run.meta["summary"]
        assert abs(f.final_brake_duration - summary["final_brake_s"]) <= period
        assert abs(f.final_coast_duration - summary["final_coast_s"]) <= coast_bound


def test_power_without_electric_braking_needs_power_coasting_off():
    """Pantograph power of a train without electric brake (nothing regenerated): with power_coasting (the default)
    a brake's first step looks like power coasting and the final brake came out 20-65 s long on half of the 12 proof
    runs (+65 and +41 s on two of these four). With it off, on these four runs, both final phases are within one
    sample period (measured coast -0.9..+0.9 s, its start where the traction power ended; brake -0.2..+0.5 s; over
    the 12 runs 11/12 each, +8.8 s and +3.7 s the misses)."""
    fcfg = FeatureConfig()
    for k in range(4):
        run, ms, _truth, train = simulated_run(k, 1.0, True, electric_brake_fraction=0.0)
        est = estimate_run(ms, train, UKFConfig.converging(power_coasting=False))
        f = extract_features(est, regimes_of(est), fcfg)
        summary = run.meta["summary"]
        assert abs(f.final_brake_duration - summary["final_brake_s"]) <= 1.0
        assert abs(f.final_coast_duration - summary["final_coast_s"]) <= 1.0
    # the estimator says so (ukf_node warns on /diagnostics): braking without regeneration, with power_coasting on
    for fraction, unseen in ((0.0, True), (0.8, False)):
        _run, ms, _truth, train = simulated_run(0, 1.0, True, electric_brake_fraction=fraction)
        for power_coasting in (True, False):
            estimator = ResistanceEstimator(train, UKFConfig.converging(power_coasting=power_coasting))
            estimate_run(ms, train, estimator=estimator)
            assert (estimator.power_braking_unseen() > 0) == (unseen and power_coasting)


def test_bundled_bags_through_the_graph():
    """The bundled bags through the ingest and the core as the node graph runs them (run_bag, converging preset).
    Regimes per sample (imm, the default: published one sample late) against the simulator's per-sample truth,
    measured: 95.4, 96.6, 96.5, 94.9, 91.7 % (10 s; _04 drives traction/coast cycles of 2-4 samples; causal, lag 0:
    93.1, 94.1, 92.2, 92.4, 85.6 %) and 96.4, 98.3 % (1 Hz; mean 95.7 %); the phases (the former regimes, causal
    whatever the lag): 91.6, 91.6, 89.6, 91.5, 90.9, 96.9, 94.4 %. Final brake
    -6.0..+1.5 s (10 s), -0.2 s (1 Hz); final coast within one sample period on four of the five 10 s bags,
    +18.5 s on _00 (the 40 km/h hold before the stop read as coasting), +2.2 s at 1 Hz."""
    from train_calib.paths import bags_dir, track_file, train_file
    from train_calib.pipeline import run_bag
    from train_calib.sim import read_truth
    from train_calib.track import load_track
    from train_calib.train import load_train

    accuracy, coast_ok = [], 0
    bags = sorted(p for p in bags_dir().iterdir() if p.is_dir())
    for bag in bags:
        tf = read_truth(bag)
        track = load_track(track_file(tf.meta["track"]["file"].removesuffix(".yaml")))
        train = load_train(train_file(tf.meta["train"]["file"].removesuffix(".yaml")))
        res = run_bag(bag, track, train, ukf=UKFConfig.converging())
        stamps = np.array([r.stamp_ns for r in res.regimes])
        regimes = np.array([r.regime for r in res.regimes])
        idx = np.searchsorted(tf.truth.t_ns, stamps)
        assert np.array_equal(tf.truth.t_ns[idx], stamps)
        accuracy.append(float(np.mean(tf.truth.regime[idx] == regimes)))
        period = float(tf.meta["sensors"]["speed_period_s"])
        f, summary = res.features[-1], tf.meta["summary"]
        assert f.run_complete and abs(f.final_brake_duration - summary["final_brake_s"]) <= period
        coast_err = abs(f.final_coast_duration - summary["final_coast_s"])
        if period >= 10.0:
            assert coast_err < 30.0
            coast_ok += coast_err <= period
        else:
            assert coast_err < 4.0  # measured 2.2 s: one sample period (1 s) is not reached at 1 Hz
    assert min(accuracy) > 0.90 and np.mean(accuracy) > 0.945, accuracy
    assert coast_ok >= 4  # of the five 10 s bags
