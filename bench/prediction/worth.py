"""The calibration's worth, measured (issue 24; docs/prediction.md): coast predictions per model against what the
runs show, on the validation family's report half, on the external runs and on a simulated set of units.

    .venv/bin/python bench/prediction/worth.py [--part family|family_units|external|units|all] [--workers N]

- family: ``build/validation/family/`` (``make validate`` generates it), report half only (odd k; the tune half is
  never used here); models train_file, causal (the run's own estimate at each coast's start) and the truth's r(v)
  (as ``given``);
- external: ``../shared/validation/runs/``: train_file, causal and the truth (as ``given``);
- units: a fleet simulated with ``train_calib.fleet.simulate`` (units that keep one resistance, drifting by a few per
  cent over the dates: ``FleetSpec`` spread 25 %, drift 2 %/year, season 1 %, no faulty unit), at 10 s and at 1 Hz:
  each run predicted with the whole-run best estimate of the unit's previous run (as a replay's summary.json gives
  it: ``given``), with the train file, causal, and its own truth (``truth``).

- family_units: the family's report half with units (``siblings.py``: each held-out run and two sibling runs of the
  same unit, its truth drifted by at most 3 %, other driver and noise seeds; ``build/prediction/siblings/``): each
  run of a unit predicted with the calibration of each other run of the unit, as ``train-calib predict --resistance
  OTHER/summary.json`` takes it (``given``: the whole-run best estimate ``best`` when it learnt from coasting, else
  the final published one; read with the command's own parser), beside the train file, the run's causal estimate
  and its own truth (``truth``).

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
CALIBRATIONS = OUT / "family_units"  # each unit run's summary.json fragment (train, best, final)
MIN_COAST_S = 30.0
LONG_S = 120.0
BOUND_PCT = {10.0: 5.0, 1.0: 3.0}  # issue 19's accuracy bound on r(v_ref) by speed period (s): 5 % at 10 s, 3 % at 1 Hz


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
    if job.get("summary"):  # a unit run of the family: its calibration, and what the energy needs
        res.update(unit=job["unit"], track=job["track"], train=job["train"], truth=job["truth"],
                   period_s=job["period_s"], summary=calibration_summary(out, train), powered=powered(out),
                   v_max=max(m.v for m in out.measurements))  # fmt: skip
        if res["energy"] is not None:
            truth_r = GivenResistance(np.array(job["truth"]), np.zeros((3, 3)), "truth")
            res["energy_truth"] = traction_energy(out, train, truth_r)["given_error_pct"]
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


def family_unit_jobs() -> list[dict[str, Any]]:
    """Every run of the family's report half and its siblings (generated here when missing), one unit each."""
    import siblings

    if not (FAMILY / "runs.csv").exists():
        sys.exit(f"{FAMILY / 'runs.csv'}: missing; run `make validate` (or bench/validation/family.py) first")
    sibs = siblings.sibling_specs()
    for sib in sibs:
        siblings.generate(sib)
    siblings.write_csv(sibs)
    jobs = []
    for folder, unit_of in ((FAMILY, None), (siblings.OUT, "sibling_of")):
        with (folder / "runs.csv").open(encoding="utf-8") as f:
            for row in csv.DictReader(f):
                if row["split"] != "report":
                    continue
                truth = json.loads((folder / f"{row['bag']}.validation-truth.json").read_text(encoding="utf-8"))
                jobs.append({"name": row["bag"], "group": row["family"], "bag": str(folder / row["bag"]),
                             "track": str(REPO / row["track"]), "train": str(REPO / row["train"]),
                             "truth": [truth["r0"], truth["r1"], truth["r2"]], "truth_as": "truth",
                             "unit": row[unit_of] if unit_of else row["bag"], "keep_coasts": True,
                             "period_s": float(row["speed_period_s"]), "summary": True})  # fmt: skip
    return jobs


