"""The track: the track file of INTERFACES.md, validated, with the functions of position s (m).

Positions ``s`` run from 0 at the start of the line to ``length_m`` in the running direction.
The track force g(s) (N/kg) is the gradient plus curve resistance averaged over the train
length: the head at s, the tail at s - L.
"""

from __future__ import annotations

import bisect
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from . import physics
from .geodesy import LocalFrame
from .piecewise import PiecewiseConstant, ScalarPiecewise
from .yamlcheck import Checker, load_yaml_mapping

MAX_PERMILLE = 100.0
MIN_CURVE_RADIUS_M = 50.0


@dataclass(frozen=True)
class Station:
    s_m: float
    name: str


@dataclass(frozen=True)
class Tunnel:
    start_m: float
    end_m: float


@dataclass(frozen=True)
class Section:
    """A track-detection section (track circuit / axle counter section) with its joints."""

    id: str
    start_m: float
    end_m: float


@dataclass
class Track:
    name: str
    length_m: float
    geometry_s_m: np.ndarray
    geometry_lat: np.ndarray
    geometry_lon: np.ndarray
    gradient: PiecewiseConstant  # rise over run (dimensionless), positive uphill
    curvature: PiecewiseConstant  # curve resistance per unit weight, CURVE_CONSTANT_M / R
    speed_limit: PiecewiseConstant  # m/s
    tunnel: PiecewiseConstant  # 1 inside a tunnel, 0 outside
    stations: list[Station] = field(default_factory=list)
    tunnels: list[Tunnel] = field(default_factory=list)
    sections: list[Section] = field(default_factory=list)
    description: str = ""
    source: str = ""

    def __post_init__(self) -> None:
        self.frame = LocalFrame(float(np.mean(self.geometry_lat)), float(np.mean(self.geometry_lon)))
        self.east_m, self.north_m = self.frame.to_enu(self.geometry_lat, self.geometry_lon)
        self._seg_start = np.stack([self.east_m[:-1], self.north_m[:-1]], axis=1)
        self._seg_vec = np.stack([np.diff(self.east_m), np.diff(self.north_m)], axis=1)
        self._seg_len2 = np.maximum(np.einsum("ij,ij->i", self._seg_vec, self._seg_vec), 1e-12)

    # -- forces ---------------------------------------------------------------------------
    def track_force(self, s_m, train_length_m: float = 0.0) -> np.ndarray:
        """g(s) = 9.81 (gradient + curve) averaged over the train (head at s), N/kg."""
        start = np.asarray(s_m, dtype=float) - train_length_m
        mean = self.gradient.mean_over(start, s_m) + self.curvature.mean_over(start, s_m)
        return physics.GRAVITY * mean

    def track_force_integral(self, s_m, train_length_m: float = 0.0) -> np.ndarray:
        """Gamma(s) = the integral of :meth:`track_force` over the head position from 0 to s, J/kg (N m/kg).

        Exact: the mean over the train of the gradient's and the curves' piecewise-linear integrals,
        (Gamma(s_j) - Gamma(s_i)) / (s_j - s_i) is the mean g over a step from s_i to s_j however often the gradient
        changes inside it (the energy form of the coast regression, docs/estimator.md)."""
        return (
            self._potential(np.asarray(s_m, dtype=float), train_length_m)
            - self._potential(np.zeros(1), train_length_m)[0]
        )

    def _potential(self, s: np.ndarray, train_length_m: float) -> np.ndarray:
        start = s - train_length_m
        mean = self.gradient.mean_integral_over(start, s) + self.curvature.mean_integral_over(start, s)
        return physics.GRAVITY * mean

    def tunnel_fraction(self, s_m, train_length_m: float = 0.0) -> np.ndarray:
        """Fraction of the train (head at s) inside a tunnel, 0..1."""
        start = np.asarray(s_m, dtype=float) - train_length_m
        return np.clip(self.tunnel.mean_over(start, s_m), 0.0, 1.0)

    def speed_limit_at(self, s_m) -> np.ndarray:
        """Static speed limit at s, m/s."""
        return self.speed_limit(s_m)

    def limit_over_train(self, s_m: float, train_length_m: float) -> float:
        """Lowest limit between tail and head (a train may only speed up once its tail clears), m/s."""
        b = self.speed_limit.breaks
        inside = b[(b > s_m - train_length_m) & (b <= s_m)]
        points = np.concatenate(([s_m], inside, [max(s_m - train_length_m, 0.0)]))
        return float(np.min(self.speed_limit(points)))

    # -- geometry -------------------------------------------------------------------------
    def enu_at(self, s_m) -> tuple[np.ndarray, np.ndarray]:
        """Local east/north (m) of the track point at s."""
        s = np.asarray(s_m, dtype=float)
        return np.interp(s, self.geometry_s_m, self.east_m), np.interp(s, self.geometry_s_m, self.north_m)

    def latlon_at(self, s_m) -> tuple[np.ndarray, np.ndarray]:
        """WGS84 latitude and longitude (degrees) of the track point at s."""
        return self.frame.to_geodetic(*self.enu_at(s_m))

    def to_enu(self, lat_deg, lon_deg) -> tuple[np.ndarray, np.ndarray]:
        return self.frame.to_enu(lat_deg, lon_deg)

    def project(
        self, east_m: float, north_m: float, s_min_m: float = -np.inf, s_max_m: float = np.inf
    ) -> tuple[float, float]:
        """Nearest track point to (east, north) with s in [s_min, s_max]: (s in m, distance in m).

        Chainage is interpolated linearly along each polyline segment between its vertices' s_m,
        so a polyline whose chord lengths differ from the chainage still maps consistently.
        """
        p = np.array([east_m, north_m], dtype=float)
        t = np.clip(((p - self._seg_start) * self._seg_vec).sum(axis=1) / self._seg_len2, 0.0, 1.0)
        nearest = self._seg_start + t[:, None] * self._seg_vec
        s = self.geometry_s_m[:-1] + t * np.diff(self.geometry_s_m)
        dist = np.hypot(nearest[:, 0] - p[0], nearest[:, 1] - p[1])
        if np.isfinite(s_min_m) or np.isfinite(s_max_m):
            # segments overlapping the window; clamp their points into it
            s = np.clip(s, s_min_m, s_max_m)
            e, n = self.enu_at(s)
            dist = np.hypot(e - p[0], n - p[1])
        i = int(np.argmin(dist))
        return float(s[i]), float(dist[i])

    def project_latlon(self, lat_deg: float, lon_deg: float, s_min_m: float = -np.inf, s_max_m: float = np.inf):
        e, n = self.to_enu(lat_deg, lon_deg)
        return self.project(float(e), float(n), s_min_m, s_max_m)

    # -- stations -------------------------------------------------------------------------
    def station_named(self, name: str) -> Station:
        for station in self.stations:
            if station.name == name:
                return station
        raise KeyError(f"track {self.name}: no station named {name!r}")


