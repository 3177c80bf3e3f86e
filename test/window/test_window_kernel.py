"""The window fit's C kernel (window/_kernel.c) against the Python path it mirrors (FastFit with compiled=False).

Both compute the same formulas in the same order from R of [x y]; R itself comes from different
Householder codes (LAPACK dgeqrf, the kernel's own), and the condition number, where its closed form
is loose, from different SVDs (dgesdd, one-sided Jacobi), and where an eq. 6/7 row binds, the LSI's
NNLS is scipy's in Python and the kernel's own. Tolerances: condition number and mean speed to 1e-9
relative (measured: 4e-11 on the bundled 1 Hz bags); GoF and relative standard error to max(1e-9,
1e-17 cond^2) relative and the estimate to max(1e-11, 1e-15 cond^2) of each bound's range, as
test_window_fast against the reference.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from build_context import kernel_skip_reason

if kernel_skip_reason():  # colcon test: the source tree without the kernel colcon built into install/
    pytest.skip(kernel_skip_reason(), allow_module_level=True)

from test_window_fast import CONFIGS, TRAIN, _objective_rtol, _window
from window_synthetic import train_spec

from train_calib.window import WindowCalibrator, WindowConfig
from train_calib.window import _kernel as kernel  # make setup builds it (a missing one fails here)
from train_calib.window import fast as fast_module
from train_calib.window.calibrator import _PyWindow
from train_calib.window.fast import CODES, MAX_CONDITION, PATTERNS, FastFit
from train_calib.window.model import StepModel

FLOATS = ("speed_span", "mean_speed", "condition_number")
EXACT = ("stamp_ns", "run_id", "window_length", "sample_count", "gof_kind", "regime", "ill_posed",
         "dropped_constraints")  # fmt: skip


def _close(a: float, b: float, rtol: float = 1e-9, atol: float = 0.0) -> bool:
    if not (math.isfinite(a) and math.isfinite(b)):
        return (math.isnan(a) and math.isnan(b)) or a == b
    return abs(a - b) <= rtol * max(abs(a), abs(b)) + atol


def _assert_same(compiled, python, config: WindowConfig, mass: float = TRAIN.effective_mass_kg) -> None:
    for name in EXACT:
        assert getattr(compiled, name) == getattr(python, name), (name, compiled, python)
    assert compiled.reason.split(" ")[:2] == python.reason.split(" ")[:2], (compiled.reason, python.reason)
    for name in FLOATS:
        assert _close(getattr(compiled, name), getattr(python, name)), (name, compiled, python)
    # eps cond^2 where an eq. 6/7 row binds (the LSI); of an exact window both are round-off (1e-12 N/kg of
    # GoF, 1e-9 of relative standard error)
    rtol = _objective_rtol(python.condition_number)
    assert _close(compiled.gof_value, python.gof_value, rtol, atol=1e-12 * mass), (compiled, python)
    assert _close(compiled.relative_error, python.relative_error, rtol, atol=1e-9), (compiled, python)
    width = np.array([hi - lo for lo, hi in config.specific_bounds])
    tolerance = max(1e-11, 1e-15 * python.condition_number**2) * width
    if python.condition_number <= MAX_CONDITION:
        np.testing.assert_array_less(np.abs(np.subtract(compiled.estimate, python.estimate)), tolerance)
    published = np.array([compiled.r0 - python.r0, compiled.r1 - python.r1, compiled.r2 - python.r2])
    assert np.all(np.isnan(published)) or np.all(np.abs(published) <= max(1e-11, 1e-15 * 1e6) * width)


def test_the_kernel_is_built_and_used_by_default():
    fit = FastFit(TRAIN, WindowConfig())
    assert fast_module.KERNEL_AVAILABLE and fit.compiled
    assert not FastFit(TRAIN, WindowConfig(), compiled=False).compiled
    assert not FastFit(TRAIN, WindowConfig(gof="sae")).compiled  # SAE is the reference's alone


@pytest.mark.parametrize("name", list(CONFIGS))
def test_streaming_compiled_equals_the_python_path(runs, name):
    """Whole runs: every window, the active set carried from window to window, the counters."""
    config = CONFIGS[name]
    fitted = by_kernel = 0
    for _, train, series in runs:
        compiled = WindowCalibrator(train, config)
        python = WindowCalibrator(train, config, compiled=False)
        run_fitted = 0
        for i in range(len(series)):
            a, b = compiled.update(series[i]), python.update(series[i])
            assert (a is None) == (b is None)
            if a is not None:
                _assert_same(a, b, config, train.effective_mass_kg)
                run_fitted += 1
        assert compiled.counts == python.counts
        assert compiled.reference_windows == python.reference_windows
        assert compiled._fit.constrained == python._fit.constrained
        assert compiled._fit.pattern == python._fit.pattern
        assert python._fit.kernel_windows == 0
        assert compiled._fit.kernel_windows + compiled.reference_windows == run_fitted
        fitted += run_fitted
        by_kernel += compiled._fit.kernel_windows
    assert fitted > 1500
    # every window by the kernel (binding eq. 6/7 rows included) but those of the reference: 78-97 %
    assert by_kernel > 0.75 * fitted, (by_kernel, fitted)


@pytest.mark.parametrize("seed", range(4))
def test_single_windows_compiled_equal_the_python_path(seed):
    """Free, at bounds, ill conditioned, eq. 6/7 rows binding (left to Python) and dropped, short, long."""
    rng = np.random.default_rng(100 + seed)
    config = WindowConfig(r1_bounds=(0.0, 1e-3), r2_bounds=(0.0, 1e-4))
    cases = [
        (60, 5.0, 40.0, 0.02, None),
        (60, 5.0, 40.0, 0.3, None),
        (30, 20.0, 21.0, 0.05, None),  # narrow speed range: the condition number by Jacobi
        (60, 5.0, 40.0, 0.05, 0.0),
        (60, 5.0, 40.0, 0.05, -0.05),
        (8, 10.0, 30.0, 0.01, 0.02),
        (4, 10.0, 30.0, 0.01, None),  # the fewest rows the fast path takes
        (3000, 0.0, 45.0, 0.05, None),  # beyond the kernel's stack buffer
    ]
    compiled, python = FastFit(TRAIN, config), FastFit(TRAIN, config, compiled=False)
    for n, v_lo, v_hi, noise, envelope in cases:
        x, y, upper, v = _window(rng, n, v_lo, v_hi, noise, envelope)
        xy = np.column_stack([x, y])
        upper_tol = upper + 1e-12 * np.maximum(1.0, np.abs(upper))
        a, b = (f(xy, upper, upper_tol, v, 1, stamp_ns=0, run_id=0, previous=None) for f in (compiled, python))
        _assert_same(a, b, config)
        assert compiled.pattern == python.pattern
    assert compiled.reference == python.reference
    assert compiled.constrained == python.constrained > 0  # binding rows met, solved by the LSI
    assert compiled.kernel_windows == len(cases) - compiled.reference  # binding rows included


def test_condition_number_matches_the_svd_where_the_closed_form_is_loose():
    """Windows of a narrow speed range (l2 < 1e-4 l1 of B^T B): Jacobi against numpy's SVD of x with unit columns."""
    rng = np.random.default_rng(5)
    inf_params = np.array([0.0, 0.0, 0.0, 1.0, 1.0, 1.0, 1e300, 0.0])
    checked = 0
    for width in (0.05, 0.3, 1.0, 3.0, 30.0):
        for _ in range(20):
            v = rng.uniform(20.0, 20.0 + width, 50)
            x = np.column_stack([np.ones(50), v, v * v])
            xy = np.column_stack([x, rng.normal(0.0, 0.01, 50)])
            inf = np.full(50, np.inf)
            out = kernel.fit(xy, inf, inf, inf_params, CODES[(0, 0, 0)], 0)
            unit = x / np.linalg.norm(x, axis=0)
            expected = np.linalg.cond(unit)
            if out[0] == 0:
                assert out[3] == pytest.approx(expected, rel=1e-12 * expected + 1e-12)
                checked += 1
    assert checked >= 80


