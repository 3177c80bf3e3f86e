"""Simulation-based calibration from occupation data (Besinovic et al. 2013): speed and optimiser settings.

Two parts, on the bundled 14.3 km dense corridor (42 sections, 39 occupations per run) with runs
of the four compositions simulated by ``train-calib simulate-occupation`` (realistic driver):

- ``timing`` (default): the running-time model per trajectory (paper: 0.02 s), one calibration per
  run in one process (paper: < 1 min; target < 1 s) with the number of model runs it needs, and the
  fleet throughput with all cores. The model time needed for the 1 s target is derived:
  (1 s - overhead) / evaluations per calibration.
- ``settings``: differential-evolution population size and convergence tolerance against the
  objective reached (vs the best found by any setting on that run) and the model runs spent.
- ``proof``: the tables of docs/occupation.md from a ``calibrate-occupation --truth`` output
  (``--cal DIR``) of a ``simulate-occupation`` fleet (``--fleet DIR``): length assignment per delta
  and speed window, filter accuracy, calibrated vs true parameters per cruising style, passage-time
  residuals, share of runs at a bound, and the one-at-a-time sensitivity over every calibrated run.

    .venv/bin/python bench/bench_occupation.py [timing|settings] [--runs N] [--seeds N]
    .venv/bin/python bench/bench_occupation.py proof --fleet FLEET_DIR --cal CAL_DIR

Results are printed as Markdown tables and written to bench/out/bench_occupation_<part>.json with the
machine load (os.getloadavg) at the start and the end: the machine is shared, timings are noisy.
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

from train_calib.occupation.calibrate import CalibrationConfig, calibrate_run
from train_calib.occupation.compositions import load_train_types
from train_calib.occupation.fleet import FleetConfig, simulate_fleet
from train_calib.occupation.model import SimulatorModel
from train_calib.occupation.objective import build_observations, objective
from train_calib.occupation.pipeline import available_workers, calibrate_fleet, default_stops
from train_calib.paths import config_file, track_file
from train_calib.track import load_track

OUT = Path(__file__).resolve().parent / "out"
PAPER_TRAJECTORY_S = 0.02
PAPER_CALIBRATION_S = 60.0
TARGET_CALIBRATION_S = 1.0


def _setup(runs_per_composition: int, seed: int = 2013):
    track = load_track(track_file("dense_corridor_14km"))
    types = load_train_types(config_file("train_types/ic_compositions.yaml"))
    fleet = simulate_fleet(track, types, FleetConfig(runs_per_composition=runs_per_composition), seed=seed)
    return track, types, fleet


def timing(args) -> dict:
    track, types, fleet = _setup(args.runs)
    stops = default_stops(track)
    out: dict = {"load_start": os.getloadavg(), "runs": len(fleet)}

    # 1. one trajectory: defaults and random parameter vectors within the bounds
    rng = np.random.default_rng(0)
    per_comp = {}
    for comp in types.compositions:
        model = SimulatorModel(track, comp)
        params = [comp.model_params()]
        for _ in range(100):
            params.append(comp.model_params(**{k: rng.uniform(*b) for k, b in comp.bounds.items()}))
        times = []
        for p in params:
            t0 = time.perf_counter()
            model(p, stops[0], stops[-1])
            times.append(time.perf_counter() - t0)
        per_comp[comp.name] = {"median_ms": 1e3 * statistics.median(times), "p90_ms": 1e3 * np.percentile(times, 90)}
    out["trajectory"] = per_comp
    traj_ms = statistics.median(v["median_ms"] for v in per_comp.values())

    # 2. the objective's own overhead (observations, median offset) beyond the model run
    run = fleet[0]
    comp = types[run.composition]
    model = SimulatorModel(track, comp)
    obs = build_observations(run.events, track.sections, stops, comp.length_m)
    p = comp.model_params()
    t0 = time.perf_counter()
    for _ in range(200):
        model(p, stops[0], stops[-1])
    bare = time.perf_counter() - t0
    t0 = time.perf_counter()
    for _ in range(200):
        objective(obs, model, p)
    out["objective_ms"] = 1e3 * (time.perf_counter() - t0) / 200
    out["objective_overhead_ms"] = out["objective_ms"] - 1e3 * bare / 200

    # 3. one calibration per run, single process
    cal = []
    for run in fleet:
        comp = types[run.composition]
        model = SimulatorModel(track, comp)
        obs = build_observations(run.events, track.sections, stops, comp.length_m)
        res = calibrate_run(obs, model, comp, CalibrationConfig(), seed=1)
        cal.append({"run": run.run_id, "s": res.elapsed_s, "nfev": res.nfev, "objective_s": res.objective_s})
    out["calibration"] = cal
    med_s = statistics.median(c["s"] for c in cal)
    med_nfev = statistics.median(c["nfev"] for c in cal)
    out["calibration_median_s"] = med_s
    out["evaluations_median"] = med_nfev
    out["per_evaluation_ms"] = 1e3 * med_s / med_nfev
    out["needed_per_evaluation_ms_for_target"] = 1e3 * TARGET_CALIBRATION_S / med_nfev

    # 4. fleet throughput on all cores
    workers = available_workers()
    events = {r.run_id: r.events for r in fleet}
    t0 = time.perf_counter()
    result = calibrate_fleet(events, track, types, workers=workers)
    wall = time.perf_counter() - t0
    n = sum(o.result is not None for o in result.outcomes)
    out["fleet"] = {"workers": workers, "runs": n, "wall_s": wall, "runs_per_minute": 60.0 * n / wall}
    out["load_end"] = os.getloadavg()

    print(f"## Occupation calibration timing (load {out['load_start'][0]:.1f} -> {out['load_end'][0]:.1f})\n")
    print("| quantity | measured | paper | target |\n|---|---:|---:|---:|")
    print(f"| running-time model, one 14.3 km trajectory | {traj_ms:.2f} ms | {1e3 * PAPER_TRAJECTORY_S:.0f} ms | - |")
    print(
        f"| objective overhead per evaluation (observations, median offset) | {out['objective_overhead_ms']:.2f} ms "
        "| - | - |"
    )
    print(f"| mean cost per evaluation inside a calibration | {out['per_evaluation_ms']:.2f} ms | - | - |")
    print(f"| one calibration (1 process) | {med_s:.1f} s | < {PAPER_CALIBRATION_S:.0f} s | < 1 s |")
    print(f"| model runs per calibration | {med_nfev:.0f} | - | - |")
    print(f"| model time per run needed for 1 s | {out['needed_per_evaluation_ms_for_target']:.2f} ms | - | - |")
    print(f"| fleet, {workers} workers | {out['fleet']['runs_per_minute']:.1f} runs/min | - | - |")
    for name, v in per_comp.items():
        print(f"\n{name}: trajectory median {v['median_ms']:.2f} ms, p90 {v['p90_ms']:.2f} ms", end="")
    print()
    return out


def settings(args) -> dict:
    track, types, fleet = _setup(args.runs, seed=77)
    stops = default_stops(track)
    grid = {
        "popsize 5, atol 0.5": CalibrationConfig(popsize=5, maxiter=100),
        "popsize 8, atol 0.5 (default)": CalibrationConfig(),
        "popsize 8, atol 2": CalibrationConfig(atol=2.0),
        "popsize 12, atol 0.5": CalibrationConfig(popsize=12, maxiter=60),
        "popsize 15, atol 0.05": CalibrationConfig(popsize=15, maxiter=150, atol=0.05),
    }
    rows: dict[str, list] = {k: [] for k in grid}
    for run in fleet:
        comp = types[run.composition]
        model = SimulatorModel(track, comp)
        obs = build_observations(run.events, track.sections, stops, comp.length_m)
        found = {}
        for name, cfg in grid.items():
            found[name] = [calibrate_run(obs, model, comp, cfg, seed=s) for s in range(args.seeds)]
        best = min(r.objective_s for rs in found.values() for r in rs)
        for name, rs in found.items():
            for r in rs:
                rows[name].append({"run": run.run_id, "gap_s": r.objective_s - best, "nfev": r.nfev, "s": r.elapsed_s})
        print(f"{run.run_id}: best objective {best:.2f} s", file=sys.stderr, flush=True)
    print("## DE settings: objective above the best found, and cost\n")
    print("| setting | median gap (s) | worst gap (s) | share within 0.5 s | model runs (median) | time (median) |")
    print("|---|---:|---:|---:|---:|---:|")
    summary = {}
    for name, rs in rows.items():
        gaps = np.array([r["gap_s"] for r in rs])
        summary[name] = {
            "median_gap_s": float(np.median(gaps)),
            "worst_gap_s": float(gaps.max()),
            "within_0_5_s": float(np.mean(gaps <= 0.5)),
            "nfev_median": float(np.median([r["nfev"] for r in rs])),
            "time_median_s": float(np.median([r["s"] for r in rs])),
        }
        s = summary[name]
        print(
            f"| {name} | {s['median_gap_s']:.2f} | {s['worst_gap_s']:.2f} | {s['within_0_5_s']:.0%} | "
            f"{s['nfev_median']:.0f} | {s['time_median_s']:.1f} s |"
        )
    return {"rows": rows, "summary": summary, "load": os.getloadavg()}


def proof(args) -> dict:
    import csv

    from train_calib.occupation.compositions import DECISION_NAMES
    from train_calib.occupation.events import load_events
    from train_calib.occupation.fleet import load_truth
    from train_calib.occupation.length import SPEED_WINDOWS, assignment_accuracy, estimate_length
    from train_calib.occupation.sensitivity import one_at_a_time

    track = load_track(track_file(args.track))
    types = load_train_types(config_file("train_types/ic_compositions.yaml"))
    fleet_dir, cal_dir = Path(args.fleet), Path(args.cal)
    events = load_events(fleet_dir / "events.csv", [s.id for s in track.sections])
    truth = load_truth(fleet_dir / "truth.csv")
    names = {k: str(v["composition"]) for k, v in truth.items()}
    out: dict = {}

    print("## Length and composition (eq. 1-2) per delta and speed window\n")
    print("| speed window | rule | delta (s) | assigned | correct | wrong | median abs error (m) | p95 (m) |")
    print("|---|---|---:|---:|---:|---:|---:|---:|")
    out["length"] = []
    for speed in SPEED_WINDOWS:
        for strict in (False, True):
            for delta in (0.0, 1.0, 2.0):
                ests = [
                    estimate_length(r, track.sections, types.lengths(), delta, speed=speed, strict=strict)
                    for r in events.values()
                ]
                acc = assignment_accuracy(ests, names, types.lengths())
                rule = "strict" if strict else "nearest"
                out["length"].append(
                    {
                        "speed": speed,
                        "rule": rule,
                        "delta": delta,
                        "assigned": acc.n_assigned,
                        "correct": acc.n_correct,
                        "runs": acc.n_runs,
                        **acc.length_error_m,
                    }
                )
                print(
                    f"| {speed} | {rule} | {delta:g} | {acc.n_assigned}/{acc.n_runs} | {acc.n_correct} | "
                    f"{acc.n_wrong} | {acc.length_error_m['median']:.1f} | {acc.length_error_m['p95']:.1f} |"
                )

    rows = {r["run_id"]: r for r in csv.DictReader((cal_dir / "runs.csv").open())}
    hindered = {k for k, t in truth.items() if t.get("hindrance")}
    rejected = {k for k, r in rows.items() if r["status"] == "rejected"}
    out["filter"] = {
        "hindered": len(hindered),
        "caught": len(hindered & rejected),
        "false_alarms": len(rejected - hindered),
    }
    print(
        f"\nfilter: {len(hindered & rejected)}/{len(hindered)} hindered runs rejected, "
        f"{len(rejected - hindered)} unhindered runs rejected"
    )

    print("\n## Calibrated vs true, median |relative error| (median signed) per cruising style\n")
    print("| composition | style | runs | " + " | ".join(DECISION_NAMES) + " |")
    print("|---|---|---:|" + "---:|" * len(DECISION_NAMES))
    out["truth"] = {}
    calibrated = {k: r for k, r in rows.items() if r["status"] == "calibrated"}
    for comp in types.names:
        for style in ("hold", "cycles", "all"):
            ids = [
                k
                for k, r in calibrated.items()
                if truth[k]["composition"] == comp and (style == "all" or truth[k]["cruise_style"] == style)
            ]
            if not ids:
                continue
            cells, stats = [], {}
            for name in DECISION_NAMES:
                rel = np.array([float(calibrated[k][name]) / float(truth[k][name]) - 1 for k in ids])
                stats[name] = {"median_abs": float(np.median(np.abs(rel))), "median": float(np.median(rel))}
                cells.append(f"{100 * stats[name]['median_abs']:.1f} % ({100 * stats[name]['median']:+.1f})")
            out["truth"][f"{comp}/{style}"] = stats
            print(f"| {comp} | {style} | {len(ids)} | " + " | ".join(cells) + " |")

    res = np.array([abs(float(r["residual_s"])) for r in csv.DictReader((cal_dir / "residuals.csv").open())])
    out["residuals"] = {q: float(np.percentile(res, p)) for q, p in (("median", 50), ("p90", 90), ("p99", 99))}
    out["residuals"]["max"] = float(res.max())
    print(
        f"\npassage residuals |t_obs - t_sim| over {res.size} passages: median {out['residuals']['median']:.2f} s, "
        f"p90 {out['residuals']['p90']:.2f} s, p99 {out['residuals']['p99']:.2f} s, max {res.max():.2f} s"
    )

    print("\n## One-at-a-time sensitivity over all calibrated runs (+-20 %), running time change\n")
    stops = default_stops(track)
    changes: dict[str, list] = {}
    for k, r in calibrated.items():
        comp = types[r["composition"]]
        params = comp.model_params(**{n: float(r[n]) for n in DECISION_NAMES})
        obs = build_observations(events[k], track.sections, stops, comp.length_m)
        for srow in one_at_a_time(SimulatorModel(track, comp), params, obs.legs, [obs.position_m]):
            changes.setdefault(srow.name, []).append(srow.max_change_pct)
    print("| parameter | median % | max % | runs below 0.1 % |\n|---|---:|---:|---:|")
    out["sensitivity"] = {}
    for name, vals in changes.items():
        a = np.array(vals)
        out["sensitivity"][name] = {
            "median": float(np.median(a)),
            "max": float(a.max()),
            "below_0_1": float(np.mean(a < 0.1)),
        }
        print(f"| {name} | {np.median(a):.3f} | {a.max():.3f} | {np.mean(a < 0.1):.0%} |")
    return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("part", nargs="?", default="timing", choices=("timing", "settings", "proof"))
    parser.add_argument("--fleet", help="proof: output directory of simulate-occupation")
    parser.add_argument("--cal", help="proof: output directory of calibrate-occupation --truth")
    parser.add_argument("--track", default="dense_corridor_14km", help="proof: the track of the fleet")
    parser.add_argument("--runs", type=int, default=2, help="runs per composition (default 2)")
    parser.add_argument("--seeds", type=int, default=2, help="settings: seeds per setting and run (default 2)")
    args = parser.parse_args()
    if args.part == "proof" and not (args.fleet and args.cal):
        parser.error("proof needs --fleet and --cal")
    result = {"timing": timing, "settings": settings, "proof": proof}[args.part](args)
    OUT.mkdir(exist_ok=True)
    path = OUT / f"bench_occupation_{args.part}.json"
    path.write_text(json.dumps(result, indent=2, default=float) + "\n")
    print(f"\nwritten {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