class ScalarTrackTerms:
    """``Track.track_force``, ``tunnel_fraction`` and ``speed_limit_at`` for one head position s (m) and a fixed
    train length, on plain floats (per sample) with the same arithmetic."""

    def __init__(self, track: Track, train_length_m: float) -> None:
        self.track = track
        self.length = float(train_length_m)
        self.gradient = ScalarPiecewise(track.gradient)
        self.curvature = ScalarPiecewise(track.curvature)
        self.tunnel = ScalarPiecewise(track.tunnel)
        self.limit = ScalarPiecewise(track.speed_limit)
        a = -self.length
        self._potential_origin = physics.GRAVITY * (
            self.gradient.mean_integral_over(a, 0.0) + self.curvature.mean_integral_over(a, 0.0)
        )

    def track_force(self, s: float) -> float:
        """g(s) averaged over the train, N/kg."""
        a = s - self.length
        return physics.GRAVITY * (self.gradient.mean_over(a, s) + self.curvature.mean_over(a, s))

    def track_force_integral(self, s: float) -> float:
        """``Track.track_force_integral`` at s, J/kg."""
        a = s - self.length
        potential = physics.GRAVITY * (self.gradient.mean_integral_over(a, s) + self.curvature.mean_integral_over(a, s))
        return potential - self._potential_origin

    def tunnel_fraction(self, s: float) -> float:
        """Fraction of the train inside a tunnel, 0..1."""
        f = self.tunnel.mean_over(s - self.length, s)
        return 0.0 if f < 0.0 else 1.0 if f > 1.0 else f  # = min(max(f, 0), 1), without two builtin calls

    def at(self, s: float) -> tuple[float, float, float, float]:
        """(:meth:`track_force` N/kg, ``limit`` m/s, :meth:`tunnel_fraction`, :meth:`track_force_integral` J/kg) at
        s: their floats, with one index look-up per piecewise function and end (per released sample)."""
        a = s - self.length
        g_mean, g_integral = self.gradient.means(a, s)
        c_mean, c_integral = self.curvature.means(a, s)
        f = self.tunnel.mean_over(a, s)
        return (
            physics.GRAVITY * (g_mean + c_mean),
            self.limit(s),
            0.0 if f < 0.0 else 1.0 if f > 1.0 else f,
            physics.GRAVITY * (g_integral + c_integral) - self._potential_origin,
        )

    def at_many(self, s: Sequence[float]) -> tuple[list[float], list[float], list[float], list[float]]:
        """:meth:`at` of many positions (m) at once, as four lists of floats: the Track's numpy functions, which
        give the same floats (a whole run's released samples, offline: ~4x faster than one ``at`` each)."""
        track, length, heads = self.track, self.length, np.asarray(s, dtype=float)
        return (
            track.track_force(heads, length).tolist(),
            track.speed_limit_at(heads).tolist(),
            track.tunnel_fraction(heads, length).tolist(),
            track.track_force_integral(heads, length).tolist(),
        )


