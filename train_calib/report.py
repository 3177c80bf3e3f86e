"""report.png of a replay: the layout of Cunillera et al. (2022), Fig. 3 and Fig. 6 (matplotlib, Agg; no ROS).

Panels, against time since the first measurement:

1. speed: measured (dots) and filtered (line) coloured by driving regime (Fig. 6: traction black,
   cruising blue, coasting purple, braking red; standing grey), with the static speed limit;
2. acceleration with the maximum service deceleration (dashed);
3. applied effort u = f_t - f_b with the tractive envelope f_t,max(v) and the brake limit (dashed);
4-6. r0, r1, r2: the estimate (red) with its +-2 sigma band, the manufacturer value (blue dashed) and,
   when known, the simulated truth (green dotted).

Run boundaries are marked with thin vertical lines.
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
) -> Path:
    """Draw the report to `path` (PNG)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.collections import LineCollection

    est, meas, reg = outputs.est, outputs.meas, outputs.regime
    fig, axes = plt.subplots(6, 1, figsize=(11, 15), sharex=True, gridspec_kw={"height_ratios": [2.2, 1, 1.4, 1, 1, 1]})
    ax_v, ax_a, ax_u, *ax_r = axes
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
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return Path(path)


__all__ = ["REGIME_COLOURS", "write_report"]
