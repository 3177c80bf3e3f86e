"""Robustness of the calibration (Besinovic Table 3): repeated calibrations of one run.

The same observed run is calibrated ``n`` times with different seeds; the mean, standard deviation
and coefficient of variation (std / mean, %) of each calibrated parameter, of the objective and of
the simulated running time show whether the optimiser returns the same answer every time (the
paper: 30 repeats, c2, b_limit and theta identical, r0 4.2 %, r2 2.8 %, objective 0.4 %).
"""

from __future__ import annotations

from collections.abc import Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass

import numpy as np

from .calibrate import CalibrationConfig, CalibrationResult, calibrate_run
from .compositions import DECISION_NAMES, Composition
from .objective import Observations, ProfileModel

ROWS: tuple[str, ...] = (*DECISION_NAMES, "objective_s", "running_time_s")


@dataclass
class RobustnessRow:
    name: str
    default: float
    mean: float
    std: float

    @property
    def cv_pct(self) -> float:
        return 100.0 * self.std / abs(self.mean) if self.mean else float("nan")


@dataclass
class Robustness:
    run_id: str
    seeds: list[int]
    results: list[CalibrationResult]
    rows: list[RobustnessRow]

    def row(self, name: str) -> RobustnessRow:
        return next(r for r in self.rows if r.name == name)

    def as_markdown(self) -> str:
        lines = [
            f"Robustness: {len(self.results)} calibrations of run {self.run_id} "
            f"(seeds {self.seeds[0]}..{self.seeds[-1]})",
            "",
            "| parameter | default | mean | std | std % |",
            "|---|---:|---:|---:|---:|",
        ]
        for r in self.rows:
            lines.append(f"| {r.name} | {r.default:.4g} | {r.mean:.4g} | {r.std:.3g} | {r.cv_pct:.2f} |")
        return "\n".join(lines)


def _one(args) -> CalibrationResult:
    obs, model, composition, config, seed = args
    return calibrate_run(obs, model, composition, config, seed=seed)


def repeated_calibrations(
    obs: Observations,
    model: ProfileModel,
    composition: Composition,
    config: CalibrationConfig | None = None,
    *,
    n: int = 30,
    first_seed: int = 0,
    workers: int = 1,
    seeds: Sequence[int] | None = None,
) -> Robustness:
    """``n`` calibrations of the same run with seeds first_seed, first_seed + 1, ...; in parallel with ``workers``."""
    seeds = list(seeds) if seeds is not None else list(range(first_seed, first_seed + n))
    jobs = [(obs, model, composition, config, s) for s in seeds]
    if workers > 1:
        with ProcessPoolExecutor(max_workers=workers) as pool:
            results = list(pool.map(_one, jobs))
    else:
        results = [_one(j) for j in jobs]
    defaults = composition.model_params()
    default_eval = results[0].default_objective_s
    rows = []
    for name in ROWS:
        if name == "objective_s":
            vals, default = [r.objective_s for r in results], default_eval
        elif name == "running_time_s":
            vals, default = [r.running_time_s for r in results], float("nan")
        else:
            vals, default = [r.params[name] for r in results], defaults[name]
        rows.append(
            RobustnessRow(name, default, float(np.mean(vals)), float(np.std(vals, ddof=1)) if len(vals) > 1 else 0.0)
        )
    return Robustness(obs.run_id, seeds, results, rows)
