"""summary.json of a replay, computed from the recorded outputs alone (no ROS).

``read_outputs(bag)`` (:mod:`summary_outputs`) gathers the output topics as arrays; ``summarize(...)`` gives the final
resistance estimate with its standard deviations (overall and per run), the features of each run,
the regime time shares, the sliding-window calibration (window_calib_node: the last well-posed window,
counts, per-regime statistics), the dropped samples by node/topic/reason (from each node's last
/diagnostics), the message counts per topic, and the comparison with the manufacturer values and
(when given) with the simulated truth.
"""

from __future__ import annotations

import json
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np

from .estimation.coast_posterior import resistance_and_sigma
from .estimation.coast_regression import CoastSettings, RunArrays, fit_coasts
from .estimation.config import RegimeConfig
from .estimation.effort import PowerEffort
from .estimation.records import EFFORT_SOURCES
from .estimation.regime_model import power_state
from .estimation.regimes_whole_run import classify_whole_run
from .physics import KMH, davis
from .regime_codes import REGIME_NAMES, regime_name
from .summary_outputs import (
    COEFFS,
    REFERENCE_SPEEDS_KMH,
    UNITS,
    Outputs,
    plain,
    read_outputs,
    window_fit_from_msg,
)
from .summary_text import format_summary
from .train import TrainSpec
from .window import GOF_KINDS, WindowFit, summarize_by_regime
from .window.pooled import pooled_summary


def window_pooled(fit: WindowFit) -> dict[str, Any] | None:
    """summary.json's ``window.pooled``: the run's windows pooled into r(v) as the last window carries it,
    {"r0", "r1", "r2" (N/kg units), "covariance" (3x3), "windows"}; None when it carries none."""
    return pooled_summary(fit.pooled, fit.pooled_covariance, fit.pooled_windows)


def window_summary(
    windows: list[WindowFit], train: TrainSpec | None = None, truth: dict[str, float] | None = None
) -> dict[str, Any]:
    """summary.json's ``window``: counts, the last well-posed window (A, B, C in N units, r0, r1, r2 per unit of
    effective mass, window length, GoF; r(v) at 40/80/120 km/h against the manufacturer values and the truth) and
    the per-regime statistics of De Martinis & Corman Section 5.3 over the well-posed windows."""
    well = [f for f in windows if not f.ill_posed]
    last = windows[-1] if windows else None
    out: dict[str, Any] = {
        "messages": len(windows),
        "well_posed": len(well),
        "ill_posed": len(windows) - len(well),
        "window_length_s": last.window_length if last else None,
        "gof": GOF_KINDS[last.gof_kind] if last and 0 <= last.gof_kind < len(GOF_KINDS) else None,
        "last_well_posed": None,
        "by_regime": {},
    }
    if train is not None:
        for regime, st in summarize_by_regime(windows, train.effective_mass_kg).items():
            name = regime_name(regime)
            out["by_regime"][name] = {
                "windows": st.windows,
                "ill_posed": st.ill_posed,
                "median_abc": st.median,
                "iqr_abc": st.iqr,
                "mean_abc": st.mean,
                "median_r": st.specific_median,
            }
    if not well:
        return out
    f = well[-1]
    entry: dict[str, Any] = {"stamp_ns": f.stamp_ns, "run_id": f.run_id, "window_length_s": f.window_length,
                             "sample_count": f.sample_count, "gof": out["gof"], "gof_value_n": f.gof_value,
                             "a_n": f.a, "b_n_per_m_s": f.b, "c_n_per_m2_s2": f.c, "r0": f.r0, "r1": f.r1, "r2": f.r2,
                             "regime": regime_name(f.regime),
                             "speed_span_m_s": f.speed_span}  # fmt: skip
    if train is not None:
        for c in COEFFS:
            ref = getattr(train.davis, c)
            entry[f"{c}_vs_manufacturer"] = (getattr(f, c) - ref) / ref if ref else None
    speeds = {}
    for kmh in REFERENCE_SPEEDS_KMH:
        v = kmh * KMH
        value = float(davis(v, f.r0, f.r1, f.r2))
        row: dict[str, Any] = {"value": value}
        if train is not None:
            ref = float(davis(v, *train.davis.as_tuple()))
            row |= {"manufacturer": ref, "vs_manufacturer": (value - ref) / ref}
        if truth is not None and all(c in truth for c in COEFFS):
            true = float(davis(v, *(truth[c] for c in COEFFS)))
            row |= {"truth": true, "vs_truth": (value - true) / true}
        speeds[f"{kmh:g}"] = row
    entry["resistance_at_kmh"] = speeds
    out["last_well_posed"] = entry
    return out


