"""The fleet manifest: a CSV with a header, ``bag,track,train,unit`` required, ``date`` (ISO 8601), ``driver``,
``line`` optional; other columns are ignored. Relative paths are taken from the manifest's folder; a track or
train that is not a file there is looked up as a bundled name (``config/tracks``, ``config/trains``), as
``replay`` does."""

from __future__ import annotations

import csv
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path

from ..errors import TrainCalibError
from ..paths import track_file, train_file

REQUIRED = ("bag", "track", "train", "unit")
OPTIONAL = ("date", "driver", "line")
COLUMNS = REQUIRED + OPTIONAL


class ManifestError(TrainCalibError):
    """A manifest the user can fix: ``<file>:<line>: <column>: <problem>`` (one line)."""


@dataclass(frozen=True)
class ManifestRow:
    """One line of the manifest; ``index`` is its position (0-based, data lines), the order of the outputs."""

    index: int
    bag: str  # as written in the manifest
    track: str
    train: str
    unit: str
    date: str = ""  # as written (ISO 8601), "" when absent
    driver: str = ""
    line: str = ""
    bag_path: str = ""  # resolved, absolute
    track_path: str = ""
    train_path: str = ""
    date_s: float = float("nan")  # POSIX seconds (UTC when the date has no zone), NaN without a date

    def columns(self) -> dict[str, object]:
        """The manifest columns of a runs.parquet row."""
        return {"index": self.index, **{c: getattr(self, c) for c in COLUMNS}}


def parse_date(text: str) -> float:
    """ISO 8601 date or date-time -> POSIX seconds (UTC when no zone is given); ValueError when it is neither."""
    stamp = datetime.fromisoformat(text.strip().replace("Z", "+00:00"))
    if stamp.tzinfo is None:
        stamp = stamp.replace(tzinfo=timezone.utc)
    return stamp.timestamp()


def _resolve(base: Path, value: str, bundled=None) -> str:
    path = Path(value).expanduser()
    if not path.is_absolute():
        path = base / path
    if bundled is not None and not path.exists():
        named = bundled(value)
        if named.exists():
            return str(named.resolve())
    return str(path.resolve())


def read_manifest(path: str | Path) -> list[ManifestRow]:
    """Parse and check the manifest; any problem raises ManifestError naming the file, line and column."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8-sig")
    except FileNotFoundError:
        raise ManifestError(f"{path}: no such file") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ManifestError(f"{path}: unreadable ({exc.__class__.__name__}: {exc})") from None
    base = path.resolve().parent
    reader = csv.reader(text.splitlines())
    try:
        header = [h.strip() for h in next(reader)]
    except StopIteration:
        raise ManifestError(f"{path}: empty (a header with {','.join(REQUIRED)} is needed)") from None
    missing = [c for c in REQUIRED if c not in header]
    if missing:
        raise ManifestError(f"{path}:1: header: missing column(s) {', '.join(missing)} (found {','.join(header)})")
    dupes = sorted({h for h in header if header.count(h) > 1})
    if dupes:
        raise ManifestError(f"{path}:1: header: column(s) {', '.join(dupes)} given twice")
    rows: list[ManifestRow] = []
    for line_no, fields in enumerate(reader, start=2):
        if not fields or all(not f.strip() for f in fields):
            continue
        if len(fields) != len(header):
            raise ManifestError(f"{path}:{line_no}: {len(fields)} fields, the header has {len(header)}")
        values = {h: f.strip() for h, f in zip(header, fields) if h in COLUMNS}
        for c in REQUIRED:
            if not values[c]:
                raise ManifestError(f"{path}:{line_no}: {c}: empty")
        date_s = float("nan")
        if values.get("date"):
            try:
                date_s = parse_date(values["date"])
            except ValueError:
                raise ManifestError(f"{path}:{line_no}: date: {values['date']!r} is not ISO 8601") from None
        rows.append(
            ManifestRow(
                index=len(rows),
                bag=values["bag"],
                track=values["track"],
                train=values["train"],
                unit=values["unit"],
                date=values.get("date", ""),
                driver=values.get("driver", ""),
                line=values.get("line", ""),
                bag_path=_resolve(base, values["bag"]),
                track_path=_resolve(base, values["track"], track_file),
                train_path=_resolve(base, values["train"], train_file),
                date_s=date_s,
            )
        )
    if not rows:
        raise ManifestError(f"{path}: no runs (only a header)")
    return rows
