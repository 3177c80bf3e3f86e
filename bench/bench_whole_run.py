"""Whole-run benchmark and proof against truth of the estimator core (docs/estimator.md).

Timing (default): ``estimate_run`` on a simulated 32 km intercity run (virm6) at 10 s and at 1 Hz,
median over repeats, core only (targets: < 5 ms at 10 s, < 50 ms at 1 Hz).

``--accuracy``: the tables of docs/estimator.md, from runs simulated with known truth:

* resistance: start from the true Davis coefficients times (1 +- 20 %) (six sign patterns), report the
  error of r(v) at 40, 80, 120 km/h and of each coefficient at the end of the run, mean |error| and
  spread over runs, per configuration (paper Table 1, converging preset, and the engineering options);
* regimes: confusion matrix against the simulator's labels on the bundled bags (through the ingest, as
  the node graph runs them) and on simulated runs, next to the ceiling of the rule itself (the rule
  applied to the TRUE effort and acceleration);
* features: brake rate per ATB-EG step, cruise speed, max tractive power, final coast and final brake
  durations, against the same definitions applied to the dense (0.5 s) truth.

    .venv/bin/python bench/bench_whole_run.py [--repeats N] [--accuracy [--runs N]] [--json PATH]
"""

from __future__ import annotations

import argparse
import glob
import json
import os
import statistics
import sys
import time
from pathlib import Path

import numpy as np

from train_calib.estimation import (
    EstimateSeries,
    FeatureConfig,
    RegimeConfig,
    UKFConfig,
    classify_regimes,
    estimate_run,
    extract_features,
)
from train_calib.paths import bags_dir, track_file, train_file
from train_calib.physics import KMH
from train_calib.sim import DriverParams, SensorParams, simulate_run
from train_calib.track import load_track
from train_calib.train import Davis, load_train

REPO = Path(__file__).resolve().parent.parent
PATTERNS = np.array([[1, 1, 1], [-1, -1, -1], [1, -1, 1], [-1, 1, -1], [1, 1, -1], [-1, -1, 1]])
SPEEDS_KMH = (40.0, 80.0, 120.0)


# -- simulated runs --------------------------------------------------------------------------------
def simulate(k: int, period: float, power: bool = False, track_name: str = "intercity_32km", train_name: str = "virm6"):
    """Run k: true resistance = train file x (1 +- U(5, 20) %), a driver drawn from the papers' ranges."""
    track = load_track(track_file(track_name))
    train = load_train(train_file(train_name))
    rng = np.random.default_rng([4, k])
    factors = 1.0 + rng.choice([-1.0, 1.0], 3) * rng.uniform(0.05, 0.2, 3)
    truth = Davis(*(np.array(train.davis.as_tuple()) * factors))
    driver = DriverParams.sample(rng, train=train)
    sensors = SensorParams(gnss_period_s=period, speed_period_s=period, power_period_s=period if power else 0.0)
    run = simulate_run(track, train, driver=driver, sensors=sensors, rng=rng, resistance=truth)
    return run, run.measurements(track, train), truth, train


def initial_guess(truth: Davis, k: int) -> Davis:
    return Davis(*(np.array(truth.as_tuple()) * (1.0 + 0.2 * PATTERNS[k % len(PATTERNS)])))


def resistance_errors(est: Davis, truth: Davis) -> list[float]:
    """Relative errors of r(v) at SPEEDS_KMH, then of r0, r1, r2."""
    out = [float((est(v * KMH) - truth(v * KMH)) / truth(v * KMH)) for v in SPEEDS_KMH]
    return out + [(a - b) / b for a, b in zip(est.as_tuple(), truth.as_tuple())]


CONFIGS = {
    "paper (Table 1, computed effort)": UKFConfig(),
    "paper + known effort": UKFConfig(effort_mode="exploit_known"),
    "converging": UKFConfig.converging(),
    "converging, r coupled (no consider)": UKFConfig.converging(decouple_unknown_effort=False),
    "converging, no power": UKFConfig.converging(use_power=False),
    "converging, accel noise 0": UKFConfig.converging(accel_noise_std=0.0),
    "converging, accel noise 0.03": UKFConfig.converging(accel_noise_std=0.03),
    "converging, r noise": UKFConfig.converging(noise_r0=1e-5, noise_r1=1e-7, noise_r2=1e-7),
    "converging, euler": UKFConfig.converging(integration="euler"),
}


REGIME_VARIANTS = (
    ("paper (Table 1, computed effort)", RegimeConfig()),
    ("converging", RegimeConfig()),
    ("converging", RegimeConfig(hold_detection=True)),
)


def resistance_table(runs, configs=CONFIGS) -> dict:
    out = {}
    for name, cfg in configs.items():
        rows = []
        for k, (_run, ms, truth, train) in enumerate(runs):
            est = estimate_run(ms, train, cfg, initial=initial_guess(truth, k))
            rows.append([*resistance_errors(est.final_davis(), truth), float(np.mean(est.health == 2))])
        e = np.array(rows) * 100.0
        out[name] = {
            "mean_abs": np.mean(np.abs(e), axis=0).tolist(),
            "std": np.std(e, axis=0).tolist(),
            "max_abs": np.max(np.abs(e), axis=0).tolist(),
        }
    return out


