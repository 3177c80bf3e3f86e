"""The independent reference: filterpy 1.4.5's UnscentedKalmanFilter + MerweScaledSigmaPoints on the model of
Cunillera et al. (eq. 4-5), driven with the estimator's own step inputs and per-step logic.

Used by test_ukf_equivalence (agreement) and bench/bench_ukf.py (speed); one implementation for both.
"""

from __future__ import annotations

import numpy as np
from filterpy.kalman import MerweScaledSigmaPoints, UnscentedKalmanFilter

from train_calib.estimation import UKFConfig


def process(x, dt, u=0.0, g=0.0, rbar=None, midpoint=False):
    """Cunillera eq. 4-5 (Euler), or the midpoint variant; rbar: the resistance at its mean (decoupled)."""
    s, v, r0, r1, r2 = x
    if rbar is not None:
        r0, r1, r2 = rbar
    a = u - g - r0 - r1 * v - r2 * v * v
    if midpoint:
        vh = v + 0.5 * dt * a
        a = u - g - r0 - r1 * vh - r2 * vh * vh
    return np.array([s + dt * v + 0.5 * dt * dt * a, v + dt * a, x[2], x[3], x[4]])


def hx_sv(x):
    return x[:2]


def hx_v(x):
    return x[1:2]


class FilterpyRun:
    """filterpy on the inputs the estimator used (its effort u, g, dt, decoupling and consider steps).

    Everything that does not depend on the filter's state (Q per step, measurement vectors, flags) is prepared
    here, so that a call times the filter alone. ``run(keep=True)`` returns the states and covariances of every
    step, (n, 5) and (n, 5, 5), the first being the prior.
    """

    def __init__(self, series, est, cfg: UKFConfig, prior) -> None:
        self.cfg, self.prior = cfg, prior
        self.x0 = np.array([series.s[0], series.v[0], *prior])
        self.p0 = est.covariance[0].copy()
        n = len(series)
        self.dt = est.dt.tolist()
        self.u = est.input_effort.tolist()
        self.g = [0.0, *est.track_force[:-1].tolist()]
        self.decoupled = est.decoupled.tolist()
        self.s_measured = series.s_measured.tolist()
        self.z = [np.array([series.s[k], series.v[k]]) if series.s_measured[k] else np.array([series.v[k]])
                  for k in range(n)]  # fmt: skip
        self.q = []
        for dt in self.dt:
            b = np.array([0.5 * dt * dt, dt])
            q = np.zeros((5, 5))
            q[:2, :2] = cfg.accel_noise_std**2 * np.outer(b, b)
            q[2, 2], q[3, 3], q[4, 4] = cfg.noise_r0**2 * dt, cfg.noise_r1**2 * dt, cfg.noise_r2**2 * dt
            self.q.append(q)
        self.r_sv = np.diag([cfg.meas_std_s**2, cfg.meas_std_v**2])
        self.r_v = np.array([[cfg.meas_std_v**2]])
        self.redraw = cfg.update_uses_process_noise and cfg.accel_noise_std > 0
        self.midpoint = cfg.integration == "midpoint"

    def __call__(self, keep: bool = False):
        cfg = self.cfg
        pts = MerweScaledSigmaPoints(5, alpha=cfg.alpha, beta=cfg.beta, kappa=cfg.kappa)
        ukf = UnscentedKalmanFilter(5, 2, 1.0, hx_sv, process, pts)
        ukf.x, ukf.P, ukf.R = self.x0.copy(), self.p0.copy(), self.r_sv
        xs, ps = [ukf.x.copy()], [ukf.P.copy()]
        for k in range(1, len(self.dt)):
            ukf.Q = self.q[k]
            decoupled = self.decoupled[k]
            rbar = tuple(ukf.x[2:]) if decoupled else None
            ukf.predict(dt=self.dt[k], u=self.u[k], g=self.g[k], rbar=rbar, midpoint=self.midpoint)
            if self.redraw:
                ukf.sigmas_f = pts.sigma_points(ukf.x, ukf.P)  # the gain sees Q
            if decoupled:
                x_prior, p_prior = ukf.x[2:].copy(), ukf.P[2:, 2:].copy()
            if self.s_measured[k]:
                ukf.update(self.z[k])
            else:
                ukf.update(self.z[k], R=self.r_v, hx=hx_v)
            if decoupled:  # Schmidt (consider) update: r and P_rr keep their prior values
                ukf.x[2:] = x_prior
                ukf.P[2:, 2:] = p_prior
            ukf.x[1:] = np.maximum(ukf.x[1:], 0.0)  # nonnegative = "clip"
            if keep:
                xs.append(ukf.x.copy())
                ps.append(ukf.P.copy())
        return np.array(xs), np.array(ps)


def run_filterpy(series, est, cfg: UKFConfig, prior):
    """States (n, 5) and covariances (n, 5, 5) of filterpy over the run, the first being the prior."""
    return FilterpyRun(series, est, cfg, prior)(keep=True)
