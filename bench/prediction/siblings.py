"""Units for the validation family (issue 24): sibling runs of each held-out run, the same unit on other days.

A sibling of a family run (``bench/validation/family.py``) has the same train, track, driving style and sensor set
as the run, the run's true resistance drifted by a common factor of at most ``MAX_DRIFT`` (3 %: the same unit a few
weeks on), and its own seed for the driver and the noise ([BASE_SEED, crc32(family), k, SIBLING_SEED, j]). The
family's own runs, their seeds and their bags are not touched: ``family.simulate_spec`` is called with the run's
truth given (an additive hook; the family's draw is made all the same, so its bags stay byte-identical).

Each sibling is written like a family run (``NAME_sJ/`` bag and ``NAME_sJ.validation-truth.json``, ``runs.csv``)
to ``build/prediction/siblings/`` (gitignored); a sibling is regenerated only when its files are missing, and its
bytes depend on the seeds only.

    .venv/bin/python bench/prediction/siblings.py [--siblings 2] [--families NAME ...] [--jobs 2]
"""

from __future__ import annotations

import argparse
import csv
import importlib.util
import json
import shutil
import sys
import time
import zlib
from collections.abc import Sequence
from dataclasses import dataclass
from multiprocessing import Pool
from pathlib import Path
from types import ModuleType
from typing import Any

import numpy as np

from train_calib.train import Davis

REPO = Path(__file__).resolve().parents[2]
OUT = REPO / "build" / "prediction" / "siblings"
SIBLING_SEED = 24  # issue 24
MAX_DRIFT = 0.03  # the sibling's r(v) within +-3 % of the run's at every speed (one common factor)
SIBLINGS = 2  # per held-out run: a unit of three runs


def _family() -> ModuleType:
    """bench/validation/family.py as a module (the bench scripts are not a package); loaded once."""
    key = "validation_family"
    if key not in sys.modules:
        spec = importlib.util.spec_from_file_location(key, REPO / "bench" / "validation" / "family.py")
        assert spec is not None and spec.loader is not None
        module = importlib.util.module_from_spec(spec)
        sys.modules[key] = module
        spec.loader.exec_module(module)
    return sys.modules[key]


family = _family()


@dataclass(frozen=True)
class SiblingSpec(family.RunSpec):  # type: ignore[name-defined,misc]
    """Sibling ``j`` (1, 2, ...) of the family run (family, k): its name and seed; the rest is the run's."""

    j: int = 1

    @property
    def name(self) -> str:
        return f"{self.family.name}_{self.k:02d}_s{self.j}"

    @property
    def seed(self) -> list[int]:
        return [family.BASE_SEED, zlib.crc32(self.family.name.encode()), self.k, SIBLING_SEED, self.j]

    @property
    def parent(self) -> Any:
        """The family run this is a sibling of."""
        return family.RunSpec(self.family, self.k)


def run_truth(spec: Any) -> Davis:
    """The family run's true resistance, as drawn from its seed (the first draw of its generator)."""
    train = family.cached_train(family.resolve_train(spec.family.train))
    return family.true_resistance(train, np.random.default_rng(spec.seed))


def drift_factor(sib: SiblingSpec) -> float:
    """The sibling's common factor on the run's r: 1 + U(-MAX_DRIFT, MAX_DRIFT), from its own seed."""
    return 1.0 + float(np.random.default_rng([*sib.seed, 1]).uniform(-MAX_DRIFT, MAX_DRIFT))


def sibling_truth(sib: SiblingSpec) -> Davis:
    """The run's true r0, r1, r2 times the sibling's drift factor (N/kg, N/(kg m/s), N/(kg (m/s)^2))."""
    r, f = run_truth(sib.parent), drift_factor(sib)
    return Davis(r.r0 * f, r.r1 * f, r.r2 * f)


def sibling_specs(
    families: Sequence[str] | None = None, siblings: int = SIBLINGS, split: str = "report"
) -> list[SiblingSpec]:
    """The siblings of every run of ``split`` (the report half: the held-out runs) of the named families."""
    runs = [s for s in family.all_specs() if s.split == split and (not families or s.family.name in families)]
    return [SiblingSpec(s.family, s.k, j) for s in runs for j in range(1, siblings + 1)]


def simulate_sibling(sib: SiblingSpec) -> tuple[Any, Davis, Any, Any]:
    """(streams, truth, track, train) of the sibling: the family's generator with the sibling's truth and seed."""
    return family.simulate_spec(sib, truth=sibling_truth(sib))  # type: ignore[no-any-return]


def generate(sib: SiblingSpec, out: Path = OUT, force: bool = False) -> tuple[str, float]:
    """Write the sibling's bag and truth JSON unless both exist; (name, seconds spent)."""
    t0 = time.perf_counter()
    bag, truth_path = out / sib.name, out / (sib.name + family.TRUTH_SUFFIX)
    if bag.is_dir() and truth_path.is_file() and not force:
        return sib.name, 0.0
    if bag.is_dir():
        shutil.rmtree(bag)
    truth_path.unlink(missing_ok=True)
    out.mkdir(parents=True, exist_ok=True)
    streams, truth, _track, _train = simulate_sibling(sib)
    family.write_bag(streams, bag)
    doc = family.truth_document(sib, streams, truth)
    doc.update(sibling_of=sib.parent.name, sibling=sib.j, drift_factor=drift_factor(sib))
    truth_path.write_text(json.dumps(doc) + "\n", encoding="utf-8")
    return sib.name, time.perf_counter() - t0


def _generate_star(args: tuple[SiblingSpec, Path, bool]) -> tuple[str, float]:
    return generate(*args)


def write_csv(sibs: Sequence[SiblingSpec], out: Path = OUT) -> Path:
    """runs.csv of the siblings: the family's columns plus ``sibling_of`` (the run whose unit it is)."""
    path = out / "runs.csv"
    out.mkdir(parents=True, exist_ok=True)
    with open(path, "w", encoding="utf-8", newline="") as f:
        w = csv.DictWriter(f, fieldnames=[*family.CSV_COLUMNS, "sibling_of"])
        w.writeheader()
        for sib in sibs:
            w.writerow({**family.csv_row(sib), "sibling_of": sib.parent.name})
    return path


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", type=Path, default=OUT, help="directory (default %(default)s)")
    ap.add_argument("--families", nargs="*", help="only these families (default all)")
    ap.add_argument("--siblings", type=int, default=SIBLINGS, help="per held-out run (default %(default)s)")
    ap.add_argument("--force", action="store_true", help="regenerate existing siblings")
    ap.add_argument("--jobs", type=int, default=2, help="processes (default 2)")
    args = ap.parse_args(argv)
    sibs = sibling_specs(args.families, args.siblings)
    t0 = time.perf_counter()
    jobs = [(s, args.out, args.force) for s in sibs]
    if args.jobs > 1:
        with Pool(args.jobs) as pool:
            done = pool.map(_generate_star, jobs, chunksize=1)
    else:
        done = [_generate_star(j) for j in jobs]
    write_csv(sibs, args.out)
    made = sum(dt > 0 for _, dt in done)
    print(f"siblings: {len(sibs)} runs in {args.out} ({made} generated, {time.perf_counter() - t0:.1f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
