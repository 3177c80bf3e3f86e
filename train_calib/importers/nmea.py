"""NMEA 0183 logs: RMC (position, speed in knots, date), GGA (position, altitude) and VTG (speed in km/h).

A sentence with a wrong checksum, a truncated one or one without a fix is a bad row. Times come from the
sentence's UTC time of day and the date of the latest RMC (the first RMC's date before it); VTG carries no time
and takes the time of the sentence before it. Position: GGA where an epoch has one (it carries the altitude),
else RMC; speed: RMC where an epoch has one, else VTG.
"""

from __future__ import annotations

import math
import re
from datetime import datetime, timezone
from pathlib import Path

from .records import ImportFormatError, RowLog, Streams

KNOT_MS = 1852.0 / 3600.0
SENTENCE = re.compile(r"^[$!](?P<body>[A-Z0-9]{5}[^*]*)(?:\*(?P<sum>[0-9A-Fa-f]{2}))?\s*$")
MIN_FIELDS = {"RMC": 10, "GGA": 10, "VTG": 8}


class SentenceError(ValueError):
    """A sentence that cannot be used (the reason is the message)."""


def checksum(body: str) -> int:
    """XOR of the characters between ``$`` and ``*``."""
    value = 0
    for ch in body:
        value ^= ord(ch)
    return value


def _coord(value: str, hemi: str, degree_digits: int, what: str) -> float:
    if not value or not hemi:
        raise SentenceError(f"{what} is empty")
    try:
        deg = float(value[:degree_digits])
        minutes = float(value[degree_digits:])
    except ValueError:
        raise SentenceError(f"{what} {value!r} is not ddmm.mmmm") from None
    if minutes >= 60.0:
        raise SentenceError(f"{what} {value!r}: minutes {minutes:g} >= 60")
    out = deg + minutes / 60.0
    if hemi in "SW":
        return -out
    if hemi not in "NE":
        raise SentenceError(f"{what} hemisphere {hemi!r} is not N/S/E/W")
    return out


def _tod_s(value: str) -> float:
    """hhmmss(.ss) to seconds of the day."""
    if len(value) < 6:
        raise SentenceError(f"time {value!r} is not hhmmss.ss")
    try:
        h, m, s = int(value[0:2]), int(value[2:4]), float(value[4:])
    except ValueError:
        raise SentenceError(f"time {value!r} is not hhmmss.ss") from None
    if h > 23 or m > 59 or s >= 61.0:
        raise SentenceError(f"time {value!r} is out of range")
    return h * 3600.0 + m * 60.0 + s


def _date_ns(value: str) -> int:
    """ddmmyy to Unix ns of that day's midnight UTC."""
    try:
        day = datetime(2000 + int(value[4:6]), int(value[2:4]), int(value[0:2]), tzinfo=timezone.utc)
    except (ValueError, IndexError):
        raise SentenceError(f"date {value!r} is not ddmmyy") from None
    if day.year >= 2038:
        raise SentenceError(f"date {value!r} is after 2037 (a ROS stamp holds int32 seconds)")
    return int(day.timestamp()) * 1_000_000_000


def _float(value: str, what: str) -> float:
    try:
        out = float(value)
    except ValueError:
        raise SentenceError(f"{what} {value!r} is not a number") from None
    if not math.isfinite(out):
        raise SentenceError(f"{what} {value!r} is not finite")
    return out


def split_sentence(line: str) -> tuple[str, list[str]]:
    """Check a sentence (form, checksum) and return its type (``RMC``) and fields; SentenceError if bad."""
    match = SENTENCE.match(line.strip())
    if match is None:
        raise SentenceError("not an NMEA sentence (truncated?)")
    body = match.group("body")
    if match.group("sum") is None:
        raise SentenceError("no checksum (truncated?)")
    expected = checksum(body)
    if int(match.group("sum"), 16) != expected:
        raise SentenceError(f"wrong checksum *{match.group('sum').upper()} (computed *{expected:02X})")
    fields = body.split(",")
    kind = fields[0][2:]
    if kind in MIN_FIELDS and len(fields) < MIN_FIELDS[kind]:
        raise SentenceError(f"{kind} with {len(fields)} fields, needs {MIN_FIELDS[kind]} (truncated?)")
    return kind, fields


def _first_date(lines: list[str]) -> int | None:
    for line in lines:
        try:
            kind, f = split_sentence(line)
            if kind == "RMC" and f[9]:
                return _date_ns(f[9])
        except SentenceError:
            continue
    return None


def read_nmea(path: Path, text: str, log: RowLog) -> Streams:
    """Read RMC, GGA and VTG sentences; other sentence types are skipped silently (not counted as bad)."""
    lines = text.splitlines()
    day_ns = _first_date(lines)
    if day_ns is None:
        raise ImportFormatError(f"{path}: no valid RMC sentence with a date: NMEA times need one")
    positions: dict[int, tuple[int, float, float, float, str]] = {}  # t_ns -> (line, lat, lon, alt, kind)
    speeds: dict[int, tuple[int, float, str]] = {}
    last_t: int | None = None
    last_tod = -1.0
    for n, line in enumerate(lines, start=1):
        if not line.strip():
            continue
        try:
            kind, f = split_sentence(line)
        except SentenceError as exc:
            log.rows += 1
            log.bad(path, n, str(exc))
            continue
        if kind not in MIN_FIELDS:
            continue
        log.rows += 1
        try:
            if kind == "VTG":
                if last_t is None:
                    raise SentenceError("VTG before any timed sentence")
                if not f[7]:
                    raise SentenceError("VTG without speed in km/h")
                speeds.setdefault(last_t, (n, _float(f[7], "speed km/h") / 3.6, kind))
                log.used += 1
                continue
            tod = _tod_s(f[1])
            if kind == "RMC":
                day_ns = _date_ns(f[9]) if f[9] else day_ns
            elif tod < last_tod - 43200.0:  # GGA past midnight before the next RMC
                day_ns += 86_400_000_000_000
            t_ns = day_ns + round(tod * 1e9)
            last_t, last_tod = t_ns, tod
            if kind == "RMC":
                if f[2] != "A":
                    raise SentenceError(f"RMC status {f[2] or 'empty'} (no fix)")
                lat = _coord(f[3], f[4], 2, "latitude")
                lon = _coord(f[5], f[6], 3, "longitude")
                if f[7]:
                    speeds[t_ns] = (n, _float(f[7], "speed knots") * KNOT_MS, kind)
                if t_ns not in positions:
                    positions[t_ns] = (n, lat, lon, math.nan, kind)
            else:  # GGA
                if f[6] in ("", "0"):
                    raise SentenceError("GGA fix quality 0 (no fix)")
                lat = _coord(f[2], f[3], 2, "latitude")
                lon = _coord(f[4], f[5], 3, "longitude")
                alt = _float(f[9], "altitude") if f[9] else math.nan
                positions[t_ns] = (n, lat, lon, alt, kind)
            log.used += 1
        except SentenceError as exc:
            log.bad(path, n, f"{kind}: {exc}")
    gnss = [(t, p[1], p[2], p[3]) for t, p in positions.items()]
    speed = [(t, s[1]) for t, s in speeds.items()]
    return Streams.from_lists(gnss, speed)
