"""report.png of a replay: the layout of Cunillera et al. (2022), Fig. 3 and Fig. 6 (matplotlib, Agg; no ROS).

Panels against time since the first measurement (min), sharing their time axis:

1. speed: measured (dots) and filtered (line) coloured by driving regime (Fig. 6: traction black,
   cruising blue, coasting purple, braking red; standing grey), with the static speed limit;
2. acceleration with the maximum service deceleration (dashed);
3. applied effort u = f_t - f_b with the tractive envelope f_t,max(v) and the brake limit (dashed);
4. pantograph power (MW): consumed, regenerated negative; only when the bag has traction power;
5-7. r0, r1, r2: the estimate (red) with its +-2 sigma band, the manufacturer value (blue dashed), the
   well-posed windows' fits (orange dots, with power) and, when known, the simulated truth (green dotted);

then, against position s (km):

8. the track profile: the gradient (per mille, step line, from the track file) and the measured track force
   g(s) over the train length expressed in per mille (g / 9.81 * 1000, dots: gradient plus curves);

and against speed (km/h):

9. r(v), the identifiable quantity: the train file's curve with its prior +-2 sigma, the on-board estimate of
   the last message and the whole run's best estimate (coast regression) each with +-2 sigma, with power
   each window's resistance at its mean speed (+-2 sigma bars) and the windows pooled into r(v) (+-2 sigma),
   and the truth when known.

Tunnels are shaded grey and GNSS gaps (measurements whose position was predicted, ``s_measured`` false: no
usable fix) shaded orange on the time panels and on the profile; run boundaries are thin vertical lines. Every
legend sits outside its axes, right of the plot, so that none covers data. The title names the configuration.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .summary_outputs import COEFFS, UNITS, Outputs
from .track import Track
from .train import TrainSpec

REGIME_COLOURS = {0: "0.6", 1: "black", 2: "tab:blue", 3: "purple", 4: "red"}
REGIME_LABELS = {0: "standing / unknown", 1: "traction", 2: "cruising", 3: "coasting", 4: "braking"}
TUNNEL_COLOUR = "0.55"
GAP_COLOUR = "tab:orange"
GAP_STYLE = {"facecolor": "none", "edgecolor": GAP_COLOUR, "hatch": "////", "lw": 0.0, "zorder": 0}  # over tunnels
WINDOW_COLOUR = "tab:orange"
G_MS2 = 9.81  # m/s^2, converts the track force g(s) (N/kg) to an equivalent gradient
LEGEND = {"loc": "upper left", "bbox_to_anchor": (1.01, 1.0), "borderaxespad": 0.0, "fontsize": 7, "framealpha": 0.9}


@dataclass
class ReportFigure:
    """The report's figure and its axes by name (``speed``, ``acceleration``, ``effort``, ``power`` (None without
    traction power), ``r0``, ``r1``, ``r2``, ``profile``, ``rv``), with the spans it shaded (for tests and callers):
    ``tunnel_spans_min`` / ``gap_spans_min`` on the time axis (min), ``tunnel_spans_km`` / ``gap_spans_km`` on the
    profile (km)."""

    fig: Any
    axes: dict[str, Any]
    tunnel_spans_min: list[tuple[float, float]] = field(default_factory=list)
    gap_spans_min: list[tuple[float, float]] = field(default_factory=list)
    tunnel_spans_km: list[tuple[float, float]] = field(default_factory=list)
    gap_spans_km: list[tuple[float, float]] = field(default_factory=list)


def _plural(n: int, noun: str, suffix: str = "s") -> str:
    return f"{n} {noun}{'' if n == 1 else suffix}"


def _minutes(t: np.ndarray) -> np.ndarray:
    return np.asarray(t, dtype=float) / 60.0


def flag_spans(x: np.ndarray, flag: np.ndarray) -> list[tuple[float, float]]:
    """The spans of ``x`` over which ``flag`` holds: each run of consecutive flagged samples from the last
    unflagged sample before it to the first one after it (the interval without, e.g., a fix), in x's units."""
    x, flag = np.asarray(x, dtype=float), np.asarray(flag, dtype=bool)
    if x.size == 0 or not flag.any():
        return []
    edges = np.diff(np.concatenate(([0], flag.astype(np.int8), [0])))
    starts, ends = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1) - 1
    last = x.size - 1
    return [(float(x[max(a - 1, 0)]), float(x[min(b + 1, last)])) for a, b in zip(starts, ends)]


