"""The printed summary of a replay (``train-calib replay`` and ``demo`` print it): summary.json as text."""

from __future__ import annotations

from typing import Any

import numpy as np

from .estimation.coast_posterior import resistance_and_sigma
from .regime_codes import REGIME_NAMES
from .summary_outputs import COEFFS, REFERENCE_SPEEDS_KMH, UNITS


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
            count = best["coasting_stretches"]
            noun = "stretch" if count == 1 else "stretches"
            lines.append(f"  learnt from {count} coasting {noun} ({best['coasting_s']:.0f} s)")
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
