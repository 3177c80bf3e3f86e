"""Gradient, speed-limit and curve tables by position (a TTOBench track JSON or CSV files) and their mapping
onto the chainage of a built geometry by the stops."""

from __future__ import annotations

import csv
import io
import itertools
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import ConfigError
from ..ttobench import load_json

CSV_KINDS = {"permille": "gradients", "kmh": "limits", "radius_m": "curves"}


@dataclass
class Profile:
    """Tables by profile position p (m): gradients (per mille, uphill +), limits (km/h), curves (radius m, 0 straight);
    ``stops``: the profile's stop positions (m) when it has them."""

    gradients: list[tuple[float, float]] = field(default_factory=list)
    limits: list[tuple[float, float]] = field(default_factory=list)
    curves: list[tuple[float, float]] = field(default_factory=list)
    stops: list[float] | None = None
    sources: list[str] = field(default_factory=list)


def _pairs(path: Path, data: dict, key: str) -> list[tuple[float, float]]:
    entry = data.get(key)
    if entry is None:
        return []
    values = entry.get("values") if isinstance(entry, dict) else None
    if not isinstance(values, list):
        raise ConfigError(str(path), key, 'expected {"values": [[position, value], ...]}')
    out = []
    for i, v in enumerate(values):
        if not (isinstance(v, list) and len(v) >= 2 and all(isinstance(x, (int, float)) for x in v[:2])):
            raise ConfigError(str(path), f"{key}.values[{i}]", f"expected [position, value], found {v!r}") from None
        out.append((float(v[0]), float(v[1])))
    for i in range(1, len(out)):
        if out[i][0] <= out[i - 1][0]:
            raise ConfigError(str(path), f"{key}.values[{i}]", "positions must be strictly increasing")
    return out


def read_ttobench_track(path: Path) -> Profile:
    """Stops, speed limits (km/h), gradients (per mille; absent: level) and curvatures of a TTOBench track."""
    data = load_json(path, "TTOBench track file")
    stops_entry = data.get("stops")
    if not isinstance(stops_entry, dict) or not isinstance(stops_entry.get("values"), list):
        raise ConfigError(str(path), "stops", "missing required key (a TTOBench track lists its stops)")
    stops = [float(x) for x in stops_entry["values"]]
    if len(stops) < 2 or any(b <= a for a, b in itertools.pairwise(stops)):
        raise ConfigError(str(path), "stops", "needs at least 2 strictly increasing positions")
    limits = _pairs(path, data, "speed limits")
    if not limits:
        raise ConfigError(str(path), "speed limits", "missing required key")
    gradients = _pairs(path, data, "gradients") or [(0.0, 0.0)]
    curves = []
    for i, v in enumerate((data.get("curvatures") or {}).get("values", [])):
        try:
            r0, r1 = float(v[1]), float(v[2])
        except (TypeError, ValueError, IndexError):
            problem = f"expected [position, r_start, r_end], found {v!r}"
            raise ConfigError(str(path), f"curvatures.values[{i}]", problem) from None
        radius = 0.0 if math.isinf(r0) and math.isinf(r1) else (r0 if math.isinf(r1) else r1 if math.isinf(r0)
                                                                  else 2.0 / (1.0 / r0 + 1.0 / r1))  # fmt: skip
        curves.append((float(v[0]), 0.0 if math.isinf(radius) else radius))
    return Profile(gradients, limits, curves, stops, [str(path)])


def read_csv_profile(path: Path) -> Profile:
    """A CSV ``s_m,permille``, ``s_m,kmh`` or ``s_m,radius_m`` table (header row); one line per bad row."""
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise ConfigError(str(path), "", f"cannot read profile: {exc.strerror or exc}") from None
    reader = csv.reader(io.StringIO(text))
    header = [h.strip() for h in next(reader, [])]
    kinds = [h for h in header if h in CSV_KINDS]
    if "s_m" not in header or len(kinds) != 1:
        raise ConfigError(str(path), "header", f"expected s_m and one of permille, kmh, radius_m, found {header}")
    i_s, i_v = header.index("s_m"), header.index(kinds[0])
    rows: list[tuple[float, float]] = []
    for row in reader:
        if not row or not "".join(row).strip():
            continue
        try:
            rows.append((float(row[i_s]), float(row[i_v])))
        except (ValueError, IndexError):
            raise ConfigError(str(path), f"line {reader.line_num}", f"expected two numbers, found {row}") from None
        if len(rows) > 1 and rows[-1][0] <= rows[-2][0]:
            raise ConfigError(str(path), f"line {reader.line_num}", "s_m must be strictly increasing")
    if not rows:
        raise ConfigError(str(path), "", "no rows")
    prof = Profile(sources=[str(path)])
    setattr(prof, CSV_KINDS[kinds[0]], rows)
    return prof