def test_active_sets_are_searched_in_the_python_order():
    """The fallback search visits every active set in fast.PATTERNS order, as FastFit._box."""
    assert [9 * (p[0] + 1) + 3 * (p[1] + 1) + p[2] + 1 for p in PATTERNS] == [CODES[p] for p in PATTERNS]
    assert sorted(CODES.values()) == list(range(27))


def test_every_starting_active_set_reaches_the_same_fit():
    rng = np.random.default_rng(11)
    x, y, upper, v = _window(rng, 60, 5.0, 40.0, 0.3, None)
    xy = np.column_stack([x, y])
    config = WindowConfig(r1_bounds=(0.0, 1e-3), r2_bounds=(0.0, 1e-4))
    fits = []
    for pattern in PATTERNS:
        fit = FastFit(TRAIN, config)
        fit.pattern = pattern
        fits.append(fit(xy, upper, upper, v, 1, stamp_ns=0, run_id=0, previous=None))
        assert fit.kernel_windows == 1
    for other in fits[1:]:
        np.testing.assert_allclose(other.estimate, fits[0].estimate, rtol=0, atol=1e-15)


def test_arrays_the_kernel_cannot_read_take_the_python_path():
    rng = np.random.default_rng(3)
    x, y, upper, v = _window(rng, 40, 5.0, 40.0, 0.05, None)
    strided = np.column_stack([x, y, y])[:, :4]  # not C-contiguous
    fit = FastFit(TRAIN, WindowConfig())
    result = fit(strided, upper, upper, v, 1, stamp_ns=0, run_id=0, previous=None)
    assert fit.kernel_windows == 0 and fit.reference == 0
    same = FastFit(TRAIN, WindowConfig())(np.ascontiguousarray(strided), upper, upper, v, 1, stamp_ns=0, run_id=0,
                                          previous=None)  # fmt: skip
    _assert_same(same, result, WindowConfig())
    single = fit(strided.astype(np.float32), upper, upper, v, 1, stamp_ns=0, run_id=0, previous=None)  # float32
    assert fit.kernel_windows == 0 and fit.reference == 0 and single.sample_count == 40


