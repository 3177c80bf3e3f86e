"""The release delay estimated from the data (``--release-offset auto``), against simulated fleets with known delays."""

from __future__ import annotations

import csv
import itertools
import json
from pathlib import Path

import numpy as np
import pytest

from train_calib.cli import main
from train_calib.occupation.compositions import load_train_types
from train_calib.occupation.events import load_events
from train_calib.occupation.fleet import FleetConfig, simulate_fleet
from train_calib.occupation.generate import occupation_events
from train_calib.occupation.length import estimate_length
from train_calib.occupation.pipeline import default_stops
from train_calib.occupation.release_delay import estimate_release_delay, run_joints
from train_calib.paths import config_file
from train_calib.track import Section, load_track

TYPES = str(config_file("train_types/ic_compositions.yaml"))
LINE = Path(__file__).resolve().parent / "data" / "line_12km_long_sections.yaml"
COMPOSITIONS = ["VIRM4", "VIRM6", "ICRm"]


@pytest.fixture(scope="module")
def setup():
    track = load_track(LINE)
    types = load_train_types(TYPES)
    return track, types


def _fleet(track, types, delay_s: float, jitter_s: float, seed: int, runs: int = 5):
    cfg = FleetConfig(runs_per_composition=runs, release_delay_s=delay_s, release_jitter_s=jitter_s)
    return simulate_fleet(track, types, cfg, seed=seed, compositions=COMPOSITIONS, workers=1)


def _correct(fleet, track, lengths, offset_s: float) -> int:
    est = [estimate_length(r.events, track.sections, lengths, 1.0, release_offset_s=offset_s) for r in fleet]
    return sum(e.composition == r.composition for e, r in zip(est, fleet))


@pytest.mark.parametrize("seed", [0, 2])
def test_recovers_a_late_release_and_the_compositions(setup, seed):
    """Releases late by 0.3 + U(0, 1.2) s per joint (mean 0.9 s), 15 runs of three compositions on 600-1500 m
    sections: the delay within 0.2 s (measured over seeds 0-7: 0.74-1.03 s, +-0.07-0.09 s stated), called
    separable, and then every composition assigned, where without the offset only 4-7 of 15 are right."""
    track, types = setup
    lengths = types.lengths()
    fleet = _fleet(track, types, 0.3, 1.2, seed)
    est = estimate_release_delay({r.run_id: r.events for r in fleet}, track.sections, default_stops(track), lengths)
    assert est.separable, est.reason
    assert abs(est.delay_s - 0.9) <= 0.2
    assert 0.03 <= est.std_s <= 0.2  # an uncertainty that says something, and not below the joints' noise
    assert est.applied_s == pytest.approx(est.delay_s)
    assert est.n_runs == 15 and est.n_joints >= 60
    assert _correct(fleet, track, lengths, est.applied_s) == 15
    assert _correct(fleet, track, lengths, 0.0) <= 10


def test_prompt_releases_give_a_small_delay(setup):
    """Releases 0-0.4 s late (mean 0.2 s): the estimate stays small and nothing changes in the assignment."""
    track, types = setup
    lengths = types.lengths()
    fleet = _fleet(track, types, 0.0, 0.4, seed=1)
    est = estimate_release_delay({r.run_id: r.events for r in fleet}, track.sections, default_stops(track), lengths)
    assert est.separable and abs(est.delay_s - 0.2) <= 0.2
    assert _correct(fleet, track, lengths, est.applied_s) == 15


def test_sections_with_different_delays_are_pointed_out(setup):
    """Releases of every other section 1 s later still (two kinds of detector): one delay is fitted (the mean,
    ~1.4 s), and the data say the sections differ: p < 1e-3 and the sections' mean residuals spread by > 0.3 s
    (measured 0.35-0.53 s over seeds 0-5, 0.05-0.24 s with one delay), the late ones with the larger residuals."""
    track, types = setup
    lengths = types.lengths()
    runs = {r.run_id: r.events for r in _fleet(track, types, 0.3, 1.2, seed=0)}
    one = estimate_release_delay(runs, track.sections, default_stops(track), lengths)
    assert not one.sections_differ and one.section_spread_s < 0.3
    for ev in runs.values():
        for sid in ev.release:
            if int(sid[1:]) % 2:
                ev.release[sid] += 1.0
    two = estimate_release_delay(runs, track.sections, default_stops(track), lengths)
    assert two.sections_differ and two.common_delay_p < 1e-3 and two.section_spread_s > 0.3
    assert "the sections' delays differ" in two.reason
    assert two.separable and abs(two.delay_s - 1.4) <= 0.25
    late = [v["mean_residual_s"] for k, v in two.sections.items() if int(k[1:]) % 2]
    prompt = [v["mean_residual_s"] for k, v in two.sections.items() if not int(k[1:]) % 2]
    assert np.mean(late) - np.mean(prompt) > 0.4


