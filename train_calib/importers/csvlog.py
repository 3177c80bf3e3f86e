"""CSV logs: a header row, then one row per time; empty cells mean "no sample of that stream in this row".

Default columns: ``time`` (s, or ISO 8601 with a zone), ``lat``, ``lon`` (WGS84 deg), optional ``alt`` (m),
``speed_kmh`` or ``speed_ms`` (or ``speed`` in ``--speed-unit``), optional ``power_consumed_w`` and
``power_regenerated_w`` (W). ``columns`` maps these names to the file's.
"""

from __future__ import annotations

import csv
import io
import math
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from .records import ImportFormatError, RowLog, Streams
from .timefmt import TimeError, parse_time_ns

SPEED_UNITS = {"kmh": 1.0 / 3.6, "ms": 1.0, "knots": 1852.0 / 3600.0, "mph": 1609.344 / 3600.0}
FIELDS = (
    "time",
    "lat",
    "lon",
    "alt",
    "speed",
    "speed_kmh",
    "speed_ms",
    "power_consumed_w",
    "power_regenerated_w",
)


def parse_columns(text: str | None) -> dict[str, str]:
    """``time=ts,lat=latitude`` -> {"time": "ts", "lat": "latitude"}; unknown names raise ImportFormatError."""
    mapping: dict[str, str] = {}
    for part in (text or "").split(","):
        if not part.strip():
            continue
        name, sep, column = part.partition("=")
        name = name.strip()
        if not sep or not column.strip():
            raise ImportFormatError(f"--columns: {part.strip()!r} is not NAME=COLUMN")
        if name not in FIELDS:
            raise ImportFormatError(f"--columns: unknown name {name!r} (known: {', '.join(FIELDS)})")
        mapping[name] = column.strip()
    return mapping


def _dialect(sample: str) -> str:
    first = sample.splitlines()[0] if sample else ""
    return max((",", ";", "\t"), key=first.count)


def _number(row: list[str], idx: int | None, name: str) -> float | None:
    """The cell as a float, None when the column is absent or the cell empty; ValueError with a reason."""
    if idx is None or idx >= len(row) or not row[idx].strip():
        return None
    try:
        value = float(row[idx])
    except ValueError:
        raise ValueError(f"column {name}: {row[idx].strip()!r} is not a number") from None
    if not math.isfinite(value):
        raise ValueError(f"column {name}: {row[idx].strip()!r} is not finite")
    return value


def read_csv(
    path: Path,
    text: str,
    log: RowLog,
    *,
    columns: dict[str, str] | None = None,
    speed_unit: str | None = None,
    time_unit: str = "s",
    start_ns: int = 0,
) -> Streams:
    """Read a CSV log; bad rows go to ``log`` with their line, a missing column raises ImportFormatError."""
    text = text.replace("\r\n", "\n").replace("\r", "\n").replace("\x00", "")
    delimiter = _dialect(text)
    reader = csv.reader(io.StringIO(text), delimiter=delimiter)
    try:
        header = [h.strip() for h in next(reader)]
    except (StopIteration, csv.Error):
        raise ImportFormatError(f"{path}: no readable CSV header row") from None
    mapping = {name: name for name in FIELDS}
    mapping.update(columns or {})
    index = {name: header.index(col) for name, col in mapping.items() if col in header}
    if "time" not in index:
        raise ImportFormatError(f"{path}: missing column {mapping['time']!r} (header: {', '.join(header)})")
    speed_col, factor = _speed_column(path, index, speed_unit, header)
    has_pos = "lat" in index and "lon" in index
    if ("lat" in index) != ("lon" in index):
        missing = "lon" if "lat" in index else "lat"
        raise ImportFormatError(f"{path}: missing column {mapping[missing]!r} (header: {', '.join(header)})")
    if not has_pos and speed_col is None:
        raise ImportFormatError(
            f"{path}: neither lat/lon nor a speed column (speed_kmh, speed_ms; header: {', '.join(header)})"
        )
    gnss: list[tuple[int, float, float, float]] = []
    speed: list[tuple[int, float]] = []
    power: list[tuple[int, float, float]] = []
    width = len(header)
    for row in _rows(reader, path, log):
        line = reader.line_num
        if not row or not any(c.strip() for c in row):
            continue
        log.rows += 1
        if len(row) < width:
            log.bad(path, line, f"truncated row: {len(row)} of {width} fields")
            continue
        if len(row) > width:
            log.bad(path, line, f"{len(row)} fields, the header has {width}")
            continue
        try:
            t_ns = parse_time_ns(row[index["time"]], time_unit, start_ns)
            lat = _number(row, index.get("lat"), "lat")
            lon = _number(row, index.get("lon"), "lon")
            alt = _number(row, index.get("alt"), "alt")
            v = _number(row, speed_col, header[speed_col] if speed_col is not None else "speed")
            pc = _number(row, index.get("power_consumed_w"), "power_consumed_w")
            pr = _number(row, index.get("power_regenerated_w"), "power_regenerated_w")
        except (ValueError, TimeError) as exc:
            log.bad(path, line, str(exc))
            continue
        if (lat is None) != (lon is None):
            log.bad(path, line, "lat and lon: one is empty")
            continue
        if lat is not None and lon is not None and not (-90.0 <= lat <= 90.0 and -180.0 <= lon <= 180.0):
            log.bad(path, line, f"position {lat:g}, {lon:g} is not WGS84 degrees")
            continue
        if v is not None and v < 0.0:
            log.bad(path, line, f"negative speed {v:g}")
            continue
        if (pc is not None and pc < 0.0) or (pr is not None and pr < 0.0):
            log.bad(path, line, "negative power")
            continue
        used = False
        if lat is not None and lon is not None:
            gnss.append((t_ns, lat, lon, math.nan if alt is None else alt))
            used = True
        if v is not None:
            speed.append((t_ns, v * factor))
            used = True
        if pc is not None or pr is not None:
            power.append((t_ns, pc or 0.0, pr or 0.0))
            used = True
        if used:
            log.used += 1
        else:
            log.bad(path, line, "no position, speed or power in this row")
    return Streams.from_lists(gnss, speed, power)


def _rows(reader: Any, path: Path, log: RowLog) -> Iterator[list[str]]:
    """The reader's rows; a row the csv module cannot split (an unterminated quote) is a bad row."""
    while True:
        try:
            yield next(reader)
        except StopIteration:
            return
        except csv.Error as exc:
            log.rows += 1
            log.bad(path, reader.line_num, f"unreadable row: {exc}")


def _speed_column(
    path: Path, index: dict[str, int], speed_unit: str | None, header: list[str]
) -> tuple[int | None, float]:
    """The speed column's index and its factor to m/s (``speed_kmh``, ``speed_ms`` or ``speed`` + --speed-unit)."""
    found = [name for name in ("speed", "speed_kmh", "speed_ms") if name in index]
    if len(found) > 1:
        raise ImportFormatError(f"{path}: several speed columns ({', '.join(found)}): map one with --columns")
    if not found:
        return None, 1.0
    name = found[0]
    if speed_unit is not None:
        return index[name], SPEED_UNITS[speed_unit]
    if name == "speed":
        raise ImportFormatError(f"{path}: column 'speed' has no unit: give --speed-unit kmh|ms|knots")
    return index[name], SPEED_UNITS["kmh" if name == "speed_kmh" else "ms"]
