"""The docs' fleets simulate: hindered runs whose crawl to a signal (10 km/h) is narrower than the driver's cycle
band (6-15 km/h) coast to a speed above zero and go on (they crashed with "negative speed" after 2703384)."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from train_calib.occupation.compositions import load_train_types
from train_calib.occupation.fleet import FleetConfig, fleet_jobs, simulate_run_job
from train_calib.paths import config_file, track_file
from train_calib.physics import KMH
from train_calib.sim.drive import Drive
from train_calib.track import load_track

# runs of `simulate-occupation --runs 40 --hindered 0.1 --seed S` (docs/occupation.md) that crashed before the fix
CRASHED = {2013: [126], 1: [63], 2: [115], 3: [79, 83, 105]}


@pytest.fixture(scope="module")
def corridor():
    return load_track(track_file("dense_corridor_14km"))


@pytest.fixture(scope="module")
def types():
    return load_train_types(config_file("train_types/ic_compositions.yaml"))


@pytest.mark.parametrize("seed", sorted(CRASHED))
def test_every_crawl_to_a_signal_of_the_docs_fleet_simulates(corridor, types, seed):
    cfg = FleetConfig(runs_per_composition=40, hindered_share=0.1)
    jobs = fleet_jobs(corridor, types, cfg, seed=seed)
    stops = [k for k, job in enumerate(jobs) if job[-1] == "stop"]
    assert set(CRASHED[seed]) <= set(stops)
    for k in stops:
        run = simulate_run_job(jobs[k])
        ids = [section.id for section in corridor.sections]
        occupy, release = run.events.times("occupy", ids), run.events.times("release", ids)
        seen = np.isfinite(occupy)
        assert seen.sum() >= 2 and np.all(np.diff(occupy[seen]) > 0), run.run_id  # the train ran along the line
        both = seen & np.isfinite(release)  # the sections of the final stop are not released
        assert np.all(release[both] > occupy[both]), run.run_id
        assert str(run.truth["hindrance"]).startswith("stop ")


def test_a_cycle_coast_ends_above_half_its_ceiling():
    drive = SimpleNamespace(band=15.0 * KMH)
    assert Drive.band_floor(drive, 8.0 * KMH) == pytest.approx(4.0 * KMH)  # the crawl: half the ceiling
    assert Drive.band_floor(drive, 140.0 * KMH) == pytest.approx(125.0 * KMH)  # the band where it fits