def read_profiles(paths: list[Path]) -> Profile:
    """Every profile file together (a .json is a TTOBench track, anything else a CSV table)."""
    out = Profile()
    for path in paths:
        part = read_ttobench_track(path) if path.suffix.lower() == ".json" else read_csv_profile(path)
        for kind in ("gradients", "limits", "curves"):
            if getattr(part, kind):
                if getattr(out, kind):
                    raise ConfigError(str(path), kind, f"given twice (also in {', '.join(out.sources)})")
                setattr(out, kind, getattr(part, kind))
        if part.stops is not None:
            out.stops = part.stops
        out.sources += part.sources
    return out


@dataclass(frozen=True)
class Alignment:
    """Profile position p -> chainage c on the geometry, piecewise linear through matched stops."""

    profile_m: np.ndarray
    chainage_m: np.ndarray
    note: str

    def __call__(self, p: np.ndarray | float) -> np.ndarray:
        p = np.asarray(p, dtype=float)
        c = np.interp(p, self.profile_m, self.chainage_m)
        c = np.where(p < self.profile_m[0], self.chainage_m[0] + (p - self.profile_m[0]), c)
        return np.where(p > self.profile_m[-1], self.chainage_m[-1] + (p - self.profile_m[-1]), c)


def align(profile_stops: list[float] | None, found: np.ndarray, source: str, tolerance: float = 0.03) -> Alignment:
    """Match the profile's stops to the stops found in the runs: all of them when the counts agree, else the first
    and last; without profile stops, p = 0 at the first stop found. A span off by more than ``tolerance`` is refused."""
    if profile_stops is None:
        return Alignment(np.array([0.0, 1.0]), np.array([found[0], found[0] + 1.0]),
                         "profile position 0 = the first stop found in the runs (no stops in the profile)")  # fmt: skip
    p = np.asarray(profile_stops, dtype=float)
    if len(p) == len(found):
        note = f"{len(p)} stops of the profile matched to the {len(found)} stops found in the runs"
        c = found
    else:
        note = (f"the profile has {len(p)} stops, the runs {len(found)}: aligned by the first and last stop "
                "(length) only")  # fmt: skip
        p, c = p[[0, -1]], found[[0, -1]]
    span_p, span_c = p[-1] - p[0], c[-1] - c[0]
    if span_c <= 0 or abs(span_c / span_p - 1.0) > tolerance:
        raise ConfigError(source, "stops", f"the profile's stops span {span_p:.0f} m, the geometry's {span_c:.0f} m "
                          f"(more than {tolerance:.0%} apart: not the same line, or a stop missed)")  # fmt: skip
    return Alignment(p, np.asarray(c, dtype=float), note)


def mapped_table(
    rows: list[tuple[float, float]],
    to_s: Callable[[np.ndarray], np.ndarray],
    length_m: float,
    first_value: float | None = None,
) -> list[tuple[float, float]]:
    """A piecewise-constant table moved to track chainage: starts at s 0 with the value holding there, entries at
    or beyond the length dropped, equal neighbours merged."""
    s = [float(x) for x in to_s(np.array([r[0] for r in rows]))]
    values = [r[1] for r in rows]
    start_value = values[0]
    for si, vi in zip(s, values):
        if si <= 0.0:
            start_value = vi
    out = [(0.0, start_value if first_value is None else first_value)]
    for si, vi in zip(s, values):
        if 0.0 < si < length_m and si > out[-1][0] + 1e-6 and vi != out[-1][1]:
            out.append((round(si, 2), vi))
    return out
