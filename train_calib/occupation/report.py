"""The files of ``train-calib calibrate-occupation``: CSV tables, markdown, JSON summary.

======================  ==================================================================
file                    content
======================  ==================================================================
runs.csv                one row per run: status (calibrated / rejected / unassigned /
                        failed) and why, estimated length and composition, the calibrated
                        parameters (and the fixed c1, r1, b_stop), objective, residuals
residuals.csv           every passage: observed and simulated time, residual
lengths.csv             length, interval and composition per run for delta = 0, 1, 2 s
distributions.csv       every candidate fitted per composition and parameter, ranked by KS
distributions.md        Table 4 / Figs. 7-9: range and best fit per composition and parameter
sensitivity.csv         running-time change per parameter (+-20 %) and identifiability
truth_comparison.csv    calibrated vs true parameters per run (with ``--truth``)
summary.json            counts, ranges, timing, settings, accuracy against the truth
======================  ==================================================================
"""

from __future__ import annotations

import csv
import json
import math
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from .compositions import DECISION_NAMES, UNITS, TrainTypes
from .length import assignment_accuracy
from .pipeline import FleetCalibration, at_bound_share, summary_numbers

FIXED_NAMES = ("c1", "r1", "b_stop")


def write_runs_csv(path: Path, fleet: FleetCalibration) -> Path:
    cols = [
        "run_id",
        "status",
        "reason",
        "composition",
        "length_m",
        "length_low_m",
        "length_high_m",
        "n_joints",
        *DECISION_NAMES,
        *FIXED_NAMES,
        "objective_s",
        "default_objective_s",
        "mean_abs_residual_s",
        "max_abs_residual_s",
        "n_observations",
        "departure_s",
        "running_time_s",
        "nfev",
        "nit",
        "elapsed_s",
        "seed",
    ]
    with path.open("w", newline="", encoding="utf-8") as f:
        w = csv.writer(f, lineterminator="\n")
        w.writerow(cols)
        for o in fleet.outcomes:
            e = o.length
            row = {
                "run_id": o.run_id,
                "status": o.status,
                "reason": o.reason,
                "composition": o.composition or "",
                "length_m": e.length_m,
                "length_low_m": e.low_m,
                "length_high_m": e.high_m,
                "n_joints": e.n_joints,
            }
            r = o.result
            if r is not None:
                ev = r.evaluation
                row.update({k: r.params[k] for k in (*DECISION_NAMES, *FIXED_NAMES)})
                row.update(
                    objective_s=r.objective_s,
                    default_objective_s=r.default_objective_s,
                    mean_abs_residual_s=r.mean_abs_residual_s,
                    max_abs_residual_s=float(np.max(np.abs(ev.residual_s)))
                    if ev is not None and len(ev.residual_s)
                    else "",
                    n_observations=r.n_observations,
                    departure_s=float(ev.departure_s[0]) if ev is not None and len(ev.departure_s) else "",
                    running_time_s=r.running_time_s,
                    nfev=r.nfev,
                    nit=r.nit,
                    elapsed_s=r.elapsed_s,
                    seed=r.seed,
                )
            w.writerow([_cell(row.get(c, "")) for c in cols])
    return path


def write_residuals_csv(path: Path, fleet: FleetCalibration, runs_obs: Mapping[str, object]) -> Path:
    """``runs_obs``: run_id -> Observations (positions, kinds, sections) of the calibrated runs."""
    with path.open("w", newline="", encoding="utf-8") as f:
        w = csv.writer(f, lineterminator="\n")
        w.writerow(["run_id", "section_id", "event", "position_m", "observed_s", "simulated_s", "residual_s"])
        for o in fleet.outcomes:
            if o.result is None or o.result.evaluation is None or o.run_id not in runs_obs:
                continue
            obs, ev = runs_obs[o.run_id], o.result.evaluation
            for i in range(len(obs)):
                w.writerow(
                    [
                        o.run_id,
                        obs.section_id[i],
                        obs.kind[i],
                        _cell(obs.position_m[i]),
                        _cell(obs.time_s[i]),
                        _cell(ev.simulated_s[i]),
                        _cell(ev.residual_s[i]),
                    ]
                )
    return path


