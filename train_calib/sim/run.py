"""A simulated run: the truth, the sensor streams, and the core-ready measurements."""

from __future__ import annotations

from dataclasses import dataclass, field, fields
from typing import Any

import numpy as np

from ..measurement import MeasurementSeries
from ..physics import KMH
from ..track import Track
from ..train import TrainSpec

TRUTH_COLUMNS: list[tuple[str, str, str]] = [
    ("t_ns", "ns", "time (Unix epoch); the speed sample stamps"),
    ("s", "m", "head position along the track"),
    ("v", "m/s", "speed"),
    ("a", "m/s^2", "acceleration dv/dt (0 at a standstill)"),
    ("u", "N/kg", "applied effort f_t - f_b per unit effective mass (0 at a standstill)"),
    (
        "regime",
        "",
        "driver phase as DrivingRegime: 0 unknown (standing), 1 traction, 2 cruising, 3 coasting, 4 braking",
    ),
    ("r0", "N/kg", "Davis r0 in force"),
    ("r1", "N/(kg m/s)", "Davis r1 in force"),
    (
        "r2",
        "N/(kg (m/s)^2)",
        "Davis r2 in force incl. the wind factor, open air (tunnels: times 1 + tunnel_factor * tunnel_fraction)",
    ),
    ("track_force", "N/kg", "g(s): gradient + curve averaged over the train length"),
    ("tunnel_fraction", "", "share of the train inside a tunnel"),
    ("speed_limit", "m/s", "static limit over the train"),
    ("power_consumed", "W", "pantograph power drawn (noise free)"),
    ("power_regenerated", "W", "pantograph power fed back (noise free)"),
]


@dataclass
class Trajectory:
    """Truth arrays at a set of times; columns as TRUTH_COLUMNS (SI units)."""

    t_ns: np.ndarray
    s: np.ndarray
    v: np.ndarray
    a: np.ndarray
    u: np.ndarray
    regime: np.ndarray
    r0: np.ndarray
    r1: np.ndarray
    r2: np.ndarray
    track_force: np.ndarray
    tunnel_fraction: np.ndarray
    speed_limit: np.ndarray
    power_consumed: np.ndarray
    power_regenerated: np.ndarray

    def __len__(self) -> int:
        return int(self.t_ns.shape[0])

    @property
    def t(self) -> np.ndarray:
        """Seconds since the first row."""
        return (self.t_ns - self.t_ns[0]) * 1e-9 if len(self) else np.zeros(0)

    def columns(self) -> dict[str, np.ndarray]:
        return {f.name: getattr(self, f.name) for f in fields(self)}

    def select(self, mask) -> Trajectory:
        return Trajectory(**{k: v[mask] for k, v in self.columns().items()})


@dataclass
class GnssStream:
    """/gnss/fix samples: stamps (ns), WGS84 degrees (NaN without a fix), status (0 fix, -1 no fix)."""

    t_ns: np.ndarray
    lat: np.ndarray
    lon: np.ndarray
    status: np.ndarray
    sigma_m: float
    s_true: np.ndarray  # truth: head position at the fix time, m
    east_err: np.ndarray  # truth: the noise added, m
    north_err: np.ndarray


@dataclass
class SpeedStream:
    """/train/speed samples: stamps (ns) and speed (m/s)."""

    t_ns: np.ndarray
    v_ms: np.ndarray


@dataclass
class PowerStream:
    """/train/traction_power samples: stamps (ns), consumed and regenerated power (W)."""

    t_ns: np.ndarray
    consumed_w: np.ndarray
    regenerated_w: np.ndarray


