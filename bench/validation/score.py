"""Score the resistance estimator on runs with known truth: the validation family and the external runs.

For every run listed in a ``runs.csv`` (the family's, written by family.py, and ``../shared/validation/runs``):
the offline pipeline (``train_calib.pipeline.run_bag``) with one UKF configuration (``--preset NAME`` or the
plain ``UKFConfig()``), then at v_ref = min(80 km/h, 0.8 x the run's top speed), and at 120 km/h where the
run reaches it:

* the final published estimate's error of r(v) against the truth (%), the prior's (train file) error;
* whether the truth lies inside 2 sigma, sigma = sqrt(h^T P_rr h), h = [1, v, v^2], and 2 sigma / r (%);
* the oracle ("the data's own limit"): a Bayesian least-squares fit over the truly coasting stretches
  (>= 20 s where the truth's u == 0 and its own speeds show no effort between the samples: coasting_throughout)
  on the pipeline's own measurements, toward the train file's values; and the same over every u == 0 stretch;
* per-sample regime accuracy against the truth (standing samples ignored), and without the truth's coasting
  samples that are not coasting_throughout;
* a whole-run best estimate when the pipeline output exposes one (``output.best``).

Aggregates per family and split go to ``build/validation/scores_<preset>.json`` and a markdown table to
stdout and ``bench/validation/RESULTS_<preset>.md``.

    .venv/bin/python bench/validation/score.py [--preset NAME] [--family-dir DIR] [--external-dir DIR]
        [--no-external] [--no-family] [--jobs 2]
"""

from __future__ import annotations

import argparse
import csv
import itertools
import json
import math
import sys
import time
from collections.abc import Iterable, Sequence
from dataclasses import asdict, dataclass, field
from functools import lru_cache
from multiprocessing import Pool
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np

from train_calib.bagio import iter_bag
from train_calib.estimation import UKFConfig
from train_calib.paths import track_file, train_file
from train_calib.physics import KMH, davis
from train_calib.pipeline import run_bag, whole_run_regimes
from train_calib.track import Track, load_track
from train_calib.train import TrainSpec, load_train

HERE = Path(__file__).resolve().parent
REPO = HERE.parent.parent
FAMILY_DIR = REPO / "build" / "validation" / "family"
EXTERNAL_DIR = (REPO / ".." / "shared" / "validation" / "runs").resolve()
SCORES_DIR = REPO / "build" / "validation"
TRUTH_SUFFIX = ".validation-truth.json"
ENERGY_PERIOD_S = 5.0  # s: the oracle takes the energy form from here on (UKFConfig.coast_energy_period)
V_CAP = 80.0 * KMH  # v_ref = min(80 km/h, 0.8 v_max), m/s
V_HIGH = 120.0 * KMH  # the second reference speed where the run reaches it, m/s
MIN_COAST_S = 20.0  # oracle: truly coasting stretches of at least this long, s
KINEMATIC_TOLERANCE = 0.2  # oracle: a coasting step's mean effort from the truth's kinematics within this x r of 0
PRIOR_COMMON = 0.18  # oracle prior: common relative std of the three coefficients
PRIOR_OWN = 0.10  # oracle prior: independent relative std per coefficient
WORSE_POINTS = 2.0  # a run is "worse than the prior" when |err| exceeds the prior's by this, points of %


# -- inputs ------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class RunEntry:
    """One run to score: bag path, track and train files, family and split names."""

    bag: str
    track: str
    train: str
    family: str
    split: str


def resolve(name: str, base: Path, bundled: Any) -> str:
    """A file relative to the runs.csv, to the repository, or a bundled name."""
    for cand in (base / name, REPO / name, Path(name)):
        if cand.is_file():
            return str(cand.resolve())
    return str(bundled(name))


def family_of(bag: str) -> str:
    """External runs: the bag name without its trailing run number (stadelhofen_kiss_eco_1hz_00 -> ..._1hz)."""
    head, _, tail = bag.rpartition("_")
    return head if tail.isdigit() else bag


