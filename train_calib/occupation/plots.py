"""Figures of the occupation calibration (matplotlib, Agg), in the layout of Besinovic et al. (2013).

- :func:`run_figure`: one run, Fig. 5: calibrated speed profile with the static limit and the
  gradient, and the time-distance trajectory, observed passages as circles over the simulated line.
- :func:`distribution_figure`: one composition, Figs. 7-9: histogram of each calibrated parameter
  with the density of the best-fitting distribution, its parameters, KS statistic and p-value.
- :func:`length_figure`: Fig. 6: the length interval of every run for each delta, coloured by the
  composition assigned, with the composition lengths.
- :func:`ranges_figure`: Fig. 10: calibrated ranges per composition with the defaults.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from ..physics import KMH
from ..track import Track
from .calibrate import CalibrationResult
from .compositions import DECISION_NAMES, UNITS, TrainTypes
from .distributions import FitResult
from .length import LengthEstimate
from .objective import Observations, ProfileModel

COLOURS = ("tab:blue", "tab:orange", "tab:green", "tab:red", "tab:purple", "tab:brown")


def run_figure(path: Path, track: Track, obs: Observations, result: CalibrationResult, model: ProfileModel) -> Path:
    """Fig. 5: speed-distance (calibrated) and time-distance, observed vs simulated."""
    fig, (ax_v, ax_t) = plt.subplots(2, 1, figsize=(10, 7), sharex=True, height_ratios=(1, 1.2))
    ev = result.evaluation
    for k, (start, stop) in enumerate(obs.legs):
        prof = model(result.params, start, stop)
        s = np.linspace(start, stop, 1500)
        v = np.asarray(prof.speed_at(s), dtype=float) / KMH
        t = np.asarray(prof.time_at(s), dtype=float) + (ev.departure_s[k] if ev is not None else 0.0)
        ax_v.plot(s / 1000, v, color="tab:blue", lw=1.5, label="calibrated speed" if k == 0 else None)
        ax_t.plot(
            s / 1000,
            t - obs.time_s.min(),
            color="tab:blue",
            lw=1.2,
            ls="--",
            label="simulated (calibrated)" if k == 0 else None,
        )
    s_all = np.linspace(obs.legs[0][0], obs.legs[-1][1], 3000)
    ax_v.plot(
        s_all / 1000,
        np.asarray(track.speed_limit_at(s_all)) / KMH,
        color="tab:blue",
        ls=":",
        lw=1,
        label="static limit",
    )
    theta = result.params["theta_cruise"]
    ax_v.plot(
        s_all / 1000,
        theta * np.asarray(track.speed_limit_at(s_all)) / KMH,
        color="grey",
        ls=":",
        lw=0.8,
        label=f"theta x limit ({theta:.2f})",
    )
    ax_g = ax_v.twinx()
    ax_g.fill_between(s_all / 1000, 1000 * track.gradient(s_all), color="tab:cyan", alpha=0.25, step="post")
    ax_g.set_ylabel("gradient (permille)")
    ax_v.set_ylabel("speed (km/h)")
    ax_v.legend(loc="upper center", fontsize=8, ncol=3)
    occ = obs.kind == "occupy"
    ax_t.plot(
        obs.position_m[occ] / 1000,
        obs.time_s[occ] - obs.time_s.min(),
        "o",
        mfc="none",
        color="k",
        label="observed occupation",
    )
    if np.any(~occ):
        ax_t.plot(
            obs.position_m[~occ] / 1000,
            obs.time_s[~occ] - obs.time_s.min(),
            "s",
            mfc="none",
            color="grey",
            label="observed release (head position)",
        )
    if ev is not None:
        ax_r = ax_t.twinx()
        ax_r.bar(obs.position_m / 1000, ev.residual_s, width=0.05, color="tab:red", alpha=0.5)
        lim = max(2.0, float(np.nanmax(np.abs(ev.residual_s))) * 1.2)
        ax_r.set_ylim(-lim * 4, lim)
        ax_r.set_ylabel("residual (s)", color="tab:red")
    ax_t.set_xlabel("distance (km)")
    ax_t.set_ylabel("time (s)")
    ax_t.legend(loc="upper left", fontsize=8)
    p = result.params
    fig.suptitle(
        f"{result.run_id} ({result.composition}): objective {result.objective_s:.1f} s over {result.n_observations} "
        f"passages\nc0 {p['c0']:.3f} N/kg, c2 {p['c2']:.2f} W/kg, r0 {p['r0']:.4f}, r2 {p['r2']:.3g}, "
        f"b_limit {p['b_limit']:.2f} m/s2, theta {p['theta_cruise']:.3f}",
        fontsize=10,
    )
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def distribution_figure(
    path: Path,
    composition: str,
    results: Sequence[CalibrationResult],
    fits: Mapping[str, Sequence[FitResult]],
    defaults: Mapping[str, float] | None = None,
) -> Path:
    """Figs. 7-9: histograms with the best-fitting density per parameter."""
    fig, axes = plt.subplots(2, 3, figsize=(13, 7))
    for ax, name in zip(axes.ravel(), DECISION_NAMES):
        x = np.array([r.params[name] for r in results])
        ax.hist(x, bins=max(5, min(20, x.size // 3)), density=True, color="lightsteelblue", edgecolor="steelblue")
        ranked = fits.get(name, [])
        if ranked and ranked[0].ok:
            best = ranked[0]
            grid = np.linspace(x.min() - 0.1 * np.ptp(x), x.max() + 0.1 * np.ptp(x), 400)
            ax.plot(grid, best.frozen.pdf(grid), color="tab:red", lw=1.5)
            params = ", ".join(f"{k}={v:.3g}" for k, v in best.params.items())
            ax.set_title(f"{name}: {best.name}\n{params}\nKS {best.ks_statistic:.3f}, p {best.p_value:.2f}", fontsize=8)
        else:
            ax.set_title(f"{name}: no fit", fontsize=8)
        if defaults and name in defaults:
            ax.axvline(defaults[name], color="gold", lw=2, label="default")
            ax.legend(fontsize=7)
        ax.set_xlabel(f"{name} ({UNITS[name]})")
    fig.suptitle(f"{composition}: {len(results)} calibrated runs", fontsize=11)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def length_figure(path: Path, lengths: Mapping[float, Sequence[LengthEstimate]], types: TrainTypes) -> Path:
    """Fig. 6: length intervals per run for each delta."""
    deltas = sorted(lengths)
    fig, axes = plt.subplots(1, len(deltas), figsize=(5 * len(deltas), 6), sharey=True)
    axes = np.atleast_1d(axes)
    colour = {name: COLOURS[i % len(COLOURS)] for i, name in enumerate(types.names)}
    for ax, delta in zip(axes, deltas):
        for y, e in enumerate(lengths[delta]):
            c = colour.get(e.composition, "lightgrey")
            if e.high_m > e.low_m:
                ax.plot([e.low_m, e.high_m], [y, y], color=c, lw=1.2)
            ax.plot([e.length_m], [y], "|", color=c, ms=5)
        for name, length in types.lengths().items():
            ax.axvline(length, color=colour[name], ls="--", lw=1, label=f"{name} {length:g} m")
        assigned = sum(e.composition is not None for e in lengths[delta])
        ax.set_title(f"delta = {delta:g} s: {assigned}/{len(lengths[delta])} assigned", fontsize=10)
        ax.set_xlabel("train length (m)")
    axes[0].set_ylabel("run")
    axes[0].legend(fontsize=8, loc="lower right")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def ranges_figure(path: Path, results_by_comp: Mapping[str, Sequence[CalibrationResult]], types: TrainTypes) -> Path:
    """Fig. 10: calibrated ranges (min-max, quartiles, median) per composition, defaults as yellow dots."""
    fig, axes = plt.subplots(2, 3, figsize=(13, 7))
    comps = [c for c in types.names if results_by_comp.get(c)]
    for ax, name in zip(axes.ravel(), DECISION_NAMES):
        for i, comp in enumerate(comps):
            x = np.array([r.params[name] for r in results_by_comp[comp]])
            q1, med, q3 = np.percentile(x, [25, 50, 75])
            ax.plot([i, i], [x.min(), x.max()], color="k", lw=1)
            ax.plot([i, i], [q1, q3], color="steelblue", lw=6, solid_capstyle="butt")
            ax.plot([i], [med], "_", color="white", ms=10)
            ax.plot([i], [types[comp].defaults[name]], "o", color="gold", mec="k", ms=7)
        ax.set_xticks(range(len(comps)), comps, fontsize=8)
        ax.set_title(f"{name} ({UNITS[name]})", fontsize=9)
        ax.set_xlim(-0.5, len(comps) - 0.5)
    fig.suptitle("Calibrated parameters per composition (bars: quartiles, lines: range, dots: defaults)", fontsize=11)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path
