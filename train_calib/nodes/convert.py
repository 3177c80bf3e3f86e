"""Core records <-> train_calib_msgs messages (rclpy). Field names and units are the same on both sides.

Readers (``*_from_msg``) are duck-typed, so they also accept rosbags messages decoded from a bag.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from builtin_interfaces.msg import Time
from train_calib_msgs.msg import DrivingFeatures, DrivingRegime, ResistanceEstimate, TrackMeasurement

from ..estimation.features import Features
from ..estimation.records import EstimateSample
from ..measurement import Measurement

NS = 1_000_000_000


def stamp_to_ns(stamp: Any) -> int:
    return int(stamp.sec) * NS + int(stamp.nanosec)


def time_msg(t_ns: int) -> Time:
    return Time(sec=int(t_ns // NS), nanosec=int(t_ns % NS))


# -- TrackMeasurement -------------------------------------------------------------------------------


def measurement_to_msg(m: Measurement, frame_id: str = "") -> TrackMeasurement:
    msg = TrackMeasurement()
    msg.header.stamp = time_msg(m.stamp_ns)
    msg.header.frame_id = frame_id
    msg.run_id = int(m.run_id)
    msg.s = float(m.s)
    msg.v = float(m.v)
    msg.track_force = float(m.track_force)
    msg.dt = float(m.dt)
    msg.s_measured = bool(m.s_measured)
    msg.s_variance = float(m.s_variance)
    msg.v_variance = float(m.v_variance)
    msg.cross_track = float(m.cross_track)
    msg.speed_limit = float(m.speed_limit)
    msg.tunnel_fraction = float(m.tunnel_fraction)
    msg.power_valid = bool(m.power_valid)
    msg.power_consumed = float(m.power_consumed)
    msg.power_regenerated = float(m.power_regenerated)
    return msg


def measurement_from_msg(msg: Any) -> Measurement:
    return Measurement(
        stamp_ns=stamp_to_ns(msg.header.stamp),
        s=float(msg.s),
        v=float(msg.v),
        track_force=float(msg.track_force),
        dt=float(msg.dt),
        run_id=int(msg.run_id),
        s_measured=bool(msg.s_measured),
        s_variance=float(msg.s_variance),
        v_variance=float(msg.v_variance),
        cross_track=float(msg.cross_track),
        speed_limit=float(msg.speed_limit),
        tunnel_fraction=float(msg.tunnel_fraction),
        power_valid=bool(msg.power_valid),
        power_consumed=float(msg.power_consumed),
        power_regenerated=float(msg.power_regenerated),
    )


# -- ResistanceEstimate -----------------------------------------------------------------------------


def estimate_to_msg(e: EstimateSample, frame_id: str = "") -> ResistanceEstimate:
    msg = ResistanceEstimate()
    msg.header.stamp = time_msg(e.stamp_ns)
    msg.header.frame_id = frame_id
    msg.run_id = int(e.run_id)
    msg.s = float(e.s)
    msg.v = float(e.v)
    msg.r0 = float(e.r0)
    msg.r1 = float(e.r1)
    msg.r2 = float(e.r2)
    msg.covariance = np.ascontiguousarray(e.covariance, dtype=np.float64).reshape(25)  # row-major 5x5
    msg.effort = float(e.effort)
    msg.acceleration = float(e.acceleration)
    msg.resistance = float(e.resistance)
    msg.track_force = float(e.track_force)
    msg.nis = float(e.nis)
    msg.effort_known = bool(e.effort_known)
    msg.health = int(e.health)
    return msg


@dataclass
class RegimeInput:
    """What regime_node and feature_node need of an estimate (duck-types EstimateSample for FeatureAccumulator
    and :func:`train_calib.pipeline.classify_estimate`).

    ``effort_known``, ``resistance`` and ``track_force`` come from a ResistanceEstimate (regime_node); a
    DrivingRegime (feature_node) does not carry them and leaves them None.
    """

    stamp_ns: int
    run_id: int
    s: float  # m
    v: float  # m/s
    effort: float  # N/kg
    acceleration: float  # m/s^2
    effort_known: bool | None = None  # effort taken as known (coasting u = 0, or measured traction power)
    resistance: float | None = None  # r(v) at the filtered speed, N/kg
    track_force: float | None = None  # g(s), N/kg


def regime_input_from_msg(msg: Any) -> RegimeInput:
    """From a ResistanceEstimate (with effort_known, resistance, track_force) or a DrivingRegime (rclpy or rosbags)."""
    sample = RegimeInput(
        stamp_to_ns(msg.header.stamp),
        int(msg.run_id),
        float(msg.s),
        float(msg.v),
        float(msg.effort),
        float(msg.acceleration),
    )
    if hasattr(msg, "resistance"):  # a ResistanceEstimate
        sample.effort_known = bool(msg.effort_known)
        sample.resistance = float(msg.resistance)
        sample.track_force = float(msg.track_force)
    return sample


# -- DrivingRegime ----------------------------------------------------------------------------------


def regime_to_msg(sample: RegimeInput | EstimateSample, regime: int, frame_id: str = "") -> DrivingRegime:
    msg = DrivingRegime()
    msg.header.stamp = time_msg(sample.stamp_ns)
    msg.header.frame_id = frame_id
    msg.run_id = int(sample.run_id)
    msg.regime = int(regime)
    msg.s = float(sample.s)
    msg.v = float(sample.v)
    msg.effort = float(sample.effort)
    msg.acceleration = float(sample.acceleration)
    return msg


# -- DrivingFeatures --------------------------------------------------------------------------------

_FEATURE_SCALARS = (
    "run_time",
    "run_distance",
    "max_tractive_effort_window_low",
    "max_tractive_effort_window_high",
    "max_tractive_effort",
    "max_tractive_effort_intercept",
    "max_tractive_effort_slope",
    "max_tractive_power_window_low",
    "max_tractive_power_window_high",
    "max_tractive_power",
    "max_tractive_power_std",
    "cruise_speed",
    "final_coast_duration",
    "final_coast_distance",
    "final_brake_duration",
    "final_brake_distance",
)
_FEATURE_COUNTS = ("max_tractive_effort_count", "max_tractive_power_count")
_FEATURE_ARRAYS = ("brake_step_low", "brake_step_high", "brake_rate_mean", "brake_rate_std", "cruise_speeds")


def features_to_msg(f: Features, frame_id: str = "") -> DrivingFeatures:
    msg = DrivingFeatures()
    msg.header.stamp = time_msg(f.stamp_ns)
    msg.header.frame_id = frame_id
    msg.run_id = int(f.run_id)
    msg.run_complete = bool(f.run_complete)
    msg.regime = int(f.regime)
    for name in _FEATURE_SCALARS:
        setattr(msg, name, float(getattr(f, name)))
    for name in _FEATURE_COUNTS:
        setattr(msg, name, int(getattr(f, name)))
    for name in _FEATURE_ARRAYS:
        setattr(msg, name, [float(x) for x in np.asarray(getattr(f, name), dtype=float).tolist()])
    msg.brake_rate_count = [int(x) for x in np.asarray(f.brake_rate_count).tolist()]
    msg.regime_time_share = np.asarray(f.regime_time_share, dtype=np.float64).reshape(5)
    return msg


__all__ = [
    "RegimeInput",
    "estimate_to_msg",
    "features_to_msg",
    "measurement_from_msg",
    "measurement_to_msg",
    "regime_input_from_msg",
    "regime_to_msg",
    "stamp_to_ns",
    "time_msg",
]
