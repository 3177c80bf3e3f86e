"""Per unit: r(v) pooled over its runs, the trend of r(80 km/h) over the dates, and the flag.

Pooling: inverse-variance weighted mean of the runs' whole-run best r(v) (``r40``, ``r80``, ``r120`` with their
sigmas), sigma = 1 / sqrt(sum of weights); ``r80_chi2`` is the reduced chi-square of the runs about it (1 when the
runs scatter as their sigmas say; more when the unit's resistance moved over the period).

Trend: weighted least squares of r80 on the date (years), weights 1/sigma^2; the slope's sigma is scaled by
sqrt(reduced chi-square) when that exceeds 1 (the scatter the sigmas do not explain, e.g. seasons), so a drifting
unit's slope is not overconfident. Units' statistics are accumulated as sums (bounded memory whatever the runs).

Flag (the rule): with m = median and s = 1.4826 x MAD over the units with a value,
  z_fleet = (r80 - m(r80)) / sqrt(r80_std^2 + s(r80)^2)                               (departs from the fleet)
  z_trend = (slope - m(slope)) / sqrt(slope_std^2 + s(slope)^2)                       (departs from its own history
                                                                                       more than the fleet's do)
  flag = z_fleet > 3 or z_trend > 3.
One-sided: what a fault does (a dragging brake, a damaged fairing) is raise the resistance; a unit below the fleet
or falling is reported in ``reason`` but not flagged (with the units' own spread of +-8 % in the simulated fleet, a
two-sided rule flagged a healthy low unit at z -3.1 in one of five fleets). The fleet's median slope removes what
every unit shares (the seasons); a unit needs ``MIN_TREND_RUNS`` dated runs for a trend, and the fleet
``MIN_UNITS`` units for the medians (fewer: z against 0 slope / no z_fleet).
"""

from __future__ import annotations

import math
from collections import defaultdict
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from ..summary_outputs import REFERENCE_SPEEDS_KMH

YEAR_S = 365.25 * 86400.0
T_REF_S = 1577836800.0  # 2020-01-01T00:00:00Z: dates in years from it
Z_FLAG = 3.0
MIN_TREND_RUNS = 3
MIN_UNITS = 3
FLAG_RULE = (
    "flag = z_fleet > 3 or z_trend > 3 (higher or rising resistance; lower or falling is reported, not flagged); "
    "z_fleet = (r80 - median r80) / sqrt(r80_std^2 + (1.4826 MAD r80)^2), "
    "z_trend = (slope - median slope) / sqrt(slope_std^2 + (1.4826 MAD slope)^2), medians and MADs over the units"
)
SPEEDS = tuple(f"r{kmh:g}" for kmh in REFERENCE_SPEEDS_KMH)
STYLE = ("cruise_speed", "share_coasting", "final_coast_duration_s", "brake_rate_mean")
RUN_COLUMNS = ["unit", "status", "date_s", "driver", "line", *SPEEDS, *(f"{s}_std" for s in SPEEDS), *STYLE]

UNITS_SCHEMA = pa.schema(
    [("unit", pa.string()), ("runs", pa.int64()), ("runs_ok", pa.int64()), ("runs_error", pa.int64()),
     *[(f"{s}{suffix}", pa.float64()) for s in SPEEDS for suffix in ("", "_std")],
     ("r80_chi2", pa.float64()), ("first_date", pa.string()), ("last_date", pa.string()),
     ("r80_trend_per_year", pa.float64()), ("r80_trend_std", pa.float64()), ("r80_trend_pct_per_year", pa.float64()),
     ("r80_at_first", pa.float64()), ("r80_at_last", pa.float64()),
     ("z_fleet", pa.float64()), ("z_trend", pa.float64()), ("flag", pa.bool_()), ("reason", pa.string()),
     *[(f"mean_{s}", pa.float64()) for s in STYLE]]
)  # fmt: skip


@dataclass
class Sums:
    """Weighted sums of one unit (pooling and WLS), and style means."""

    runs: int = 0
    ok: int = 0
    pool: dict[str, list[float]] = field(default_factory=lambda: {s: [0.0, 0.0, 0.0] for s in SPEEDS})  # w, wy, wy2
    trend: np.ndarray = field(default_factory=lambda: np.zeros(6))  # w, wt, wt2, wy, wty, wy2 (dated runs)
    dated: int = 0
    t_min: float = math.inf
    t_max: float = -math.inf
    style: dict[str, list[float]] = field(default_factory=lambda: {s: [0.0, 0] for s in STYLE})

    def add(self, row: dict[str, Any]) -> None:
        self.runs += 1
        if row["status"] != "ok":
            return
        self.ok += 1
        for s in SPEEDS:
            y, sd = row.get(s), row.get(f"{s}_std")
            if _good(y) and _good(sd) and sd > 0:
                w = 1.0 / sd**2
                p = self.pool[s]
                p[0] += w
                p[1] += w * y
                p[2] += w * y * y
        for s in STYLE:
            x = row.get(s)
            if _good(x):
                self.style[s][0] += x
                self.style[s][1] += 1
        y, sd, t = row.get("r80"), row.get("r80_std"), row.get("date_s")
        if _good(y) and _good(sd) and sd > 0 and _good(t):
            w = 1.0 / sd**2
            ty = (t - T_REF_S) / YEAR_S
            self.trend += w * np.array([1.0, ty, ty * ty, y, ty * y, y * y])
            self.dated += 1
            self.t_min, self.t_max = min(self.t_min, t), max(self.t_max, t)


def _good(x: Any) -> bool:
    return x is not None and math.isfinite(x)


