"""report.png's panels (issue 21): tunnels and GNSS gaps shaded, the gradient profile, traction power and the window
estimates only when the bag has power, legends outside the data. A synthetic run on the tunnel line, no ROS."""

from __future__ import annotations

import math

import numpy as np
import pytest

from train_calib import paths
from train_calib.report import build_report, flag_spans, tunnel_time_spans, write_report
from train_calib.summary_outputs import Outputs
from train_calib.track import load_track
from train_calib.train import load_train
from train_calib.window.fit import WindowFit

SPEED_MS = 30.0  # constant, so a position s is reached at s / SPEED_MS
GAP = slice(300, 311)  # measurements 300..310 without a fix


@pytest.fixture(scope="module")
def track():
    return load_track(paths.track_file("tunnel_line_37km"))


@pytest.fixture(scope="module")
def train():
    return load_train(paths.train_file("icrm"))


def _window(k: int, t_s: float) -> WindowFit:
    nan3 = (math.nan,) * 3
    return WindowFit(
        stamp_ns=int(t_s * 1e9), run_id=0, window_length=60.0, sample_count=60, gof_kind=1, gof_value=1.0,
        a=math.nan, b=math.nan, c=math.nan, r0=math.nan, r1=math.nan, r2=math.nan, regime=2, ill_posed=True,
        speed_span=0.5, estimate=nan3, resistance_speed=SPEED_MS, resistance_at_speed=0.04 + 1e-4 * k,
        resistance_at_speed_std=0.002, pooled=(0.018, 3e-4, 2.8e-5),
        pooled_covariance=tuple((np.diag([1e-6, 1e-10, 1e-12])).ravel()), pooled_windows=k + 1,
    )  # fmt: skip


def _outputs(track, power: bool) -> Outputs:
    """A 1 Hz run at 30 m/s over the whole line (s from 0 m), measurements 300..310 without a fix."""
    n = int(track.length_m / SPEED_MS)
    t = np.arange(n, dtype=float)
    s = SPEED_MS * t
    measured = np.ones(n, dtype=bool)
    measured[GAP] = False
    meas = {
        "t": t, "s": s, "v": np.full(n, SPEED_MS), "run_id": np.zeros(n, dtype=np.int64),
        "speed_limit": np.full(n, 44.0), "s_measured": measured, "track_force": track.track_force(s, 200.0),
        "tunnel_fraction": track.tunnel_fraction(s, 200.0), "power_valid": np.full(n, power),
        "power_consumed": np.full(n, 2.0e6 if power else 0.0), "power_regenerated": np.zeros(n),
    }  # fmt: skip
    est = {
        "t": t, "run_id": np.zeros(n, dtype=np.int64), "s": s, "v": np.full(n, SPEED_MS),
        "r0": np.full(n, 0.02), "r1": np.full(n, 3e-4), "r2": np.full(n, 3e-5), "std_r0": np.full(n, 1e-3),
        "std_r1": np.full(n, 1e-5), "std_r2": np.full(n, 1e-6), "effort": np.full(n, 0.05),
        "acceleration": np.zeros(n), "health": np.zeros(n), "effort_known": np.zeros(n, dtype=bool),
        "nis": np.ones(n), "effort_source": np.zeros(n),
    }  # fmt: skip
    regime = {"t": t, "regime": np.full(n, 2, dtype=np.int64), "v": np.full(n, SPEED_MS), "run_id": np.zeros(n)}
    out = Outputs(meas=meas, est=est, regime=regime, last_r_covariance=np.diag([1e-6, 1e-10, 1e-12]))
    if power:
        out.windows = [_window(k, 60.0 + k) for k in range(50)]
    return out


def test_flag_spans_run_from_last_good_to_next_good_sample():
    x = np.array([0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0])
    flag = np.array([True, False, True, True, False, False, True])
    assert flag_spans(x, flag) == [(0.0, 1.0), (1.0, 4.0), (5.0, 6.0)]
    assert flag_spans(x, np.zeros(7, dtype=bool)) == []


