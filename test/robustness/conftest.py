"""The fault tests' shared scenario: a physics-consistent 1 Hz run (faultlib) and its fault-free result."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))
from faultlib import CONVERGING, make_scenario, write_bag

from train_calib.pipeline import run_bag


@pytest.fixture(scope="module")
def scenario(tmp_path_factory):
    """The default scenario (faultlib.DEFAULT_SCRIPT, seed 7), built once per test module."""
    return make_scenario(tmp_path_factory.mktemp("scenario"))


@pytest.fixture(scope="module")
def reference(scenario, tmp_path_factory):
    """The scenario's fault-free bag through the core chain with the converging filter."""
    bag = write_bag(tmp_path_factory.mktemp("reference") / "bag", scenario.events)
    return run_bag(bag, scenario.track, scenario.train, ukf=CONVERGING)
