"""Fixtures of the occupation tests: the 6 km test line and a composition on it."""

from __future__ import annotations

from pathlib import Path

import pytest

from train_calib.occupation.compositions import Composition
from train_calib.track import load_track

HERE = Path(__file__).resolve().parent
DEFAULTS = dict(
    c0=0.562, c1=0.0, c2=6.21, r0=0.0153, r1=2.162e-4, r2=4.08e-5, b_limit=0.66, b_stop=0.66, theta_cruise=1.0
)
BOUNDS = dict(
    c0=(0.2, 0.7), c2=(2.5, 12.0), r0=(0.010, 0.025), r2=(1.5e-5, 5.0e-5), b_limit=(0.24, 0.9), theta_cruise=(0.8, 1.02)
)


@pytest.fixture(scope="session")
def line():
    """6 km, stations West (150 m) and East (5850 m), 19 contiguous sections of 180-440 m."""
    return load_track(HERE / "data" / "line_6km.yaml")


@pytest.fixture(scope="session")
def composition():
    """A VIRM6-like composition with the paper's defaults and the bundled bounds (no train file)."""
    return Composition("VIRM6", 162.0, dict(DEFAULTS), dict(BOUNDS))
