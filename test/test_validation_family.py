"""The validation family (bench/validation/family.py) and its scorer (bench/validation/score.py).

A tiny run round-trips through the generator and the scorer; the oracle (the data's own limit) recovers
r(v) from a coast with known truth; the tune/report split and the true resistance are deterministic.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
from repo_paths import DATA, validation_module

from train_calib.estimation import UKFConfig
from train_calib.physics import KMH
from train_calib.track import load_track
from train_calib.train import load_train

family = validation_module("family")
score = validation_module("score")

TINY = family.Family(
    "tiny", str(DATA / "small_track.yaml"), str(DATA / "small_train.yaml"), "hold", "1hz_gnss2s", runs=2
)


@pytest.fixture(scope="module")
def tiny_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("family")
    specs = family.all_specs([TINY])
    for spec in specs:
        family.generate(spec, out)
    family.write_csv(specs, out)
    return out


def test_tiny_run_files_and_truth_format(tiny_dir: Path) -> None:
    doc = json.loads((tiny_dir / ("tiny_01" + family.TRUTH_SUFFIX)).read_text())
    assert (tiny_dir / "tiny_01" / "tiny_01.mcap").is_file()
    for key in ("r0", "r1", "r2", "t", "s", "v", "a", "u", "regime", "split", "family"):
        assert key in doc
    t = np.array(doc["t"])
    assert t[0] == 0.0 and np.allclose(np.diff(t), 1.0)  # 1 Hz from the first message
    assert doc["split"] == "report" and doc["family"] == "tiny"
    regime, u, v = np.array(doc["regime"]), np.array(doc["u"]), np.array(doc["v"])
    assert np.all(regime[(u == 0.0) & (v > 0.0)] == 3)  # coasting is physical: u == 0 while moving
    assert np.all(regime[v <= 0.0] == 0)
    base = np.array(load_train(DATA / "small_train.yaml").davis.as_tuple())
    _check_ratio(np.array([doc["r0"], doc["r1"], doc["r2"]]) / base)


def _check_ratio(ratio: np.ndarray) -> None:
    """True / train file: 1 +- (10-30 %) in common, times 1 +- 4 % per coefficient."""
    dev = np.abs(ratio - 1.0)
    assert np.all((dev >= 1.1 * 0.96 - 1.0 - 1e-12) & (dev <= 1.3 * 1.04 - 1.0 + 1e-12))
    assert np.all(np.sign(ratio - 1.0) == np.sign(ratio[0] - 1.0))  # one common sign
    assert ratio.max() / ratio.min() <= 1.04 / 0.96 + 1e-12


def test_generation_is_deterministic_and_cached(tiny_dir: Path, tmp_path: Path) -> None:
    spec = family.RunSpec(TINY, 1)
    assert family.generate(spec, tiny_dir)[1] == 0.0  # present: not regenerated
    family.generate(spec, tmp_path)
    name = "tiny_01" + family.TRUTH_SUFFIX
    assert (tmp_path / name).read_bytes() == (tiny_dir / name).read_bytes()
    assert (tmp_path / "tiny_01" / "tiny_01.mcap").read_bytes() == (tiny_dir / "tiny_01" / "tiny_01.mcap").read_bytes()


def test_tiny_run_scores(tiny_dir: Path) -> None:
    entries = score.read_runs(tiny_dir, "tune")
    assert [(e.family, e.split) for e in entries] == [("tiny", "tune"), ("tiny", "report")]
    s = score.score_run(entries[1], UKFConfig())
    assert s.error is None and s.runs_in_bag == 1
    doc = json.loads(Path(entries[1].bag + family.TRUTH_SUFFIX).read_text())
    truth = [doc["r0"], doc["r1"], doc["r2"]]
    prior = load_train(DATA / "small_train.yaml").davis
    v_ref = min(80.0 * KMH, 0.8 * max(doc["v"]))
    assert s.v_ref_kmh == pytest.approx(v_ref / KMH)
    expected_prior = 100.0 * (prior(v_ref) - score.r_of(truth, v_ref)) / score.r_of(truth, v_ref)
    assert s.prior_err == pytest.approx(expected_prior, rel=1e-9)
    assert np.isfinite(s.err) and s.two_sigma_pct >= 0.0
    assert s.regime_accuracy is not None and 0.5 < s.regime_accuracy <= 1.0
    agg = score.aggregate([s])
    assert agg["runs"] == 1 and agg["median_prior_err"] == pytest.approx(abs(expected_prior))
    assert "tiny" in score.markdown([s], "default")


@dataclass
class _M:
    """The fields of a Measurement the oracle reads."""

    stamp_ns: int
    v: float
    track_force: float
    tunnel_fraction: float = 0.0
    run_id: int = 0


def _coast(truth: list[float], g: float, v0: float, seconds: int, noise: float, seed: int) -> list[_M]:
    """A 1 Hz coast from v0 (m/s) under r(v) = truth and a constant g (N/kg), exact to 1e-9 (fine Euler steps)."""
    rng = np.random.default_rng(seed)
    out, v, h = [], v0, 1e-3
    for k in range(seconds + 1):
        out.append(_M(k * 1_000_000_000, v + noise * rng.standard_normal(), g))
        for _ in range(1000):  # midpoint steps of 1 ms
            vm = v - 0.5 * h * (score.r_of(truth, v) + g)
            v -= h * (score.r_of(truth, vm) + g)
    return out


def test_oracle_recovers_the_truth_of_a_coast() -> None:
    prior = [0.0125, 0.00025, 0.0000474]  # a VIRM-like train file
    truth = [p * 0.8 * j for p, j in zip(prior, (1.03, 0.97, 1.02))]  # 20 % below, with jitter
    ms = _coast(truth, g=0.01, v0=140.0 * KMH, seconds=400, noise=0.15, seed=3)
    eqs = score.coast_equations(ms, 0, [(0.0, 400.0)], tunnel_factor=0.0)
    assert eqs.y.size == 400 and eqs.seconds == 400.0
    x, P = score.bayes_fit(eqs.y, eqs.H, prior, score.prior_covariance(prior), eqs.D)
    v_ref = 80.0 * KMH
    err = abs(score.rel_err(x, truth, v_ref))
    assert err < 1.5  # %, the prior is 20 % off
    assert abs(score.r_of(x, v_ref) - score.r_of(truth, v_ref)) < 2.0 * score.sigma_of(P, v_ref)
    # no data: the prior and its covariance
    x0, P0 = score.bayes_fit(np.zeros(0), np.zeros((0, 3)), prior, score.prior_covariance(prior))
    assert np.allclose(x0, prior) and np.allclose(P0, score.prior_covariance(prior))


def test_coasting_stretches() -> None:
    t = np.arange(60.0)
    u = np.where((t >= 5) & (t <= 30), 0.0, 0.1)
    u[45:55] = 0.0  # 9 s: too short
    v = np.full(60, 20.0)
    assert score.coasting_stretches(t, u, v) == [(5.0, 30.0)]


def test_coasting_throughout_rejects_a_speed_held_by_traction_pulses() -> None:
    """The external runs' truth: u sampled at 1 Hz reads 0 between sub-second traction pulses that hold the speed.
    A sample is coasting only where the truth's own speeds show no effort over the steps next to it."""
    track = load_track(DATA / "small_track.yaml")
    train = load_train(DATA / "small_train.yaml")
    truth = train.davis.as_tuple()
    t = np.arange(0.0, 60.0)
    v = np.empty_like(t)
    v[:30] = 12.0  # held: the pulses cancel r + g over each second
    # then coasting on the flat first km: dv/dt = -(r + g), integrated finely
    s = np.empty_like(t)
    s[:30] = 50.0 + 12.0 * t[:30]
    vv, ss = 12.0, float(s[29])
    for k in range(30, 60):
        for _ in range(100):
            g = float(track.track_force(ss, train.length_m))
            vv -= 0.01 * (truth[0] + truth[1] * vv + truth[2] * vv * vv + g)
            ss += 0.01 * vv
        v[k], s[k] = vv, ss
    assert s[-1] < 1000.0 - train.length_m  # flat ground throughout
    u = np.zeros_like(t)
    u[::4] = 1.0  # a pulse every 4 s at the samples; 0 at the others
    u[30:] = 0.0
    mask = score.coasting_throughout(t, s, v, u, truth, track, train)
    assert not mask[:30].any()  # u == 0 at 3 of 4 of these samples, and none coasting
    assert mask[30:].all()  # the coast
    assert score.coasting_stretches(t, u, v) == [(29.0, 59.0)]  # by u alone: the held second before the coast too
    assert score.coasting_stretches(t, u, v, coast=mask) == [(30.0, 59.0)]


