"""Test helper: a bag's copy whose fixes carry a synthetic altitude from a track's gradient profile."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from train_calib.importers.convert import write_bag
from train_calib.track import Track


def bag_with_altitude(bag: Path, track: Track, out: Path, noise_m: float, seed: int) -> Path:
    """Altitude = integral of the track's gradient at each fix's projected s, plus N(0, noise_m) noise, m."""
    import sys

    sys.path.insert(0, str(Path(__file__).parent / "importers"))
    from logexport import bag_streams

    streams = bag_streams(bag)
    e, n = track.to_enu(streams.lat, streams.lon)
    s = np.array([track.project(a, b)[0] for a, b in zip(e, n)])
    alt = 400.0 + track.gradient.mean_over(np.zeros_like(s), s) * s
    streams.alt = alt + np.random.default_rng(seed).normal(0.0, noise_m, s.size)
    write_bag(streams, out, 4.0)
    return out
