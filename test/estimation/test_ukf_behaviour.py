"""ResistanceEstimator behaviour: whole run = per sample, runs, gaps, health, safeguards, configuration."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from estimation_cases import synthetic_run, wrong_prior
from synthetic import add_power

from train_calib.errors import ConfigError
from train_calib.estimation import (
    COASTING,
    EFFORT_COASTING,
    EFFORT_COMPUTED,
    EFFORT_POWER,
    EFFORT_POWER_COASTING,
    HEALTH_DEGRADED,
    HEALTH_OK,
    HEALTH_REPAIRED,
    HEALTH_RESET,
    EstimateSeries,
    ResistanceEstimator,
    UKFConfig,
    estimate_run,
)
from train_calib.estimation.covariance import pack, project_nonnegative, repair, unpack
from train_calib.estimation.ukf import Prediction, StepInput, StepResult, TraceStep
from train_calib.measurement import MeasurementSeries
from train_calib.train import Davis


def copy_series(series: MeasurementSeries) -> MeasurementSeries:
    return MeasurementSeries(**{f.name: getattr(series, f.name).copy() for f in dataclasses.fields(series)})


def two_runs_with_gaps(power: bool = True) -> tuple:
    train, truth, series = synthetic_run(1, 10.0)
    s = copy_series(series)
    if power:
        add_power(s, truth, train, np.random.default_rng(0))
        s.power_valid[::7] = False
    s.s_measured[40:46] = False
    n = len(s)
    both = MeasurementSeries(
        **{
            f.name: np.concatenate([getattr(s, f.name), getattr(s, f.name)])
            for f in dataclasses.fields(MeasurementSeries)
        }
    )
    both.stamp_ns[n:] += both.stamp_ns[n - 1] + 600_000_000_000
    both.run_id[n:] = 1
    return train, both


@pytest.mark.parametrize("preset", ["paper", "converging"])
def test_estimate_run_equals_per_sample_updates(preset):
    """Identical numbers (bit for bit) from update() per sample and estimate_run(), over two runs with gaps."""
    train, series = two_runs_with_gaps()
    cfg = UKFConfig.preset(preset, carry_over="keep")
    prior = wrong_prior(train.davis, 3)
    batch = estimate_run(series, train, cfg, initial=prior)
    est = ResistanceEstimator(train, cfg, prior)
    online = EstimateSeries.from_samples([est.update(m) for m in series])
    for f in dataclasses.fields(EstimateSeries):
        if f.name == "decoupled":
            continue
        a, b = getattr(batch, f.name), getattr(online, f.name)
        assert np.array_equal(a, b), f.name
    assert np.array_equal(est.state, batch.state[-1])
    assert np.array_equal(est.covariance, batch.covariance[-1])


def test_process_and_the_trace_api():
    """process(StepInput) -> StepResult (named, the packed covariance with it) equals update() field for field; with
    look-ahead, record_trace() gives one TraceStep per sample the resistance filter used, behind the published r."""
    train, series = two_runs_with_gaps()
    cfg = UKFConfig.converging()
    a, b = ResistanceEstimator(train, cfg), ResistanceEstimator(train, cfg)
    assert a.has_lookahead and a.trace is None
    trace = a.record_trace()
    for m in series:
        r, sample = a.process(StepInput.from_measurement(m)), b.update(m)
        assert isinstance(r, StepResult) and r._fields[:3] == ("s", "v", "r0")
        assert np.array_equal(unpack(r.covariance), sample.covariance)
        assert (r.s, r.v, r.r0, r.r1, r.r2, r.effort, r.nis, r.health) == (
            sample.s,
            sample.v,
            sample.r0,
            sample.r1,
            sample.r2,
            sample.effort,
            sample.nis,
            sample.health,
        )
        assert (r.effort_source != EFFORT_COMPUTED) == sample.effort_known
    a.flush()
    assert a.trace is trace and [t.arrival for t in trace] == list(range(1, len(series) + 1))
    assert all(isinstance(t, TraceStep) and len(t.x) == 5 and len(t.covariance) == 15 for t in trace)
    assert sum(t.effort_known for t in trace) > 0
    assert trace[-1].x[2:] == tuple(a.state[2:])  # the published r is the resistance filter's
    # predict(): the resistance filter's prediction, the filter itself untouched
    x, p = trace[10].x, trace[10].covariance
    pred = a.predict(x, p, 10.0, 0.0, 0.0, False)
    assert isinstance(pred, Prediction) and pred.x[0] > x[0] and pred.x[1] < x[1]  # coasting on the level: slower
    assert a.predict(x, tuple([0.0] * 15), 10.0, 0.0, 0.0, False) is None
    assert trace[-1].x[2:] == tuple(a.state[2:])


def test_outputs_finite_nonnegative_symmetric_pd():
    train, series = two_runs_with_gaps()
    for cfg in (UKFConfig(), UKFConfig.converging(), UKFConfig.converging(nonnegative="clip")):
        est = estimate_run(series, train, cfg, initial=wrong_prior(train.davis, 1))
        for name in ("s", "v", "r0", "r1", "r2", "effort", "acceleration", "resistance", "nis"):
            assert np.all(np.isfinite(getattr(est, name))), name
        assert np.all(est.state[:, 1:] >= 0.0)
        cov = est.covariance
        assert np.array_equal(cov, np.swapaxes(cov, 1, 2))
        assert np.all(np.linalg.eigvalsh(cov / np.sqrt(np.einsum("kii,kjj->kij", cov, cov))) > 0.0)


def test_new_run_resets_or_keeps_resistance():
    train, series = two_runs_with_gaps(power=False)
    n = len(series) // 2
    prior = wrong_prior(train.davis, 0)
    reset = estimate_run(series, train, UKFConfig.converging(carry_over="reset"), initial=prior)
    keep = estimate_run(series, train, UKFConfig.converging(carry_over="keep"), initial=prior)
    assert reset.state[n, 2:].tolist() == list(prior.as_tuple())
    assert np.array_equal(keep.state[n, 2:], keep.state[n - 1, 2:])
    assert np.array_equal(keep.covariance[n, 2:, 2:], keep.covariance[n - 1, 2:, 2:])
    assert keep.health[n] == HEALTH_OK and keep.dt[n] == 0.0  # a new run is not a fault
    # the first run is identical in both
    assert np.array_equal(reset.state[:n], keep.state[:n])


def test_reset_api_and_carry_over_inflation():
    train, _truth, series = synthetic_run(1, 10.0)
    est = ResistanceEstimator(train, UKFConfig.converging(carry_over_inflation=4.0))
    for m in series:
        est.update(m)
    r_end, p_end = est.state[2:].copy(), est.covariance[2:, 2:].copy()
    est.reset(keep_resistance=True)
    first = est.update(series[0])
    assert np.allclose(first.state[2:], r_end) and np.allclose(first.covariance[2:, 2:], 4.0 * p_end)
    est.reset(keep_resistance=False)
    again = est.update(series[0])
    assert again.state[2:].tolist() == list(train.davis.as_tuple())
    assert np.isnan(ResistanceEstimator(train).state).all()


def test_gap_longer_than_max_dt_reinitialises_and_keeps_r():
    train, _truth, series = synthetic_run(1, 10.0)
    s = copy_series(series)
    s.stamp_ns[30:] += 500_000_000_000  # 500 s gap
    est = estimate_run(s, train, UKFConfig.converging())
    assert est.health[30] == HEALTH_RESET
    assert np.array_equal(est.state[30, 2:], est.state[29, 2:])
    assert est.s[30] == s.s[30] and est.v[30] == s.v[30]
    assert np.all(est.health[31:] != HEALTH_RESET)


def test_position_not_measured_updates_speed_only():
    train, _truth, series = synthetic_run(1, 10.0)
    s = copy_series(series)
    s.s_measured[50] = False
    s.s[50] += 5000.0  # a wrong dead-reckoned position must not move the filter
    ref = estimate_run(series, train, UKFConfig())
    est = estimate_run(s, train, UKFConfig())
    assert abs(est.s[50] - ref.s[50]) < 10.0
    assert est.nis[50] < 20.0


def test_invalid_and_out_of_order_samples_are_counted_and_ignored():
    train, _truth, series = synthetic_run(1, 10.0)
    est = ResistanceEstimator(train, UKFConfig.converging())
    out = [est.update(series[i]) for i in range(20)]
    before = est.state.copy()
    bad = [
        dataclasses.replace(series[20], v=math.nan),
        dataclasses.replace(series[20], v=-1.0),
        dataclasses.replace(series[20], track_force=math.inf),
        dataclasses.replace(series[5]),  # older than the last
    ]
    for m in bad:
        e = est.update(m)
        assert np.all(np.isfinite(e.state)) and e.health == HEALTH_OK
    assert np.array_equal(est.state, before)
    assert est.counters["invalid_input"] == 4
    nan_s = est.update(dataclasses.replace(series[20], s=math.nan))  # position NaN: speed-only update
    assert np.all(np.isfinite(nan_s.state)) and est.counters["position_missing"] == 1
    same = est.update(dataclasses.replace(series[20]))  # same stamp: update without prediction
    assert same.dt == 0.0 and est.counters["nonpositive_dt"] == 1
    assert out[-1].health == HEALTH_OK


def test_non_positive_definite_covariance_is_repaired_and_counted():
    train, _truth, series = synthetic_run(1, 10.0)
    est = ResistanceEstimator(train, UKFConfig.converging())
    for i in range(30):
        est.update(series[i])
    bad = est.covariance
    bad[2, 4] = bad[4, 2] = 1.5 * math.sqrt(bad[2, 2] * bad[4, 4])  # correlation 1.5: not positive definite
    est._rf.P = pack(bad)  # the resistance filter's (it owns r; with look-ahead it runs one sample behind here)
    sample = est.update(series[30])
    assert sample.health == HEALTH_REPAIRED and est.counters["repairs"] == 1
    assert np.all(np.linalg.eigvalsh(sample.covariance) > 0.0)
    assert np.all(np.isfinite(sample.state))


def test_nan_covariance_resets_to_the_prior():
    train, _truth, series = synthetic_run(1, 10.0)
    est = ResistanceEstimator(train, UKFConfig.converging(), wrong_prior(train.davis, 0))
    for i in range(30):
        est.update(series[i])
    est._rf.P = tuple([math.nan] * 15)
    sample = est.update(series[30])
    assert sample.health == HEALTH_RESET and est.counters["resets"] == 1
    assert sample.state[2:].tolist() == list(est.prior.as_tuple())
    assert np.all(np.isfinite(sample.covariance))
    assert est.update(series[31]).health in (HEALTH_OK, HEALTH_DEGRADED)


def test_repair_keeps_variances_and_floors_correlation_eigenvalues():
    rng = np.random.default_rng(1)
    a = rng.normal(size=(5, 5))
    p = a @ a.T * np.outer([10, 1, 1e-3, 1e-5, 1e-6], [10, 1, 1e-3, 1e-5, 1e-6])
    d = np.sqrt(np.diag(p))
    c = p / np.outer(d, d)
    w, v = np.linalg.eigh(c)
    bad = (v * np.r_[-0.3, w[1:]]) @ v.T * np.outer(d, d)
    fixed = unpack(repair(pack(bad), 1e-6))
    assert np.allclose(np.diag(fixed), np.diag(bad), rtol=1e-12)
    corr = fixed / np.outer(d, d)
    assert np.linalg.eigvalsh(corr).min() > 0.0
    assert repair(tuple([math.nan] * 15), 1e-9) is None


def test_nonnegative_projection():
    p = np.diag([16.0, 0.1, 1e-5, 1e-8, 1e-10])
    p[2, 4] = p[4, 2] = 0.9 * math.sqrt(1e-5 * 1e-10)
    x = [100.0, 10.0, -0.002, 1e-4, 4e-5]
    y = list(x)
    assert project_nonnegative(y, pack(p), (1, 2, 3, 4), "project")
    assert y[2] == 0.0
    # the correlated r2 moves by P_42 / P_22 * 0.002 (the projection of the mean), the others stay
    assert y[4] == pytest.approx(4e-5 + p[4, 2] / p[2, 2] * 0.002, rel=1e-12)
    assert y[0] == 100.0 and y[1] == 10.0 and y[3] == 1e-4
    z = list(x)
    assert project_nonnegative(z, pack(p), (1, 2, 3, 4), "clip") and z == [100.0, 10.0, 0.0, 1e-4, 4e-5]
    assert not project_nonnegative([1.0] * 5, pack(p), (1, 2, 3, 4), "project")


def test_nis_flags_degraded_when_innovations_are_inconsistent():
    train, _truth, series = synthetic_run(1, 10.0)
    s = copy_series(series)
    s.s[40:70] += 80.0 * np.arange(30)  # the position runs away from the speed
    est = estimate_run(s, train, UKFConfig.converging())
    assert np.all(est.health[:35] == HEALTH_OK)
    assert np.sum(est.health[40:70] == HEALTH_DEGRADED) > 10
    consistent = estimate_run(series, train, UKFConfig.converging())
    assert np.all(consistent.health == HEALTH_OK)
    assert 0.5 < np.mean(consistent.nis[1:]) < 2.5  # chi-square with 2 dof: mean 2 when consistent


def test_power_gives_known_traction_effort():
    train, truth, series = synthetic_run(1, 10.0)
    s = copy_series(series)
    add_power(s, truth, train, np.random.default_rng(0), rel_noise=0.0)
    est = ResistanceEstimator(train, UKFConfig.converging())
    out = estimate_run(s, train, estimator=est)
    assert est.counters["known_effort_power"] > 3
    traction = out.effort_known & (truth.u > 0.1)
    # the mean effort over a step from power at both ends matches the truth effort of the step
    u_true = 0.5 * (truth.u[:-1] + truth.u[1:])
    assert np.allclose(out.effort[1:][traction[1:]], u_true[traction[1:]], rtol=0.1)


def test_effort_source_says_where_the_effort_came_from():
    """EFFORT_POWER on steps with traction power at both ends, EFFORT_POWER_COASTING on coasting steps without it,
    computed on the step the traction power ends in (what features locate the coast's start with); without power
    only computed and speed-confirmed coasting. effort_known is "not computed", per sample and over a run."""
    train, truth, series = synthetic_run(1, 10.0)
    s = copy_series(series)
    add_power(s, truth, train, np.random.default_rng(0), rel_noise=0.0)
    out = estimate_run(s, train, UKFConfig.converging())
    src = out.effort_source
    fast = s.v >= UKFConfig.converging().known_effort_min_speed
    step = fast[1:] & fast[:-1]
    pulling = (truth.u[1:] > 0.01) & (truth.u[:-1] > 0.01) & step  # traction and the hold
    coasting = (truth.regime[1:] == COASTING) & (truth.regime[:-1] == COASTING) & step
    ends = (truth.u[:-1] > 0.01) & (truth.regime[1:] == COASTING) & step
    assert pulling.sum() > 5 and coasting.sum() > 5 and ends.sum() >= 1
    assert np.all(src[1:][pulling] == EFFORT_POWER)
    assert np.mean(src[1:][coasting] == EFFORT_POWER_COASTING) > 0.9
    assert np.all(src[1:][ends] == EFFORT_COMPUTED)
    np.testing.assert_array_equal(out.effort_known, src != EFFORT_COMPUTED)
    est = ResistanceEstimator(train, UKFConfig.converging())
    np.testing.assert_array_equal([est.update(m).effort_source for m in s], src)
    gnss_only = estimate_run(series, train, UKFConfig.converging()).effort_source
    assert set(np.unique(gnss_only)) == {EFFORT_COMPUTED, EFFORT_COASTING}
    # power_coasting false (no electric brake, or a meter without regeneration): traction from power, coasting only
    # where the speeds confirm it
    no_power_coasting = estimate_run(s, train, UKFConfig.converging(power_coasting=False)).effort_source
    assert set(np.unique(no_power_coasting)) == {EFFORT_COMPUTED, EFFORT_COASTING, EFFORT_POWER}
    np.testing.assert_array_equal(no_power_coasting == EFFORT_POWER, src == EFFORT_POWER)


def test_config_validation_and_presets():
    with pytest.raises(ConfigError, match="kappa"):
        UKFConfig(kappa=-4.9, alpha=0.001).replace(kappa=-5.0)
    with pytest.raises(ConfigError, match="preset"):
        UKFConfig.preset("fast")
    assert UKFConfig.preset("learning") == UKFConfig()
    assert UKFConfig.preset("paper") == UKFConfig(resistance_learning="ukf")
    conv = UKFConfig.converging(accel_noise_std=0.02)
    assert conv.accel_noise_std == 0.02 and conv.effort_mode == "exploit_known"
    t1 = UKFConfig.paper()
    assert (t1.alpha, t1.beta, t1.kappa, t1.init_std_s) == (0.001, 2.0, -2.0, 1.0)
    assert t1.init_std_v == pytest.approx(0.0018 / 3.6) and t1.meas_std_v == pytest.approx(1 / 3.6)
    assert (t1.init_std_r0, t1.init_std_r1, t1.init_std_r2, t1.meas_std_s) == (1e-6, 1e-8, 1e-9, 4.0)
    with pytest.raises(ValueError, match="initial resistance"):
        ResistanceEstimator(synthetic_run(1, 10.0)[0], initial=Davis(-0.01, 0.0, 0.0))
