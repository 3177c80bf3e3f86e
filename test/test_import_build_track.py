"""train-calib build-track: geometry averaged from runs' GNSS, stations from their stops, profile mapped by stops."""

from __future__ import annotations

import numpy as np
import pytest
import yaml
from repo_paths import REPO

from train_calib import cli
from train_calib.errors import ConfigError
from train_calib.paths import track_file, train_file
from train_calib.pipeline import run_bag
from train_calib.track import load_track
from train_calib.train import load_train

BAGS = sorted((REPO / "bags").glob("intercity_32km_10s_0?"))
V_REF = 80.0 / 3.6


def r_at(davis_like, v: float = V_REF) -> float:
    return davis_like.r0 + davis_like.r1 * v + davis_like.r2 * v * v


def profile_csvs(track_path, folder):
    """The bundled track's gradients, limits and curves as the CSV tables a railway engineer has."""
    data = yaml.safe_load(track_path.read_text())
    out = []
    for key, column, name in (("gradients", "permille", "grad"), ("speed_limits", "kmh", "lim"),
                              ("curves", "radius_m", "curves")):  # fmt: skip
        path = folder / f"{name}.csv"
        path.write_text(f"s_m,{column}\n" + "".join(f"{e['s_m']},{e[column]}\n" for e in data[key]))
        out.append(str(path))
    return out


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    folder = tmp_path_factory.mktemp("built")
    out = folder / "ic.yaml"
    argv = ["build-track", "--gnss", *map(str, BAGS), "--profile", *profile_csvs(track_file("intercity_32km"), folder),
            "--profile-stops", "300,32403", "--name", "ic_built", "--out", str(out)]  # fmt: skip
    assert cli.main(argv) == 0
    return load_track(out)


def test_built_geometry_matches_the_bundled_track(built):
    ref = load_track(track_file("intercity_32km"))
    assert abs(built.length_m - ref.length_m) < 50.0  # measured: 12 m over 32.7 km
    assert [round(s.s_m) for s in built.stations] == pytest.approx([300, 32403], abs=20)
    s = np.arange(300.0, 32403.0, 250.0)  # between the stops (beyond them: a straight extension, assumed)
    lat, lon = built.latlon_at(s)
    e, n = ref.to_enu(lat, lon)
    proj = np.array([ref.project(a, b) for a, b in zip(e, n)])
    tunnel = (s > 9100.0) & (s < 10150.0)  # no fixes: a straight chord across the curve (R 4000 m: sagitta 34 m)
    assert np.max(proj[~tunnel, 1]) < 10.0 and np.max(proj[tunnel, 1]) < 40.0  # cross-track, m
    assert np.max(np.abs(proj[:, 0] - s)) < 40.0  # chainage, m; measured 8.7 m (cross-track 4.6 m, in the tunnel 30 m)


def test_built_track_marks_the_tunnel(built):
    """The bundled runs lose their fixes in the 1,050 m tunnel at 9,100-10,150 m (10 s fixes at ~38 m/s: each run
    bounds each edge to ~385 m; five runs' different phases narrow it). Measured 9,065-10,187 m, edges +-31 m."""
    assert len(built.tunnels) == 1
    assert built.tunnels[0].start_m == pytest.approx(9100.0, abs=80.0)
    assert built.tunnels[0].end_m == pytest.approx(10150.0, abs=80.0)


def test_built_track_gives_the_bundled_tracks_estimates(built):
    """r(80 km/h) from the built track and from the bundled one: measured within 0.03 % (final and best) on all
    five bundled runs, with the tunnel found in the built track (0.02 % without it); bound 0.5 %."""
    ref = load_track(track_file("intercity_32km"))
    train = load_train(train_file("virm6"))
    for bag in BAGS:
        a, b = run_bag(bag, ref, train), run_bag(bag, built, train)
        assert r_at(b.final) == pytest.approx(r_at(a.final), rel=5e-3), bag.name
        assert r_at(b.best) == pytest.approx(r_at(a.best), rel=5e-3), bag.name


