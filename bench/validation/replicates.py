"""Noise replicates of validation runs: how often a run ends worse than its prior, and whether 2 sigma holds.

A run of the family is one draw of the sensor noise. Whether *that* draw ends more than 2 points worse than the
prior, or outside its 2 sigma, says little on its own where a run carries little information (eco at 10 s: two
short coasts a run). Here each run is simulated again N times with the same truth, drivers, dwells and sensor
phase, and only the sensor noise redrawn (``family.simulate_spec(..., noise_seed=...)``). For each replicate the
scorer's ``score_run`` gives the estimate at the defaults (or ``--preset``) and the oracle (the fit over the true
coasts, the data's own limit). Per run:

* the estimate's and the oracle's mean and spread of the signed r(v_ref) error (%), against the prior's;
* P(worse): the share of replicates more than 2 points worse than the prior (``score.WORSE_POINTS``), for the
  estimate and for the oracle: how often the data themselves mislead on this run;
* the share of replicates whose truth lies inside the published 2 sigma, and the median 2 sigma / r (%).

Per family and split: the sums of P(worse) (the expected number of runs worse than their prior in one draw of
the family) and the coverage over all replicates. Markdown to stdout and ``--md`` (default
``bench/validation/RESULTS_replicates.md``), every draw to ``build/validation/<md's stem>_<preset>.json``.

    .venv/bin/python bench/validation/replicates.py [--families NAME ...] [--runs NAME ...] [--split S]
        [--replicates 50] [--preset NAME] [--jobs 2] [--md FILE]
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
import tempfile
import time
from collections.abc import Iterable, Sequence
from dataclasses import asdict, dataclass
from multiprocessing import Pool
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

import family as fam_mod  # noqa: E402  (a script folder, not a package)
import score  # noqa: E402

from train_calib.estimation import UKFConfig  # noqa: E402
from train_calib.sim.truthio import write_bag  # noqa: E402

NOISE_BASE_SEED = 1919  # replicate j of run k of family F: noise seed [1919, crc32(F), k, j]
DEFAULT_MD = HERE / "RESULTS_replicates.md"


@dataclass
class Replicate:
    """One noise draw of one run: signed errors in % at v_ref, inside 2 sigma, 2 sigma / r in %."""

    j: int
    err: float
    oracle_err: float | None
    inside_2sigma: bool
    two_sigma_pct: float


@dataclass
class RunReplicates:
    """All the noise draws of one run (``j = -1``: the family's own draw, as in the bag)."""

    run: str
    family: str
    split: str
    prior_err: float
    own: Replicate
    replicates: list[Replicate]

    def errors(self, oracle: bool = False) -> np.ndarray:
        """The draws' signed errors in % (the estimate's, or the oracle's: nan where it has no coast)."""
        vals = [r.oracle_err if oracle else r.err for r in self.replicates]
        return np.array([np.nan if v is None else v for v in vals], dtype=float)

    def worse_share(self, oracle: bool = False) -> float | None:
        """Share of replicates whose |error| exceeds the prior's by more than score.WORSE_POINTS."""
        e = self.errors(oracle)
        e = e[np.isfinite(e)]
        if e.size == 0:
            return None
        return float(np.mean(np.abs(e) > abs(self.prior_err) + score.WORSE_POINTS))

    def mean_sd(self, oracle: bool = False) -> tuple[float, float] | None:
        e = self.errors(oracle)
        e = e[np.isfinite(e)]
        return (float(e.mean()), float(e.std())) if e.size else None

    def coverage(self) -> float:
        return float(np.mean([r.inside_2sigma for r in self.replicates]))

    def median_two_sigma(self) -> float:
        return float(np.median([r.two_sigma_pct for r in self.replicates]))


def spec_named(name: str) -> fam_mod.RunSpec:
    """The RunSpec of a family run name such as ``eco_stadelhofen_05``."""
    family_name, _, k = name.rpartition("_")
    for f in fam_mod.FAMILIES:
        if f.name == family_name and k.isdigit() and int(k) < f.runs:
            return fam_mod.RunSpec(f, int(k))
    raise ValueError(f"--runs: {name!r} is not a run of the validation family")


def noise_seed(spec: fam_mod.RunSpec, j: int) -> list[int]:
    return [NOISE_BASE_SEED, spec.seed[1], spec.k, j]


def one_replicate(args: tuple[str, int, UKFConfig]) -> tuple[str, float, Replicate]:
    """Simulate run ``name`` with noise draw ``j`` (-1: the family's own), score it; returns (name, prior, rep)."""
    name, j, ukf = args
    spec = spec_named(name)
    streams, truth, _track, _train = fam_mod.simulate_spec(spec, noise_seed=None if j < 0 else noise_seed(spec, j))
    tmp = Path(tempfile.mkdtemp(prefix="replicate-"))
    try:
        bag = tmp / spec.name
        write_bag(streams, bag)  # type: ignore[arg-type]  # reads .gnss, .speed, .power only
        (tmp / (spec.name + score.TRUTH_SUFFIX)).write_text(
            json.dumps(fam_mod.truth_document(spec, streams, truth)), encoding="utf-8"
        )
        entry = score.RunEntry(
            bag=str(bag),
            track=str(fam_mod.resolve_track(spec.family.track)),
            train=str(fam_mod.resolve_train(spec.family.train)),
            family=spec.family.name,
            split=spec.split,
        )
        s = score.score_run(entry, ukf)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return name, s.prior_err, Replicate(j, s.err, s.oracle_err, s.inside_2sigma, s.two_sigma_pct)


def run_replicates(names: Sequence[str], replicates: int, ukf: UKFConfig, jobs: int = 2) -> list[RunReplicates]:
    """Every run's own draw and ``replicates`` noise draws, scored in ``jobs`` processes."""
    work = [(n, j, ukf) for n in names for j in range(-1, replicates)]
    if jobs > 1:
        with Pool(jobs) as pool:
            done = pool.map(one_replicate, work, chunksize=4)
    else:
        done = [one_replicate(w) for w in work]
    out = []
    for n in names:
        mine = [(p, r) for name, p, r in done if name == n]
        spec = spec_named(n)
        own = next(r for _, r in mine if r.j < 0)
        out.append(RunReplicates(n, spec.family.name, spec.split, mine[0][0], own, [r for _, r in mine if r.j >= 0]))
    return out


# -- output ------------------------------------------------------------------------------------------------
def _ms(x: tuple[float, float] | None) -> str:
    return "-" if x is None else f"{x[0]:+.1f} ± {x[1]:.1f}"


def _share(x: float | None) -> str:
    return "-" if x is None else f"{100 * x:.0f} %"


def _abs_median(parts: Iterable[np.ndarray]) -> float | None:
    """Median |error| over the finite values of every run's draws (None when there are none)."""
    e = np.abs(np.concatenate(list(parts)))
    e = e[np.isfinite(e)]
    return float(np.median(e)) if e.size else None


def markdown(results: Sequence[RunReplicates], replicates: int, preset: str) -> str:
    lines = [
        f"## Noise replicates, UKF preset `{preset}`, {replicates} draws a run",
        "",
        "Each run simulated again with the same truth, drivers, dwells and sensor phase and only the sensor noise "
        "redrawn. err: signed r(v_ref) error in %, mean ± spread over the draws; own: the family's draw (the bag "
        "`make validate` scores); oracle: the fit over the true coasts (the data's own limit); P(worse): share of "
        "draws more than 2 points worse than the prior; inside: share of draws with the truth inside the published "
        "2 sigma.",
        "",
        "| family | split | runs | median abs err, estimate (all draws) | oracle | prior | expected runs worse, "
        "estimate | expected runs worse, oracle | worse in the own draw | inside 2 sigma (all draws) |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    groups: dict[tuple[str, str], list[RunReplicates]] = {}
    for r in results:
        groups.setdefault((r.family, r.split), []).append(r)
    for (f, split), members in groups.items():
        est = sum(m.worse_share() or 0.0 for m in members)
        ora = sum(m.worse_share(oracle=True) or 0.0 for m in members)
        own = sum(1 for m in members if abs(m.own.err) > abs(m.prior_err) + score.WORSE_POINTS)
        cov = float(np.mean([r.inside_2sigma for m in members for r in m.replicates]))
        med = _abs_median(m.errors() for m in members)
        med_o = _abs_median(m.errors(oracle=True) for m in members)
        prior = float(np.median([abs(m.prior_err) for m in members]))
        lines.append(
            f"| {f} | {split} | {len(members)} | {score._f(med)} | {score._f(med_o)} | {prior:.1f} | {est:.2f} | "
            f"{ora:.2f} | {own} | {_share(cov)} |"
        )
    lines += [
        "",
        "| run | split | prior | own draw | estimate | oracle | P(worse) estimate | P(worse) oracle | inside | "
        "2 sigma / r |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for m in results:
        lines.append(
            f"| {m.run} | {m.split} | {m.prior_err:+.1f} | {m.own.err:+.1f} | {_ms(m.mean_sd())} | "
            f"{_ms(m.mean_sd(oracle=True))} | {_share(m.worse_share())} | {_share(m.worse_share(oracle=True))} | "
            f"{_share(m.coverage())} | {m.median_two_sigma():.1f} |"
        )
    return "\n".join(lines) + "\n"


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--families", nargs="*", help="every run of these families (default: eco_stadelhofen)")
    ap.add_argument("--runs", nargs="*", help="these runs, e.g. eco_stadelhofen_05 (instead of --families)")
    ap.add_argument("--split", choices=("tune", "report", "all"), default="all", help="only this half")
    ap.add_argument("--replicates", type=int, default=50, help="noise draws a run (default %(default)s)")
    ap.add_argument("--preset", help="UKFConfig.preset(NAME) instead of the defaults")
    ap.add_argument("--jobs", type=int, default=2, help="processes (default %(default)s)")
    ap.add_argument("--md", type=Path, default=DEFAULT_MD, help="markdown output (default %(default)s)")
    args = ap.parse_args(argv)
    if args.replicates < 1:
        print(f"--replicates: {args.replicates} must be at least 1", file=sys.stderr)
        return 2
    try:
        preset, ukf = score.config_for(args.preset)
    except (KeyError, ValueError) as exc:
        print(f"--preset: {exc}", file=sys.stderr)
        return 2
    try:
        if args.runs:
            names = [spec_named(n).name for n in args.runs]
        else:
            wanted = args.families or ["eco_stadelhofen"]
            known = {f.name: f for f in fam_mod.FAMILIES}
            unknown = [w for w in wanted if w not in known]
            if unknown:
                print(f"--families: unknown {unknown} (known: {', '.join(known)})", file=sys.stderr)
                return 2
            names = [s.name for s in fam_mod.all_specs([known[w] for w in wanted])]
    except ValueError as exc:
        print(exc, file=sys.stderr)
        return 2
    if args.split != "all":
        names = [n for n in names if spec_named(n).split == args.split]
    t0 = time.perf_counter()
    results = run_replicates(names, args.replicates, ukf, args.jobs)
    text = markdown(results, args.replicates, preset)
    print(text, end="")
    print(f"{len(names)} runs x {args.replicates + 1} draws in {time.perf_counter() - t0:.0f} s")
    args.md.write_text(text, encoding="utf-8")
    out = score.SCORES_DIR / f"{args.md.stem}_{preset}.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps([asdict(r) for r in results]) + "\n", encoding="utf-8")
    return 0


if __name__ == "__main__":
    sys.exit(main())
