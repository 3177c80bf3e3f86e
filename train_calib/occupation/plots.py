"""Figures of the occupation calibration (matplotlib, Agg), in the layout of Besinovic et al. (2013).

- :func:`run_figure`: one run, Fig. 5: calibrated speed profile with the static limit and the
  gradient, and the time-distance trajectory, observed passages as circles over the simulated line.
- :func:`distribution_figure`: one composition, Figs. 7-9: histogram of each calibrated parameter
  with the density of the best-fitting distribution, its parameters, KS statistic and p-value.
- :func:`length_figure`: Fig. 6: the length interval of every run for each delta, coloured by the
  composition assigned, with the composition lengths.
- :func:`ranges_figure`: Fig. 10: calibrated ranges per composition with the defaults and the search bounds.

With the simulated truth (truth.csv), the distributions and the ranges show the true values of the same runs.
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


def true_values(
    results: Sequence[CalibrationResult], truth: Mapping[str, Mapping[str, float | str]] | None, name: str
) -> np.ndarray:
    """The true ``name`` of each of ``results``' runs that truth.csv has (finite values only; empty without truth)."""
    if not truth:
        return np.zeros(0)
    values = [truth[r.run_id].get(name, np.nan) for r in results if r.run_id in truth]
    x = np.array([v for v in values if isinstance(v, (int, float))], dtype=float)
    return x[np.isfinite(x)]