def _constant_speed_runs(lengths: list[float], delay_s: float, speed_ms: float = 30.0):
    edges = np.cumsum(np.concatenate(([0.0], np.random.default_rng(3).uniform(600, 1500, 12))))
    sections = [Section(f"S{k:02d}", float(a), float(b)) for k, (a, b) in enumerate(itertools.pairwise(edges))]
    rng = np.random.default_rng(4)
    runs = {}
    for k in range(10):
        t = np.linspace(0.0, edges[-1] / speed_ms + 60.0, 3000)
        runs[f"r{k}"] = occupation_events(
            t, speed_ms * t - 400.0, lengths[k % len(lengths)], sections, run_id=f"r{k}", t0_s=rng.uniform(0, 1e5),
            release_delay_s=delay_s, rng=rng,
        )  # fmt: skip
    return sections, runs


def test_one_speed_one_composition_is_not_separable():
    """Every joint at 30 m/s, all runs 162 m, the four IC lengths possible: a 162 m train late by d and a 108 m
    train late by d + 54/30 s look the same. Not separable, no offset applied, the reason says why."""
    lengths = load_train_types(TYPES).lengths()
    sections, runs = _constant_speed_runs([162.0], delay_s=1.0)
    est = estimate_release_delay(runs, sections, [-1e9, 1e9], lengths)
    assert not est.separable and est.applied_s == 0.0
    assert "not separable" in est.reason and "fits almost as well" in est.reason
    assert abs(abs(est.alias_delay_s - est.delay_s) - 54.0 / 30.0) < 0.15
    # a mix of compositions at that one speed fits only one delay: separable from the known lengths
    sections, runs = _constant_speed_runs([108.0, 162.0, 270.0], delay_s=1.0)
    mixed = estimate_release_delay(runs, sections, [-1e9, 1e9], lengths)
    assert mixed.separable and abs(mixed.delay_s - 1.0) <= 0.1


def test_no_usable_joint_is_said():
    """Two sections per leg: no joint has a section behind and ahead within one leg."""
    sections = [Section("A", 0.0, 1000.0), Section("B", 1000.0, 2000.0)]
    t = np.linspace(0.0, 100.0, 500)
    run = occupation_events(t, 30.0 * t - 100.0, 100.0, sections, run_id="x")
    assert run_joints(run, sections, [0.0, 2000.0]).gap_s.size == 0
    est = estimate_release_delay({"x": run}, sections, [0.0, 2000.0], {"A": 100.0})
    assert not est.separable and est.applied_s == 0.0 and "no joint" in est.reason


def test_cli_auto_and_fixed_offsets(tmp_path, capsys):
    """calibrate-occupation --release-offset auto: the estimate in summary.json and printed, every composition
    assigned (12 runs); a fixed offset is used for the lengths too; a bad value is one line and exit 2."""
    fleet_dir = tmp_path / "fleet"
    sim = ["simulate-occupation", "--track", str(LINE), "--train-types", TYPES,
           "--compositions", ",".join(COMPOSITIONS), "--runs", "4", "--seed", "0",
           "--release-delay", "0.3", "--release-jitter", "1.2", "--workers", "1",
           "--out", str(fleet_dir)]  # fmt: skip
    assert main(sim) == 0
    base = ["calibrate-occupation", str(fleet_dir / "events.csv"), "--track", str(LINE), "--train-types", TYPES,
            "--truth", str(fleet_dir / "truth.csv"), "--workers", "1", "--popsize", "2", "--maxiter", "2",
            "--run-plots", "0"]  # fmt: skip
    capsys.readouterr()
    assert main([*base, "--out", str(tmp_path / "auto"), "--release-offset", "auto"]) == 0
    printed = capsys.readouterr().out
    summary = json.loads((tmp_path / "auto" / "summary.json").read_text())
    delay = summary["release_delay"]
    assert delay["separable"] and abs(delay["delay_s"] - 0.9) <= 0.2 and delay["std_s"] < 0.2
    assert summary["release_offset_s"] == pytest.approx(delay["applied_s"])
    assert delay["reason"] in printed
    assert summary["length_accuracy"]["1"]["correct"] == 12
    assert summary["counts"].get("unassigned", 0) == 0

    assert main([*base, "--out", str(tmp_path / "fixed"), "--release-offset", "0.9"]) == 0
    fixed = json.loads((tmp_path / "fixed" / "summary.json").read_text())
    assert "release_delay" not in fixed and fixed["release_offset_s"] == 0.9
    assert fixed["length_accuracy"]["1"]["correct"] == 12
    # without an offset (measured: 3 of these 12 right; the lengths' interval misses every composition)
    runs = load_events(fleet_dir / "events.csv")
    lengths = load_train_types(TYPES).lengths()
    sections = load_track(LINE).sections
    truth = {r["run_id"]: r["composition"] for r in csv.DictReader((fleet_dir / "truth.csv").open())}
    right = sum(estimate_length(r, sections, lengths, 1.0).composition == truth[k] for k, r in runs.items())
    assert right <= 8

    capsys.readouterr()
    assert main([*base, "--out", str(tmp_path / "bad"), "--release-offset", "late"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--release-offset" in err[0] and "'late'" in err[0]
