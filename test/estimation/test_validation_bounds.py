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
