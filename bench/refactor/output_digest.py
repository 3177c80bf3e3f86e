"""sha256 of everything the pipeline publishes, per input: the check that a refactor changes no output bit.

Issue 23 ("behaviour unchanged"): run this before and after a refactor and compare. Inputs:

- every bundled bag (``bags/``), with its truth file's track and train;
- every fault class of ``test/robustness/faultlib.CASES`` injected into the robustness scenario;
- the validation family (``build/validation/family``, made by ``bench/validation/family.py``) and the external
  runs of ``../shared/validation/runs`` (``--no-family`` skips both).

Per input, the online chain (``pipeline.run_bag``: measurements, estimates, regimes, features, windows, the
whole-run best estimate, the ingest's counters) and the offline whole-run APIs on its measurements
(``estimate_run``, ``classify_regimes``, ``features_per_run``) are encoded exactly (floats by ``float.hex``,
arrays by dtype, shape and bytes) and hashed.

    .venv/bin/python bench/refactor/output_digest.py --out build/digest_before.json
    .venv/bin/python bench/refactor/output_digest.py --compare build/digest_before.json

``--compare`` exits 1 and names each input whose digest differs. ``--jobs`` runs inputs in processes.
"""

from __future__ import annotations

import argparse
import dataclasses
import enum
import hashlib
import json
import sys
import tempfile
from collections.abc import Iterable, Iterator
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path[:0] = [str(ROOT / "test" / "robustness"), str(ROOT / "bench" / "validation")]

from train_calib.estimation import UKFConfig  # noqa: E402
from train_calib.estimation.features import features_per_run  # noqa: E402
from train_calib.estimation.regimes import classify_regimes  # noqa: E402
from train_calib.estimation.run import estimate_run  # noqa: E402
from train_calib.measurement import MeasurementSeries  # noqa: E402
from train_calib.paths import track_file, train_file  # noqa: E402
from train_calib.pipeline import run_bag  # noqa: E402
from train_calib.track import load_track  # noqa: E402
from train_calib.train import load_train  # noqa: E402


def encode(obj: Any, out: list[bytes]) -> None:
    """Append an exact, type-tagged byte encoding of ``obj`` (dataclasses, tuples, arrays, floats ...)."""
    if obj is None or isinstance(obj, bool):
        out.append(repr(obj).encode())
    elif isinstance(obj, enum.Enum):
        out.append(f"E{type(obj).__name__}.{obj.name}".encode())
    elif isinstance(obj, (int, np.integer)):
        out.append(b"i" + str(int(obj)).encode())
    elif isinstance(obj, (float, np.floating)):
        out.append(b"f" + float(obj).hex().encode())
    elif isinstance(obj, str):
        out.append(b"s" + obj.encode())
    elif isinstance(obj, np.ndarray):
        a = np.ascontiguousarray(obj)
        out.append(f"a{a.dtype.str}{a.shape}".encode())
        if a.dtype == object:
            for x in a.ravel():
                encode(x, out)
        else:
            out.append(a.tobytes())
    elif dataclasses.is_dataclass(obj):
        out.append(f"D{type(obj).__name__}".encode())
        for f in dataclasses.fields(obj):
            out.append(f.name.encode())
            encode(getattr(obj, f.name), out)
    elif isinstance(obj, tuple) and hasattr(obj, "_fields"):
        out.append(f"N{type(obj).__name__}".encode())
        for name, value in zip(obj._fields, obj):
            out.append(name.encode())
            encode(value, out)
    elif isinstance(obj, (list, tuple)):
        out.append(f"L{len(obj)}".encode())
        for x in obj:
            encode(x, out)
    elif isinstance(obj, dict):
        out.append(f"M{len(obj)}".encode())
        for k in sorted(obj, key=repr):
            encode(k, out)
            encode(obj[k], out)
    elif hasattr(obj, "__dict__"):
        out.append(f"O{type(obj).__name__}".encode())
        for k in sorted(vars(obj)):
            if not k.startswith("_"):
                out.append(k.encode())
                encode(vars(obj)[k], out)
    else:
        raise TypeError(f"cannot encode {type(obj).__name__}")


def digest(obj: Any) -> str:
    parts: list[bytes] = []
    encode(obj, parts)
    h = hashlib.sha256()
    for p in parts:
        h.update(len(p).to_bytes(8, "little"))
        h.update(p)
    return h.hexdigest()