def read_runs(directory: Path, default_split: str) -> list[RunEntry]:
    """The runs of a ``runs.csv`` directory; family and split from the columns or from the bag name."""
    path = directory / "runs.csv"
    with open(path, encoding="utf-8", newline="") as f:
        rows = list(csv.DictReader(f))
    out = []
    for r in rows:
        out.append(
            RunEntry(
                bag=str(directory / r["bag"]),
                track=resolve(r["track"], directory, track_file),
                train=resolve(r["train"], directory, train_file),
                family=r.get("family") or family_of(r["bag"]),
                split=r.get("split") or default_split,
            )
        )
    return out


@lru_cache(maxsize=16)
def _track(path: str) -> Track:
    return load_track(path)


@lru_cache(maxsize=16)
def _train(path: str) -> TrainSpec:
    return load_train(path)


def first_message_ns(bag: str) -> int:
    """Log time (= stamp) of the bag's first message, ns: the truth's t = 0."""
    for m in iter_bag(bag):
        return int(m.log_time_ns)
    raise ValueError(f"{bag}: empty bag")


# -- resistance arithmetic -------------------------------------------------------------------------------------
def r_of(c: Sequence[float], v: float) -> float:
    """Davis r(v) = r0 + r1 v + r2 v^2, N/kg (v in m/s)."""
    return float(c[0] + c[1] * v + c[2] * v * v)


def sigma_of(cov_rr: np.ndarray, v: float) -> float:
    """Standard deviation of r(v) from the 3x3 covariance of (r0, r1, r2), N/kg."""
    h = np.array([1.0, v, v * v])
    return float(math.sqrt(max(float(h @ cov_rr @ h), 0.0)))


def rel_err(est: Sequence[float], truth: Sequence[float], v: float) -> float:
    """Relative error of r(v), %."""
    return 100.0 * (r_of(est, v) - r_of(truth, v)) / r_of(truth, v)


def r_block(cov: Any) -> np.ndarray:
    """The (r0, r1, r2) block of a 5x5 (s, v, r0, r1, r2) or 3x3 covariance."""
    c = np.asarray(cov, dtype=float)
    if c.size == 9:
        return c.reshape(3, 3)
    return c.reshape(5, 5)[2:5, 2:5]


# -- the oracle ------------------------------------------------------------------------------------------------
def coasting_stretches(
    t: np.ndarray, u: np.ndarray, v: np.ndarray, min_s: float = MIN_COAST_S, coast: np.ndarray | None = None
) -> list[tuple[float, float]]:
    """(start, end) in s of the truth's moving u == 0 stretches lasting at least ``min_s`` (or of the samples
    ``coast`` marks: :func:`coasting_throughout`)."""
    coast = (u == 0.0) & (v > 0.0) if coast is None else coast
    out = []
    i, n = 0, len(t)
    while i < n:
        if not coast[i]:
            i += 1
            continue
        j = i
        while j + 1 < n and coast[j + 1] and t[j + 1] - t[j] <= 1.5:
            j += 1
        if t[j] - t[i] >= min_s:
            out.append((float(t[i]), float(t[j])))
        i = j + 1
    return out


def coasting_throughout(
    t: np.ndarray,
    s: np.ndarray,
    v: np.ndarray,
    u: np.ndarray,
    truth: Sequence[float],
    track: Track,
    train: TrainSpec,
    tolerance: float = KINEMATIC_TOLERANCE,
) -> np.ndarray:
    """Per truth sample: u == 0 there, moving, and no effort over either adjacent step by the truth's own
    kinematics: the step's mean effort dv/dt + mean r + mean g (the truth's r, this project's g(s) over the
    train length at the truth's s) within ``tolerance`` x mean r of zero.

    The truth's u is sampled at 1 Hz. The external runs' simulator holds a cruise with traction pulses shorter
    than a second, so its u reads 0 at most samples of a held speed (stadelhofen_kiss_eco_1hz_00 at t = 230-245 s:
    u = 0, 1.035, 0, 0, 1.035, 0, ..., a = -0.3 .. -0.1 m/s^2, v held at 12.33 m/s): those samples are not
    coasting, and the oracle over them missed the truth by up to 40 %. On this project's family the check removes
    0-3 % of a run's coasting samples (family medians; the seconds where the effort ramps at a coast's ends)."""
    t, s, v, u = (np.asarray(x, dtype=float) for x in (t, s, v, u))
    tun = np.asarray(track.tunnel_fraction(s, train.length_m), dtype=float)
    r = davis(v, *truth, tun, train.tunnel_factor)
    g = np.asarray(track.track_force(s, train.length_m), dtype=float)
    dt = np.diff(t)
    with np.errstate(invalid="ignore", divide="ignore"):
        effort = np.diff(v) / dt + 0.5 * (r[1:] + r[:-1]) + 0.5 * (g[1:] + g[:-1])
    calm = (np.abs(effort) <= tolerance * 0.5 * (r[1:] + r[:-1])) | (dt > 1.5)  # a gap is not a step
    out = (u == 0.0) & (v > 0.0)
    out[:-1] &= calm
    out[1:] &= calm
    return out


