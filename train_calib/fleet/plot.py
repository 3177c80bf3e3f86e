"""fleet.png: r(80 km/h) per unit (pooled, +-2 sigma, flagged units in red), r(80 km/h) of the runs over the dates
with each unit's trend line, and distributions of driving features. Runs are read in batches and at most
``MAX_POINTS`` of them (every k-th) are drawn, so the plot's memory does not grow with the fleet."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow.parquet as pq

from .units import T_REF_S, YEAR_S

MAX_POINTS = 20000
FEATURES = (("cruise_speed", "cruise speed (km/h)", 3.6), ("share_coasting", "coasting share of time (%)", 100.0),
            ("final_coast_duration_s", "final coast (s)", 1.0))  # fmt: skip


def _sample(runs_path: Path) -> dict[str, np.ndarray]:
    pf = pq.ParquetFile(runs_path)
    step = max(1, math.ceil(pf.metadata.num_rows / MAX_POINTS))
    cols = ["unit", "status", "date_s", "r80", *(f for f, _, _ in FEATURES)]
    keep: dict[str, list[Any]] = {c: [] for c in cols}
    seen = 0
    for batch in pf.iter_batches(columns=cols, batch_size=8192):
        n = batch.num_rows
        idx = [i for i in range(n) if (seen + i) % step == 0]
        seen += n
        part = batch.take(idx).to_pydict()
        for c in cols:
            keep[c] += part[c]
    out = {c: np.asarray(v, dtype=object if c in ("unit", "status") else float) for c, v in keep.items()}
    ok = out["status"] == "ok"
    return {c: v[ok] for c, v in out.items()}


def fleet_plot(path: str | Path, runs_path: str | Path, units: list[dict[str, Any]], title: str = "") -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    runs = _sample(Path(runs_path))
    fig = plt.figure(figsize=(13, 8.5), layout="constrained")
    grid = fig.add_gridspec(2, 3)
    ax = fig.add_subplot(grid[0, :2])
    names = [u["unit"] for u in units]
    x = np.arange(len(units))
    y = np.array([u["r80"] for u in units], dtype=float) * 1000.0
    e = 2.0 * np.array([u["r80_std"] for u in units], dtype=float) * 1000.0
    flag = np.array([u["flag"] for u in units], dtype=bool)
    ax.errorbar(x[~flag], y[~flag], yerr=e[~flag], fmt="o", color="tab:blue", label="unit (pooled, +-2 sigma)")
    if flag.any():
        ax.errorbar(x[flag], y[flag], yerr=e[flag], fmt="s", color="tab:red", label="flagged")
    finite = np.isfinite(y)
    if finite.any():
        ax.axhline(float(np.median(y[finite])), color="grey", lw=1, ls="--", label="fleet median")
    ax.set_xticks(x, names, rotation=90 if len(units) > 12 else 0, fontsize=7 if len(units) > 30 else 9)
    ax.set_ylabel("r(80 km/h), mN/kg")
    ax.set_title("r(80 km/h) per unit")
    ax.legend(fontsize=8)
    ax = fig.add_subplot(grid[0, 2])
    slope = np.array([u["r80_trend_pct_per_year"] for u in units], dtype=float)
    ax.barh(x, np.nan_to_num(slope), color=np.where(flag, "tab:red", "tab:blue"))
    ax.set_yticks(x, names, fontsize=7 if len(units) > 30 else 9)
    ax.set_xlabel("trend of r(80 km/h), % per year")
    ax.set_title("trend per unit")
    ax = fig.add_subplot(grid[1, :2])
    dated = np.isfinite(runs["date_s"]) & np.isfinite(runs["r80"])
    t_years = (runs["date_s"] - T_REF_S) / YEAR_S + 2020.0
    by_unit = {u["unit"]: u for u in units}
    for name in sorted(set(runs["unit"][dated].tolist())):
        sel = dated & (runs["unit"] == name)
        red = by_unit.get(name, {}).get("flag", False)
        ax.plot(t_years[sel], runs["r80"][sel] * 1000.0, ".", ms=3, color="tab:red" if red else "tab:blue", alpha=0.4)
        u = by_unit.get(name)
        if u and math.isfinite(u["r80_trend_per_year"]) and u["first_date"]:
            t0, t1 = float(np.min(t_years[sel])), float(np.max(t_years[sel]))
            ax.plot([t0, t1], [u["r80_at_first"] * 1000.0, u["r80_at_last"] * 1000.0],
                    color="tab:red" if red else "tab:blue", lw=1.5 if red else 0.8)  # fmt: skip
    ax.set_xlabel("date (year)")
    ax.set_ylabel("r(80 km/h), mN/kg")
    ax.set_title("runs' r(80 km/h) over the dates, and each unit's trend (red: flagged)")
    sub = grid[1, 2].subgridspec(len(FEATURES), 1)
    for k, (col, label, scale) in enumerate(FEATURES):
        ax = fig.add_subplot(sub[k])
        v = runs[col] * scale
        v = v[np.isfinite(v)]
        if v.size:
            ax.hist(v, bins=30, color="tab:grey")
        ax.set_xlabel(label, fontsize=8)
        ax.tick_params(labelsize=7)
    fig.suptitle(title or "fleet")
    fig.savefig(path, dpi=90)
    plt.close(fig)
