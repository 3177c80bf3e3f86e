"""The UKF stage's C kernel (estimation/_ukf_kernel.c) against the Python it mirrors, float for float, and the package
without it (the Python paths alone give the same outputs)."""

from __future__ import annotations

import hashlib
import math
import os
import subprocess
import sys
from dataclasses import fields
from pathlib import Path

import numpy as np
import pytest
from estimation_cases import simulated_run
from test_fast_paths import CONFIGS, same_float, same_result, step_inputs

from train_calib.estimation import UKFConfig, coast_regression, ukf_fast
from train_calib.estimation.coast_regression import (
    CoastRegression,
    CoastSettings,
    candidate_steps,
    candidate_steps_python,
    fit_coasts,
    local_slopes,
)
from train_calib.estimation.coast_types import POWER_DRIVE, POWER_NONE, POWER_UNKNOWN, RunArrays
from train_calib.estimation.run import estimate_run
from train_calib.estimation.ukf import ResistanceEstimator

ROOT = Path(__file__).resolve().parents[2]


def test_kernel_is_built():
    """The comparisons below need the kernel (setup.py builds it where a C compiler is found): without it they would
    compare the Python with itself."""
    assert ukf_fast.KERNEL_AVAILABLE and coast_regression._ukf_kernel is not None
    assert ukf_fast.common_step is ukf_fast._ukf_kernel.common_step
    assert ResistanceEstimator(simulated_run(0, 1.0)[3])._common_step is ukf_fast.common_step


class Counting:
    """A common step that counts the steps it took (not None) and the steps it left to the chain."""

    def __init__(self, step) -> None:
        self.step, self.taken, self.left = step, 0, 0

    def __call__(self, *args):
        out = self.step(*args)
        if out is None:
            self.left += 1
        else:
            self.taken += 1
        return out


@pytest.mark.parametrize("period", [1.0, 10.0])
@pytest.mark.parametrize("faults", [False, True])
@pytest.mark.parametrize("config", list(CONFIGS))
def test_c_step_equals_the_python_step(config, faults, period):
    """_ukf_kernel.common_step gives ukf_fast.common_step_python's outputs bit for bit: every StepResult, the
    counters and the final state, with and without faults (steps it leaves to the chain included), at 1 Hz and 10 s."""
    train = simulated_run(0, period)[3]
    kernel, python = ResistanceEstimator(train, CONFIGS[config]), ResistanceEstimator(train, CONFIGS[config])
    kernel._common_step = Counting(ukf_fast._ukf_kernel.common_step)
    python._common_step = Counting(ukf_fast.common_step_python)
    for m in step_inputs(period, faults):
        a, b = kernel.process(m), python.process(m)
        assert same_result(a, b), (m, a, b)
    assert kernel.counters == python.counters
    for name in ("x", "P", "L", "m", "q_sv"):
        a, b = getattr(kernel._h, name), getattr(python._h, name)
        assert all(same_float(p, q) for p, q in zip(a, b, strict=True)), name
    for name in ("_last_effort", "_last_accel", "_last_input", "_gated_since", "_gated_count", "_relocked"):
        assert repr(getattr(kernel, name)) == repr(getattr(python, name)), name
    k, p = kernel._common_step, python._common_step
    assert (k.taken, k.left) == (p.taken, p.left)
    assert k.taken > (0.5 if faults else 0.9) * (k.taken + k.left)  # the kernel did the work
    if faults:
        assert k.left > 0  # and left the uncommon steps to the chain


def test_c_step_leaves_the_estimator_untouched_when_it_declines():
    """A step the kernel leaves to the chain (a gated position, a position not measured, a non-finite effort) leaves
    the filter and the estimator as they were; the Python step declines the same steps."""
    train = simulated_run(0, 1.0)[3]
    steps = step_inputs(1.0, False)
    for i, change in enumerate(({"s_measured": False}, {"s": math.nan}, {"s": 1e9}, {"v": math.inf})):
        kernel, python = ResistanceEstimator(train), ResistanceEstimator(train)
        for m in steps[: 50 + i]:
            kernel.process(m), python.process(m)
        m = steps[50 + i]._replace(**change)
        before = (list(kernel._h.x), kernel._h.P, kernel._h.L, kernel._h.m, kernel._last_effort)
        assert ukf_fast._ukf_kernel.common_step(kernel, m, 1.0, 0.01, 4.0, 0.01) is None
        assert ukf_fast.common_step_python(python, m, 1.0, 0.01, 4.0, 0.01) is None
        assert before == (kernel._h.x, kernel._h.P, kernel._h.L, kernel._h.m, kernel._last_effort)


