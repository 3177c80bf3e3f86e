"""summary.json of a replay, computed from the recorded outputs alone (no ROS).

``read_outputs(bag)`` gathers the output topics as arrays; ``summarize(...)`` gives the final
resistance estimate with its standard deviations (overall and per run), the features of each run,
the regime time shares, the sliding-window calibration (window_calib_node: the last well-posed window,
counts, per-regime statistics), the dropped samples by node/topic/reason (from each node's last
/diagnostics), the message counts per topic, and the comparison with the manufacturer values and
(when given) with the simulated truth.
"""

from __future__ import annotations

import json
import math
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np

from .bagio import iter_bag, stamp_ns
from .estimation.coast_posterior import resistance_and_sigma
from .estimation.coast_regression import CoastSettings, RunArrays, fit_coasts
from .estimation.config import RegimeConfig
from .estimation.effort import PowerEffort
from .estimation.records import EFFORT_COMPUTED, EFFORT_SOURCES
from .estimation.regime_model import power_state
from .estimation.regimes_whole_run import classify_whole_run
from .measurement import track_force_integral_of
from .physics import KMH, davis
from .regime_codes import REGIME_NAMES, regime_name
from .train import TrainSpec
from .window import GOF_KINDS, WindowFit, summarize_by_regime
from .window.pooled import pooled_summary

RESISTANCE = "/train_calib/resistance"
MEASUREMENT = "/train_calib/measurement"
REGIME = "/train_calib/regime"
FEATURES = "/train_calib/features"
DIAGNOSTICS = "/diagnostics"
WINDOW = "/train_calib/window_resistance"
COEFFS = ("r0", "r1", "r2")
UNITS = {"r0": "N/kg", "r1": "N/(kg m/s)", "r2": "N/(kg (m/s)^2)"}
REFERENCE_SPEEDS_KMH = (40.0, 80.0, 120.0)
WINDOW_FIELDS = ("run_id", "window_length", "sample_count", "gof_kind", "gof_value", "a", "b", "c", "r0", "r1", "r2",
                 "regime", "ill_posed", "speed_span")  # fmt: skip


@dataclass
class Outputs:
    """The recorded outputs of a replay as arrays (SI units; t in s since the first measurement)."""

    t0_ns: int = 0
    meas: dict[str, np.ndarray] = field(default_factory=dict)  # t, s, v, run_id, speed_limit, s_measured
    est: dict[str, np.ndarray] = field(default_factory=dict)  # t, run_id, s, v, r0..r2, std_r0..2, effort, ...
    regime: dict[str, np.ndarray] = field(default_factory=dict)  # t, regime, v, run_id
    features: list[dict[str, Any]] = field(default_factory=list)
    window: dict[str, Any] | None = None  # the last well-posed /train_calib/window_resistance (window_calib_node)
    window_count: int = 0
    windows: list[WindowFit] = field(default_factory=list)  # every /train_calib/window_resistance, in order
    diagnostics: dict[str, dict[str, str]] = field(default_factory=dict)  # node -> last status values
    diagnostics_level: dict[str, int] = field(default_factory=dict)
    diagnostics_message: dict[str, str] = field(default_factory=dict)
    counts: Counter = field(default_factory=Counter)
    last_r_covariance: np.ndarray | None = None  # 3x3, of the last /train_calib/resistance message


def _plain(value: Any) -> Any:
    if isinstance(value, (np.ndarray, list, tuple)):
        return [_plain(v) for v in (value.tolist() if isinstance(value, np.ndarray) else value)]
    if isinstance(value, (np.floating, float)):
        return None if not math.isfinite(float(value)) else float(value)
    if isinstance(value, (np.integer,)):
        return int(value)
    if isinstance(value, (np.bool_,)):
        return bool(value)
    return value