@pytest.mark.parametrize(
    ("args", "message"),
    [
        ((np.zeros((5, 3)), np.zeros(5), np.zeros(5), np.zeros(8), 13, 0), "xy: expected a C-contiguous float64 array"),
        ((np.zeros((5, 4)), np.zeros(5), np.zeros(4), np.zeros(8), 13, 0), "upper, upper_tol: one entry per row of xy"),
        ((np.zeros((5, 4)), np.zeros(5), np.zeros(5), np.zeros(9), 13, 0), "params: lo[3] hi[3] max_condition k"),
        ((np.zeros((5, 4)), np.zeros(5), np.zeros(5), np.zeros(8), 27, 0), "pattern: an active-set code 0..26"),
        ((np.zeros((5, 4)), np.zeros(5, dtype=np.float32), np.zeros(5), np.zeros(8), 13, 0), "upper: expected"),
    ],
)
def test_bad_arguments_are_refused_in_one_line(args, message):
    with pytest.raises(ValueError, match=message.replace("[", r"\[").replace("]", r"\]")):
        kernel.fit(*args)
    not_a_buffer = (list(args[0]), *args[1:4], 13, 0)
    with pytest.raises(TypeError):  # the buffer protocol's own message
        kernel.fit(*not_a_buffer)


def test_a_window_of_other_trains_and_bounds():
    """Non-zero lower bounds (dropped rows counted by the kernel) and reference speeds of another train."""
    train = train_spec(adhesive_mass_fraction=0.3)
    config = WindowConfig(r0_bounds=(0.001, 0.05), reference_speeds_kmh=(30.0, 60.0, 90.0, 120.0))
    rng = np.random.default_rng(8)
    compiled, python = FastFit(train, config), FastFit(train, config, compiled=False)
    for envelope in (None, 0.05, 0.2):
        x, y, upper, v = _window(rng, 80, 5.0, 40.0, 0.05, envelope)
        xy = np.column_stack([x, y])
        a, b = (f(xy, upper, upper, v, 1, stamp_ns=0, run_id=0, previous=None) for f in (compiled, python))
        _assert_same(a, b, config, train.effective_mass_kg)
    assert compiled.kernel_windows > 0