# -- truth features --------------------------------------------------------------------------------
def truth_series(traj) -> EstimateSeries:
    """The dense truth as an estimate series (effort = u, acceleration = a), for extract_features."""
    n = len(traj)
    out = EstimateSeries.empty(n)
    out.stamp_ns[:] = traj.t_ns
    out.s[:], out.v[:] = traj.s, traj.v
    out.effort[:], out.acceleration[:] = traj.u, traj.a
    out.dt[1:] = np.diff(traj.t_ns) * 1e-9
    return out


def confusion(truth: np.ndarray, est: np.ndarray) -> np.ndarray:
    return np.array([[int(np.sum((truth == i) & (est == j))) for j in range(5)] for i in range(5)])


def feature_errors(est_f, truth_f, period: float) -> dict:
    out = {}
    both = (est_f.brake_rate_count > 0) & (truth_f.brake_rate_count > 0)
    out["brake_rate_abs_err"] = np.abs(est_f.brake_rate_mean - truth_f.brake_rate_mean)[both].tolist()
    out["cruise_speed_err_kmh"] = float((est_f.cruise_speed - truth_f.cruise_speed) / KMH)
    out["max_power_rel_err"] = float(
        (est_f.max_tractive_power - truth_f.max_tractive_power) / truth_f.max_tractive_power
    )
    out["final_coast_err_s"] = float(est_f.final_coast_duration - truth_f.final_coast_duration)
    out["final_brake_err_s"] = float(est_f.final_brake_duration - truth_f.final_brake_duration)
    out["period"] = period
    return out


def sim_regimes_features(runs, cfg: UKFConfig, rcfg: RegimeConfig, fcfg: FeatureConfig, period: float) -> dict:
    cm = np.zeros((5, 5), dtype=int)
    cm_rule = np.zeros((5, 5), dtype=int)
    cm_vs_rule = np.zeros((5, 5), dtype=int)
    feats = []
    for run, ms, _truth, train in runs:
        est = estimate_run(ms, train, cfg)
        reg = classify_regimes(est.effort, est.acceleration, rcfg, speed=est.v)
        t = run.truth
        rule = classify_regimes(t.u, t.a, rcfg, speed=t.v)
        cm += confusion(t.regime, reg)
        cm_rule += confusion(t.regime, rule)
        cm_vs_rule += confusion(rule, reg)
        f_est = extract_features(est, reg, fcfg)
        f_truth = extract_features(truth_series(run.dense), run.dense.regime, fcfg)
        feats.append(feature_errors(f_est, f_truth, period))
    return {"confusion": cm, "rule_ceiling": cm_rule, "vs_rule": cm_vs_rule, "features": feats}


def bag_regimes(cfg: UKFConfig, rcfg: RegimeConfig, fcfg: FeatureConfig) -> dict:
    """The bundled bags through the pipeline (ingest + core, as the node graph)."""
    from train_calib.pipeline import run_bag
    from train_calib.sim import read_truth

    out = {}
    for path in sorted(glob.glob(str(bags_dir() / "*.truth.csv"))):
        bag = path[: -len(".truth.csv")]
        tf = read_truth(bag)
        meta = tf.meta
        track = load_track(track_file(Path(meta["track"]["file"]).stem))
        train = load_train(train_file(Path(meta["train"]["file"]).stem))
        res = run_bag(bag, track, train, ukf=cfg, regime=rcfg, features=fcfg)
        est = EstimateSeries.from_samples(res.estimates)
        reg = np.array([r.regime for r in res.regimes], dtype=np.uint8)
        t = tf.truth
        idx = np.searchsorted(t.t_ns, est.stamp_ns)
        idx = np.minimum(idx, len(t) - 1)
        ok = t.t_ns[idx] == est.stamp_ns
        tr = t.regime[idx[ok]]
        rule = classify_regimes(t.u, t.a, rcfg, speed=t.v)[idx[ok]]
        period = float(meta["sensors"]["speed_period_s"])
        f_est = res.features[-1] if res.features else None
        truth_d = Davis(**meta["resistance"])
        item = {
            "accuracy": float(np.mean(tr == reg[ok])),
            "rule_ceiling": float(np.mean(tr == rule)),
            "vs_rule": float(np.mean(rule == reg[ok])),
            "confusion": confusion(tr, reg[ok]).tolist(),
            "resistance_err_pct": (np.array(resistance_errors(est.final_davis(), truth_d)) * 100).round(2).tolist(),
            "period": period,
        }
        if f_est is not None:
            summ = meta["summary"]
            item["final_coast_est_truth_s"] = [f_est.final_coast_duration, summ["final_coast_s"]]
            item["final_brake_est_truth_s"] = [f_est.final_brake_duration, summ["final_brake_s"]]
            item["cruise_speed_est_kmh"] = f_est.cruise_speed / KMH
        out[Path(bag).name] = item
    return out