def read_outputs(bag: str | Path) -> Outputs:
    """Decode the output topics of a recorded bag (directory or output.mcap)."""
    out = Outputs()
    meas: list[tuple] = []
    est: list[tuple] = []
    reg: list[tuple] = []
    for m in iter_bag(bag):
        out.counts[m.topic] += 1
        if m.topic not in (MEASUREMENT, RESISTANCE, REGIME, FEATURES, DIAGNOSTICS, WINDOW):
            continue
        msg = m.decode()
        if m.topic == MEASUREMENT:
            meas.append(
                (stamp_ns(msg.header), msg.s, msg.v, msg.run_id, msg.speed_limit, msg.s_measured, msg.track_force,
                 msg.tunnel_fraction, msg.power_valid, msg.power_consumed, msg.power_regenerated,
                 track_force_integral_of(msg), msg.s_variance, msg.v_variance)
            )  # fmt: skip
        elif m.topic == RESISTANCE:
            cov = np.asarray(msg.covariance, dtype=float).reshape(5, 5)
            std = np.sqrt(np.maximum(np.diag(cov), 0.0))
            out.last_r_covariance = cov[2:, 2:]
            est.append(
                (stamp_ns(msg.header), msg.run_id, msg.s, msg.v, msg.r0, msg.r1, msg.r2, std[2], std[3], std[4],
                 msg.effort, msg.acceleration, msg.health, msg.effort_known, msg.nis,
                 getattr(msg, "effort_source", EFFORT_COMPUTED),  # bags recorded before effort_source: computed
                 msg.resistance, msg.track_force, msg.v_measured)
            )  # fmt: skip
        elif m.topic == REGIME:
            reg.append((stamp_ns(msg.header), msg.regime, msg.v, msg.run_id))
        elif m.topic == WINDOW:
            out.window_count += 1
            fit = window_fit_from_msg(msg)
            window_pooled_from_msg(fit, msg)
            out.windows.append(fit)
            if not fit.ill_posed:
                out.window = {name: _plain(getattr(fit, name)) for name in WINDOW_FIELDS if name != "ill_posed"}
                out.window["stamp_ns"] = fit.stamp_ns
        elif m.topic == FEATURES:
            f = {
                name: _plain(getattr(msg, name))
                for name in msg.__dataclass_fields__
                if name not in ("header", "__msgtype__")
            }
            f["stamp_ns"] = stamp_ns(msg.header)
            out.features.append(f)
        else:
            for status in msg.status:
                out.diagnostics[status.name] = {kv.key: kv.value for kv in status.values}
                level = status.level
                out.diagnostics_level[status.name] = level[0] if isinstance(level, (bytes, bytearray)) else int(level)
                out.diagnostics_message[status.name] = status.message
    t0 = meas[0][0] if meas else (est[0][0] if est else 0)
    out.t0_ns = t0
    if meas:
        a = list(zip(*meas))
        out.meas = {
            "t": (np.array(a[0], dtype=np.int64) - t0) * 1e-9,
            "s": np.array(a[1]),
            "v": np.array(a[2]),
            "run_id": np.array(a[3], dtype=np.int64),
            "speed_limit": np.array(a[4]),
            "s_measured": np.array(a[5], dtype=bool),
            "track_force": np.array(a[6], dtype=float),
            "tunnel_fraction": np.array(a[7], dtype=float),
            "power_valid": np.array(a[8], dtype=bool),
            "power_consumed": np.array(a[9], dtype=float),
            "power_regenerated": np.array(a[10], dtype=float),
            "track_force_integral": np.array(a[11], dtype=float),  # NaN in bags recorded before the field
            "s_variance": np.array(a[12], dtype=float),
            "v_variance": np.array(a[13], dtype=float),
        }
    if est:
        a = list(zip(*est))
        names = ("t", "run_id", "s", "v", "r0", "r1", "r2", "std_r0", "std_r1", "std_r2", "effort", "acceleration",
                 "health", "effort_known", "nis", "effort_source",
                 "resistance", "track_force", "v_measured")  # fmt: skip
        out.est = {n: np.array(col) for n, col in zip(names, a)}
        out.est["t"] = (np.array(a[0], dtype=np.int64) - t0) * 1e-9
    if reg:
        a = list(zip(*reg))
        out.regime = {
            "t": (np.array(a[0], dtype=np.int64) - t0) * 1e-9,
            "regime": np.array(a[1], dtype=np.int64),
            "v": np.array(a[2]),
            "run_id": np.array(a[3], dtype=np.int64),
        }
    return out


def window_fit_from_msg(msg: Any) -> WindowFit:
    """A WindowResistance message as a WindowFit (``estimate`` = the published r0, r1, r2 of a well-posed window)."""
    values = {name: getattr(msg, name) for name in WINDOW_FIELDS}
    values = {k: (bool(v) if k == "ill_posed" else int(v) if isinstance(v, (int, np.integer)) else float(v))
              for k, v in values.items()}  # fmt: skip
    if not values["ill_posed"]:
        values["estimate"] = (values["r0"], values["r1"], values["r2"])
    return WindowFit(stamp_ns=stamp_ns(msg.header), **values)


