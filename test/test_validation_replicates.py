"""Noise replicates of validation runs (bench/validation/replicates.py, family.simulate_spec(noise_seed=...)).

A replicate is the same run (truth, drivers, dwells, sensor phase) with other sensor noise: its truth arrays and
sample times equal the run's, its speeds differ; draw -1 is the family's own run, scored as ``make validate``
scores the bag.
"""

from __future__ import annotations

import numpy as np
import pytest
from repo_paths import validation_module

from train_calib.estimation import UKFConfig

family = validation_module("family")
score = validation_module("score")
replicates = validation_module("replicates")

RUN = "eco_stadelhofen_05"  # 3 interstations at 10 s: ~0.1 s a draw


def test_noise_seed_keeps_the_run_and_redraws_the_noise() -> None:
    spec = replicates.spec_named(RUN)
    own, truth, _, _ = family.simulate_spec(spec)
    again, truth_again, _, _ = family.simulate_spec(spec)
    a, truth_a, _, _ = family.simulate_spec(spec, noise_seed=replicates.noise_seed(spec, 0))
    a2, _, _, _ = family.simulate_spec(spec, noise_seed=replicates.noise_seed(spec, 0))
    b, _, _, _ = family.simulate_spec(spec, noise_seed=replicates.noise_seed(spec, 1))
    assert truth_a.as_tuple() == truth.as_tuple() == truth_again.as_tuple()
    np.testing.assert_array_equal(again.speed.v_ms, own.speed.v_ms)  # without noise_seed: the family's run, as before
    # the same run: the same truth trajectory (drivers, dwells) and the same sample times
    for key in ("t", "s", "v", "u", "regime"):
        np.testing.assert_array_equal(family.truth_1hz(a)[key], family.truth_1hz(own)[key])
    np.testing.assert_array_equal(a.speed.t_ns, own.speed.t_ns)
    np.testing.assert_array_equal(a.gnss.t_ns, own.gnss.t_ns)
    # other noise, reproducible from the seed
    np.testing.assert_array_equal(a2.speed.v_ms, a.speed.v_ms)
    assert np.mean(a.speed.v_ms != own.speed.v_ms) > 0.2
    assert np.mean(a.speed.v_ms != b.speed.v_ms) > 0.2
    assert np.max(np.abs(a.speed.v_ms - own.speed.v_ms)) < 1.0  # m/s: 0.5 km/h noise, 1 km/h rounding


def test_replicates_of_one_run(tmp_path) -> None:  # type: ignore[no-untyped-def]
    (res,) = replicates.run_replicates([RUN], 4, UKFConfig(), jobs=1)
    spec = replicates.spec_named(RUN)
    family.generate(spec, tmp_path)
    family.write_csv([spec], tmp_path)
    direct = score.score_run(score.read_runs(tmp_path, "tune")[0], UKFConfig())
    assert res.own.err == pytest.approx(direct.err, abs=1e-9)  # draw -1 is the bag make validate scores
    assert res.prior_err == pytest.approx(direct.prior_err, abs=1e-9)
    assert [r.j for r in res.replicates] == [0, 1, 2, 3]
    errs = [r.err for r in res.replicates]
    assert len(set(errs)) == 4 and res.own.err not in errs
    # each run moves toward the truth on average; the own draw (measured +17.9 against a prior of +15.3) is
    # the tail: the 100-draw mean is +7.6 (RESULTS_replicates_eco.md)
    mean, sd = res.mean_sd()
    assert abs(mean) < abs(res.prior_err) and sd > 0.0
    share = res.worse_share()
    assert share is not None and 0.0 <= share <= 1.0
    text = replicates.markdown([res], 4, "default")
    assert f"| {RUN} | report | {res.prior_err:+.1f} | {res.own.err:+.1f} |" in text


def test_bad_names_exit_2(capsys: pytest.CaptureFixture[str]) -> None:
    assert replicates.main(["--runs", "eco_stadelhofen_99"]) == 2
    assert "--runs: 'eco_stadelhofen_99'" in capsys.readouterr().err
    assert replicates.main(["--families", "nope"]) == 2
    assert "--families: unknown ['nope']" in capsys.readouterr().err
    assert replicates.main(["--replicates", "0"]) == 2
    assert "--replicates: 0" in capsys.readouterr().err


def test_coast_consistency_of_a_draw_and_its_table(capsys) -> None:
    """bench/validation/coast_consistency.py: a draw of an eco run has its two coasts in the energy form, NIS/dof
    of the order of 1 (measured 0.2-0.9 over the family, the stated 1 km/h being twice the variance seen), and the
    table counts it; a family name that is not one exits 2 naming --families."""
    consistency = validation_module("coast_consistency")
    name, split, worse, nis, dof = consistency.one_draw((RUN, 0))
    assert (name, split) == (RUN, "report")
    assert dof >= 8 and 0.05 < nis / dof < 3.0
    table = consistency.markdown([(name, split, worse, nis, dof)], 1)
    assert f"| report | 1 | {nis / dof:.2f} " in table
    with pytest.raises(SystemExit) as exc:
        consistency.main(["--families", "eco_nowhere"])
    assert exc.value.code == 2
    assert "--families" in capsys.readouterr().err
