"""Their eq. 3-7 as implemented in train_calib.window.model, against hand computations."""

from __future__ import annotations

import math

import numpy as np
import pytest
from window_synthetic import train_spec

from train_calib.window import WindowConfig, difference_rows, envelope_limit, regime_from_power, tractive_force
from train_calib.window.model import BRAKING, COASTING, CRUISING, TRACTION, UNKNOWN


def test_tractive_force_from_power():
    train = train_spec()
    # traction: wheel gets eta * P; F = eta P / v
    assert tractive_force(20.0, 850e3, 0.0, train, 2.0) == pytest.approx(0.85 * 850e3 / 20.0, rel=1e-12)
    # electric braking: the pantograph gets eta * wheel power; F = -P_reg / (eta v)
    assert tractive_force(25.0, 0.0, 500e3, train, 2.0) == pytest.approx(-500e3 / (0.85 * 25.0), rel=1e-12)
    # below min_speed there is no force (v -> 0 guard)
    assert math.isnan(tractive_force(1.9, 850e3, 0.0, train, 2.0))
    out = tractive_force(np.array([0.0, 2.0]), np.array([1e5, 1e5]), np.zeros(2), train, 2.0)
    assert math.isnan(out[0]) and out[1] == pytest.approx(0.85 * 1e5 / 2.0)


def test_tractive_force_net_of_auxiliary_power():
    train = train_spec(auxiliary_power_kw=100.0)
    assert tractive_force(20.0, 100e3, 0.0, train, 2.0) == pytest.approx(0.0, abs=1e-9)  # coasting, hotel load only
    assert tractive_force(20.0, 600e3, 0.0, train, 2.0) == pytest.approx(0.85 * 500e3 / 20.0, rel=1e-12)
    # braking feeds the hotel load first: wheel power = (P_reg + P_aux) / eta
    assert tractive_force(20.0, 0.0, 300e3, train, 2.0) == pytest.approx(-(300e3 + 100e3) / (0.85 * 20.0), rel=1e-12)


def test_envelope_is_min_of_effort_power_and_adhesion():
    train = train_spec(adhesive_mass_fraction=0.2)
    cfg = WindowConfig()
    v = np.array([5.0, 12.0, 30.0])
    mu = 0.161 + 7.5 / (3.6 * v + 44.0)
    adhesion = mu * 9.81 * 0.2 / 1.06
    expected = np.minimum(np.minimum(0.9, 9.5 / v), adhesion)
    np.testing.assert_allclose(envelope_limit(v, train, cfg), expected, rtol=1e-12)
    assert adhesion[0] < 0.9  # the adhesion limit binds at 5 m/s here
    only_power = envelope_limit(v, train, cfg.replace(adhesion_constraint=False))
    np.testing.assert_allclose(only_power, np.minimum(0.9, 9.5 / v), rtol=1e-12)
    assert np.all(np.isinf(envelope_limit(v, train, cfg.replace(adhesion_constraint=False, traction_constraint=False))))


def test_forward_rows_by_hand():
    train = train_spec()
    cfg = WindowConfig(adhesion_constraint=False)
    t = [0.0, 1.0, 2.0, 9.0]
    v = [10.0, 10.5, 10.8, 12.0]
    f = [0.4, 0.3, np.nan, 0.2]
    g = [0.01, 0.02, 0.0, 0.0]
    tau = [0.0, 1.0, 0.0, 0.0]
    rows = difference_rows(t, v, f, g, tau, train, cfg, v_variance=[0.01, 0.01, 0.04, 0.01])
    assert len(rows) == 3
    np.testing.assert_allclose(rows.x[0], [1.0, 10.0, 100.0])
    np.testing.assert_allclose(rows.x[1], [1.0, 10.5, 10.5**2 * (1 + 0.6)])  # tunnel: C (1 + f_tun)
    np.testing.assert_allclose(rows.acceleration, [0.5, 0.3, 1.2 / 7.0])
    assert rows.y[0] == pytest.approx(0.4 - 0.01 - 0.5)
    assert rows.y[1] == pytest.approx(0.3 - 0.02 - 0.3)
    # eq. 7 with a 2-sigma margin of the acceleration: min(c0, c2/v) - g - a + 2 sqrt(var_k + var_k+1)/dt
    assert rows.upper[0] == pytest.approx(min(0.9, 9.5 / 10.0) - 0.01 - 0.5 + 2.0 * math.sqrt(0.02))
    assert list(rows.valid) == [True, True, False]  # third: no force at sample 2, and a 7 s gap > max_gap
    np.testing.assert_allclose(rows.t_end, [1.0, 2.0, 9.0])


def test_midpoint_and_trapezoid_rows():
    train = train_spec()
    t, v, f, g, tau = [0.0, 1.0], [10.0, 12.0], [0.5, 0.3], [0.01, 0.03], [0.0, 0.0]
    mid = difference_rows(t, v, f, g, tau, train, WindowConfig(difference_scheme="midpoint"))
    trap = difference_rows(t, v, f, g, tau, train, WindowConfig(difference_scheme="trapezoid"))
    np.testing.assert_allclose(mid.x[0], [1.0, 11.0, (100.0 + 144.0) / 2])
    assert mid.y[0] == pytest.approx(0.5 - 0.02 - 2.0)
    assert trap.y[0] == pytest.approx(0.4 - 0.02 - 2.0)


def test_step_across_runs_is_not_valid():
    train = train_spec()
    rows = difference_rows([0, 1, 2], [10, 11, 12], [0.3, 0.3, 0.3], [0, 0, 0], [0, 0, 0], train, WindowConfig(),
                           segment=[0, 0, 1])  # fmt: skip
    assert list(rows.valid) == [True, False]


def test_regime_from_power():
    cfg = WindowConfig()  # effort tolerance 0.025 N/kg, cruise tolerance 0.04 m/s^2
    f = np.array([0.3, 0.3, 0.01, -0.3, -0.3, 0.3, np.nan])
    a = np.array([0.3, 0.02, -0.05, -0.5, -0.01, -0.2, 0.0])
    expected = [TRACTION, CRUISING, COASTING, BRAKING, CRUISING, TRACTION, UNKNOWN]
    assert list(regime_from_power(f, a, cfg)) == expected
