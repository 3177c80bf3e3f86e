"""The paired, map-matched sample every estimator consumes (the core twin of TrackMeasurement)."""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import Any

import numpy as np


@dataclass
class Measurement:
    """One speed sample with its track position; fields and units as in TrackMeasurement.msg."""

    stamp_ns: int  # measurement time, ns
    s: float  # position along the track, m
    v: float  # speed, m/s
    track_force: float  # g(s) averaged over the train length, N/kg
    dt: float = 0.0  # s since the previous measurement of this run (0 for the first)
    run_id: int = 0
    s_measured: bool = True  # False: s dead-reckoned (GNSS gap); update v only
    s_variance: float = 16.0  # m^2
    v_variance: float = (1.0 / 3.6) ** 2 / 12.0 + (0.5 / 3.6) ** 2  # (m/s)^2
    cross_track: float = 0.0  # m
    speed_limit: float = float("inf")  # m/s
    tunnel_fraction: float = 0.0
    power_valid: bool = False
    power_consumed: float = 0.0  # W
    power_regenerated: float = 0.0  # W
    track_force_integral: float = float("nan")  # Gamma(s), J/kg: integral of track_force over s (NaN: unknown)

    @property
    def t(self) -> float:
        """Measurement time in s."""
        return self.stamp_ns * 1e-9


def track_force_integral_of(msg: Any) -> float:
    """TrackMeasurement.track_force_integral of a message (rclpy, rosbags or a view), NaN where unknown: absent (bags
    recorded before the field) or left at the message's default 0.0 by a publisher that does not fill it (Gamma is 0
    only at s = 0)."""
    value = float(getattr(msg, "track_force_integral", math.nan))
    return math.nan if value == 0.0 and float(msg.s) != 0.0 else value


@dataclass
class MeasurementSeries:
    """A whole run as arrays (offline use); field names as in Measurement."""

    stamp_ns: np.ndarray
    s: np.ndarray
    v: np.ndarray
    track_force: np.ndarray
    dt: np.ndarray
    run_id: np.ndarray
    s_measured: np.ndarray
    s_variance: np.ndarray
    v_variance: np.ndarray
    cross_track: np.ndarray
    speed_limit: np.ndarray
    tunnel_fraction: np.ndarray
    power_valid: np.ndarray
    power_consumed: np.ndarray
    power_regenerated: np.ndarray
    track_force_integral: np.ndarray | None = None  # J/kg; None: unknown (NaN at every sample)

    def __post_init__(self) -> None:
        if self.track_force_integral is None:
            self.track_force_integral = np.full(self.stamp_ns.shape, np.nan)

    @property
    def t(self) -> np.ndarray:
        """Seconds since the first sample."""
        return (self.stamp_ns - self.stamp_ns[0]) * 1e-9 if len(self) else np.zeros(0)

    def __len__(self) -> int:
        return int(self.stamp_ns.shape[0])

    def __getitem__(self, i: int) -> Measurement:
        return Measurement(**{f.name: getattr(self, f.name)[i].item() for f in fields(Measurement)})

    def __iter__(self):
        return (self[i] for i in range(len(self)))

    @classmethod
    def from_measurements(cls, items: list[Measurement]) -> MeasurementSeries:
        columns = {}
        for f in fields(Measurement):
            dtype = np.int64 if f.name in ("stamp_ns", "run_id") else bool if f.type in ("bool",) else float
            columns[f.name] = np.array([getattr(m, f.name) for m in items], dtype=dtype)
        return cls(**columns)