def _iso(t: float) -> str | None:
    if not math.isfinite(t):
        return None
    from datetime import datetime, timezone

    return datetime.fromtimestamp(t, tz=timezone.utc).date().isoformat()


def _robust(values: list[float]) -> tuple[float, float]:
    a = np.asarray([v for v in values if _good(v)], dtype=float)
    if a.size == 0:
        return math.nan, math.nan
    m = float(np.median(a))
    return m, float(1.4826 * np.median(np.abs(a - m)))


def unit_row(unit: str, s: Sums) -> dict[str, Any]:
    nan = math.nan
    row: dict[str, Any] = {"unit": unit, "runs": s.runs, "runs_ok": s.ok, "runs_error": s.runs - s.ok}
    for name in SPEEDS:
        w, wy, wy2 = s.pool[name]
        row[name] = wy / w if w > 0 else nan
        row[f"{name}_std"] = 1.0 / math.sqrt(w) if w > 0 else nan
        if name == "r80":
            n = s.ok
            chi2 = wy2 - wy * wy / w if w > 0 else nan
            row["r80_chi2"] = max(chi2, 0.0) / (n - 1) if w > 0 and n > 1 else nan
    row["first_date"], row["last_date"] = _iso(s.t_min), _iso(s.t_max)
    slope = slope_std = intercept = nan
    if s.dated >= MIN_TREND_RUNS:
        w, wt, wt2, wy, wty, wy2 = s.trend
        det = w * wt2 - wt * wt
        if det > 0:
            slope = (w * wty - wt * wy) / det
            intercept = (wt2 * wy - wt * wty) / det
            chi2 = wy2 - 2 * intercept * wy - 2 * slope * wty + intercept**2 * w + 2 * intercept * slope * wt
            chi2 += slope**2 * wt2
            red = max(chi2, 0.0) / (s.dated - 2) if s.dated > 2 else 1.0
            slope_std = math.sqrt(w / det) * math.sqrt(max(1.0, red))
    row["r80_trend_per_year"] = slope
    row["r80_trend_std"] = slope_std
    row["r80_trend_pct_per_year"] = 100.0 * slope / row["r80"] if _good(slope) and row["r80"] else nan
    for key, t in (("r80_at_first", s.t_min), ("r80_at_last", s.t_max)):
        row[key] = intercept + slope * (t - T_REF_S) / YEAR_S if _good(slope) else nan
    for name in STYLE:
        total, count = s.style[name]
        row[f"mean_{name}"] = total / count if count else nan
    return row


def flag_units(rows: list[dict[str, Any]]) -> None:
    """z_fleet, z_trend, flag and reason of every unit row (in place), by FLAG_RULE."""
    m_r, s_r = _robust([r["r80"] for r in rows])
    m_t, s_t = _robust([r["r80_trend_per_year"] for r in rows])
    enough = sum(_good(r["r80"]) for r in rows) >= MIN_UNITS
    enough_t = sum(_good(r["r80_trend_per_year"]) for r in rows) >= MIN_UNITS
    for r in rows:
        z_f = z_t = math.nan
        if enough and _good(r["r80"]):
            z_f = (r["r80"] - m_r) / math.sqrt(r["r80_std"] ** 2 + s_r**2)
        if _good(r["r80_trend_per_year"]):
            center, spread = (m_t, s_t) if enough_t else (0.0, 0.0)
            z_t = (r["r80_trend_per_year"] - center) / math.sqrt(r["r80_trend_std"] ** 2 + spread**2)
        r["z_fleet"], r["z_trend"] = z_f, z_t
        reasons, notes = [], []
        if _good(z_f) and abs(z_f) > Z_FLAG:
            (reasons if z_f > 0 else notes).append(f"r80 {'above' if z_f > 0 else 'below'} the fleet (z {z_f:+.1f})")
        if _good(z_t) and abs(z_t) > Z_FLAG:
            (reasons if z_t > 0 else notes).append(
                f"r80 {'rising' if z_t > 0 else 'falling'} against the fleet (z {z_t:+.1f})"
            )
        r["flag"] = bool(reasons)
        r["reason"] = "; ".join(reasons + [f"(not flagged: {n})" for n in notes])


@dataclass
class FleetStats:
    units: list[dict[str, Any]]
    groups: dict[str, dict[str, dict[str, Any]]]  # "line"/"driver" -> name -> {runs, mean style}


def summarize_units(runs_path: str | Path) -> FleetStats:
    """Read runs.parquet batch by batch; per unit rows (flagged) and per line / driver style means."""
    sums: dict[str, Sums] = defaultdict(Sums)
    groups: dict[str, dict[str, Sums]] = {"line": defaultdict(Sums), "driver": defaultdict(Sums)}
    pf = pq.ParquetFile(runs_path)
    for batch in pf.iter_batches(columns=RUN_COLUMNS, batch_size=8192):
        for row in batch.to_pylist():
            sums[row["unit"]].add(row)
            for g in ("line", "driver"):
                if row[g]:
                    groups[g][row[g]].add(row)
    rows = [unit_row(u, sums[u]) for u in sorted(sums)]
    flag_units(rows)
    out_groups: dict[str, dict[str, dict[str, Any]]] = {}
    for g, by in groups.items():
        out_groups[g] = {}
        for name in sorted(by):
            s = by[name]
            entry: dict[str, Any] = {"runs": s.runs, "runs_ok": s.ok}
            for k in STYLE:
                total, count = s.style[k]
                entry[f"mean_{k}"] = total / count if count else None
            out_groups[g][name] = entry
    return FleetStats(rows, out_groups)


def write_units(path: str | Path, rows: list[dict[str, Any]]) -> None:
    pq.write_table(pa.Table.from_pylist(rows, schema=UNITS_SCHEMA), path)
