"""Benchmark of the prediction per estimate (prediction_node's work: issue 24), against its 5 ms target at 1 Hz.

The estimates of a real replay's core (``train_calib.pipeline.run_bag``) on a bundled bag, then for each estimate
``Predictor.predict`` (coasting to the next station and lower limit for both models with sigma points, the nominal
time for both) and the conversion to the Prediction message, timed one by one: median, 99th percentile and max
wall time, and the median CPU time of the process (the better estimate of the unloaded time on a shared machine).

    .venv/bin/python bench/bench_prediction.py [--stride N] [--json PATH]
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np
from benchlib import OUT, fmt_time, load, print_summary, row, write_json

from train_calib.paths import bags_dir, track_file, train_file
from train_calib.pipeline import run_bag
from train_calib.prediction import Predictor
from train_calib.track import load_track
from train_calib.train import load_train

TARGET_S = 0.005
CASES = (("1 Hz, tunnel_line_37km_1s_00 (icrm)", "tunnel_line_37km_1s_00", "tunnel_line_37km", "icrm"),
         ("10 s, intercity_32km_10s_00 (virm6)", "intercity_32km_10s_00", "intercity_32km", "virm6"))  # fmt: skip


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--stride", type=int, default=1, help="time every N-th estimate (default every one)")
    parser.add_argument("--json", default=str(OUT / "bench_prediction.json"))
    args = parser.parse_args()
    from train_calib.nodes.prediction_node import prediction_to_msg

    rows, cases = [], {}
    for title, bag, track_name, train_name in CASES:
        track, train = load_track(track_file(track_name)), load_train(train_file(train_name))
        estimates = run_bag(bags_dir() / bag, track, train).estimates[:: max(args.stride, 1)]
        predictor = Predictor(track, train)
        for e in estimates[:5]:  # warm-up (the legs' grids are cached per station, as in the node)
            predictor.predict(e.stamp_ns, e.run_id, e.s, e.v, np.array([e.r0, e.r1, e.r2]), e.covariance)
        load_before = load()
        wall, cpu = [], []
        for e in estimates:
            t0, c0 = time.perf_counter(), time.process_time()
            p = predictor.predict(e.stamp_ns, e.run_id, e.s, e.v, np.array([e.r0, e.r1, e.r2]), e.covariance)
            prediction_to_msg(p)
            wall.append(time.perf_counter() - t0)
            cpu.append(time.process_time() - c0)
        w = np.array(wall)
        med, p99, mx = float(np.median(w)), float(np.percentile(w, 99)), float(w.max())
        cpu_med = statistics.median(cpu)
        cases[title] = {"estimates": len(w), "median_s": med, "p99_s": p99, "max_s": mx, "cpu_median_s": cpu_med,
                        "load_before": load_before, "load_after": load()}  # fmt: skip
        print(f"{title}: {len(w)} estimates, median {fmt_time(med)} (CPU {fmt_time(cpu_med)}), p99 {fmt_time(p99)}, "
              f"max {fmt_time(mx)}; load {load_before:.1f} -> {load():.1f}")  # fmt: skip
        rows.append(row(f"prediction per estimate, {title}", measured=f"median {fmt_time(med)}, p99 {fmt_time(p99)}",
                        target="median < 5 ms", met=med < TARGET_S, reference=f"CPU median {fmt_time(cpu_med)}",
                        note=f"max {fmt_time(mx)}, load {load_before:.1f}"))  # fmt: skip
    print_summary(rows)
    write_json(args.json, {"summary": rows, "cases": cases})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