def dropped_counts(outputs: Outputs, what: str = "dropped") -> dict[str, dict[str, dict[str, int]]]:
    """node -> topic -> reason -> count, from each node's last /diagnostics (``what``: dropped or repaired)."""
    out: dict[str, dict[str, dict[str, int]]] = {}
    for node, values in outputs.diagnostics.items():
        for key, value in values.items():
            topic, sep, reason = key.partition(f" {what} ")
            if sep and topic.startswith("/"):
                out.setdefault(node, {}).setdefault(topic, {})[reason] = int(value)
    return out


def filter_health(outputs: Outputs) -> dict[str, int]:
    """ukf_node's counts per health state and the filter's counters (resets, repairs, gated positions...)."""
    values = outputs.diagnostics.get("ukf_node", {})
    out = {}
    for key, value in values.items():
        for prefix in ("health ", "filter "):
            if key.startswith(prefix) and key != "filter health" and value.lstrip("-").isdigit():
                out[key.replace(" ", "_")] = int(value)
    return out


def _estimate(est: dict[str, np.ndarray], i: int, train: TrainSpec | None, truth: dict | None) -> dict[str, Any]:
    out: dict[str, Any] = {"t": float(est["t"][i]), "run_id": int(est["run_id"][i]), "health": int(est["health"][i])}
    for c in COEFFS:
        entry = {"value": float(est[c][i]), "std": float(est[f"std_{c}"][i]), "unit": UNITS[c]}
        if train is not None:
            ref = getattr(train.davis, c)
            entry["manufacturer"] = ref
            entry["vs_manufacturer"] = (entry["value"] - ref) / ref if ref else None
        if truth is not None and c in truth:
            entry["truth"] = truth[c]
            entry["vs_truth"] = (entry["value"] - truth[c]) / truth[c] if truth[c] else None
        out[c] = entry
    return out


def resistance_at_speeds(
    r: np.ndarray, cov: np.ndarray, train: TrainSpec | None, truth: dict | None
) -> dict[str, dict[str, float]]:
    """r(v) (N/kg) and its std at the reference speeds, with the train file's and the truth's values when known."""
    out: dict[str, dict[str, float]] = {}
    for kmh in REFERENCE_SPEEDS_KMH:
        v = kmh / 3.6
        value, std = resistance_and_sigma(r, cov, v)
        row = {"value": value, "std": std}
        if train is not None:
            row["manufacturer"] = float(train.davis(v))
        if truth is not None and all(c in truth for c in COEFFS):
            row["truth"] = float(np.array([1.0, v, v * v]) @ np.array([truth[c] for c in COEFFS]))
            row["vs_truth"] = (row["value"] - row["truth"]) / row["truth"] if row["truth"] else None
        out[str(kmh)] = row
    return out