class WindowProjector:
    """``Track.project(e, n, s_min, s_max)`` for one point (m) on plain floats, visiting only the segments that
    overlap the window: the nearest point with s in the window, the chainage interpolated linearly along each
    segment (a window holds a few segments)."""

    def __init__(self, track: Track) -> None:
        self.s = [float(x) for x in track.geometry_s_m]
        self.x = [float(x) for x in track.east_m]
        self.y = [float(y) for y in track.north_m]
        self.length = self.s[-1]
        self.segments = len(self.s) - 1
        s, x, y = self.s, self.x, self.y
        # per segment i (vertex i to i + 1): (s0, x0, y0, ds, dx, dy, max(|d|^2, 1e-12)), m and m^2
        self._seg = []
        for i in range(len(s) - 1):
            dx, dy = x[i + 1] - x[i], y[i + 1] - y[i]
            self._seg.append((s[i], x[i], y[i], s[i + 1] - s[i], dx, dy, max(dx * dx + dy * dy, 1e-12)))

    def project(self, e: float, n: float, lo: float, hi: float) -> tuple[float, float]:
        """(s, distance) in m of the nearest track point to (e, n) with s in [lo, hi]."""
        s, start, end = self.s, self.s[0], self.length
        lo = start if start > lo else lo  # = max(lo, start)
        hi = end if end < hi else hi  # = min(hi, end)
        if hi < lo:  # the window lies beyond an end of the line: its nearest end
            lo = hi = start if hi < start else end
        segments = self.segments
        first = bisect.bisect_right(s, lo) - 1
        first = 0 if first < 0 else segments - 1 if first > segments - 1 else first
        stop = bisect.bisect_left(s, hi)
        stop = first + 1 if stop < first + 1 else segments if stop > segments else stop
        best_s, best_d = lo, math.inf
        hypot = math.hypot
        for s0, x0, y0, ds, dx, dy, len2 in self._seg[first:stop]:
            t = ((e - x0) * dx + (n - y0) * dy) / len2
            t = 0.0 if t < 0.0 else 1.0 if t > 1.0 else t  # = min(max(t, 0), 1)
            si = s0 + t * ds
            si = lo if si < lo else hi if si > hi else si  # = min(max(si, lo), hi) (lo <= hi)
            f = (si - s0) / ds if ds > 0 else 0.0
            d = hypot(x0 + f * dx - e, y0 + f * dy - n)
            if d < best_d:
                best_s, best_d = si, d
        return best_s, best_d


TRACK_KEYS = (
    "name",
    "length_m",
    "geometry",
    "gradients",
    "speed_limits",
    "stations",
    "curves",
    "tunnels",
    "sections",
    "description",
)
"""The keys of a track file (../shared/INTERFACES.md); any other is refused with the nearest of these."""


def load_track(path: str | Path) -> Track:
    """Read and validate a track file; a problem raises ConfigError('<file>: <key>: <problem>').

    ``GEOMETRY.yaml+PROFILE.json``: a track file's geometry and stations with the gradients, limits and curves of a
    TTOBench track JSON mapped onto them through the stops (``train_calib.trackbuild.combine``).
    """
    if str(path).lower().endswith(".json"):
        from .trackbuild.combine import combined_track_mapping

        data, source = combined_track_mapping(str(path))
        return track_from_mapping(data, source)
    return track_from_mapping(load_yaml_mapping(path, "track file"), path)