def calibration_summary(out: Any, train: Any) -> dict[str, Any]:
    """What ``train-calib predict --resistance summary.json`` reads of a replay's summary.json: the train, the whole
    run's best estimate (``best``: r0, r1, r2, covariance, learnt) and the final published one (``final``)."""
    doc: dict[str, Any] = {"train": {"name": train.name}}
    best = out.best
    if best is not None:
        doc["best"] = {**{c: float(x) for c, x in zip(("r0", "r1", "r2"), best.r)},
                       "covariance": np.asarray(best.covariance).tolist(), "learnt": bool(best.stretches)}  # fmt: skip
    final = out.final
    if final is not None:
        doc["final"] = {"r0": {"value": final.r0}, "r1": {"value": final.r1}, "r2": {"value": final.r2},
                        "covariance": np.asarray(final.covariance)[2:, 2:].tolist()}  # fmt: skip
    return doc


def powered(out: Any) -> Any:
    """The measurements with traction power and their estimates (what ``traction_energy`` reads), or None."""
    from types import SimpleNamespace

    meas = [m for m in out.measurements if m.power_valid]
    if not meas:
        return None
    stamps = {m.stamp_ns for m in meas}
    return SimpleNamespace(measurements=meas, estimates=[e for e in out.estimates if e.stamp_ns in stamps])


def add_other_runs(results: list[dict[str, Any]]) -> None:
    """``given`` rows: each run of a unit predicted with each other run's calibration (its summary.json fragment,
    read by ``train-calib predict``'s own parser), and the traction energy with it where power exists."""
    from train_calib.prediction.offline import predict_coasts, resistance_source, traction_energy
    from train_calib.track import load_track
    from train_calib.train import load_train

    CALIBRATIONS.mkdir(parents=True, exist_ok=True)
    for res in results:
        (CALIBRATIONS / f"{res['name']}.summary.json").write_text(json.dumps(res["summary"]) + "\n", encoding="utf-8")
    units: dict[str, list[dict[str, Any]]] = {}
    for res in results:
        units.setdefault(res["unit"], []).append(res)
    for members in units.values():
        for res in members:
            track, train = load_track(res["track"]), load_train(res["train"])
            res["given_err_pct"], res["given_from"], res["given_learnt"], res["energy_given"] = [], [], [], []
            for other in members:
                if other is res:
                    continue
                given = resistance_source(str(CALIBRATIONS / f"{other['name']}.summary.json"), train)
                rows = [x for x in predict_coasts(res["coasts"], track, train, given) if x["model"] == "given"]
                for x in rows:
                    x["run"], x["group"], x["calibrated_on"] = res["name"], res["group"], other["name"]
                res["rows"] += rows
                res["given_from"].append(other["name"])
                res["given_learnt"].append("whole-run best" in given.source)
                res["given_err_pct"].append(v_ref_error(given.r, np.array(res["truth"]), res["v_max"]))
                if res.get("powered") is not None:
                    e = traction_energy(res["powered"], train, given)
                    res["energy_given"].append(e["given_error_pct"] if e else None)
    for res in results:
        res.pop("coasts", None)
        res.pop("powered", None)


BOUND_PCT_DEFAULT = 3.0


