"""Track file loading, validation and the functions of position."""

from __future__ import annotations

import numpy as np
import pytest
import yaml

from train_calib.errors import ConfigError
from train_calib.physics import GRAVITY
from train_calib.track import ScalarTrackTerms, WindowProjector, load_track


@pytest.fixture
def track(data_dir):
    return load_track(data_dir / "small_track.yaml")


def test_loads_all_parts(track):
    assert track.name == "small-test-line"
    assert track.length_m == 3000.0
    assert [s.name for s in track.stations] == ["Alpha", "Beta"]
    assert [(t.start_m, t.end_m) for t in track.tunnels] == [(1200.0, 1600.0)]
    assert [s.id for s in track.sections] == ["S1", "S2", "S3"]
    assert track.speed_limit_at(100.0) == pytest.approx(40 / 3.6)
    assert track.speed_limit_at(1000.0) == pytest.approx(140 / 3.6)


def test_point_force_is_gradient_plus_curve(track):
    assert track.track_force(500.0) == pytest.approx(0.0)
    assert track.track_force(1200.0) == pytest.approx(GRAVITY * 0.005)
    assert track.track_force(1700.0) == pytest.approx(GRAVITY * (0.005 + 0.7 / 1000))
    assert track.track_force(2700.0) == pytest.approx(GRAVITY * -0.003)


def test_force_is_averaged_over_train_length(track):
    # head at 1050, tail at 950: 50 m on the level, 50 m on +5 permille
    assert track.track_force(1050.0, 100.0) == pytest.approx(GRAVITY * 0.0025)
    # against a numerical mean over 2001 points, for many positions at once
    heads = np.linspace(100.0, 2999.0, 57)
    numeric = [np.mean(track.track_force(np.linspace(h - 150.0, h, 20001))) for h in heads]
    assert np.allclose(track.track_force(heads, 150.0), numeric, atol=2e-5)


def test_tunnel_fraction(track):
    assert track.tunnel_fraction(1100.0, 100.0) == pytest.approx(0.0)
    assert track.tunnel_fraction(1250.0, 100.0) == pytest.approx(0.5)
    assert track.tunnel_fraction(1400.0, 100.0) == pytest.approx(1.0)


def test_limit_over_train_waits_for_the_tail(track):
    assert track.limit_over_train(450.0, 100.0) == pytest.approx(40 / 3.6)
    assert track.limit_over_train(550.0, 100.0) == pytest.approx(140 / 3.6)


def test_latlon_round_trip_through_projection(track):
    for s in np.linspace(0.0, 3000.0, 31):
        lat, lon = track.latlon_at(s)
        s_back, dist = track.project_latlon(float(lat), float(lon))
        assert s_back == pytest.approx(s, abs=1e-3)
        assert dist < 1e-3


def test_projection_of_an_offset_point_and_window(track):
    east, north = track.enu_at(1500.0)
    s, dist = track.project(float(east) + 30.0, float(north))
    assert s == pytest.approx(1500.0, abs=0.5) and dist == pytest.approx(30.0, abs=0.5)
    s, dist = track.project(float(east), float(north), s_min_m=1800.0, s_max_m=2000.0)
    assert s == pytest.approx(1800.0) and dist == pytest.approx(300.0, abs=1.0)


def _write(tmp_path, data, name="track.yaml"):
    path = tmp_path / name
    path.write_text(yaml.safe_dump(data))
    return path


def _valid(data_dir):
    return yaml.safe_load((data_dir / "small_track.yaml").read_text())


@pytest.mark.parametrize(
    "mutate, key, problem",
    [
        (lambda d: d.pop("gradients"), "gradients", "missing required key"),
        (lambda d: d.update(length_m="long"), "length_m", "expected a number"),
        (lambda d: d["speed_limits"][1].update(kmh=-5), "speed_limits[1].kmh", "out of range"),
        (lambda d: d["gradients"][2].update(s_m=500), "gradients[2].s_m", "strictly increasing"),
        (lambda d: d.update(geometry=[]), "geometry", "at least 2 entries"),
        (lambda d: d["gradients"][1].update(permille=250), "gradients[1].permille", "out of range"),
        (lambda d: d["geometry"][1].update(lat=5.0, lon=52.008993), "geometry[1]", "swapped"),
        (lambda d: d["tunnels"][0].update(end_m=1100), "tunnels[0].end_m", "greater than start_m"),
        (lambda d: d["sections"][1].update(id="S1"), "sections[1].id", "duplicate"),
        (lambda d: d["stations"][0].pop("name"), "stations[0].name", "missing required key"),
        (lambda d: d["gradients"][0].update(s_m=10), "gradients[0].s_m", "must be at s_m 0"),
        (lambda d: d.update(tunels=d.pop("tunnels")), "tunels", "unknown key (did you mean tunnels?)"),
        (lambda d: d["tunnels"][0].update(lenght_m=400), "tunnels[0].lenght_m", "unknown key (did you mean end_m?)"),
        (lambda d: d.update(zzz=1), "zzz", "unknown key (known keys: name, length_m"),
    ],
)
def test_invalid_files_are_refused_in_one_line(tmp_path, data_dir, mutate, key, problem):
    data = _valid(data_dir)
    mutate(data)
    path = _write(tmp_path, data)
    with pytest.raises(ConfigError) as err:
        load_track(path)
    message = str(err.value)
    assert "\n" not in message
    assert message.startswith(f"{path}: {key}: "), message
    assert problem in message