def write_lengths_csv(path: Path, fleet: FleetCalibration) -> Path:
    with path.open("w", newline="", encoding="utf-8") as f:
        w = csv.writer(f, lineterminator="\n")
        w.writerow(
            ["run_id", "delta_s", "length_m", "low_m", "high_m", "n_joints", "composition", "candidates", "reason"]
        )
        for delta, ests in sorted(fleet.lengths.items()):
            for e in ests:
                w.writerow(
                    [
                        e.run_id,
                        _cell(delta),
                        _cell(e.length_m),
                        _cell(e.low_m),
                        _cell(e.high_m),
                        e.n_joints,
                        e.composition or "",
                        " ".join(e.candidates),
                        e.reason,
                    ]
                )
    return path


def write_distributions(folder: Path, fleet: FleetCalibration) -> tuple[Path, Path]:
    csv_path, md_path = folder / "distributions.csv", folder / "distributions.md"
    with csv_path.open("w", newline="", encoding="utf-8") as f:
        w = csv.writer(f, lineterminator="\n")
        w.writerow(
            [
                "composition",
                "parameter",
                "rank",
                "distribution",
                "parameters",
                "ks_statistic",
                "p_value",
                "log_likelihood",
                "aic",
                "n",
                "ok",
                "message",
            ]
        )
        for comp, per_param in fleet.fits.items():
            for name, fits in per_param.items():
                for rank, fit in enumerate(fits, start=1):
                    params = " ".join(f"{k}={v:.6g}" for k, v in fit.params.items())
                    w.writerow(
                        [
                            comp,
                            name,
                            rank if fit.ok else "",
                            fit.name,
                            params,
                            _cell(fit.ks_statistic),
                            _cell(fit.p_value),
                            _cell(fit.log_likelihood),
                            _cell(fit.aic),
                            fit.n,
                            fit.ok,
                            fit.message,
                        ]
                    )
    md_path.write_text(distributions_markdown(fleet), encoding="utf-8")
    return csv_path, md_path


def distributions_markdown(fleet: FleetCalibration) -> str:
    lines = [
        "# Calibrated parameters per composition (Besinovic et al. 2013, Table 4 and Figs. 7-9)",
        "",
        "Range over the calibrated runs, and the candidate distribution with the lowest Kolmogorov-Smirnov",
        "statistic (maximum likelihood fits; the p-value is optimistic as the parameters come from the same data).",
        "",
    ]
    for comp in sorted({o.composition for o in fleet.outcomes if o.result is not None}):
        results = fleet.calibrated(comp)
        lines += [
            f"## {comp} ({len(results)} runs)",
            "",
            "| parameter | unit | min | median | max | at a bound | best fit | KS | p |",
            "|---|---|---:|---:|---:|---:|---|---:|---:|",
        ]
        for name in DECISION_NAMES:
            vals = np.array([r.params[name] for r in results])
            at_bound = at_bound_share(vals, fleet.bounds.get(comp, {}).get(name))
            best = fleet.fits.get(comp, {}).get(name, [None])[0]
            if best is not None and best.ok:
                fit, ks, p = best.describe(), f"{best.ks_statistic:.3f}", f"{best.p_value:.3f}"
            else:
                fit, ks, p = (best.message if best is not None else "too few runs to fit"), "", ""
            lines.append(
                f"| {name} | {UNITS[name]} | {vals.min():.4g} | {np.median(vals):.4g} | {vals.max():.4g} | "
                f"{at_bound:.0%} | {fit} | {ks} | {p} |"
            )
        lines.append("")
        lines.append(
            "A parameter that often ends at a bound of the search box is not determined by the data "
            "(see docs/occupation.md, identifiability): its distribution describes the box, not the trains."
        )
        lines.append("")
    return "\n".join(lines)


def write_sensitivity_csv(path: Path, fleet: FleetCalibration) -> Path:
    with path.open("w", newline="", encoding="utf-8") as f:
        w = csv.writer(f, lineterminator="\n")
        w.writerow(
            [
                "composition",
                "parameter",
                "value",
                "low",
                "high",
                "running_time_s",
                "change_low_pct",
                "change_high_pct",
                "max_passage_change_s",
                "std_error",
                "relative_std_error_pct",
            ]
        )
        for comp, rows in fleet.sensitivity.items():
            ident = fleet.identifiability.get(comp)
            err = dict(zip(ident.names, ident.std_error)) if ident else {}
            for s in rows:
                se = err.get(s.name)
                w.writerow(
                    [
                        comp,
                        s.name,
                        _cell(s.base),
                        _cell(s.low),
                        _cell(s.high),
                        _cell(s.running_time_s),
                        _cell(s.change_low_pct),
                        _cell(s.change_high_pct),
                        _cell(s.max_passage_change_s),
                        _cell(se) if se is not None else "",
                        _cell(100 * se / abs(s.base)) if se is not None and s.base else "",
                    ]
                )
    return path


