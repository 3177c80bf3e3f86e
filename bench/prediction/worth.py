"""The calibration's worth, measured (issue 24; docs/prediction.md): coast predictions per model against what the
runs show, on the validation family's report half, on the external runs and on a simulated set of units.

    .venv/bin/python bench/prediction/worth.py [--part family|external|units|all] [--workers N]

- family: ``build/validation/family/`` (``make validate`` generates it), report half only (odd k; the tune half is
  never used here); models train_file, causal (the run's own estimate at each coast's start) and the truth's r(v)
  (as ``given``);
- external: ``../shared/validation/runs/``: train_file, causal and the truth (as ``given``);
- units: a fleet simulated with ``train_calib.fleet.simulate`` (units that keep one resistance, drifting by a few per
  cent over the dates: ``FleetSpec`` spread 25 %, drift 2 %/year, season 1 %, no faulty unit), at 10 s and at 1 Hz:
  each run predicted with the whole-run best estimate of the unit's previous run (as a replay's summary.json gives
  it: ``given``), with the train file, causal, and its own truth (``truth``).

Every coast of at least 30 s is predicted (``train_calib.prediction.offline``); the tables are over the coasts of at
least 2 min and over all. Writes ``build/prediction/worth_<part>.json`` and prints the markdown tables.
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np

REPO = Path(__file__).resolve().parents[2]
FAMILY = REPO / "build" / "validation" / "family"
EXTERNAL = REPO.parent / "shared" / "validation" / "runs"
UNITS = REPO / "build" / "prediction" / "units"
OUT = REPO / "build" / "prediction"
MIN_COAST_S = 30.0
LONG_S = 120.0


def v_ref_error(r: np.ndarray, truth: np.ndarray, v_max: float) -> float:
    """|r(v_ref) error| % at v_ref = min(80 km/h, 0.8 v_max) (the validation scorer's reference speed)."""
    v = min(80.0 / 3.6, 0.8 * v_max)
    h = np.array([1.0, v, v * v])
    return float(abs(h @ r - h @ truth) / (h @ truth) * 100.0)


def predict_run(job: dict[str, Any]) -> dict[str, Any]:
    """One bag: its coasts predicted with train_file, causal and job['given'] (r0, r1, r2 and 3x3 covariance)."""
    from train_calib.pipeline import run_bag
    from train_calib.prediction.offline import GivenResistance, find_coasts, predict_coasts, traction_energy
    from train_calib.track import load_track
    from train_calib.train import load_train

    track, train = load_track(job["track"]), load_train(job["train"])
    out = run_bag(job["bag"], track, train)
    given = None
    if job.get("given") is not None:
        given = GivenResistance(np.array(job["given"][0]), np.array(job["given"][1]), job.get("given_name", "given"))
    coasts = find_coasts(out, MIN_COAST_S)
    rows = predict_coasts(coasts, track, train, given)
    if job.get("truth") is not None and job.get("truth_as") == "truth":  # the truth as a fourth model
        t = GivenResistance(np.array(job["truth"]), np.zeros((3, 3)), "truth")
        extra = [r for r in predict_coasts(coasts, track, train, t) if r["model"] == "given"]
        for r in extra:
            r["model"] = "truth"
        rows += extra
    for r in rows:
        r["run"] = job["name"]
        r["group"] = job["group"]
    res: dict[str, Any] = {"name": job["name"], "group": job["group"], "rows": rows,
                           "energy": traction_energy(out, train, given)}  # fmt: skip
    if job.get("keep_coasts"):
        res["coasts"] = coasts
    best = out.best
    if best is not None:
        res["best"] = [np.asarray(best.r).tolist(), np.asarray(best.covariance).tolist(), bool(best.stretches)]
    if out.final is not None and job.get("truth") is not None:
        v_max = max(m.v for m in out.measurements)
        res["final_err_pct"] = v_ref_error(np.array([out.final.r0, out.final.r1, out.final.r2]),
                                           np.array(job["truth"]), v_max)  # fmt: skip
        res["file_err_pct"] = v_ref_error(np.array(train.davis.as_tuple()), np.array(job["truth"]), v_max)
    return res


def family_jobs(split: str = "report") -> list[dict[str, Any]]:
    if not (FAMILY / "runs.csv").exists():
        sys.exit(f"{FAMILY / 'runs.csv'}: missing; run `make validate` (or bench/validation/family.py) first")
    jobs = []
    with (FAMILY / "runs.csv").open(encoding="utf-8") as f:
        for row in csv.DictReader(f):
            if row["split"] != split:
                continue
            truth = json.loads((FAMILY / f"{row['bag']}.validation-truth.json").read_text(encoding="utf-8"))
            r = [truth["r0"], truth["r1"], truth["r2"]]
            jobs.append({"name": row["bag"], "group": row["family"], "bag": str(FAMILY / row["bag"]),
                         "track": str(REPO / row["track"]), "train": str(REPO / row["train"]), "truth": r,
                         "given": [r, np.zeros((3, 3)).tolist()], "given_name": "truth"})  # fmt: skip
    return jobs


def external_jobs() -> list[dict[str, Any]]:
    jobs = []
    with (EXTERNAL / "runs.csv").open(encoding="utf-8") as f:
        for row in csv.DictReader(f):
            truth = json.loads((EXTERNAL / f"{row['bag']}.validation-truth.json").read_text(encoding="utf-8"))
            r = [truth["r0"], truth["r1"], truth["r2"]]
            group = row["bag"].rsplit("_", 1)[0]
            jobs.append({"name": row["bag"], "group": group, "bag": str(EXTERNAL / row["bag"]),
                         "track": str(EXTERNAL / row["track"]), "train": str(EXTERNAL / row["train"]), "truth": r,
                         "given": [r, np.zeros((3, 3)).tolist()], "given_name": "truth"})  # fmt: skip
    return jobs


FLEETS = {"units_10s": {"period_s": 10.0, "units": 6, "runs_per_unit": 4, "seed": 24},
          "units_1hz": {"period_s": 1.0, "units": 4, "runs_per_unit": 3, "seed": 25}}  # fmt: skip


def unit_fleets() -> dict[str, list[dict[str, str]]]:
    """Simulate the unit fleets (once; bytes from the seed) and return their manifests' rows."""
    from train_calib.fleet.simulate import FleetSpec, simulate_fleet

    out = {}
    for name, kw in FLEETS.items():
        folder = UNITS / name
        manifest = folder / "manifest.csv"
        if not manifest.exists():
            spec = FleetSpec(faulty=0, spread=0.25, drift=0.02, season=0.01, **kw)
            simulate_fleet(folder, spec, quiet=True)
        with manifest.open(encoding="utf-8") as f:
            out[name] = [dict(r, folder=str(folder)) for r in csv.DictReader(f)]
    return out


def unit_jobs() -> list[dict[str, Any]]:
    """Every run of the unit fleets, in date order per unit."""
    from train_calib.paths import track_file, train_file

    jobs = []
    for fleet, rows in unit_fleets().items():
        by_unit: dict[str, list[dict[str, str]]] = {}
        for r in rows:
            by_unit.setdefault(r["unit"], []).append(r)
        for unit, runs in by_unit.items():
            runs.sort(key=lambda r: r["date"])
            for k, r in enumerate(runs):
                bag = str(Path(r["folder"]) / r["bag"])
                truth = json.loads(Path(bag + ".truth.json").read_text(encoding="utf-8"))["resistance"]
                job = {"name": f"{fleet}/{Path(bag).name}", "group": fleet, "bag": bag,
                       "track": str(track_file(r["track"])), "train": str(train_file(r["train"])),
                       "truth": [truth["r0"], truth["r1"], truth["r2"]], "truth_as": "truth", "unit": unit,
                       "order": k, "keep_coasts": True}  # fmt: skip
                jobs.append(job)
    return jobs


def add_previous_run(results: list[dict[str, Any]]) -> None:
    """``given`` rows: each run's coasts predicted with the whole-run best estimate of the unit's previous run (its
    summary.json's ``best``); the unit's first run has none and is left out of the results."""
    from train_calib.paths import track_file, train_file
    from train_calib.prediction.offline import GivenResistance, predict_coasts
    from train_calib.track import load_track
    from train_calib.train import load_train

    jobs = {j["name"]: j for j in unit_jobs()}
    previous: dict[tuple[str, str], dict[str, Any]] = {}
    keep = []
    for res in sorted(results, key=lambda r: (jobs[r["name"]]["unit"], jobs[r["name"]]["order"])):
        job = jobs[res["name"]]
        key = (res["group"], job["unit"])
        prev = previous.get(key)
        previous[key] = res
        if prev is None:
            continue
        track, train = load_track(track_file("intercity_32km")), load_train(train_file("virm6"))
        r, cov, learnt = prev["best"]
        given = GivenResistance(np.array(r), np.array(cov), "previous run")
        rows = [x for x in predict_coasts(res["coasts"], track, train, given) if x["model"] == "given"]
        for x in rows:
            x["run"], x["group"] = res["name"], res["group"]
        res["rows"] += rows
        res["given_learnt"] = learnt
        res["given_err_pct"] = v_ref_error(np.array(r), np.array(job["truth"]), 140 / 3.6)
        keep.append(res)
    for res in results:
        res.pop("coasts", None)
    results[:] = keep


def stats(rows: list[dict[str, Any]], model: str, min_s: float) -> dict[str, Any] | None:
    rs = [r for r in rows if r["model"] == model and r["measured_duration_s"] >= min_s]
    rs = [r for r in rs if math.isfinite(r["predicted_end_speed_kmh"])]
    if not rs:
        return None
    ev = np.array([abs(r["predicted_end_speed_kmh"] - r["measured_end_speed_kmh"]) for r in rs])
    dur = np.array([r["predicted_duration_s"] for r in rs])
    md = np.array([r["measured_duration_s"] for r in rs])
    ed = np.abs(dur - md) / md * 100.0
    ed = ed[np.isfinite(ed)]
    sig = np.array([r["predicted_end_speed_sigma_kmh"] for r in rs])
    return {"n": len(rs), "v_med": float(np.median(ev)), "v_p90": float(np.percentile(ev, 90)),
            "d_med": float(np.median(ed)) if ed.size else math.nan,
            "d_p90": float(np.percentile(ed, 90)) if ed.size else math.nan,
            "inside": float(np.mean(ev <= 2.0 * sig)), "two_sigma": float(np.median(2.0 * sig))}  # fmt: skip


def table(results: list[dict[str, Any]], models: tuple[str, ...], min_s: float) -> str:
    groups = sorted({r["group"] for r in results})
    head = "| group | runs | calib. r(v_ref) err %, median | coasts | " + " | ".join(
        f"{m}: end speed err km/h med / p90 | {m}: duration err % med / p90 | {m}: inside 2σ (median 2σ, km/h)"
        for m in models) + " |"
    lines = [head, "|" + "---|" * (4 + 3 * len(models))]
    for g in [*groups, "ALL"]:
        rs = [r for r in results if g in ("ALL", r["group"])]
        rows = [row for r in rs for row in r["rows"]]
        key = "given_err_pct" if any("given_err_pct" in r for r in rs) else "final_err_pct"
        errs = [r[key] for r in rs if key in r]
        cells = [g, str(len(rs)), f"{np.median(errs):.1f}" if errs else "-"]
        first = stats(rows, models[0], min_s)
        cells.append(str(first["n"]) if first else "0")
        for m in models:
            s = stats(rows, m, min_s)
            if s is None:
                cells += ["-", "-", "-"]
            else:
                cells += [f"{s['v_med']:.2f} / {s['v_p90']:.2f}", f"{s['d_med']:.1f} / {s['d_p90']:.1f}",
                          f"{s['inside'] * 100:.0f} % (±{s['two_sigma']:.1f})"]  # fmt: skip
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def energy_table(results: list[dict[str, Any]], models: tuple[str, ...]) -> str:
    lines = ["| run | metered kWh | " + " | ".join(f"{m} error %" for m in models) + " |",
             "|" + "---|" * (2 + len(models))]  # fmt: skip
    for r in results:
        e = r.get("energy")
        if not e:
            continue
        cells = [r["name"], f"{e['measured_kwh']:.1f}"]
        cells += [f"{e[f'{m}_error_pct']:+.1f}" if e.get(f"{m}_error_pct") is not None else "-" for m in models]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) if len(lines) > 2 else "(no run with traction power)"


