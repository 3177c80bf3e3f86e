"""build-track with runs recorded in both directions: each run's direction detected against the first, reversed
before averaging; one polyline, the same stations, tunnel and profile alignment as from runs all one way."""

from __future__ import annotations

import numpy as np
import pytest
import yaml
from logexport import bag_streams
from repo_paths import REPO

from train_calib import bagio, cli
from train_calib.paths import track_file, train_file
from train_calib.pipeline import run_bag
from train_calib.track import load_track
from train_calib.train import load_train

BAGS = sorted((REPO / "bags").glob("intercity_32km_10s_0?"))[:4]
V_REF = 80.0 / 3.6


def _profile_csvs(folder):
    data = yaml.safe_load(track_file("intercity_32km").read_text())
    out = []
    for key, column in (("gradients", "permille"), ("speed_limits", "kmh")):
        path = folder / f"{key}.csv"
        path.write_text(f"s_m,{column}\n" + "".join(f"{e['s_m']},{e[column]}\n" for e in data[key]))
        out.append(str(path))
    return out


def _backwards(bag, out):
    """The run driven the other way: every sample at t_first + t_last - t (the same places, in reverse order)."""
    st = bag_streams(bag)
    t0 = int(min(st.gnss_t_ns[0], st.speed_t_ns[0]))
    t1 = int(max(st.gnss_t_ns[-1], st.speed_t_ns[-1]))
    bagio.write_input_bag(
        out, gnss_t_ns=(t0 + t1 - st.gnss_t_ns)[::-1], lat=st.lat[::-1], lon=st.lon[::-1], altitude=st.alt[::-1],
        gnss_sigma_m=4.0, speed_t_ns=(t0 + t1 - st.speed_t_ns)[::-1], speed_ms=st.speed_ms[::-1],
    )  # fmt: skip
    return out


def _build(folder, bags, name):
    out = folder / f"{name}.yaml"
    argv = ["build-track", "--gnss", *map(str, bags), "--profile", *_profile_csvs(folder), "--profile-stops",
            "300,32403", "--name", name, "--out", str(out)]  # fmt: skip
    assert cli.main(argv) == 0
    return out


@pytest.fixture(scope="module")
def tracks(tmp_path_factory):
    folder = tmp_path_factory.mktemp("directions")
    one_way = _build(folder, BAGS, "one_way")
    mixed_bags = [BAGS[0], _backwards(BAGS[1], folder / "b1"), BAGS[2], _backwards(BAGS[3], folder / "b3")]
    mixed = _build(folder, mixed_bags, "mixed")
    return load_track(one_way), load_track(mixed), mixed.read_text()


def test_mixed_directions_give_the_one_way_track(tracks):
    """Runs 2 and 4 driven the other way (played backwards): detected, reversed, and the track is the one-way
    track (measured: length, stations, geometry, tunnel, gradient steps identical to 1e-9 m)."""
    one_way, mixed, text = tracks
    assert "b1, b3 recorded the other way than intercity_32km_10s_00: reversed before averaging" in text
    assert mixed.length_m == pytest.approx(one_way.length_m, abs=1.0)
    assert [s.s_m for s in mixed.stations] == pytest.approx([s.s_m for s in one_way.stations], abs=1.0)
    s = np.arange(300.0, 32400.0, 250.0)
    la, lo = mixed.latlon_at(s)
    e, n = one_way.to_enu(la, lo)
    proj = np.array([one_way.project(a, b) for a, b in zip(e, n)])
    assert np.max(np.abs(proj[:, 1])) < 1.0 and np.max(np.abs(proj[:, 0] - s)) < 1.0
    assert len(mixed.tunnels) == 1 == len(one_way.tunnels)
    assert mixed.tunnels[0].start_m == pytest.approx(9100.0, abs=80.0)
    assert mixed.tunnels[0].end_m == pytest.approx(10150.0, abs=80.0)
    # the profile mapped the same way: the same gradient steps, at the same places
    assert np.array_equal(mixed.gradient.values, one_way.gradient.values)
    assert np.max(np.abs(mixed.gradient.breaks - one_way.gradient.breaks)) < 1.0


def test_mixed_directions_track_gives_the_same_estimates(tracks):
    """r(80 km/h) of a forward run replayed on the mixed-direction track against the one-way track (measured: equal
    on all four runs); bound 0.1 %."""
    one_way, mixed, _ = tracks
    train = load_train(train_file("virm6"))
    a, b = run_bag(BAGS[2], one_way, train), run_bag(BAGS[2], mixed, train)
    r = [e.r0 + e.r1 * V_REF + e.r2 * V_REF**2 for e in (a.final, b.final)]
    assert r[1] == pytest.approx(r[0], rel=1e-3)
