"""Simulation-based calibration from occupation data (Besinovic et al. 2013): speed and optimiser settings.

On the bundled 14.3 km dense corridor (42 sections, 39 occupations per run) with runs of the four
compositions simulated by ``train-calib simulate-occupation`` (realistic driver). Two model engines
are compared in the same process on the same runs and seeds: *vectorised* (what calibrate_run uses:
``running_time_batch``, one call per generation, differential evolution with vectorized=True and
updating='deferred') and *scalar* (the engine before it: one ``running_time_profile`` per member,
updating='immediate'; a model without ``batch``).

- ``timing`` (default): the running-time model per trajectory (paper: 0.02 s), one calibration per
  run in one process with each engine (paper: < 1 min; target < 1 s): time, CPU time, model runs,
  time per model run, objective and parameters per run; then the parallelism options on this
  machine's cores: runs in parallel processes (each vectorised) and one run with
  differential_evolution(workers=N) (per-vector; vectorized and workers exclude each other).
- ``settings``: differential-evolution population size and convergence tolerance against the
  objective reached (vs the best found by any setting on that run) and the model runs spent
  (``--engine vectorised|scalar|both``).
- ``robustness``: Table 3 with both engines, ``--seeds`` (30) calibrations of one realistic and one
  in-model VIRM4 run: mean and std % of every parameter, of the objective and of the running time.
- ``proof``: the tables of docs/occupation.md from a ``calibrate-occupation --truth`` output
  (``--cal DIR``) of a ``simulate-occupation`` fleet (``--fleet DIR``): length assignment per delta
  and speed window, filter accuracy, calibrated vs true parameters per cruising style, passage-time
  residuals, share of runs at a bound, and the one-at-a-time sensitivity over every calibrated run.

    .venv/bin/python bench/bench_occupation.py [timing|settings|robustness] [--runs N] [--seeds N]
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
from benchlib import print_summary, row, speed_text

from train_calib.occupation.calibrate import CalibrationConfig, calibrate_run
from train_calib.occupation.compositions import load_train_types
from train_calib.occupation.fleet import FleetConfig, simulate_fleet
from train_calib.occupation.model import SimulatorModel
from train_calib.occupation.objective import build_observations
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


class ScalarOnly:
    """The model without ``batch``: calibrate_run then takes the per-vector path (the engine before the
    population-vectorised model: one running_time_profile per member, updating='immediate')."""

    def __init__(self, model: SimulatorModel) -> None:
        self.model = model

    def __call__(self, values, start_m, stop_m):
        return self.model(values, start_m, stop_m)


def _cal_row(run_id, res, cpu) -> dict:
    return {
        "run": run_id,
        "s": res.elapsed_s,
        "cpu_s": cpu,
        "model_runs": res.nfev,
        "generations": res.nit,
        "per_model_run_ms": 1e3 * res.elapsed_s / max(res.nfev, 1),
        "objective_s": res.objective_s,
        "params": {k: float(v) for k, v in res.decision.items()},
    }


def timing(args) -> dict:
    """Per-trajectory cost, one calibration per run with both engines (same runs, same seeds), fleet throughput."""
    track, types, fleet = _setup(args.runs)
    stops = default_stops(track)
    out: dict = {"load_start": os.getloadavg(), "runs": len(fleet), "cores": os.cpu_count()}

    # 1. one trajectory: defaults and random parameter vectors within the bounds; scalar and batched
    rng = np.random.default_rng(0)
    per_comp = {}
    for comp in types.compositions:
        model = SimulatorModel(track, comp)
        vals = {k: rng.uniform(*b, 100) for k, b in comp.bounds.items()}
        params = [comp.model_params()] + [comp.model_params(**{k: v[i] for k, v in vals.items()}) for i in range(100)]
        times = []
        for p in params:
            t0 = time.perf_counter()
            model(p, stops[0], stops[-1])
            times.append(time.perf_counter() - t0)
        pop = {**comp.model_params(), **{k: v[:48] for k, v in vals.items()}}
        batch = []
        for _ in range(10):
            t0 = time.perf_counter()
            model.batch(pop, stops[0], stops[-1])
            batch.append(time.perf_counter() - t0)
        per_comp[comp.name] = {
            "median_ms": 1e3 * statistics.median(times),
            "p90_ms": 1e3 * np.percentile(times, 90),
            "batch48_ms": 1e3 * statistics.median(batch),
        }
    out["trajectory"] = per_comp
    traj_ms = statistics.median(v["median_ms"] for v in per_comp.values())
    batch_ms = statistics.median(v["batch48_ms"] for v in per_comp.values())

    # 2. one calibration per run, single process: the per-vector engine and the vectorised one
    engines = {"scalar": [], "vectorised": []}
    for run in fleet:
        comp = types[run.composition]
        model = SimulatorModel(track, comp)
        obs = build_observations(run.events, track.sections, stops, comp.length_m)
        for name, m in (("vectorised", model), ("scalar", ScalarOnly(model))):
            if name == "scalar" and args.no_scalar:
                continue
            c0 = time.process_time()
            res = calibrate_run(obs, m, comp, CalibrationConfig(), seed=1)
            engines[name].append(_cal_row(run.run_id, res, time.process_time() - c0))
        print(
            f"{run.run_id}: " + ", ".join(f"{k} {v[-1]['s']:.2f} s" for k, v in engines.items() if v), file=sys.stderr
        )
    out["calibration"] = engines
    summary = {}
    for name, rows in engines.items():
        if rows:
            summary[name] = {
                "median_s": statistics.median(r["s"] for r in rows),
                "median_cpu_s": statistics.median(r["cpu_s"] for r in rows),
                "model_runs": statistics.median(r["model_runs"] for r in rows),
                "per_model_run_ms": statistics.median(r["per_model_run_ms"] for r in rows),
                "objective_s": statistics.median(r["objective_s"] for r in rows),
            }
    out["summary"] = summary

    # 3. parallelism on this machine's cores: runs in parallel processes (each vectorised), and one
    # calibration's members in parallel processes (differential_evolution(workers=N), per-vector)
    workers = available_workers()
    events = {r.run_id: r.events for r in fleet}
    par = {}
    for w in sorted({1, workers}):
        t0 = time.perf_counter()
        result = calibrate_fleet(events, track, types, workers=w)
        wall = time.perf_counter() - t0
        n = sum(o.result is not None for o in result.outcomes)
        par[f"fleet, {w} process{'es' if w > 1 else ''} (runs in parallel, each vectorised)"] = {
            "wall_s": wall,
            "runs": n,
            "runs_per_minute": 60.0 * n / wall,
            "per_run_s": wall / max(n, 1),
        }
    if workers > 1:
        run = fleet[0]
        comp = types[run.composition]
        obs = build_observations(run.events, track.sections, stops, comp.length_m)
        res = calibrate_run(obs, SimulatorModel(track, comp), comp, CalibrationConfig(), seed=1, workers=workers)
        par[f"one run, differential_evolution(workers={workers}), per-vector"] = {
            "wall_s": res.elapsed_s,
            "runs": 1,
            "runs_per_minute": 60.0 / res.elapsed_s,
            "per_run_s": res.elapsed_s,
        }
    out["parallel"] = par
    out["load_end"] = os.getloadavg()

    print(
        f"## Occupation calibration timing ({out['cores']} cores, load {out['load_start'][0]:.1f} -> "
        f"{out['load_end'][0]:.1f})\n"
    )
    print("| quantity | per-vector engine (before) | vectorised engine | paper | target |")
    print("|---|---:|---:|---:|---:|")
    sc, ve = summary.get("scalar"), summary.get("vectorised")

    def cell(d, key, fmt):
        return fmt.format(d[key]) if d else "-"

    print(
        f"| one 14.3 km trajectory | {traj_ms:.2f} ms | {batch_ms / 48:.2f} ms (48 in one call: {batch_ms:.1f} ms) "
        f"| {1e3 * PAPER_TRAJECTORY_S:.0f} ms | - |"
    )
    print(
        f"| one calibration, 1 process (median) | {cell(sc, 'median_s', '{:.2f} s')} | "
        f"{cell(ve, 'median_s', '{:.2f} s')} | < {PAPER_CALIBRATION_S:.0f} s | < {TARGET_CALIBRATION_S:.0f} s |"
    )
    print(
        f"| CPU time per calibration (median) | {cell(sc, 'median_cpu_s', '{:.2f} s')} | "
        f"{cell(ve, 'median_cpu_s', '{:.2f} s')} | - | - |"
    )
    print(
        f"| model runs per calibration | {cell(sc, 'model_runs', '{:.0f}')} | {cell(ve, 'model_runs', '{:.0f}')} "
        "| - | - |"
    )
    print(
        f"| time per model run inside a calibration | {cell(sc, 'per_model_run_ms', '{:.2f} ms')} | "
        f"{cell(ve, 'per_model_run_ms', '{:.2f} ms')} | - | - |"
    )
    print(
        f"| objective (median over the runs) | {cell(sc, 'objective_s', '{:.2f} s')} | "
        f"{cell(ve, 'objective_s', '{:.2f} s')} | - | - |"
    )
    print("\n| run | engine | time (s) | model runs | objective (s) | c0 | c2 | r0 | r2 | b_limit | theta |")
    print("|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    for i in range(len(fleet)):
        for name, rows in engines.items():
            if i < len(rows):
                r = rows[i]
                p = r["params"]
                print(
                    f"| {r['run']} | {name} | {r['s']:.2f} | {r['model_runs']} | {r['objective_s']:.2f} | "
                    f"{p['c0']:.3f} | {p['c2']:.2f} | {p['r0']:.4f} | {1e5 * p['r2']:.2f}e-5 | "
                    f"{p['b_limit']:.3f} | {p['theta_cruise']:.4f} |"
                )
    print("\n| parallelism | wall | runs/min | per run |\n|---|---:|---:|---:|")
    for name, v in par.items():
        print(f"| {name} | {v['wall_s']:.1f} s | {v['runs_per_minute']:.1f} | {v['per_run_s']:.2f} s |")
    for name, v in per_comp.items():
        print(
            f"\n{name}: trajectory median {v['median_ms']:.2f} ms, p90 {v['p90_ms']:.2f} ms; "
            f"48 vectors in one call {v['batch48_ms']:.1f} ms",
            end="",
        )
    print()
    out["summary"] = _timing_summary(traj_ms, batch_ms, sc, ve, par)
    print_summary(out["summary"])
    return out


def _timing_summary(traj_ms: float, batch_ms: float, sc: dict | None, ve: dict | None, par: dict) -> list:
    rows = [
        row("one 14.3 km trajectory of the running-time model (median over compositions)", f"{traj_ms:.2f} ms",
            f"<= {1e3 * PAPER_TRAJECTORY_S:.0f} ms (paper)", traj_ms <= 1e3 * PAPER_TRAJECTORY_S,
            f"paper {1e3 * PAPER_TRAJECTORY_S:.0f} ms", 1e3 * PAPER_TRAJECTORY_S / traj_ms,
            speed_text(1e3 * PAPER_TRAJECTORY_S / traj_ms),
            note=f"48 in one call: {batch_ms / 48:.2f} ms each"),
    ]  # fmt: skip
    if ve:
        ref = f"paper < {PAPER_CALIBRATION_S:.0f} s"
        note = f"CPU {ve['median_cpu_s']:.2f} s, {ve['model_runs']:.0f} model runs, objective {ve['objective_s']:.2f} s"
        if sc:
            note += f"; per-vector engine {sc['median_s']:.2f} s ({sc['median_s'] / ve['median_s']:.1f}x slower)"
        rows.append(
            row("one calibration (vectorised engine, 1 process, median over runs)", f"{ve['median_s']:.2f} s",
                f"< {TARGET_CALIBRATION_S:g} s", ve["median_s"] < TARGET_CALIBRATION_S, ref,
                PAPER_CALIBRATION_S / ve["median_s"], speed_text(PAPER_CALIBRATION_S / ve["median_s"]),
                note=note)
        )  # fmt: skip
    for name, v in par.items():
        rows.append(row(name, f"{v['runs_per_minute']:.1f} runs/min", note=f"{v['per_run_s']:.2f} s per run"))
    return rows


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
    engines = ("vectorised", "scalar") if args.engine == "both" else (args.engine,)
    if len(engines) > 1:
        grid = {f"{e}: {k}": v for e in engines for k, v in grid.items()}
    rows: dict[str, list] = {k: [] for k in grid}
    for run in fleet:
        comp = types[run.composition]
        model = SimulatorModel(track, comp)
        obs = build_observations(run.events, track.sections, stops, comp.length_m)
        found = {}
        for name, cfg in grid.items():
            m = ScalarOnly(model) if name.startswith("scalar") or engines == ("scalar",) else model
            found[name] = [calibrate_run(obs, m, comp, cfg, seed=s) for s in range(args.seeds)]
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


def robustness(args) -> dict:
    """Table 3 with both engines: ``--seeds`` calibrations of one run (same seeds), mean and std %."""
    from train_calib.occupation.robustness import ROWS, repeated_calibrations

    out: dict = {"load_start": os.getloadavg()}
    cases = [
        ("realistic", FleetConfig(runs_per_composition=2, hindered_share=0.1), 2013, args.run or "VIRM4-001"),
        ("in-model", FleetConfig(runs_per_composition=1, driver="minimum_time"), 77, args.run or "VIRM4-000"),
    ]
    track = load_track(track_file("dense_corridor_14km"))
    types = load_train_types(config_file("train_types/ic_compositions.yaml"))
    stops = default_stops(track)
    print(f"## Robustness (Table 3): {args.seeds} seeds per run and engine; std in % of the mean\n")
    print("| fleet, run | engine | time/cal | " + " | ".join(ROWS) + " |")
    print("|---|---|---:|" + "---:|" * len(ROWS))
    for label, cfg, seed, run_id in cases:
        fleet = {r.run_id: r for r in simulate_fleet(track, types, cfg, seed=seed, compositions=["VIRM4"])}
        run = fleet[run_id]
        comp = types[run.composition]
        model = SimulatorModel(track, comp)
        obs = build_observations(run.events, track.sections, stops, comp.length_m)
        for engine, m in (("vectorised", model), ("scalar", ScalarOnly(model))):
            t0 = time.perf_counter()
            rob = repeated_calibrations(obs, m, comp, CalibrationConfig(), n=args.seeds, first_seed=1000)
            per = (time.perf_counter() - t0) / args.seeds
            rows = {r.name: {"mean": r.mean, "std": r.std, "std_pct": r.cv_pct} for r in rob.rows}
            out[f"{label} {run_id} {engine}"] = {"per_calibration_s": per, "rows": rows}
            print(
                f"| {label} {run_id} | {engine} | {per:.2f} s | "
                + " | ".join(f"{rows[n]['mean']:.4g} ({rows[n]['std_pct']:.2f} %)" for n in ROWS)
                + " |",
                flush=True,
            )
    out["load_end"] = os.getloadavg()
    print(f"\nload {out['load_start'][0]:.1f} -> {out['load_end'][0]:.1f}")
    return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("part", nargs="?", default="timing", choices=("timing", "settings", "robustness", "proof"))
    parser.add_argument("--fleet", help="proof: output directory of simulate-occupation")
    parser.add_argument("--cal", help="proof: output directory of calibrate-occupation --truth")
    parser.add_argument("--track", default="dense_corridor_14km", help="proof: the track of the fleet")
    parser.add_argument("--runs", type=int, default=2, help="runs per composition (default 2)")
    parser.add_argument("--seeds", type=int, default=2, help="settings: seeds per setting and run (default 2)")
    parser.add_argument("--no-scalar", action="store_true", help="timing: skip the per-vector engine (slow)")
    parser.add_argument(
        "--engine",
        choices=("vectorised", "scalar", "both"),
        default="vectorised",
        help="settings: the model engine (default vectorised)",
    )
    parser.add_argument("--run", help="robustness: run id (default VIRM4-001 realistic, VIRM4-000 in-model)")
    args = parser.parse_args()
    if args.part == "proof" and not (args.fleet and args.cal):
        parser.error("proof needs --fleet and --cal")
    if args.part == "robustness" and args.seeds == 2:
        args.seeds = 30
    result = {"timing": timing, "settings": settings, "robustness": robustness, "proof": proof}[args.part](args)
    OUT.mkdir(exist_ok=True)
    path = OUT / f"bench_occupation_{args.part}.json"
    path.write_text(json.dumps(result, indent=2, default=float) + "\n")
    print(f"\nwritten {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