def outputs_of(bag: str, track_path: str, train_path: str) -> dict[str, str]:
    """Digest of each output stream of one bag: online chain and the whole-run APIs."""
    track, train = load_track(track_path), load_train(train_path)
    out = run_bag(bag, track, train)
    result = {
        name: digest(getattr(out, name))
        for name in ("measurements", "estimates", "regimes", "features", "windows", "best", "ingest_stats")
    }
    if out.measurements:
        series = estimate_run(MeasurementSeries.from_measurements(out.measurements), train, UKFConfig())
        regimes, phases = classify_regimes(
            series.effort, series.acceleration, speed=series.v, effort_known=series.effort_known,
            opposing_force=series.resistance + series.track_force, speed_measured=series.v_measured,
            time=series.stamp_ns * 1e-9, phase=True,
        )  # fmt: skip
        result["estimate_run"] = digest(series)
        result["classify_regimes"] = digest((regimes, phases))
        result["features_per_run"] = digest(features_per_run(series, phases))
    return result


def bundled_inputs() -> Iterator[tuple[str, str, str, str]]:
    for truth in sorted((ROOT / "bags").glob("*.truth.json")):
        meta = json.loads(truth.read_text())
        bag = str(truth).removesuffix(".truth.json")
        yield (f"bags/{Path(bag).name}", bag, str(track_file(meta["track"]["name"])),
               str(train_file(Path(meta["train"]["file"]).stem)))  # fmt: skip


def fault_inputs(directory: Path) -> Iterator[tuple[str, str, str, str]]:
    import faultlib

    scenario = faultlib.make_scenario(directory)
    yield ("fault/none", str(faultlib.write_bag(directory / "none", scenario.events)),
           str(scenario.track_path), str(scenario.train_path))  # fmt: skip
    for case in faultlib.CASES:
        bag = faultlib.write_bag(directory / case.name, case.inject(scenario))
        yield f"fault/{case.name}", str(bag), str(scenario.track_path), str(scenario.train_path)


def family_inputs() -> Iterator[tuple[str, str, str, str]]:
    import score

    family = ROOT / "build" / "validation" / "family"
    if not (family / "runs.csv").exists():
        sys.exit(f"{family}/runs.csv: missing; make it with .venv/bin/python bench/validation/family.py")
    entries = score.read_runs(family, "report")
    external = ROOT.parent / "shared" / "validation" / "runs"
    if (external / "runs.csv").exists():
        entries += score.read_runs(external, "external")
    for e in entries:
        yield f"{e.split}/{Path(e.bag).name}", e.bag, e.track, e.train


def _one(item: tuple[str, str, str, str]) -> tuple[str, dict[str, str]]:
    name, bag, track, train = item
    try:
        return name, outputs_of(bag, track, train)
    except Exception as exc:  # an input that fails is an output too: its error must stay the same
        return name, {"error": f"{type(exc).__name__}: {exc}"}


def collect(items: Iterable[tuple[str, str, str, str]], jobs: int) -> dict[str, dict[str, str]]:
    items = list(items)
    if jobs <= 1:
        return dict(map(_one, items))
    with ProcessPoolExecutor(jobs) as pool:
        return dict(pool.map(_one, items, chunksize=1))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--out", type=Path, help="write the digests here (JSON)")
    ap.add_argument("--compare", type=Path, help="compare with a digests JSON written by --out; exit 1 on a difference")
    ap.add_argument("--no-family", action="store_true", help="skip the validation family and the external runs")
    ap.add_argument("--jobs", type=int, default=2)
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        inputs = [*bundled_inputs(), *fault_inputs(Path(tmp))]
        if not args.no_family:
            inputs += list(family_inputs())
        digests = collect(inputs, args.jobs)
    total = digest(digests)
    print(f"{len(digests)} inputs, {sum(len(d) for d in digests.values())} output streams, sha256 {total}")
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps({"total": total, "inputs": digests}, indent=1, sort_keys=True) + "\n")
    if args.compare:
        before = json.loads(args.compare.read_text())
        changed = sorted(
            f"{name}: {stream}"
            for name in sorted(set(before["inputs"]) | set(digests))
            for stream in sorted(set(before["inputs"].get(name, {})) | set(digests.get(name, {})))
            if before["inputs"].get(name, {}).get(stream) != digests.get(name, {}).get(stream)
        )
        for line in changed:
            print(f"differs: {line}")
        print(f"before sha256 {before['total']}; {'identical' if not changed else f'{len(changed)} streams differ'}")
        return 1 if changed else 0
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