def test_tunnel_time_spans_interpolate_each_tunnel_in_both_directions(track):
    t = np.arange(0.0, 1300.0, 10.0)  # 10 s sampling: 300 m between samples, longer than the 270 m tunnel
    s = SPEED_MS * t
    spans = tunnel_time_spans(t, s, np.zeros(t.size), track, train_length_m=200.0)
    assert len(spans) == len(track.tunnels) == 4
    for (a, b), tunnel in zip(spans, track.tunnels):
        assert a == pytest.approx(tunnel.start_m / SPEED_MS, abs=1e-9)
        assert b == pytest.approx((tunnel.end_m + 200.0) / SPEED_MS, abs=1e-9)
    back = tunnel_time_spans(t, track.length_m - s, np.zeros(t.size), track, train_length_m=200.0)
    first = track.tunnels[-1]  # met first on the way back
    assert back[0] == pytest.approx(((track.length_m - first.end_m) / SPEED_MS,
                                     (track.length_m - first.start_m + 200.0) / SPEED_MS))  # fmt: skip
    assert len(back) == 4


@pytest.mark.parametrize("power", [False, True])
def test_report_panels_spans_power_and_windows(track, train, power):
    report = build_report(_outputs(track, power), train, track=track, truth={"r0": 0.018, "r1": 2.8e-4, "r2": 2.9e-5})
    axes = report.axes
    # tunnels: one span per tunnel on the profile and on every time panel, at the times the train was in it
    assert len([p for p in axes["profile"].patches if p.get_gid() == "tunnel"]) == len(track.tunnels) == 4
    assert len(report.tunnel_spans_min) == 4
    for (a, b), tunnel in zip(report.tunnel_spans_min, track.tunnels):
        assert a == pytest.approx(tunnel.start_m / SPEED_MS / 60.0)
        assert b == pytest.approx((tunnel.end_m + train.length_m) / SPEED_MS / 60.0)
    for name in ("speed", "acceleration", "effort", "r0", "r1", "r2"):
        assert len([p for p in axes[name].patches if p.get_gid() == "tunnel"]) == 4
        assert len([p for p in axes[name].patches if p.get_gid() == "gnss_gap"]) == 1
    # the GNSS gap: from the last fix before it (t = 299 s) to the first after it (311 s); along s likewise
    assert report.gap_spans_min == [pytest.approx((299 / 60.0, 311 / 60.0))]
    assert report.gap_spans_km == [pytest.approx((299 * SPEED_MS / 1000.0, 311 * SPEED_MS / 1000.0))]
    # gradient profile: the track's step line in per mille
    step = next(line for line in axes["profile"].get_lines() if line.get_label().startswith("gradient"))
    assert np.nanmax(np.abs(step.get_ydata())) == pytest.approx(np.max(np.abs(track.gradient.values)) * 1000.0)
    # power and the window estimates only with power
    rv_gids = {line.get_gid() for line in axes["rv"].get_lines()}
    if power:
        assert axes["power"] is not None
        consumed = next(line for line in axes["power"].get_lines() if line.get_gid() == "power_consumed")
        assert np.nanmax(consumed.get_ydata()) == pytest.approx(2.0)  # MW
        assert {"window_points", "window_pooled"} <= rv_gids
        points = next(line for line in axes["rv"].get_lines() if line.get_gid() == "window_points")
        assert len(points.get_xdata()) == 50 and points.get_xdata()[0] == pytest.approx(SPEED_MS * 3.6)
    else:
        assert axes["power"] is None
        assert not {"window_points", "window_pooled"} & rv_gids
    # every legend lies right of its axes: none covers data
    report.fig.canvas.draw()
    for name, ax in axes.items():
        if ax is None:
            continue
        legend = ax.get_legend()
        assert legend is not None, name
        assert legend.get_window_extent().x0 >= ax.get_window_extent().x1, name
    import matplotlib.pyplot as plt

    plt.close(report.fig)


def test_report_without_track_takes_tunnels_from_the_measurements(track, train, tmp_path):
    report = build_report(_outputs(track, False), train)
    assert len(report.tunnel_spans_min) == 4 and len(report.tunnel_spans_km) == 4
    path = write_report(tmp_path / "report.png", _outputs(track, True), train, track=track, configuration="learning")
    assert path.stat().st_size > 50_000
