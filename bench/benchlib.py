"""Helpers shared by the benchmarks: timing with CPU time beside wall time, the machine's load, and the summary
rows that ``run_all.py`` collects from each benchmark's JSON into ``bench/RESULTS.md``.

A summary row compares one measured quantity with its target and, where there is one, with a peer or a paper
figure measured or quoted for the same work::

    row("UKF step, paper preset", measured="52 us", target=">= 5x filterpy", reference="filterpy 266 us",
        ratio=5.1, ratio_text="5.1x faster", met=True)

The benchmarks write ``{"summary": [row, ...], ...}``; ``met`` is None where there is no target.
"""

from __future__ import annotations

import json
import os
import statistics
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parent.parent
OUT = REPO / "bench" / "out"


def timed(fn: Callable[[], Any], repeats: int, warmup: int = 1) -> dict[str, float]:
    """Median and minimum wall time and median CPU time of this process (s) over `repeats` calls after `warmup`.

    On a shared machine the CPU time is the better estimate of the unloaded wall time (a descheduled process
    does not accumulate CPU time); the targets are judged on the median wall time.
    """
    for _ in range(warmup):
        fn()
    wall, cpu = [], []
    for _ in range(max(1, repeats)):
        t0, c0 = time.perf_counter(), time.process_time()
        fn()
        wall.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
    return {"median_s": statistics.median(wall), "min_s": min(wall), "cpu_median_s": statistics.median(cpu),
            "repeats": len(wall)}  # fmt: skip


def load() -> float:
    """1-minute load average of the machine."""
    return os.getloadavg()[0]


def row(
    case: str,
    measured: str,
    target: str = "-",
    met: bool | None = None,
    reference: str = "-",
    ratio: float | None = None,
    ratio_text: str = "",
    note: str = "",
) -> dict[str, Any]:
    """One line of a benchmark's table in RESULTS.md (all values already formatted with their units)."""
    return {
        "case": case,
        "measured": measured,
        "target": target,
        "met": met,
        "reference": reference,
        "ratio": ratio,
        "ratio_text": ratio_text or ("-" if ratio is None else f"{ratio:.2f}"),
        "note": note,
    }


def fmt_time(seconds: float) -> str:
    """A duration with a unit that keeps 3 significant digits (us, ms or s)."""
    if seconds < 1e-3:
        return f"{seconds * 1e6:.3g} us"
    if seconds < 1.0:
        return f"{seconds * 1e3:.3g} ms"
    return f"{seconds:.3g} s"


def fmt_factor(ratio: float) -> str:
    """A speed ratio: 2 significant digits below 100, whole numbers with thousands separators above."""
    return f"{ratio:,.0f}x" if ratio >= 100 else f"{ratio:.2g}x"


def speed_text(ratio: float) -> str:
    """reference time / our time as "12x faster" or "1.3x slower"."""
    return f"{fmt_factor(ratio)} faster" if ratio >= 1.0 else f"{fmt_factor(1.0 / ratio)} slower"


def write_json(path: str | Path, data: dict[str, Any]) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(data, indent=1, default=float) + "\n", encoding="utf-8")
    return path


def print_summary(rows: list[dict[str, Any]], file: Any = sys.stdout) -> None:
    """The rows as they go to RESULTS.md, on the console."""
    for r in rows:
        met = {True: "met", False: "MISSED", None: "-"}[r["met"]]
        print(f"  {r['case']}: {r['measured']} (target {r['target']}; vs {r['reference']}: {r['ratio_text']}) {met}",
              file=file)  # fmt: skip
