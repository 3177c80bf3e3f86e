"""The GNSS fixes and speeds of recorded runs (bags), in a common local frame."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .. import bagio
from ..errors import BagError
from ..geodesy import LocalFrame


@dataclass
class RunData:
    """One bag: fixes (Unix ns, WGS84 deg, altitude m, NaN unknown) and speeds (Unix ns, m/s), time-sorted."""

    source: str
    fix_t_ns: np.ndarray
    lat: np.ndarray
    lon: np.ndarray
    alt: np.ndarray
    speed_t_ns: np.ndarray
    speed_ms: np.ndarray

    def enu(self, frame: LocalFrame) -> np.ndarray:
        """(n, 2) east/north of the fixes, m."""
        e, n = frame.to_enu(self.lat, self.lon)
        return np.stack([np.asarray(e, dtype=float), np.asarray(n, dtype=float)], axis=1)

    def reversed_in_time(self) -> RunData:
        """The run played backwards (t -> t_first + t_last - t): the same places passed the other way at the same
        speeds, stops and outages where they were. How a run recorded in the opposite direction is averaged."""
        t0 = int(min(self.fix_t_ns[0], self.speed_t_ns[0]))
        t1 = int(max(self.fix_t_ns[-1], self.speed_t_ns[-1]))
        return RunData(
            source=self.source,
            fix_t_ns=(t0 + t1 - self.fix_t_ns)[::-1].copy(),
            lat=self.lat[::-1].copy(),
            lon=self.lon[::-1].copy(),
            alt=self.alt[::-1].copy(),
            speed_t_ns=(t0 + t1 - self.speed_t_ns)[::-1].copy(),
            speed_ms=self.speed_ms[::-1].copy(),
        )

    def speed_at(self, t_ns: np.ndarray) -> np.ndarray:
        """Speed interpolated to the given stamps, m/s."""
        return np.interp(t_ns.astype(float), self.speed_t_ns.astype(float), self.speed_ms)


def read_run(path: str | Path) -> RunData:
    """Fixes with a fix (status >= 0, finite) and speeds of a bag; BagError when either is missing."""
    fixes: list[tuple[int, float, float, float]] = []
    speeds: list[tuple[int, float]] = []
    for m in bagio.iter_bag(path, (bagio.GNSS_TOPIC, bagio.SPEED_TOPIC)):
        msg = m.decode()
        t = bagio.stamp_ns(msg.header)
        if m.topic == bagio.GNSS_TOPIC:
            lat, lon = float(msg.latitude), float(msg.longitude)
            if int(msg.status.status) >= 0 and np.isfinite(lat) and np.isfinite(lon):
                fixes.append((t, lat, lon, float(msg.altitude)))
        else:
            v = float(msg.twist.linear.x)
            if np.isfinite(v) and v >= 0.0:
                speeds.append((t, v))
    if len(fixes) < 3:
        raise BagError(f"{path}: {bagio.GNSS_TOPIC}: {len(fixes)} fixes, need at least 3")
    if len(speeds) < 3:
        raise BagError(f"{path}: {bagio.SPEED_TOPIC}: {len(speeds)} speeds, need at least 3")
    fixes.sort()
    speeds.sort()
    f = np.array(fixes, dtype=object)
    s = np.array(speeds, dtype=object)
    return RunData(
        source=str(path),
        fix_t_ns=f[:, 0].astype(np.int64),
        lat=f[:, 1].astype(float),
        lon=f[:, 2].astype(float),
        alt=f[:, 3].astype(float),
        speed_t_ns=s[:, 0].astype(np.int64),
        speed_ms=s[:, 1].astype(float),
    )


def stop_intervals(run: RunData, max_speed_ms: float = 0.3, min_duration_s: float = 10.0) -> list[tuple[int, int]]:
    """(start ns, end ns) of each standstill: speed <= max_speed for at least min_duration (or at a run end)."""
    still = run.speed_ms <= max_speed_ms
    t = run.speed_t_ns
    out: list[tuple[int, int]] = []
    i = 0
    n = still.size
    while i < n:
        if not still[i]:
            i += 1
            continue
        j = i
        while j + 1 < n and still[j + 1]:
            j += 1
        at_end = i == 0 or j == n - 1
        if (t[j] - t[i]) * 1e-9 >= min_duration_s or at_end:
            out.append((int(t[i]), int(t[j])))
        i = j + 1
    return out
