"""Train file loading and validation; the physics helpers."""

from __future__ import annotations

import numpy as np
import pytest
import yaml

from train_calib import physics
from train_calib.errors import ConfigError
from train_calib.train import load_train


def test_loads_train(data_dir):
    train = load_train(data_dir / "small_train.yaml")
    assert train.name == "test-emu"
    assert train.davis.as_tuple() == (0.0073, 0.00012, 0.000045)
    assert train.effective_mass_kg == pytest.approx(400e3 * 1.06)
    assert train.transition_speed_ms == pytest.approx(9.5 / 0.9)
    assert train.transmission_efficiency == 0.85 and train.tunnel_factor == 0.6


def test_envelope_effort_then_power_then_adhesion(data_dir):
    train = load_train(data_dir / "small_train.yaml")
    v = np.array([1.0, 5.0, 20.0, 40.0])
    expected = np.minimum(np.minimum(0.9, 9.5 / v), physics.adhesion_limit(v, 0.5, 1.06))
    assert np.allclose(train.tractive_envelope(v), expected)
    assert train.tractive_envelope(20.0) == pytest.approx(9.5 / 20.0)


def test_curtius_kniffler():
    assert physics.adhesion_coefficient(0.0) == pytest.approx(0.161 + 7.5 / 44)
    assert physics.adhesion_coefficient(100 / 3.6) == pytest.approx(0.161 + 7.5 / 144)


def test_davis_with_tunnel():
    assert physics.davis(10.0, 0.01, 0.001, 0.0001) == pytest.approx(0.01 + 0.01 + 0.01)
    assert physics.davis(10.0, 0.01, 0.001, 0.0001, tunnel_fraction=1.0, tunnel_factor=0.5) == pytest.approx(0.035)


@pytest.mark.parametrize(
    "mutate, key, problem",
    [
        (lambda d: d.pop("mass_t"), "mass_t", "missing required key"),
        (lambda d: d["davis"].update(r2="x"), "davis.r2", "expected a number"),
        (lambda d: d["davis"].update(r0=-0.01), "davis.r0", "out of range"),
        (lambda d: d.update(rotating_mass_factor=0.9), "rotating_mass_factor", "out of range"),
        (lambda d: d.update(max_brake_decel=0), "max_brake_decel", "greater than 0"),
        (lambda d: d.update(davis=[1, 2, 3]), "davis", "expected a mapping"),
        (lambda d: d.update(transmission_efficiency=1.5), "transmission_efficiency", "out of range"),
        (lambda d: d.update(tunnel_factr=0.5), "tunnel_factr", "unknown key (did you mean tunnel_factor?)"),
        (lambda d: d["davis"].update(r3=0.1), "davis.r3", "unknown key (known keys: r0, r1, r2)"),
    ],
)
def test_invalid_train_files(tmp_path, data_dir, mutate, key, problem):
    data = yaml.safe_load((data_dir / "small_train.yaml").read_text())
    mutate(data)
    path = tmp_path / "train.yaml"
    path.write_text(yaml.safe_dump(data))
    with pytest.raises(ConfigError) as err:
        load_train(path)
    assert str(err.value).startswith(f"{path}: {key}: ") and problem in str(err.value)
    assert "\n" not in str(err.value)


@pytest.mark.parametrize("c1", [0.0, 0.01, -0.005, -0.02])
def test_envelope_switches_at_the_first_crossing(c1):
    c0, c2 = 0.6, 6.0
    v_t = physics.transition_speed(c0, c2, c1)
    v = np.linspace(0.1, 80.0, 2000)
    f = physics.tractive_envelope(v, c0, c2, c1)
    if np.isfinite(v_t):
        assert c0 + c1 * v_t == pytest.approx(c2 / v_t)
        below, above = v <= v_t, v > v_t
        assert np.allclose(f[below], np.maximum(c0 + c1 * v[below], 0.0))
        assert np.allclose(f[above], c2 / v[above])  # not min(): with c1 < 0 the line re-crosses later
    else:
        assert np.allclose(f, np.maximum(c0 + c1 * v, 0.0))
    assert np.all(f >= 0.0)