def criteria_table(results: list[dict[str, Any]]) -> str:
    """The issue's done-when per family (coasts of at least LONG_S): the calibration's r(v_ref) error against the
    estimator's bound, the calibrated model's median end-speed error against half the train file's, the truth's
    within 1 km/h, the calibrated model's 2 sigma."""
    head = (
        "| family | bound % | calib. r(v_ref) err % (median) | bound met | coasts (x calibrations) | "
        "train file km/h | calibrated km/h | calibrated / train file | truth km/h | calibrated inside 2σ | "
        "criteria |"
    )
    lines = [head, "|" + "---|" * 11]
    met_rows: list[dict[str, Any]] = []
    for g in sorted({r["group"] for r in results}):
        rs = [r for r in results if r["group"] == g]
        bound = BOUND_PCT.get(rs[0].get("period_s", 1.0), BOUND_PCT_DEFAULT)
        errs = [e for r in rs for e in r.get("given_err_pct", [])]
        med = float(np.median(errs)) if errs else math.nan
        ok_bound = med <= bound
        rows = [row for r in rs for row in r["rows"]]
        f, c, t = (stats(rows, m, LONG_S) for m in ("train_file", "given", "truth"))
        if f is None or c is None or t is None:
            lines.append(f"| {g} | {bound:g} | {med:.1f} | {'yes' if ok_bound else 'no'} | 0 | - | - | - | - | - | "
                         "no coast of 2 min |")  # fmt: skip
            continue
        ratio = c["v_med"] / f["v_med"] if f["v_med"] > 0 else math.nan
        verdict = (
            "-" if not ok_bound else ("met" if ratio <= 0.5 and t["v_med"] <= 1.0 and c["inside"] >= 0.9 else "not met")
        )
        if ok_bound:
            met_rows += [row for row in rows if row["model"] in ("train_file", "given", "truth")]
        lines.append(f"| {g} | {bound:g} | {med:.1f} | {'yes' if ok_bound else 'no'} | {f['n']} ({c['n']}) | "
                     f"{f['v_med']:.2f} | {c['v_med']:.2f} | {ratio:.2f} | {t['v_med']:.2f} | "
                     f"{c['inside'] * 100:.0f} % | {verdict} |")  # fmt: skip
    f, c, t = (stats(met_rows, m, LONG_S) for m in ("train_file", "given", "truth"))
    if f and c and t:
        ratio = c["v_med"] / f["v_med"]
        verdict = "met" if ratio <= 0.5 and t["v_med"] <= 1.0 and c["inside"] >= 0.9 else "not met"
        lines.append(f"| **where the bound is met** | | | | {f['n']} ({c['n']}) | {f['v_med']:.2f} | "
                     f"{c['v_med']:.2f} | {ratio:.2f} | {t['v_med']:.2f} | {c['inside'] * 100:.0f} % | "
                     f"**{verdict}** |")  # fmt: skip
    return "\n".join(lines)