def truth_comparison(fleet: FleetCalibration, truth: Mapping[str, Mapping]) -> dict:
    """Per composition and parameter: median and 90th percentile of |calibrated - true| / true, and bias."""
    out: dict[str, dict] = {}
    for comp in sorted({o.composition for o in fleet.outcomes if o.result is not None}):
        stats = {}
        for name in DECISION_NAMES:
            rel = [
                (r.params[name] - float(truth[r.run_id][name])) / float(truth[r.run_id][name])
                for r in fleet.calibrated(comp)
                if r.run_id in truth and _finite(truth[r.run_id].get(name))
            ]
            if rel:
                a = np.array(rel)
                stats[name] = {
                    "median_abs_rel_error": float(np.median(np.abs(a))),
                    "p90_abs_rel_error": float(np.percentile(np.abs(a), 90)),
                    "median_rel_bias": float(np.median(a)),
                    "n": int(a.size),
                }
        dep = [
            abs(float(r.evaluation.departure_s[0]) - float(truth[r.run_id]["departure_s"]))
            for r in fleet.calibrated(comp)
            if r.run_id in truth
            and r.evaluation is not None
            and len(r.evaluation.departure_s) == 1
            and _finite(truth[r.run_id].get("departure_s"))
        ]
        if dep:  # the free departure time of eq. 8 (single-leg runs)
            stats["departure_s"] = {
                "median_abs_error_s": float(np.median(dep)),
                "p90_abs_error_s": float(np.percentile(dep, 90)),
            }
        out[comp] = stats
    return out


def write_truth_csv(path: Path, fleet: FleetCalibration, truth: Mapping[str, Mapping]) -> Path:
    with path.open("w", newline="", encoding="utf-8") as f:
        w = csv.writer(f, lineterminator="\n")
        w.writerow(["run_id", "composition", "parameter", "calibrated", "true", "relative_error"])
        for r in fleet.calibrated():
            t = truth.get(r.run_id)
            if t is None:
                continue
            for name in DECISION_NAMES:
                true = float(t.get(name, math.nan))
                w.writerow(
                    [
                        r.run_id,
                        r.composition,
                        name,
                        _cell(r.params[name]),
                        _cell(true),
                        _cell((r.params[name] - true) / true if _finite(true) and true else math.nan),
                    ]
                )
    return path


def length_accuracy(fleet: FleetCalibration, truth: Mapping[str, Mapping], types: TrainTypes) -> dict:
    """Assignment accuracy per delta against the true compositions."""
    names = {rid: str(t["composition"]) for rid, t in truth.items()}
    out = {}
    for delta, ests in sorted(fleet.lengths.items()):
        acc = assignment_accuracy(ests, names, types.lengths())
        out[f"{delta:g}"] = {
            "runs": acc.n_runs,
            "assigned": acc.n_assigned,
            "correct": acc.n_correct,
            "wrong": acc.n_wrong,
            "correct_share": acc.correct_share,
            "precision": acc.precision,
            "length_error_m": acc.length_error_m,
            "confusion": acc.confusion,
        }
    return out


