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
from build_context import ukf_kernel_skip_reason

if ukf_kernel_skip_reason():  # colcon test: the source tree without the kernel colcon built into install/
    pytest.skip(ukf_kernel_skip_reason(), allow_module_level=True)

from estimation_cases import simulated_run
from test_fast_paths import CONFIGS, same_float, same_result, step_inputs

from train_calib.estimation import UKFConfig, coast_detection, coast_regression, effort, ukf_fast
from train_calib.estimation.coast_detection import candidate_steps, candidate_steps_python, local_slopes
from train_calib.estimation.coast_regression import CoastRegression, CoastSettings, fit_coasts
from train_calib.estimation.coast_types import POWER_DRIVE, POWER_NONE, POWER_UNKNOWN, RunArrays
from train_calib.estimation.effort import SpeedSlope
from train_calib.estimation.run import estimate_run
from train_calib.estimation.ukf import ResistanceEstimator, StepInput

ROOT = Path(__file__).resolve().parents[2]


def test_kernel_is_built():
    """The comparisons below need the kernel (setup.py builds it where a C compiler is found): without it they would
    compare the Python with itself."""
    assert ukf_fast.KERNEL_AVAILABLE and coast_regression._ukf_kernel is not None and effort._ukf_kernel is not None
    assert coast_detection._ukf_kernel is not None
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


