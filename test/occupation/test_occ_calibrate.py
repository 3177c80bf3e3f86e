"""Per-run calibration (differential evolution) on data from the model itself: what it recovers.

The 6 km test line, one leg West -> East, 18 occupations. Identifiable (measured, see
docs/occupation.md): theta, b_limit, c2 and c0 to a few per cent; r0 and r2 trade off against each
other (correlation about -0.99) and are not identifiable from passage times.
"""

from __future__ import annotations

import numpy as np
import pytest

from train_calib.occupation.calibrate import CalibrationConfig, calibrate_run
from train_calib.occupation.compositions import DECISION_NAMES
from train_calib.occupation.generate import occupation_events
from train_calib.occupation.model import SimulatorModel
from train_calib.occupation.objective import build_observations, evaluate
from train_calib.occupation.robustness import repeated_calibrations
from train_calib.occupation.sensitivity import identifiability, one_at_a_time

STOPS = (150.0, 5850.0)
TRUTH = dict(c0=0.45, c2=5.5, r0=0.018, r2=3.5e-5, b_limit=0.4, theta_cruise=0.95)


@pytest.fixture(scope="module")
def setup(line, composition):
    model = SimulatorModel(line, composition)
    truth = composition.model_params(**TRUTH)
    prof = model(truth, *STOPS)
    s = np.linspace(*STOPS, 12000)
    t = prof.time_at(s)
    exact = occupation_events(t, s, 162.0, line.sections, t0_s=1000.37, round_down=False)
    rounded = occupation_events(t, s, 162.0, line.sections, t0_s=1000.37)
    obs_exact = build_observations(exact, line.sections, STOPS, 162.0)
    obs_rounded = build_observations(rounded, line.sections, STOPS, 162.0)
    return model, truth, obs_exact, obs_rounded


def test_recovers_the_identifiable_parameters_from_exact_times(setup, composition):
    model, truth, obs, _ = setup
    res = calibrate_run(obs, model, composition, CalibrationConfig(atol=0.1, maxiter=40), seed=4)
    rel = {k: res.params[k] / truth[k] - 1 for k in DECISION_NAMES}
    assert res.objective_s < 1.0  # 18 passages, truth 0
    assert res.default_objective_s > 30.0
    assert abs(rel["theta_cruise"]) < 0.005
    assert abs(rel["b_limit"]) < 0.05
    assert abs(rel["c2"]) < 0.06
    assert abs(rel["c0"]) < 0.06
    for k in DECISION_NAMES:  # within the bounds, fixed parameters untouched
        lo, hi = composition.bounds[k]
        assert lo <= res.params[k] <= hi
    assert res.params["r1"] == composition.defaults["r1"] and res.params["c1"] == 0.0
    assert res.evaluation.residual_s.shape == (len(obs),)
    assert res.running_time_s == pytest.approx(model(res.params, *STOPS).run_time)


def test_rounded_times_optimum_beats_the_truth_and_is_reproducible(setup, composition):
    model, truth, _, obs = setup
    at_truth = evaluate(obs, model, truth).objective_s
    assert 2.0 < at_truth < 9.0  # 18 times rounded down: about 0.25 s each after the median offset
    a = calibrate_run(obs, model, composition, CalibrationConfig(maxiter=25), seed=11)
    assert a.objective_s <= at_truth + 0.5
    assert abs(a.params["theta_cruise"] / truth["theta_cruise"] - 1) < 0.02
    # the same seed gives the same answer
    short = CalibrationConfig(maxiter=4)
    b, c = (calibrate_run(obs, model, composition, short, seed=3) for _ in range(2))
    assert b.params == c.params and b.objective_s == c.objective_s and b.nfev == c.nfev


def test_robustness_table(setup, composition):
    model, _, _, obs = setup
    rob = repeated_calibrations(obs, model, composition, CalibrationConfig(maxiter=3), n=3, first_seed=5)
    assert rob.seeds == [5, 6, 7] and len(rob.results) == 3
    c2 = [r.params["c2"] for r in rob.results]
    row = rob.row("c2")
    assert row.mean == pytest.approx(np.mean(c2)) and row.std == pytest.approx(np.std(c2, ddof=1))
    assert row.cv_pct == pytest.approx(100 * np.std(c2, ddof=1) / np.mean(c2))
    assert rob.row("objective_s").mean == pytest.approx(np.mean([r.objective_s for r in rob.results]))
    assert "| c2 |" in rob.as_markdown()


def test_sensitivity_justifies_fixing_r1_and_identifiability(setup):
    model, truth, obs, _ = setup
    sens = {s.name: s for s in one_at_a_time(model, truth, obs.legs, [obs.position_m])}
    assert sens["r1"].max_change_pct < 0.1  # the paper's criterion for fixing r1
    # c1 (effort at the transition speed +-20 % of c0) matters a little more: "small relevance"
    assert sens["r1"].max_change_pct < sens["c1"].max_change_pct < 2.0
    assert sens["theta_cruise"].max_change_pct > 5.0 and sens["c2"].max_change_pct > 0.5
    # the faster train (higher c2) runs shorter
    assert sens["c2"].change_high_pct < 0 < sens["c2"].change_low_pct
    ident = identifiability(obs, model, truth)
    rel = dict(zip(ident.names, ident.relative_error()))
    assert rel["theta_cruise"] < 0.01 and rel["b_limit"] < 0.1
    assert rel["r0"] > 0.5  # not identifiable
    corr = {(a, b): c for a, b, c in ident.strongest_correlations(15)}
    assert corr[("r0", "r2")] < -0.9
    # the standard errors scale with the assumed timing noise
    twice = identifiability(obs, model, truth, sigma_s=2 * ident.sigma_s)
    np.testing.assert_allclose(twice.std_error, 2 * ident.std_error, rtol=1e-9)
