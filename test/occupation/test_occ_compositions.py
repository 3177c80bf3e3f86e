"""TYPES.yaml: defaults from the train file with overrides, bounds, and one-line errors."""

from __future__ import annotations

import shutil

import pytest
import yaml

from train_calib.errors import ConfigError
from train_calib.occupation.compositions import DECISION_NAMES, MODEL_NAMES, load_train_types

BOUNDS = {
    "c0": [0.2, 0.7],
    "c2": [2.5, 12.0],
    "r0": [0.010, 0.025],
    "r2": [1.5e-5, 5.0e-5],
    "b_limit": [0.24, 0.9],
    "theta_cruise": [0.8, 1.02],
}


@pytest.fixture
def types_dir(tmp_path, data_dir):
    (tmp_path / "trains").mkdir()
    shutil.copy(data_dir / "small_train.yaml", tmp_path / "trains" / "emu.yaml")
    (tmp_path / "types").mkdir()
    return tmp_path / "types"


def _write(folder, doc) -> str:
    path = folder / "TYPES.yaml"
    path.write_text(yaml.safe_dump(doc), encoding="utf-8")
    return path


def _doc(**changes):
    doc = {
        "name": "test",
        "bounds": dict(BOUNDS),
        "defaults": {"b_limit": 0.5},
        "compositions": [
            {"name": "EMU4", "length_m": 100, "train": "../trains/emu.yaml", "defaults": {"r1": 2.0e-4}},
            {
                "name": "LOCO",
                "length_m": 282,
                "defaults": dict(c0=0.4, c2=5.0, r0=0.02, r1=3.3e-4, r2=3e-5, b_stop=0.66),
                "bounds": {"c2": [3.0, 12.0]},
            },
        ],
    }
    doc.update(changes)
    return doc


def test_defaults_layering_and_bounds(types_dir):
    types = load_train_types(_write(types_dir, _doc()))
    assert types.names == ["EMU4", "LOCO"] and types.lengths() == {"EMU4": 100.0, "LOCO": 282.0}
    emu = types["EMU4"]
    # train file: c0 0.9, c2 9.5, davis 0.0073 / 1.2e-4 / 4.5e-5, brake 0.66; file default b_limit; own r1
    assert emu.defaults == pytest.approx(
        dict(c0=0.9, c1=0.0, c2=9.5, r0=0.0073, r1=2.0e-4, r2=4.5e-5, b_limit=0.5, b_stop=0.66, theta_cruise=1.0)
    )
    assert emu.train_file.endswith("emu.yaml")
    assert set(emu.bounds) == set(DECISION_NAMES) and emu.bounds["c2"] == (2.5, 12.0)
    assert types["LOCO"].bounds["c2"] == (3.0, 12.0) and types["LOCO"].bounds["c0"] == (0.2, 0.7)
    p = types["LOCO"].model_params(b_limit=0.3)
    assert p["b_limit"] == 0.3 and p["length_m"] == 282.0 and set(MODEL_NAMES) <= set(p)
    assert "LOCO" in types and "X" not in types
    with pytest.raises(KeyError):
        types["X"]


@pytest.mark.parametrize(
    ("change", "key", "problem"),
    [
        ({"bounds": {**BOUNDS, "c0": [0.7, 0.2]}}, "bounds.c0", "upper bound 0.2 must exceed lower bound 0.7"),
        ({"bounds": {k: v for k, v in BOUNDS.items() if k != "r2"}}, "bounds", "missing bounds for r2"),
        ({"bounds": {**BOUNDS, "r1": [0, 1e-3]}}, "bounds.r1", "not a calibrated parameter"),
        ({"bounds": {**BOUNDS, "c2": 5}}, "bounds.c2", "expected [low, high]"),
        ({"defaults": {"c3": 1}}, "defaults.c3", "unknown parameter"),
        ({"defaults": {"r0": 5}}, "defaults.r0", "out of range"),
        ({"compositions": []}, "compositions", "needs at least 1 entries"),
    ],
)
def test_errors(types_dir, change, key, problem):
    path = _write(types_dir, _doc(**change))
    with pytest.raises(ConfigError) as err:
        load_train_types(path)
    assert str(err.value).startswith(f"{path}: {key}: ") and problem in str(err.value)


def test_composition_errors(types_dir):
    doc = _doc()
    doc["compositions"].append(dict(doc["compositions"][0]))
    with pytest.raises(ConfigError, match=r"compositions\[2\]\.name: duplicate composition 'EMU4'"):
        load_train_types(_write(types_dir, doc))
    doc = _doc()
    doc["compositions"][0]["train"] = "../trains/none.yaml"
    with pytest.raises(ConfigError, match=r"compositions\[0\]\.train: train file '../trains/none.yaml' not found"):
        load_train_types(_write(types_dir, doc))
    doc = _doc()
    del doc["compositions"][1]["defaults"]["r2"]
    with pytest.raises(ConfigError, match=r"compositions\[1\]: no value for r2"):
        load_train_types(_write(types_dir, doc))
    doc = _doc()
    doc["compositions"][0]["length_m"] = -3
    with pytest.raises(ConfigError, match=r"compositions\[0\]\.length_m: -3 m is out of range"):
        load_train_types(_write(types_dir, doc))
