"""Test helper: a bag's input topics exported as the logs a recorder writes (CSV, NMEA 0183, GPX 1.1).

Each writer takes the bag's streams (``bag_streams``) and writes a file that ``train-calib import`` reads back.
NMEA and GPX carry speed only at the fixes' epochs (a receiver's speed), so they are used on runs whose speed and
GNSS share their stamps; CSV writes every stream at its own stamps.
"""

from __future__ import annotations

import math
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

from train_calib import bagio
from train_calib.importers.nmea import checksum
from train_calib.importers.records import Streams


def bag_streams(bag: str | Path) -> Streams:
    """The fixes (with a fix), speeds and powers of a bag."""
    gnss, speed, power = [], [], []
    for m in bagio.iter_bag(bag, bagio.INPUT_TOPICS):
        msg = m.decode()
        t = bagio.stamp_ns(msg.header)
        if m.topic == bagio.GNSS_TOPIC and int(msg.status.status) >= 0:
            gnss.append((t, float(msg.latitude), float(msg.longitude), float(msg.altitude)))
        elif m.topic == bagio.SPEED_TOPIC:
            speed.append((t, float(msg.twist.linear.x)))
        elif m.topic == bagio.POWER_TOPIC:
            power.append((t, float(msg.power_consumed), float(msg.power_regenerated)))
    return Streams.from_lists(gnss, speed, power)


def _iso(t_ns: int) -> str:
    whole, frac = divmod(int(t_ns), 1_000_000_000)
    stamp = datetime.fromtimestamp(whole, tz=timezone.utc).strftime("%Y-%m-%dT%H:%M:%S")
    return f"{stamp}.{frac // 1000:06d}Z"


def write_csv(streams: Streams, path: Path, *, speed_kmh: bool = True, iso: bool = False) -> Path:
    """One CSV, one row per distinct stamp; empty cells where a stream has no sample at that stamp."""
    rows: dict[int, dict[str, str]] = {}
    for t, lat, lon in zip(streams.gnss_t_ns, streams.lat, streams.lon):
        rows.setdefault(int(t), {}).update(lat=f"{lat:.8f}", lon=f"{lon:.8f}")
    for t, v in zip(streams.speed_t_ns, streams.speed_ms):
        rows.setdefault(int(t), {})["speed"] = f"{v * 3.6:.4f}" if speed_kmh else f"{v:.5f}"
    for t, pc, pr in zip(streams.power_t_ns, streams.consumed_w, streams.regenerated_w):
        rows.setdefault(int(t), {}).update(pc=f"{pc:.1f}", pr=f"{pr:.1f}")
    speed_col = "speed_kmh" if speed_kmh else "speed_ms"
    header = ["time", "lat", "lon", speed_col]
    keys = ["lat", "lon", "speed"]
    if streams.power_t_ns.size:
        header += ["power_consumed_w", "power_regenerated_w"]
        keys += ["pc", "pr"]
    lines = [",".join(header)]
    for t in sorted(rows):
        cell = _iso(t) if iso else f"{t * 1e-9:.6f}"
        lines.append(",".join([cell] + [rows[t].get(k, "") for k in keys]))
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


def _nmea(body: str) -> str:
    return f"${body}*{checksum(body):02X}"


def _ddmm(value: float, degree_digits: int, hemis: str) -> tuple[str, str]:
    hemi = hemis[0] if value >= 0 else hemis[1]
    value = abs(value)
    deg = int(value)
    minutes = (value - deg) * 60.0
    return f"{deg:0{degree_digits}d}{minutes:09.6f}", hemi


def write_nmea(streams: Streams, path: Path) -> Path:
    """GGA + RMC + VTG per fix epoch (speed linearly interpolated to it), 10 ms times, 1e-6 minute positions."""
    v = np.interp(streams.gnss_t_ns, streams.speed_t_ns, streams.speed_ms)
    lines = []
    for t, lat, lon, alt, speed in zip(streams.gnss_t_ns, streams.lat, streams.lon, streams.alt, v):
        whole, frac = divmod(int(t), 1_000_000_000)
        stamp = datetime.fromtimestamp(whole, tz=timezone.utc)
        hms = stamp.strftime("%H%M%S") + f".{frac // 10_000_000:02d}"
        date = stamp.strftime("%d%m%y")
        la, lh = _ddmm(lat, 2, "NS")
        lo, oh = _ddmm(lon, 3, "EW")
        ele = f"{alt:.1f}" if math.isfinite(alt) else ""
        knots = speed * 3600.0 / 1852.0
        lines.append(_nmea(f"GPGGA,{hms},{la},{lh},{lo},{oh},1,08,0.9,{ele},M,47.0,M,,"))
        lines.append(_nmea(f"GPRMC,{hms},A,{la},{lh},{lo},{oh},{knots:.3f},90.0,{date},,,A"))
        lines.append(_nmea(f"GPVTG,90.0,T,,M,{knots:.3f},N,{speed * 3.6:.3f},K,A"))
    path.write_text("\r\n".join(lines) + "\r\n", encoding="ascii")
    return path


def write_gpx(streams: Streams, path: Path, *, with_speed: bool = True) -> Path:
    """GPX 1.1, one trkpt per fix, speed (m/s, interpolated to the fix) in Garmin's TrackPointExtension v2."""
    v = np.interp(streams.gnss_t_ns, streams.speed_t_ns, streams.speed_ms)
    out = [
        '<?xml version="1.0" encoding="UTF-8"?>',
        '<gpx version="1.1" creator="train_calib test" xmlns="http://www.topografix.com/GPX/1/1" '
        'xmlns:gpxtpx="http://www.garmin.com/xmlschemas/TrackPointExtension/v2">',
        "<trk><name>run</name><trkseg>",
    ]
    for t, lat, lon, alt, speed in zip(streams.gnss_t_ns, streams.lat, streams.lon, streams.alt, v):
        ele = f"<ele>{alt:.2f}</ele>" if math.isfinite(alt) else ""
        ext = (
            f"<extensions><gpxtpx:TrackPointExtension><gpxtpx:speed>{speed:.4f}</gpxtpx:speed>"
            "</gpxtpx:TrackPointExtension></extensions>"
            if with_speed
            else ""
        )
        out.append(f'<trkpt lat="{lat:.8f}" lon="{lon:.8f}">{ele}<time>{_iso(int(t))}</time>{ext}</trkpt>')
    out += ["</trkseg></trk>", "</gpx>"]
    path.write_text("\n".join(out) + "\n", encoding="utf-8")
    return path
