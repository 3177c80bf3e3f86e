"""Regime rule (Cunillera Section 3.2): per-sample and vectorised, total on any input, hold detection."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from train_calib.estimation import (
    BRAKING,
    COASTING,
    CRUISING,
    TRACTION,
    UNKNOWN,
    RegimeClassifier,
    RegimeConfig,
    classify_regimes,
)


@pytest.mark.parametrize(
    "effort, accel, expected",
    [
        (0.0, -0.05, COASTING),
        (0.025, 0.3, COASTING),  # the band is closed
        (-0.025, -0.3, COASTING),
        (0.0251, 0.061, TRACTION),
        (0.3, 0.2, TRACTION),
        (0.08, 0.0, CRUISING),  # traction holding the speed
        (0.08, 0.06, CRUISING),
        (0.08, -0.06, CRUISING),
        (0.08, -0.2, TRACTION),  # traction uphill, decelerating: still traction (by the effort)
        (-0.3, -0.4, BRAKING),
        (-0.05, 0.01, CRUISING),  # braking downhill to hold the speed
        (math.nan, 0.0, UNKNOWN),
        (0.1, math.nan, UNKNOWN),
        (math.inf, 1.0, TRACTION),
        (-math.inf, -1.0, BRAKING),
    ],
)
def test_rule(effort, accel, expected):
    assert RegimeClassifier().classify(effort, accel) == expected
    assert classify_regimes([effort], [accel])[0] == expected


def test_constants_match_the_message():
    assert (UNKNOWN, TRACTION, CRUISING, COASTING, BRAKING) == (0, 1, 2, 3, 4)


def test_speed_standstill_and_bad_types():
    c = RegimeClassifier()
    assert c.classify(0.0, 0.0, 0.0) == UNKNOWN
    assert c.classify(0.0, 0.0, 0.29) == UNKNOWN
    assert c.classify(0.0, -0.1, 0.31) == COASTING
    assert c.classify(0.0, 0.0, math.nan) == UNKNOWN
    assert c.classify(None, 0.0) == UNKNOWN
    assert c.classify("x", 0.0) == UNKNOWN
    assert c.classify(0.0, 0.0, "fast") == UNKNOWN
    out = classify_regimes([0.0, 0.0, 0.5], [0.0, -0.1, 0.5], speed=[0.0, 10.0, np.nan])
    assert out.tolist() == [UNKNOWN, COASTING, UNKNOWN] and out.dtype == np.uint8


def test_hold_detection():
    """A low-speed hold (effort r + g = 0.02, a = 0) is cruising; coasting (effort 0, a = -0.02) is not."""
    cfg = RegimeConfig(hold_detection=True)
    c = RegimeClassifier(cfg)
    assert c.classify(0.02, 0.0) == CRUISING
    assert c.classify(0.0, -0.02) == COASTING
    assert c.classify(0.005, -0.02) == COASTING
    assert RegimeClassifier().classify(0.02, 0.0) == COASTING  # the paper's rule
    assert classify_regimes([0.02, 0.0], [0.0, -0.02], cfg).tolist() == [CRUISING, COASTING]


finite_or_nan = st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.none())


@settings(max_examples=300, deadline=None)
@given(
    effort=st.floats(allow_nan=True, allow_infinity=True),
    accel=st.floats(allow_nan=True, allow_infinity=True),
    speed=finite_or_nan,
    hold=st.booleans(),
    tol=st.floats(0.0, 0.1),
    cruise=st.floats(0.0, 0.2),
)
def test_vectorised_equals_per_sample_and_is_total(effort, accel, speed, hold, tol, cruise):
    cfg = RegimeConfig(effort_tolerance=tol, cruise_tolerance=cruise, hold_detection=hold)
    one = RegimeClassifier(cfg).classify(effort, accel, speed)
    vec = classify_regimes([effort], [accel], cfg, speed=None if speed is None else [speed])[0]
    assert one == vec and one in (UNKNOWN, TRACTION, CRUISING, COASTING, BRAKING)
