"""Cases shared by the estimator tests: synthetic truth runs (own generator), simulated runs, wrong priors."""

from __future__ import annotations

import sys
from functools import cache
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from synthetic import make_run

from train_calib.train import Davis

PATTERNS = np.array([[1, 1, 1], [-1, -1, -1], [1, -1, 1], [-1, 1, -1], [1, 1, -1], [-1, -1, 1]])


def wrong_prior(truth: Davis, k: int, spread: float = 0.2) -> Davis:
    """The truth times (1 +- spread), sign pattern k."""
    return Davis(*(np.array(truth.as_tuple()) * (1.0 + spread * PATTERNS[k % len(PATTERNS)])))


@cache
def synthetic_run(seed: int = 0, period: float = 10.0):
    return make_run(seed=seed, period=period)


@cache
def simulated_run(k: int, period: float, power: bool = False, electric_brake_fraction: float = 0.8):
    """A simulated 32 km intercity run (virm6, true Davis 5-20 % off the file's), as bench_whole_run makes them;
    electric_brake_fraction: the brake's electric (regenerating) share (SensorParams)."""
    from train_calib.paths import track_file, train_file
    from train_calib.sim import DriverParams, SensorParams, simulate_run
    from train_calib.track import load_track
    from train_calib.train import load_train

    track = load_track(track_file("intercity_32km"))
    train = load_train(train_file("virm6"))
    rng = np.random.default_rng([4, k])
    factors = 1.0 + rng.choice([-1.0, 1.0], 3) * rng.uniform(0.05, 0.2, 3)
    truth = Davis(*(np.array(train.davis.as_tuple()) * factors))
    driver = DriverParams.sample(rng, train=train)
    sensors = SensorParams(
        gnss_period_s=period,
        speed_period_s=period,
        power_period_s=period if power else 0.0,
        electric_brake_fraction=electric_brake_fraction,
    )
    run = simulate_run(track, train, driver=driver, sensors=sensors, rng=rng, resistance=truth)
    return run, run.measurements(track, train), truth, train