# -- the kernel's Window against calibrator._PyWindow -------------------------------------------------


def _random_rows(rng, count):
    """Steps of 1 s with rows (x0, x1, x2, y, upper), some invalid, some negative entries or upper below 0."""
    for k in range(count):
        end_ns = (k + 1) * 1_000_000_000
        if rng.random() < 0.1:
            yield end_ns, -1, None, False
            continue
        v = rng.uniform(-0.5, 40.0) if rng.random() < 0.05 else rng.uniform(0.0, 40.0)
        upper = rng.normal(0.05, 0.1)
        regime = int(rng.choice([1, 2, 3, 4, 200]))
        yield end_ns, regime, (1.0, v, v * v, rng.normal(0.02, 0.01), upper, v, 0.0, 0.0), rng.random() < 0.9


@pytest.mark.parametrize("window_s", [3, 60, 700])
def test_window_keeps_what_the_python_window_keeps(window_s):
    """Steps, rows, counters, span and dominant regime after every step; growth past the first capacity."""
    rng = np.random.default_rng(window_s)
    c_window = kernel.Window(FastFit(TRAIN, WindowConfig())._params)
    py_window = _PyWindow(StepModel(TRAIN, WindowConfig()), 16)
    for end_ns, regime, row, keep in _random_rows(rng, 2500):
        for w in (c_window, py_window):
            w.add(end_ns, regime, row, keep)
            w.expire(end_ns - window_s * 1_000_000_000)
        for name in ("steps", "rows", "negatives", "below_zero", "speed_span", "regime"):
            assert getattr(c_window, name) == getattr(py_window, name), (name, end_ns)
        if end_ns % 97_000_000_000 == 0:
            xy, upper, upper_tol, _ = py_window.arrays()
            c_xy, c_upper, c_tol = (np.frombuffer(b) for b in c_window.view())
            assert np.array_equal(c_xy.reshape(-1, 4), xy) and np.array_equal(c_upper, upper)
            assert np.array_equal(c_tol, upper_tol)
    assert c_window.steps == py_window.steps == window_s
    c_window.clear()
    assert (c_window.steps, c_window.rows, c_window.negatives, c_window.below_zero, c_window.regime) == (0, 0, 0, 0, 0)
    assert c_window.speed_span == 0.0 and c_window.view() == (b"", b"", b"")


def test_window_ties_go_to_the_newest_regime():
    w = kernel.Window(FastFit(TRAIN, WindowConfig())._params)
    row = (1.0, 10.0, 100.0, 0.0, 1.0)
    for end_s, regime in ((1, 3), (2, 1), (3, 1), (4, 3)):
        w.add(end_s * 10**9, regime, row, True)
    assert w.regime == 3  # 2 each: coasting's step is the newest
    w.add(5 * 10**9, -1, None, False)  # an invalid step counts for no regime
    assert w.regime == 3 and w.steps == 5
    w.expire(10**9)
    assert w.regime == 1  # coasting lost its oldest step


@pytest.mark.parametrize(
    ("args", "message"),
    [
        ((0, 256, (1.0, 1.0, 1.0, 0.0, 1.0), True), "regime: -1 .* or a DrivingRegime code 0..255"),
        ((0, 1, (1.0, 1.0), True), "row: a tuple"),
        ((0, 1, [1.0, 1.0, 1.0, 0.0, 1.0], True), "row: a tuple"),
    ],
)
def test_window_refuses_bad_steps_in_one_line(args, message):
    w = kernel.Window(FastFit(TRAIN, WindowConfig())._params)
    with pytest.raises(ValueError, match=message):
        w.add(*args)
    assert w.steps == 0
    with pytest.raises(ValueError, match="params: lo"):
        kernel.Window(np.zeros(9))


