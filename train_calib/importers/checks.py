"""Checks of the merged streams: time order, duplicates, and speed against the change of position."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..geodesy import LocalFrame
from .records import ImportFormatError, Streams

KNOT_MS = 1852.0 / 3600.0  # m/s per knot
UNIT_SUSPECTS: dict[float, str] = {
    3.6: "km/h read as m/s? (--speed-unit kmh)",
    1.0 / 3.6: "m/s read as km/h? (--speed-unit ms)",
    1.852: "km/h read as knots? (--speed-unit kmh)",
    1.0 / 1.852: "knots read as km/h? (--speed-unit knots)",
    1.0 / KNOT_MS: "knots read as m/s? (--speed-unit knots)",
    KNOT_MS: "m/s read as knots? (--speed-unit ms)",
}
"""Ratio of speed distance to GNSS distance -> the unit mix-up it points to."""
MIN_CHECK_DISTANCE_M = 500.0
CHECK_STEP_S = 30.0
REFUSE_BAND = 0.12  # a ratio within 12 % of a unit factor is refused
WARN_BAND = 0.25  # a ratio off 1 by more than this is warned about


def sort_streams(streams: Streams) -> tuple[Streams, dict[str, int]]:
    """Each stream sorted by time, samples at a time already taken dropped; counts of both per stream."""
    counts: dict[str, int] = {}
    out = {}
    for name, keys in (
        ("gnss", ("gnss_t_ns", "lat", "lon", "alt")),
        ("speed", ("speed_t_ns", "speed_ms")),
        ("power", ("power_t_ns", "consumed_w", "regenerated_w")),
    ):
        t = getattr(streams, keys[0])
        counts[f"{name}_unsorted"] = int(np.count_nonzero(np.diff(t) < 0)) if t.size > 1 else 0
        order = np.argsort(t, kind="stable")
        t_sorted = t[order]
        keep = np.concatenate(([True], np.diff(t_sorted) > 0)) if t.size else np.zeros(0, dtype=bool)
        counts[f"{name}_duplicate"] = int(t.size - np.count_nonzero(keep))
        for k in keys:
            out[k] = getattr(streams, k)[order][keep]
    return Streams(**out), counts


@dataclass(frozen=True)
class SpeedCheck:
    """Distance from the speeds over distance from the positions, over the moving parts of the log."""

    ratio: float  # speed distance / GNSS distance (1 when consistent)
    distance_m: float  # GNSS distance the ratio rests on
    verdict: str  # "ok", "warn", "refuse" or "skipped"
    message: str


def check_speed_units(streams: Streams) -> SpeedCheck:
    """Compare the speed integrated over time with the GNSS track length (fixes thinned to >= 30 s apart).

    A ratio near 3.6, 1/3.6, 1.852 ... means a unit mix-up: "refuse"; off 1 by more than 25 %: "warn".
    """
    tg, ts = streams.gnss_t_ns, streams.speed_t_ns
    if tg.size < 3 or ts.size < 3:
        return SpeedCheck(float("nan"), 0.0, "skipped", "speed check skipped: too few fixes or speeds")
    frame = LocalFrame(float(np.median(streams.lat)), float(np.median(streams.lon)))
    e, n = frame.to_enu(streams.lat, streams.lon)
    t = tg * 1e-9
    picks = [0]
    for i in range(1, t.size):
        if t[i] - t[picks[-1]] >= CHECK_STEP_S:
            picks.append(i)
    picks_a = np.array(picks)
    if picks_a.size < 2:
        return SpeedCheck(float("nan"), 0.0, "skipped", "speed check skipped: the fixes span under 30 s")
    gnss_d = np.hypot(np.diff(e[picks_a]), np.diff(n[picks_a]))
    tsec = ts * 1e-9
    cum = np.concatenate(([0.0], np.cumsum(0.5 * (streams.speed_ms[1:] + streams.speed_ms[:-1]) * np.diff(tsec))))
    tp = t[picks_a]
    inside = (tp[:-1] >= tsec[0]) & (tp[1:] <= tsec[-1])
    speed_d = np.interp(tp[1:], tsec, cum) - np.interp(tp[:-1], tsec, cum)
    moving = inside & (gnss_d > 50.0)
    total = float(gnss_d[moving].sum())
    if total < MIN_CHECK_DISTANCE_M:
        return SpeedCheck(float("nan"), total, "skipped", f"speed check skipped: {total:.0f} m of travel to compare")
    ratio = float(speed_d[moving].sum() / total)
    if not ratio > 0.0:
        return SpeedCheck(ratio, total, "refuse", f"the speeds are zero while the positions move {total:.0f} m")
    factor = min(UNIT_SUSPECTS, key=lambda f: abs(np.log(ratio / f)))
    hint = UNIT_SUSPECTS[factor]
    if abs(ratio / factor - 1.0) < REFUSE_BAND:
        return SpeedCheck(
                ratio, total, "refuse",
                f"the speeds give {ratio:.2f} times the distance the positions give over {total / 1000:.1f} km: "
                f"{hint}",
            )  # fmt: skip
    if abs(ratio - 1.0) > WARN_BAND:
        return SpeedCheck(
            ratio, total, "warn",
            f"warning: the speeds give {ratio:.2f} times the distance the positions give over {total / 1000:.1f} km",
        )  # fmt: skip
    return SpeedCheck(ratio, total, "ok", f"speed vs positions: ratio {ratio:.3f} over {total / 1000:.1f} km")


def refuse(check: SpeedCheck, path: str) -> None:
    """Raise the refusal of a unit mix-up as ImportFormatError."""
    raise ImportFormatError(f"{path}: {check.message}; --no-speed-check imports anyway")