@dataclass
class SimulatedRun:
    """One run from a stop to the next with everything known about it.

    ``truth``: at the speed sample stamps (one row per /train/speed message). ``dense``: on a fine
    uniform time grid (plots, exact checks). ``meta``: parameters, seed and a summary (JSON-ready).
    """

    truth: Trajectory
    dense: Trajectory
    gnss: GnssStream
    speed: SpeedStream
    power: PowerStream | None
    meta: dict[str, Any] = field(default_factory=dict)

    @property
    def run_time_s(self) -> float:
        return float(self.meta["summary"]["run_time_s"])

    def measurements(self, track: Track, train: TrainSpec, *, max_gap_s: float | None = None) -> MeasurementSeries:
        """The core's input: every speed sample paired with a map-matched position.

        The GNSS fixes with a fix are interpolated (east/north) to each speed stamp between two fixes
        at most ``max_gap_s`` apart (default 2.5 GNSS periods) and projected on the track; without
        such a pair (tunnel, dropout, ends) s is dead-reckoned from the measured speed
        (``s_measured`` False). No continuity logic or outlier rejection: that is the ingest's job.
        Power samples are paired when one lies within half a power period of the stamp.
        """
        sensors = self.meta["sensors"]
        sigma = float(sensors["gnss_noise_m"])
        gap_ns = round((max_gap_s if max_gap_s is not None else 2.5 * float(sensors["gnss_period_s"])) * 1e9)
        ok = self.gnss.status >= 0
        tg = self.gnss.t_ns[ok]
        east, north = track.to_enu(self.gnss.lat[ok], self.gnss.lon[ok]) if ok.any() else (np.zeros(0), np.zeros(0))
        stamps = self.speed.t_ns
        v = self.speed.v_ms
        n = stamps.size
        quantum = float(sensors["speed_quantum_kmh"]) * KMH
        v_var = quantum * quantum / 12.0 + (float(sensors["speed_noise_kmh"]) * KMH) ** 2
        s = np.zeros(n)
        cross = np.zeros(n)
        measured = np.zeros(n, dtype=bool)
        s_var = np.full(n, max(sigma * sigma, 1e-6))
        last_fix_t = None
        for i in range(n):
            t = stamps[i]
            j = int(np.searchsorted(tg, t, side="right"))
            pair = None
            if 0 < j <= tg.size:
                if tg[j - 1] == t:
                    pair = (j - 1, j - 1, 0.0)
                elif j < tg.size and tg[j] - tg[j - 1] <= gap_ns:
                    w = (t - tg[j - 1]) / (tg[j] - tg[j - 1])
                    pair = (j - 1, j, float(w))
            if pair is not None:
                a, b, w = pair
                e = east[a] + w * (east[b] - east[a])
                nn = north[a] + w * (north[b] - north[a])
                s[i], cross[i] = track.project(float(e), float(nn))
                measured[i] = True
                last_fix_t = t
            elif i > 0:
                dt = (t - stamps[i - 1]) * 1e-9
                s[i] = s[i - 1] + 0.5 * (v[i] + v[i - 1]) * dt
                since = (t - last_fix_t) * 1e-9 if last_fix_t is not None else (t - stamps[0]) * 1e-9
                s_var[i] = sigma * sigma + v_var * since * since
            else:  # no fix at the first sample: start from the first fix projected, else the track start
                if tg.size:
                    s[i], cross[i] = track.project(float(east[0]), float(north[0]))
                s_var[i] = sigma * sigma + 1e4
        dt = np.concatenate(([0.0], np.diff(stamps) * 1e-9)) if n else np.zeros(0)
        power_valid = np.zeros(n, dtype=bool)
        consumed = np.zeros(n)
        regenerated = np.zeros(n)
        if self.power is not None and self.power.t_ns.size and n:
            half = round(0.5 * float(sensors["power_period_s"]) * 1e9)
            k = np.clip(np.searchsorted(self.power.t_ns, stamps), 1, self.power.t_ns.size - 1)
            prev, nxt = self.power.t_ns[k - 1], self.power.t_ns[np.minimum(k, self.power.t_ns.size - 1)]
            nearest = np.where(np.abs(stamps - prev) <= np.abs(nxt - stamps), k - 1, k)
            nearest = np.clip(nearest, 0, self.power.t_ns.size - 1)
            power_valid = np.abs(self.power.t_ns[nearest] - stamps) <= half
            consumed = np.where(power_valid, self.power.consumed_w[nearest], 0.0)
            regenerated = np.where(power_valid, self.power.regenerated_w[nearest], 0.0)
        return MeasurementSeries(
            stamp_ns=stamps.astype(np.int64),
            s=s,
            v=v.astype(float),
            track_force=np.asarray(track.track_force(s, train.length_m), dtype=float),
            dt=dt,
            run_id=np.zeros(n, dtype=np.int64),
            s_measured=measured,
            s_variance=s_var,
            v_variance=np.full(n, v_var),
            cross_track=cross,
            speed_limit=np.asarray(track.speed_limit_at(s), dtype=float),
            tunnel_fraction=np.asarray(track.tunnel_fraction(s, train.length_m), dtype=float),
            power_valid=power_valid,
            power_consumed=consumed,
            power_regenerated=regenerated,
            track_force_integral=np.asarray(track.track_force_integral(s, train.length_m), dtype=float),
        )
