"""Core records <-> train_calib_msgs messages (rclpy). Field names and units are the same on both sides.

Readers (``*_from_msg``) are duck-typed, so they also accept rosbags messages decoded from a bag.

Writers build the message without its generated ``__init__`` and property setters, which cost several
microseconds per message (every field set twice, a default sub-message built and thrown away): the instance is
made with :func:`.slots.bare` and its slots (``_<field>``, the rosidl layout, checked at import) are filled with
the same values the setters would store. Field checks (``ROS_PYTHON_CHECK_FIELDS=1``) are skipped here as they
are for the setters by default; the values are converted to the field types exactly as before, so the
serialized messages are identical.

The nodes publish the chain's messages as bytes (``*_to_cdr``: the same values packed by :mod:`cdr`), which
skips rclpy's per-field conversion of a message object; a test checks they deserialize to the ``*_to_msg``
messages field for field.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from builtin_interfaces.msg import Time
from std_msgs.msg import Header
from train_calib_msgs.msg import DrivingFeatures, DrivingRegime, ResistanceEstimate, TrackMeasurement

from ..estimation.features import Features
from ..estimation.records import EFFORT_COMPUTED, EstimateSample
from ..measurement import Measurement, track_force_integral_of
from . import cdr
from .slots import bare, check_layout

NS = 1_000_000_000


_SLOTS: dict[type, list[str]] = {}  # message type -> the slots of its fields after the header (layout checked)


def _slots_after_header(cls: type) -> list[str]:
    slots = _SLOTS.get(cls)
    if slots is None:
        check_layout(cls)
        slots = _SLOTS[cls] = [f"_{name}" for name in cls.get_fields_and_field_types()][1:]
    return slots


for _cls in (Time, Header):
    check_layout(_cls)
for _cls in (TrackMeasurement, ResistanceEstimate, DrivingRegime):  # this module's writers: checked at import
    _slots_after_header(_cls)
_MEASUREMENT, _ESTIMATE, _REGIME = (cdr.layout(c) for c in (TrackMeasurement, ResistanceEstimate, DrivingRegime))

_float64 = np.float64


def stamp_to_ns(stamp: Any) -> int:
    return int(stamp.sec) * NS + int(stamp.nanosec)


def time_msg(t_ns: int) -> Time:
    t = bare(Time)
    t._sec = int(t_ns // NS)
    t._nanosec = int(t_ns % NS)
    return t


def header_msg(t_ns: int, frame_id: str) -> Header:
    """A std_msgs/Header: stamp from ns, frame_id."""
    h = bare(Header)
    h._stamp = time_msg(t_ns)
    h._frame_id = frame_id
    return h


def message_with_header(cls: type, t_ns: int, frame_id: str, values: tuple) -> Any:
    """A message of `cls` (a header first) with this header and these values of the fields after it, in message
    order and field types (lists for arrays)."""
    msg = bare(cls)
    msg._header = header_msg(t_ns, frame_id)
    for slot, value in zip(_slots_after_header(cls), values, strict=True):
        setattr(msg, slot, np.array(value, dtype=_float64) if type(value) is list else value)
    return msg


def to_cdr(layout: cdr.Layout, t_ns: int, frame_id: str, values: tuple) -> bytes:
    """The serialized message of `layout` with this header (stamp in ns, frame_id) and these scalar values of the
    fields after it, in message order (arrays flattened)."""
    t_ns = int(t_ns)
    return layout.encode((t_ns // NS, t_ns % NS, frame_id, *values))


# -- TrackMeasurement -------------------------------------------------------------------------------


def _measurement_values(m: Measurement) -> tuple:
    """The TrackMeasurement fields after the header, in message order and field types."""
    return (
        int(m.run_id),
        float(m.s),
        float(m.v),
        float(m.track_force),
        float(m.dt),
        bool(m.s_measured),
        float(m.s_variance),
        float(m.v_variance),
        float(m.cross_track),
        float(m.speed_limit),
        float(m.tunnel_fraction),
        bool(m.power_valid),
        float(m.power_consumed),
        float(m.power_regenerated),
        float(m.track_force_integral),
    )


def measurement_to_msg(m: Measurement, frame_id: str = "") -> TrackMeasurement:
    return message_with_header(TrackMeasurement, m.stamp_ns, frame_id, _measurement_values(m))


def measurement_to_cdr(m: Measurement, frame_id: str = "") -> bytes:
    """The serialized TrackMeasurement (plain CDR, what rclpy would publish for measurement_to_msg)."""
    return to_cdr(_MEASUREMENT, m.stamp_ns, frame_id, _measurement_values(m))


def measurement_from_msg(msg: Any) -> Measurement:
    return Measurement(
        stamp_to_ns(msg.header.stamp),
        float(msg.s),
        float(msg.v),
        float(msg.track_force),
        float(msg.dt),
        int(msg.run_id),
        bool(msg.s_measured),
        float(msg.s_variance),
        float(msg.v_variance),
        float(msg.cross_track),
        float(msg.speed_limit),
        float(msg.tunnel_fraction),
        bool(msg.power_valid),
        float(msg.power_consumed),
        float(msg.power_regenerated),
        track_force_integral_of(msg),
    )


# -- ResistanceEstimate -----------------------------------------------------------------------------


def _estimate_values(e: EstimateSample) -> tuple:
    """The ResistanceEstimate fields after the header (the covariance as a list of 25, row-major 5x5)."""
    return (
        int(e.run_id),
        float(e.s),
        float(e.v),
        float(e.r0),
        float(e.r1),
        float(e.r2),
        np.asarray(e.covariance, dtype=_float64).ravel().tolist(),  # row-major 5x5 -> 25
        float(e.effort),
        float(e.acceleration),
        float(e.resistance),
        float(e.track_force),
        float(e.nis),
        bool(e.effort_known),
        int(e.health),
        float(e.v_measured),
        int(e.effort_source),
    )


def estimate_to_msg(e: EstimateSample, frame_id: str = "") -> ResistanceEstimate:
    return message_with_header(ResistanceEstimate, e.stamp_ns, frame_id, _estimate_values(e))


def estimate_to_cdr(e: EstimateSample, frame_id: str = "") -> bytes:
    """The serialized ResistanceEstimate (plain CDR, what rclpy would publish for estimate_to_msg)."""
    run_id, s, v, r0, r1, r2, cov, *rest = _estimate_values(e)
    return to_cdr(_ESTIMATE, e.stamp_ns, frame_id, (run_id, s, v, r0, r1, r2, *cov, *rest))


@dataclass(slots=True)
class RegimeInput:
    """What regime_node and feature_node need of an estimate (duck-types EstimateSample for FeatureAccumulator
    and :func:`train_calib.pipeline.classify_estimate`).

    ``effort_known``, ``resistance`` and ``track_force`` come from a ResistanceEstimate (regime_node); a
    DrivingRegime (feature_node) does not carry them and leaves them None. ``frame_id``: the message header's, so
    that a sample published later (regime_node's ``lag_samples``) keeps its own.
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
    v_measured: float = math.nan  # the speed measurement, m/s (NaN: a message recorded without it)
    effort_source: int = EFFORT_COMPUTED  # EFFORT_* (a message recorded without it: computed)
    frame_id: str = ""


def regime_input_from_msg(msg: Any) -> RegimeInput:
    """From a ResistanceEstimate (with effort_known, resistance, track_force) or a DrivingRegime (rclpy or rosbags)."""
    t_ns = stamp_to_ns(msg.header.stamp)
    v_measured = float(getattr(msg, "v_measured", math.nan))  # bags recorded before the field: NaN
    source = int(getattr(msg, "effort_source", EFFORT_COMPUTED))  # bags recorded before the field: computed
    if hasattr(msg, "resistance"):  # a ResistanceEstimate
        return RegimeInput(
            t_ns,
            int(msg.run_id),
            float(msg.s),
            float(msg.v),
            float(msg.effort),
            float(msg.acceleration),
            bool(msg.effort_known),
            float(msg.resistance),
            float(msg.track_force),
            v_measured,
            source,
            msg.header.frame_id,
        )
    return RegimeInput(
        t_ns, int(msg.run_id), float(msg.s), float(msg.v), float(msg.effort), float(msg.acceleration),
        v_measured=v_measured, effort_source=source, frame_id=msg.header.frame_id,
    )  # fmt: skip


# -- DrivingRegime ----------------------------------------------------------------------------------


def _regime_values(sample: RegimeInput | EstimateSample, regime: int, phase: int | None) -> tuple:
    """The DrivingRegime fields after the header (phase None: the regime)."""
    return (
        int(sample.run_id),
        int(regime),
        float(sample.s),
        float(sample.v),
        float(sample.effort),
        float(sample.acceleration),
        float(sample.v_measured),
        int(sample.effort_source),
        int(regime if phase is None else phase),
    )


def regime_to_msg(
    sample: RegimeInput | EstimateSample, regime: int, frame_id: str = "", phase: int | None = None
) -> DrivingRegime:
    return message_with_header(DrivingRegime, sample.stamp_ns, frame_id, _regime_values(sample, regime, phase))


def regime_to_cdr(
    sample: RegimeInput | EstimateSample, regime: int, frame_id: str = "", phase: int | None = None
) -> bytes:
    """The serialized DrivingRegime (plain CDR, what rclpy would publish for regime_to_msg)."""
    return to_cdr(_REGIME, sample.stamp_ns, frame_id, _regime_values(sample, regime, phase))


def phase_from_msg(msg: Any) -> int:
    """A DrivingRegime's phase (the paper's regime notion); a message recorded before the field: its regime."""
    return int(getattr(msg, "phase", msg.regime))


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
    msg = DrivingFeatures(header=header_msg(f.stamp_ns, frame_id))
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
    "estimate_to_cdr",
    "estimate_to_msg",
    "features_to_msg",
    "header_msg",
    "measurement_from_msg",
    "measurement_to_cdr",
    "measurement_to_msg",
    "message_with_header",
    "phase_from_msg",
    "regime_input_from_msg",
    "regime_to_cdr",
    "regime_to_msg",
    "stamp_to_ns",
    "time_msg",
    "to_cdr",
]
