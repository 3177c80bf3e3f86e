"""Covariance bookkeeping of the 5-state filter: packed symmetric storage, Cholesky, repair, projection.

P is kept as its 15 upper-triangle entries (row-major: 00 01 02 03 04 11 12 13 14 22 23 24 33 34 44), so
it is symmetric by construction; the lower Cholesky factor is packed column-major
(l00 l10 l20 l30 l40 l11 l21 l31 l41 l22 l32 l42 l33 l43 l44).
"""

from __future__ import annotations

import math

import numpy as np

UPPER_INDEX = np.array([[0, 1, 2, 3, 4], [1, 5, 6, 7, 8], [2, 6, 9, 10, 11], [3, 7, 10, 12, 13], [4, 8, 11, 13, 14]])
"""Packed index of entry (i, j) of the symmetric 5x5 matrix."""
_IU = np.triu_indices(5)


def unpack(packed) -> np.ndarray:
    """(..., 15) packed upper triangle -> (..., 5, 5) symmetric matrix."""
    a = np.asarray(packed, dtype=float)
    return a[UPPER_INDEX] if a.ndim == 1 else a[..., UPPER_INDEX]  # one matrix (per sample): no Ellipsis, 2x faster


def pack(matrix: np.ndarray) -> tuple[float, ...]:
    """5x5 matrix -> packed upper triangle (the upper triangle is taken as is)."""
    return tuple(float(x) for x in np.asarray(matrix, dtype=float)[_IU])


def cholesky(p: tuple[float, ...]) -> tuple[float, ...] | None:
    """Lower Cholesky factor of the packed matrix, or None when it is not (numerically) positive definite."""
    p00, p01, p02, p03, p04, p11, p12, p13, p14, p22, p23, p24, p33, p34, p44 = p
    try:
        if not p00 > 0.0:
            return None
        l00 = math.sqrt(p00)
        l10 = p01 / l00
        l20 = p02 / l00
        l30 = p03 / l00
        l40 = p04 / l00
        d = p11 - l10 * l10
        if not d > 0.0:
            return None
        l11 = math.sqrt(d)
        l21 = (p12 - l20 * l10) / l11
        l31 = (p13 - l30 * l10) / l11
        l41 = (p14 - l40 * l10) / l11
        d = p22 - l20 * l20 - l21 * l21
        if not d > 0.0:
            return None
        l22 = math.sqrt(d)
        l32 = (p23 - l30 * l20 - l31 * l21) / l22
        l42 = (p24 - l40 * l20 - l41 * l21) / l22
        d = p33 - l30 * l30 - l31 * l31 - l32 * l32
        if not d > 0.0:
            return None
        l33 = math.sqrt(d)
        l43 = (p34 - l40 * l30 - l41 * l31 - l42 * l32) / l33
        d = p44 - l40 * l40 - l41 * l41 - l42 * l42 - l43 * l43
        if not d > 0.0:
            return None
        l44 = math.sqrt(d)
    except (OverflowError, ValueError, ZeroDivisionError):
        return None
    out = (l00, l10, l20, l30, l40, l11, l21, l31, l41, l22, l32, l42, l33, l43, l44)
    return out if math.isfinite(sum(out)) else None


def repair(p: tuple[float, ...], min_eigenvalue: float) -> tuple[float, ...] | None:
    """Nearest positive-definite matrix by eigenvalue flooring of the correlation matrix.

    The scaled matrix C = D^-1 P D^-1 (D = sqrt(diag P)) has its eigenvalues floored at
    ``min_eigenvalue`` and is scaled back, so the variances keep their size whatever their units.
    Returns None when the diagonal is not positive and finite (nothing to repair: reset instead).
    """
    m = unpack(p)
    diag = np.diag(m).copy()
    if not (np.all(np.isfinite(m)) and np.all(diag > 0.0)):
        return None
    d = np.sqrt(diag)
    corr = m / np.outer(d, d)
    corr = 0.5 * (corr + corr.T)
    w, vec = np.linalg.eigh(corr)
    w = np.maximum(w, min_eigenvalue)
    fixed = (vec * w) @ vec.T
    # keep unit diagonal of the correlation (variances unchanged)
    s = np.sqrt(np.diag(fixed))
    fixed = fixed / np.outer(s, s)
    fixed = fixed * np.outer(d, d)
    return pack(fixed)


def project_nonnegative(
    x: list[float], p: tuple[float, ...], indices: tuple[int, ...], rule: str, clip_only: tuple[int, ...] = ()
) -> bool:
    """Make x[i] >= 0 for i in ``indices`` in place; True when something was changed.

    ``project``: the covariance-weighted projection of the mean onto the active bounds
    (Simon & Chia 2002, estimate projection: x <- x - P_:A P_AA^-1 x_A for the active set A), repeated
    while new bounds become active, then a final clip; ``clip``: x_i <- max(x_i, 0). P is left unchanged.
    Indices in ``clip_only`` are always clipped, never projected: their bound moves no other state (the
    speed at a standstill: its noise around 0 would otherwise leak into r through the correlations).
    """
    if all(x[i] >= 0.0 for i in indices):
        return False
    for i in clip_only:
        if x[i] < 0.0:
            x[i] = 0.0
    indices = tuple(i for i in indices if i not in clip_only)
    if rule == "project":
        m = unpack(p)
        xv = np.array(x, dtype=float)
        active: list[int] = []
        for _ in range(len(indices)):
            new = [i for i in indices if xv[i] < 0.0 and i not in active]
            if not new:
                break
            active.extend(new)
            a = np.array(active)
            paa = m[np.ix_(a, a)]
            try:
                corr = np.linalg.solve(paa, xv[a])
            except np.linalg.LinAlgError:
                break
            xv = xv - m[:, a] @ corr
            xv[a] = 0.0
        for i in range(5):
            x[i] = float(xv[i])
    for i in indices:
        if x[i] < 0.0:
            x[i] = 0.0
    return True
