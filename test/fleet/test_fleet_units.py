"""units.parquet's statistics against independent computations (numpy), and the flag rule on made-up units."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from train_calib.fleet.row import RUNS_SCHEMA, empty_result
from train_calib.fleet.units import T_REF_S, YEAR_S, summarize_units


def write_runs(path: Path, runs: list[dict]) -> None:
    rows = []
    for k, r in enumerate(runs):
        row = dict.fromkeys(RUNS_SCHEMA.names) | empty_result()
        row |= {"index": k, "bag": f"b{k}", "track": "t", "train": "r", "date": "", "driver": "", "line": ""}
        row |= {"status": "ok", "error": ""} | r
        rows.append(row)
    pq.write_table(pa.Table.from_pylist(rows, schema=RUNS_SCHEMA), path)


def test_pooling_and_trend_match_numpy(tmp_path: Path) -> None:
    rng = np.random.default_rng(3)
    t = T_REF_S + YEAR_S * np.sort(rng.uniform(5.0, 6.0, 15))
    sd = rng.uniform(0.001, 0.003, 15)
    y = 0.04 + 0.004 * (t - T_REF_S) / YEAR_S + rng.normal(0.0, 1.0, 15) * sd
    runs = [{"unit": "A", "date_s": float(a), "r80": float(b), "r80_std": float(c), "r40": float(b) / 2,
             "r40_std": float(c)} for a, b, c in zip(t, y, sd)]  # fmt: skip
    runs.append({"unit": "A", "status": "error", "error": "x"})
    write_runs(tmp_path / "runs.parquet", runs)
    (u,) = summarize_units(tmp_path / "runs.parquet").units
    w = 1.0 / sd**2
    assert (u["runs"], u["runs_ok"], u["runs_error"]) == (16, 15, 1)
    assert math.isclose(u["r80"], np.average(y, weights=w), rel_tol=1e-12)
    assert math.isclose(u["r80_std"], 1.0 / math.sqrt(w.sum()), rel_tol=1e-12)
    assert math.isnan(u["r120"])
    x = (t - T_REF_S) / YEAR_S
    coef, cov = np.polyfit(x, y, 1, w=np.sqrt(w), cov="unscaled")
    resid = y - np.polyval(coef, x)
    red = float(np.sum(w * resid**2) / (len(x) - 2))
    assert math.isclose(u["r80_trend_per_year"], coef[0], rel_tol=1e-6)
    assert math.isclose(u["r80_trend_std"], math.sqrt(cov[0, 0] * max(1.0, red)), rel_tol=1e-6)
    assert math.isclose(u["r80_at_first"], np.polyval(coef, x[0]), rel_tol=1e-6)


def test_flag_rule(tmp_path: Path) -> None:
    """Five ordinary units, one high, one rising, one low: only high and rising are flagged, each for its reason;
    the low one is reported, not flagged (the rule is one-sided: faults raise the resistance)."""
    runs = []
    rng = np.random.default_rng(0)
    for unit, level, slope in [("u0", 0.040, 0.0), ("u1", 0.041, 0.0), ("u2", 0.039, 0.0), ("u3", 0.0405, 0.0),
                               ("u4", 0.0395, 0.0), ("high", 0.060, 0.0), ("rising", 0.040, 0.012),
                               ("low", 0.025, 0.0)]:  # fmt: skip
        for k in range(10):
            x = 5.0 + k / 10
            runs.append({"unit": unit, "date_s": T_REF_S + x * YEAR_S, "r80_std": 0.001,
                         "r80": level + slope * (k / 10) + rng.normal(0, 0.001)})  # fmt: skip
    write_runs(tmp_path / "runs.parquet", runs)
    units = {u["unit"]: u for u in summarize_units(tmp_path / "runs.parquet").units}
    assert sorted(n for n, u in units.items() if u["flag"]) == ["high", "rising"]
    assert "above the fleet" in units["high"]["reason"] and units["high"]["z_fleet"] > 3
    assert "rising" in units["rising"]["reason"] and units["rising"]["z_trend"] > 3
    assert units["low"]["z_fleet"] < -3 and units["low"]["reason"].startswith("(not flagged: r80 below the fleet")