def test_gradients_from_altitude_state_their_uncertainty(tmp_path):
    """No profile: gradients from a synthetic altitude (the bundled track's profile, 3 m noise) come back within
    3 sigma of the truth on 95 % of the segments, and the file states the sigma."""
    from logexport_alt import bag_with_altitude

    ref = load_track(track_file("intercity_32km"))
    bags = [bag_with_altitude(b, ref, tmp_path / f"alt{k}", noise_m=3.0, seed=k) for k, b in enumerate(BAGS)]
    out = tmp_path / "alt.yaml"
    assert cli.main(["build-track", "--gnss", *map(str, bags), "--name", "alt", "--out", str(out),
                     "--grade-step", "1000"]) == 0  # fmt: skip
    text = out.read_text()
    assert "gradients from the GNSS altitude over 1000 m segments: 1-sigma" in text
    sigma = np.array([float(x) for x in text.split("per segment 1-sigma (per mille): ")[1].splitlines()[0].split(",")])
    track = load_track(out)
    mids = track.gradient.breaks + 500.0
    truth = np.array([ref.gradient.mean_over(m - 500.0, m + 500.0) for m in mids - 300.0 + 300.0]) * 1000.0
    got = track.gradient(mids) * 1000.0
    inside = np.abs(got - truth) <= 3.0 * sigma + 0.5  # + 0.5: a segment straddles steps of the truth
    assert inside.mean() >= 0.9, (got - truth, sigma)
    assert np.median(sigma) < 3.0  # 3 m altitude noise, a fix every ~300 m, 5 runs: 2.5 per mille


def test_profile_errors_are_one_line(tmp_path, capsys):
    bag = str(BAGS[0])
    (tmp_path / "g.csv").write_text("s_m,permille\n0,1\n500,x\n")
    (tmp_path / "l.csv").write_text("s_m,kmh\n0,100\n")
    cases = [
        (["--profile", str(tmp_path / "g.csv")], "g.csv: line 3: expected two numbers"),
        (["--profile", str(tmp_path / "l.csv")], "gradients: the profile has no gradients"),
        (["--profile", str(REPO.parent / "shared/validation/ttobench/tracks/CH_Stadelhofen_Altstetten.json")],
         "the profile's stops span 5790 m, the geometry's 32"),
    ]  # fmt: skip
    for k, (extra, message) in enumerate(cases):
        code = cli.main(["build-track", "--gnss", bag, *extra, "--name", "x", "--out", str(tmp_path / f"{k}.yaml")])
        err = capsys.readouterr().err.strip()
        assert code == 2 and len(err.splitlines()) == 1 and message in err, err


def test_alignment_maps_stops_piecewise():
    from train_calib.trackbuild.profile import align, mapped_table

    a = align([0.0, 1000.0, 3000.0], np.array([10.0, 1020.0, 3010.0]), "p")
    assert a(np.array([-5.0, 500.0, 2000.0, 3100.0])) == pytest.approx([5.0, 515.0, 2015.0, 3110.0])
    with pytest.raises(ConfigError, match="span 3000 m, the geometry's 3300 m"):
        align([0.0, 3000.0], np.array([0.0, 3300.0]), "p")
    table = mapped_table([(0.0, 1.0), (100.0, 2.0), (200.0, 2.0), (300.0, 3.0)], lambda p: p + 50.0, 320.0)
    assert table == [(0.0, 1.0), (150.0, 2.0)]


def test_track_option_takes_a_geometry_plus_a_ttobench_profile(tmp_path, capsys):
    """``--track GEOMETRY.yaml+PROFILE.json``: the gradients and limits of the JSON on the YAML's geometry and
    stations, equal to what build-track --profile JSON writes; a profile of another line is refused in one line."""
    validation = REPO.parent / "shared" / "validation"
    if not validation.is_dir():
        pytest.skip("../shared/validation not present")
    profile = validation / "ttobench" / "tracks" / "CH_Stadelhofen_Altstetten.json"
    bag = validation / "runs" / "stadelhofen_kiss_eco_1hz_00"
    out = tmp_path / "built.yaml"
    argv = ["build-track", "--gnss", str(bag), "--profile", str(profile), "--name", "s", "--out", str(out)]
    assert cli.main(argv) == 0
    combined = load_track(f"{out}+{profile}")
    built = load_track(out)
    np.testing.assert_allclose(combined.gradient.breaks, built.gradient.breaks, atol=0.01)
    np.testing.assert_array_equal(combined.gradient.values, built.gradient.values)
    np.testing.assert_array_equal(combined.speed_limit.values, built.speed_limit.values)
    other = validation / "ttobench" / "tracks" / "SE_Vasteras_Kolback.json"
    with pytest.raises(ConfigError, match="the profile's stops span 19305 m"):
        load_track(f"{out}+{other}")
    with pytest.raises(ConfigError, match="a TTOBench track has no coordinates: give GEOMETRY"):
        load_track(profile)
