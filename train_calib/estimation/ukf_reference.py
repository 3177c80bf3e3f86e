"""The UKF step of Cunillera et al. (2022), eq. 3-18, written out as the paper states it: the tests' oracle.

One numpy line per equation, the equation number beside it, sigma points formed explicitly (filterpy's
``UnscentedKalmanFilter`` + ``MerweScaledSigmaPoints`` style). Slow and plain on purpose: ``ukf_step.py`` computes
the same step in closed form (docs/estimator.md, "The filter"), and test/estimation/test_ukf_reference.py checks it
against this module step by step, for the resistance filter and for the output (published) filter.

Everything is SI: s in m, v in m/s, r0 N/kg, r1 N/(kg m/s), r2 N/(kg (m/s)^2), u and g in N/kg, dt in s.
Beyond the paper, as in the estimator: the midpoint process (``midpoint``), process noise Q, the consider
(Schmidt) update (``consider``: r and P_rr keep their predicted values), and the output filter's step
(:func:`output_step`).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

import numpy as np

from .config import UKFConfig

L = 5
"""State size: x = (s, v, r0, r1, r2)."""


class ReferenceStep(NamedTuple):
    """The state after one step: mean (5,), covariance (5, 5), normalised innovation squared."""

    x: np.ndarray
    P: np.ndarray
    nis: float


def acceleration(x: np.ndarray, u: float, g: float) -> float:
    """Cunillera eq. 5: a = u - r0 - r1 v - r2 v^2 - g(s), N/kg (g taken at the measurement: see the docs)."""
    _s, v, r0, r1, r2 = x
    return u - r0 - r1 * v - r2 * v * v - g  # (5)


def f(x: np.ndarray, dt: float, u: float, g: float, midpoint: bool = False, r_mean=None) -> np.ndarray:
    """Cunillera eq. 4 with eq. 5; ``midpoint``: a at the mid-step speed (RK2); ``r_mean``: r at its mean."""
    xr = x if r_mean is None else np.array([x[0], x[1], *r_mean])
    a = acceleration(xr, u, g)  # (5)
    if midpoint:
        a = acceleration(np.array([xr[0], xr[1] + 0.5 * dt * a, *xr[2:]]), u, g)
    return x + np.array([dt * x[1] + 0.5 * dt * dt * a, dt * a, 0.0, 0.0, 0.0])  # (4)


def weights(alpha: float, beta: float, kappa: float) -> tuple[float, np.ndarray, np.ndarray]:
    """lambda and van der Merwe's weights w^m, w^c (eq. 9)."""
    lam = alpha**2 * (L + kappa) - L
    wm = np.full(2 * L + 1, 0.5 / (L + lam))  # (9) w_i^m, i >= 1
    wc = wm.copy()  # (9) w_i^c = w_i^m, i >= 1
    wm[0] = lam / (L + lam)  # (9) w_0^m
    wc[0] = lam / (L + lam) + 1.0 - alpha**2 + beta  # (9) w_0^c
    return lam, wm, wc


def sigma_points(x: np.ndarray, P: np.ndarray, lam: float) -> np.ndarray:
    """The 2L + 1 sigma points X_i as rows (eq. 7), square root by Cholesky."""
    S = np.linalg.cholesky((L + lam) * P)  # (7) sqrt((L + lambda) P), columns S[:, i]
    return np.vstack([x, x + S.T, x - S.T])  # (7) X_0 = x, X_i = x + S_i, X_{L+i} = x - S_i


def process_noise(cfg: UKFConfig, dt: float) -> np.ndarray:
    """Q of eq. 11 (the paper has none): piecewise-constant acceleration noise and a random walk of r."""
    b = np.array([0.5 * dt * dt, dt, 0.0, 0.0, 0.0])
    return cfg.accel_noise_std**2 * np.outer(b, b) + np.diag([0.0, 0.0, cfg.noise_r0**2 * dt,
                                                             cfg.noise_r1**2 * dt, cfg.noise_r2**2 * dt])  # fmt: skip


def update(x_bar, P_bar, Y, wm, wc, z, R, s_measured: bool) -> tuple[np.ndarray, np.ndarray, float]:
    """Eq. 12-18 with the linear h(x) = (s, v) (v alone when s was not measured), from the sigma points Y."""
    H = [0, 1] if s_measured else [1]
    Z = Y[:, H]  # (12) Z_i = h(Y_i)
    z_bar = wm @ Z  # (13)
    Pz = (Z - z_bar).T @ np.diag(wc) @ (Z - z_bar) + R[np.ix_(H, H)]  # (14)
    Pxz = (Y - x_bar).T @ np.diag(wc) @ (Z - z_bar)  # (15)
    K = Pxz @ np.linalg.inv(Pz)  # (16)
    nu = z[H] - z_bar
    x = x_bar + K @ nu  # (17)
    P = P_bar - K @ Pz @ K.T  # (18)
    return x, P, float(nu @ np.linalg.solve(Pz, nu))


