"""WGS84 geodetic coordinates to a local East-North-Up plane and back (vectorised).

The track polyline and the GNSS fixes are compared in a local tangent plane centred on the track,
which is exact to well below a millimetre at the scale of a line (tens of km) for positions on the
ellipsoid; heights are ignored (rail GNSS altitude is not used).
"""

from __future__ import annotations

from dataclasses import dataclass
from math import cos, radians, sin, sqrt

import numpy as np

WGS84_A = 6378137.0  # semi-major axis, m
WGS84_F = 1.0 / 298.257223563
WGS84_E2 = WGS84_F * (2.0 - WGS84_F)  # first eccentricity squared
_ONE_MINUS_E2 = 1.0 - WGS84_E2


def geodetic_to_ecef(lat_deg, lon_deg, h_m=0.0) -> np.ndarray:
    """ECEF coordinates (..., 3) in m of geodetic latitude/longitude in degrees and height in m."""
    lat = np.radians(np.asarray(lat_deg, dtype=float))
    lon = np.radians(np.asarray(lon_deg, dtype=float))
    sin_lat, cos_lat = np.sin(lat), np.cos(lat)
    n = WGS84_A / np.sqrt(1.0 - WGS84_E2 * sin_lat**2)
    h = np.asarray(h_m, dtype=float)
    x = (n + h) * cos_lat * np.cos(lon)
    y = (n + h) * cos_lat * np.sin(lon)
    z = (n * (1.0 - WGS84_E2) + h) * sin_lat
    return np.stack(np.broadcast_arrays(x, y, z), axis=-1)


def ecef_to_geodetic(ecef: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Latitude, longitude (degrees) and height (m) of ECEF points (..., 3); Bowring, then 2 iterations."""
    x, y, z = ecef[..., 0], ecef[..., 1], ecef[..., 2]
    lon = np.arctan2(y, x)
    p = np.hypot(x, y)
    lat = np.arctan2(z, p * (1.0 - WGS84_E2))
    for _ in range(4):
        sin_lat = np.sin(lat)
        n = WGS84_A / np.sqrt(1.0 - WGS84_E2 * sin_lat**2)
        h = p / np.cos(lat) - n
        lat = np.arctan2(z, p * (1.0 - WGS84_E2 * n / (n + h)))
    sin_lat = np.sin(lat)
    n = WGS84_A / np.sqrt(1.0 - WGS84_E2 * sin_lat**2)
    h = p / np.cos(lat) - n
    return np.degrees(lat), np.degrees(lon), h


@dataclass(frozen=True)
class LocalFrame:
    """East-North-Up tangent plane at a reference point (degrees)."""

    lat0_deg: float
    lon0_deg: float

    @property
    def _rotation(self) -> np.ndarray:
        lat, lon = np.radians(self.lat0_deg), np.radians(self.lon0_deg)
        sl, cl, so, co = np.sin(lat), np.cos(lat), np.sin(lon), np.cos(lon)
        # rows: east, north, up expressed in ECEF
        return np.array([[-so, co, 0.0], [-sl * co, -sl * so, cl], [cl * co, cl * so, sl]])

    @property
    def _origin(self) -> np.ndarray:
        return geodetic_to_ecef(self.lat0_deg, self.lon0_deg)

    def to_enu(self, lat_deg, lon_deg) -> tuple[np.ndarray, np.ndarray]:
        """East and north (m) of points on the ellipsoid."""
        d = geodetic_to_ecef(lat_deg, lon_deg) - self._origin
        enu = d @ self._rotation.T
        return enu[..., 0], enu[..., 1]

    def to_geodetic(self, east_m, north_m) -> tuple[np.ndarray, np.ndarray]:
        """Latitude and longitude (degrees) of the ellipsoid point below local (east, north).

        The local plane point is lifted by the plane's drop below the ellipsoid (up = 0 is the
        tangent plane), then projected to the ellipsoid along its normal; round trips agree with
        ``to_enu`` to micrometres over tens of km.
        """
        east = np.asarray(east_m, dtype=float)
        north = np.asarray(north_m, dtype=float)
        up = np.zeros(np.broadcast(east, north).shape)
        rot = self._rotation
        for _ in range(3):  # find the up offset that puts the point on the ellipsoid (h = 0)
            enu = np.stack(np.broadcast_arrays(east, north, up), axis=-1)
            ecef = enu @ rot + self._origin
            lat, lon, h = ecef_to_geodetic(ecef)
            up = up - h
        return lat, lon


class ScalarEnu:
    """WGS84 -> a LocalFrame's east/north (m) for one point in degrees: ``LocalFrame.to_enu`` on plain floats,
    with the frame's origin and rotation computed once (float64 either way; Python floats skip numpy's scalar
    overhead per sample)."""

    def __init__(self, frame: LocalFrame) -> None:
        self._o = tuple(float(x) for x in geodetic_to_ecef(frame.lat0_deg, frame.lon0_deg))
        self._r = tuple(tuple(float(x) for x in row) for row in frame._rotation[:2])
        self._constants = (*self._o, *self._r[0], *self._r[1])  # origin (m), east and north rows: one unpacking

    def __call__(self, lat: float, lon: float) -> tuple[float, float]:
        lat_r, lon_r = radians(lat), radians(lon)
        sin_lat, cos_lat = sin(lat_r), cos(lat_r)
        n = WGS84_A / sqrt(1.0 - WGS84_E2 * sin_lat * sin_lat)
        o0, o1, o2, r00, r01, r02, r10, r11, r12 = self._constants
        d0, d1, d2 = (n * cos_lat * cos(lon_r) - o0, n * cos_lat * sin(lon_r) - o1,
                      n * _ONE_MINUS_E2 * sin_lat - o2)  # fmt: skip
        return r00 * d0 + r01 * d1 + r02 * d2, r10 * d0 + r11 * d1 + r12 * d2
