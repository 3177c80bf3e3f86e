"""Which parameters matter: one-at-a-time sensitivity of the running time, and local identifiability.

Besinovic et al. vary one parameter at a time and drop from the calibration those that change the
running time by less than 0.1 % (r1; c1 nearly so). :func:`one_at_a_time` reproduces that: each
parameter is moved by +-``rel_step`` of its value (c1, whose default is 0, up by ``rel_step`` times
c0^2 / c2, i.e. the effort at the transition speed raised by ``rel_step`` c0) and the stop-to-stop
running time and the passage times are compared with the base.

:func:`identifiability` goes further: the Jacobian of the observed passage times with respect to
the decision vector (central differences, with each leg's constant removed since the departure time
is free) gives, for passage-time noise sigma (the one-second rounding: 1/sqrt(12) s), the standard
error of each parameter and their correlations, (J'J)^-1 sigma^2. A parameter whose standard error
is large against its bounds, or that is nearly collinear with another, is not identifiable from
occupation data.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from .compositions import DECISION_NAMES
from .objective import Observations, ProfileModel

SENSITIVITY_NAMES: tuple[str, ...] = ("c0", "c1", "c2", "r0", "r1", "r2", "b_limit", "theta_cruise")
ROUNDING_SIGMA_S = 1.0 / math.sqrt(12.0)
"""Standard deviation of a time rounded down to the second (uniform error over one second), s."""


@dataclass
class Sensitivity:
    """Effect of moving one parameter by +-step on the running time and the passage times."""

    name: str
    base: float
    low: float
    high: float
    running_time_s: float  # base stop-to-stop running time, all legs, s
    change_low_pct: float  # running time change with the low value, %
    change_high_pct: float  # running time change with the high value, %
    max_passage_change_s: float  # largest change of any passage time (either side), s

    @property
    def max_change_pct(self) -> float:
        return max(abs(self.change_low_pct), abs(self.change_high_pct))


def _passages(model: ProfileModel, params: Mapping[str, float], legs, positions) -> tuple[float, np.ndarray]:
    total, times = 0.0, []
    for (start, stop), pos in zip(legs, positions):
        prof = model(params, start, stop)
        total += float(np.asarray(prof.time_at(np.array([stop])))[0])
        times.append(np.asarray(prof.time_at(pos), dtype=float))
    return total, np.concatenate(times) if times else np.zeros(0)


def one_at_a_time(
    model: ProfileModel,
    params: Mapping[str, float],
    legs: Sequence[tuple[float, float]],
    positions: Sequence[np.ndarray],
    *,
    rel_step: float = 0.2,
    names: Sequence[str] = SENSITIVITY_NAMES,
) -> list[Sensitivity]:
    """Running-time sensitivity to each parameter (see the module docstring).

    ``legs``: (start_m, stop_m) between stops; ``positions``: passage positions per leg (m).
    """
    base_total, base_times = _passages(model, params, legs, positions)
    out = []
    for name in names:
        value = float(params[name])
        step = rel_step * (params["c0"] ** 2 / params["c2"] if name == "c1" and value == 0.0 else abs(value))
        # c1 = 0 is moved upwards only (+20 % effort at the transition speed), as in docs/occupation.md;
        # c1 < 0 is valid too (the envelope switches to c2 / v at the transition speed, eq. 4)
        low = value if name == "c1" and value == 0.0 else value - step
        changes, worst = [], 0.0
        for v in (low, value + step):
            p = dict(params)
            p[name] = v
            total, times = _passages(model, p, legs, positions)
            changes.append(100.0 * (total - base_total) / base_total)
            worst = max(worst, float(np.nanmax(np.abs(times - base_times))) if times.size else 0.0)
        out.append(Sensitivity(name, value, low, value + step, base_total, changes[0], changes[1], worst))
    return out


@dataclass
class Identifiability:
    """Local standard errors and correlations of the decision vector from the passage times."""

    names: tuple[str, ...]
    values: np.ndarray
    std_error: np.ndarray  # same units as the parameters
    correlation: np.ndarray  # len(names) x len(names)
    singular_values: np.ndarray  # of the column-scaled Jacobian (s per unit relative change)
    sigma_s: float
    n_observations: int

    def relative_error(self) -> np.ndarray:
        """Standard error over |value|."""
        return self.std_error / np.abs(self.values)

    def strongest_correlations(self, k: int = 3) -> list[tuple[str, str, float]]:
        n = len(self.names)
        pairs = [
            (self.names[i], self.names[j], float(self.correlation[i, j])) for i in range(n) for j in range(i + 1, n)
        ]
        return sorted(pairs, key=lambda p: -abs(p[2]))[:k]


def identifiability(
    obs: Observations,
    model: ProfileModel,
    params: Mapping[str, float],
    *,
    names: Sequence[str] = DECISION_NAMES,
    rel_step: float = 1e-3,
    sigma_s: float = ROUNDING_SIGMA_S,
) -> Identifiability:
    """Gauss-Newton covariance of the parameters at ``params`` for the passages of ``obs``."""
    values = np.array([float(params[n]) for n in names])
    cols = []
    for k, name in enumerate(names):
        h = rel_step * abs(values[k]) if values[k] != 0 else rel_step
        sides = []
        for v in (values[k] - h, values[k] + h):
            p = dict(params)
            p[name] = v
            sides.append(_leg_centred_times(obs, model, p))
        cols.append((sides[1] - sides[0]) / (2.0 * h))
    jac = np.column_stack(cols)  # s per unit of each parameter
    scaled = jac * values  # s per relative change
    # (J'J)^-1 through the SVD without truncation: a direction the data do not see gets a huge
    # variance (not a pseudo-inverse's zero), and the correlations stay consistent
    _, sv, vt = np.linalg.svd(scaled, full_matrices=False)
    with np.errstate(divide="ignore", over="ignore"):
        inv_s2 = 1.0 / np.maximum(sv, 1e-300) ** 2
    cov_rel = (vt.T * inv_s2) @ vt * sigma_s**2
    std_rel = np.sqrt(np.clip(np.diag(cov_rel), 0.0, None))
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        corr = np.clip(cov_rel / np.outer(std_rel, std_rel), -1.0, 1.0)
    return Identifiability(tuple(names), values, std_rel * np.abs(values), corr, sv, sigma_s, len(obs))


def _leg_centred_times(obs: Observations, model: ProfileModel, params: Mapping[str, float]) -> np.ndarray:
    """Simulated passage times with each leg's mean removed (the departure time is free)."""
    out = np.empty(len(obs))
    for k, (start, stop) in enumerate(obs.legs):
        mask = obs.leg == k
        t = np.asarray(model(params, start, stop).time_at(obs.position_m[mask]), dtype=float)
        out[mask] = t - np.mean(t)
    return out
