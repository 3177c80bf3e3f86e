"""Calibrate a fleet: every run of a manifest through the offline pipeline, per unit and over time.

MANIFEST is a CSV with a header: ``bag,track,train,unit`` required, ``date`` (ISO 8601), ``driver``, ``line``
optional; relative paths are taken from the manifest's folder (a track or train that is no file there is a bundled
name). Writes DIR/runs.parquet (one row per manifest line, in its order), DIR/units.parquet (per unit: pooled
r(v), trend of r(80 km/h), flag), DIR/fleet.json (totals) and DIR/fleet.png. Runs on local worker processes
(--workers, default all cores) or on a running Dask cluster (--scheduler tcp://HOST:PORT, or tls://HOST:PORT with
--tls-ca-file, --tls-cert, --tls-key); the rows are the same either way. A run that fails is a row with status
"error" and its reason; the exit status is 0 when every run was processed. See docs/fleet.md.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path
from typing import Any

NAME = "fleet"
HELP = "calibrate a fleet from a manifest of bags (local processes or a Dask cluster): runs, units, trends, flags"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("manifest", metavar="MANIFEST", help="CSV: bag,track,train,unit[,date,driver,line]")
    parser.add_argument("--out", required=True, metavar="DIR", help="output directory")
    where = parser.add_mutually_exclusive_group()
    where.add_argument("--workers", type=int, metavar="N", help="local worker processes (default: all cores)")
    where.add_argument(
        "--scheduler",
        metavar="ADDRESS",
        help="a running Dask scheduler, tcp://HOST:PORT (private networks only) or tls://HOST:PORT",
    )
    parser.add_argument("--tls-ca-file", metavar="FILE", help="CA certificate (PEM) for --scheduler tls://")
    parser.add_argument("--tls-cert", metavar="FILE", help="client certificate (PEM) for --scheduler tls://")
    parser.add_argument("--tls-key", metavar="FILE", help="client private key (PEM) for --scheduler tls://")
    parser.add_argument(
        "--params-file",
        metavar="FILE",
        help="ROS 2 params file (the nodes' format, e.g. config/train_calib.yaml) applied to every run",
    )
    parser.add_argument("--resume", action="store_true", help="reuse the rows already in DIR (same bag content)")
    parser.add_argument("--quiet", action="store_true", help="no progress bar, one line at the end")


def run(args: argparse.Namespace) -> int:
    from ..fleet.manifest import read_manifest
    from ..fleet.params import load_fleet_params
    from ..fleet.runner import Cluster, FleetError, run_fleet

    if args.workers is not None and args.workers < 1:
        raise FleetError(f"--workers: must be at least 1, found {args.workers}")
    rows = read_manifest(args.manifest)
    params = load_fleet_params(args.params_file) if args.params_file else None
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise FleetError(f"--out: {out}: exists and is not a directory")
    cluster = Cluster(
        workers=args.workers,
        scheduler=args.scheduler,
        tls_ca_file=args.tls_ca_file,
        tls_cert=args.tls_cert,
        tls_key=args.tls_key,
    )
    if not args.scheduler and (args.tls_ca_file or args.tls_cert or args.tls_key):
        raise FleetError("--tls-ca-file/--tls-cert/--tls-key: need --scheduler tls://HOST:PORT")
    bar = None
    on_row = None
    if not args.quiet:
        from tqdm import tqdm

        bar = tqdm(total=len(rows), unit="run", file=sys.stderr, dynamic_ncols=True, smoothing=0.1)

        def on_row(row: dict[str, Any], result: Any) -> None:
            bar.update(1)
            bar.set_postfix(ok=result.ok, error=result.errors, resumed=result.resumed, refresh=False)

    try:
        result = run_fleet(rows, out, cluster, resume=args.resume, on_row=on_row, params=params)
    finally:
        if bar is not None:
            bar.close()
    totals = finish(out, result, args)
    line = (
        f"{out}: {totals['runs']} runs ({totals['ok']} ok, {totals['errors']} error, {totals['resumed']} resumed) "
        f"in {totals['wall_s']:.1f} s on {totals['workers']} workers ({totals['runs_per_s']:.1f} runs/s); "
        f"{totals['units']} units, {len(totals['flagged'])} flagged"
        + (f": {', '.join(totals['flagged'])}" if totals["flagged"] else "")
    )
    print(line)
    return 0


def finish(out: Path, result: Any, args: argparse.Namespace | None = None) -> dict[str, Any]:
    """units.parquet, fleet.json and fleet.png from runs.parquet; returns the totals (fleet.json)."""
    from ..fleet.plot import fleet_plot
    from ..fleet.runner import RUNS
    from ..fleet.units import FLAG_RULE, summarize_units, write_units

    start = time.perf_counter()
    stats = summarize_units(out / RUNS)
    write_units(out / "units.parquet", stats.units)
    flagged = [u["unit"] for u in stats.units if u["flag"]]
    r80 = [u["r80"] for u in stats.units if math.isfinite(u["r80"])]
    totals: dict[str, Any] = {
        "manifest": str(Path(args.manifest).resolve()) if args is not None else None,
        "params_file": str(Path(args.params_file).resolve()) if getattr(args, "params_file", None) else None,
        "params_sha256": result.params_sha256 or None,
        "runs": result.total,
        "ok": result.ok,
        "errors": result.errors,
        "resumed": result.resumed,
        "computed": result.computed,
        "units": len(stats.units),
        "flagged": flagged,
        "flag_rule": FLAG_RULE,
        "fleet_r80_median": sorted(r80)[len(r80) // 2] if r80 else None,
        "scheduler": result.scheduler,
        "workers": result.workers,
        "wall_s": result.wall_s,
        "runs_per_s": result.computed / result.wall_s if result.wall_s > 0 else 0.0,
        "worker_seconds": result.worker_seconds,
        "seconds_per_run": result.worker_seconds / result.computed if result.computed else None,
        "by_line": stats.groups["line"],
        "by_driver": stats.groups["driver"],
        "outputs": ["runs.parquet", "units.parquet", "fleet.json", "fleet.png"],
    }
    fleet_plot(out / "fleet.png", out / RUNS, stats.units,
               title=f"fleet: {result.total} runs, {len(stats.units)} units, {len(flagged)} flagged")  # fmt: skip
    totals["summary_s"] = time.perf_counter() - start
    (out / "fleet.json").write_text(json.dumps(_plain(totals), indent=1) + "\n", encoding="utf-8")
    return totals


def _plain(value: Any) -> Any:
    if isinstance(value, dict):
        return {k: _plain(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_plain(v) for v in value]
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value
