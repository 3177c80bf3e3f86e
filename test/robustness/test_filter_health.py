"""Filter health: the rules that detect and recover a broken filter, and properties over any input.

Rules (docs/reliability.md, docs/estimator.md): a covariance that is not positive definite is repaired
(REPAIRED); NaN or inf in the state, covariance or innovation restarts s and v at the measurement, keeping r
when it is valid (RESET); a position innovation beyond the gate is not used, and after gate_relock_time of
them in a row s restarts there (RESET); innovations inconsistent with their covariance (the NIS window above
its chi-square limit: DEGRADED) for nis_reset_windows windows in a row restart s and v (RESET). Properties
(hypothesis): for any finite input within physical ranges the filter returns finite values, a symmetric
positive definite covariance and r >= 0; for any floats at all (NaN, inf, huge) it still never returns NaN
or a negative r; the regime classifier is total.
"""

from __future__ import annotations

import dataclasses
import math
import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

sys.path.insert(0, str(Path(__file__).resolve().parent))
from faultlib import make_scenario, write_bag

from train_calib.estimation import HEALTH_DEGRADED, HEALTH_OK, HEALTH_REPAIRED, HEALTH_RESET, UKFConfig
from train_calib.estimation.covariance import pack
from train_calib.estimation.regimes import REGIME_NAMES, RegimeClassifier, classify_regimes
from train_calib.estimation.safeguards import SafeguardConfig
from train_calib.estimation.ukf import ResistanceEstimator
from train_calib.measurement import Measurement
from train_calib.pipeline import run_bag
from train_calib.train import load_train

TRAIN = load_train(Path(__file__).resolve().parents[1] / "data" / "small_train.yaml")
PRESETS = {"paper": UKFConfig(), "converging": UKFConfig.converging()}
NS = 1_000_000_000


def check_physical(e, where: str = "") -> None:
    values = [e.s, e.v, e.r0, e.r1, e.r2, e.effort, e.acceleration, e.resistance, e.nis, e.track_force]
    assert all(math.isfinite(x) for x in values), (where, values)
    assert min(e.r0, e.r1, e.r2) >= 0.0 and e.v >= 0.0, where
    cov = e.covariance
    assert np.all(np.isfinite(cov)) and np.array_equal(cov, cov.T), where
    assert np.linalg.eigvalsh(cov)[0] > 0.0, (where, np.linalg.eigvalsh(cov))


@pytest.fixture(scope="module")
def measurements(tmp_path_factory):
    """The measurements of the robustness scenario (1 Hz, coasting phases), from the core chain."""
    sc = make_scenario(tmp_path_factory.mktemp("scenario"))
    out = run_bag(write_bag(tmp_path_factory.mktemp("bag") / "bag", sc.events), sc.track, sc.train)
    return out.measurements


def _run(ms, cfg=None, safeguards=None, hook=None):
    est = ResistanceEstimator(TRAIN, cfg or UKFConfig.converging(), safeguards=safeguards)
    out = []
    for k, m in enumerate(ms):
        if hook is not None:
            hook(k, est)
        out.append(est.update(m))
    return est, out


def test_covariance_not_positive_definite_is_repaired_and_flagged(measurements):
    """Broken in the resistance filter (it owns r and its covariance; with look-ahead it runs coast_confirm_ahead
    behind the output filter and steps again within the next update): repaired there and flagged on that update,
    which also outranks the DEGRADED flag the NIS window gives at that sample anyway."""

    def break_covariance(k, est):
        if k == 300:
            bad = est.covariance
            bad[2, 3] = bad[3, 2] = 2.0 * math.sqrt(bad[2, 2] * bad[3, 3])  # correlation 2
            est._rf.P = pack(bad)

    _, clean = _run(measurements)
    assert clean[300].health == HEALTH_DEGRADED  # what the flag would be without the fault
    est, out = _run(measurements, hook=break_covariance)
    assert out[300].health == HEALTH_REPAIRED and est.counters["repairs"] == 1
    for e in out:
        check_physical(e)


@pytest.mark.parametrize("where", ["state_v", "state_r", "covariance"])
def test_nan_in_the_state_or_covariance_resets_keeping_a_valid_r(measurements, where):
    """v is the output filter's (the published s, v); r and its covariance the resistance filter's (it steps again
    within the next update: it runs coast_confirm_ahead behind)."""

    def poison(k, est):
        if k == 400:
            if where == "state_v":
                est._h.x[1] = math.nan
            elif where == "state_r":
                est._rf.x[3] = math.inf
            else:
                est._rf.P = tuple([math.nan] * 15)

    _, clean = _run(measurements)
    est, out = _run(measurements, hook=poison)
    assert out[400].health == HEALTH_RESET and est.counters["resets"] == 1
    for e in out:
        check_physical(e)
    if where == "state_v":  # r was valid: kept through the reset, learnt on as in the fault-free run
        assert (out[400].r0, out[400].r1, out[400].r2) == (clean[400].r0, clean[400].r1, clean[400].r2)
    else:  # r itself (or its covariance) was broken: back to the prior
        assert (out[400].r0, out[400].r1, out[400].r2) == TRAIN.davis.as_tuple()
    assert all(e.health in (HEALTH_OK, HEALTH_DEGRADED) for e in out[401:])


def _offset(ms, start, stop, ds):
    return [dataclasses.replace(m, s=m.s + ds) if start <= k < stop else m for k, m in enumerate(ms)]


