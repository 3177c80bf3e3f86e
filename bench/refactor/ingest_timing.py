"""Per-sample time of the ingest alone: ``Ingest.run`` over the inputs of every bundled bag (issue 23's check that
the split of ``Ingest`` costs nothing per sample).

The messages are decoded once; each repeat runs a fresh Ingest per bag. Printed: the minimum over the repeats of
the wall time and of the CPU time, per input sample in us (the CPU time is the steadier one on a shared machine).
To compare two trees, run this file with each on PYTHONPATH, alternately, a few times, and take the minima:

    git archive BASE train_calib package.xml | tar -x -C /tmp/base && ln -s $PWD/config /tmp/base/config
    PYTHONPATH=/tmp/base .venv/bin/python bench/refactor/ingest_timing.py
    PYTHONPATH=$PWD .venv/bin/python bench/refactor/ingest_timing.py
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path
from typing import Any

import train_calib
from train_calib.ingest import Ingest, fix_from_msg, power_from_msg, speed_from_msg
from train_calib.paths import track_file, train_file
from train_calib.pipeline import GNSS_TOPIC, POWER_TOPIC, SPEED_TOPIC, bag_messages
from train_calib.track import Track, load_track
from train_calib.train import TrainSpec, load_train

ROOT = Path(__file__).resolve().parents[2]
CONVERTERS = {GNSS_TOPIC: fix_from_msg, SPEED_TOPIC: speed_from_msg, POWER_TOPIC: power_from_msg}


def bundled_events() -> list[tuple[Track, TrainSpec, list[Any]]]:
    """(track, train, input samples in arrival order) of every bundled bag."""
    out = []
    for truth in sorted((ROOT / "bags").glob("*.truth.json")):
        meta = json.loads(truth.read_text())
        bag = str(truth).removesuffix(".truth.json")
        track = load_track(track_file(meta["track"]["name"]))
        train = load_train(train_file(Path(meta["train"]["file"]).stem))
        events = [CONVERTERS[topic](msg) for topic, msg in bag_messages(bag) if topic in CONVERTERS]
        out.append((track, train, events))
    return out


def time_ingest(inputs: list[tuple[Track, TrainSpec, list[Any]]], repeats: int) -> tuple[float, float]:
    """Minimum wall and CPU time (s) of one pass over all inputs."""
    wall = cpu = float("inf")
    for _ in range(repeats):
        w0, c0 = time.perf_counter(), time.process_time()
        for track, train, events in inputs:
            for _m in Ingest(track, train).run(events):
                pass
        wall = min(wall, time.perf_counter() - w0)
        cpu = min(cpu, time.process_time() - c0)
    return wall, cpu


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeats", type=int, default=7)
    args = ap.parse_args(argv)
    inputs = bundled_events()
    n = sum(len(events) for _, _, events in inputs)
    wall, cpu = time_ingest(inputs, args.repeats)
    print(
        f"{Path(train_calib.__file__).parent}: {n} samples of {len(inputs)} bags, min of {args.repeats}: "
        f"wall {wall / n * 1e6:.2f} us, CPU {cpu / n * 1e6:.2f} us per sample"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