def tunnel_time_spans(
    t_s: np.ndarray, s_m: np.ndarray, run_id: np.ndarray, track: Track, train_length_m: float = 0.0
) -> list[tuple[float, float]]:
    """When the train (head at s) was partly in each tunnel, per run: [(t_in, t_out)] in s, interpolated on the
    run's position s(t) (m; made monotone in the run's direction), so a tunnel shorter than the sampling interval
    still gets its span. A tunnel the run does not reach gives none."""
    t_s, s_m, run_id = (np.asarray(a) for a in (t_s, s_m, run_id))
    spans: list[tuple[float, float]] = []
    for run in np.unique(run_id):
        sel = run_id == run
        t, s = t_s[sel].astype(float), s_m[sel].astype(float)
        if t.size < 2 or s[-1] == s[0]:
            continue
        sign = 1.0 if s[-1] > s[0] else -1.0
        s_dir = np.maximum.accumulate(sign * s)  # increasing along the run's direction
        for tunnel in track.tunnels:
            if sign > 0:  # head in at the start .. tail out a train length past the end
                enter, leave = tunnel.start_m, tunnel.end_m + train_length_m
            else:
                enter, leave = -tunnel.end_m, -(tunnel.start_m - train_length_m)
            if leave < s_dir[0] or enter > s_dir[-1]:
                continue
            spans.append((float(np.interp(enter, s_dir, t)), float(np.interp(leave, s_dir, t))))
    return sorted(spans)


def _tunnel_spans_from_measurements(meas: dict[str, np.ndarray]) -> list[tuple[float, float]]:
    """Without the track: the spans in which the measurements' tunnel fraction is positive (s)."""
    inside = np.asarray(meas["tunnel_fraction"], dtype=float) > 0.0
    return flag_spans(np.asarray(meas["t"], dtype=float), inside)


