"""report.png of a replay: the layout of Cunillera et al. (2022), Fig. 3 and Fig. 6 (matplotlib, Agg; no ROS).

Panels, against time since the first measurement:

1. speed: measured (dots) and filtered (line) coloured by driving regime (Fig. 6: traction black,
   cruising blue, coasting purple, braking red; standing grey), with the static speed limit;
2. acceleration with the maximum service deceleration (dashed);
3. applied effort u = f_t - f_b with the tractive envelope f_t,max(v) and the brake limit (dashed);
4-6. r0, r1, r2: the estimate (red) with its +-2 sigma band, the manufacturer value (blue dashed) and,
   when known, the simulated truth (green dotted);
7. r(v) against speed, the identifiable quantity: the train file's curve with its prior +-2 sigma, the on-board
   estimate of the last message and the whole run's best estimate (coast regression) each with +-2 sigma, the
   truth when known, and the speeds at which the run coasted (the stretches the regression used).

Run boundaries are marked with thin vertical lines; the title names the configuration.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .summary import COEFFS, UNITS, Outputs
from .train import TrainSpec

REGIME_COLOURS = {0: "0.6", 1: "black", 2: "tab:blue", 3: "purple", 4: "red"}
REGIME_LABELS = {0: "standing / unknown", 1: "traction", 2: "cruising", 3: "coasting", 4: "braking"}


def _minutes(t: np.ndarray) -> np.ndarray:
    return np.asarray(t, dtype=float) / 60.0


def write_report(
    path: str | Path,
    outputs: Outputs,
    train: TrainSpec,
    *,
    truth: dict[str, float] | None = None,
    title: str = "",
    best: dict | None = None,
    configuration: str = "",
) -> Path:
    """Draw the report to `path` (PNG); ``best``: summary.json's whole-run estimate; ``configuration``: the UKF
    preset that ran (in the title)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.collections import LineCollection

    est, meas, reg = outputs.est, outputs.meas, outputs.regime
    fig = plt.figure(figsize=(11, 18.5))
    grid = fig.add_gridspec(7, 1, height_ratios=[2.2, 1, 1.4, 1, 1, 1, 2.0], hspace=0.35)
    ax_v = fig.add_subplot(grid[0])
    axes = [ax_v] + [fig.add_subplot(grid[i], sharex=ax_v) for i in range(1, 6)]
    ax_rv = fig.add_subplot(grid[6])
    ax_v, ax_a, ax_u, *ax_r = axes
    if configuration:
        title = f"{title or 'UKF running-resistance estimation'} [ukf preset {configuration}]"
    if not est:
        ax_v.text(0.5, 0.5, "no estimates were published", ha="center", va="center", transform=ax_v.transAxes)
        fig.savefig(path, dpi=100)
        plt.close(fig)
        return Path(path)
    t = _minutes(est["t"])

    # 1. speed coloured by regime (Fig. 6) with the measured speed and the limit
    if meas:
        ax_v.plot(_minutes(meas["t"]), meas["v"] * 3.6, ".", ms=2.5, color="tab:orange", label="measured", zorder=1)
        ax_v.step(_minutes(meas["t"]), meas["speed_limit"] * 3.6, where="post", color="0.75", lw=1, ls="--",
                  label="speed limit")  # fmt: skip
    if reg and len(reg["t"]) > 1:
        tr, vr = _minutes(reg["t"]), est["v"] * 3.6 if len(est["v"]) == len(reg["t"]) else reg["v"] * 3.6
        segments = np.stack([np.column_stack([tr[:-1], vr[:-1]]), np.column_stack([tr[1:], vr[1:]])], axis=1)
        colours = [REGIME_COLOURS.get(int(r), "0.6") for r in reg["regime"][1:]]
        ax_v.add_collection(LineCollection(segments, colors=colours, linewidths=1.8, zorder=2))
        for r, colour in REGIME_COLOURS.items():
            ax_v.plot([], [], color=colour, lw=2, label=REGIME_LABELS[r])
    else:
        ax_v.plot(t, est["v"] * 3.6, color="red", lw=1.2, label="filtered")
    ax_v.set_ylabel("speed (km/h)")
    ax_v.set_ylim(bottom=0)
    ax_v.legend(loc="upper right", fontsize=7, ncol=4)
    ax_v.set_title(title or "UKF running-resistance estimation (layout of Cunillera et al. 2022, Fig. 3 and 6)")

    # 2. acceleration with the maximum service deceleration
    ax_a.plot(t, est["acceleration"], color="red", lw=0.9)
    ax_a.axhline(-train.max_brake_decel, color="k", ls="--", lw=0.9, label=f"-{train.max_brake_decel:g} m/s^2")
    ax_a.axhline(0.0, color="0.8", lw=0.6)
    ax_a.set_ylabel("acceleration\n(m/s^2)")
    ax_a.legend(loc="lower right", fontsize=7)

    # 3. effort with the tractive envelope and the brake limit
    v_sorted = np.asarray(est["v"], dtype=float)
    envelope = np.asarray(train.tractive_envelope(np.maximum(v_sorted, 0.01)), dtype=float)
    ax_u.plot(t, est["effort"], color="red", lw=0.9, label="applied effort u")
    ax_u.plot(t, envelope, color="k", ls="--", lw=0.9, label="max tractive effort f_t,max(v)")
    ax_u.axhline(-train.max_brake_decel, color="k", ls=":", lw=0.9, label="max brake effort")
    known = np.asarray(est["effort_known"], dtype=bool)
    if known.any():
        ax_u.plot(t[known], np.asarray(est["effort"])[known], "o", ms=2, color="tab:green", label="effort known")
    ax_u.set_ylabel("effort (N/kg)")
    ax_u.legend(loc="upper right", fontsize=7, ncol=2)

    # 4-6. resistance coefficients with +-2 sigma, manufacturer and truth
    for ax, c in zip(ax_r, COEFFS):
        value, std = np.asarray(est[c], dtype=float), np.asarray(est[f"std_{c}"], dtype=float)
        ax.fill_between(t, value - 2 * std, value + 2 * std, color="red", alpha=0.18, lw=0, label="+-2 sigma")
        ax.plot(t, value, color="red", lw=1.1, label="UKF estimate")
        ax.axhline(getattr(train.davis, c), color="tab:blue", ls="--", lw=1, label="manufacturer")
        if truth and c in truth:
            ax.axhline(truth[c], color="tab:green", ls=":", lw=1.4, label="simulated truth")
        ax.set_ylabel(f"{c}\n({UNITS[c]})", fontsize=8)
        ax.ticklabel_format(axis="y", style="sci", scilimits=(-3, 3))
        ax.legend(loc="upper right", fontsize=7, ncol=4)

    # run boundaries
    runs = np.asarray(est["run_id"])
    for i in np.flatnonzero(np.diff(runs) != 0) + 1:
        for ax in axes:
            ax.axvline(t[i], color="0.5", lw=0.6, ls="-.")
    for ax in axes:
        ax.grid(alpha=0.25)
    axes[-1].set_xlabel("time since the first measurement (min)")
    _resistance_curve(ax_rv, outputs, train, truth, best)
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return Path(path)