# -- timing ----------------------------------------------------------------------------------------
def timing(repeats: int) -> dict:
    out = {"load_before": os.getloadavg()[0], "cpus": os.cpu_count()}
    for period in (10.0, 1.0):
        run, ms, _truth, train = simulate(0, period)
        for name, cfg in (("paper", UKFConfig()), ("converging", UKFConfig.converging())):
            times = []
            for _ in range(repeats):
                t0 = time.perf_counter()
                estimate_run(ms, train, cfg)
                times.append(time.perf_counter() - t0)
            key = f"{period:g}s_{name}"
            out[key] = {
                "samples": len(ms),
                "median_ms": statistics.median(times) * 1e3,
                "min_ms": min(times) * 1e3,
                "run_time_s": run.run_time_s,
            }
    out["load_after"] = os.getloadavg()[0]
    return out


def _fmt_table(res: dict) -> str:
    head = "| configuration | r(40) | r(80) | r(120) | r0 | r1 | r2 | DEGRADED |\n|---|---|---|---|---|---|---|---|"
    rows = [
        f"| {name} | " + " | ".join(f"{m:.1f} ± {s:.1f}" for m, s in zip(v["mean_abs"], v["std"])) + " |"
        for name, v in res.items()
    ]
    return "\n".join([head, *rows])


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=20)
    parser.add_argument("--accuracy", action="store_true", help="the proof tables (slow: simulates runs)")
    parser.add_argument("--runs", type=int, default=12, help="simulated runs per sampling (accuracy)")
    parser.add_argument("--json", default=str(REPO / "bench" / "out" / "bench_whole_run.json"))
    args = parser.parse_args()
    result: dict = {"timing": timing(args.repeats)}
    for key, val in result["timing"].items():
        if isinstance(val, dict):
            target = 5.0 if key.startswith("10s") else 50.0
            print(f"{key:16s} {val['samples']:5d} samples  median {val['median_ms']:7.2f} ms  (target < {target:g} ms)")
    print(f"load average {result['timing']['load_before']:.2f} on {result['timing']['cpus']} cpus")
    if args.accuracy:
        fcfg = FeatureConfig()
        acc: dict = {}
        for label, period, power in (("10 s", 10.0, False), ("1 Hz", 1.0, False), ("1 Hz + power", 1.0, True)):
            runs = [simulate(k, period, power) for k in range(args.runs)]
            res = resistance_table(runs, CONFIGS if not os.environ.get("QUICK") else {})
            acc[label] = {"resistance": res}
            print(f"\n### resistance, {label}, {len(runs)} runs: mean |error| ± std over runs, %\n")
            print(_fmt_table(res))
            for cname, rcfg in REGIME_VARIANTS:
                cfg = CONFIGS[cname]
                cname = f"{cname} / {'hold detection' if rcfg.hold_detection else 'paper rule'}"
                rf = sim_regimes_features(runs, cfg, rcfg, fcfg, period)
                n = rf["confusion"].sum()
                print(
                    f"\nregimes {label} {cname}: accuracy {np.trace(rf['confusion']) / n:.1%}, "
                    f"rule ceiling {np.trace(rf['rule_ceiling']) / n:.1%}, vs rule on truth "
                    f"{np.trace(rf['vs_rule']) / n:.1%}"
                )
                print(rf["confusion"])
                feats = rf["features"]
                br = np.concatenate([f["brake_rate_abs_err"] for f in feats]) if feats else np.zeros(0)
                print(
                    f"features: brake rate |err| median {np.median(br):.3f} max {np.max(br):.3f} m/s^2; "
                    f"cruise speed err {[round(f['cruise_speed_err_kmh'], 2) for f in feats]} km/h; "
                    f"max power rel err {[round(f['max_power_rel_err'], 3) for f in feats]}; "
                    f"final coast err {[round(f['final_coast_err_s'], 1) for f in feats]} s; "
                    f"final brake err {[round(f['final_brake_err_s'], 1) for f in feats]} s"
                )
                acc[label][cname] = {
                    "confusion": rf["confusion"].tolist(),
                    "rule_ceiling": rf["rule_ceiling"].tolist(),
                    "vs_rule": rf["vs_rule"].tolist(),
                    "features": feats,
                }
        for cname, rcfg in REGIME_VARIANTS:
            bags = bag_regimes(CONFIGS[cname], rcfg, fcfg)
            cname = f"{cname} / {'hold detection' if rcfg.hold_detection else 'paper rule'}"
            acc[f"bags {cname}"] = bags
            print(f"\n### bundled bags, {cname}")
            for name, item in bags.items():
                print(
                    f"{name}: regimes {item['accuracy']:.1%} (rule ceiling {item['rule_ceiling']:.1%}, vs rule "
                    f"{item['vs_rule']:.1%}), r err % {item['resistance_err_pct']}, final coast est/truth "
                    f"{item.get('final_coast_est_truth_s')}, final brake {item.get('final_brake_est_truth_s')}"
                )
        result["accuracy"] = acc
    Path(args.json).parent.mkdir(parents=True, exist_ok=True)
    Path(args.json).write_text(json.dumps(result, indent=1, default=float))
    return 0


if __name__ == "__main__":
    sys.exit(main())