def build_report(
    outputs: Outputs,
    train: TrainSpec,
    *,
    track: Track | None = None,
    truth: dict[str, float] | None = None,
    title: str = "",
    best: dict | None = None,
    configuration: str = "",
) -> ReportFigure:
    """The report's figure (module docstring) without saving it. ``track``: the track file the replay ran on (its
    gradients and tunnels; without it the profile and the tunnels come from the measurements' g(s) and tunnel
    fraction); ``best``: summary.json's whole-run estimate; ``configuration``: the UKF preset (in the title)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    est, meas = outputs.est, outputs.meas
    has_power = bool(meas) and bool(np.any(meas.get("power_valid", np.zeros(0, dtype=bool))))
    time_rows = ["speed", "acceleration", "effort"] + (["power"] if has_power else []) + list(COEFFS)
    heights = {"speed": 2.2, "acceleration": 1.0, "effort": 1.4, "power": 1.2, "r0": 1.0, "r1": 1.0, "r2": 1.0}
    rows = [*time_rows, "gap1", "profile", "gap2", "rv"]
    ratios = [heights.get(r, 0.12 if r.startswith("gap") else 1.5 if r == "profile" else 2.3) for r in rows]
    fig = plt.figure(figsize=(13.5, 1.65 * sum(ratios)))
    grid = fig.add_gridspec(len(rows), 1, height_ratios=ratios, hspace=0.3)
    fig.subplots_adjust(left=0.08, right=0.72, top=1.0 - 0.45 / fig.get_figheight(), bottom=0.5 / fig.get_figheight())
    axes: dict[str, Any] = {}
    first = fig.add_subplot(grid[0])
    for i, name in enumerate(rows):
        if name.startswith("gap"):
            continue
        if name in time_rows:
            axes[name] = first if i == 0 else fig.add_subplot(grid[i], sharex=first)
        else:
            axes[name] = fig.add_subplot(grid[i])
    axes.setdefault("power", None)
    report = ReportFigure(fig, axes)
    if configuration:
        title = f"{title or 'UKF running-resistance estimation'} [ukf preset {configuration}]"
    default_title = "UKF running-resistance estimation (layout of Cunillera et al. 2022, Fig. 3 and 6)"
    axes["speed"].set_title(title or default_title, loc="left", fontsize=10)
    if not est:
        axes["speed"].text(0.5, 0.5, "no estimates were published", ha="center", va="center",
                           transform=axes["speed"].transAxes)  # fmt: skip
        return report
    t = _minutes(est["t"])
    _spans(report, outputs, train, track)
    time_axes = [axes[name] for name in time_rows]
    for a, b in report.tunnel_spans_min:
        for ax in time_axes:
            ax.axvspan(a, b, color=TUNNEL_COLOUR, alpha=0.22, lw=0, zorder=0, gid="tunnel")
    for a, b in report.gap_spans_min:
        for ax in time_axes:
            ax.axvspan(a, b, gid="gnss_gap", **GAP_STYLE)
    _speed_panel(axes["speed"], outputs, t, report)
    _dynamics_panels(axes["acceleration"], axes["effort"], est, t, train)
    if axes["power"] is not None:
        _power_panel(axes["power"], meas)
    _coefficient_panels([axes[c] for c in COEFFS], outputs, t, train, truth)
    runs = np.asarray(est["run_id"])
    for i in np.flatnonzero(np.diff(runs) != 0) + 1:
        for ax in time_axes:
            ax.axvline(t[i], color="0.5", lw=0.6, ls="-.")
    for ax in time_axes:
        ax.grid(alpha=0.25)
        if ax is not time_axes[-1]:
            ax.tick_params(labelbottom=False)
    time_axes[-1].set_xlabel("time since the first measurement (min)")
    _profile_panel(axes["profile"], outputs, train, track, report)
    _resistance_curve(axes["rv"], outputs, train, truth, best)
    return report


def write_report(
    path: str | Path,
    outputs: Outputs,
    train: TrainSpec,
    *,
    track: Track | None = None,
    truth: dict[str, float] | None = None,
    title: str = "",
    best: dict | None = None,
    configuration: str = "",
) -> Path:
    """Draw the report (``build_report``) to ``path`` (PNG, 100 dpi)."""
    import matplotlib.pyplot as plt

    report = build_report(outputs, train, track=track, truth=truth, title=title, best=best, configuration=configuration)
    report.fig.savefig(path, dpi=100)
    plt.close(report.fig)
    return Path(path)


def _spans(report: ReportFigure, outputs: Outputs, train: TrainSpec, track: Track | None) -> None:
    """Tunnel and GNSS-gap spans in time (min) and along s (km) into ``report``."""
    meas = outputs.meas
    if not meas:
        return
    t_s, s_m = np.asarray(meas["t"], dtype=float), np.asarray(meas["s"], dtype=float)
    if track is not None:
        spans = tunnel_time_spans(t_s, s_m, meas["run_id"], track, train.length_m)
        report.tunnel_spans_km = [(tn.start_m / 1000.0, tn.end_m / 1000.0) for tn in track.tunnels]
    else:
        spans = _tunnel_spans_from_measurements(meas)
        report.tunnel_spans_km = [(a / 1000.0, b / 1000.0) for a, b in flag_spans(s_m, meas["tunnel_fraction"] > 0)]
    report.tunnel_spans_min = [(a / 60.0, b / 60.0) for a, b in spans]
    unmeasured = ~np.asarray(meas["s_measured"], dtype=bool)
    report.gap_spans_min = [(a / 60.0, b / 60.0) for a, b in flag_spans(t_s, unmeasured)]
    report.gap_spans_km = [(min(a, b) / 1000.0, max(a, b) / 1000.0) for a, b in flag_spans(s_m, unmeasured)]


def _speed_panel(ax, outputs: Outputs, t: np.ndarray, report: ReportFigure) -> None:
    """Panel 1: speed coloured by regime (Fig. 6) with the measured speed, the limit, tunnels and gaps."""
    from matplotlib.collections import LineCollection
    from matplotlib.patches import Patch

    est, meas, reg = outputs.est, outputs.meas, outputs.regime
    if meas:
        ax.plot(_minutes(meas["t"]), meas["v"] * 3.6, ".", ms=2.5, color="tab:orange", label="measured", zorder=1)
        ax.step(_minutes(meas["t"]), meas["speed_limit"] * 3.6, where="post", color="0.75", lw=1, ls="--",
                label="speed limit")  # fmt: skip
    if reg and len(reg["t"]) > 1:
        tr, vr = _minutes(reg["t"]), est["v"] * 3.6 if len(est["v"]) == len(reg["t"]) else reg["v"] * 3.6
        segments = np.stack([np.column_stack([tr[:-1], vr[:-1]]), np.column_stack([tr[1:], vr[1:]])], axis=1)
        colours = [REGIME_COLOURS.get(int(r), "0.6") for r in reg["regime"][1:]]
        ax.add_collection(LineCollection(segments, colors=colours, linewidths=1.8, zorder=2))
        for r, colour in REGIME_COLOURS.items():
            ax.plot([], [], color=colour, lw=2, label=REGIME_LABELS[r])
    else:
        ax.plot(t, est["v"] * 3.6, color="red", lw=1.2, label="filtered")
    handles, labels = ax.get_legend_handles_labels()
    handles.append(Patch(color=TUNNEL_COLOUR, alpha=0.3))
    labels.append(_plural(len(report.tunnel_spans_min), "tunnel passage"))
    handles.append(Patch(**GAP_STYLE))
    labels.append(_plural(len(report.gap_spans_min), "GNSS gap") + " (position predicted)")
    ax.set_ylabel("speed (km/h)")
    ax.set_ylim(bottom=0)
    ax.legend(handles, labels, **LEGEND)


def _dynamics_panels(ax_a, ax_u, est: dict[str, np.ndarray], t: np.ndarray, train: TrainSpec) -> None:
    """Panels 2-3: acceleration (m/s^2) and effort (N/kg) with the train's limits."""
    ax_a.plot(t, est["acceleration"], color="red", lw=0.9, label="filtered acceleration")
    brake = f"-{train.max_brake_decel:g} m/s^2 (max brake)"
    ax_a.axhline(-train.max_brake_decel, color="k", ls="--", lw=0.9, label=brake)
    ax_a.axhline(0.0, color="0.8", lw=0.6)
    ax_a.set_ylabel("acceleration\n(m/s^2)")
    ax_a.legend(**LEGEND)
    v = np.asarray(est["v"], dtype=float)
    envelope = np.asarray(train.tractive_envelope(np.maximum(v, 0.01)), dtype=float)
    ax_u.plot(t, est["effort"], color="red", lw=0.9, label="applied effort u")
    ax_u.plot(t, envelope, color="k", ls="--", lw=0.9, label="max tractive effort f_t,max(v)")
    ax_u.axhline(-train.max_brake_decel, color="k", ls=":", lw=0.9, label="max brake effort")
    known = np.asarray(est["effort_known"], dtype=bool)
    if known.any():
        ax_u.plot(t[known], np.asarray(est["effort"])[known], "o", ms=2, color="tab:green", label="effort known")
    ax_u.set_ylabel("effort (N/kg)")
    ax_u.legend(**LEGEND)