def test_regime_codes_outside_uint8_count_as_unknown(runs):
    """A regime the message type cannot carry is taken from power, in both paths (as UNKNOWN is)."""
    _, train, series = runs[1]
    fits = {}
    for compiled in (True, False):
        for regime in (0, 300, -2):
            calibrator = WindowCalibrator(train, WindowConfig(), compiled=compiled)
            fits[compiled, regime] = [calibrator.update(series[i], regime) for i in range(200)]
    for key, values in fits.items():
        assert [f.regime if f else None for f in values] == [f.regime if f else None for f in fits[key[0], 0]], key


@pytest.mark.parametrize("scheme", ["forward", "midpoint", "trapezoid"])
@pytest.mark.parametrize("constraints", [(True, True), (False, True), (False, False)])
def test_pushed_samples_make_the_python_rows_bit_for_bit(scheme, constraints):
    """push: the C step model (force, limit, row, regime from power) against StepModel, on random samples with
    gaps, stops, missing power, braking (left out) and topic regimes."""
    config = WindowConfig(difference_scheme=scheme, traction_constraint=constraints[0],
                          adhesion_constraint=constraints[1], max_gap=2.0, window_length=40.0)  # fmt: skip
    step = StepModel(TRAIN, config)
    c_window = kernel.Window(FastFit(TRAIN, config)._params, step.params(kernel.STEP_PARAM_NAMES))
    py_window = _PyWindow(step, 16)
    rng = np.random.default_rng(len(scheme) + 3 * sum(constraints))
    t_ns = 0
    invalid = 0
    for k in range(3000):
        t_ns += int(rng.choice([0.5, 1.0, 1.0, 1.0, 3.0]) * 1e9)
        v = max(rng.uniform(-2.0, 45.0), 0.0)
        sample = (t_ns, t_ns * 1e-9, v, bool(rng.random() < 0.95), rng.uniform(-2e5, 4e6),
                  rng.uniform(0.0, 3e6) if rng.random() < 0.3 else 0.0, rng.normal(0.0, 0.05),
                  rng.random() if rng.random() < 0.3 else 0.0, rng.uniform(0.0, 0.02),
                  int(rng.choice([-1, -1, 1, 2, 3, 4])), t_ns - 40_000_000_000)  # fmt: skip
        flags = c_window.push(*sample), py_window.push(*sample)
        assert flags[0] == flags[1], k
        invalid += flags[0]
        for name in ("steps", "rows", "negatives", "below_zero", "speed_span", "regime"):
            assert getattr(c_window, name) == getattr(py_window, name), (name, k)
        if k % 50 == 0:
            xy, upper, upper_tol, _ = py_window.arrays()
            c_xy, c_upper, c_tol = (np.frombuffer(b) for b in c_window.view())
            assert c_xy.tobytes() == xy.tobytes() and c_upper.tobytes() == upper.tobytes()
            assert c_tol.tobytes() == upper_tol.tobytes()
    assert 100 < invalid < 2000 and c_window.rows > 10
    c_window.clear()
    c_window.push(*sample)  # after clear(), no step from the sample before it
    assert c_window.steps == 0


def test_push_needs_the_step_model():
    window = kernel.Window(FastFit(TRAIN, WindowConfig())._params)
    with pytest.raises(ValueError, match="push: this Window was made without step_params"):
        window.push(0, 0.0, 10.0, True, 1e5, 0.0, 0.0, 0.0, 0.0, -1, 0)
    with pytest.raises(ValueError, match=r"step_params: the 19 values of StepModel\.params\(STEP_PARAM_NAMES\)"):
        kernel.Window(FastFit(TRAIN, WindowConfig())._params, np.zeros(18))


def _same_value(x, y) -> bool:
    """Equal, NaN equal to NaN (tuples item by item)."""
    if isinstance(x, tuple):
        return len(x) == len(y) and all(_same_value(p, q) for p, q in zip(x, y))
    return x == y or (isinstance(x, float) and math.isnan(x) and math.isnan(y))


def _same_fit(a, b) -> bool:
    if a is None or b is None:
        return a is b
    return all(_same_value(getattr(a, name), getattr(b, name)) for name in a.__dataclass_fields__)


