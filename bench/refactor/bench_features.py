"""Timing of the feature extraction alone, online and offline, on the bundled bags (issue 23's before/after check).

Each bundled bag goes once through ``pipeline.run_bag`` (ingest, UKF, regimes); the timed part is then only the
features: ``FeatureAccumulator.update`` over every estimate with its phase (online, as feature_node) and
``features_per_run`` over the whole run (offline). Minimum and median wall time and median CPU
time over repeats (benchlib.timed), in ms for all bags together.

    PYTHONPATH=. .venv/bin/python bench/refactor/bench_features.py [--repeats N]
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path[:0] = [str(ROOT / "bench" / "refactor"), str(ROOT / "bench")]

from benchlib import timed  # noqa: E402
from output_digest import bundled_inputs  # noqa: E402

from train_calib.estimation import EstimateSeries, FeatureAccumulator  # noqa: E402
from train_calib.estimation.features import features_per_run  # noqa: E402
from train_calib.pipeline import run_bag  # noqa: E402
from train_calib.track import load_track  # noqa: E402
from train_calib.train import load_train  # noqa: E402


def prepared() -> list[tuple[list, list[int], EstimateSeries, np.ndarray]]:
    """(estimates, phases, the estimates as a series, phases as an array) per bundled bag."""
    out = []
    for _name, bag, track, train in bundled_inputs():
        res = run_bag(bag, load_track(track), load_train(train))
        phases = [r.phase for r in res.regimes]
        estimates = res.estimates[: len(phases)]
        out.append((estimates, phases, EstimateSeries.from_samples(estimates), np.asarray(phases)))
    return out


def _ms(t: dict[str, float]) -> dict[str, float]:
    """benchlib.timed's result in ms: minimum wall, median wall, median CPU time."""
    return {"min": 1e3 * t["min_s"], "median": 1e3 * t["median_s"], "cpu_median": 1e3 * t["cpu_median_s"]}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeats", type=int, default=7)
    args = ap.parse_args()
    data = prepared()

    def online() -> None:
        for estimates, phases, _, _ in data:
            acc = FeatureAccumulator()
            for e, p in zip(estimates, phases):
                acc.update(e, p)
            acc.snapshot(True)

    def offline() -> None:
        for _, _, series, phases in data:
            features_per_run(series, phases)

    result = {
        "samples": sum(len(d[1]) for d in data),
        "online_ms": _ms(timed(online, args.repeats)),
        "offline_ms": _ms(timed(offline, args.repeats)),
        "load": os.getloadavg()[0],
    }
    print(json.dumps(result))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
