"""One run, bag to row: the worker's job. The same core as ``replay`` (``pipeline.run_bag`` with the default
configuration, i.e. the learning UKF preset and the whole run's coast regression), so a fleet row holds what
``replay`` reports for that bag: the final estimate (the last /train_calib/resistance) and the whole run's best
estimate with their covariances and r(v) at 40/80/120 km/h (``summary.resistance_at_speeds``), the closing
features and the regime time shares, the ingest counts. Any failure becomes a row with status "error" and a
one-line reason; nothing raises out of :func:`process_run`.

``run_key``: sha256 over the bag's bytes (every file of a rosbag2 directory, by relative name) and the track's
and train's file contents; ``--resume`` reuses a row whose key it finds, whatever the bag is called.
"""

from __future__ import annotations

import gc
import hashlib
import json
import math
import time
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa

from .. import __version__
from ..errors import BagError
from ..regime_codes import REGIME_NAMES
from ..summary import resistance_at_speeds
from ..summary_outputs import REFERENCE_SPEEDS_KMH

KEY_VERSION = f"train_calib {__version__} fleet 1"  # part of the run key: a new version recomputes

_F = pa.float64()
_I = pa.int64()
_S = pa.string()
_L = pa.list_(pa.float64())


def _speed_fields(prefix: str) -> list[tuple[str, pa.DataType]]:
    out = []
    for kmh in REFERENCE_SPEEDS_KMH:
        out += [(f"{prefix}r{kmh:g}", _F), (f"{prefix}r{kmh:g}_std", _F)]
    return out


MANIFEST_FIELDS = [("index", _I), ("bag", _S), ("track", _S), ("train", _S), ("unit", _S), ("date", _S),
                   ("driver", _S), ("line", _S), ("date_s", _F)]  # fmt: skip
RESULT_FIELDS = [
    ("run_key", _S), ("status", _S), ("error", _S),
    ("samples", _I), ("estimates", _I), ("runs_in_bag", _I),
    ("gnss_received", _I), ("speed_received", _I), ("power_received", _I), ("dropped_total", _I), ("dropped_json", _S),
    ("r0", _F), ("r1", _F), ("r2", _F), ("final_cov", _L),
    ("best_r0", _F), ("best_r1", _F), ("best_r2", _F), ("best_cov", _L), ("coast_stretches", _I), ("coasting_s", _F),
    ("best_learnt", pa.bool_()),
    *_speed_fields(""), *_speed_fields("final_"),
    ("run_time_s", _F), ("run_distance_m", _F), ("max_tractive_effort", _F), ("max_tractive_power", _F),
    ("cruise_speed", _F), ("final_coast_duration_s", _F), ("final_brake_duration_s", _F), ("brake_rate_mean", _F),
    *[(f"share_{name}", _F) for name in REGIME_NAMES],
    ("seconds", _F),
]  # fmt: skip
RUNS_SCHEMA = pa.schema(MANIFEST_FIELDS + RESULT_FIELDS)
TIMING_COLUMNS = ("seconds",)  # differ between two executions of the same manifest
MANIFEST_COLUMNS = tuple(name for name, _ in MANIFEST_FIELDS)


def file_sha256(path: Path, h: Any) -> None:
    with open(path, "rb") as f:
        while chunk := f.read(1 << 20):
            h.update(chunk)


def run_key(bag: str | Path, track: str | Path, train: str | Path, params_sha256: str = "") -> str:
    """sha256 (hex) of the bag's content, the track's and the train's file contents, KEY_VERSION and, with
    ``--params-file``, the params file's sha256 (without one the key is as before params files existed)."""
    h = hashlib.sha256(KEY_VERSION.encode())
    bag = Path(bag)
    if not bag.exists():
        raise BagError(f"{bag}: no such bag")
    files = sorted(p for p in bag.rglob("*") if p.is_file()) if bag.is_dir() else [bag]
    if not files:
        raise BagError(f"{bag}: an empty directory, no bag files")
    for p in files:
        h.update(b"\0bag\0" + (p.relative_to(bag).as_posix().encode() if bag.is_dir() else b""))
        file_sha256(p, h)
    for tag, p in ((b"\0track\0", track), (b"\0train\0", train)):
        h.update(tag)
        file_sha256(Path(p), h)
    if params_sha256:
        h.update(b"\0params\0" + params_sha256.encode())
    return h.hexdigest()


