"""Writing a simulated run as a bag (inputs only) with its truth beside it, and reading the truth back.

Layout for a run named NAME in DIR::

    DIR/NAME/                 rosbag2 directory: metadata.yaml + NAME.mcap (message definitions embedded)
    DIR/NAME.truth.csv        truth at every /train/speed stamp (columns: run.TRUTH_COLUMNS)
    DIR/NAME.truth.json       parameters, seed, summary, column units (JSON)
    DIR/NAME.dense.csv        (optional) truth on the fine time grid

CSV: a header line with the column names, one row per sample, integers for t_ns and regime,
floats with 17 significant digits (read back bit-exact). Everything is written deterministically,
so the same command gives byte-identical files.
"""

from __future__ import annotations

import csv
import io
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from .. import bagio
from ..errors import BagError
from .run import TRUTH_COLUMNS, SimulatedRun, Trajectory

_INT_COLUMNS = {"t_ns": np.int64, "regime": np.uint8}


def truth_paths(bag_path: str | Path) -> tuple[Path, Path, Path]:
    """(truth.csv, truth.json, dense.csv) of a bag directory (or of the .mcap file inside it)."""
    path = Path(bag_path)
    if path.suffix == ".mcap" and path.parent.name == path.stem:
        path = path.parent
    stem = path.parent / path.name
    return (
        stem.with_name(path.name + ".truth.csv"),
        stem.with_name(path.name + ".truth.json"),
        stem.with_name(path.name + ".dense.csv"),
    )


def write_run(run: SimulatedRun, out_dir: str | Path, name: str, *, dense: bool = False) -> Path:
    """Write the bag DIR/NAME (rosbag2, MCAP) and the truth files beside it; returns the bag path."""
    out_dir = Path(out_dir)
    bag = out_dir / name
    csv_path, json_path, dense_path = truth_paths(bag)
    for p in (bag, csv_path, json_path) + ((dense_path,) if dense else ()):
        if p.exists():
            raise BagError(f"{p}: already exists (remove it or choose another --out/--name)")
    out_dir.mkdir(parents=True, exist_ok=True)
    write_bag(run, bag)
    csv_path.write_text(_csv_text(run.truth), encoding="utf-8", newline="")
    meta = dict(run.meta)
    meta["name"] = name
    meta["columns"] = {c: {"unit": u, "description": d} for c, u, d in TRUTH_COLUMNS}
    json_path.write_text(json.dumps(_finite(meta), indent=1, sort_keys=True) + "\n", encoding="utf-8")
    if dense:
        dense_path.write_text(_csv_text(run.dense), encoding="utf-8", newline="")
    return bag


def write_bag(run: SimulatedRun, path: Path) -> None:
    """The input topics of the run, in stamp order (log time = stamp)."""
    g, sp, pw = run.gnss, run.speed, run.power
    bagio.write_input_bag(
        path, gnss_t_ns=g.t_ns, lat=g.lat, lon=g.lon, altitude=np.zeros(g.t_ns.size), gnss_ok=g.status >= 0,
        gnss_sigma_m=g.sigma_m, speed_t_ns=sp.t_ns, speed_ms=sp.v_ms,
        power=(pw.t_ns, pw.consumed_w, pw.regenerated_w) if pw is not None else None,
    )  # fmt: skip


@dataclass
class TruthFile:
    """The truth of a written run: per-sample arrays, the meta data, and the dense grid if written."""

    truth: Trajectory
    meta: dict[str, Any]
    dense: Trajectory | None
    path: Path


def read_truth(bag_path: str | Path) -> TruthFile:
    """Read NAME.truth.csv / .truth.json (and .dense.csv if present) beside a bag; BagError if missing."""
    csv_path, json_path, dense_path = truth_paths(bag_path)
    for p in (csv_path, json_path):
        if not p.is_file():
            raise BagError(f"{p}: truth file not found (is {Path(bag_path)} a simulated bag?)")
    try:
        meta = json.loads(json_path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise BagError(f"{json_path}: unreadable truth meta data: {exc}") from None
    truth = _read_csv(csv_path)
    dense = _read_csv(dense_path) if dense_path.is_file() else None
    return TruthFile(truth, meta, dense, csv_path)


def _csv_text(traj: Trajectory) -> str:
    cols = traj.columns()
    names = [c for c, _, _ in TRUTH_COLUMNS]
    buf = io.StringIO()
    buf.write(",".join(names) + "\n")
    formatted = []
    for name in names:
        arr = cols[name]
        if name in _INT_COLUMNS:
            formatted.append([str(int(x)) for x in arr])
        else:
            formatted.append([f"{float(x):.17g}" for x in arr])
    for row in zip(*formatted):
        buf.write(",".join(row) + "\n")
    return buf.getvalue()


def _read_csv(path: Path) -> Trajectory:
    try:
        with open(path, encoding="utf-8", newline="") as f:
            reader = csv.reader(f)
            header = next(reader)
            rows = list(reader)
    except (OSError, StopIteration, csv.Error) as exc:
        raise BagError(f"{path}: unreadable truth CSV: {exc.__class__.__name__}: {exc}") from None
    names = [c for c, _, _ in TRUTH_COLUMNS]
    missing = [c for c in names if c not in header]
    if missing:
        raise BagError(f"{path}: truth CSV lacks column {missing[0]!r}")
    index = {c: header.index(c) for c in names}
    cols: dict[str, np.ndarray] = {}
    try:
        for c in names:
            values = [r[index[c]] for r in rows]
            if c in _INT_COLUMNS:
                cols[c] = np.array([int(x) for x in values], dtype=_INT_COLUMNS[c])
            else:
                cols[c] = np.array([float(x) for x in values], dtype=float)
    except (ValueError, IndexError) as exc:
        raise BagError(f"{path}: bad value in truth CSV: {exc}") from None
    return Trajectory(**cols)


def _finite(value: Any) -> Any:
    """JSON has no NaN/inf: map them to None (recursively)."""
    if isinstance(value, float):
        return value if np.isfinite(value) else None
    if isinstance(value, dict):
        return {k: _finite(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_finite(v) for v in value]
    if isinstance(value, (np.floating, np.integer)):
        return _finite(value.item())
    return value