@dataclass
class CoastData:
    """The oracle's equations: y = -(dv/dt) - mean g (N/kg) against h = [1, vbar, k vbar^2] (k: tunnel term).

    ``D``: the equations' noise covariance up to a scale (1/s^2): with independent speed noise per sample,
    the pair (i, j) has -(n_j - n_i)/dt, so neighbouring equations sharing a sample are correlated
    (D = B B^T, B the scaled difference operator). Without it, the 1 Hz equations look 1/dt^2 noisier
    than the sums over a coast are (they telescope), and the fit would shrink toward the prior.
    """

    y: np.ndarray
    H: np.ndarray
    D: np.ndarray
    stretches: int
    seconds: float


def coast_equations(
    ms: Sequence[Any], first_ns: int, stretches: Sequence[tuple[float, float]], tunnel_factor: float
) -> CoastData:
    """One equation per consecutive pair of measurements (same run_id) inside one coasting stretch: the time form
    -(v_j - v_i) / dt - g = r(v), or, at 5 s sampling and sparser where the measurements carry the track force's
    integral Gamma(s), the energy form -(E_j - E_i) / (s_j - s_i) = mean r over the step with E = v^2/2 + Gamma
    (the gradient's changes inside a 200-300 m step are then exact; the product uses the same form there)."""
    t = np.array([(m.stamp_ns - first_ns) * 1e-9 for m in ms])
    v = np.array([m.v for m in ms])
    g = np.array([m.track_force for m in ms])
    tun = np.array([m.tunnel_fraction for m in ms])
    rid = np.array([m.run_id for m in ms])
    s = np.array([getattr(m, "s", math.nan) for m in ms])
    gamma = np.array([getattr(m, "track_force_integral", math.nan) for m in ms])
    energy = t.size > 2 and float(np.median(np.diff(t))) >= ENERGY_PERIOD_S and bool(np.all(np.isfinite(gamma)))
    e = 0.5 * v * v + gamma
    ys, hs, pairs = [], [], []
    for a, b in stretches:
        inside = np.flatnonzero((t >= a - 1e-6) & (t <= b + 1e-6))
        for i, j in itertools.pairwise(inside):
            if j != i + 1 or rid[i] != rid[j] or t[j] <= t[i]:
                continue
            k = 1.0 + tunnel_factor * 0.5 * (tun[i] + tun[j])
            if energy:
                ds = s[j] - s[i]
                if ds <= 1.0:
                    continue
                ys.append(-(e[j] - e[i]) / ds)
                hs.append([1.0, 0.5 * (v[i] + v[j]), k * 0.5 * (v[i] * v[i] + v[j] * v[j])])
                pairs.append((int(i), int(j), float(ds), float(v[i]), float(v[j])))
            else:
                vbar = 0.5 * (v[i] + v[j])
                ys.append(-(v[j] - v[i]) / (t[j] - t[i]) - 0.5 * (g[i] + g[j]))
                hs.append([1.0, vbar, k * vbar * vbar])
                pairs.append((int(i), int(j), float(t[j] - t[i]), 1.0, 1.0))
    seconds = float(sum(b - a for a, b in stretches))
    return CoastData(np.array(ys), np.array(hs).reshape(-1, 3), difference_covariance(pairs), len(stretches), seconds)


def difference_covariance(pairs: Sequence[tuple[int, int, float, float, float]]) -> np.ndarray:
    """D = B B^T for equations (w_j n_j - w_i n_i) / d over independent unit sample noises n (pairs (i, j, d, w_i,
    w_j): d = dt and w = 1 in the time form, d = ds and w = v in the energy form)."""
    used = sorted({p[0] for p in pairs} | {p[1] for p in pairs})
    col = {k: c for c, k in enumerate(used)}
    B = np.zeros((len(pairs), len(used)))
    for row, (i, j, d, wi, wj) in enumerate(pairs):
        B[row, col[i]] = -wi / d
        B[row, col[j]] = wj / d
    return B @ B.T