@pytest.mark.parametrize("compiled", [True, False])
def test_a_calibrator_copied_or_pickled_mid_run_goes_on_alike(runs, compiled):
    """copy.deepcopy and pickle (multiprocessing) carry the window along: the copies' next fits equal the original's."""
    import copy
    import pickle

    _, train, series = runs[2]
    calibrator = WindowCalibrator(train, WindowConfig(), compiled=compiled)
    for i in range(150):
        calibrator.update(series[i])
    copies = [copy.deepcopy(calibrator), pickle.loads(pickle.dumps(calibrator))]
    assert all(type(c._window) is type(calibrator._window) for c in copies)
    fitted = 0
    for i in range(150, len(series)):
        fit = calibrator.update(series[i])
        assert all(_same_fit(fit, c.update(series[i])) for c in copies), i
        fitted += fit is not None
    assert fitted > 200


def test_window_state_is_checked_when_restored():
    window = kernel.Window(FastFit(TRAIN, WindowConfig())._params)
    restore, (state,) = window.__reduce__()
    assert restore(state).steps == 0
    with pytest.raises(ValueError, match="Window state: a tuple of 20 items"):
        restore(state[:-1])
    with pytest.raises(ValueError, match="Window state: inconsistent item sizes"):
        restore((*state[:2], b"123", *state[3:]))


def test_the_calibrator_says_how_it_fits():
    assert WindowCalibrator(TRAIN, WindowConfig()).fit_path == "C kernel"
    assert WindowCalibrator(TRAIN, WindowConfig(), compiled=False).fit_path == "Python"
    assert WindowCalibrator(TRAIN, WindowConfig(), fast=False).fit_path == "reference solver"
    assert WindowCalibrator(TRAIN, WindowConfig(gof="sae")).fit_path == "reference solver"


# -- the step model goes to the kernel by name (issue 23: 19 values by position, only their count checked) ----------
FLAGS = ("traction", "adhesion", "exclude_braking")


def test_the_kernel_reads_each_step_value_under_its_own_name():
    """One value set at a time: the kernel's Window reads it into the field of that name and no other, so its name
    table (STEP_PARAM_NAMES) and its reads cannot go out of step unnoticed."""
    names = kernel.STEP_PARAM_NAMES
    assert sorted(names) == sorted(StepModel(TRAIN, WindowConfig()).values())
    for name in names:
        read = kernel._read_step_params(np.array([2.0 if n == name else 0.0 for n in names]))
        assert set(read) == set(names)
        assert read[name] == (1.0 if name in FLAGS else 2.0), name
        assert all(value == 0.0 for other, value in read.items() if other != name), (name, read)


def test_the_step_model_is_ordered_by_the_kernels_names():
    """StepModel.params(names) places every value by name: a reordering on either side changes nothing, a name
    that one side lacks is an error at construction of the Window."""
    step = StepModel(TRAIN, WindowConfig(exclude_braking=True))
    values = step.values()
    names = kernel.STEP_PARAM_NAMES
    assert kernel._read_step_params(step.params(names)) == values
    reordered = tuple(reversed(names))
    np.testing.assert_array_equal(step.params(reordered), [values[n] for n in reordered])
    assert step.params(reordered)[0] == values[names[-1]] != step.params(names)[0]
    with pytest.raises(ValueError, match="step model names"):
        step.params((*names[:-1], "exclude_braking_typo"))
    with pytest.raises(ValueError, match="step model names"):
        step.params(names[:-1])


def test_a_kernel_name_the_model_lacks_fails_when_the_window_is_built(monkeypatch):
    """The calibrator asks the kernel for its order of names; with a name the model lacks, building the window fails
    instead of misreading."""
    step = StepModel(TRAIN, WindowConfig())
    fit = FastFit(TRAIN, WindowConfig())

    class Renamed:
        STEP_PARAM_NAMES = (*kernel.STEP_PARAM_NAMES[:-1], "unknown")
        Window = kernel.Window

    monkeypatch.setattr(fast_module, "_kernel", Renamed)
    with pytest.raises(ValueError, match="step model names"):
        fit.new_window(step)