def window_pooled_from_msg(fit: WindowFit, msg: Any) -> None:
    """The window's resistance at its mean speed and the pooled r(v) of a WindowResistance message into its WindowFit
    (NaN / 0 windows from bags recorded before the fields)."""
    nan = math.nan
    fit.resistance_speed = float(getattr(msg, "resistance_speed", nan))
    fit.resistance_at_speed = float(getattr(msg, "resistance_at_speed", nan))
    fit.resistance_at_speed_std = float(getattr(msg, "resistance_at_speed_std", nan))
    fit.pooled = tuple(float(getattr(msg, f"pooled_{c}", nan)) for c in COEFFS)  # type: ignore[assignment]
    fit.pooled_covariance = tuple(float(x) for x in getattr(msg, "pooled_covariance", ()))
    fit.pooled_windows = int(getattr(msg, "pooled_windows", 0))


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


REFERENCE_SPEEDS_KMH = (40, 80, 120)


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
    return _plain(value)


def format_summary(summary: dict[str, Any]) -> str:
    """A readable text version (the demo prints it)."""
    lines = []
    final = summary.get("final")
    train = summary.get("train", {})
    if final:
        has_truth = any("truth" in final[c] for c in COEFFS)
        head = f"{'':4}{'estimate':>12} {'+- std':>10} {'manufacturer':>13} {'vs manuf.':>10}"
        head += f" {'truth':>11} {'vs truth':>9}" if has_truth else ""
        lines.append(
            f"Running resistance after the last sample (train {train.get('name', '?')}, run {final['run_id']}):"
        )
        lines.append(head)
        for c in COEFFS:
            e = final[c]
            row = f"{c:4}{e['value']:12.4e} {e['std']:10.2e}"
            if "manufacturer" in e:
                row += f" {e['manufacturer']:13.4e} {_pct(e.get('vs_manufacturer')):>10}"
            if has_truth:
                row += f" {e.get('truth', float('nan')):11.4e} {_pct(e.get('vs_truth')):>9}"
            lines.append(row + f"  {UNITS[c]}")
    lines += _format_resistance(summary)
    shares = summary.get("regime_share", {})
    if shares:
        lines.append(
            "Regime time shares: "
            + ", ".join(f"{name} {100 * shares[name]:.1f} %" for name in REGIME_NAMES[1:] if name in shares)
            + (f", standing/unknown {100 * shares.get('unknown', 0.0):.1f} %" if shares.get("unknown") else "")
        )
    regimes = summary.get("regimes", {})
    if "whole_run" in regimes:
        moving = sum(n for name, n in regimes["whole_run"].items() if name != REGIME_NAMES[0])
        lines.append(
            f"Regimes given the whole run (offline): {regimes['samples_relabelled']} of {moving} moving samples "
            "labelled otherwise than on board; samples "
            + ", ".join(f"{name} {regimes['whole_run'][name]}" for name in REGIME_NAMES[1:])
        )
    for run in summary.get("runs", []):
        f = run.get("features")
        if not f:
            continue
        distance_km = (f["run_distance"] or 0.0) / 1000.0
        parts = [f"run {run['run_id']}: {run['samples']} samples, {f['run_time'] or 0:.0f} s, {distance_km:.1f} km"]
        if f.get("cruise_speed") is not None:
            parts.append(f"cruise {3.6 * f['cruise_speed']:.0f} km/h")
        if f.get("max_tractive_effort") is not None:
            parts.append(f"max tractive effort {f['max_tractive_effort']:.3f} N/kg")
        if f.get("max_tractive_power") is not None:
            parts.append(f"max tractive power {f['max_tractive_power']:.2f} W/kg")
        if f.get("final_coast_duration") is not None:
            parts.append(f"final coast {f['final_coast_duration']:.0f} s")
        if f.get("final_brake_duration") is not None:
            parts.append(f"final brake {f['final_brake_duration']:.0f} s")
        means = [m for m in f.get("brake_rate_mean", []) if m is not None]
        if means:
            parts.append("brake rates " + "/".join(f"{m:.2f}" for m in means) + " m/s^2")
        lines.append("  " + ", ".join(parts))
    lines += _format_window(summary.get("window"))
    dropped = summary.get("dropped", {})
    total = summary.get("dropped_total", 0)
    detail = "; ".join(
        f"{topic} " + ", ".join(f"{r} {n}" for r, n in reasons.items())
        for node in dropped.values()
        for topic, reasons in node.items()
    )
    lines.append(f"Dropped samples: {total}" + (f" ({detail})" if detail else ""))
    repaired = "; ".join(
        f"{topic} " + ", ".join(f"{r} {n}" for r, n in reasons.items())
        for node in summary.get("repaired", {}).values()
        for topic, reasons in node.items()
    )
    if repaired:
        lines.append(f"Repaired samples (used): {repaired}")
    health = summary.get("filter", {})
    resets = health.get("health_reset", 0) + health.get("health_repaired", 0)
    if resets:
        lines.append(
            f"Filter: {health.get('health_reset', 0)} resets, {health.get('health_repaired', 0)} repairs, "
            f"{health.get('health_degraded', 0)} degraded steps"
        )
    if summary.get("input_error"):
        lines.append(f"Input: {summary['input_error']}")
    return "\n".join(lines)