def prior_covariance(r: Sequence[float]) -> np.ndarray:
    """P0 = (0.18)^2 r r^T + diag((0.10 r_i)^2): common scale uncertainty plus independent shape."""
    rv = np.asarray(r, dtype=float)
    return PRIOR_COMMON**2 * np.outer(rv, rv) + np.diag((PRIOR_OWN * rv) ** 2)


def bayes_fit(
    y: np.ndarray, H: np.ndarray, x0: Sequence[float], P0: np.ndarray, D: np.ndarray | None = None, iterations: int = 4
) -> tuple[np.ndarray, np.ndarray]:
    """Posterior mean and covariance of x for y = H x + e, x ~ N(x0, P0), e ~ N(0, s2 D), s2 from residuals.

    ``D`` defaults to the identity. Gain form (no inverse of P0, which may be singular: r1 = 0 trains);
    s2 is re-estimated from the posterior residuals a few times (res^T D^-1 res / (n - effective parameters)).
    """
    x0 = np.asarray(x0, dtype=float)
    if y.size == 0:
        return x0.copy(), P0.copy()
    D = np.eye(y.size) if D is None else D
    r0 = y - H @ x0
    s2 = max(float(r0 @ np.linalg.solve(D, r0)) / y.size, 1e-18)
    x, P = x0, P0
    for _ in range(iterations):
        S = H @ P0 @ H.T + s2 * D
        K = np.linalg.solve(S, H @ P0).T
        x = x0 + K @ r0
        P = P0 - K @ H @ P0
        dof = float(np.trace(H @ K))
        res = y - H @ x
        s2 = max(float(res @ np.linalg.solve(D, res)) / max(y.size - dof, 1.0), 1e-18)
    return x, P


# -- one run -------------------------------------------------------------------------------------------------
@dataclass
class RunScore:
    """Scores of one run (errors in %, speeds in km/h, sigma as 2 sigma / r in %)."""

    bag: str
    family: str
    split: str
    v_ref_kmh: float
    v_max_kmh: float
    truth: list[float]
    prior: list[float]
    final: list[float]
    err: float
    prior_err: float
    inside_2sigma: bool
    two_sigma_pct: float
    err_120: float | None
    prior_err_120: float | None
    inside_2sigma_120: bool | None
    oracle_err: float | None
    oracle_err_120: float | None
    oracle_two_sigma_pct: float | None
    oracle_white_err: float | None
    coast_stretches: int
    coast_s: float
    coast_equations: int
    regime_accuracy: float | None
    runs_in_bag: int
    best: dict[str, Any] | None = None
    regime_accuracy_whole_run: float | None = None
    oracle_u0_err: float | None = None  # the oracle over every u == 0 stretch of the truth (before coasting_throughout)
    regime_accuracy_consistent: float | None = None  # without the truth's coasting samples that are not coasting
    truth_coasting_aliased: float | None = None  # share of the truth's coasting samples not coasting_throughout
    seconds: float = 0.0
    error: str | None = None
    extra: dict[str, Any] = field(default_factory=dict)


def regime_accuracy(output: Any, first_ns: int, t: np.ndarray, regime: np.ndarray) -> float | None:
    """Share of the pipeline's per-sample regimes equal to the truth at the nearest second (standing ignored)."""
    recs = getattr(output, "regimes", None)
    if not recs:
        return None
    tr = np.array([(r.stamp_ns - first_ns) * 1e-9 for r in recs])
    est = np.array([r.regime for r in recs])
    idx = np.clip(np.searchsorted(t, tr), 1, len(t) - 1)
    idx = np.where(np.abs(t[idx - 1] - tr) <= np.abs(t[idx] - tr), idx - 1, idx)
    tru = regime[idx]
    use = (tru != 0) & (np.abs(t[idx] - tr) <= 1.0)
    return float(np.mean(est[use] == tru[use])) if use.any() else None


def best_of(output: Any) -> Any:
    """The whole-run best estimate if the pipeline exposes one (``output.best`` or ``output.final.best``)."""
    best = getattr(output, "best", None)
    if best is None and getattr(output, "final", None) is not None:
        best = getattr(output.final, "best", None)
    return best


