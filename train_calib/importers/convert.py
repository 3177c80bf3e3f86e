"""Logs to a bag: read each file in its format, merge, sort, check the speed units, write the input topics."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from .. import bagio
from .checks import SpeedCheck, check_speed_units, refuse, sort_streams
from .csvlog import read_csv
from .detect import resolve_format
from .gpx import read_gpx
from .nmea import read_nmea
from .records import ImportFormatError, RowLog, Streams

DEFAULT_START_NS = 1_577_836_800_000_000_000  # 2020-01-01T00:00:00Z: origin of times in s since the log's start


@dataclass
class ImportOptions:
    """How to read the logs. ``gnss_sigma_m``: 1-sigma horizontal error written as the fix covariance, m."""

    fmt: str | None = None
    columns: dict[str, str] = field(default_factory=dict)
    speed_unit: str | None = None
    time_unit: str = "s"
    start_ns: int = DEFAULT_START_NS
    gnss_sigma_m: float = 5.0
    speed_check: bool = True


@dataclass
class ImportResult:
    """What was imported: per-file formats, the rows log, sorting counts, the speed check, samples written."""

    formats: dict[str, str]
    log: RowLog
    sorting: dict[str, int]
    speed_check: SpeedCheck
    fixes: int
    speeds: int
    powers: int
    notes: list[str] = field(default_factory=list)


def _read_text(path: Path) -> str:
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        raise ImportFormatError(f"{path}: no such file") from None
    except OSError as exc:
        raise ImportFormatError(f"{path}: cannot read: {exc.strerror or exc}") from None
    if b"\x00" in data[:4096]:
        raise ImportFormatError(f"{path}: a binary file, not a CSV, NMEA or GPX log")
    return data.decode("utf-8", errors="replace")


def read_logs(paths: Sequence[Path], options: ImportOptions) -> tuple[Streams, dict[str, str], RowLog, list[str]]:
    """Every log read and merged (unsorted), with the format of each, the bad rows and notes to print."""
    log = RowLog()
    merged = Streams()
    formats: dict[str, str] = {}
    notes: list[str] = []
    for path in paths:
        text = _read_text(path)
        fmt = resolve_format(path, text, options.fmt)
        formats[str(path)] = fmt
        if fmt == "csv":
            streams = read_csv(
                path, text, log, columns=options.columns, speed_unit=options.speed_unit,
                time_unit=options.time_unit, start_ns=options.start_ns,
            )  # fmt: skip
        elif fmt == "nmea":
            streams = read_nmea(path, text, log)
        else:
            streams, derived = read_gpx(path, text, log)
            if derived:
                notes.append(f"{path}: no speed in the file: speed derived from the positions")
        merged = merged.merged(streams)
    return merged, formats, log, notes


def import_logs(
    paths: Sequence[Path], out: Path, options: ImportOptions, say: Callable[[str], None] = print
) -> ImportResult:
    """Read, check and write ``out`` (rosbag2 directory, MCAP); ImportFormatError when nothing usable is left."""
    streams, formats, log, notes = read_logs(paths, options)
    first = str(paths[0])
    if streams.gnss_t_ns.size == 0:
        raise ImportFormatError(f"{first}: no usable position in {log.rows} rows (the bag needs /gnss/fix)")
    if streams.speed_t_ns.size == 0:
        raise ImportFormatError(f"{first}: no usable speed in {log.rows} rows (the bag needs /train/speed)")
    streams, sorting = sort_streams(streams)
    check = check_speed_units(streams)
    if check.verdict == "refuse" and options.speed_check:
        refuse(check, first)
    write_bag(streams, out, options.gnss_sigma_m)
    for line in log.lines():
        say(line)
    for note in notes:
        say(note)
    for name in ("gnss", "speed", "power"):
        if sorting[f"{name}_unsorted"]:
            say(f"{name}: {sorting[name + '_unsorted']} samples out of time order: sorted")
        if sorting[f"{name}_duplicate"]:
            say(f"{name}: {sorting[name + '_duplicate']} samples at a time already taken: dropped")
    say(check.message)
    result = ImportResult(
        formats, log, sorting, check, int(streams.gnss_t_ns.size), int(streams.speed_t_ns.size),
        int(streams.power_t_ns.size), notes,
    )  # fmt: skip
    say(
        f"{out}: used {log.used} of {log.rows} rows ({len(log.problems)} bad): {result.fixes} fixes, "
        f"{result.speeds} speeds, {result.powers} power samples"
    )
    return result


def write_bag(streams: Streams, path: Path, gnss_sigma_m: float) -> None:
    """The input topics of INTERFACES.md in stamp order (log time = stamp), as the simulator writes them."""
    bagio.write_input_bag(
        path, gnss_t_ns=streams.gnss_t_ns, lat=streams.lat, lon=streams.lon, altitude=streams.alt,
        gnss_sigma_m=gnss_sigma_m, speed_t_ns=streams.speed_t_ns, speed_ms=streams.speed_ms,
        power=(streams.power_t_ns, streams.consumed_w, streams.regenerated_w) if streams.power_t_ns.size else None,
    )  # fmt: skip