def _arrays(rng: np.random.Generator, n: int, power: bool, period: float) -> RunArrays:
    """Coasting, braking, holding and stopped stretches with speed noise, some gaps and run changes."""
    t = np.cumsum(rng.choice([period, period, period, 3.0 * period, 0.5 * period], n))
    phase = rng.integers(0, 4, size=n // 20 + 1).repeat(20)[:n]
    accel = np.choose(phase, [-0.01, -0.3, 0.0, 0.4]) + rng.normal(0.0, 0.002, n)
    v = np.clip(15.0 + np.cumsum(accel * period) + rng.normal(0.0, 0.05, n), 0.0, None)
    v[rng.random(n) < 0.05] = 0.0
    g = rng.normal(0.0, 0.01, n)
    run = np.cumsum(rng.random(n) < 0.01).astype(np.int64) + 3
    states = rng.choice([POWER_UNKNOWN, POWER_NONE, POWER_DRIVE], n).astype(np.int8)
    return RunArrays(t, v, g, np.zeros(n), run, states if power else None)


@pytest.mark.parametrize("power", [False, True])
def test_c_candidates_equal_numpy(power):
    """_ukf_kernel.coast_candidates (candidate_steps with local_slopes in C) gives candidate_steps_python's
    booleans on random runs: short and long, every window and period, with and without power states and
    power_decides; unsorted keys (run ids falling) go to numpy."""
    rng = np.random.default_rng(11 if power else 12)
    prior = np.array([0.012, 1.6e-4, 6.5e-5])
    taken = found = 0
    for k in range(300):
        n = int(rng.choice([0, 1, 2, 3, 4, 7, 30, 120, 600]))
        period = float(rng.choice([1.0, 2.0, 10.0]))
        arr = _arrays(rng, n, power, period)
        settings = CoastSettings(power_coasting=bool(k % 3))
        window, sigma_v = float(rng.uniform(5.0, 90.0)), float(rng.uniform(0.002, 0.2))
        by_speed, by_power = candidate_steps(arr, settings, prior, sigma_v, window, period)
        ref_speed, ref_power = candidate_steps_python(arr, settings, prior, sigma_v, window, period)
        assert by_speed.dtype == ref_speed.dtype == bool and by_power.dtype == ref_power.dtype == bool
        np.testing.assert_array_equal(by_speed, ref_speed)
        np.testing.assert_array_equal(by_power, ref_power)
        out = np.empty(n, bool), np.empty(n, bool)
        params = (window, min(0.8 * window, window - 1.5 * period), *prior.tolist(), settings.coast_ratio_min,
                  settings.coast_ratio_max, settings.coast_hold_sigmas, sigma_v, settings.coast_min_speed,
                  float(settings.power_decides), 1.6 * settings.coast_ratio_max,
                  min(settings.max_gap, 2.5 * period))  # fmt: skip
        slopes = np.empty(n), np.empty(n)
        if coast_regression._ukf_kernel.coast_candidates(arr.t, arr.v, arr.g, arr.run, arr.power, *out, params,
                                                         *slopes):  # fmt: skip
            taken += 1
            np.testing.assert_array_equal(out[0], ref_speed)
            np.testing.assert_array_equal(out[1], ref_power)
            ref_slopes = local_slopes(arr.t, arr.v, arr.run, window, period)
            for a, b in zip(slopes, ref_slopes, strict=True):  # the floats behind the booleans, bit for bit
                assert a.tobytes() == b.tobytes()
        found += bool(ref_speed.any() or ref_power.any())
    assert taken > 250 and found > 30  # the kernel decided, and on arrays with candidates
    # run ids falling: keys out of order, the kernel declines (numpy's answer)
    arr = _arrays(rng, 200, power, 1.0)
    arr.run = arr.run[::-1].copy()
    out = np.empty(200, bool), np.empty(200, bool)
    params = (30.0, 24.0, *prior.tolist(), 0.5, 2.0, 2.0, 0.02, 3.0, 1.0, 3.2, 2.5)
    assert not coast_regression._ukf_kernel.coast_candidates(arr.t, arr.v, arr.g, arr.run, arr.power, *out, params)

    def outcome(f) -> list:
        try:
            return [a.tolist() for a in f(arr, CoastSettings(), prior, 0.02, 30.0, 1.0)]
        except IndexError as e:  # numpy's searchsorted past the end of an unsorted array
            return [repr(e)]

    assert outcome(candidate_steps) == outcome(candidate_steps_python)


def test_c_candidates_find_coasts():
    """The simulated runs' detections hold candidates (the equality above is not one of empty arrays)."""
    _, series, _, train = simulated_run(0, 1.0)
    arr = RunArrays.from_series(series, train)
    settings = CoastSettings()
    prior = np.asarray(train.davis.as_tuple(), dtype=float)
    by_speed, _ = candidate_steps(arr, settings, prior, 0.03, 30.0, 1.0)
    assert by_speed.sum() > 50
    np.testing.assert_array_equal(by_speed, candidate_steps_python(arr, settings, prior, 0.03, 30.0, 1.0)[0])


@pytest.mark.parametrize("period", [1.0, 10.0])
def test_coast_regression_with_and_without_the_c_candidates(monkeypatch, period):
    """The causal coast regression and the whole-run fit give the same r and covariance, bit for bit, with the
    kernel's candidates and with numpy's."""
    _, series, _, train = simulated_run(1, period, power=True)
    arr = RunArrays.from_series(series, train)

    def run() -> list[bytes]:
        reg = CoastRegression(train, CoastSettings(), train.davis)
        out = []
        for i in range(arr.t.size):
            power = POWER_UNKNOWN if arr.power is None else int(arr.power[i])
            if reg.push(
                float(arr.t[i]), float(arr.v[i]), float(arr.g[i]), float(arr.tunnel[i]), int(arr.run[i]), power
            ):
                out.append(reg.r.tobytes() + reg.covariance.tobytes())
        fit = fit_coasts(arr, train)
        return [*out, fit.r.tobytes(), fit.covariance.tobytes(), str(len(fit.stretches)).encode()]

    with_kernel = run()
    monkeypatch.setattr(coast_regression, "_ukf_kernel", None)
    assert with_kernel == run()
    assert len(with_kernel) > 3  # r moved during the run


_WITHOUT_KERNEL = """
import sys
sys.modules["train_calib.estimation._ukf_kernel"] = None  # the import fails as on a machine without a compiler
sys.path[:0] = [{root!r}, {tests!r}, {tests_root!r}]
from test_ukf_kernel import digest
from train_calib.estimation import coast_regression, ukf_fast
assert not ukf_fast.KERNEL_AVAILABLE and coast_regression._ukf_kernel is None
assert ukf_fast.common_step is ukf_fast.common_step_python
print(digest())
"""


def digest() -> str:
    """sha256 of estimate_run's every column (default configuration and the ukf learning) and the whole-run coast
    fit on simulated runs at 1 Hz and 10 s, with and without power."""
    h = hashlib.sha256()
    for period, power in ((1.0, False), (10.0, False), (1.0, True)):
        _, series, _, train = simulated_run(2, period, power=power)
        for config in (UKFConfig(), CONFIGS["ukf-learning-decoupled"], CONFIGS["accel-noise-outside-gain"]):
            out = estimate_run(series, train, config)
            for f in fields(out):
                h.update(np.ascontiguousarray(getattr(out, f.name)).tobytes())
        fit = fit_coasts(RunArrays.from_series(series, train), train)
        h.update(fit.r.tobytes() + fit.covariance.tobytes())
    return h.hexdigest()


def test_package_without_the_kernel_gives_the_same_outputs():
    """With the kernel's import failing (a machine without a C compiler) the package runs the Python paths and its
    outputs equal the kernel's bit for bit."""
    assert ukf_fast.KERNEL_AVAILABLE
    here = Path(__file__).resolve().parent
    script = _WITHOUT_KERNEL.format(root=str(ROOT), tests=str(here), tests_root=str(here.parent))
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]))
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, env=env, timeout=600)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == digest()
