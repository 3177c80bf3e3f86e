"""The whole run's regimes from a recorded run's columns: what ``pipeline.whole_run_regimes`` (records of the offline
chain) and ``summary.whole_run_regimes`` (topics of a replay's output bag) both classify, so that the two give the
same labels from the same inputs.

Units: efforts and forces N/kg, accelerations m/s^2, speeds m/s, times s, positions m, Gamma(s) J/kg.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from .config import RegimeConfig
from .regimes import classify_regimes

ESTIMATE_COLUMNS = ("effort", "acceleration", "v", "effort_known", "resistance", "track_force", "v_measured", "t")
"""The columns of the published estimates the classifier reads (``t``: the stamp, s, any origin)."""


def classify_whole_run(
    est: Mapping[str, Any],
    cfg: RegimeConfig,
    power: Sequence[int],
    position: Sequence[float] | None,
    track_force_integral: Sequence[float] | None,
) -> np.ndarray:
    """The regime of every estimate given the whole run (``classify_regimes(..., smooth=True)``; per sample with the
    stateless ``rule``), with the inputs regime_node gives the classifier: ``est`` the estimates' columns
    (``ESTIMATE_COLUMNS``; NaN where unknown), ``power`` each one's traction power state (POWER_*, -1: not measured),
    ``position`` and ``track_force_integral`` its measurement's s and Gamma(s) (NaN where unknown)."""
    return classify_regimes(
        est["effort"], est["acceleration"], cfg, speed=est["v"], effort_known=np.asarray(est["effort_known"], bool),
        opposing_force=np.asarray(est["resistance"], float) + np.asarray(est["track_force"], float),
        speed_measured=est["v_measured"], time=est["t"], power=power, track_force=est["track_force"],
        position=position, track_force_integral=track_force_integral, smooth=cfg.method != "rule",
    )  # fmt: skip