def best_estimate(
    meas: dict[str, np.ndarray], train: TrainSpec, truth: dict | None, coast: CoastSettings | None = None
) -> dict[str, Any]:
    """The whole run's best estimate of r: the coast regression over every coasting stretch of the recorded
    measurements (offline; docs/estimator.md, "Coast regression"), with its covariance and r(v) at the reference
    speeds. Without a coasting stretch it is the train file's values with the prior's covariance, and says so."""
    settings = coast if coast is not None else CoastSettings()
    columns = ("t", "v", "track_force", "tunnel_fraction", "run_id", "power_valid", "power_consumed",
               "power_regenerated")  # fmt: skip
    energy = ("s", "track_force_integral", "s_variance", "v_variance")
    arrays = RunArrays.from_columns(*(meas[c] for c in columns), train, settings, *(meas.get(c) for c in energy))
    fit = fit_coasts(arrays, train, settings)
    out: dict[str, Any] = {
        "method": "coast regression over the whole run",
        **{c: float(x) for c, x in zip(COEFFS, fit.r)},
        "covariance": fit.covariance,
        "resistance_at_kmh": resistance_at_speeds(fit.r, fit.covariance, train, truth),
        "coasting_stretches": len(fit.stretches),
        "coasting_s": fit.coasting_time,
        "speed_noise_m_s": fit.speed_noise,
        "slope_window_s": fit.window,
        "learnt": bool(fit.stretches),
    }
    if not fit.stretches:
        out["note"] = "no coasting stretch: the train file's values with the prior's covariance"
    return out


def whole_run_regimes(outputs: Outputs, train: TrainSpec, config: RegimeConfig | None = None) -> dict[str, Any]:
    """The published regimes (on board) beside the whole run's (``classify_regimes(..., smooth=True)`` over the
    recorded estimates, with each one's measurement: the traction power's state, s and Gamma(s); as
    ``pipeline.whole_run_regimes``), as sample counts per regime and the number of samples whose label differs.
    ``config``: the regime configuration (the defaults if None)."""
    cfg = config if config is not None else RegimeConfig()
    est, meas, reg = outputs.est, outputs.meas, outputs.regime
    if not est or not reg or len(reg["t"]) != len(est["t"]):
        return {"note": "no regimes recorded, or not one per estimate"}
    index = {t: k for k, t in enumerate(meas["t"].tolist())} if meas else {}
    rows = [index.get(t) for t in est["t"].tolist()]

    def at_measurement(name: str) -> np.ndarray | None:
        if not meas or name not in meas:
            return None
        return np.array([np.nan if k is None else float(meas[name][k]) for k in rows])

    power = PowerEffort(train)
    states = [
        -1 if k is None else power_state(SimpleNamespace(**{c: meas[c][k] for c in POWER_COLUMNS}), power) for k in rows
    ]
    position, integral = at_measurement("s"), at_measurement("track_force_integral")
    whole = classify_whole_run(est, cfg, [-1 if p is None else p for p in states], position, integral)
    on_board = np.asarray(reg["regime"])

    def counts(labels: np.ndarray) -> dict[str, int]:
        return {name: int(np.count_nonzero(labels == code)) for code, name in enumerate(REGIME_NAMES)}

    return {
        "method": f"{cfg.method}, "
        + ("smoothed over the whole run (offline)" if cfg.method != "rule" else "per sample"),
        "on_board": counts(on_board),
        "on_board_lag_samples": cfg.lag_samples,  # regime_node's: 1 published one sample late, revised; 0 causal
        "whole_run": counts(whole),
        "samples_relabelled": int(np.count_nonzero(whole != on_board)),
    }


POWER_COLUMNS = ("power_valid", "power_consumed", "power_regenerated")
"""The measurement's traction power, as regime_model.power_state reads it."""


def regime_shares(features: list[dict[str, Any]]) -> dict[str, float]:
    """Time shares over all runs: each run's closing features weighted by its run time."""
    closing = run_features(features)
    total = sum(f["run_time"] or 0.0 for f in closing.values())
    shares = np.zeros(len(REGIME_NAMES))
    for f in closing.values():
        shares += np.asarray([x or 0.0 for x in f["regime_time_share"]]) * (f["run_time"] or 0.0)
    if total > 0:
        shares /= total
    return {name: float(x) for name, x in zip(REGIME_NAMES, shares)}


def run_features(features: list[dict[str, Any]]) -> dict[int, dict[str, Any]]:
    """run_id -> its closing features (run_complete), else its latest."""
    out: dict[int, dict[str, Any]] = {}
    for f in features:
        rid = int(f["run_id"])
        if rid not in out or not out[rid].get("run_complete"):
            out[rid] = f
    return out


