"""Per-step cost of the resistance UKF against filterpy's UnscentedKalmanFilter on the same model and inputs.

Measured on a simulated 1 Hz intercity run (1 000+ steps), medians over repeats, microseconds per
measurement (predict + update):

- ``ResistanceEstimator.update``: the node's call (Measurement in, EstimateSample with its 5x5
  covariance array out), including the effort computation, safeguards and health;
- ``estimate_run``: the same filter over a MeasurementSeries (no per-sample records);
- filterpy 1.4.5: ``UnscentedKalmanFilter.predict`` + ``update`` with MerweScaledSigmaPoints, the
  estimator's own effort inputs, the same process and measurement functions (filter only: no effort
  computation, no safeguards).

Target: the UKF step at least 5x faster than filterpy.

    .venv/bin/python bench/bench_ukf.py [--repeats N] [--json PATH]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import time
from pathlib import Path

import numpy as np
from filterpy.kalman import MerweScaledSigmaPoints, UnscentedKalmanFilter

from train_calib.estimation import ResistanceEstimator, UKFConfig, estimate_run
from train_calib.paths import track_file, train_file
from train_calib.sim import DriverParams, SensorParams, simulate_run
from train_calib.track import load_track
from train_calib.train import load_train

REPO = Path(__file__).resolve().parent.parent


def process(x, dt, u=0.0, g=0.0):
    s, v, r0, r1, r2 = x
    a = u - g - r0 - r1 * v - r2 * v * v
    return np.array([s + dt * v + 0.5 * dt * dt * a, v + dt * a, r0, r1, r2])


def filterpy_run(series, est, cfg: UKFConfig, prior) -> None:
    pts = MerweScaledSigmaPoints(5, alpha=cfg.alpha, beta=cfg.beta, kappa=cfg.kappa)
    ukf = UnscentedKalmanFilter(5, 2, 1.0, lambda x: x[:2], process, pts)
    ukf.x = np.array([series.s[0], series.v[0], *prior])
    ukf.P = est.covariance[0].copy()
    ukf.R = np.diag([cfg.meas_std_s**2, cfg.meas_std_v**2])
    ukf.Q = np.zeros((5, 5))
    dts, us, gs = est.dt.tolist(), est.input_effort.tolist(), est.track_force.tolist()
    zs = np.stack([series.s, series.v], axis=1)
    for k in range(1, len(series)):
        ukf.predict(dt=dts[k], u=us[k], g=gs[k - 1])
        ukf.update(zs[k])


def median_time(fn, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--json", default=str(REPO / "bench" / "out" / "bench_ukf.json"))
    args = parser.parse_args()
    track = load_track(track_file("intercity_32km"))
    train = load_train(train_file("virm6"))
    rng = np.random.default_rng([4, 0])
    run = simulate_run(
        track,
        train,
        driver=DriverParams.sample(rng, train=train),
        sensors=SensorParams(gnss_period_s=1.0, speed_period_s=1.0),
        rng=rng,
    )
    series = run.measurements(track, train)
    n = len(series) - 1
    items = list(series)
    result = {"steps": n, "load_before": os.getloadavg()[0], "cpus": os.cpu_count()}
    for name, cfg in (("paper", UKFConfig()), ("converging", UKFConfig.converging())):
        est = estimate_run(series, train, cfg)

        def per_sample(cfg=cfg):
            e = ResistanceEstimator(train, cfg)
            for m in items:
                e.update(m)

        t_update = median_time(per_sample, args.repeats) / n * 1e6
        t_run = median_time(lambda cfg=cfg: estimate_run(series, train, cfg), args.repeats) / n * 1e6
        t_fp = median_time(lambda cfg=cfg, est=est: filterpy_run(series, est, cfg, train.davis.as_tuple()), 3) / n * 1e6
        result[name] = {
            "update_us": t_update,
            "estimate_run_us": t_run,
            "filterpy_us": t_fp,
            "speedup_update": t_fp / t_update,
            "speedup_run": t_fp / t_run,
        }
        print(
            f"{name:10s} update() {t_update:6.1f} us/step   estimate_run {t_run:6.1f} us/step   "
            f"filterpy {t_fp:7.1f} us/step   speed-up {t_fp / t_update:4.1f}x / {t_fp / t_run:4.1f}x (target >= 5x)"
        )
    result["load_after"] = os.getloadavg()[0]
    print(f"load average {result['load_before']:.2f} -> {result['load_after']:.2f} on {result['cpus']} cpus")
    Path(args.json).parent.mkdir(parents=True, exist_ok=True)
    Path(args.json).write_text(json.dumps(result, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