def test_split_is_deterministic() -> None:
    specs = family.all_specs()
    assert [s.split for s in specs] == [family.split_of(s.k) for s in specs]
    assert [s.split for s in family.all_specs()] == [s.split for s in specs]
    assert len({s.name for s in specs}) == len(specs) and len({tuple(s.seed) for s in specs}) == len(specs)
    for fam in family.FAMILIES:
        splits = [s.split for s in specs if s.family is fam]
        assert splits.count("tune") == splits.count("report") >= 2
    assert family.split_of(0) == "tune" and family.split_of(1) == "report" and family.split_of(4) == "tune"


def test_true_resistance_ranges() -> None:
    train = load_train(DATA / "small_train.yaml")
    base = np.array(train.davis.as_tuple())
    for k in range(200):
        _check_ratio(np.array(family.true_resistance(train, np.random.default_rng([k])).as_tuple()) / base)


def test_oracle_on_a_family_run(tmp_path: Path) -> None:
    """hold_10s run 1 (32 km, ~6 min of final coast at 10 s): the oracle over the pipeline's measurements."""
    fam = next(f for f in family.FAMILIES if f.name == "hold_10s")
    spec = family.RunSpec(fam, 1)
    family.generate(spec, tmp_path)
    family.write_csv([spec], tmp_path)
    s = score.score_run(score.read_runs(tmp_path, "tune")[0], UKFConfig())
    assert s.split == "report" and s.coast_s > 200.0 and s.coast_equations > 20
    assert abs(s.prior_err) > 5.0
    assert s.oracle_err is not None and abs(s.oracle_err) < 3.0  # % at v_ref; measured 1.8 (white), 0.4
    assert s.oracle_two_sigma_pct is not None and abs(s.oracle_err) < s.oracle_two_sigma_pct


def test_best_estimate_is_scored_when_present() -> None:
    """``output.best`` with r0, r1, r2 (or an array r) and a 3x3 covariance is read; absent: None."""

    @dataclass
    class _Best:
        r: np.ndarray
        covariance: np.ndarray

    @dataclass
    class _Out:
        best: object = None
        final: object = None

    assert score.best_of(_Out()) is None
    best = score.best_of(_Out(best=_Best(np.array([0.01, 1e-4, 5e-5]), np.eye(3) * 1e-8)))
    assert [score._field(best, k) for k in ("r0", "r1", "r2")] == [0.01, 1e-4, 5e-5]
    assert score._field({"r0": 0.02}, "r0") == 0.02
    s = score.score_estimate([0.01, 1e-4, 5e-5], np.eye(3) * 1e-8, [0.011, 1e-4, 5e-5], 20.0)
    assert s["err"] == pytest.approx(100.0 * -0.001 / (0.011 + 2e-3 + 0.02))
