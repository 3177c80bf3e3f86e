"""The streams read from a log and the record of its bad rows."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import TrainCalibError


class ImportFormatError(TrainCalibError):
    """A log that is not what its format says, or lacks what the import needs (one line, exit 2)."""


@dataclass
class RowLog:
    """Bad rows (file, line, reason) and the count of rows read, per import."""

    problems: list[tuple[str, int, str]] = field(default_factory=list)
    rows: int = 0  # data rows (lines, sentences, track points) read
    used: int = 0  # of them, rows that gave at least one sample

    def bad(self, path: str | Path, line: int, reason: str) -> None:
        """Record a row that was skipped: ``line`` is 1-based."""
        self.problems.append((str(path), int(line), reason))

    def lines(self, limit: int = 20) -> list[str]:
        """The first ``limit`` problems as ``file:line: reason``, then how many more."""
        out = [f"{p}:{n}: {r}" for p, n, r in self.problems[:limit]]
        if len(self.problems) > limit:
            out.append(f"... and {len(self.problems) - limit} more bad rows")
        return out


def _f(values: list[float] | np.ndarray) -> np.ndarray:
    return np.asarray(values, dtype=float)


@dataclass
class Streams:
    """Samples of one or more logs, SI units; stamps are Unix ns.

    GNSS: ``gnss_t_ns``, ``lat``/``lon`` (WGS84 deg), ``alt`` (m, NaN if unknown), ``gnss_line`` (source line,
    for messages). Speed: ``speed_t_ns``, ``speed_ms`` (m/s), ``speed_line``. Power: ``power_t_ns``,
    ``consumed_w``/``regenerated_w`` (W).
    """

    gnss_t_ns: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    lat: np.ndarray = field(default_factory=lambda: np.zeros(0))
    lon: np.ndarray = field(default_factory=lambda: np.zeros(0))
    alt: np.ndarray = field(default_factory=lambda: np.zeros(0))
    speed_t_ns: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    speed_ms: np.ndarray = field(default_factory=lambda: np.zeros(0))
    power_t_ns: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    consumed_w: np.ndarray = field(default_factory=lambda: np.zeros(0))
    regenerated_w: np.ndarray = field(default_factory=lambda: np.zeros(0))

    @classmethod
    def from_lists(
        cls,
        gnss: list[tuple[int, float, float, float]],
        speed: list[tuple[int, float]],
        power: list[tuple[int, float, float]] | None = None,
    ) -> Streams:
        """From row tuples: gnss (t_ns, lat, lon, alt), speed (t_ns, m/s), power (t_ns, consumed W, regen W)."""
        power = power or []
        g = list(zip(*gnss)) if gnss else [[], [], [], []]
        s = list(zip(*speed)) if speed else [[], []]
        p = list(zip(*power)) if power else [[], [], []]
        return cls(
            gnss_t_ns=np.asarray(g[0], dtype=np.int64),
            lat=_f(g[1]),
            lon=_f(g[2]),
            alt=_f(g[3]),
            speed_t_ns=np.asarray(s[0], dtype=np.int64),
            speed_ms=_f(s[1]),
            power_t_ns=np.asarray(p[0], dtype=np.int64),
            consumed_w=_f(p[1]),
            regenerated_w=_f(p[2]),
        )

    def merged(self, other: Streams) -> Streams:
        """Both logs' samples together (unsorted)."""
        return Streams(**{k: np.concatenate([getattr(self, k), getattr(other, k)]) for k in self.__dataclass_fields__})

    @property
    def empty(self) -> bool:
        return self.gnss_t_ns.size == 0 and self.speed_t_ns.size == 0