def run_jobs(jobs: list[dict[str, Any]], workers: int) -> list[dict[str, Any]]:
    if workers <= 1:
        return [predict_run(j) for j in jobs]
    with ProcessPoolExecutor(workers) as pool:
        return list(pool.map(predict_run, jobs))


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--part", choices=("family", "external", "units", "all"), default="all")
    parser.add_argument("--workers", type=int, default=1)
    parser.add_argument("--tables", action="store_true", help="only print the tables of the last run's JSON")
    args = parser.parse_args()
    OUT.mkdir(parents=True, exist_ok=True)
    parts = ("family", "external", "units") if args.part == "all" else (args.part,)
    for part in parts:
        models = ("train_file", "causal", "given", "truth") if part == "units" else ("train_file", "causal", "given")
        if args.tables:
            results = json.loads((OUT / f"worth_{part}.json").read_text(encoding="utf-8"))
        elif part == "units":
            results = run_jobs(unit_jobs(), args.workers)  # every run: its coasts and whole-run best
            add_previous_run(results)
        else:
            results = run_jobs(family_jobs() if part == "family" else external_jobs(), args.workers)
        if not args.tables:
            text = json.dumps(results, indent=1, default=float) + "\n"
            (OUT / f"worth_{part}.json").write_text(text, encoding="utf-8")
        print(f"\n## {part}: coasts of at least {LONG_S:g} s (given = "
              f"{'the previous run of the unit' if part == 'units' else 'the truth'})\n")  # fmt: skip
        print(table(results, models, LONG_S))
        print(f"\n## {part}: every coast of at least {MIN_COAST_S:g} s\n")
        print(table(results, models, MIN_COAST_S))
        print(f"\n## {part}: traction energy for the measured speed profile\n")
        print(energy_table(results, models[:3]))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
