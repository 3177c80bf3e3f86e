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