def _format_resistance(summary: dict[str, Any]) -> list[str]:
    """r(v) at the reference speeds: the on-board (causal) value and the whole run's best, with sigma."""
    lines = []
    final = summary.get("final") or {}
    best = summary.get("best")
    config = summary.get("ukf_preset")
    if config:
        lines.append(f"Configuration: ukf preset {config}")
    for label, rows in (("on board (last message)", final.get("resistance_at_kmh")),
                        ("whole run (offline)", best.get("resistance_at_kmh") if best else None)):  # fmt: skip
        if not rows:
            continue
        parts = []
        for kmh, row in rows.items():
            text = f"{kmh} km/h {row['value']:.4f} +- {row['std']:.4f}"
            if row.get("vs_truth") is not None:
                text += f" ({_pct(row['vs_truth'])} vs truth)"
            elif row.get("manufacturer"):
                text += f" ({_pct((row['value'] - row['manufacturer']) / row['manufacturer'])} vs manuf.)"
            parts.append(text)
        lines.append(f"r(v) N/kg, {label}: " + ", ".join(parts))
    if best is not None:
        if best["learnt"]:
            lines.append(f"  learnt from {best['coasting_stretches']} coasting stretches ({best['coasting_s']:.0f} s)")
        else:
            lines.append("  no coasting stretch found: the estimate is the train file's values with the prior's sigma")
    return lines


def _format_window(window: dict[str, Any] | None) -> list[str]:
    if not window:
        return []
    head = (
        f"Sliding-window calibration with traction power ({window['gof']}, {window['window_length_s']:g} s windows): "
        f"{window['well_posed']} of {window['messages']} windows well posed"
    )
    w = window.get("last_well_posed")
    pooled = _format_pooled(window.get("pooled"))
    if not w:
        return [
            head + f" (every one of the {window['messages']} published windows has r0, r1, r2 NaN: within a window "
            "the speed spans too little to separate them, docs/window.md)",
            *pooled,
        ]
    lines = [head + f"; the last ({w['regime']}, {w['sample_count']} steps, {window['gof']} {w['gof_value_n']:.3g} N):"]
    lines.append(
        f"    A {w['a_n']:.4g} N, B {w['b_n_per_m_s']:.4g} N/(m/s), C {w['c_n_per_m2_s2']:.4g} N/(m/s)^2 = "
        f"r0 {w['r0']:.4e}, r1 {w['r1']:.4e}, r2 {w['r2']:.4e}"
    )
    parts = []
    for kmh, row in w.get("resistance_at_kmh", {}).items():
        text = f"{kmh} km/h {row['value']:.4f} N/kg"
        if "vs_truth" in row:
            text += f" ({_pct(row['vs_truth'])} vs truth)"
        elif "vs_manufacturer" in row:
            text += f" ({_pct(row['vs_manufacturer'])} vs manuf.)"
        parts.append(text)
    if parts:
        lines.append("    r(v): " + ", ".join(parts))
    regimes = window.get("by_regime", {})
    if regimes:
        lines.append(
            "    per regime (well/ill posed): "
            + ", ".join(f"{name} {st['windows']}/{st['ill_posed']}" for name, st in regimes.items())
        )
    return lines + pooled


def _format_pooled(pooled: dict[str, Any] | None) -> list[str]:
    """The windows pooled into one r(v) (each window's resistance at its mean speed), at the reference speeds."""
    if not pooled:
        return []
    r, cov = np.array([pooled[c] for c in COEFFS]), np.asarray(pooled["covariance"], dtype=float)
    parts = []
    for kmh in REFERENCE_SPEEDS_KMH:
        value, std = resistance_and_sigma(r, cov, kmh / 3.6)
        parts.append(f"{kmh} km/h {value:.4f} +- {std:.4f}")
    return [f"    pooled over {pooled.get('windows', 0)} windows, r(v) N/kg: " + ", ".join(parts)]


def _pct(x: float | None) -> str:
    return "" if x is None else f"{100 * x:+.1f} %"


__all__ = ["Outputs", "dropped_counts", "filter_health", "format_summary", "read_outputs", "regime_shares",
           "run_features", "summarize", "window_fit_from_msg", "window_summary", "write_summary"]  # fmt: skip