def _power_panel(ax, meas: dict[str, np.ndarray]) -> None:
    """Panel 4: pantograph power consumed and regenerated (MW, regenerated negative) of the valid samples."""
    valid = np.asarray(meas["power_valid"], dtype=bool)
    t = _minutes(meas["t"])
    consumed = np.where(valid, np.asarray(meas["power_consumed"], dtype=float), np.nan) / 1e6
    regenerated = np.where(valid, np.asarray(meas["power_regenerated"], dtype=float), np.nan) / 1e6
    ax.plot(t, consumed, color="tab:brown", lw=0.9, label="power consumed", gid="power_consumed")
    ax.plot(t, -regenerated, color="tab:cyan", lw=0.9, label="power regenerated (negative)")
    ax.axhline(0.0, color="0.8", lw=0.6)
    ax.set_ylabel("pantograph\npower (MW)")
    ax.legend(**LEGEND)


def _coefficient_panels(axes: list, outputs: Outputs, t: np.ndarray, train: TrainSpec, truth: dict | None) -> None:
    """Panels 5-7: r0, r1, r2 with +-2 sigma, manufacturer, the well-posed windows' fits and the truth."""
    est = outputs.est
    well = [w for w in outputs.windows if not w.ill_posed and all(np.isfinite(w.estimate))]
    t_window = _minutes((np.array([w.stamp_ns for w in well], dtype=np.int64) - outputs.t0_ns) * 1e-9)
    for k, (ax, c) in enumerate(zip(axes, COEFFS)):
        value, std = np.asarray(est[c], dtype=float), np.asarray(est[f"std_{c}"], dtype=float)
        ax.fill_between(t, value - 2 * std, value + 2 * std, color="red", alpha=0.18, lw=0, label="+-2 sigma")
        ax.plot(t, value, color="red", lw=1.1, label="UKF estimate")
        ax.axhline(getattr(train.davis, c), color="tab:blue", ls="--", lw=1, label="manufacturer")
        if well:
            ax.plot(t_window, [w.estimate[k] for w in well], ".", ms=2, color=WINDOW_COLOUR,
                    label=f"window fits ({len(well)} well posed)")  # fmt: skip
        if truth and c in truth:
            ax.axhline(truth[c], color="tab:green", ls=":", lw=1.4, label="simulated truth")
        ax.set_ylabel(f"{c}\n({UNITS[c]})", fontsize=8)
        ax.ticklabel_format(axis="y", style="sci", scilimits=(-3, 3))
        ax.legend(**LEGEND)