@lru_cache(maxsize=16)
def _load(kind: str, path: str, mtime_ns: int) -> Any:
    from ..track import load_track
    from ..train import load_train

    return load_track(path) if kind == "track" else load_train(path)


def _cached(kind: str, path: str) -> Any:
    return _load(kind, path, Path(path).stat().st_mtime_ns)


def empty_result() -> dict[str, Any]:
    return {name: None for name, _ in RESULT_FIELDS}


def one_line(exc: BaseException) -> str:
    text = " ".join(str(exc).split()) or exc.__class__.__name__
    if exc.__class__.__name__ not in ("BagError", "ConfigError", "TrainCalibError"):
        text = f"{exc.__class__.__name__}: {text}"
    return text[:400]


GC_THRESHOLD0 = 20_000
"""The collector's youngest-generation threshold in a fleet worker (Python's default 700): a 1 Hz run allocates
fewer net container objects (reference counting frees the per-sample ones), so no collection falls inside a run."""
_gc_tuned = False


def tune_gc() -> None:
    """For a process that does many runs (a fleet worker), once: what is alive now (the modules, the track and
    train caches, Dask's worker) is frozen out of the collector's reach (``gc.freeze``: a full collection no longer
    walks it: 40 ms each in a bench process, more in a Dask worker) and the youngest generation is collected every
    GC_THRESHOLD0 net allocations. 1 Hz run: the collector's 5-6 ms per run -> 0 (gc callbacks)."""
    global _gc_tuned
    if not _gc_tuned:
        _gc_tuned = True
        gc.collect()
        gc.freeze()
        gc.set_threshold(GC_THRESHOLD0, *gc.get_threshold()[1:])


def _in_dask_worker() -> bool:
    try:
        from distributed import get_worker

        get_worker()
        return True
    except Exception:
        return False


def process_run(job: dict[str, Any]) -> dict[str, Any]:
    """A manifest row (``ManifestRow.columns()`` plus ``bag_path``, ``track_path``, ``train_path`` and, from
    ``--params-file``, ``configs`` (Pipeline keyword -> ParamSet) and ``params_sha256``) -> a runs.parquet row
    (dict). Never raises: a failure is status "error" with a one-line reason."""
    start = time.perf_counter()
    row = {name: job.get(name) for name in MANIFEST_COLUMNS} | empty_result()
    try:
        row["run_key"] = run_key(job["bag_path"], job["track_path"], job["train_path"], job.get("params_sha256", ""))
        row |= run_result(job["bag_path"], job["track_path"], job["train_path"], job.get("configs"))
        row["status"] = "ok"
        row["error"] = ""
    except Exception as exc:  # any failure of one run is its row, the fleet goes on
        row["status"] = "error"
        row["error"] = one_line(exc)
    row["seconds"] = time.perf_counter() - start
    if not _gc_tuned and _in_dask_worker():
        tune_gc()  # after the first run: its imports and caches are then among what is frozen
    return row


def _finite(x: Any) -> float | None:
    x = float(x)
    return x if math.isfinite(x) else None