def test_position_gated_then_relocked_when_the_offset_persists(measurements):
    """An s offset of 80 m (a wrong lock, a drifted dead reckoning): gated (speed-only updates) for
    gate_relock_time (10 s), then s restarts at the measurement (RESET); the same when it goes away."""
    ms = _offset(measurements, 300, 400, 80.0)
    est, out = _run(ms)
    health = [e.health for e in out]
    assert health[300:310].count(HEALTH_RESET) == 0 and health[310] == HEALTH_RESET
    assert abs(out[310].s - ms[310].s) < 1e-9 and est.counters["position_relocks"] == 2
    assert abs(out[420].s - measurements[420].s) < 10.0
    for e in out:
        check_physical(e)


def test_inconsistent_innovations_for_many_steps_are_flagged_then_reset(measurements):
    """The speed reads 12 % high for 150 s (a wheel-diameter fault) while the fixes are right: the NIS window
    exceeds its chi-square limit (DEGRADED); after nis_reset_windows (3) windows in a row s and v restart at
    the measurement, r kept (RESET). Nothing non-physical is published, and the filter is consistent again
    once the fault ends."""
    ms = [dataclasses.replace(m, v=m.v * 1.12) if 300 <= k < 450 else m for k, m in enumerate(measurements)]
    guards = SafeguardConfig(position_gate=1.0)  # the NIS rule alone (the gate would also catch the drift)
    est, out = _run(ms, UKFConfig.paper(), guards)
    health = [e.health for e in out]
    assert health[300:450].count(HEALTH_DEGRADED) >= 20
    assert est.counters["nis_resets"] >= 1 and HEALTH_RESET in health[300:460]
    reset = health.index(HEALTH_RESET, 300)
    kept = np.array([out[reset].r0, out[reset].r1, out[reset].r2])
    assert np.allclose(kept, [out[reset - 1].r0, out[reset - 1].r1, out[reset - 1].r2], rtol=1e-3)
    assert not np.array_equal(kept, TRAIN.davis.as_tuple())  # the learnt r, not the prior
    for e in out:
        check_physical(e)
    assert health[-100:].count(HEALTH_OK) >= 95
    # without the rule the flag is all there is: the inconsistency stays until the fault ends
    est_off, out_off = _run(ms, UKFConfig.paper(), dataclasses.replace(guards, nis_reset_windows=0))
    assert est_off.counters["nis_resets"] == 0 and HEALTH_RESET not in [e.health for e in out_off]


# -- properties ----------------------------------------------------------------------------------------------

_steps = st.lists(
    st.tuples(
        st.floats(0.05, 30.0),  # dt, s
        st.floats(0.0, 1.0e5),  # s, m
        st.floats(0.0, 80.0),  # v, m/s
        st.floats(-0.6, 0.6),  # g, N/kg (60 permille)
        st.booleans(),  # s measured
        st.floats(0.01, 1.0e4),  # s variance
        st.floats(1e-4, 10.0),  # v variance
        st.booleans(),  # power valid
        st.floats(0.0, 2.0e7),  # power consumed, W
        st.floats(0.0, 2.0e7),  # power regenerated, W
        st.integers(0, 40),  # a new run when 0
    ),
    min_size=2,
    max_size=60,
)


def _measurements(steps, physical_order=True):
    t, run, out = 1_700_000_000 * NS, 0, []
    for dt, s, v, g, sm, sv, vv, pv, pc, pr, new in steps:
        t += round(dt * NS) if physical_order else int(dt)
        run += new == 0
        out.append(Measurement(t, s, v, g, dt, run, sm, sv, vv, 0.0, 40.0, 0.0, pv, pc, pr))
    return out


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(steps=_steps, preset=st.sampled_from(sorted(PRESETS)), keep=st.booleans())
def test_any_physical_input_gives_finite_estimates_spd_covariance_and_nonnegative_r(steps, preset, keep):
    cfg = PRESETS[preset].replace(carry_over="keep" if keep else "reset")
    est = ResistanceEstimator(TRAIN, cfg)
    for k, m in enumerate(_measurements(steps)):
        check_physical(est.update(m), f"step {k}")


_any = st.floats(allow_nan=True, allow_infinity=True)
_raw_steps = st.lists(
    st.tuples(
        st.integers(-(2**40), 2**40),  # stamp steps (even backwards), ns
        _any,
        _any,
        _any,
        st.booleans(),
        _any,
        _any,
        st.booleans(),
        _any,
        _any,
        st.integers(0, 5),
    ),
    min_size=1,
    max_size=30,
)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(steps=_raw_steps, preset=st.sampled_from(sorted(PRESETS)))
def test_any_floats_at_all_never_give_nan_or_a_negative_resistance(steps, preset):
    est = ResistanceEstimator(TRAIN, PRESETS[preset])
    for k, m in enumerate(_measurements(steps, physical_order=False)):
        check_physical(est.update(m), f"step {k}")


_regime_in = st.one_of(st.none(), _any)


@settings(max_examples=200, deadline=None)
@given(effort=_any, acceleration=_any, speed=_regime_in, hold=st.booleans())
def test_the_regime_classifier_is_total(effort, acceleration, speed, hold):
    from train_calib.estimation import RegimeConfig

    cfg = RegimeConfig(hold_detection=hold)
    regime = RegimeClassifier(cfg).classify(effort, acceleration, speed)
    assert regime in range(len(REGIME_NAMES))
    vector = classify_regimes([effort], [acceleration], cfg, speed=None if speed is None else [speed])
    assert vector.shape == (1,) and int(vector[0]) == regime
