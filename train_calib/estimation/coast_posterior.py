"""The coast regression's Bayesian step (step 6, :mod:`coast_regression`): the prior N(train file, P0) in
information form, each coast's equations added with their common error, the posterior and its projection onto
r >= 0.
"""

from __future__ import annotations

import math

import numpy as np

from ..train import Davis
from .coast_types import Stretch

_SHAPE_SPEED = 20.0  # m/s: speed at which a zero coefficient's floor std is set


def prior_covariance(davis: Davis | tuple[float, float, float], scale_std: float, coefficient_std: float) -> np.ndarray:
    """P0 (3x3, units of r0, r1, r2) = scale_std^2 r r^T + diag(max(coefficient_std |r_j|, floor_j)^2); the floor
    (5 % of r at 20 m/s in each term) keeps a zero coefficient from being certain."""
    r = np.asarray(davis.as_tuple() if isinstance(davis, Davis) else davis, dtype=float)
    vc = _SHAPE_SPEED
    r_c = r[0] + r[1] * vc + r[2] * vc * vc
    floor = 0.05 * abs(r_c) / vc ** np.arange(3)
    return scale_std**2 * np.outer(r, r) + np.diag(np.maximum(coefficient_std * np.abs(r), floor) ** 2)


def resistance_and_sigma(r: np.ndarray, covariance: np.ndarray, v: float) -> tuple[float, float]:
    """(r(v), its std) in N/kg at speed v (m/s), the std through h = (1, v, v^2) of the 3x3 covariance."""
    h = np.array([1.0, v, v * v])
    return float(h @ r), float(math.sqrt(max(float(h @ covariance @ h), 0.0)))


def prior_information(prior: np.ndarray, P0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(P0^-1, P0^-1 prior): the prior in information form."""
    info_matrix = np.linalg.inv(P0)
    return info_matrix, info_matrix @ prior


def add_coast(info: tuple[np.ndarray, np.ndarray], members: list[Stretch]) -> tuple[np.ndarray, np.ndarray]:
    """The information plus that of one coast (its stretches share the common error): noise covariance
    noise_var I + bias^2 tau tau^T, inverted by Sherman-Morrison."""
    info_matrix, info_vector = info
    A = np.vstack([st.A for st in members])
    y = np.concatenate([st.y for st in members])
    tau = np.concatenate([st.tau for st in members])
    noise_var = max(st.noise_var for st in members)
    bias = max(st.bias_std for st in members)
    gain = bias * bias / (noise_var + bias * bias * float(tau @ tau))
    a_tau = A.T @ tau
    info_matrix = info_matrix + (A.T @ A - gain * np.outer(a_tau, a_tau)) / noise_var
    info_vector = info_vector + (A.T @ y - gain * a_tau * float(tau @ y)) / noise_var
    return info_matrix, info_vector


def coasts_of(stretches: list[Stretch]) -> list[list[Stretch]]:
    """The stretches grouped by coast, in order."""
    groups: dict[int, list[Stretch]] = {}
    for st in stretches:
        groups.setdefault(st.group, []).append(st)
    return list(groups.values())


def solve_information(info: tuple[np.ndarray, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """(mean, covariance) from the information form."""
    cov = np.linalg.inv(info[0])
    cov = 0.5 * (cov + cov.T)
    return cov @ info[1], cov


def posterior(prior: np.ndarray, P0: np.ndarray, stretches: list[Stretch]) -> tuple[np.ndarray, np.ndarray]:
    """Gaussian posterior of r given the prior and the stretches' equations (information form); the prior itself
    (copies) without stretches."""
    if not stretches:
        return prior.copy(), P0.copy()
    info = prior_information(prior, P0)
    for members in coasts_of(stretches):
        info = add_coast(info, members)
    return solve_information(info)


def nonnegative(r: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """Covariance-weighted projection of r onto r >= 0 (Simon & Chia), then a clip."""
    r = r.copy()
    for _ in range(3):
        active = np.flatnonzero(r < 0.0)
        if active.size == 0:
            break
        paa = cov[np.ix_(active, active)]
        r = r - cov[:, active] @ np.linalg.solve(paa, r[active])
    return np.maximum(r, 0.0)
