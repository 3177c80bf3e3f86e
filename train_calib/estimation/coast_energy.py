"""The energy form of the coast regression, for sparse samples (docs/estimator.md, "Coasts at 10 s sampling").

At 10 s the train runs 200-300 m between two samples, over gradients that may change every few dozen metres: the
track force at the samples says little about its mean over the step, and the speeds' local slopes (the time form's
detection, :mod:`coast_detection`, steps 2-3) span 60-90 s against coasts of 40-60 s. The work-energy theorem
needs neither. With E = v^2 / 2 + Gamma(s), Gamma the integral of the track force over s (``Measurement.
track_force_integral``, exact from the track), a coast (u = 0) obeys

    E_i = E_0 - r0 (s_i - s_0) - r1 int v ds - r2 int v^2 (1 + f_tun tunnel) ds + n_i,

whatever the gradient did in between. The noise of E_i is v_i n_v (the speed) and g_i n_s (the position), so each
equation is weighted by 1 / (v_i^2 sigma_v^2 + g_i^2 sigma_s^2).

**Detection** (:func:`energy_candidates`): a window of ``coast_energy_window`` consecutive samples is coasting when

1. its energies fit E_0 - k R_i (R = int r_prior(v) ds, the train file's curve scaled by k) within the noise:
   chi^2 <= the 99 % point of chi^2 with m - 2 degrees of freedom;
2. k lies in ``coast_ratio_min`` .. ``coast_ratio_max`` (traction gives k < 0, braking k >> 1);
3. a held speed explains the speeds worse by at least ``coast_hold_sigmas``^2 in chi^2 (on a gradient where
   r + g = 0 a coast and a hold look alike: such windows are left out, they would let a hold with a light
   traction in).

Samples of accepted windows form stretches; each stretch's end samples are then pruned while their
leave-one-out residual exceeds ``PRUNE_SIGMAS`` and grown by the neighbouring samples whose leave-one-out residual
is within ``GROW_SIGMAS`` (a coast starts and ends between two samples: the step that holds the change is left
out, the full coasting steps next to the window test's reach are taken in; among them the steps where r + g is
near 0, which the window test's hold check leaves out). The two limits were chosen on the tune half of the
validation family's 10 s eco runs (bench/validation): on the family's own draw, no pruning or growth 9.3 %,
pruning 10.4 %, pruning 2.5 and growth 1.5 sigma 6.0 % median error; then over 30 noise draws of each run
(bench/validation/replicates.py; median |error| over the draws, runs worse than their prior per draw of the
half): growth 1.0 / 1.5 / 1.75 / 2.0 / 2.5 / 3.0 sigma 7.8 / 7.0 / 6.9 / 6.4 / 6.2 / 6.4 % and 0.70 / 0.37 / 0.27 /
0.13 / 0.17 / 0.17 (the oracle over the true coasts: 4.5 %, 0.13), truth inside 2 sigma 95-96 % (94 % at 3.0);
pruning 1.5-3.0 changed little (7.0-7.1 %, 0.37-0.43 at growth 1.5). Growth 2.0 was taken.

**Ends** (:func:`end_mixture`, ``coast_energy_end_effort``): a coast starts and ends between two samples, and a
10 s step cannot place the change: the stretch's first sample may have traction in the step after it, its last
sample braking or traction in the step before it, and the neighbours just outside may have coasted throughout. A
leak of 1-2 s of traction is about one sigma of a sample's energy, yet an end sample has the most leverage on the
slope: on the tune run eco_stadelhofen_04 the same two coasts found one sample off at each end gave -4.1 % and
-21.2 % (prior -19.9 %). So the posterior (:func:`coast_posterior.add_coast_with_ends`) does not take the detected
ends as sure: every configuration whose coasting part starts at the outer neighbour, the first sample or the
second, and ends likewise, keeps all the samples; those outside the coasting part get the variance of an effort
over their step added ((``coast_energy_end_effort`` x v x period)^2, 0.5 N/kg: a typical traction over the whole
step), and the configurations are weighed by their evidence with E_0 integrated out, then moment-matched to one
Gaussian (the spread between configurations enters the covariance). Chosen on the tune half over 100 noise draws
a run (median |error|, runs worse than their prior per draw, truth inside 2 sigma): detected ends as sure 6.5 %,
0.18, 97 %; effort 0.3 / 0.5 / 0.8 N/kg 7.2 / 6.9 / 6.8 %, 0.08 / 0.08 / 0.09, 97 % (the oracle: 4.5 %, 0.10);
on 30 draws an effort of 3 or 5 sigma of the sample's energy instead (about 0.08-0.14 N/kg) 9.2 / 7.4 % and 1.33 /
0.73 runs worse (an effort that small leaves a real leak its pull), and two samples deep at each end 9.0-14.2 %.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view
from scipy.stats import chi2

from .coast_types import CoastSettings, EndMixture, RunArrays, Stretch, davis_value

PRUNE_SIGMAS = 2.5
"""An end sample of a stretch whose leave-one-out residual exceeds this many sigma is dropped."""
GROW_SIGMAS = 2.0
"""A neighbouring sample whose leave-one-out residual is within this many sigma joins the stretch."""
_CHI2_QUANTILE = 0.99


def step_grade_error(arr: RunArrays, prior: np.ndarray, min_speed: float) -> float:
    """Median over the moving steps of |mean g over the step (from Gamma) - trapezoid of g at its ends|, relative to
    the train file's r(v): how wrong the time form's gradient term is on these samples (0 where the gradient is
    constant over most steps)."""
    if arr.gamma is None or arr.s is None or arr.t.size < 3:
        return 0.0
    ds = np.diff(arr.s)
    moving = (arr.v[1:] >= min_speed) & (arr.v[:-1] >= min_speed) & (ds > 1.0)
    moving &= np.isfinite(arr.gamma[1:]) & np.isfinite(arr.gamma[:-1])
    if not np.any(moving):
        return 0.0
    exact = np.diff(arr.gamma)[moving] / ds[moving]
    trapezoid = 0.5 * (arr.g[1:] + arr.g[:-1])[moving]
    r = davis_value(prior, 0.5 * (arr.v[1:] + arr.v[:-1])[moving])
    return float(np.median(np.abs(exact - trapezoid) / np.maximum(r, 1e-6)))


def uses_energy_form(arr: RunArrays, settings: CoastSettings, period: float, grade_error: float) -> bool:
    """The energy form applies: sparse samples (period >= ``coast_energy_period``) over gradients that change
    within a step (``grade_error``, :func:`step_grade_error` of the samples so far, at least
    ``coast_energy_grade_error``), Gamma known at every sample, no traction power (with power the power decides,
    :func:`coast_detection.candidate_steps`). Elsewhere the time form, whose
    detection is the more conservative (on the bundled lines at 10 s the energy form took traction/coast cycles at
    130 km/h for coasts: 1.1 % median error against 0.7 %, one run 6 sigma off; the median step error is 0.00-0.04
    of r on every family but the Stadelhofen profile's 10 s runs, 0.21-0.35)."""
    return (
        period >= settings.coast_energy_period
        and arr.gamma is not None
        and arr.power is None
        and arr.t.size >= 3
        and bool(np.isfinite(arr.gamma).all())
        and bool(np.isfinite(arr.s).all())
        and grade_error >= settings.coast_energy_grade_error
    )


def energy_sigma_v(arr: RunArrays, sigma_v: float) -> float:
    """The speed noise (m/s) for the energy form: the sensor's stated std (``Measurement.v_variance``, the ingest's
    ``speed_std``) where it is given, else ``sigma_v`` (the data's estimate). At 10 s the data cannot tell noise
    from dynamics: second and third differences read 0.5-0.8 m/s on the Stadelhofen profile's eco runs against a
    true 0.16 (the acceleration changes with the gradient between samples), and their MAD reads the 1 km/h
    rounding's floor 0.08 on a held speed (the rounded values repeat)."""
    if arr.v_var is not None and arr.v_var.size:
        stated = float(np.median(arr.v_var))
        if math.isfinite(stated) and stated > 0.0:
            return math.sqrt(stated)
    return sigma_v


def energy_noise_var(arr: RunArrays, sigma_v: float) -> np.ndarray:
    """Variance of E at each sample, (J/kg)^2: v^2 sigma_v^2 + g^2 sigma_s^2."""
    s_var = arr.s_var if arr.s_var is not None else np.zeros_like(arr.v)
    return arr.v * arr.v * sigma_v * sigma_v + arr.g * arr.g * s_var


def _trapezoid_in_s(y: np.ndarray, s: np.ndarray) -> np.ndarray:
    out = np.zeros_like(y)
    if y.size > 1:
        out[1:] = np.cumsum(0.5 * (y[1:] + y[:-1]) * np.diff(s))
    return out


def _coast_fit(E: np.ndarray, R: np.ndarray, w: np.ndarray) -> tuple[float, float, np.ndarray]:
    """Weighted fit E = E0 - k R: (k, E0, residuals)."""
    sw = float(np.sum(w))
    e_bar, r_bar = float(w @ E) / sw, float(w @ R) / sw
    dr = R - r_bar
    srr = float(w @ (dr * dr))
    k = -float(w @ ((E - e_bar) * dr)) / srr if srr > 0.0 else 0.0
    e0 = e_bar + k * r_bar
    return k, e0, E - (e0 - k * R)


class EnergyTerms(NamedTuple):
    """Per sample: E = v^2/2 + Gamma (J/kg), R = the train file's r(v) integrated over s (J/kg), w = 1 / var(E);
    and the speed noise sigma_v (m/s) they were weighted with."""

    E: np.ndarray
    R: np.ndarray
    w: np.ndarray
    sigma_v: float


def energy_terms(arr: RunArrays, prior: np.ndarray, sigma_v: float) -> EnergyTerms:
    """E, R and the weights of every sample (once for a detection: the window test and the refinement share them)."""
    return EnergyTerms(
        0.5 * arr.v * arr.v + arr.gamma,
        _trapezoid_in_s(davis_value(prior, arr.v), arr.s),
        1.0 / np.maximum(energy_noise_var(arr, sigma_v), 1e-12),
        sigma_v,
    )


def energy_candidates(arr: RunArrays, terms: EnergyTerms, settings: CoastSettings, period: float) -> np.ndarray:
    """Per sample: inside a window that passes the coasting test (module docstring, 1-3)."""
    m = int(settings.coast_energy_window)
    n = arr.t.size
    flag = np.zeros(n, dtype=bool)
    if n < m:
        return flag
    E, R, w, _ = terms
    step_ok = np.zeros(n, dtype=bool)  # step ok[i]: sample i-1 -> i usable inside one window
    gap = min(settings.max_gap, 2.5 * period)
    dt = np.diff(arr.t)
    step_ok[1:] = (arr.run[1:] == arr.run[:-1]) & (dt > 0.0) & (dt <= gap)
    moving = arr.v >= settings.coast_min_speed
    Ew, Rw, ww, vw = (sliding_window_view(x, m) for x in (E, R, w, arr.v))
    valid = np.all(sliding_window_view(moving, m), axis=1) & np.all(sliding_window_view(step_ok, m)[:, 1:], axis=1)
    sw = ww.sum(axis=1)
    e_bar = (ww * Ew).sum(axis=1) / sw
    r_bar = (ww * Rw).sum(axis=1) / sw
    de = Ew - e_bar[:, None]
    dr = Rw - r_bar[:, None]
    srr = (ww * dr * dr).sum(axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        k = -(ww * de * dr).sum(axis=1) / srr
    chi_coast = (ww * (de + k[:, None] * dr) ** 2).sum(axis=1)
    dv = vw - vw.mean(axis=1)[:, None]
    chi_hold = (dv * dv).sum(axis=1) / (terms.sigma_v * terms.sigma_v)
    accept = (
        valid
        & (srr > 0.0)
        & (k >= settings.coast_ratio_min)
        & (k <= settings.coast_ratio_max)
        & (chi_coast <= chi2.ppf(_CHI2_QUANTILE, m - 2))
        & (chi_hold - chi_coast >= settings.coast_hold_sigmas**2)
    )
    for i in np.flatnonzero(accept):
        flag[i : i + m] = True
    return flag


def _leave_one_out(E: np.ndarray, R: np.ndarray, w: np.ndarray, idx: np.ndarray, pos: int) -> float:
    """Residual of sample idx[pos] in sigma against the coast fit of the others."""
    keep = np.delete(idx, pos)
    k, e0, _ = _coast_fit(E[keep], R[keep], w[keep])
    j = idx[pos]
    return abs(E[j] - (e0 - k * R[j])) * math.sqrt(w[j])


def refine(arr: RunArrays, terms: EnergyTerms, idx: np.ndarray, settings: CoastSettings, period: float) -> np.ndarray:
    """A stretch's samples after pruning its ends and growing it by its neighbours (module docstring)."""
    E, R, w, _ = terms
    while idx.size >= 4:
        worst = max(((pos, _leave_one_out(E, R, w, idx, pos)) for pos in (0, idx.size - 1)), key=lambda x: x[1])
        if worst[1] <= PRUNE_SIGMAS:
            break
        idx = np.delete(idx, worst[0])
    if idx.size < 3:
        return idx
    for forward in (False, True):
        while True:
            edge = int(idx[-1] if forward else idx[0])
            k = edge + 1 if forward else edge - 1
            if not _neighbour(arr, k, edge, settings, period):
                break
            grown = np.append(idx, k) if forward else np.insert(idx, 0, k)
            if _leave_one_out(E, R, w, grown, grown.size - 1 if forward else 0) > GROW_SIGMAS:
                break
            idx = grown
    return idx


def energy_bounds(
    arr: RunArrays, settings: CoastSettings, prior: np.ndarray, sigma_v: float, period: float
) -> tuple[list[tuple[int, int, int, int]], np.ndarray]:
    """(bounds (k0, k1, k0, k1) of the stretches after :func:`refine`, the per-sample candidate flags)."""
    terms = energy_terms(arr, prior, sigma_v)
    flag = energy_candidates(arr, terms, settings, period)
    refined: list[list[int]] = []
    min_duration = max(settings.coast_min_duration, 3.0 * period)
    idx = np.flatnonzero(flag)
    if idx.size:
        cuts = np.flatnonzero((np.diff(idx) > 1) | (arr.run[idx[1:]] != arr.run[idx[:-1]])) + 1
        for part in np.split(idx, cuts):
            if part.size < 3:
                continue
            part = refine(arr, terms, part, settings, period)
            if part.size < 3:
                continue
            k0, k1 = int(part[0]), int(part[-1])
            if refined and k0 <= refined[-1][1] and arr.run[k0] == arr.run[refined[-1][1]]:
                refined[-1][1] = max(refined[-1][1], k1)  # grown into the previous one: one stretch (no sample twice)
            else:
                refined.append([k0, k1])
    bounds = [(k0, k1, k0, k1) for k0, k1 in refined if arr.t[k1] - arr.t[k0] >= min_duration]
    return bounds, flag


def _samples(arr: RunArrays, k0: int, k1: int) -> RunArrays:
    sl = slice(k0, k1 + 1)
    return RunArrays(arr.t[sl], arr.v[sl], arr.g[sl], arr.tunnel[sl], arr.run[sl], None, arr.s[sl], arr.gamma[sl],
                     None if arr.s_var is None else arr.s_var[sl])  # fmt: skip


def _energy_columns(sub: RunArrays, tunnel_factor: float) -> np.ndarray:
    """(n, 3): s - s_0, the integral of v over s and that of v^2 (1 + f_tun tunnel), from the first sample."""
    s, v = sub.s, sub.v
    return np.column_stack(
        (s - s[0], _trapezoid_in_s(v, s), _trapezoid_in_s(v * v * (1.0 + tunnel_factor * sub.tunnel), s))
    )


def _neighbour(arr: RunArrays, k: int, edge: int, settings: CoastSettings, period: float) -> bool:
    """Sample k next to the stretch end ``edge`` may have coasted with it: same run, moving, no gap."""
    return (
        0 <= k < arr.t.size
        and arr.run[k] == arr.run[edge]
        and arr.v[k] >= settings.coast_min_speed
        and 0.0 < abs(arr.t[k] - arr.t[edge]) <= min(settings.max_gap, 2.5 * period)
    )


def neighbour_limits(spans: list[tuple[int, int]], first: int, last: int) -> list[tuple[int, int]]:
    """Per stretch (k0, k1) in order, the samples (lo, hi) its outer neighbours may come from: after the stretch
    before it (from ``first``), before the stretch after it (up to ``last``)."""
    lows = [first] + [k1 + 1 for _, k1 in spans[:-1]]
    highs = [k0 - 1 for k0, _ in spans[1:]] + [last]
    return list(zip(lows, highs))


def end_mixture(
    arr: RunArrays,
    k0: int,
    k1: int,
    settings: CoastSettings,
    sigma_v: float,
    tunnel_factor: float,
    period: float,
    lo: int = 0,
    hi: int | None = None,
) -> EndMixture:
    """The stretch k0..k1 with its ends uncertain (module docstring, "Ends"): the samples from its outer neighbour
    a = k0 - 1 to b = k1 + 1 (where they may have coasted with it, and within lo..hi), and every configuration whose
    coasting part starts at a, k0 or k0 + 1 and ends at k1 - 1, k1 or b, at least 3 samples."""
    hi = arr.t.size - 1 if hi is None else hi
    a = k0 - 1 if k0 - 1 >= lo and _neighbour(arr, k0 - 1, k0, settings, period) else k0
    b = k1 + 1 if k1 + 1 <= hi and _neighbour(arr, k1 + 1, k1, settings, period) else k1
    sub = _samples(arr, a, b)
    v = sub.v
    n = b - a + 1
    masks = []
    for i0 in range(a, min(k0 + 1, k1) + 1):
        for i1 in range(max(k1 - 1, k0), b + 1):
            if i1 - i0 >= 2:
                mask = np.zeros(n, dtype=bool)
                mask[i0 - a : i1 - a + 1] = True
                masks.append(mask)
    effort = settings.coast_energy_end_effort * v * period  # J/kg: the effort's work over a whole step
    return EndMixture(
        0.5 * v * v + sub.gamma,
        -_energy_columns(sub, tunnel_factor),
        np.maximum(energy_noise_var(sub, sigma_v), 1e-12),
        effort * effort,
        sub.s - arr.s[k0],
        np.array(masks, dtype=bool).reshape(-1, n),
    )


def energy_equations(
    arr: RunArrays,
    k0: int,
    k1: int,
    settings: CoastSettings,
    prior: np.ndarray,
    sigma_v: float,
    tunnel_factor: float,
    period: float,
    lo: int = 0,
    hi: int | None = None,
) -> Stretch:
    """The stretch's equations in the energy form, whitened to the speed noise's scale (each row divided by
    sqrt(var(E_i)) / sigma_v) with E_0 projected out in the weighted sense; tau the whitened distance (the direction
    of a constant extra deceleration common to the coast). With ``coast_energy_end_effort`` > 0 the stretch also
    carries its :func:`end_mixture` (neighbours within samples lo..hi), which the posterior uses in their place."""
    sub = _samples(arr, k0, k1)
    s, v = sub.s, sub.v
    y = 0.5 * v * v + sub.gamma
    phi = _energy_columns(sub, tunnel_factor)
    scale = np.sqrt(np.maximum(energy_noise_var(sub, sigma_v), 1e-12)) / sigma_v  # m/s: E's std over sigma_v
    u = 1.0 / scale  # the whitened E_0 column

    def project(x: np.ndarray) -> np.ndarray:
        xw = x / (scale[:, None] if x.ndim == 2 else scale)
        return xw - np.outer(u, u @ xw) / (u @ u) if x.ndim == 2 else xw - u * (u @ xw) / (u @ u)

    bias = settings.coast_stretch_std * float(davis_value(prior, float(np.mean(v))))
    ends = None
    if settings.coast_energy_end_effort > 0.0:
        ends = end_mixture(arr, k0, k1, settings, sigma_v, tunnel_factor, period, lo, hi)
    return Stretch(
        float(sub.t[0]), float(sub.t[-1]), float(np.min(v)), float(np.max(v)),
        -project(phi), project(y), project(s - s[0]), sigma_v * sigma_v, bias, int(sub.run[0]), ends=ends,
    )  # fmt: skip


__all__ = [
    "EnergyTerms",
    "end_mixture",
    "energy_bounds",
    "energy_candidates",
    "energy_equations",
    "energy_noise_var",
    "energy_sigma_v",
    "energy_terms",
    "neighbour_limits",
    "refine",
    "step_grade_error",
    "uses_energy_form",
]
