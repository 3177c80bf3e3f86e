"""Do a run's coasts say when they mislead? Their residuals against their stated noise, over noise draws.

For each run and noise draw (as ``replicates.py`` draws them: same truth, drivers, dwells and sensor phase, only
the sensor noise redrawn), the whole run's fit (``summary.json`` ``best``) is walked coast by coast in its own
order, and each coast in the energy form gives its NIS and degrees of freedom before it is added
(``coast_posterior.coast_consistency``). Under the stated noise NIS/dof is near 1. The question is whether the
draws that end more than 2 points worse than their prior (``score.WORSE_POINTS``; on board, the criterion's
figure) are the inconsistent ones, which a Birge ratio (the data's information divided by max(1, NIS/dof))
would then pull back toward the prior. Markdown to stdout; docs/estimator.md (Validation) quotes the result.

    .venv/bin/python bench/validation/coast_consistency.py [--families eco_stadelhofen] [--replicates 30]
        [--jobs 2]
"""

from __future__ import annotations

import argparse
import shutil
import sys
import tempfile
from collections.abc import Sequence
from multiprocessing import Pool
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

import family as fam_mod  # noqa: E402  (a script folder, not a package)
import replicates  # noqa: E402
import score  # noqa: E402

from train_calib.estimation import UKFConfig  # noqa: E402
from train_calib.estimation.coast_posterior import (  # noqa: E402
    add_coast,
    coast_consistency,
    coasts_of,
    prior_covariance,
    prior_information,
)
from train_calib.estimation.coast_types import CoastSettings  # noqa: E402
from train_calib.pipeline import run_bag  # noqa: E402
from train_calib.sim.truthio import write_bag  # noqa: E402


def one_draw(args: tuple[str, int]) -> tuple[str, str, bool, float, int]:
    """Run ``name`` with noise draw ``j``: (name, split, worse than the prior on board, NIS, dof) over its coasts."""
    name, j = args
    spec = replicates.spec_named(name)
    streams, truth, _track, _train = fam_mod.simulate_spec(spec, noise_seed=replicates.noise_seed(spec, j))
    track = score._track(str(fam_mod.resolve_track(spec.family.track)))
    train = score._train(str(fam_mod.resolve_train(spec.family.train)))
    tmp = Path(tempfile.mkdtemp(prefix="consistency-"))
    try:
        write_bag(streams, tmp / spec.name)  # type: ignore[arg-type]  # reads .gnss, .speed, .power only
        out = run_bag(str(tmp / spec.name), track, train, ukf=UKFConfig())
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    v_true = fam_mod.truth_document(spec, streams, truth)["v"]  # the truth's speeds, as score_run reads them
    v_ref = min(score.V_CAP, 0.8 * float(np.max(v_true)))
    err = score.rel_err([out.final.r0, out.final.r1, out.final.r2], truth.as_tuple(), v_ref)
    prior_err = score.rel_err(train.davis.as_tuple(), truth.as_tuple(), v_ref)
    settings = CoastSettings.from_config(UKFConfig())
    r_prior = np.asarray(train.davis.as_tuple(), dtype=float)
    info = prior_information(
        r_prior, prior_covariance(r_prior, settings.prior_scale_std, settings.prior_coefficient_std)
    )
    nis, dof = 0.0, 0
    for members in coasts_of(out.best.stretches if out.best is not None else []):
        consistency = coast_consistency(info, members)  # None: a coast taken with its ends sure
        if consistency is not None:
            nis, dof = nis + consistency[0], dof + consistency[1]
        info = add_coast(info, members)
    return name, spec.split, abs(err) > abs(prior_err) + score.WORSE_POINTS, nis, dof


def markdown(rows: Sequence[tuple[str, str, bool, float, int]], draws: int) -> str:
    lines = [
        f"NIS/dof of the whole-run fit's coasts (energy form), {draws} noise draws a run; worse: on board, more "
        f"than {score.WORSE_POINTS:g} points worse than the prior",
        "",
        "| split | draws with coasts | NIS/dof median (10-90 %) | draws worse | their NIS/dof median | others' median "
        "| worse with NIS/dof > 1 | others with NIS/dof > 1 |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for split in ("tune", "report"):
        mine = [(w, n / d) for _, s, w, n, d in rows if s == split and d > 0]
        if not mine:
            continue
        worse = np.array([w for w, _ in mine])
        ratio = np.array([r for _, r in mine])
        p10, p90 = np.percentile(ratio, [10, 90])

        def med(x: np.ndarray) -> str:
            return f"{np.median(x):.2f}" if x.size else "-"

        def above(x: np.ndarray) -> str:
            return f"{int(np.sum(x > 1.0))} of {x.size}"

        lines.append(
            f"| {split} | {len(mine)} | {np.median(ratio):.2f} ({p10:.2f}-{p90:.2f}) | {int(worse.sum())} | "
            f"{med(ratio[worse])} | {med(ratio[~worse])} | {above(ratio[worse])} | {above(ratio[~worse])} |"
        )
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--families", nargs="+", default=["eco_stadelhofen"])
    ap.add_argument("--replicates", type=int, default=30)
    ap.add_argument("--jobs", type=int, default=2)
    a = ap.parse_args(argv)
    known = {f.name: f for f in fam_mod.FAMILIES}
    unknown = [f for f in a.families if f not in known]
    if unknown:
        ap.error(f"--families: not a family of bench/validation/family.py: {', '.join(unknown)}")
    names = [f"{f}_{k:02d}" for f in a.families for k in range(known[f].runs)]
    work = [(n, j) for n in names for j in range(a.replicates)]
    if a.jobs > 1:
        with Pool(a.jobs) as pool:
            rows = pool.map(one_draw, work, chunksize=4)
    else:
        rows = [one_draw(w) for w in work]
    print(markdown(rows, a.replicates))
    return 0


if __name__ == "__main__":
    sys.exit(main())
