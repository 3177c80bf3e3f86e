"""Outlier gating and recovery rules of the resistance UKF (no ROS); the rules are in docs/reliability.md.

A separate ParamSet from :class:`~train_calib.estimation.config.UKFConfig` (the paper's Table 1 and the
estimation options): these are the engineering safeguards against faulty inputs. ``ukf_node`` declares both.
"""

from __future__ import annotations

from dataclasses import dataclass

from ..params import ParamSet, param


@dataclass(frozen=True)
class SafeguardConfig(ParamSet):
    """Gating of position outliers and recovery of an inconsistent filter (resistance UKF)."""

    position_gate: float = param(
        0.999999,
        "a position measurement whose innovation exceeds this chi-square quantile (1 dof, of its predicted "
        "variance) is not used: the step updates the speed only (a multipath fix); 1: no gate",
        low=0.5,
        high=1.0,
    )
    gate_accel_std: float = param(
        0.3,
        "model error the position gate allows beyond the filter's covariance: an acceleration error of this std "
        "over the step adds (std dt^2 / 2)^2 to the innovation variance (a phase change within a 10 s step; the "
        "paper's filter has no process noise)",
        unit="m/s^2",
        low=0.0,
    )
    gate_relock_time: float = param(
        10.0,
        "when the position has been gated for this long in a row, s is re-initialised at the measurement "
        "(health RESET): the position really moved (e.g. dead reckoning drifted in a tunnel)",
        unit="s",
        low=0.0,
    )
    nis_reset_windows: int = param(
        3,
        "when the NIS window stays above its limit (DEGRADED) for this many windows in a row, s and v are "
        "re-initialised at the measurement with their initial covariance, r and its covariance kept (health "
        "RESET); 0: never",
        low=0,
        high=100000,
    )


__all__ = ["SafeguardConfig"]