def run_result(bag: str, track_path: str, train_path: str, configs: dict[str, Any] | None = None) -> dict[str, Any]:
    """The estimates, features and counts of one bag (raises on a bad bag, track or train); ``configs``: the
    :class:`pipeline.Pipeline` keyword configurations (None: the defaults, as ``replay`` without options)."""
    from ..pipeline import run_bag

    track = _cached("track", track_path)
    train = _cached("train", train_path)
    # the sliding-window calibration (window_calib_node) feeds nothing else and has no column in the row: not run
    # (a 1 Hz run with traction power: 300 -> 240 ms); the features of each regime change are not snapshot, the
    # row takes each run's closing ones (10 s run: 32 -> 29 ms); the per-sample regimes (the imm) are not labelled,
    # the features take the phase (1 Hz run: 131 -> 116 ms). The row is the same (test_fleet_row).
    out = run_bag(bag, track, train, **{**(configs or {}), "window": False, "feature_changes": False,
                                        "regime_labels": False})  # fmt: skip
    res: dict[str, Any] = {}
    stats = out.ingest_stats
    if stats is not None:
        res["gnss_received"] = int(stats.received.get("gnss", 0))
        res["speed_received"] = int(stats.received.get("speed", 0))
        res["power_received"] = int(stats.received.get("power", 0))
        res["dropped_total"] = int(stats.dropped_total())
        res["dropped_json"] = json.dumps(
            {s: dict(sorted(c.items())) for s, c in stats.dropped.items() if c}, sort_keys=True
        )
    res["samples"] = len(out.measurements)
    res["estimates"] = len(out.estimates)
    if not out.estimates:
        raise ValueError(f"{bag}: no sample reached the filter (is the track the bag's line?)")
    final = out.final
    r_final = np.array([final.r0, final.r1, final.r2])
    cov_final = np.asarray(final.covariance, dtype=float)[2:, 2:]
    res |= {"r0": final.r0, "r1": final.r1, "r2": final.r2, "final_cov": cov_final.ravel().tolist()}
    for kmh, v in resistance_at_speeds(r_final, cov_final, None, None).items():
        res[f"final_r{float(kmh):g}"] = v["value"]
        res[f"final_r{float(kmh):g}_std"] = v["std"]
    best = out.best
    if best is not None:
        res |= {"best_r0": best.r0, "best_r1": best.r1, "best_r2": best.r2,
                "best_cov": np.asarray(best.covariance, dtype=float).ravel().tolist(),
                "coast_stretches": len(best.stretches), "coasting_s": best.coasting_time,
                "best_learnt": bool(best.stretches)}  # fmt: skip
        for kmh, v in resistance_at_speeds(np.asarray(best.r), np.asarray(best.covariance), None, None).items():
            res[f"r{float(kmh):g}"] = v["value"]
            res[f"r{float(kmh):g}_std"] = v["std"]
    res |= _features(out.features)
    return res


def _features(features: list[Any]) -> dict[str, Any]:
    """The closing features of the bag's longest run, and the regime time shares over all its runs."""
    closing: dict[int, Any] = {}
    for f in features:
        if f.run_id not in closing or not closing[f.run_id].run_complete:
            closing[f.run_id] = f
    res: dict[str, Any] = {"runs_in_bag": len(closing)}
    if not closing:
        return res
    total = sum(f.run_time for f in closing.values())
    shares = sum(np.asarray(f.regime_time_share, dtype=float) * f.run_time for f in closing.values())
    if total > 0:
        for name, x in zip(REGIME_NAMES, np.asarray(shares) / total):
            res[f"share_{name}"] = float(x)
    f = max(closing.values(), key=lambda g: g.run_time)
    counts = np.asarray(f.brake_rate_count, dtype=float)
    means = np.asarray(f.brake_rate_mean, dtype=float)
    ok = (counts > 0) & np.isfinite(means)
    res |= {
        "run_time_s": _finite(f.run_time),
        "run_distance_m": _finite(f.run_distance),
        "max_tractive_effort": _finite(f.max_tractive_effort),
        "max_tractive_power": _finite(f.max_tractive_power),
        "cruise_speed": _finite(f.cruise_speed),
        "final_coast_duration_s": _finite(f.final_coast_duration),
        "final_brake_duration_s": _finite(f.final_brake_duration),
        "brake_rate_mean": float(np.average(means[ok], weights=counts[ok])) if ok.any() else None,
    }
    return res
