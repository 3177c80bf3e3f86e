"""The estimator at the defaults against the bounds of issue 19, on data it was not tuned on.

- All 16 external runs of ../shared/validation/runs (another simulator, three real profiles; never tuned on): no
  run more than 2 points worse than its prior, the truth inside the published 2 sigma in at least 90 % of them,
  and where a run's coasting carries information (the oracle over its true coasts is better than the prior) the
  estimate moves toward the truth.
- A held-out slice of the validation family (bench/validation/family.py, `report` half): held cruise at 10 s and
  1 Hz, cycles at 1 Hz, the metro's stop-to-stop service with power (the first report run of each): r(v_ref)
  within the issue's bounds (5 % at 10 s, 3 % at 1 Hz),
  truth inside 2 sigma. The full sweep is `make validate` (bench/validation/README.md, docs/estimator.md).
"""

from __future__ import annotations

import numpy as np
import pytest
from repo_paths import REPO, validation_module

from train_calib.estimation import UKFConfig

EXTERNAL = REPO.parent / "shared" / "validation" / "runs"


score = validation_module("score")
family = validation_module("family")


@pytest.fixture(scope="module")
def external_scores():
    if not (EXTERNAL / "runs.csv").is_file():
        pytest.skip(f"{EXTERNAL} is not here (it is beside the repository in CI and in every session)")
    entries = score.read_runs(EXTERNAL, "external")
    return [score.score_run(e, UKFConfig()) for e in entries]


def test_external_runs_honest_and_never_worse_than_the_prior(external_scores):
    assert len(external_scores) == 16
    assert all(s.error is None for s in external_scores), [s.error for s in external_scores if s.error]
    worse = [s.bag for s in external_scores if abs(s.err) > abs(s.prior_err) + 2.0]
    assert worse == []
    inside = sum(s.inside_2sigma for s in external_scores)
    assert inside >= 0.9 * len(external_scores)
    # a sigma that still says something: 2 sigma under half of r (the prior's 2 sigma is about 40 %)
    assert max(s.two_sigma_pct for s in external_scores) < 50.0


def test_external_runs_move_toward_the_truth_where_coasting_informs(external_scores):
    """Where the oracle over at least 60 s of true coasting beats the prior by 5 points, the estimate is at least 5
    points better than the prior (measured: stadelhofen_kiss_eco_1hz_00 20.6 -> 0.5 %, _02 16.1 -> 1.6 %, the
    yizhuang eco runs 15.7 / 21.4 -> 3.5 / 0.7 %). Not met with less coasting: vasteras_loco_eco_10s_00 has 24 s
    of it at 10 s (three samples; the oracle 37.5 -> 25.4 %), too short for the detection, and stays at its prior
    (docs/estimator.md)."""
    informative = [
        s
        for s in external_scores
        if s.oracle_err is not None and abs(s.oracle_err) < abs(s.prior_err) - 5 and s.coast_s >= 60.0
    ]
    assert len(informative) >= 3
    for s in informative:
        assert abs(s.err) < abs(s.prior_err) - 5.0, (s.bag, s.err, s.prior_err, s.oracle_err)


HELD_OUT = {  # the first report run of four families -> bound on |r(v_ref) error| in %
    "hold_10s_01": 5.0,  # the bound at 10 s
    "hold_1hz_01": 3.0,  # ... at 1 Hz
    "cycles_1hz_01": 3.0,
    "eco_metro_yizhuang_01": 3.0,  # measured +0.3 % (was +5.6 % with 20 s chunk equations; oracle -0.3 %)
}


@pytest.fixture(scope="module")
def held_out(tmp_path_factory: pytest.TempPathFactory):
    out = tmp_path_factory.mktemp("family")
    specs = [s for s in family.all_specs() if s.name in HELD_OUT]
    assert len(specs) == len(HELD_OUT) and all(family.split_of(s.k) == "report" for s in specs)
    for spec in specs:
        family.generate(spec, out)
    family.write_csv(specs, out)
    return [score.score_run(e, UKFConfig()) for e in score.read_runs(out, "report")]


def test_held_out_family_runs_within_the_bounds(held_out):
    for s in held_out:
        assert s.error is None, s.error
        assert abs(s.err) <= HELD_OUT[s.bag], (s.bag, s.err, s.prior_err)
        assert s.inside_2sigma, (s.bag, s.err, s.two_sigma_pct)
        assert abs(s.err) < abs(s.prior_err) - 5.0


ECO_10S_RUNS = 10  # the report half of eco_stadelhofen (20 runs, 60 samples each: a few seconds)


@pytest.fixture(scope="module")
def eco_10s(tmp_path_factory: pytest.TempPathFactory):
    out = tmp_path_factory.mktemp("eco10s")
    specs = [s for s in family.all_specs() if s.family.name == "eco_stadelhofen" and family.split_of(s.k) == "report"]
    assert len(specs) == ECO_10S_RUNS
    for spec in specs:
        family.generate(spec, out)
    family.write_csv(specs, out)
    return [score.score_run(e, UKFConfig()) for e in score.read_runs(out, "report")]


def test_eco_10s_on_a_steep_profile_within_its_data_limit(eco_10s):
    """10 s speeds at 1 km/h, two 40-70 s coasts a run on gradients to 28 per mille changing every few dozen metres:
    the energy form (docs/estimator.md, "Coasts at 10 s sampling"). The data limit (the oracle over the true coasts,
    energy form) is 3.4 % here, above half the 5 % bound, so the bound is 1.5 x 3.4 = 5.1 %; measured 3.3 % (the
    time form stayed at the prior: 17.9 % on the first four runs). Every run inside its 2 sigma; one run
    (eco_stadelhofen_05) ends 2.6 points worse than its prior, where the oracle over its true coasts is 3 points
    worse too: the data mislead there (docs/estimator.md, Limitations)."""
    errs = [abs(s.err) for s in eco_10s]
    oracle = [abs(s.oracle_err) for s in eco_10s if s.oracle_err is not None]
    assert len(oracle) == ECO_10S_RUNS
    limit = float(np.median(oracle))
    assert float(np.median(errs)) <= max(5.0 if limit < 2.5 else 1.5 * limit, 1.0)
    assert float(np.median(errs)) < 0.5 * float(np.median([abs(s.prior_err) for s in eco_10s]))
    assert all(s.inside_2sigma for s in eco_10s)
    worse = [s.bag for s in eco_10s if abs(s.err) > abs(s.prior_err) + 2.0]
    assert len(worse) <= 1, worse
    for s in eco_10s:
        if s.bag in worse:
            assert abs(s.oracle_err) > abs(s.prior_err), (s.bag, s.err, s.prior_err, s.oracle_err)