def build_distribution_figure(
    composition: str,
    results: Sequence[CalibrationResult],
    fits: Mapping[str, Sequence[FitResult]],
    defaults: Mapping[str, float] | None = None,
    truth: Mapping[str, Mapping[str, float | str]] | None = None,
):
    """Figs. 7-9 for one composition: per calibrated parameter the histogram of the runs' values (density, 1/unit)
    with the best-fitting density, the default (gold) and, with ``truth`` (truth.csv by run id), the true values of
    the same runs (green step histogram) and their median (green dashed line). Returns (figure, 2x3 axes)."""
    fig, axes = plt.subplots(2, 3, figsize=(13, 7.5))
    for ax, name in zip(axes.ravel(), DECISION_NAMES):
        x = np.array([r.params[name] for r in results])
        bins = np.histogram_bin_edges(x, bins=max(5, min(20, x.size // 3)))
        ax.hist(x, bins=bins, density=True, color="lightsteelblue", edgecolor="steelblue", label="calibrated runs")
        ranked = fits.get(name, [])
        if ranked and ranked[0].ok:
            best = ranked[0]
            grid = np.linspace(x.min() - 0.1 * np.ptp(x), x.max() + 0.1 * np.ptp(x), 400)
            ax.plot(grid, best.frozen.pdf(grid), color="tab:red", lw=1.5, label=f"fit: {best.name}")
            params = ", ".join(f"{k}={v:.3g}" for k, v in best.params.items())
            ax.set_title(f"{name}: {best.name}\n{params}\nKS {best.ks_statistic:.3f}, p {best.p_value:.2f}", fontsize=8)
        else:
            ax.set_title(f"{name}: no fit", fontsize=8)
        if defaults and name in defaults:
            ax.axvline(defaults[name], color="gold", lw=2, label="default")
        true = true_values(results, truth, name)
        if true.size:
            spread = np.ptp(true) > 0
            if spread:
                inside = true.min() >= bins[0] and true.max() <= bins[-1]
                ax.hist(true, bins=bins if inside else 10, density=True, histtype="step", color="tab:green", lw=1.3,
                        label=f"truth ({true.size} runs)", gid="truth")  # fmt: skip
            ax.axvline(float(np.median(true)), color="tab:green", ls="--", lw=1.5, gid="truth_median",
                       label="true median" if spread else f"truth ({true.size} runs)")  # fmt: skip
        ax.set_xlabel(f"{name} ({UNITS[name]})")
        ax.set_ylabel(f"density (1/({UNITS[name]}))" if UNITS[name] != "-" else "density")
        ax.legend(fontsize=6, loc="upper left", bbox_to_anchor=(0.0, -0.2), ncol=2, framealpha=0.9)
    title = f"{composition}: {len(results)} calibrated runs"
    fig.suptitle(title + (" (green: simulated truth)" if truth else ""), fontsize=11)
    fig.tight_layout()
    return fig, axes


def distribution_figure(
    path: Path,
    composition: str,
    results: Sequence[CalibrationResult],
    fits: Mapping[str, Sequence[FitResult]],
    defaults: Mapping[str, float] | None = None,
    truth: Mapping[str, Mapping[str, float | str]] | None = None,
) -> Path:
    """Figs. 7-9: histograms with the best-fitting density per parameter (``build_distribution_figure``)."""
    fig, _ = build_distribution_figure(composition, results, fits, defaults, truth)
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


def build_ranges_figure(
    results_by_comp: Mapping[str, Sequence[CalibrationResult]],
    types: TrainTypes,
    truth: Mapping[str, Mapping[str, float | str]] | None = None,
):
    """Fig. 10: per parameter and composition the calibrated range (line: min-max, bar: quartiles, white: median),
    the default (gold dot), the search bounds of the calibration (red bracket ends, the composition's ``bounds``)
    and, with ``truth``, the true values' range of the same runs (green, beside the bar, dot at the median).
    The y axis is the parameter in its unit. Returns (figure, 2x3 axes)."""
    from matplotlib.lines import Line2D

    fig, axes = plt.subplots(2, 3, figsize=(13, 7.5))
    comps = [c for c in types.names if results_by_comp.get(c)]
    for ax, name in zip(axes.ravel(), DECISION_NAMES):
        for i, comp in enumerate(comps):
            x = np.array([r.params[name] for r in results_by_comp[comp]])
            q1, med, q3 = np.percentile(x, [25, 50, 75])
            ax.plot([i, i], [x.min(), x.max()], color="k", lw=1)
            ax.plot([i, i], [q1, q3], color="steelblue", lw=6, solid_capstyle="butt")
            ax.plot([i], [med], "_", color="white", ms=10)
            ax.plot([i], [types[comp].defaults[name]], "o", color="gold", mec="k", ms=7)
            low, high = types[comp].bounds[name]
            ax.plot([i - 0.3, i + 0.3], [low, low], color="tab:red", lw=1.5, gid="bound")
            ax.plot([i - 0.3, i + 0.3], [high, high], color="tab:red", lw=1.5, gid="bound")
            true = true_values(results_by_comp[comp], truth, name)
            if true.size:
                ax.plot([i + 0.18, i + 0.18], [true.min(), true.max()], color="tab:green", lw=3, gid="truth")
                ax.plot([i + 0.18], [float(np.median(true))], "o", color="tab:green", mec="k", ms=5)
        ax.set_xticks(range(len(comps)), comps, fontsize=8)
        ax.set_title(name, fontsize=9)
        ax.set_ylabel(f"{name} ({UNITS[name]})", fontsize=8)
        ax.set_xlim(-0.5, len(comps) - 0.5)
    handles = [
        Line2D([], [], color="k", lw=1, label="calibrated range"),
        Line2D([], [], color="steelblue", lw=6, label="quartiles"),
        Line2D([], [], marker="o", color="gold", mec="k", ls="", label="default"),
        Line2D([], [], color="tab:red", lw=1.5, label="search bounds"),
    ]
    if truth:
        handles.append(Line2D([], [], color="tab:green", lw=3, marker="o", mec="k", label="truth: range, median"))
    fig.suptitle("Calibrated parameters per composition (Fig. 10)", fontsize=11)
    fig.legend(handles=handles, loc="lower center", ncol=len(handles), fontsize=8, frameon=False)
    fig.tight_layout(rect=(0, 0.05, 1, 1))
    return fig, axes


def ranges_figure(
    path: Path,
    results_by_comp: Mapping[str, Sequence[CalibrationResult]],
    types: TrainTypes,
    truth: Mapping[str, Mapping[str, float | str]] | None = None,
) -> Path:
    """Fig. 10 (``build_ranges_figure``) to ``path``."""
    fig, _ = build_ranges_figure(results_by_comp, types, truth)
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path