def hurt_table(results: list[dict[str, Any]], min_s: float = MIN_COAST_S, margin_kmh: float = 0.1) -> str:
    """Where calibration does not help: per family, each calibrated prediction (and the run's causal one) against the
    train file's on the same coast; the share worse by more than ``margin_kmh`` and by how much (km/h)."""

    def spread(x: np.ndarray) -> str:
        return f"{np.median(x):.2f} / {x.max():.2f}" if x.size else "-"

    lines = ["| family | coasts x calibrations | calibrated worse than the train file by > 0.1 km/h | "
             "by, median / max km/h | calibrated better by, median km/h | causal worse than the train file | "
             "by, median / max km/h |", "|---|---|---|---|---|---|---|"]  # fmt: skip
    for g in sorted({r["group"] for r in results}):
        rows = [row for r in results if r["group"] == g for row in r["rows"] if row["measured_duration_s"] >= min_s]
        err: dict[str, dict[tuple[str, float], float]] = {"train_file": {}, "causal": {}}
        given = []
        for row in rows:
            key = (row["run"], row["start_stamp_s"])
            e = abs(row["predicted_end_speed_kmh"] - row["measured_end_speed_kmh"])
            if row["model"] in err:
                err[row["model"]][key] = e
            elif row["model"] == "given":
                given.append((key, e))
        if not given:
            continue
        d = np.array([e - err["train_file"][k] for k, e in given])
        dc = np.array([err["causal"][k] - err["train_file"][k] for k in err["causal"]])
        worse, better, cworse = d[d > margin_kmh], -d[d < -margin_kmh], dc[dc > margin_kmh]
        cells = [
            g,
            str(len(d)),
            f"{len(worse)} ({len(worse) / len(d) * 100:.0f} %)",
            spread(worse),
            f"{np.median(better):.2f}" if better.size else "-",
            f"{len(cworse)} of {len(dc)}",
            spread(cworse),
        ]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def unit_energy_table(results: list[dict[str, Any]]) -> str:
    """Per family with traction power: median / 90th percentile |traction energy error| % per model (calibrated: over
    every other run of the unit)."""
    lines = ["| family | runs | train_file: abs. error % med / p90 | causal | calibrated on another run | truth |",
             "|---|---|---|---|---|---|"]  # fmt: skip
    for g in sorted({r["group"] for r in results}):
        rs = [r for r in results if r["group"] == g and r.get("energy")]
        if not rs:
            continue
        cells = [g, str(len(rs))]
        for key in ("train_file", "causal", "given", "truth"):
            if key == "given":
                vals = [abs(x) for r in rs for x in r.get("energy_given", []) if x is not None]
            elif key == "truth":
                vals = [abs(r["energy_truth"]) for r in rs if r.get("energy_truth") is not None]
            else:
                name = f"{key}_error_pct"
                vals = [abs(r["energy"][name]) for r in rs if r["energy"].get(name) is not None]
            cells.append(f"{np.median(vals):.1f} / {np.percentile(vals, 90):.1f}" if vals else "-")
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) if len(lines) > 2 else "(no run with traction power)"


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
    head = (
        "| group | runs | calib. r(v_ref) err %, median | coasts | "
        + " | ".join(
            f"{m}: end speed err km/h med / p90 | {m}: duration err % med / p90 | {m}: inside 2σ (median 2σ, km/h)"
            for m in models
        )
        + " |"
    )
    lines = [head, "|" + "---|" * (4 + 3 * len(models))]
    for g in [*groups, "ALL"]:
        rs = [r for r in results if g in ("ALL", r["group"])]
        rows = [row for r in rs for row in r["rows"]]
        key = "given_err_pct" if any("given_err_pct" in r for r in rs) else "final_err_pct"
        errs = [e for r in rs if key in r for e in (r[key] if isinstance(r[key], list) else [r[key]])]
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
    parser.add_argument("--part", choices=("family", "family_units", "external", "units", "all"), default="all")
    parser.add_argument("--workers", type=int, default=1)
    parser.add_argument("--tables", action="store_true", help="only print the tables of the last run's JSON")
    args = parser.parse_args()
    OUT.mkdir(parents=True, exist_ok=True)
    parts = ("family", "family_units", "external", "units") if args.part == "all" else (args.part,)
    for part in parts:
        with_truth = part in ("units", "family_units")
        models = ("train_file", "causal", "given", "truth") if with_truth else ("train_file", "causal", "given")
        if args.tables:
            results = json.loads((OUT / f"worth_{part}.json").read_text(encoding="utf-8"))
        elif part == "units":
            results = run_jobs(unit_jobs(), args.workers)  # every run: its coasts and whole-run best
            add_previous_run(results)
        elif part == "family_units":
            results = run_jobs(family_unit_jobs(), args.workers)  # every run: coasts, calibration
            add_other_runs(results)
        else:
            results = run_jobs(family_jobs() if part == "family" else external_jobs(), args.workers)
        if not args.tables:
            text = json.dumps(results, indent=1, default=float) + "\n"
            (OUT / f"worth_{part}.json").write_text(text, encoding="utf-8")
        given = {"units": "the previous run of the unit", "family_units": "another run of the unit"}.get(
            part, "the truth"
        )
        print(f"\n## {part}: coasts of at least {LONG_S:g} s (given = {given})\n")
        print(table(results, models, LONG_S))
        print(f"\n## {part}: every coast of at least {MIN_COAST_S:g} s\n")
        print(table(results, models, MIN_COAST_S))
        print(f"\n## {part}: traction energy for the measured speed profile\n")
        if part == "family_units":
            print(unit_energy_table(results))
            print(f"\n## {part}: where calibration does not help (coasts of at least {MIN_COAST_S:g} s)\n")
            print(hurt_table(results))
            print(f"\n## {part}: the issue's criteria (coasts of at least {LONG_S:g} s)\n")
            print(criteria_table(results))
        else:
            print(energy_table(results, models[:3]))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