def _field(obj: Any, name: str) -> Any:
    """obj[name] or obj.name; r0, r1, r2 also from an array ``r`` (N/kg units as published)."""
    if isinstance(obj, dict):
        return obj[name] if name in obj else obj["r"][("r0", "r1", "r2").index(name)]
    if hasattr(obj, name):
        return getattr(obj, name)
    return obj.r[("r0", "r1", "r2").index(name)]


def score_estimate(c: Sequence[float], cov: Any, truth: Sequence[float], v: float) -> dict[str, float | bool]:
    """err %, inside 2 sigma, 2 sigma / r % of one estimate at speed v."""
    sig = sigma_of(r_block(cov), v)
    err = rel_err(c, truth, v)
    return {
        "err": err,
        "inside_2sigma": bool(abs(r_of(c, v) - r_of(truth, v)) <= 2.0 * sig),
        "two_sigma_pct": 200.0 * sig / r_of(c, v),
    }


def score_run(entry: RunEntry, ukf: UKFConfig) -> RunScore:
    """Run the pipeline on one bag and score its final estimate, the prior and the oracle."""
    t_start = time.perf_counter()
    track, train = _track(entry.track), _train(entry.train)
    doc = json.loads(Path(entry.bag + TRUTH_SUFFIX).read_text(encoding="utf-8"))
    truth = [float(doc["r0"]), float(doc["r1"]), float(doc["r2"])]
    prior = list(train.davis.as_tuple())
    t, u, vt, reg, st = (np.asarray(doc[k], dtype=float) for k in ("t", "u", "v", "regime", "s"))
    v_max = float(vt.max())
    v_ref = min(V_CAP, 0.8 * v_max)
    speeds = [v_ref] + ([V_HIGH] if v_max >= V_HIGH else [])
    first_ns = first_message_ns(entry.bag)
    out = run_bag(entry.bag, track, train, ukf=ukf)
    fin = out.final
    final = [fin.r0, fin.r1, fin.r2]
    at = [score_estimate(final, fin.covariance, truth, v) for v in speeds]
    prior_errs = [rel_err(prior, truth, v) for v in speeds]
    throughout = coasting_throughout(t, st, vt, u, truth, track, train)
    stretches = coasting_stretches(t, u, vt, coast=throughout)
    eqs = coast_equations(out.measurements, first_ns, stretches, train.tunnel_factor)
    oracle_x, oracle_P = bayes_fit(eqs.y, eqs.H, prior, prior_covariance(prior), eqs.D)
    has_oracle = eqs.y.size > 0
    white_x, _ = bayes_fit(eqs.y, eqs.H, prior, prior_covariance(prior))
    eqs_u0 = coast_equations(out.measurements, first_ns, coasting_stretches(t, u, vt), train.tunnel_factor)
    u0_x, _ = bayes_fit(eqs_u0.y, eqs_u0.H, prior, prior_covariance(prior), eqs_u0.D)
    aliased = (reg == 3) & ~throughout  # the truth says coasting, its own kinematics show effort next to it
    best = best_of(out)
    best_scores = None
    if best is not None:
        bc = [float(_field(best, k)) for k in ("r0", "r1", "r2")]
        cov = _field(best, "covariance")
        best_scores = {"coefficients": bc, "at": [score_estimate(bc, cov, truth, v) for v in speeds]}
    return RunScore(
        bag=Path(entry.bag).name,
        family=entry.family,
        split=entry.split,
        v_ref_kmh=v_ref / KMH,
        v_max_kmh=v_max / KMH,
        truth=truth,
        prior=prior,
        final=final,
        err=float(at[0]["err"]),
        prior_err=prior_errs[0],
        inside_2sigma=bool(at[0]["inside_2sigma"]),
        two_sigma_pct=float(at[0]["two_sigma_pct"]),
        err_120=float(at[1]["err"]) if len(at) > 1 else None,
        prior_err_120=prior_errs[1] if len(at) > 1 else None,
        inside_2sigma_120=bool(at[1]["inside_2sigma"]) if len(at) > 1 else None,
        oracle_err=rel_err(oracle_x, truth, v_ref) if has_oracle else None,
        oracle_err_120=rel_err(oracle_x, truth, V_HIGH) if has_oracle and len(speeds) > 1 else None,
        oracle_two_sigma_pct=200.0 * sigma_of(oracle_P, v_ref) / r_of(oracle_x, v_ref) if has_oracle else None,
        oracle_white_err=rel_err(white_x, truth, v_ref) if has_oracle else None,
        oracle_u0_err=rel_err(u0_x, truth, v_ref) if eqs_u0.y.size else None,
        coast_stretches=eqs.stretches,
        coast_s=eqs.seconds,
        coast_equations=int(eqs.y.size),
        regime_accuracy=regime_accuracy(out, first_ns, t, reg.astype(int)),
        regime_accuracy_consistent=regime_accuracy(out, first_ns, t, np.where(aliased, 0, reg).astype(int)),
        truth_coasting_aliased=float(np.sum(aliased) / max(np.sum(reg == 3), 1)),
        regime_accuracy_whole_run=regime_accuracy(
            SimpleNamespace(regimes=whole_run_regimes(out, train)), first_ns, t, reg.astype(int)
        ),
        runs_in_bag=len({m.run_id for m in out.measurements}),
        best=best_scores,
        seconds=time.perf_counter() - t_start,
    )