def track_from_mapping(data: dict, path: str | Path) -> Track:
    """Validate a track file's mapping (``path`` names it in errors)."""
    c = Checker(path)
    c.known_keys(data, TRACK_KEYS)
    name = c.string(data, "name")
    length = c.number(data, "length_m", low=0.0, high=3.0e6, low_open=True, unit="m")

    geometry = _entries(c, data, "geometry", ("s_m", "lat", "lon"), min_len=2)
    geo_s = [
        c.check_number(e["s_m"], f"geometry[{i}].s_m", low=0.0, high=length, unit="m") for i, e in enumerate(geometry)
    ]
    lat = [
        c.check_number(e["lat"], f"geometry[{i}].lat", low=-90.0, high=90.0, unit="deg") for i, e in enumerate(geometry)
    ]
    lon = [
        c.check_number(e["lon"], f"geometry[{i}].lon", low=-180.0, high=180.0, unit="deg")
        for i, e in enumerate(geometry)
    ]
    c.increasing(geo_s, "geometry", "s_m")
    if geo_s[0] != 0.0:
        raise c.fail("geometry[0].s_m", f"the geometry must start at s_m 0, found {geo_s[0]:g}")
    if abs(geo_s[-1] - length) > 1.0:
        raise c.fail(
            f"geometry[{len(geo_s) - 1}].s_m", f"the geometry must end at length_m {length:g}, found {geo_s[-1]:g}"
        )
    _check_geometry_spacing(c, np.array(geo_s), np.array(lat), np.array(lon))

    gradients = _entries(c, data, "gradients", ("s_m", "permille"), min_len=1)
    grad_s = _positions(c, gradients, "gradients", length, start_at_zero=True)
    permille = [
        c.check_number(e["permille"], f"gradients[{i}].permille", low=-MAX_PERMILLE, high=MAX_PERMILLE, unit="permille")
        for i, e in enumerate(gradients)
    ]

    limits = _entries(c, data, "speed_limits", ("s_m", "kmh"), min_len=1)
    lim_s = _positions(c, limits, "speed_limits", length, start_at_zero=True)
    kmh = [
        c.check_number(e["kmh"], f"speed_limits[{i}].kmh", low=0.0, high=600.0, low_open=True, unit="km/h")
        for i, e in enumerate(limits)
    ]

    stations_raw = _entries(c, data, "stations", ("s_m", "name"), min_len=0)
    st_s = _positions(c, stations_raw, "stations", length, strict=False)
    stations = [Station(s, c.string(e, "name", f"stations[{i}].")) for i, (s, e) in enumerate(zip(st_s, stations_raw))]

    curves_raw = _entries(c, data, "curves", ("s_m", "radius_m"), min_len=0, required=False)
    curve_s = _positions(c, curves_raw, "curves", length)
    curve_k = []
    for i, e in enumerate(curves_raw):
        radius = c.check_number(e["radius_m"], f"curves[{i}].radius_m", unit="m")
        if radius != 0.0 and abs(radius) < MIN_CURVE_RADIUS_M:
            raise c.fail(
                f"curves[{i}].radius_m",
                f"{radius:g} m is out of range: 0 (straight) or |R| >= {MIN_CURVE_RADIUS_M:g} m",
            )
        curve_k.append(0.0 if radius == 0.0 else physics.CURVE_CONSTANT_M / abs(radius))

    tunnels_raw = _entries(c, data, "tunnels", ("start_m", "end_m"), min_len=0, required=False)
    tunnels = [Tunnel(*_interval(c, e, f"tunnels[{i}]", length)) for i, e in enumerate(tunnels_raw)]
    _non_overlapping(c, [(t.start_m, t.end_m) for t in tunnels], "tunnels")

    sections_raw = _entries(c, data, "sections", ("id", "start_m", "end_m"), min_len=0, required=False)
    sections = []
    seen: set[str] = set()
    for i, e in enumerate(sections_raw):
        sid = c.string(e, "id", f"sections[{i}].")
        if sid in seen:
            raise c.fail(f"sections[{i}].id", f"duplicate section id {sid!r}")
        seen.add(sid)
        sections.append(Section(sid, *_interval(c, e, f"sections[{i}]", length)))
    _non_overlapping(c, [(s.start_m, s.end_m) for s in sections], "sections")

    tunnel_breaks, tunnel_values = [0.0], [0.0]
    for t in tunnels:
        if t.start_m == tunnel_breaks[-1]:
            tunnel_values[-1] = 1.0
        else:
            tunnel_breaks.append(t.start_m)
            tunnel_values.append(1.0)
        tunnel_breaks.append(t.end_m)
        tunnel_values.append(0.0)

    return Track(
        name=name,
        length_m=length,
        geometry_s_m=np.array(geo_s),
        geometry_lat=np.array(lat),
        geometry_lon=np.array(lon),
        gradient=PiecewiseConstant(grad_s, np.array(permille) / 1000.0),
        curvature=_curvature(curve_s, curve_k),
        speed_limit=PiecewiseConstant(lim_s, np.array(kmh) * physics.KMH),
        tunnel=PiecewiseConstant(tunnel_breaks, tunnel_values),
        stations=stations,
        tunnels=tunnels,
        sections=sections,
        description=str(data.get("description", "")),
        source=str(path),
    )


