"""Which format a log is, from its content."""

from __future__ import annotations

from pathlib import Path

from .records import ImportFormatError

FORMATS = ("csv", "nmea", "gpx")


def sniff(text: str) -> str | None:
    """``gpx``, ``nmea`` or ``csv`` when the content says so unambiguously, else None."""
    head = text.lstrip("\ufeff \t\r\n")[:4096]
    if head.startswith("<"):
        return "gpx" if "<gpx" in head else None
    lines = [ln.strip() for ln in head.splitlines() if ln.strip()]
    if not lines:
        return None
    if lines[0].startswith(("$", "!")):
        return "nmea"
    first = lines[0]
    if any(sep in first for sep in (",", ";", "\t")) and not first[0].isdigit():
        return "csv"
    return None


def resolve_format(path: Path, text: str, requested: str | None) -> str:
    """The format to read ``path`` with; a file that is not the ``requested`` format raises ImportFormatError."""
    found = sniff(text)
    if requested is None:
        if found is None:
            raise ImportFormatError(f"{path}: cannot tell the format from the content: give --format csv|nmea|gpx")
        return found
    if found is not None and found != requested:
        raise ImportFormatError(f"{path}: not a {requested.upper()} file (its content looks like {found.upper()})")
    if found is None and requested == "csv" and text.strip():
        raise ImportFormatError(f"{path}: no CSV header row (the first line names the columns: time,lat,lon,...)")
    if found is None:
        raise ImportFormatError(f"{path}: not a {requested.upper()} file")
    return requested
