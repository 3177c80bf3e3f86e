"""Sliding-window calibration of the running resistance with traction power (De Martinis & Corman 2019).

ROS-free core of window_calib_node. Inputs per sample: time, speed, track force g(s), tunnel fraction
and pantograph power; output per window: A, B, C (N units, whole train) and r0, r1, r2 (per effective
mass), the GoF, the dominant regime and whether the window is ill posed. See docs/window.md.
"""

from .calibrator import WindowCalibrator, calibrate_series
from .config import GOF_KINDS, WindowConfig
from .fit import WindowFit, fit_rows, fit_window, scaled_condition_number
from .model import (
    BRAKING,
    COASTING,
    CRUISING,
    REGIME_NAMES,
    SAUTHOFF_TEXTBOOK_ABC,
    TRACTION,
    UNKNOWN,
    DifferenceRows,
    difference_rows,
    envelope_limit,
    regime_from_power,
    tractive_force,
)
from .solvers import Solution, multistart, objective, solve
from .summary import RegimeStats, summarize_by_regime

__all__ = [
    "BRAKING",
    "COASTING",
    "CRUISING",
    "GOF_KINDS",
    "REGIME_NAMES",
    "SAUTHOFF_TEXTBOOK_ABC",
    "TRACTION",
    "UNKNOWN",
    "DifferenceRows",
    "RegimeStats",
    "Solution",
    "WindowCalibrator",
    "WindowConfig",
    "WindowFit",
    "calibrate_series",
    "difference_rows",
    "envelope_limit",
    "fit_rows",
    "fit_window",
    "multistart",
    "objective",
    "regime_from_power",
    "scaled_condition_number",
    "solve",
    "summarize_by_regime",
    "tractive_force",
]
