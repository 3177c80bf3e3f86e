"""Track occupation/release events (train describer records) and their CSV file format.

A train describer (TROTS in the Netherlands) logs, per train run, the time each track-detection
section is *occupied* (the head enters it) and *released* (the tail leaves it, seen after the
release delay of the track circuit). Times are rounded down to the full second.

CSV format (UTF-8, comma separated, one event per line, ``#`` lines are comments)::

    run_id,section_id,event,time
    IC1913-2010-04-12,S07,occupy,25953
    IC1913-2010-04-12,S06,release,25961

- ``run_id``: any non-empty text naming one train run (train number + date, say).
- ``section_id``: the ``id`` of a section in the track file's ``sections``.
- ``event``: ``occupy`` or ``release``.
- ``time``: seconds (a number, any epoch, typically whole seconds) or an ISO 8601 timestamp
  (``2010-04-12T07:12:33``, naive = UTC); one style per file.

Extra columns are ignored. Rows may come in any order. A duplicate (run, section, event), an unknown
event kind, a section the track does not have or an unreadable time refuses the file with one line
``<file>: line <n>: <problem>``. Inconsistencies inside one run (a release before its occupation)
do not refuse the file: the unhindered-run filter drops that run with the reason recorded.
"""

from __future__ import annotations

import csv
import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

from ..errors import ConfigError

EVENT_KINDS = ("occupy", "release")
REQUIRED_COLUMNS = ("run_id", "section_id", "event", "time")


@dataclass
class RunEvents:
    """The occupation and release times (s) of one train run, by section id."""

    run_id: str
    occupy: dict[str, float] = field(default_factory=dict)
    release: dict[str, float] = field(default_factory=dict)

    def times(self, kind: str, section_ids: Sequence[str]) -> np.ndarray:
        """Times (s) of ``kind`` events for the given sections in that order; NaN where missing."""
        table = self.occupy if kind == "occupy" else self.release
        return np.array([table.get(sid, np.nan) for sid in section_ids], dtype=float)

    @property
    def n_events(self) -> int:
        return len(self.occupy) + len(self.release)

    def first_time(self) -> float:
        """Earliest event time of the run, s (NaN for an empty run)."""
        values = [*self.occupy.values(), *self.release.values()]
        return min(values) if values else math.nan


def load_events(path: str | Path, section_ids: Iterable[str] | None = None) -> dict[str, RunEvents]:
    """Read an occupation CSV into runs (in order of first appearance); see the module docstring.

    ``section_ids``: the track's section ids; rows naming another section are refused.
    """
    path = Path(path)
    source = str(path)
    known = set(section_ids) if section_ids is not None else None
    try:
        handle = path.open(newline="", encoding="utf-8")
    except FileNotFoundError:
        raise ConfigError(source, "", "occupation events file not found") from None
    except OSError as exc:
        raise ConfigError(source, "", f"cannot read occupation events file: {exc}") from None
    runs: dict[str, RunEvents] = {}
    time_style: str | None = None
    with handle:
        lines = ((n, line) for n, line in enumerate(handle, start=1) if line.strip() and not line.startswith("#"))
        try:
            header_no, header_line = next(lines)
        except StopIteration:
            raise ConfigError(source, "", "empty file: expected the header run_id,section_id,event,time") from None
        except UnicodeDecodeError as exc:
            raise ConfigError(source, "", f"not UTF-8 text: {exc.reason}") from None
        header = [h.strip() for h in next(csv.reader([header_line]))]
        missing = [c for c in REQUIRED_COLUMNS if c not in header]
        if missing:
            raise ConfigError(
                source, f"line {header_no}", f"header lacks column(s) {', '.join(missing)} (found {', '.join(header)})"
            )
        col = {c: header.index(c) for c in REQUIRED_COLUMNS}
        width = max(col.values()) + 1
        try:
            for line_no, line in lines:
                row = next(csv.reader([line]))
                where = f"line {line_no}"
                if len(row) < width:
                    raise ConfigError(source, where, f"expected at least {width} columns, found {len(row)}")
                run_id = row[col["run_id"]].strip()
                section = row[col["section_id"]].strip()
                kind = row[col["event"]].strip().lower()
                if not run_id:
                    raise ConfigError(source, where, "empty run_id")
                if not section:
                    raise ConfigError(source, where, "empty section_id")
                if known is not None and section not in known:
                    raise ConfigError(source, where, f"section {section!r} is not a section of the track")
                if kind not in EVENT_KINDS:
                    raise ConfigError(source, where, f"event {kind!r} is not one of {', '.join(EVENT_KINDS)}")
                value, style = _parse_time(row[col["time"]].strip())
                if style is None:
                    raise ConfigError(
                        source, where, f"time {row[col['time']].strip()!r} is neither seconds nor an ISO 8601 timestamp"
                    )
                if time_style is None:
                    time_style = style
                elif style != time_style:
                    raise ConfigError(
                        source, where, f"time {row[col['time']].strip()!r} mixes {style} with {time_style}"
                    )
                run = runs.setdefault(run_id, RunEvents(run_id))
                table = run.occupy if kind == "occupy" else run.release
                if section in table:
                    raise ConfigError(source, where, f"duplicate {kind} of section {section!r} in run {run_id!r}")
                table[section] = value
        except UnicodeDecodeError as exc:
            raise ConfigError(source, "", f"not UTF-8 text: {exc.reason}") from None
    if not runs:
        raise ConfigError(source, "", "no events after the header")
    return runs


def write_events(path: str | Path, runs: Iterable[RunEvents], comments: Sequence[str] = ()) -> Path:
    """Write runs in the CSV format (times in seconds, events of a run in time order)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("w", newline="", encoding="utf-8") as f:
        for text in comments:
            f.write(f"# {text}\n")
        writer = csv.writer(f, lineterminator="\n")
        writer.writerow(REQUIRED_COLUMNS)
        for run in runs:
            rows = [(t, sid, "occupy") for sid, t in run.occupy.items()]
            rows += [(t, sid, "release") for sid, t in run.release.items()]
            rows.sort(key=lambda r: (r[0], r[2] == "occupy"))
            for t, sid, kind in rows:
                writer.writerow((run.run_id, sid, kind, _format_time(t)))
    return path


def _parse_time(text: str) -> tuple[float, str | None]:
    try:
        value = float(text)
    except ValueError:
        pass
    else:
        return (value, "seconds") if math.isfinite(value) else (value, None)
    try:
        stamp = datetime.fromisoformat(text)
    except ValueError:
        return math.nan, None
    if stamp.tzinfo is None:
        stamp = stamp.replace(tzinfo=timezone.utc)
    return stamp.timestamp(), "ISO 8601 timestamps"


def _format_time(t: float) -> str:
    return str(int(t)) if float(t).is_integer() else repr(float(t))
