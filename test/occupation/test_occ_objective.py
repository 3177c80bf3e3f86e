"""Observations and eq. 8: exact zero at the truth, per-leg offsets, the L1-optimal shift, failures."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from scipy.optimize import minimize_scalar

from train_calib.occupation.calibrate import PENALTY_S, _BatchObjective, _Objective
from train_calib.occupation.events import RunEvents
from train_calib.occupation.generate import occupation_events
from train_calib.occupation.model import FailedProfile, SimulatorModel
from train_calib.occupation.objective import build_observations, evaluate, objective, objective_batch

STOPS = (150.0, 3000.0, 5850.0)
TRUTH = dict(c0=0.45, c2=5.5, r0=0.018, r2=3.5e-5, b_limit=0.4, theta_cruise=0.95)


def _two_leg_run(model, params, line, *, dwell=73.4, t0=40_000.25, round_down=False):
    """Head trajectory over two legs (stop at 3000 m), from the model itself; returns events and departures."""
    ts, ss, departures, clock = [], [], [], t0
    for start, stop in itertools.pairwise(STOPS):
        prof = model(params, start, stop)
        s = np.linspace(start, stop, 6000)
        ts.append(clock + prof.time_at(s))
        ss.append(s)
        departures.append(clock)
        clock += prof.run_time + dwell
    run = occupation_events(
        np.concatenate(ts), np.concatenate(ss), params["length_m"], line.sections, round_down=round_down
    )
    return run, departures


def test_objective_is_zero_at_the_truth_with_per_leg_offsets(line, composition):
    model = SimulatorModel(line, composition)
    truth = composition.model_params(**TRUTH)
    run, departures = _two_leg_run(model, truth, line)
    obs = build_observations(run, line.sections, STOPS, composition.length_m)
    assert obs.legs == [(150.0, 3000.0), (3000.0, 5850.0)]
    assert obs.n_occupations == len(obs) == 18  # every section start in (150, 5850]
    ev = evaluate(obs, model, truth)
    assert ev.objective_s == pytest.approx(0.0, abs=1e-3)
    np.testing.assert_allclose(ev.departure_s, departures, atol=1e-4)  # the dwell is recovered
    np.testing.assert_allclose(ev.residual_s, 0.0, atol=1e-4)
    # releases: the head is at end + L when the tail clears the end
    with_rel = build_observations(run, line.sections, STOPS, composition.length_m, use_releases=True)
    assert len(with_rel) > len(obs) and set(with_rel.kind) == {"occupy", "release"}
    # (1e-2: the events are read off a 0.5 m grid of the trajectory, linearly interpolated)
    assert evaluate(with_rel, model, truth).objective_s == pytest.approx(0.0, abs=1e-2)
    # another parameter vector does worse
    assert objective(obs, model, {**truth, "theta_cruise": 0.9}) > 1.0


def test_median_offset_is_the_l1_optimum(line, composition):
    model = SimulatorModel(line, composition)
    run, _ = _two_leg_run(model, composition.model_params(**TRUTH), line, round_down=True)
    obs = build_observations(run, line.sections, STOPS, composition.length_m)
    rng = np.random.default_rng(0)
    for _ in range(3):
        p = composition.model_params(**{k: rng.uniform(*composition.bounds[k]) for k in TRUTH})
        total = 0.0
        for k, (a, b) in enumerate(obs.legs):
            m = obs.leg == k
            r = obs.time_s[m] - model(p, a, b).time_at(obs.position_m[m])
            res = minimize_scalar(lambda c, r=r: np.sum(np.abs(r - c)), bounds=(r.min(), r.max()), method="bounded")
            total += res.fun
        assert objective(obs, model, p) == pytest.approx(total, abs=1e-3)


def test_failed_runs_cost_the_penalty(line, composition):
    model = SimulatorModel(line, composition)
    run, _ = _two_leg_run(model, composition.model_params(**TRUTH), line)
    obs = build_observations(run, line.sections, STOPS, composition.length_m)
    # c0 below the resistance at standstill: the train cannot start
    weak = composition.model_params(**{**TRUTH, "c0": 0.01})
    assert isinstance(model(weak, 150.0, 3000.0), FailedProfile)
    assert model.failures == 1 and "cannot start" in model.last_failure
    assert objective(obs, model, weak) == float("inf")
    fun = _Objective(obs, model, weak)
    assert fun(np.array([weak[k] for k in ("c0", "c2", "r0", "r2", "b_limit", "theta_cruise")])) == PENALTY_S


def test_observations_outside_the_legs_are_dropped(line):
    run = RunEvents("r", occupy={"T00": 1.0, "T05": 50.0, "T18": 300.0}, release={"T17": 310.0})
    obs = build_observations(run, line.sections, (150.0, 3000.0), 162.0, use_releases=True)
    # T00 starts at 0 (before the first stop), T18 at 5560 and T17's release head at 5560 + 162 (after the last)
    assert list(obs.section_id) == ["T05"] and obs.legs == [(150.0, 3000.0)]
    with pytest.raises(ValueError):
        build_observations(run, line.sections, (150.0,), 162.0)


def test_batch_objective_equals_the_scalar_one(line, composition):
    """objective_batch (one vectorised model call per leg, what differential evolution uses) = objective.

    The scalar model's passage times between its knots are cubic Hermite interpolants (errors up to a
    few 1e-3 s on long steps); the batch uses the integrator's dense output. Measured: up to 6e-3 s
    over 18 passages and two legs.
    """
    model = SimulatorModel(line, composition)
    run, _ = _two_leg_run(model, composition.model_params(**TRUTH), line, round_down=True)
    obs = build_observations(run, line.sections, STOPS, composition.length_m)
    rng = np.random.default_rng(3)
    n = 12
    values = {k: rng.uniform(*composition.bounds[k], n) for k in TRUTH}
    values["c0"][-1] = 0.01  # cannot start
    batch = objective_batch(obs, model, {**composition.model_params(), **values})
    assert batch.shape == (n,) and batch[-1] == np.inf
    for i in range(n - 1):
        p = composition.model_params(**{k: float(v[i]) for k, v in values.items()})
        assert batch[i] == pytest.approx(objective(obs, model, p), abs=0.02)
    fun = _BatchObjective(obs, model, composition.model_params())
    x = np.array([values[k] for k in ("c0", "c2", "r0", "r2", "b_limit", "theta_cruise")])
    out = fun(x)
    assert out[-1] == PENALTY_S and np.array_equal(out[:-1], batch[:-1]) and fun.runs == n
    assert fun(x[:, 0]) == batch[0]  # one vector: a number


def test_evaluate_sums_the_absolute_passage_time_errors(line, composition):
    """Away from the truth the residuals have both signs: evaluate's objective is the sum of their absolute values
    (eq. 8), the same number as objective() and the batch objective."""
    model = SimulatorModel(line, composition)
    run, _ = _two_leg_run(model, composition.model_params(**TRUTH), line)
    obs = build_observations(run, line.sections, STOPS, composition.length_m)
    p = composition.model_params(**{**TRUTH, "theta_cruise": 0.85, "c2": 4.5})
    ev = evaluate(obs, model, p)
    assert (ev.residual_s > 0.1).any() and (ev.residual_s < -0.1).any()
    assert ev.objective_s == pytest.approx(float(np.sum(np.abs(ev.residual_s))), rel=1e-12)
    assert ev.objective_s == pytest.approx(objective(obs, model, p), rel=1e-12)
    assert ev.objective_s > 1.0