def _score_star(args: tuple[RunEntry, UKFConfig]) -> RunScore:
    entry, ukf = args
    try:
        return score_run(entry, ukf)
    except Exception as exc:  # one broken run must not hide the others' scores
        return failed_score(entry, f"{type(exc).__name__}: {exc}")


def failed_score(entry: RunEntry, error: str) -> RunScore:
    """A run the scorer could not score: NaN numbers, the error text."""
    nan = float("nan")
    values: dict[str, Any] = {name: None for name in RunScore.__dataclass_fields__}
    values.update(bag=Path(entry.bag).name, family=entry.family, split=entry.split, truth=[], prior=[], final=[])
    values.update(v_ref_kmh=nan, v_max_kmh=nan, err=nan, prior_err=nan, inside_2sigma=False, two_sigma_pct=nan)
    values.update(coast_stretches=0, coast_s=0.0, coast_equations=0, runs_in_bag=0, seconds=0.0, extra={}, error=error)
    return RunScore(**values)


def score_all(entries: Sequence[RunEntry], ukf: UKFConfig, jobs: int = 2) -> list[RunScore]:
    """Score every run, in order (``jobs`` processes)."""
    args = [(e, ukf) for e in entries]
    if jobs > 1 and len(args) > 1:
        with Pool(jobs) as pool:
            return pool.map(_score_star, args, chunksize=1)
    return [_score_star(a) for a in args]


# -- aggregation -------------------------------------------------------------------------------------------
def _median(values: Iterable[float | None]) -> float | None:
    vals = [abs(v) for v in values if v is not None and math.isfinite(v)]
    return float(np.median(vals)) if vals else None


def aggregate(scores: Sequence[RunScore]) -> dict[str, Any]:
    """Medians of |error| (%), share inside 2 sigma, runs worse than the prior by > 2 points, for one group."""
    ok = [s for s in scores if s.error is None]
    n = len(ok)
    worse = sum(1 for s in ok if abs(s.err) > abs(s.prior_err) + WORSE_POINTS)
    at120 = [s for s in ok if s.err_120 is not None]
    best = [s for s in ok if s.best is not None]
    return {
        "runs": n,
        "failed": len(scores) - n,
        "median_err": _median(s.err for s in ok),
        "median_err_120": _median(s.err_120 for s in at120),
        "runs_120": len(at120),
        "median_prior_err": _median(s.prior_err for s in ok),
        "median_oracle_err": _median(s.oracle_err for s in ok),
        "median_oracle_white_err": _median(s.oracle_white_err for s in ok),
        "median_oracle_u0_err": _median(s.oracle_u0_err for s in ok),
        "median_regime_accuracy_consistent": _median(s.regime_accuracy_consistent for s in ok),
        "median_truth_coasting_aliased": _median(s.truth_coasting_aliased for s in ok),
        "runs_with_coast": sum(1 for s in ok if s.coast_equations > 0),
        "median_coast_s": float(np.median([s.coast_s for s in ok])) if ok else None,
        "inside_2sigma": sum(1 for s in ok if s.inside_2sigma),
        "median_two_sigma_pct": _median(s.two_sigma_pct for s in ok),
        "worse_than_prior": worse,
        "median_regime_accuracy": _median(s.regime_accuracy for s in ok),
        "median_regime_accuracy_whole_run": _median(s.regime_accuracy_whole_run for s in ok),
        "median_best_err": _median(s.best["at"][0]["err"] for s in best) if best else None,
        "best_inside_2sigma": sum(1 for s in best if s.best["at"][0]["inside_2sigma"]) if best else None,
    }


