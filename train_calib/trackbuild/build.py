"""Build a track (the track file's mapping) from runs and an optional profile; see the package doc."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import ConfigError
from .altitude import gradients_from_altitude
from .geometry import average_runs
from .profile import align, mapped_table, read_profiles
from .runs import read_run
from .tunnels import find_tunnels


@dataclass
class BuildOptions:
    """``margin_m``: track before the first and after the last stop (m); ``spacing_m``: vertex spacing (m);
    ``grade_step_m``: segment of the altitude gradients (m); ``profile_stops``: stop positions in a CSV profile."""

    name: str
    margin_m: float = 300.0
    spacing_m: float = 25.0
    grade_step_m: float = 400.0
    profile_stops: list[float] | None = None


@dataclass
class BuiltTrack:
    """The track file's mapping, the comment lines to write above it, and what to print."""

    data: dict
    comments: list[str] = field(default_factory=list)


def build_track(bags: list[Path], profiles: list[Path], options: BuildOptions) -> BuiltTrack:
    """Geometry and stations from the bags' GNSS, gradients/limits/curves from the profiles (or altitude)."""
    runs = [read_run(b) for b in bags]
    try:
        geo = average_runs(runs, options.spacing_m)
    except ValueError as exc:
        raise ConfigError(str(bags[0]), "gnss", str(exc)) from None
    runs = geo.runs  # those recorded the other way, played backwards
    found = geo.stops_m
    if found.size < 2:
        raise ConfigError(str(bags[0]), "stops", f"{found.size} stop(s) found in the runs, need a start and an end")
    origin = found[0] - options.margin_m  # chainage at track s = 0
    length = float(found[-1] - origin + options.margin_m)
    comments = [
        f"built by train-calib build-track from {len(bags)} run(s): {', '.join(b.name for b in bags)}",
        f"geometry: fixes averaged (local linear, +-{geo.window_m:.0f} m); cross-track scatter of the fixes "
        f"{geo.cross_track_rms_m:.1f} m (median-based rms); {options.margin_m:g} m added before the first and after "
        "the last stop (straight)",
        f"stations: {found.size} stops found in the runs (per run: {', '.join(map(str, geo.stops_per_run))})",
    ]
    if geo.reversed_runs:
        names = ", ".join(bags[k].name for k in geo.reversed_runs)
        comments.append(f"direction: {names} recorded the other way than {bags[0].name}: reversed before averaging")
    prof = read_profiles(profiles) if profiles else None
    data: dict = {"name": options.name, "length_m": round(length, 2)}
    s_grid = np.arange(0.0, length, options.spacing_m)
    s_grid = np.append(s_grid, length) if length - s_grid[-1] > 1.0 else np.append(s_grid[:-1], length)
    en = geo.polyline.at(s_grid + origin)
    lat, lon = geo.frame.to_geodetic(en[:, 0], en[:, 1])
    data["geometry"] = [{"s_m": round(float(s), 2), "lat": round(float(la), 8), "lon": round(float(lo), 8)}
                        for s, la, lo in zip(s_grid, lat, lon)]  # fmt: skip
    description = f"built from {len(bags)} run(s)' GNSS"
    if prof is not None:
        stops = options.profile_stops if options.profile_stops is not None else prof.stops
        alignment = align(stops, found, prof.sources[0])
        comments.append(f"profile {', '.join(Path(s).name for s in prof.sources)}: {alignment.note}")
        to_s = lambda p: alignment(p) - origin  # noqa: E731 - profile position -> track s
        if not prof.gradients:
            raise ConfigError(prof.sources[0], "gradients", "the profile has no gradients (add an s_m,permille CSV)")
        data["gradients"] = [{"s_m": s, "permille": v} for s, v in mapped_table(prof.gradients, to_s, length)]
        limits = prof.limits or [(0.0, _limit_from_runs(runs))]
        if not prof.limits:
            comments.append(f"speed limit {limits[0][1]:g} km/h: none in the profile (recorded maximum, rounded up)")
        data["speed_limits"] = [{"s_m": s, "kmh": v} for s, v in mapped_table(limits, to_s, length)]
        if prof.curves:
            data["curves"] = [{"s_m": s, "radius_m": v} for s, v in mapped_table(prof.curves, to_s, length)]
        description += f", profile {', '.join(Path(s).name for s in prof.sources)}"
    else:
        s_fix = np.concatenate(geo.fix_chainage) - origin
        alt = np.concatenate([r.alt for r in runs])
        grad = gradients_from_altitude(s_fix, alt, length, options.grade_step_m, str(bags[0]))
        data["gradients"] = [{"s_m": float(s), "permille": round(float(g), 2)} for s, g in zip(grad.s_m, grad.permille)]
        med = float(np.median(grad.sigma_permille))
        worst = float(np.max(grad.sigma_permille))
        note = (f"gradients from the GNSS altitude over {options.grade_step_m:g} m segments: 1-sigma {med:.2f} "
                f"per mille (median), {worst:.2f} (worst segment); altitude scatter {grad.altitude_scatter_m:.1f} m"
                )  # fmt: skip
        comments.append(note)
        comments.append("per segment 1-sigma (per mille): " + ", ".join(f"{x:.2f}" for x in grad.sigma_permille))
        limit = _limit_from_runs(runs)
        comments.append(f"speed limit {limit:g} km/h: no profile (recorded maximum, rounded up)")
        data["speed_limits"] = [{"s_m": 0.0, "kmh": limit}]
        description += f"; {note}"
    data["tunnels"], notes = _tunnels(runs, geo.fix_chainage, origin, length)
    comments += notes
    names = [f"stop {k}" for k in range(found.size)]
    data["stations"] = [{"s_m": round(float(s - origin), 2), "name": n} for s, n in zip(found, names)]
    data["description"] = description
    return BuiltTrack(data, comments)


def _tunnels(runs: list, chains: list[np.ndarray], origin: float, length: float) -> tuple[list[dict], list[str]]:
    """The tunnels (GNSS outages consistent across the runs; trackbuild.tunnels) in track s, and comment lines."""
    found = find_tunnels(runs, chains)
    out, spans = [], []
    for (a, b), seen, sigma in zip(found.tunnels, found.seen_by, found.edge_sigma_m):
        a, b = max(a - origin, 0.0), min(b - origin, length)
        if b - a < 1.0:
            continue
        out.append({"start_m": round(float(a), 1), "end_m": round(float(b), 1)})
        spans.append(f"{a:.0f}-{b:.0f} m (edges +-{sigma:.0f} m, in {seen} of {len(runs)} runs)")
    notes = [f"tunnels from GNSS outages while moving: {'; '.join(spans) if spans else 'none'}"]
    notes += [f"not a tunnel: {d}" for d in found.dropped]
    return out, notes


def _limit_from_runs(runs: list) -> float:
    """The highest recorded speed, km/h, rounded up to 10 km/h."""
    top = max(float(np.max(r.speed_ms)) for r in runs) * 3.6
    return float(np.ceil((top + 1.0) / 10.0) * 10.0)


def track_yaml_text(built: BuiltTrack) -> str:
    """The track file: the comments, then the mapping."""
    import yaml

    head = "".join(f"# {c}\n" for c in built.comments)
    return head + yaml.safe_dump(built.data, sort_keys=False, width=1000, allow_unicode=True)