def summary(fleet: FleetCalibration, types: TrainTypes, truth: Mapping[str, Mapping] | None = None) -> dict:
    nums = summary_numbers(fleet)
    calibrated = fleet.calibrated()
    times = [r.elapsed_s for r in calibrated]
    out = {
        "runs": len(fleet.outcomes),
        **nums,
        "rejected": {o.run_id: o.reason for o in fleet.outcomes if o.status == "rejected"},
        "unassigned": {o.run_id: o.reason for o in fleet.outcomes if o.status == "unassigned"},
        "failed": {o.run_id: o.reason for o in fleet.outcomes if o.status == "failed"},
        "timing": {
            "wall_s": fleet.elapsed_s,
            "workers": fleet.workers,
            "per_calibration_s_median": float(np.median(times)) if times else None,
            "per_calibration_s_max": float(np.max(times)) if times else None,
            "evaluations_median": float(np.median([r.nfev for r in calibrated])) if calibrated else None,
        },
        "sensitivity": {
            comp: {
                s.name: {"change_pct": s.max_change_pct, "max_passage_change_s": s.max_passage_change_s} for s in rows
            }
            for comp, rows in fleet.sensitivity.items()
        },
        "identifiability": {
            comp: {
                "relative_std_error": dict(zip(i.names, (float(x) for x in i.relative_error()))),
                "strongest_correlations": [list(c) for c in i.strongest_correlations(3)],
            }
            for comp, i in fleet.identifiability.items()
        },
        "best_fits": {
            comp: {
                name: (
                    {
                        "distribution": fits[0].name,
                        "params": fits[0].params,
                        "ks": fits[0].ks_statistic,
                        "p_value": fits[0].p_value,
                    }
                    if fits and fits[0].ok
                    else None
                )
                for name, fits in per.items()
            }
            for comp, per in fleet.fits.items()
        },
        "settings": fleet.settings,
        "release_offset_s": fleet.release_offset_s,
    }
    if fleet.release_delay is not None:
        out["release_delay"] = fleet.release_delay.as_dict()
    if truth is not None:
        out["length_accuracy"] = length_accuracy(fleet, truth, types)
        out["truth_comparison"] = truth_comparison(fleet, truth)
        hindered = {rid for rid, t in truth.items() if t.get("hindrance")}
        rejected = {o.run_id for o in fleet.outcomes if o.status == "rejected"}
        out["filter_accuracy"] = {
            "hindered": len(hindered),
            "hindered_rejected": len(hindered & rejected),
            "unhindered_rejected": len(rejected - hindered),
        }
    return out


def write_summary(path: Path, data: dict) -> Path:
    path.write_text(json.dumps(_jsonable(data), indent=2, sort_keys=False) + "\n", encoding="utf-8")
    return path


def summary_text(data: dict) -> str:
    """The printed summary."""
    c = data["counts"]
    lines = [
        f"runs: {data['runs']}  calibrated: {c.get('calibrated', 0)}  rejected: {c.get('rejected', 0)}  "
        f"unassigned: {c.get('unassigned', 0)}  failed: {c.get('failed', 0)}",
    ]
    if "release_delay" in data:
        lines.append(data["release_delay"]["reason"])
    t = data["timing"]
    if t["per_calibration_s_median"] is not None:
        lines.append(
            f"time: {t['wall_s']:.1f} s wall on {t['workers']} worker(s); per calibration median "
            f"{t['per_calibration_s_median']:.2f} s ({t['evaluations_median']:.0f} model runs)"
        )
    for comp, r in data["ranges"].items():
        lines.append(
            f"{comp}: {r['runs']} runs, median objective {r['objective_s']:.1f} s "
            f"(mean |residual| {r['mean_abs_residual_s']:.2f} s)"
        )
        for name in DECISION_NAMES:
            v = r[name]
            fit = data["best_fits"].get(comp, {}).get(name)
            tail = f"  best fit {fit['distribution']} (KS {fit['ks']:.3f}, p {fit['p_value']:.2f})" if fit else ""
            bound = f", {v['at_bound_share']:.0%} at a bound" if v["at_bound_share"] > 0 else ""
            lines.append(
                f"  {name:13s} [{v['min']:.4g}, {v['max']:.4g}] median {v['median']:.4g} {UNITS[name]}{bound}{tail}"
            )
    if "length_accuracy" in data:
        for delta, a in data["length_accuracy"].items():
            lines.append(
                f"length delta {delta} s: {a['assigned']}/{a['runs']} assigned, {a['correct']} correct, "
                f"{a['wrong']} wrong; median |length error| {a['length_error_m'].get('median', float('nan')):.1f} m"
            )
    if "filter_accuracy" in data:
        f = data["filter_accuracy"]
        lines.append(
            f"filter: {f['hindered_rejected']}/{f['hindered']} hindered runs rejected, "
            f"{f['unhindered_rejected']} unhindered rejected"
        )
    return "\n".join(lines)


def _finite(value) -> bool:
    try:
        return math.isfinite(float(value))
    except (TypeError, ValueError):
        return False


def _cell(value) -> str:
    if isinstance(value, (float, np.floating)):
        return "" if not math.isfinite(float(value)) else f"{float(value):.8g}"
    return str(value)


def _jsonable(value):
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if isinstance(value, (np.floating, float)):
        return float(value) if math.isfinite(float(value)) else None
    if isinstance(value, np.integer):
        return int(value)
    if isinstance(value, np.ndarray):
        return _jsonable(value.tolist())
    return value