def _curvature(curve_s: list[float], curve_k: list[float]) -> PiecewiseConstant:
    """Curve resistance per unit weight; straight track before the first listed curve."""
    if not curve_s or curve_s[0] > 0.0:
        return PiecewiseConstant([0.0, *curve_s], [0.0, *curve_k])
    return PiecewiseConstant(curve_s, curve_k)


def _entries(
    c: Checker, data: dict, key: str, fields: Sequence[str], *, min_len: int, required: bool = True
) -> list[dict[str, Any]]:
    items = c.sequence(data, key, required=required, min_len=min_len)
    for i, item in enumerate(items):
        if not isinstance(item, dict):
            raise c.fail(f"{key}[{i}]", f"expected a mapping with {', '.join(fields)}, found {type(item).__name__}")
        c.known_keys(item, fields, f"{key}[{i}].")
        for f in fields:
            c.get(item, f, f"{key}[{i}].")
    return list(items)


def _positions(
    c: Checker, items: list[dict], key: str, length: float, *, start_at_zero: bool = False, strict: bool = True
) -> list[float]:
    s = [c.check_number(e["s_m"], f"{key}[{i}].s_m", low=0.0, high=length, unit="m") for i, e in enumerate(items)]
    c.increasing(s, key, "s_m", strict=strict)
    if start_at_zero and s and s[0] != 0.0:
        raise c.fail(
            f"{key}[0].s_m", f"the first entry must be at s_m 0 (the value holds from there on), found {s[0]:g}"
        )
    return s


def _interval(c: Checker, e: dict, key: str, length: float) -> tuple[float, float]:
    start = c.check_number(e["start_m"], f"{key}.start_m", low=0.0, high=length, unit="m")
    end = c.check_number(e["end_m"], f"{key}.end_m", low=0.0, high=length, unit="m")
    if end <= start:
        raise c.fail(f"{key}.end_m", f"end_m {end:g} must be greater than start_m {start:g}")
    return start, end


def _non_overlapping(c: Checker, intervals: list[tuple[float, float]], key: str) -> None:
    for i in range(1, len(intervals)):
        if intervals[i][0] < intervals[i - 1][1]:
            raise c.fail(
                f"{key}[{i}].start_m",
                f"intervals must be sorted and not overlap: starts at {intervals[i][0]:g} "
                f"before the previous ends at {intervals[i - 1][1]:g}",
            )


def _check_geometry_spacing(c: Checker, s: np.ndarray, lat: np.ndarray, lon: np.ndarray) -> None:
    """Chord between vertices vs chainage difference: catches swapped lat/lon or wrong units."""
    frame = LocalFrame(float(np.mean(lat)), float(np.mean(lon)))
    e, n = frame.to_enu(lat, lon)
    chord = np.hypot(np.diff(e), np.diff(n))
    ds = np.diff(s)
    bad = np.nonzero((chord > 1.1 * ds + 10.0) | (chord < 0.5 * ds - 10.0))[0]
    if bad.size:
        i = int(bad[0]) + 1
        raise c.fail(
            f"geometry[{i}]",
            f"vertices {i - 1} and {i} are {chord[i - 1]:.0f} m apart but their s_m differ by {ds[i - 1]:.0f} m "
            "(lat/lon swapped or not in degrees?)",
        )