def _profile_panel(ax, outputs: Outputs, train: TrainSpec, track: Track | None, report: ReportFigure) -> None:
    """Panel 8: gradient (per mille) along s (km) with the measured g(s), tunnels and GNSS gaps."""
    meas = outputs.meas
    if track is not None:
        breaks = np.append(track.gradient.breaks, track.length_m)
        values = np.append(track.gradient.values, track.gradient.values[-1]) * 1000.0
        ax.step(breaks / 1000.0, values, where="post", color="k", lw=1.1, label=f"gradient ({track.name})")
    if meas:
        ax.plot(np.asarray(meas["s"]) / 1000.0, np.asarray(meas["track_force"]) / G_MS2 * 1000.0, ".", ms=2.5,
                color="tab:red", label="measured g(s) / 9.81 (train length,\ngradient + curves)")  # fmt: skip
    for a, b in report.tunnel_spans_km:
        ax.axvspan(a, b, color=TUNNEL_COLOUR, alpha=0.3, lw=0, zorder=0, gid="tunnel")
    for a, b in report.gap_spans_km:
        ax.axvspan(a, b, gid="gnss_gap", **GAP_STYLE)
    from matplotlib.patches import Patch

    handles, labels = ax.get_legend_handles_labels()
    handles += [Patch(color=TUNNEL_COLOUR, alpha=0.3), Patch(**GAP_STYLE)]
    labels += [f"tunnel ({len(report.tunnel_spans_km)})", "GNSS gap"]
    ax.axhline(0.0, color="0.8", lw=0.6)
    ax.set_xlabel("position s (km)")
    ax.set_ylabel("gradient\n(per mille, + uphill)")
    ax.grid(alpha=0.25)
    ax.legend(handles, labels, **LEGEND)


def _band(
    ax,
    v_kmh: np.ndarray,
    r: np.ndarray,
    cov: np.ndarray,
    colour: str,
    label: str,
    ls: Any = "-",
    gid: str | None = None,
) -> np.ndarray:
    """r(v) = r0 + r1 v + r2 v^2 with its +-2 sigma band (v in km/h on the axis, N/kg); returns the upper edge."""
    v = v_kmh / 3.6
    h = np.stack([np.ones_like(v), v, v * v], axis=1)
    mean = h @ r
    sigma = np.sqrt(np.maximum(np.einsum("ij,jk,ik->i", h, cov, h), 0.0))
    ax.fill_between(v_kmh, mean - 2 * sigma, mean + 2 * sigma, color=colour, alpha=0.15, lw=0)
    ax.plot(v_kmh, mean, color=colour, ls=ls, lw=1.3, label=label, gid=gid)
    return mean + 2 * sigma