def group(scores: Sequence[RunScore]) -> dict[tuple[str, str], list[RunScore]]:
    """Scores by (family, split), in first-seen order, plus all-family totals per split."""
    out: dict[tuple[str, str], list[RunScore]] = {}
    for s in scores:
        out.setdefault((s.family, s.split), []).append(s)
    for split in ("tune", "report", "external"):
        members = [s for s in scores if s.split == split]
        if members:
            out[("ALL", split)] = members
    return out


# -- output ------------------------------------------------------------------------------------------------
def _f(x: float | None, digits: int = 1) -> str:
    return "-" if x is None else f"{x:.{digits}f}"


def _pct(share: float | None) -> str:
    """A share in 0-1 as a whole percentage, '-' for None."""
    return "-" if share is None else f"{100 * share:.0f}"


def _signed(x: float | None) -> str:
    return "-" if x is None else f"{x:+.1f}"


def markdown(scores: Sequence[RunScore], preset: str, note: str = "") -> str:
    """The aggregate table and the per-run table, markdown."""
    groups = group(scores)
    lines = [
        f"## Validation scores, UKF preset `{preset}`",
        "",
        *([note, ""] if note else []),
        "Errors are median |r(v) error| in % at v_ref = min(80 km/h, 0.8 v_max) (and at 120 km/h where runs reach "
        "it); oracle: Bayesian least squares toward the train file over the truly coasting stretches >= 20 s on the "
        "pipeline's own measurements (the data's own limit), with the correlation of the speed-difference "
        "equations; truly coasting: u == 0 at the truth's samples and no effort over the steps next to them by the "
        "truth's own speeds (``score.coasting_throughout``); oracle, white: the same with the equations taken as "
        "independent; oracle, u == 0: over every u == 0 stretch, as the truth's samples say (the external runs' "
        "simulator holds speeds with traction pulses between its 1 Hz samples, which read u = 0); "
        "2 sigma: runs whose truth lies inside the final estimate's 2 sigma; worse: runs more than 2 points worse "
        "than the prior; regimes: median per-sample accuracy (standing ignored), on board (what regime_node publishes "
        "at the defaults, one sample late) / whole run (offline, ``pipeline.whole_run_regimes``); regimes, "
        "kinematic: on board, without the truth's coasting samples that are not truly coasting (their share: "
        "aliased).",
        "",
        "| family | split | runs | err v_ref | err 120 (runs) | prior | oracle (runs with coast) | oracle, white | "
        "oracle, u == 0 | coast s | inside 2 sigma | 2 sigma / r | worse | regimes | regimes, kinematic (aliased) | "
        "best err (inside) |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for (fam, split), members in groups.items():
        a = aggregate(members)
        best = "-" if a["median_best_err"] is None else f"{a['median_best_err']:.1f} ({a['best_inside_2sigma']})"
        failed = f" ({a['failed']} failed)" if a["failed"] else ""
        lines.append(
            f"| {fam} | {split} | {a['runs']}{failed} | {_f(a['median_err'])} | {_f(a['median_err_120'])} "
            f"({a['runs_120']}) | {_f(a['median_prior_err'])} | {_f(a['median_oracle_err'])} "
            f"({a['runs_with_coast']}) | {_f(a['median_oracle_white_err'])} | {_f(a['median_oracle_u0_err'])} | "
            f"{_f(a['median_coast_s'], 0)} | {a['inside_2sigma']}/{a['runs']} | "
            f"{_f(a['median_two_sigma_pct'])} | {a['worse_than_prior']} | "
            f"{_pct(a['median_regime_accuracy'])} / {_pct(a['median_regime_accuracy_whole_run'])} | "
            f"{_pct(a['median_regime_accuracy_consistent'])} ({_pct(a['median_truth_coasting_aliased'])} %) | {best} |"
        )
    lines += [
        "",
        "Per run (signed errors, %):",
        "",
        "| run | split | v_ref km/h | err | prior | oracle | oracle, white | oracle, u == 0 | 2 sigma / r | inside | "
        "err 120 | coast s (eq) | regimes % | regimes, kinematic % (aliased) | run_ids |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for s in scores:
        if s.error is not None:
            lines.append(f"| {s.bag} | {s.split} | failed: {s.error} ||||||||||||")
            continue
        reg = f"{_pct(s.regime_accuracy)} / {_pct(s.regime_accuracy_whole_run)}"
        lines.append(
            f"| {s.bag} | {s.split} | {s.v_ref_kmh:.0f} | {s.err:+.1f} | {s.prior_err:+.1f} | "
            f"{_signed(s.oracle_err)} | {_signed(s.oracle_white_err)} | {_signed(s.oracle_u0_err)} | "
            f"{s.two_sigma_pct:.1f} | {'yes' if s.inside_2sigma else 'no'} | {_signed(s.err_120)} | "
            f"{s.coast_s:.0f} ({s.coast_equations}) | {reg} | "
            f"{_pct(s.regime_accuracy_consistent)} ({_pct(s.truth_coasting_aliased)}) | {s.runs_in_bag} |"
        )
    return "\n".join(lines) + "\n"


def to_json(scores: Sequence[RunScore], preset: str, seconds: float) -> dict[str, Any]:
    """Everything: the configuration, the aggregates per (family, split) and every run."""
    return {
        "preset": preset,
        "seconds": seconds,
        "aggregates": [{"family": f, "split": s, **aggregate(m)} for (f, s), m in group(scores).items()],
        "runs": [asdict(s) for s in scores],
    }


def config_for(preset: str | None) -> tuple[str, UKFConfig]:
    """(label, config): a named preset, or the plain defaults."""
    if not preset or preset == "default":
        return "default", UKFConfig()
    return preset, UKFConfig.preset(preset)


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--preset", help="UKFConfig.preset name (default: the plain UKFConfig())")
    ap.add_argument("--family-dir", type=Path, default=FAMILY_DIR, help="the family's runs.csv directory")
    ap.add_argument("--external-dir", type=Path, default=EXTERNAL_DIR, help="the external runs' directory")
    ap.add_argument("--no-family", action="store_true", help="score the external runs only")
    ap.add_argument("--no-external", action="store_true", help="score the family only")
    ap.add_argument("--families", nargs="*", help="only these families (and external ones) by name")
    ap.add_argument("--json", type=Path, help="output JSON (default build/validation/scores_<preset>.json)")
    ap.add_argument("--markdown", type=Path, help="output markdown (default bench/validation/RESULTS_<preset>.md)")
    ap.add_argument("--jobs", type=int, default=2, help="processes (default 2)")
    ap.add_argument("--note", default="", help="a line under the table's title (e.g. which code was measured)")
    args = ap.parse_args(argv)
    label, ukf = config_for(args.preset)
    entries: list[RunEntry] = []
    if not args.no_family:
        entries += read_runs(args.family_dir, "tune")
    if not args.no_external and (args.external_dir / "runs.csv").is_file():
        entries += read_runs(args.external_dir, "external")
    elif not args.no_external:
        print(f"{args.external_dir}: no runs.csv, external runs skipped", file=sys.stderr)
    if args.families:
        entries = [e for e in entries if e.family in args.families]
    t0 = time.perf_counter()
    scores = score_all(entries, ukf, args.jobs)
    seconds = time.perf_counter() - t0
    text = markdown(scores, label, args.note)
    text += f"\n{len(scores)} runs scored in {seconds:.0f} s ({args.jobs} processes).\n"
    json_path = args.json or SCORES_DIR / f"scores_{label}.json"
    md_path = args.markdown or HERE / f"RESULTS_{label}.md"
    json_path.parent.mkdir(parents=True, exist_ok=True)
    json_path.write_text(json.dumps(to_json(scores, label, seconds), indent=1) + "\n", encoding="utf-8")
    md_path.write_text(text, encoding="utf-8")
    print(text)
    print(f"wrote {json_path} and {md_path}")
    return 1 if any(s.error is not None for s in scores) else 0


if __name__ == "__main__":
    sys.exit(main())
