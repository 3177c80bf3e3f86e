"""GPX 1.1 (and 1.0) track points: ``<trkpt lat lon>`` with ``<time>`` (ISO 8601), ``<ele>`` (m) and speed (m/s).

Speed is read from ``<speed>`` in the point (GPX 1.0) or in its ``<extensions>`` (any element named ``speed``,
e.g. Garmin's ``gpxtpx:speed``). Without any speed in the file the speed is derived from the positions
(distance over time between neighbours) and the import says so. A file cut short keeps the points before the cut.
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

from ..geodesy import LocalFrame
from .records import RowLog, Streams
from .timefmt import TimeError, parse_iso_ns


def _local(tag: str) -> str:
    return tag.rsplit("}", 1)[-1]


def _child_text(elem: ET.Element, name: str) -> str | None:
    for child in elem:
        if _local(child.tag) == name:
            return (child.text or "").strip()
    return None


def _speed_text(point: ET.Element) -> str | None:
    direct = _child_text(point, "speed")
    if direct is not None:
        return direct
    for child in point:
        if _local(child.tag) == "extensions":
            for elem in child.iter():
                if _local(elem.tag) == "speed":
                    return (elem.text or "").strip()
    return None


def read_gpx(path: Path, text: str, log: RowLog) -> tuple[Streams, bool]:
    """Read the track points; returns the streams and whether the speed was derived from the positions."""
    gnss: list[tuple[int, float, float, float]] = []
    speed: list[tuple[int, float]] = []
    parser = ET.XMLPullParser(events=("end",))
    lines = text.splitlines(keepends=True)
    point_line = 0
    for n, chunk in enumerate(lines, start=1):
        try:
            parser.feed(chunk)
            events = list(parser.read_events())
        except ET.ParseError as exc:
            log.rows += 1
            log.bad(path, n, f"XML broken ({exc.msg if hasattr(exc, 'msg') else exc}); the rest of the file is skipped")
            break
        for _, elem in events:
            name = _local(elem.tag)
            if name != "trkpt":
                continue
            log.rows += 1
            point_line = n
            sample = _point(elem, path, point_line, log)
            elem.clear()
            if sample is None:
                continue
            t_ns, lat, lon, alt, v = sample
            gnss.append((t_ns, lat, lon, alt))
            if v is not None:
                speed.append((t_ns, v))
            log.used += 1
    else:
        try:
            parser.close()
        except ET.ParseError as exc:
            log.rows += 1
            log.bad(path, len(lines), f"XML ends early ({exc}): the file is truncated")
    derived = not speed and len(gnss) >= 2
    if derived:
        speed = derive_speed(gnss)
    return Streams.from_lists(gnss, speed), derived


Point = tuple[int, float, float, float, float | None]  # t_ns, lat, lon, alt (m), speed (m/s) or None


def _point(elem: ET.Element, path: Path, line: int, log: RowLog) -> Point | None:
    try:
        lat = float(elem.attrib["lat"])
        lon = float(elem.attrib["lon"])
    except KeyError as exc:
        log.bad(path, line, f"trkpt without {exc.args[0]}")
        return None
    except ValueError:
        log.bad(path, line, "trkpt lat/lon is not a number")
        return None
    if not (-90.0 <= lat <= 90.0 and -180.0 <= lon <= 180.0):
        log.bad(path, line, f"trkpt position {lat:g}, {lon:g} is not WGS84 degrees")
        return None
    time_text = _child_text(elem, "time")
    if not time_text:
        log.bad(path, line, "trkpt without <time>")
        return None
    try:
        t_ns = parse_iso_ns(time_text)
    except TimeError as exc:
        log.bad(path, line, str(exc))
        return None
    ele_text = _child_text(elem, "ele")
    try:
        alt = float(ele_text) if ele_text else math.nan
        speed_text = _speed_text(elem)
        v = float(speed_text) if speed_text else None
    except ValueError:
        log.bad(path, line, "trkpt <ele> or <speed> is not a number")
        return None
    if v is not None and not (math.isfinite(v) and v >= 0.0):
        log.bad(path, line, f"trkpt speed {v:g} is not a speed")
        return None
    return t_ns, lat, lon, alt, v


def derive_speed(gnss: list[tuple[int, float, float, float]]) -> list[tuple[int, float]]:
    """Speed (m/s) at each point from the distance between its neighbours over their time difference."""
    order = sorted(gnss)
    t = np.array([g[0] for g in order], dtype=float) * 1e-9
    lat = np.array([g[1] for g in order])
    lon = np.array([g[2] for g in order])
    e, n = LocalFrame(float(lat.mean()), float(lon.mean())).to_enu(lat, lon)
    dist = np.concatenate(([0.0], np.cumsum(np.hypot(np.diff(e), np.diff(n)))))
    v = np.gradient(dist, t) if t.size > 1 else np.zeros(t.size)
    return [(int(g[0]), float(max(x, 0.0))) for g, x in zip(order, v)]