def test_unreadable_and_invalid_yaml(tmp_path):
    with pytest.raises(ConfigError, match="track file not found"):
        load_track(tmp_path / "missing.yaml")
    bad = tmp_path / "bad.yaml"
    bad.write_text("name: [unclosed\n")
    with pytest.raises(ConfigError, match=r"bad.yaml: invalid YAML at line \d+"):
        load_track(bad)
    listy = tmp_path / "list.yaml"
    listy.write_text("- 1\n- 2\n")
    with pytest.raises(ConfigError, match="expected a mapping"):
        load_track(listy)


def test_scalar_track_terms_are_the_track_functions_floats(track):
    """The ingest's per-sample twin gives the numpy functions' floats exactly."""
    terms = ScalarTrackTerms(track, 150.0)
    for s in np.concatenate((np.linspace(-50.0, 3100.0, 127), [1200.0, 1350.0, 1600.0])):
        s = float(s)
        assert terms.track_force(s) == float(track.track_force(s, 150.0))
        assert terms.tunnel_fraction(s) == float(track.tunnel_fraction(s, 150.0))
        assert terms.limit(s) == float(track.speed_limit_at(s))


def test_scalar_track_terms_at_is_the_four_terms(track):
    """``at`` (one look-up per function and end, per released sample) gives the four terms' floats exactly."""
    for length in (0.0, 150.0):
        terms = ScalarTrackTerms(track, length)
        for s in np.concatenate((np.linspace(-50.0, 3100.0, 211), [0.0, 1200.0, 1350.0, 1600.0, 3000.0])):
            s = float(s)
            expected = (terms.track_force(s), terms.limit(s), terms.tunnel_fraction(s), terms.track_force_integral(s))
            assert terms.at(s) == expected


def test_scalar_track_terms_at_many_is_at_bit_for_bit(track):
    """The numpy pass of a whole run's positions gives ``at``'s floats, bit for bit (signed zeros too)."""
    heads = np.concatenate((np.linspace(-50.0, 3100.0, 631), [0.0, 100.0, 1200.0, 1350.0, 1600.0, 3000.0]))
    for length in (0.0, 100.0, 150.0):
        terms = ScalarTrackTerms(track, length)
        many = terms.at_many(heads.tolist())
        for k, s in enumerate(heads.tolist()):
            assert [x.hex() for x in terms.at(s)] == [column[k].hex() for column in many]
    assert ScalarTrackTerms(track, 100.0).at_many([]) == ([], [], [], [])


def test_window_projector_agrees_with_track_project(track):
    projector = WindowProjector(track)
    rng = np.random.default_rng(5)
    for s_true in np.linspace(0.0, 3000.0, 41):
        east, north = track.enu_at(s_true)
        e, n = float(east) + rng.uniform(-40.0, 40.0), float(north) + rng.uniform(-40.0, 40.0)
        for lo, hi in ((s_true - 60.0, s_true + 60.0), (s_true + 200.0, s_true + 400.0), (-500.0, 4000.0)):
            s, d = projector.project(e, n, lo, hi)
            s_ref, d_ref = track.project(e, n, max(lo, 0.0), min(hi, track.length_m))
            assert s == pytest.approx(s_ref, abs=1e-6) and d == pytest.approx(d_ref, abs=1e-6)
    # a window beyond the end of the line: its nearest end
    east, north = track.enu_at(2990.0)
    assert projector.project(float(east), float(north), 3500.0, 3600.0)[0] == 3000.0


def test_track_force_integral_is_the_integral_of_the_track_force(track):
    """Gamma(s) (J/kg) against a fine trapezoid of track_force (0.01 m steps; the averaged force is continuous,
    so the trapezoid converges fast), 0 at s = 0, and the scalar twin's floats to 1e-9 J/kg."""
    for length in (0.0, 150.0):
        grid = np.arange(0.0, 3000.0 + 1e-9, 0.01)
        g = track.track_force(grid, length)
        ref = np.concatenate(([0.0], np.cumsum(0.5 * (g[1:] + g[:-1]) * np.diff(grid))))
        s = np.array([0.0, 250.0, 1200.0, 1350.0, 1600.0, 2999.0])
        gamma = track.track_force_integral(s, length)
        np.testing.assert_allclose(gamma, np.interp(s, grid, ref), atol=2e-3 if length == 0.0 else 1e-6)
        assert gamma[0] == 0.0
        terms = ScalarTrackTerms(track, length)
        for x, y in zip(s, gamma):
            assert terms.track_force_integral(float(x)) == pytest.approx(float(y), abs=1e-9)
