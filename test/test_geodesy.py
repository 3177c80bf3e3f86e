"""LocalFrame and its scalar twin ScalarEnu (the ingest's per-fix form)."""

from __future__ import annotations

import numpy as np
import pytest

from train_calib.geodesy import LocalFrame, ScalarEnu


@pytest.mark.parametrize("lat0, lon0", [(52.0, 4.4), (-33.9, 151.2), (64.1, -21.9)])
def test_scalar_enu_matches_the_frame_to_a_micrometre(lat0, lon0):
    frame = LocalFrame(lat0, lon0)
    enu = ScalarEnu(frame)
    rng = np.random.default_rng(3)
    lats = lat0 + rng.uniform(-0.3, 0.3, 200)
    lons = lon0 + rng.uniform(-0.3, 0.3, 200)
    east, north = frame.to_enu(lats, lons)
    for lat, lon, e, n in zip(lats, lons, east, north):
        e1, n1 = enu(float(lat), float(lon))
        assert abs(e1 - e) < 1e-6 and abs(n1 - n) < 1e-6
    assert enu(lat0, lon0) == pytest.approx((0.0, 0.0), abs=1e-6)


def test_scalar_enu_is_the_plain_formula_bit_for_bit():
    """ScalarEnu's floats are those of the plain formula (math.*, 1 - e^2 inline), which the ingest's outputs
    were recorded with: the same operations in the same order."""
    import math

    from train_calib.geodesy import WGS84_A, WGS84_E2

    frame = LocalFrame(47.37, 8.54)
    enu = ScalarEnu(frame)
    (r00, r01, r02), (r10, r11, r12) = enu._r
    o0, o1, o2 = enu._o
    rng = np.random.default_rng(9)
    for lat, lon in zip(47.37 + rng.uniform(-0.5, 0.5, 300), 8.54 + rng.uniform(-0.5, 0.5, 300)):
        lat_r, lon_r = math.radians(lat), math.radians(lon)
        sin_lat, cos_lat = math.sin(lat_r), math.cos(lat_r)
        n = WGS84_A / math.sqrt(1.0 - WGS84_E2 * sin_lat * sin_lat)
        d0 = n * cos_lat * math.cos(lon_r) - o0
        d1 = n * cos_lat * math.sin(lon_r) - o1
        d2 = n * (1.0 - WGS84_E2) * sin_lat - o2
        assert enu(float(lat), float(lon)) == (r00 * d0 + r01 * d1 + r02 * d2, r10 * d0 + r11 * d1 + r12 * d2)