def _band(ax, v_kmh: np.ndarray, r: np.ndarray, cov: np.ndarray, colour: str, label: str, ls: str = "-") -> None:
    """r(v) = r0 + r1 v + r2 v^2 with its +-2 sigma band (v in km/h on the axis, N/kg)."""
    v = v_kmh / 3.6
    h = np.stack([np.ones_like(v), v, v * v], axis=1)
    mean = h @ r
    sigma = np.sqrt(np.maximum(np.einsum("ij,jk,ik->i", h, cov, h), 0.0))
    ax.fill_between(v_kmh, mean - 2 * sigma, mean + 2 * sigma, color=colour, alpha=0.15, lw=0)
    ax.plot(v_kmh, mean, color=colour, ls=ls, lw=1.3, label=label)


def _resistance_curve(ax, outputs: Outputs, train: TrainSpec, truth: dict | None, best: dict | None) -> None:
    """Panel 7: r(v) against speed (module docstring)."""
    from .estimation.coast_regression import prior_covariance

    est = outputs.est
    v_top = max(float(np.max(outputs.meas["v"])) * 3.6 if outputs.meas else 0.0, 40.0)
    v_kmh = np.linspace(0.0, 1.05 * v_top, 120)
    prior = np.array(train.davis.as_tuple())
    _band(ax, v_kmh, prior, prior_covariance(prior, 0.18, 0.10), "tab:blue", "train file (prior +-2 sigma)", "--")
    if outputs.last_r_covariance is not None:
        final = np.array([est[c][-1] for c in COEFFS], dtype=float)
        _band(ax, v_kmh, final, outputs.last_r_covariance, "red", "on board, last message (+-2 sigma)")
    if best:
        _band(ax, v_kmh, np.array([best[c] for c in COEFFS]), np.asarray(best["covariance"]), "tab:purple",
              f"whole run, {best.get('coasting_stretches', 0)} coasting stretches (+-2 sigma)", "-.")  # fmt: skip
    if truth and all(c in truth for c in COEFFS):
        v = v_kmh / 3.6
        ax.plot(v_kmh, truth["r0"] + truth["r1"] * v + truth["r2"] * v * v, color="tab:green", ls=":", lw=1.6,
                label="simulated truth")  # fmt: skip
    ax.set_xlabel("speed (km/h)")
    ax.set_ylabel("r(v) (N/kg)")
    ax.set_xlim(0.0, v_kmh[-1])
    ax.set_ylim(bottom=0.0)
    ax.grid(alpha=0.25)
    ax.legend(loc="upper left", fontsize=7)


__all__ = ["REGIME_COLOURS", "write_report"]
