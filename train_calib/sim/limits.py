"""The speed ceiling of a run and the braking targets it implies.

A train may run at the static limit that holds over its whole length: a lower limit applies as soon
as the head reaches it, a higher one only once the tail has cleared the lower section. The ceiling
is therefore ``min(limit(x) for x in [s - L, s])`` (``Track.limit_over_train``), piecewise constant
with breaks at the limit changes (drops, at the head) and at the changes + L (rises, tail clear).
"""

from __future__ import annotations

from bisect import bisect_right
from dataclasses import dataclass

import numpy as np

from ..track import Track


@dataclass(frozen=True)
class Drop:
    """The ceiling falls to ``v_low`` (m/s) when the head reaches ``s_m``."""

    s_m: float
    v_low: float


class SpeedCeiling:
    """Allowed speed over the train (m/s) on [start_s, stop_s], capped at the train's v_max."""

    def __init__(self, track: Track, length_m: float, start_s: float, stop_s: float, v_max: float = np.inf) -> None:
        b = track.speed_limit.breaks
        cand = np.unique(np.concatenate([b, b + length_m]))
        cand = cand[(cand > start_s) & (cand < stop_s)]
        edges = np.concatenate(([start_s], cand, [stop_s]))
        mids = 0.5 * (edges[:-1] + edges[1:])
        values = [min(track.limit_over_train(float(m), length_m), v_max) for m in mids]
        breaks: list[float] = [float(start_s)]
        vals: list[float] = [values[0]]
        for edge, value in zip(edges[1:-1], values[1:]):
            if value != vals[-1]:
                breaks.append(float(edge))
                vals.append(value)
        self.start_s, self.stop_s = float(start_s), float(stop_s)
        self.breaks = breaks
        self.values = vals

    def at(self, s: float) -> float:
        i = bisect_right(self.breaks, s) - 1
        return self.values[max(i, 0)]

    def at_vec(self, s) -> np.ndarray:
        idx = np.clip(
            np.searchsorted(self.breaks, np.asarray(s, dtype=float), side="right") - 1, 0, len(self.breaks) - 1
        )
        return np.asarray(self.values)[idx]

    def drops(self) -> list[Drop]:
        """Positions where the ceiling falls (braking targets), in order."""
        return [
            Drop(self.breaks[i], self.values[i])
            for i in range(1, len(self.breaks))
            if self.values[i] < self.values[i - 1]
        ]

    def rises(self) -> list[float]:
        """Positions where the ceiling rises (the tail has cleared a lower limit)."""
        return [self.breaks[i] for i in range(1, len(self.breaks)) if self.values[i] > self.values[i - 1]]

    def scaled(self, theta: float) -> list[float]:
        return [theta * v for v in self.values]
