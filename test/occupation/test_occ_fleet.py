"""Simulated fleets: reproducibility, hindrances, the in-model truth, and the bundled TYPES.yaml."""

from __future__ import annotations

import numpy as np
import pytest

from train_calib.occupation.compositions import load_train_types
from train_calib.occupation.fleet import FleetConfig, hindered_track, load_truth, simulate_fleet, write_truth
from train_calib.occupation.length import estimate_length
from train_calib.paths import config_file
from train_calib.physics import KMH


@pytest.fixture(scope="module")
def types():
    return load_train_types(config_file("train_types/ic_compositions.yaml"))


def test_bundled_types_match_the_paper_and_the_train_files(types):
    assert types.lengths() == {"VIRM4": 108.0, "VIRM6": 162.0, "VIRM10": 270.0, "ICRm": 282.0}  # Table 2
    virm6 = types["VIRM6"]
    # Table 3 defaults (c0 in N/kg, see the file's comment on the unit misprint), Table 4 r1
    assert virm6.defaults["c0"] == 0.562 and virm6.defaults["c2"] == 6.21
    assert virm6.defaults["r0"] == 1.53e-2 and virm6.defaults["r2"] == 4.08e-5 and virm6.defaults["r1"] == 1.939e-4
    assert virm6.defaults["b_limit"] == 0.66 and virm6.defaults["theta_cruise"] == 1.0 and virm6.defaults["c1"] == 0
    assert {c.defaults["r1"] for c in types.compositions} == {2.162e-4, 1.939e-4, 3.341e-4, 3.342e-4}
    for comp in types.compositions:  # every default inside its bounds
        for name, (lo, hi) in comp.bounds.items():
            assert lo <= comp.defaults[name] <= hi, (comp.name, name)
    assert virm6.bounds["b_limit"] == (0.24, 0.9)


def test_fleet_is_reproducible_and_independent_of_workers(line, types, tmp_path):
    cfg = FleetConfig(runs_per_composition=2)
    one = simulate_fleet(line, types, cfg, seed=8, compositions=["VIRM6", "VIRM10"])
    two = simulate_fleet(line, types, cfg, seed=8, compositions=["VIRM6", "VIRM10"], workers=2)
    assert [r.run_id for r in one] == ["VIRM6-000", "VIRM6-001", "VIRM10-000", "VIRM10-001"]
    for a, b in zip(one, two):
        assert a.events.occupy == b.events.occupy and a.events.release == b.events.release
        assert a.truth == b.truth
    other = simulate_fleet(line, types, cfg, seed=9, compositions=["VIRM6"])
    assert other[0].events.occupy != one[0].events.occupy
    # truth round trip
    path = write_truth(tmp_path / "truth.csv", one)
    back = load_truth(path)
    assert back["VIRM10-001"]["composition"] == "VIRM10"
    assert back["VIRM10-001"]["c2"] == pytest.approx(one[3].truth["c2"], rel=1e-9)
    # rounded, length-consistent events (VIRM10 and ICRm differ by 12 m: not asked of 17 joints)
    for run in one:
        est = estimate_length(run.events, line.sections, types.lengths(), 1.0)
        assert abs(est.length_m - types[run.composition].length_m) < 15.0
        assert est.composition in ((run.composition,) if run.composition == "VIRM6" else ("VIRM10", "ICRm"))


def test_minimum_time_truth_is_the_model_class(line, types):
    cfg = FleetConfig(runs_per_composition=3, driver="minimum_time")
    runs = simulate_fleet(line, types, cfg, seed=1, compositions=["ICRm"])
    comp = types["ICRm"]
    for run in runs:
        t = run.truth
        assert t["traction_fraction"] == 1.0 and t["cruise_style"] == "hold" and t["coast_before_brake_s"] == 0.0
        assert 0.75 * comp.defaults["c0"] <= t["c0"] <= comp.defaults["c0"]  # no adhesion cap in this mode
        assert t["b_limit"] == t["b_limit_min"] == t["b_limit_max"] and t["b_stop"] == comp.defaults["b_stop"]
        assert 0.85 <= t["theta_cruise"] <= 1.02


def test_hindrances(line):
    rng = np.random.default_rng(2)
    restricted, info = hindered_track(line, "restriction", rng, 150.0, 5850.0)
    assert info["kind"] == "restriction" and 400.0 <= info["end_m"] - info["start_m"] <= 1200.0
    mid = 0.5 * (info["start_m"] + info["end_m"])
    assert restricted.speed_limit_at(mid) == pytest.approx(40 * KMH)
    assert restricted.speed_limit_at(info["end_m"] + 1) == line.speed_limit_at(info["end_m"] + 1)
    assert line.speed_limit_at(mid) > 40 * KMH  # the original is untouched
    stop, info = hindered_track(line, "stop", rng, 150.0, 5850.0)
    assert stop.speed_limit_at(info["start_m"] + 30) == pytest.approx(10 * KMH)
    with pytest.raises(ValueError):
        hindered_track(line, "derailment", rng, 150.0, 5850.0)