def _with_power(steps: list[StepInput]) -> list[StepInput]:
    """Power measured on a third of the samples (traction, none, regeneration), and a power that is none (repaired)."""
    out = []
    for i, m in enumerate(steps):
        if i % 3 == 0:
            m = m._replace(power_valid=True, power_consumed=[2.0e6, 1.0e4, 0.0][i % 9 // 3],
                           power_regenerated=[0.0, 0.0, 5.0e5][i % 9 // 3])  # fmt: skip
        if i % 101 == 50:
            m = m._replace(power_valid=True, power_consumed=-1.0)
        out.append(m)
    return out


@pytest.mark.parametrize("period", [1.0, 10.0])
@pytest.mark.parametrize("faults", [False, True])
@pytest.mark.parametrize("config", list(CONFIGS))
def test_c_process_equals_the_python_process(config, faults, period):
    """_ukf_kernel.process_common (a common sample's process() in C) gives the Python process's outputs bit for bit:
    every StepResult, the counters, the filter, the NIS window, what the next step remembers, the coast regression
    and the speed slope, with and without faults and power; the samples it leaves to Python included."""
    train = simulated_run(0, period)[3]
    kernel, python = ResistanceEstimator(train, CONFIGS[config]), ResistanceEstimator(train, CONFIGS[config])
    kernel._process_kernel = Counting(kernel._process_kernel)
    python._process_kernel, python._common_step = None, ukf_fast.common_step_python
    steps = step_inputs(period, faults)
    for m in _with_power(steps) if faults else steps:
        a, b = kernel.process(m), python.process(m)
        assert same_result(a, b), (m, a, b)
        assert type(a) is type(b) and [type(x) for x in a] == [type(x) for x in b]
    assert kernel.counters == python.counters
    for name in ("x", "P", "L", "m", "q_sv"):
        assert [float(x).hex() for x in getattr(kernel._h, name)] == [float(x).hex() for x in getattr(python._h, name)]
    remembered = ("_nis_ring", "_nis_sum", "_nis_dof", "_degraded_steps", "_last_stamp", "_zv_prev", "_g_prev")
    remembered += ("_pw_prev", "rejected", "_last_effort", "_last_accel", "_last_input", "_gated_count", "_run_id")
    for name in remembered:
        assert repr(getattr(kernel, name)) == repr(getattr(python, name)), name
    assert _state(kernel._slope) == _state(python._slope)
    if kernel._coast is not None:
        assert _state(kernel._coast) == _state(python._coast)
    k = kernel._process_kernel
    assert k.taken > (0.5 if faults else 0.9) * (k.taken + k.left)
    if faults:
        assert k.left > 0 and kernel.counters["degraded"] + kernel.counters["position_gated"] > 0


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
        if coast_detection._ukf_kernel.coast_candidates(arr.t, arr.v, arr.g, arr.run, arr.power, *out, params,
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
    assert not coast_detection._ukf_kernel.coast_candidates(arr.t, arr.v, arr.g, arr.run, arr.power, *out, params)

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


def _state(obj) -> dict:
    """Every attribute of a SpeedSlope or CoastRegression, floats by their bits (arrays by their bytes)."""
    names = obj.__slots__ if hasattr(obj, "__slots__") else vars(obj)
    out = {}
    for name in names:
        value = getattr(obj, name)
        if isinstance(value, np.ndarray):
            out[name] = (value.dtype.str, value.shape, value.tobytes())
        elif isinstance(value, tuple) and value and isinstance(value[0], np.ndarray):
            out[name] = [a.tobytes() for a in value]
        elif name == "stretches":
            out[name] = [(st.t_start, st.t_end, st.group, st.A.tobytes(), st.y.tobytes()) for st in value]
        elif name not in ("_train", "settings"):
            out[name] = [float(x).hex() if isinstance(x, float) else repr(x) for x in value] if isinstance(
                value, (list, tuple)) else repr(value)  # fmt: skip
    return out


def test_c_slope_push_equals_python():
    """_ukf_kernel.slope_push gives SpeedSlope.push_python's slope and state bit for bit: windows of 2 to 60 s,
    stamp jitter, repeated stamps and holes, resets, past the 256 pushes between refreshes."""
    rng = np.random.default_rng(5)
    for window in (2.0, 10.0, 60.0):
        kernel, python = SpeedSlope(window), SpeedSlope(window)
        t, v = 1000.0, 12.0
        for k in range(3000):
            t += float(rng.choice([1.0, 1.0, 0.98, 1.02, 0.0, 10.0, 0.1]))
            v = max(v + float(rng.normal(0.0, 0.3)), 0.0)
            if k % 997 == 500:
                kernel.reset(), python.reset()
            a, b = kernel.push(t, v), python.push_python(t, v)
            assert same_float(a, b) and same_float(kernel.slope, b), (window, k)
            assert same_float(kernel.residual_std(), python.residual_std()) and kernel.span == python.span
            if k % 37 == 0:
                assert _state(kernel) == _state(python), (window, k)
        assert _state(kernel) == _state(python)


def test_c_step_input_equals_from_measurement():
    """_ukf_kernel.step_input gives StepInput.from_measurement's tuple, field for field and type for type, from
    Measurements holding Python and numpy scalars, NaN and infinities; update() takes it."""
    from train_calib.estimation import ukf_types
    from train_calib.measurement import Measurement

    assert ukf_types.step_input.func is ukf_fast._ukf_kernel.step_input
    assert ukf_types.step_input.args == (ukf_types.StepInput,)
    rng = np.random.default_rng(3)
    values = [0.0, -0.0, 1.5, math.nan, math.inf, np.float64(2.25), np.float32(0.1), 7, np.int64(9)]
    for k in range(500):
        m = Measurement(
            stamp_ns=int(rng.integers(0, 2**62)) if k % 2 else np.int64(rng.integers(0, 2**62)),
            s=values[k % len(values)], v=values[(k + 1) % len(values)], track_force=values[(k + 2) % len(values)],
            run_id=np.int32(k) if k % 3 else k, s_measured=np.bool_(k % 5 != 0) if k % 2 else k % 5 != 0,
            s_variance=values[(k + 3) % len(values)], v_variance=values[(k + 4) % len(values)],
            power_valid=bool(k % 7), power_consumed=values[(k + 5) % len(values)],
            power_regenerated=values[(k + 6) % len(values)], tunnel_fraction=values[(k + 7) % len(values)],
            track_force_integral=values[(k + 8) % len(values)],
        )  # fmt: skip
        a, b = ukf_types.step_input(m), ukf_types.StepInput.from_measurement(m)
        assert type(a) is type(b) is ukf_types.StepInput
        assert [type(x) for x in a] == [type(x) for x in b]
        assert all(repr(x) == repr(y) for x, y in zip(a, b, strict=True)), (a, b)
    with pytest.raises(AttributeError):
        ukf_types.step_input(object())


class _Counted:
    """The kernel with its coast_push counted (code 2: left to push_python)."""

    def __init__(self) -> None:
        self.codes = [0, 0, 0]

    def coast_push(self, *args):
        code = coast_regression._ukf_kernel_module.coast_push(*args)
        self.codes[code] += 1
        return code

    def __getattr__(self, name):
        return getattr(coast_regression._ukf_kernel_module, name)


@pytest.mark.parametrize("period", [1.0, 10.0])
@pytest.mark.parametrize("faults", [False, True])
def test_c_coast_push_equals_python(monkeypatch, period, faults):
    """CoastRegression.push with _ukf_kernel.coast_push gives push_python's answers and state (every list, deque,
    counter, r and covariance) bit for bit on simulated runs with positions and the track force's integral (the
    energy form at 10 s); ``faults``: NaN speeds, repeated stamps, a clock reset, new runs, unknown gamma, NaN
    tunnel fractions and infinite position variances."""
    _, series, _, train = simulated_run(3, period)  # without power: more coasts from the speeds
    arr = RunArrays.from_series(series, train)
    power = arr.power.tolist() if arr.power is not None else [POWER_UNKNOWN] * arr.t.size
    rows = list(zip(arr.t.tolist(), arr.v.tolist(), arr.g.tolist(), arr.tunnel.tolist(), arr.run.tolist(), power,
                    series.s.tolist(), series.track_force_integral.tolist(), series.s_variance.tolist(),
                    series.v_variance.tolist(), strict=True))  # fmt: skip
    if faults:
        for i in range(len(rows)):
            t, v, g, tun, run, power, s_, gamma, s_var, v_var = rows[i]
            if i % 89 == 7:
                v = math.nan
            if i % 97 == 9 and i:
                t = rows[i - 1][0]  # a repeated stamp
            if i % 53 == 3:
                gamma, tun, s_var = math.nan, math.nan, math.inf
            if i > len(rows) // 2:
                run += 1
            if i > 3 * len(rows) // 4:
                t, run = t - 500.0, run + 1  # a clock reset with a run change
            rows[i] = (t, v, g, tun, run, power, s_, gamma, s_var, v_var)
    counted = _Counted()
    monkeypatch.setattr(coast_regression, "_ukf_kernel_module", coast_regression._ukf_kernel, raising=False)
    monkeypatch.setattr(coast_regression, "_ukf_kernel", counted)
    kernel, python = CoastRegression(train, CoastSettings()), CoastRegression(train, CoastSettings())
    changed = 0
    for k, row in enumerate(rows):
        a, b = kernel.push(*row), python.push_python(*row)
        assert a == b and type(a) is type(b), (k, row)
        changed += a
        if k % 25 == 0 or a:
            assert _state(kernel) == _state(python), (k, row)
    assert _state(kernel) == _state(python)
    assert changed >= (0 if faults else 1)  # coasts were found and used
    assert counted.codes[0] + counted.codes[1] > 0.9 * len(rows) and counted.codes[1] > 10
    assert (counted.codes[2] > 0) == faults  # repeated stamps and the clock reset went to push_python


_WITHOUT_KERNEL = """
import sys
sys.modules["train_calib.estimation._ukf_kernel"] = None  # the import fails as on a machine without a compiler
sys.path[:0] = [{root!r}, {tests!r}, {tests_root!r}]
from test_ukf_kernel import digest
from train_calib.estimation import coast_detection, coast_regression, effort, ukf_fast
assert not ukf_fast.KERNEL_AVAILABLE and coast_regression._ukf_kernel is None and effort._ukf_kernel is None
assert coast_detection._ukf_kernel is None
assert ukf_fast.common_step is ukf_fast.common_step_python
print(digest())
"""


def digest() -> str:
    """sha256 of estimate_run's every column (three configurations), the whole-run coast fit and the estimates of
    update() on simulated runs at 1 Hz and 10 s, with and without power."""
    h = hashlib.sha256()
    for period, power in ((1.0, False), (10.0, False), (1.0, True)):
        _, series, _, train = simulated_run(2, period, power=power)
        for config in (UKFConfig(), CONFIGS["ukf-learning-decoupled"], CONFIGS["accel-noise-outside-gain"]):
            out = estimate_run(series, train, config)
            for f in fields(out):
                h.update(np.ascontiguousarray(getattr(out, f.name)).tobytes())
        fit = fit_coasts(RunArrays.from_series(series, train), train)
        h.update(fit.r.tobytes() + fit.covariance.tobytes())
        est = ResistanceEstimator(train)  # update(Measurement), as the pipeline drives it
        for m in series:
            e = est.update(m)
            h.update(repr((e.s, e.v, e.r0, e.r1, e.r2, e.effort, e.nis, e.health, e.input_effort)).encode())
            h.update(e.covariance.tobytes())
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
