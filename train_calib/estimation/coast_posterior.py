"""The coast regression's Bayesian step (step 6, :mod:`coast_regression`): the prior N(train file, P0) in
information form, each coast's equations added with their common error (in the energy form, over the
configurations of its stretches' uncertain ends: :func:`add_coast_with_ends`), the posterior and its projection
onto r >= 0.
"""

from __future__ import annotations

import math
from typing import NamedTuple

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


MAX_END_CONFIGURATIONS = 729
"""A coast whose stretches have more configurations of their ends together (9 a stretch) takes its detected ends
as sure."""


def _uses_end_mixture(members: list[Stretch]) -> bool:
    """The coast's stretches carry their ends (the energy form) and have at most MAX_END_CONFIGURATIONS together."""
    return (
        all(st.ends is not None for st in members)
        and math.prod(st.ends.masks.shape[0] for st in members) <= MAX_END_CONFIGURATIONS
    )


def add_coast(info: tuple[np.ndarray, np.ndarray], members: list[Stretch]) -> tuple[np.ndarray, np.ndarray]:
    """The information plus that of one coast (its stretches share the common error): noise covariance
    noise_var I + bias^2 tau tau^T, inverted by Sherman-Morrison. A coast whose stretches carry their ends
    (``Stretch.ends``, the energy form) goes to :func:`add_coast_with_ends`."""
    if _uses_end_mixture(members):
        return add_coast_with_ends(info, members)
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


def _end_configurations(members: list[Stretch]) -> np.ndarray:
    """(configurations, n) bool: every combination of the members' configurations, rows concatenated in order."""
    masks = members[0].ends.masks
    for st in members[1:]:
        other = st.ends.masks
        masks = np.hstack((np.repeat(masks, other.shape[0], axis=0), np.tile(other, (masks.shape[0], 1))))
    return masks


class _EndTerms(NamedTuple):
    """The terms of one coast's configurations of ends (:func:`_end_terms`); c configurations, n samples."""

    e: np.ndarray  # (n,) J/kg: the innovation E - H m
    HP: np.ndarray  # (n, 3): H P
    Q: np.ndarray  # (c, n, n): the restricted precision of the innovation (E0 integrated out)
    weights: np.ndarray  # (c,): the configurations' posterior weights, summing to 1
    dof: int  # n less one E0 per stretch


def _end_terms(m: np.ndarray, P: np.ndarray, members: list[Stretch]) -> _EndTerms:
    """Per configuration of the members' ends, given the current N(m, P) of r: see :func:`add_coast_with_ends`."""
    ends = [st.ends for st in members]
    E = np.concatenate([x.E for x in ends])
    H = np.vstack([x.H for x in ends])
    var = np.concatenate([x.var for x in ends])
    effort_var = np.concatenate([x.effort_var for x in ends])
    d = np.concatenate([x.distance for x in ends])
    U = np.zeros((E.size, len(ends)))
    row = 0
    for j, x in enumerate(ends):
        U[row : row + x.E.size, j] = 1.0
        row += x.E.size
    bias = max(st.bias_std for st in members)
    e = E - H @ m
    HP = H @ P
    shared = HP @ H.T + bias * bias * np.outer(d, d)
    coasting = _end_configurations(members)  # (c, n)
    K = shared + np.einsum("ci,ij->cij", var + np.where(coasting, 0.0, effort_var), np.eye(E.size))
    K_inv = np.linalg.inv(K)
    KU = K_inv @ U
    UKU = U.T @ KU  # (c, stretches, stretches)
    Q = K_inv - KU @ np.linalg.solve(UKU, np.swapaxes(KU, 1, 2))
    log_w = -0.5 * (np.linalg.slogdet(K)[1] + np.linalg.slogdet(UKU)[1] + np.einsum("i,cij,j->c", e, Q, e))
    w = np.exp(log_w - log_w.max())
    w /= w.sum()
    return _EndTerms(e, HP, Q, w, E.size - len(ends))


def add_coast_with_ends(info: tuple[np.ndarray, np.ndarray], members: list[Stretch]) -> tuple[np.ndarray, np.ndarray]:
    """The information after one coast in the energy form whose stretch ends are uncertain (``Stretch.ends``,
    docs/estimator.md "Coasts at 10 s sampling"): assumed-density filtering over the configurations of its ends.

    For each configuration c (which samples coast), with the current N(m, P) of r, E = U E0 + H r + n, E0 one flat
    nuisance per stretch (U its indicator columns), n ~ N(0, C_c), C_c = diag(var + effort_var where not coasting)
    + bias^2 d d^T (the coast's common error along the distance d): K = C_c + H P H^T, the restricted likelihood
    (E0 integrated out) Q = K^-1 - K^-1 U (U^T K^-1 U)^-1 U^T K^-1, the log evidence
    -1/2 (log|K| + log|U^T K^-1 U| + e^T Q e) with e = E - H m, and the update m_c = m + P H^T Q e,
    P_c = P - P H^T Q H P. The configurations (equally likely a priori) are weighted by their evidence and
    moment-matched to one Gaussian: mean sum w_c m_c, covariance sum w_c (P_c + (m_c - mean)(m_c - mean)^T)."""
    m, P = solve_information(info)
    t = _end_terms(m, P, members)
    gain = t.HP.T @ t.Q  # (c, 3, n)
    means = m + gain @ t.e
    covs = P - gain @ t.HP
    mean = t.weights @ means
    spread = means - mean
    cov = np.einsum("c,cij->ij", t.weights, covs) + np.einsum("c,ci,cj->ij", t.weights, spread, spread)
    info_matrix = np.linalg.inv(0.5 * (cov + cov.T))
    return info_matrix, info_matrix @ mean


def coast_consistency(info: tuple[np.ndarray, np.ndarray], members: list[Stretch]) -> tuple[float, int] | None:
    """(NIS, degrees of freedom) of one coast in the energy form with its ends uncertain, before it is added to
    ``info``: the restricted normalised innovation e^T Q e averaged over the configurations by their weights, and
    the samples less one E0 per stretch; None for a coast that :func:`add_coast` takes with its ends sure. Under the
    stated noise NIS/dof is about 1 (docs/estimator.md, Validation: measured 0.5 on the eco family;
    bench/validation/coast_consistency.py)."""
    if not _uses_end_mixture(members):
        return None
    m, P = solve_information(info)
    t = _end_terms(m, P, members)
    return float(t.weights @ np.einsum("i,cij,j->c", t.e, t.Q, t.e)), t.dof


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
