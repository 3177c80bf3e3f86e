"""The ingest's inputs and names: stream and drop-reason names, the input records (stamps in ns since the epoch)
and their converters from rclpy or rosbags messages, the map-matched fix, and stamp-ordered insertion."""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass
from typing import Any, Protocol

NS = 1_000_000_000

GNSS = "gnss"
SPEED = "speed"
POWER = "power"
STREAMS = (GNSS, SPEED, POWER)

# Drop reasons (stable names: they appear in /diagnostics and summary.json).
NAN = "nan"
NO_FIX = "no_fix"
OFF_TRACK = "off_track"
JUMP = "jump"
OUT_OF_ORDER = "out_of_order"
STALE = "stale"
NEGATIVE_SPEED = "negative_speed"
IMPLAUSIBLE_SPEED = "implausible_speed"
SPEED_JUMP = "speed_jump"
NO_POSITION = "no_position"
NEGATIVE_POWER = "negative_power"
DUPLICATE = "duplicate"
REVERSING = "reversing"

DROP_REASONS: dict[str, str] = {
    NAN: "a value is NaN or infinite",
    NO_FIX: "NavSatFix status < 0 (no fix)",
    OFF_TRACK: "fix farther than max_cross_track from the track polyline",
    JUMP: "fix near the track but not where the train can be (continuity gate)",
    OUT_OF_ORDER: "stamp older than the last speed sample already released (too late to be paired in order)",
    DUPLICATE: "stamp equal to that of a recent sample of the same stream (the first one is kept)",
    STALE: "stamp older than the newest input by more than max_sample_age",
    NEGATIVE_SPEED: "speed below 0",
    IMPLAUSIBLE_SPEED: "speed above max_speed",
    SPEED_JUMP: "|dv/dt| to the previous speed sample above max_acceleration",
    NO_POSITION: "no position yet (not acquired) or dead reckoning longer than max_dead_reckoning",
    NEGATIVE_POWER: "power_consumed or power_regenerated below 0",
    REVERSING: "the fixes move against the track direction (shunting, or the other direction's track file needed)",
}

# Repair reasons (samples used after a repair; counted like drops, in /diagnostics and summary.json).
BAD_COVARIANCE = "bad_covariance"
REPAIR_REASONS: dict[str, str] = {
    BAD_COVARIANCE: "NavSatFix covariance known but NaN, infinite or not positive: position_std used",
}


# -- input records (duck-typed converters from rclpy or rosbags messages below) -----------------------


@dataclass
class GnssFix:
    """A GNSS fix (sensor_msgs/NavSatFix); stamp in ns since the epoch."""

    stamp_ns: int
    lat: float  # deg
    lon: float  # deg
    status: int = 0  # NavSatStatus.status; < 0 no fix
    horizontal_variance: float = math.nan  # m^2, NaN when unknown
    covariance_known: bool = False  # position_covariance_type not UNKNOWN (a NaN variance is then a fault)


@dataclass
class SpeedSample:
    """A speed sample (geometry_msgs/TwistStamped); stamp in ns since the epoch."""

    stamp_ns: int
    v: float  # m/s along the track


@dataclass
class PowerSample:
    """A traction power sample (train_calib_msgs/TractionPower); stamp in ns since the epoch."""

    stamp_ns: int
    consumed: float  # W
    regenerated: float  # W


def header_stamp_ns(msg: Any) -> int:
    """A message's header stamp in ns since the epoch."""
    stamp = msg.header.stamp
    return int(stamp.sec) * NS + int(stamp.nanosec)


def fix_from_msg(msg: Any) -> GnssFix:
    """A sensor_msgs/NavSatFix (rclpy or rosbags) as a GnssFix."""
    variance = math.nan
    known = int(msg.position_covariance_type) != 0  # COVARIANCE_TYPE_UNKNOWN
    if known:
        cov = msg.position_covariance
        variance = 0.5 * (float(cov[0]) + float(cov[4]))
    status = int(msg.status.status)
    return GnssFix(header_stamp_ns(msg), float(msg.latitude), float(msg.longitude), status, variance, known)


def speed_from_msg(msg: Any) -> SpeedSample:
    """A geometry_msgs/TwistStamped (rclpy or rosbags) as a SpeedSample (twist.linear.x)."""
    return SpeedSample(header_stamp_ns(msg), float(msg.twist.linear.x))


def power_from_msg(msg: Any) -> PowerSample:
    """A train_calib_msgs/TractionPower (rclpy or rosbags) as a PowerSample."""
    return PowerSample(header_stamp_ns(msg), float(msg.power_consumed), float(msg.power_regenerated))


@dataclass
class MatchedFix:
    """An accepted fix on the track: chainage s (m), its variance (m^2) and the distance from the polyline (m)."""

    stamp_ns: int
    s: float
    variance: float
    cross_track: float


class Stamped(Protocol):
    """Anything with a stamp in ns (the input records, MatchedFix)."""

    stamp_ns: int


def insort_by_stamp(queue: deque, item: Stamped) -> None:
    """Insert into a deque kept in stamp order (late samples are rare: a linear scan from the end)."""
    t = item.stamp_ns
    i = len(queue)
    while i > 0 and queue[i - 1].stamp_ns > t:
        i -= 1
    queue.insert(i, item)
