"""Fast paths against the readable code they stand for, float for float (outputs must not move by one bit)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from estimation_cases import simulated_run

from train_calib.estimation import UKFConfig
from train_calib.estimation.coast_detection import median
from train_calib.estimation.ukf import ResistanceEstimator, StepInput, StepResult
from train_calib.paths import train_file
from train_calib.train import load_train


def same_float(a: float, b: float) -> bool:
    """Equal bit for bit (NaN equals NaN, 0.0 differs from -0.0)."""
    return float(a).hex() == float(b).hex()


def test_median_is_numpy_median():
    """coast_detection.median equals float(np.median(x)): odd and even sizes, ties, signed zeros, NaN."""
    rng = np.random.default_rng(7)
    for n in [*range(1, 30), 64, 65, 1199, 1200, 4000]:
        for kind in range(6):
            if kind == 0:
                x = rng.normal(size=n)
            elif kind == 1:
                x = np.round(rng.normal(size=n), 1)  # ties
            elif kind == 2:
                x = np.abs(rng.standard_cauchy(n))
            elif kind == 3:
                x = rng.choice([-0.0, 0.0, 1.0, -1.0], n)  # signed zeros in the middle
            elif kind == 4:
                x = np.abs(rng.normal(size=n) * 1e-3)
            else:
                x = rng.normal(size=n)
                x[rng.integers(n)] = np.nan
            assert same_float(median(x), float(np.median(x))), (n, kind)


@pytest.mark.parametrize("seed", range(3))
def test_euler_speed_directions_equal_the_general_ones(seed):
    """The Euler rule's written-out sigma directions equal _speed_directions_any (the closure) float for float."""
    est = ResistanceEstimator(load_train(train_file("virm6")), UKFConfig(integration="euler"))
    assert not est._midpoint
    rng = np.random.default_rng(seed)
    for _ in range(2000):
        v = float(rng.choice([0.0, rng.uniform(0.0, 60.0), rng.uniform(0.0, 1e-3)]))
        x = [0.0, v, *(float(r) for r in rng.uniform(0.0, 1.0, 3) * [0.02, 3e-4, 8e-5])]
        l10, l11 = float(rng.normal() * 0.1), float(abs(rng.normal()) * 10 ** rng.uniform(-4, 1))
        h = float(rng.uniform(0.05, 10.0))
        vh = v + h * float(rng.normal())
        fast = est._speed_directions(x, vh, h, l10, l11)
        reference = est._speed_directions_any(x, vh, h, l10, l11)
        assert all(same_float(a, b) for a, b in zip(fast, reference, strict=True))
    assert math.isfinite(sum(fast))


def step_inputs(period: float, faults: bool) -> list[StepInput]:
    """A simulated run's measurements as StepInputs; ``faults``: with gated positions, positions not measured, NaN
    and negative speeds, repeated stamps, a gap, a speed jump and a second run."""
    _, series, _, _ = simulated_run(0, period)
    cols = (series.stamp_ns, series.run_id, series.s, series.v, series.track_force, series.s_measured,
            series.s_variance, series.v_variance, series.power_valid, series.power_consumed,
            series.power_regenerated, series.tunnel_fraction, series.track_force_integral)  # fmt: skip
    steps = [StepInput(*args) for args in zip(*(c.tolist() for c in cols), strict=True)]
    if not faults:
        return steps
    out = []
    for i, m in enumerate(steps):
        if i % 97 == 5:
            m = m._replace(s=m.s + 400.0)  # gated (and relocked when in a row)
        if i % 97 in (6, 7, 8, 9):
            m = m._replace(s=m.s + 400.0)
        if i % 131 == 3:
            m = m._replace(s_measured=False, s=math.nan)
        if i % 173 == 11:
            m = m._replace(v=math.nan)
        if i % 211 == 17:
            m = m._replace(v=-1.0)
        if i % 157 == 23 and out:
            m = m._replace(stamp_ns=out[-1].stamp_ns)  # dt = 0
        if i % 191 == 29:
            m = m._replace(v=m.v + 3.0)  # a speed jump: a large innovation
        if i == len(steps) // 2:
            out.append(m._replace(stamp_ns=m.stamp_ns + 900 * 10**9))  # a gap longer than max_dt
            continue
        if i > 2 * len(steps) // 3:
            m = m._replace(run_id=m.run_id + 1, stamp_ns=m.stamp_ns + 1000 * 10**9)
        out.append(m)
    return out


def same_result(a: StepResult, b: StepResult) -> bool:
    return all(
        (x == y and type(x) is type(y)) if not isinstance(x, float) else same_float(x, y)
        for x, y in zip(a[:-1], b[:-1], strict=True)
    ) and all(same_float(x, y) for x, y in zip(a.covariance, b.covariance, strict=True))


CONFIGS = {
    "default": UKFConfig(),
    "accel-noise-outside-gain": UKFConfig(accel_noise_std=0.05, update_uses_process_noise=False),
    "accel-noise-in-gain": UKFConfig(accel_noise_std=0.05),
    "measured-variances": UKFConfig(use_measurement_variance=True),
    "ukf-learning-decoupled": UKFConfig(resistance_learning="ukf", decouple_unknown_effort=True),
}


@pytest.mark.parametrize("period", [1.0, 10.0])
@pytest.mark.parametrize("faults", [False, True])
@pytest.mark.parametrize("config", list(CONFIGS))
def test_common_step_equals_the_chain(config, faults, period):
    """ukf_fast.common_step (the common step in one frame) gives the readable chain's outputs bit for bit: every
    StepResult, the counters and the final state, with and without faults, where it applies and where it falls
    back."""
    train = simulated_run(0, period)[3]
    fast, chain = ResistanceEstimator(train, CONFIGS[config]), ResistanceEstimator(train, CONFIGS[config])
    assert fast._common
    chain._common = False  # the readable chain only
    for m in step_inputs(period, faults):
        a, b = fast.process(m), chain.process(m)
        assert same_result(a, b), (m, a, b)
    assert fast.counters == chain.counters
    assert fast._h.x == chain._h.x and fast._h.L == chain._h.L and fast._h.m == chain._h.m
    assert fast._h.q_sv == chain._h.q_sv


def test_common_step_is_not_taken_outside_its_configuration():
    """Look-ahead (converging preset), the midpoint rule and a coupled r take the chain."""
    train = load_train(train_file("virm6"))
    for cfg in (UKFConfig.converging(), UKFConfig(integration="midpoint"), UKFConfig.paper()):
        assert not ResistanceEstimator(train, cfg)._common
