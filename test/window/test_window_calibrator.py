"""The streaming WindowCalibrator: window bookkeeping, runs, gaps, missing power, and offline equality."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from window_synthetic import TRUTH, euler_run, train_spec

from train_calib.window import (
    COASTING,
    WindowCalibrator,
    WindowConfig,
    calibrate_series,
    fit_window,
    summarize_by_regime,
)

TRAIN = train_spec()


@pytest.fixture(scope="module")
def run():
    return euler_run(speed_noise=0.03, power_noise=0.01, rng=4)


def test_streaming_equals_fit_window_on_the_same_samples(run):
    series = run.series
    config = WindowConfig(window_length=10.0)
    calibrator = WindowCalibrator(TRAIN, config)
    fits = [calibrator.update(series[i]) for i in range(120)]
    assert fits[0] is None  # no step yet
    for k in (15, 60, 119):
        streamed = fits[k]
        sl = slice(k - 10, k + 1)  # 11 samples = 10 steps ending at sample k
        direct = fit_window(series.t[sl], series.v[sl], series.power_consumed[sl], series.power_regenerated[sl],
                            series.track_force[sl], series.tunnel_fraction[sl], TRAIN, config,
                            v_variance=series.v_variance[sl], stamp_ns=int(series.stamp_ns[k]))  # fmt: skip
        assert streamed.sample_count == 10
        assert streamed.stamp_ns == series.stamp_ns[k]
        np.testing.assert_allclose(streamed.estimate, direct.estimate, rtol=1e-9, atol=1e-15)
        assert streamed.gof_value == pytest.approx(direct.gof_value, rel=1e-9)
        assert streamed.speed_span == pytest.approx(direct.speed_span, rel=1e-12)


def test_window_never_exceeds_its_length(run):
    counts = [f.sample_count for f in calibrate_series(run.series, TRAIN, WindowConfig(window_length=30.0))]
    assert max(counts) == 30
    assert counts[:6] == [0, 0, 1, 2, 3, 4]  # the first two samples are below min_speed (2 m/s)


def test_new_run_restarts_the_window_and_keeps_published_values():
    series = euler_run().series
    calibrator = WindowCalibrator(TRAIN, WindowConfig(window_length=10.0))
    last = None
    for i in range(20):  # accelerating: well posed
        last = calibrator.update(series[i]) or last
    assert not last.ill_posed
    m = dataclasses.replace(series[20], run_id=1)
    fit = calibrator.update(m)
    assert fit is None  # first sample of the new run: no step yet
    fit = calibrator.update(dataclasses.replace(series[21], run_id=1))
    assert fit.sample_count == 1 and fit.ill_posed and fit.run_id == 1
    assert (fit.r0, fit.r1, fit.r2) == (last.r0, last.r1, last.r2)
    assert calibrator.counts["new_run"] == 1


def test_out_of_order_non_finite_and_missing_power_are_counted(run):
    series = run.series
    calibrator = WindowCalibrator(TRAIN, WindowConfig(window_length=10.0))
    for i in range(20):
        calibrator.update(series[i])
    assert calibrator.update(series[10]) is None
    assert calibrator.update(dataclasses.replace(series[20], v=float("nan"))) is None
    no_power = dataclasses.replace(series[20], power_valid=False)
    assert calibrator.update(no_power) is None
    fit = calibrator.update(series[21])  # the step 20 -> 21 has no force at its start: not used
    assert fit.sample_count == 9
    assert calibrator.counts["out_of_order"] == 1
    assert calibrator.counts["non_finite"] == 1
    assert calibrator.counts["no_power"] == 1


def test_a_run_without_power_holds_only_one_window_of_steps(run):
    """Without power the calibrator publishes nothing, and what it holds stays one window long (it leaked
    one entry per sample before: hours without power on board grew it without bound)."""
    series = run.series
    calibrator = WindowCalibrator(TRAIN, WindowConfig(window_length=10.0))
    for i in range(len(series.t)):
        assert calibrator.update(dataclasses.replace(series[i], power_valid=False)) is None
    assert len(series.t) > 100
    assert calibrator._window.steps <= 10 and calibrator._window.rows <= 10
    assert calibrator.counts["no_power"] == len(series.t)


def test_gap_breaks_the_difference(run):
    series = run.series
    calibrator = WindowCalibrator(TRAIN, WindowConfig(window_length=30.0, max_gap=5.0))
    for i in range(40):
        calibrator.update(series[i])
    invalid_before = calibrator.counts["invalid_step"]
    late = dataclasses.replace(series[40], stamp_ns=int(series.stamp_ns[39] + 8e9))
    fit = calibrator.update(late)
    assert fit.sample_count == 29 - 7  # 8 s gap: the oldest steps expire and the step across it is not used
    assert calibrator.counts["invalid_step"] == invalid_before + 1


def test_per_regime_summary_on_exact_data():
    exact = euler_run()
    fits = calibrate_series(exact.series, TRAIN, WindowConfig(window_length=30.0), regimes=exact.regime)
    stats = summarize_by_regime(fits, TRAIN.effective_mass_kg)
    truth_force = np.array(TRUTH.as_tuple()) * TRAIN.effective_mass_kg
    assert {1, 2, 3, 4} <= set(stats)
    for s in stats.values():
        assert s.windows + s.ill_posed > 0
        if s.windows:
            np.testing.assert_allclose(s.median, truth_force, rtol=1e-6)
            np.testing.assert_allclose(s.specific_median, TRUTH.as_tuple(), rtol=1e-6)
    assert stats[COASTING].name == "coasting"
    assert sum(s.windows + s.ill_posed for s in stats.values()) == len(fits)