def summarize(
    outputs: Outputs,
    *,
    train: TrainSpec | None = None,
    truth: dict[str, float] | None = None,
    extra: dict[str, Any] | None = None,
    coast: CoastSettings | None = None,
    regime: RegimeConfig | None = None,
) -> dict[str, Any]:
    """The summary.json content (``coast``: the settings of the whole run's best estimate, ``regime``: regime_node's,
    for the whole run's regimes; the defaults if None)."""
    est = outputs.est
    summary: dict[str, Any] = dict(extra or {})
    if train is not None:
        summary["train"] = {"name": train.name, "manufacturer": dict(zip(COEFFS, train.davis.as_tuple()))}
    if est:
        last = len(est["t"]) - 1
        summary["final"] = _estimate(est, last, train, truth)
        r_final = np.array([est[c][last] for c in COEFFS], dtype=float)
        if outputs.last_r_covariance is not None:
            summary["final"]["covariance"] = outputs.last_r_covariance
            summary["final"]["resistance_at_kmh"] = resistance_at_speeds(
                r_final, outputs.last_r_covariance, train, truth
            )
        runs = []
        features = run_features(outputs.features)
        for rid in sorted(set(est["run_id"].tolist())):
            idx = np.flatnonzero(est["run_id"] == rid)
            run = {
                "run_id": int(rid),
                "samples": int(idx.size),
                "t_start": float(est["t"][idx[0]]),
                "t_end": float(est["t"][idx[-1]]),
                "final": _estimate(est, int(idx[-1]), train, truth),
                "effort_known_samples": int(np.count_nonzero(est["effort_known"][idx])),
                "effort_sources": {
                    name: int(np.count_nonzero(est["effort_source"][idx] == code))
                    for code, name in enumerate(EFFORT_SOURCES)
                },
            }
            if rid in features:
                run["features"] = features[rid]
            runs.append(run)
        summary["runs"] = runs
    else:
        summary["final"] = None
        summary["runs"] = []
    if train is not None and outputs.meas:
        summary["best"] = best_estimate(outputs.meas, train, truth, coast)
    if outputs.windows:
        summary["window"] = window_summary(outputs.windows, train, truth)
        summary["window"]["pooled"] = window_pooled(outputs.windows[-1])
    summary["regime_share"] = regime_shares(outputs.features)
    if train is not None:
        summary["regimes"] = whole_run_regimes(outputs, train, regime)
    summary["dropped"] = dropped_counts(outputs)
    summary["dropped_total"] = sum(n for t in summary["dropped"].values() for r in t.values() for n in r.values())
    summary["repaired"] = dropped_counts(outputs, "repaired")
    summary["filter"] = filter_health(outputs)
    ingest = outputs.diagnostics.get("gnss_speed_node", {})
    summary["ingest"] = {
        key.replace(" ", "_").replace("(", "").replace(")", "").replace("-", "_"): ingest[key]
        for key in (
            "re-acquisitions",
            "dead-reckoned measurements",
            "reversals",
            "clock resets",
            "gnss delay estimate (s)",
        )
        if key in ingest
    }
    summary["diagnostics"] = {
        node: {"level": ("OK", "WARN", "ERROR", "STALE")[min(level, 3)], "message": outputs.diagnostics_message[node]}
        for node, level in outputs.diagnostics_level.items()
    }
    summary["output_counts"] = dict(outputs.counts)
    if truth is not None:
        summary["truth"] = truth
    return summary


def write_summary(path: str | Path, summary: dict[str, Any]) -> None:
    Path(path).write_text(json.dumps(_plain_tree(summary), indent=2) + "\n", encoding="utf-8")


def _plain_tree(value: Any) -> Any:
    if isinstance(value, dict):
        return {str(k): _plain_tree(v) for k, v in value.items()}
    if isinstance(value, (list, tuple, np.ndarray)):
        return [_plain_tree(v) for v in (value.tolist() if isinstance(value, np.ndarray) else value)]
    return plain(value)


__all__ = ["Outputs", "dropped_counts", "filter_health", "format_summary", "read_outputs", "regime_shares",
           "run_features", "summarize", "window_fit_from_msg", "window_summary", "write_summary"]  # fmt: skip