def _resistance_curve(ax, outputs: Outputs, train: TrainSpec, truth: dict | None, best: dict | None) -> None:
    """Panel 9: r(v) against speed (module docstring)."""
    from .estimation.coast_posterior import prior_covariance

    est = outputs.est
    v_top = max(float(np.max(outputs.meas["v"])) * 3.6 if outputs.meas else 0.0, 40.0)
    v_kmh = np.linspace(0.0, 1.05 * v_top, 120)
    prior = np.array(train.davis.as_tuple())
    top = _band(ax, v_kmh, prior, prior_covariance(prior, 0.18, 0.10), "tab:blue", "train file (prior +-2 sigma)", "--")
    y_top = float(np.max(top))
    if outputs.last_r_covariance is not None:
        final = np.array([est[c][-1] for c in COEFFS], dtype=float)
        _band(ax, v_kmh, final, outputs.last_r_covariance, "red", "on board, last message (+-2 sigma)")
    if best:
        label = "whole run, " + _plural(best.get("coasting_stretches", 0), "coasting stretch", "es") + " (+-2 sigma)"
        _band(ax, v_kmh, np.array([best[c] for c in COEFFS]), np.asarray(best["covariance"]), "tab:purple", label, "-.")
    _window_estimates(ax, outputs, v_kmh)
    if truth and all(c in truth for c in COEFFS):
        v = v_kmh / 3.6
        ax.plot(v_kmh, truth["r0"] + truth["r1"] * v + truth["r2"] * v * v, color="tab:green", ls=":", lw=1.6,
                label="simulated truth")  # fmt: skip
    ax.set_xlabel("speed (km/h)")
    ax.set_ylabel("r(v) (N/kg)")
    ax.set_xlim(0.0, v_kmh[-1])
    ax.set_ylim(0.0, 1.15 * y_top)  # the prior's band: window points far off it do not squash the curves
    ax.grid(alpha=0.25)
    ax.legend(**LEGEND)


def _window_estimates(ax, outputs: Outputs, v_kmh: np.ndarray) -> None:
    """Each window's resistance at its mean speed (+-2 sigma) and the last window's pooled r(v) (+-2 sigma)."""
    points = [(w.resistance_speed, w.resistance_at_speed, w.resistance_at_speed_std) for w in outputs.windows]
    pts = np.array([p for p in points if all(np.isfinite(p))], dtype=float).reshape(-1, 3)
    if pts.size:
        ax.plot(pts[:, 0] * 3.6, pts[:, 1], ".", ms=2.5, color=WINDOW_COLOUR, alpha=0.4, zorder=1, gid="window_points",
                label=f"windows: r at their mean speed ({len(pts)})")  # fmt: skip
        step = max(1, len(pts) // 40)  # +-2 sigma bars on at most about 40 of them, spread over the run
        bars = pts[::step]
        bar_label = f"+-2 sigma (every {step}th window)" if step > 1 else "+-2 sigma"
        ax.errorbar(bars[:, 0] * 3.6, bars[:, 1], yerr=2 * bars[:, 2], fmt="none", ecolor=WINDOW_COLOUR,
                    elinewidth=0.6, alpha=0.6, zorder=1, label=bar_label)  # fmt: skip
    last = outputs.windows[-1] if outputs.windows else None
    pooled = last is not None and last.pooled_windows > 0 and all(np.isfinite(last.pooled))
    if last is not None and pooled and len(last.pooled_covariance) == 9:
        cov = np.asarray(last.pooled_covariance, dtype=float).reshape(3, 3)
        label = f"windows pooled ({last.pooled_windows} windows, +-2 sigma)"
        _band(
            ax, v_kmh, np.asarray(last.pooled, dtype=float), cov, "tab:brown", label, (0, (5, 2, 1, 2)), "window_pooled"
        )


__all__ = ["REGIME_COLOURS", "ReportFigure", "build_report", "flag_spans", "tunnel_time_spans", "write_report"]
