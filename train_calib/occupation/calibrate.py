"""Calibration of one run: differential evolution over beta = (c0, c2, r0, r2, b_limit, theta_cruise).

Besinovic et al. use a hand-tuned genetic algorithm in MATLAB; we use scipy's differential evolution
(a well-kept evolutionary optimiser: seeded, bounded). The objective (eq. 8, :mod:`.objective`) is a
sum of absolute values of piecewise-smooth passage times, so gradient polishing (L-BFGS-B) gains
nothing and is off. c1 and r1 are fixed (c1 = 0, r1 = the composition default), as the paper's
sensitivity analysis justifies (reproduced by :mod:`.sensitivity`).

Speed: with a model that has ``batch`` (:class:`.model.SimulatorModel`) and ``workers=1`` the
whole population of a generation is simulated in one call (``vectorized=True``,
``updating='deferred'``: each generation's trials are built from the previous generation); this is
what makes a calibration take well under a second. ``workers`` > 1 instead evaluates the members
one by one in parallel processes (also deferred). Runs of a fleet are calibrated in parallel
processes, each vectorised (:mod:`.pipeline`).
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import differential_evolution

from ..params import ParamSet, param
from .compositions import DECISION_NAMES, Composition
from .objective import Evaluation, Observations, ProfileModel, evaluate, objective, objective_batch


@dataclass(frozen=True)
class CalibrationConfig(ParamSet):
    """Settings of the per-run calibration (differential evolution, scipy.optimize)."""

    popsize: int = param(8, "population size per decision variable (population = popsize x 6)", low=2)
    maxiter: int = param(60, "largest number of generations", low=1)
    tol: float = param(0.0, "relative convergence tolerance on the population's objective spread", low=0.0)
    atol: float = param(
        0.5,
        "absolute convergence tolerance: stop when the objective's std in the population is below it",
        unit="s",
        low=0.0,
    )
    mutation_low: float = param(0.5, "lower end of the dithered mutation factor", low=0.0, high=2.0)
    mutation_high: float = param(1.0, "upper end of the dithered mutation factor", low=0.0, high=2.0)
    recombination: float = param(0.7, "crossover probability", low=0.0, high=1.0)
    strategy: str = param("best1bin", "DE strategy", choices=("best1bin", "rand1bin", "currenttobest1bin"))
    init: str = param("latinhypercube", "initial population", choices=("sobol", "latinhypercube", "halton", "random"))
    stall_generations: int = param(
        0, "stop when the best objective improved by less than stall_tol over this many generations (0: off)", low=0
    )
    stall_tol: float = param(0.05, "improvement of the best objective that counts as progress", unit="s", low=0.0)
    polish: bool = param(False, "polish the best member with L-BFGS-B (no gain on this non-smooth objective)")
    use_releases: bool = param(False, "add release passages (tail at section end) to the occupations")
    release_offset_s: float = param(0.0, "known systematic release delay subtracted from release times", unit="s")

    def validate(self, source: str = "parameters", prefix: str = "") -> None:
        from ..errors import ConfigError

        if self.mutation_high < self.mutation_low:
            raise ConfigError(source, f"{prefix}mutation_high", "must be at least mutation_low")


@dataclass
class CalibrationResult:
    """The calibrated parameters of one run and how well they reproduce it."""

    run_id: str
    composition: str
    params: dict[str, float]  # every model parameter (calibrated and fixed) and length_m
    objective_s: float  # eq. 8 at the optimum, s
    default_objective_s: float  # eq. 8 with the composition defaults, s
    n_observations: int
    n_legs: int
    nfev: int  # parameter vectors the optimiser evaluated (model runs per leg)
    nit: int
    elapsed_s: float
    success: bool
    message: str
    seed: int | None
    evaluation: Evaluation | None = field(default=None, repr=False)

    @property
    def decision(self) -> dict[str, float]:
        return {k: self.params[k] for k in DECISION_NAMES}

    @property
    def mean_abs_residual_s(self) -> float:
        return self.objective_s / self.n_observations if self.n_observations else float("nan")

    @property
    def running_time_s(self) -> float:
        """Simulated stop-to-stop running time, all legs, s."""
        return float(np.sum(self.evaluation.running_time_s)) if self.evaluation is not None else float("nan")


PENALTY_S = 1.0e6
"""Objective of a parameter vector the model cannot run (the train cannot start or stalls), s."""


class _Objective:
    """Picklable objective over the decision vector (for DE workers); a failed run costs PENALTY_S."""

    def __init__(self, obs: Observations, model: ProfileModel, fixed: Mapping[str, float]) -> None:
        self.obs = obs
        self.model = model
        self.fixed = dict(fixed)
        self.runs = 0  # parameter vectors evaluated (in this process)

    def params(self, x: np.ndarray) -> dict[str, float]:
        p = dict(self.fixed)
        p.update(zip(DECISION_NAMES, (float(v) for v in x)))
        return p

    def __call__(self, x: np.ndarray) -> float:
        self.runs += 1
        value = objective(self.obs, self.model, self.params(x))
        return value if np.isfinite(value) else PENALTY_S


class _BatchObjective(_Objective):
    """The objective of a whole population: x of shape (6, S) -> (S,) (differential_evolution(vectorized=True))."""

    def population_params(self, x: np.ndarray) -> dict:
        """The parameter mapping of a population: each decision parameter an array of shape (S,)."""
        p: dict = dict(self.fixed)
        p.update(zip(DECISION_NAMES, np.asarray(x, dtype=float)))
        return p

    def __call__(self, x: np.ndarray):
        x = np.asarray(x, dtype=float)
        self.runs += x.size // len(DECISION_NAMES)
        values = objective_batch(self.obs, self.model, self.population_params(x.reshape(len(DECISION_NAMES), -1)))
        values = np.where(np.isfinite(values), values, PENALTY_S)
        return values if x.ndim == 2 else float(values[0])


class _Member:
    """A batch-capable model seen as a scalar ProfileModel (one member): for the final evaluation."""

    def __init__(self, model) -> None:
        self.model = model

    def __call__(self, params, start_m: float, stop_m: float):
        return self.model.batch(params, start_m, stop_m).member(0)


def calibrate_run(
    obs: Observations,
    model: ProfileModel,
    composition: Composition,
    config: CalibrationConfig | None = None,
    *,
    seed: int | None = None,
    workers: int = 1,
    fixed_overrides: Mapping[str, float] | None = None,
) -> CalibrationResult:
    """Minimise eq. 8 for one run within the composition's bounds.

    ``fixed_overrides``: values for the non-calibrated parameters (c1, r1, b_stop) other than the
    composition defaults. With ``workers`` = 1 and a model that has ``batch`` each generation is one
    vectorised model call; ``workers`` > 1 evaluates the members in parallel processes instead.
    """
    cfg = config or CalibrationConfig()
    fixed = composition.model_params(**(fixed_overrides or {}))
    vectorized = workers == 1 and callable(getattr(model, "batch", None))
    fun = (_BatchObjective if vectorized else _Objective)(obs, model, fixed)
    bounds = [composition.bounds[name] for name in DECISION_NAMES]
    t0 = time.perf_counter()
    default_obj = fun(np.array([fixed[n] for n in DECISION_NAMES]))
    runs0 = fun.runs
    history: list[float] = []

    def stalled(intermediate_result) -> bool:
        """DE callback: True stops the search once the best objective has stalled."""
        history.append(float(intermediate_result.fun))
        k = cfg.stall_generations
        return k > 0 and len(history) > k and history[-1 - k] - history[-1] < cfg.stall_tol

    res = differential_evolution(
        fun,
        bounds,
        strategy=cfg.strategy,
        maxiter=cfg.maxiter,
        popsize=cfg.popsize,
        tol=cfg.tol,
        atol=cfg.atol,
        mutation=(cfg.mutation_low, cfg.mutation_high),
        recombination=cfg.recombination,
        seed=seed,
        polish=cfg.polish,
        init=cfg.init,
        workers=workers,
        updating="deferred" if workers != 1 or vectorized else "immediate",
        vectorized=vectorized,
        callback=stalled,
    )
    elapsed = time.perf_counter() - t0
    best = fun.params(res.x)
    ev = evaluate(obs, _Member(model) if vectorized else model, best)
    return CalibrationResult(
        run_id=obs.run_id,
        composition=composition.name,
        params=best,
        objective_s=float(res.fun),
        default_objective_s=float(default_obj),
        n_observations=len(obs),
        n_legs=len(obs.legs),
        nfev=int(fun.runs - runs0) if vectorized else int(res.nfev),
        nit=int(res.nit),
        elapsed_s=elapsed,
        success=bool(res.success),
        message=str(res.message),
        seed=seed,
        evaluation=ev,
    )