def resistance_step(
    cfg: UKFConfig, x: np.ndarray, P: np.ndarray, dt: float, u: float, g: float, z: np.ndarray, s_measured: bool,
    consider: bool, g_of_s: Callable[[float], float] | None = None,
) -> ReferenceStep:  # fmt: skip
    """One step of the filter that learns r (the paper's filter): predict over dt with effort u and track force g,
    update with z = (s, v). ``consider``: the process takes r at its mean and r, P_rr keep their predicted values
    (Schmidt update). v, r clipped at 0 (``nonnegative: clip``). dt = 0: update only. ``g_of_s``: eq. 5 literally,
    g(s) at each sigma point's own position (the estimator, like g here, takes g at the measurement)."""
    lam, wm, wc = weights(cfg.alpha, cfg.beta, cfg.kappa)
    midpoint = cfg.integration == "midpoint"
    R = np.diag([cfg.meas_std_s**2, cfg.meas_std_v**2])
    if dt > 0.0:
        X = sigma_points(x, P, lam)  # (7)
        gs = [g if g_of_s is None else g_of_s(Xi[0]) for Xi in X]  # g(s) at the measurement, or at each X_i
        Y = np.array([f(Xi, dt, u, gi, midpoint, x[2:] if consider else None) for Xi, gi in zip(X, gs)])  # (8)
        x_bar = wm @ Y  # (10)
        Q = process_noise(cfg, dt)
        P_bar = (Y - x_bar).T @ np.diag(wc) @ (Y - x_bar) + Q  # (11)
        if cfg.update_uses_process_noise:
            Y = sigma_points(x_bar, P_bar, lam)  # the gain sees Q: sigma points redrawn (filterpy's option)
    else:
        x_bar, P_bar = x.copy(), P.copy()
        Y = sigma_points(x_bar, P_bar, lam)
    x_new, P_new, nis = update(x_bar, P_bar, Y, wm, wc, z, R, s_measured)  # (12)-(18)
    if consider:
        x_new[2:], P_new[2:, 2:] = x_bar[2:], P_bar[2:, 2:]
    x_new[1:] = np.maximum(x_new[1:], 0.0)
    return ReferenceStep(x_new, P_new, nis)


def output_step(
    cfg: UKFConfig, x: np.ndarray, P: np.ndarray, dt: float, u: float, g: float, z: np.ndarray, s_measured: bool,
    with_r: bool,
) -> ReferenceStep:  # fmt: skip
    """One step of the output (published) filter with look-ahead: the UKF step of eq. 7-18 with r a consider
    parameter at its mean in the process; P is block diagonal ((s, v) and r), its r block is not propagated.
    ``with_r`` (known effort): r's uncertainty enters as acceleration noise J P_rr J^T, J = da/dr at the mean
    (the first-order unscented transform in the r directions, not in the paper). v clipped at 0."""
    lam, wm, wc = weights(cfg.alpha, cfg.beta, cfg.kappa)
    midpoint = cfg.integration == "midpoint"
    R = np.diag([cfg.meas_std_s**2, cfg.meas_std_v**2])
    b = np.array([0.5 * dt * dt, dt, 0.0, 0.0, 0.0])
    Q = cfg.accel_noise_std**2 * np.outer(b, b)  # acceleration noise only: r is not propagated
    if dt > 0.0:
        X = sigma_points(x, P, lam)  # (7)
        Y = np.array([f(Xi, dt, u, g, midpoint, x[2:]) for Xi in X])  # (8), r at its mean
        x_bar = wm @ Y  # (10)
        P_bar = (Y - x_bar).T @ np.diag(wc) @ (Y - x_bar)  # (11), without Q
        P_bar[2:, 2:] = P[2:, 2:]  # r: a consider parameter, not propagated
        if with_r:
            J = consider_jacobian(x, dt, u, g, midpoint)
            P_bar += (J @ P[2:, 2:] @ J) * np.outer(b, b)
        gain_basis = P_bar if not cfg.update_uses_process_noise else P_bar + Q
        P_bar = P_bar + Q  # (11)
        Y = sigma_points(x_bar, gain_basis, lam)  # eq. 12's sigma points: covariance P_bar (- Q, the paper's)
    else:
        x_bar, P_bar = x.copy(), P.copy()
        Y = sigma_points(x_bar, P_bar, lam)
    x_new, P_new, nis = update(x_bar, P_bar, Y, wm, wc, z, R, s_measured)  # (12)-(18)
    x_new[1] = max(x_new[1], 0.0)
    return ReferenceStep(x_new, P_new, nis)


def consider_jacobian(x: np.ndarray, dt: float, u: float, g: float, midpoint: bool) -> np.ndarray:
    """J = da/dr at the mean (3,): (1, v, v^2) for Euler; for the midpoint rule through the mid-step speed vh,
    (1 - k) (1, ., .) with k = dt/2 r'(vh): (1 - k, vh - k v, vh^2 - k v^2)."""
    v, r1, r2 = x[1], x[3], x[4]
    if not midpoint:
        return np.array([1.0, v, v * v])
    vh = v + 0.5 * dt * acceleration(x, u, g)
    k = 0.5 * dt * (r1 + 2.0 * r2 * vh)
    return np.array([1.0 - k, vh - k * v, vh * vh - k * v * v])
