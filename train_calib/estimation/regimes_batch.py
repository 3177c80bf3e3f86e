"""The HMM regime filter of :mod:`.regimes` over a whole run at once (``classify_regimes``, offline).

The same model, the same sample rules and the same operations as ``RegimeClassifier.classify`` called
per sample in time order, arranged for numpy: the opposing force w (given, computed or carried over),
the observed acceleration y and the four log densities for every filtered sample in array operations;
only the forward recursion -- four multiplications and a normalisation per sample -- stays a loop, on
plain floats. numpy's and scipy's exp/log/erf may differ from the math module's in the last bit, so the
probabilities agree to round-off and a label can differ only on an exact tie (test/estimation/test_regimes.py
checks the labels on the bundled runs).

``smooth=True`` (offline only) labels each sample with the regime most probable given the *whole* run
instead: the same forward pass, then the backward recursion of the forward-backward algorithm within each
moving sequence (a standstill ends one), and the most probable regime of each sample's posterior marginal
(which maximises the expected number of right labels). No longer causal: a sample's label depends on later
samples, so it is never what the graph publishes.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np
from scipy.special import erf, erfc

from ..regime_codes import UNKNOWN
from .regime_model import DEFAULT_W, LOG_SQRT_2PI, SQRT2, START_PRIOR, backward_message, most_probable, rule

if TYPE_CHECKING:  # annotations only: regimes imports this module
    from .regimes import RegimeClassifier


def classify_hmm(
    e: np.ndarray,
    a: np.ndarray,
    clf: RegimeClassifier,
    speed: np.ndarray | None,
    known: np.ndarray | None,
    w_given: np.ndarray | None,
    smooth: bool = False,
) -> np.ndarray:
    """Regimes (uint8) of 1-d float arrays effort e (N/kg), acceleration a (m/s^2), speed (m/s) or None,
    known (bool) or None, w_given = resistance + track force (N/kg) or None; clf supplies the constants.
    ``smooth``: posterior given the whole run (forward-backward) instead of the causal filter."""
    with np.errstate(all="ignore"):  # extreme inputs overflow to inf as the math module's floats do
        return _classify(e, a, clf, speed, known, w_given, smooth)


def _classify(e, a, clf, speed, known, w_given, smooth=False) -> np.ndarray:
    n = len(e)
    out = np.full(n, UNKNOWN, dtype=np.uint8)
    usable = ~(np.isnan(e) | np.isnan(a))  # NaN effort or acceleration: UNKNOWN, the filter left as it is
    reset = np.zeros(n, dtype=bool)
    if speed is not None:
        moving = speed >= clf._v  # NaN too: not moving
        reset = usable & ~moving  # a standstill restarts the filter
        usable &= moving
    finite = np.isfinite(e) & np.isfinite(a)
    for i in np.flatnonzero(usable & ~finite):  # infinite values: the rule, the filter left as it is
        out[i] = rule(float(e[i]), float(a[i]), clf.config)
    index = np.flatnonzero(usable & finite)
    if not len(index):
        return out
    ef, af = e[index], a[index]
    v = speed[index] if speed is not None else np.full(len(index), math.nan)
    zero_known = ef == 0.0
    if known is not None:
        kf = known[index]
        zero_known &= kf  # an exact 0 known to be one (RegimeClassifier: known is not False)
        computed = ~zero_known & ~kf
    else:
        kf = None
        computed = ~zero_known
    # w: given where finite, else computed (e - a), else the last computed value scaled with speed
    diff = ef - af
    last = np.maximum.accumulate(np.where(computed, np.arange(len(index)), -1))
    seen = last >= 0
    w_last = np.where(seen, diff[np.maximum(last, 0)], DEFAULT_W)
    v0 = v[np.maximum(last, 0)]
    scale = seen & np.isfinite(v) & np.isfinite(v0)
    vc2 = clf._vc2
    w_carried = np.where(scale, w_last * ((vc2 + v * v) / (vc2 + v0 * v0)), w_last)
    w = np.where(computed, diff, w_carried)
    y = af
    if w_given is not None:
        wg = w_given[index]
        given = np.isfinite(wg)
        w = np.where(given, wg, w)
        if kf is not None:
            y = np.where(kf & ~zero_known & given, ef - w, af)
    logs = _log_densities(y, w, clf)
    logs[:, 2] += np.where(zero_known, clf._known_log, 0.0)
    logs -= logs.max(axis=1, keepdims=True)
    likelihood = np.exp(logs).tolist()
    # a filtered sample starts a new sequence if it is the first, or a standstill came since the last one
    resets = np.cumsum(reset)[index]
    starts = np.empty(len(index), dtype=bool)
    starts[0] = True
    starts[1:] = resets[1:] != resets[:-1]
    out[index] = (_smoothed if smooth else _forward)(likelihood, starts.tolist(), clf)
    return out


def _log_densities(y: np.ndarray, w: np.ndarray, clf: RegimeClassifier) -> np.ndarray:
    """(n, 4) log densities of y under TRACTION, CRUISING, COASTING, BRAKING (RegimeClassifier._filter)."""
    s, lam = clf._sigma, clf._lam
    logs = np.empty((len(y), 4))
    yt = y - clf._t_min
    logs[:, 0] = clf._t_const - lam * yt + _log_erfc((lam * s * s - yt) / (SQRT2 * s))
    z = y / s
    logs[:, 1] = clf._log_norm - 0.5 * z * z
    sc = np.hypot(s, clf._w_rel * w)
    z = (y + w) / sc
    logs[:, 2] = -LOG_SQRT_2PI - np.log(sc) - 0.5 * z * z
    lo, hi = clf._b_lo, clf._b_hi
    mass = 0.5 * (erf((hi - y) / (SQRT2 * s)) - erf((lo - y) / (SQRT2 * s)))
    inside = mass > 1e-300
    l_in = np.log(mass / (hi - lo))
    z = np.minimum(np.abs(y - lo), np.abs(y - hi)) / s  # far outside [lo, hi]: the nearer end's Gaussian tail
    logs[:, 3] = np.where(inside, l_in, clf._log_norm - 0.5 * z * z - math.log(hi - lo))
    return logs


def _log_erfc(x: np.ndarray) -> np.ndarray:
    """log(erfc(x)); the asymptotic series where erfc underflows (regime_model.log_erfc, elementwise)."""
    small = x < 5.0
    direct = np.log(erfc(np.where(small, x, 0.0)))
    x2 = x * x
    series = -x2 - np.log(x * math.sqrt(math.pi)) + np.log1p(-0.5 / x2 + 0.75 / (x2 * x2))
    return np.where(small, direct, series)


def _forward(likelihood: list[list[float]], starts: list[bool], clf: RegimeClassifier) -> list[int]:
    """The forward recursion on the likelihoods exp(log density - max) per sample: the most probable regime."""
    return [most_probable(*p) for p in _filtered(likelihood, starts, clf)]


def _filtered(likelihood: list[list[float]], starts: list[bool], clf: RegimeClassifier) -> list[tuple]:
    """The forward recursion: P(regime | this and earlier samples of the sequence) per sample."""
    stay, switch = math.exp(clf._log_stay), math.exp(clf._log_switch)
    keep = stay - switch
    out = []
    p0 = p1 = p2 = p3 = 0.0
    for (l0, l1, l2, l3), start in zip(likelihood, starts):
        if start:
            q0, q1, q2, q3 = START_PRIOR
        else:
            q0, q1, q2, q3 = p0 * keep + switch, p1 * keep + switch, p2 * keep + switch, p3 * keep + switch
        q0, q1, q2, q3 = q0 * l0, q1 * l1, q2 * l2, q3 * l3
        total = q0 + q1 + q2 + q3
        p0, p1, p2, p3 = q0 / total, q1 / total, q2 / total, q3 / total
        out.append((p0, p1, p2, p3))
    return out


def _smoothed(likelihood: list[list[float]], starts: list[bool], clf: RegimeClassifier) -> list[int]:
    """Forward-backward on the same likelihoods and sequences: the most probable regime of each sample's posterior
    marginal given the whole sequence. The transition matrix is keep I + switch 1 1^T, so A b = keep b + switch
    sum(b); each backward message is normalised (only its direction matters)."""
    stay, switch = math.exp(clf._log_stay), math.exp(clf._log_switch)
    keep = stay - switch
    filtered = _filtered(likelihood, starts, clf)
    n = len(filtered)
    regimes = [0] * n
    b0 = b1 = b2 = b3 = 1.0
    for i in range(n - 1, -1, -1):
        if i + 1 < n and not starts[i + 1]:  # the message from sample i + 1 of the same sequence
            l0, l1, l2, l3 = likelihood[i + 1]
            b0, b1, b2, b3 = backward_message(l0 * b0, l1 * b1, l2 * b2, l3 * b3, keep, switch)
        else:  # the last sample of a sequence
            b0 = b1 = b2 = b3 = 1.0
        f0, f1, f2, f3 = filtered[i]
        regimes[i] = most_probable(f0 * b0, f1 * b1, f2 * b2, f3 * b3)
    return regimes
