"""Fingerprint of the estimator's outputs: a sha256 over every output byte of the whole-run API.

Run before and after a refactoring of the filter (``estimation/ukf*.py``, ``run.py``): the hash must not change
(bit-identical outputs). Covers ``estimate_run``, ``resistance_run`` and ``smooth_run`` for the presets learning
(the default, ``UKFConfig()``), paper and converging, on simulated runs with and without traction power at 10 s and
1 Hz, on the synthetic runs at 10 s and 1 Hz, and on the bundled bags through ``train_calib.pipeline.run_bag``
(per-sample ``update()``; the bags' measurements also through the whole-run API).

    .venv/bin/python test/estimation/ukf_fingerprint.py [-v]     # -v: one hash per case too
    .venv/bin/python test/estimation/ukf_fingerprint.py --against REV [FILE ...]

``--against REV``: the fingerprint of this tree and of a copy of it whose FILEs (default the filter's own,
``FILTER_FILES``) are taken from git revision REV (a FILE that REV does not have is left out of the copy: before the
split of ukf.py, its one module held the step, the safeguards, the look-ahead and the types) -- the check of a
refactoring while other files of the working tree change under it (both hashes move with them; they must stay
equal).
"""

from __future__ import annotations

import hashlib
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # repo_paths
sys.path.insert(0, str(Path(__file__).resolve().parent))

from estimation_cases import simulated_run, synthetic_run

from train_calib.estimation import UKFConfig, estimate_run, smooth_run
from train_calib.estimation.records import EstimateSeries
from train_calib.estimation.run import resistance_run
from train_calib.measurement import MeasurementSeries

PRESETS = {"learning": UKFConfig(), "paper": UKFConfig.paper(), "converging": UKFConfig.converging()}
BAGS = {
    "intercity_32km_10s_00": ("intercity_32km", "virm6"),
    "intercity_32km_10s_04": ("intercity_32km", "virm6"),
    "tunnel_line_37km_1s_00": ("tunnel_line_37km", "icrm"),
}


def series_bytes(est: EstimateSeries) -> bytes:
    """Every field of an EstimateSeries, in field order, as raw bytes (name, dtype and shape included)."""
    out = []
    for name, value in vars(est).items():
        a = np.ascontiguousarray(value)
        out.append(f"{name}:{a.dtype.str}:{a.shape}".encode())
        out.append(a.tobytes())
    return b"".join(out)


def cases():
    """(name, train, series) of every input run."""
    for power in (False, True):
        for period in (10.0, 1.0):
            _run, series, _truth, train = simulated_run(0, period, power)
            yield f"sim-power{int(power)}-{period:g}s", train, series
    for period in (10.0, 1.0):
        train, _truth, series = synthetic_run(1, period)
        yield f"synthetic-{period:g}s", train, series


def main(verbose: bool = False) -> str:
    from train_calib.paths import bags_dir, track_file, train_file
    from train_calib.pipeline import run_bag
    from train_calib.track import load_track
    from train_calib.train import load_train

    total = hashlib.sha256()
    t0 = time.perf_counter()

    def add(name: str, data: bytes) -> None:
        total.update(name.encode())
        total.update(data)
        if verbose:
            print(f"{hashlib.sha256(data).hexdigest()[:16]}  {name}", flush=True)

    runs = list(cases())
    for bag, (track_name, train_name) in BAGS.items():
        track, train = load_track(track_file(track_name)), load_train(train_file(train_name))
        for preset, cfg in PRESETS.items():
            out = run_bag(bags_dir() / bag, track, train, ukf=cfg, window=False)
            add(f"bag-{bag}-{preset}-run_bag", series_bytes(EstimateSeries.from_samples(out.estimates)))
        runs.append((f"bag-{bag}", train, MeasurementSeries.from_measurements(out.measurements)))
    for name, train, series in runs:
        for preset, cfg in PRESETS.items():
            add(f"{name}-{preset}-estimate_run", series_bytes(estimate_run(series, train, cfg)))
            pub, own = resistance_run(series, train, cfg)
            add(f"{name}-{preset}-resistance_run", series_bytes(pub) + series_bytes(own))
            add(f"{name}-{preset}-smooth_run", series_bytes(smooth_run(series, train, cfg)))
    digest = total.hexdigest()
    print(f"fingerprint {digest}  ({time.perf_counter() - t0:.0f} s)")
    return digest


FILTER_FILES = [
    f"train_calib/estimation/{name}.py"
    for name in ("ukf", "ukf_step", "ukf_safeguards", "ukf_lookahead", "ukf_types", "run")
]
"""The filter's own modules (``--against``'s default FILEs)."""


def against(rev: str, files: list[str]) -> bool:
    """Fingerprint of the working tree and of a temporary copy with ``files`` from ``rev``; True when equal."""
    import shutil
    import subprocess
    import tempfile

    root = Path(__file__).resolve().parents[2]
    hashes = []
    with tempfile.TemporaryDirectory() as tmp:
        copy = Path(tmp)
        for name in ("train_calib", "test", "config"):
            shutil.copytree(root / name, copy / name, ignore=shutil.ignore_patterns("__pycache__", "*.so"))
        shutil.copy(root / "package.xml", copy / "package.xml")
        (copy / "bags").symlink_to(root / "bags")
        for label, tree in (("working tree", root), (rev, copy)):
            if tree is copy:
                for f in files:
                    shown = subprocess.run(["git", "-C", str(root), "show", f"{rev}:{f}"], capture_output=True)
                    if shown.returncode == 0:
                        (copy / f).write_bytes(shown.stdout)
                    else:  # not in rev (a module split off since)
                        (copy / f).unlink(missing_ok=True)
            out = subprocess.run([sys.executable, str(tree / "test/estimation/ukf_fingerprint.py")], check=True,
                                 capture_output=True, text=True, cwd=tree,
                                 env={**__import__("os").environ, "PYTHONPATH": str(tree)}).stdout  # fmt: skip
            hashes.append(out.split()[1])
            print(f"{label}: {hashes[-1]}")
    print("identical" if hashes[0] == hashes[1] else "DIFFERENT")
    return hashes[0] == hashes[1]


if __name__ == "__main__":
    args = sys.argv[1:]
    if args and args[0] == "--against":
        sys.exit(0 if against(args[1], args[2:] or FILTER_FILES) else 1)
    main("-v" in args)
