"""Per-step cost of the resistance UKF against filterpy's UnscentedKalmanFilter on the same model and inputs.

On a simulated 1 Hz intercity run (virm6 on intercity_32km, about 1 170 steps), for the paper preset (Table 1:
computed effort, Euler, Q = 0) and the converging preset (known effort where confirmed, consider updates,
midpoint process, acceleration noise), medians over repeats, microseconds per measurement (predict + update):

- ``ResistanceEstimator.update``: the node's call (Measurement in, EstimateSample with its 5x5 covariance array
  out), including the effort computation, safeguards and health;
- ``estimate_run``: the same filter over a MeasurementSeries;
- filterpy 1.4.5: ``UnscentedKalmanFilter.predict`` + ``update`` with ``MerweScaledSigmaPoints`` (same alpha,
  beta, kappa), the same process and measurement functions, the estimator's own step inputs (dt, effort u,
  track force g, decoupled steps) and the same per-step logic (Q of the step, v-only updates without a GNSS
  position, consider steps, clip at 0). Only the filter: the effort computation and health are ours alone, and
  with look-ahead (converging preset) ours runs two filters per measurement (resistance and output filter).

Both filters are run with ``nonnegative="clip"`` (filterpy has no covariance-weighted projection). The outputs
are checked to agree: every state over the whole run relative to its scale, and the covariance in units of the
standard deviations (with look-ahead on known coasting, the converging preset's resistance filter, which runs
behind the published estimate: ``resistance_run``, as in test_ukf_equivalence). With the paper's sigma points
(alpha 0.001, kappa -2, w0 = -1.7e6) filterpy's own double-precision rounding is ~1e-8, hence a looser
tolerance there.

Target: the UKF step at least 5x faster than filterpy.

    .venv/bin/python bench/bench_ukf.py [--repeats N] [--json PATH]
"""

from __future__ import annotations

import argparse
import sys

import numpy as np
from benchlib import OUT, REPO, fmt_time, load, print_summary, row, speed_text, timed, write_json

sys.path.insert(0, str(REPO / "test" / "estimation"))  # the reference the tests check agreement with
from filterpy_reference import FilterpyRun

from train_calib.estimation import ResistanceEstimator, UKFConfig, estimate_run
from train_calib.estimation import run as estimation_run
from train_calib.paths import track_file, train_file
from train_calib.sim import DriverParams, SensorParams, simulate_run
from train_calib.track import load_track
from train_calib.train import load_train

TARGET_SPEEDUP = 5.0
TOLERANCE = {"paper": (1e-6, 1e-5), "converging": (1e-9, 1e-8)}
"""(state, covariance) agreement with filterpy: paper sigma points are ill-conditioned in double precision."""


def filter_trajectory(series, train, cfg: UKFConfig):
    """The UKF's own trajectory over the run, the one filterpy is compared with: estimate_run, or, where the
    estimator learns r behind the published estimate (look-ahead on known coasting), the resistance filter's
    trajectory (``resistance_run``), with the efforts it used."""
    resistance_run = getattr(estimation_run, "resistance_run", None)
    if resistance_run is None:
        return estimate_run(series, train, cfg)
    return resistance_run(series, train, cfg)[1]


def agreement(est, xs: np.ndarray, ps: np.ndarray) -> tuple[float, float]:
    """(largest state difference relative to each state's scale, largest covariance difference in units of
    sqrt(P_ii P_jj))."""
    state = est.state
    scale = np.abs(state).max(axis=0)
    x_err = float((np.abs(xs - state) / scale).max())
    d = np.sqrt(np.abs(np.diagonal(est.covariance, axis1=1, axis2=2)))
    p_err = float((np.abs(ps - est.covariance) / (d[:, :, None] * d[:, None, :] + 1e-300)).max())
    return x_err, p_err


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=9, help="repeats of our filter (filterpy: a third)")
    parser.add_argument("--json", default=str(OUT / "bench_ukf.json"))
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
    prior = train.davis.as_tuple()
    result: dict = {"steps": n, "load_before": load(), "summary": []}
    for name, cfg in (
        ("paper", UKFConfig.paper(nonnegative="clip")),
        ("converging", UKFConfig.converging(nonnegative="clip")),
    ):
        est = filter_trajectory(series, train, cfg)
        fp = FilterpyRun(series, est, cfg, prior)
        xs, ps = fp(keep=True)
        x_err, p_err = agreement(est, xs, ps)
        x_tol, p_tol = TOLERANCE[name]
        agree = x_err < x_tol and p_err < p_tol

        def per_sample(cfg=cfg):
            e = ResistanceEstimator(train, cfg)
            for m in items:
                e.update(m)

        t_update = timed(per_sample, args.repeats)
        t_run = timed(lambda cfg=cfg: estimate_run(series, train, cfg), args.repeats)
        t_fp = timed(fp, max(3, args.repeats // 3))
        us = {k: t["median_s"] / n * 1e6 for k, t in (("update", t_update), ("run", t_run), ("filterpy", t_fp))}
        cpu = {k: t["cpu_median_s"] / n * 1e6 for k, t in (("update", t_update), ("run", t_run), ("filterpy", t_fp))}
        speedup, speedup_run = us["filterpy"] / us["update"], us["filterpy"] / us["run"]
        result[name] = {
            "update_us": us["update"],
            "estimate_run_us": us["run"],
            "filterpy_us": us["filterpy"],
            "cpu_us": cpu,
            "speedup_update": speedup,
            "speedup_run": speedup_run,
            "state_err": x_err,
            "cov_err": p_err,
            "agree": agree,
            "known_effort_steps": int(est.effort_known.sum()),
            "decoupled_steps": int(est.decoupled.sum()),
        }
        print(
            f"{name:10s} update() {us['update']:6.1f} us/step   estimate_run {us['run']:6.1f} us/step   "
            f"filterpy {us['filterpy']:7.1f} us/step   speed-up {speedup:4.1f}x / {speedup_run:4.1f}x "
            f"(target >= {TARGET_SPEEDUP:g}x); outputs agree: {agree} (state {x_err:.1e}, covariance {p_err:.1e})",
            flush=True,
        )
        ok = agree and speedup >= TARGET_SPEEDUP
        result["summary"] += [
            row(f"{name} preset: ResistanceEstimator.update (node call), per step", f"{us['update']:.1f} us",
                f">= {TARGET_SPEEDUP:g}x filterpy, outputs agree", ok, f"filterpy {us['filterpy']:.0f} us",
                speedup, speed_text(speedup),
                note=f"state agreement {x_err:.0e}, covariance {p_err:.0e}"),
            row(f"{name} preset: estimate_run (whole series), per step", f"{us['run']:.1f} us",
                f">= {TARGET_SPEEDUP:g}x filterpy", speedup_run >= TARGET_SPEEDUP and agree,
                f"filterpy {us['filterpy']:.0f} us", speedup_run, speed_text(speedup_run),
                note=f"whole run {fmt_time(t_run['median_s'])}"),
        ]  # fmt: skip
    result["load_after"] = load()
    print(f"load average {result['load_before']:.2f} -> {result['load_after']:.2f}")
    print_summary(result["summary"])
    write_json(args.json, result)
    return 0


if __name__ == "__main__":
    sys.exit(main())
