"""The closed-form unscented step of the resistance UKF (Cunillera et al. 2022, eq. 4-18): prediction and update of
one (s, v, r0, r1, r2) filter.

State x = (s, v, r0, r1, r2); process (eq. 4-5) over the step dt between two measurements:

    a  = u - g - r0 - r1 v - r2 v^2       (euler; midpoint: a at v + dt/2 * a)
    s' = s + dt v + dt^2/2 a,  v' = v + dt a,  r' = r

with u the applied effort and g the track force of the measurement at the start of the step; the
measurement z = (s, v) (or v alone when s was not measured) is linear.

The unscented transform is done in closed form. Every sigma point is x + d with d = 0 or +-c L_j
(L the Cholesky factor of P, c^2 = L + lambda), and the process is A x + b a(x) with A linear,
b = (dt^2/2, dt, 0, 0, 0) and a(x) a scalar; with o_j, e_j the odd and even parts of
a(x +- c L_j) - a(x):

    a_bar = a(x) + sum_j e_j / c^2
    m     = sum_j L_j o_j / c                      (cross-covariance of x and a)
    q     = (beta - alpha^2) E^2 + sum_j (o_j^2 + e_j^2) / c^2,  E = sum_j e_j / c^2
    x_bar = A x + b a_bar,   P_bar = A P A^T + A m b^T + b m^T A^T + q b b^T + Q

which is algebraically the weighted sums of eq. 10-11 (van der Merwe weights, eq. 9) without
forming the 11 sigma points or their huge cancelling weights (w0 = -1.7e6 with Table 1), and the
update (eq. 12-18) with a linear h reduces to a 2x2 Kalman update (derivation: docs/estimator.md, "The filter").
``ukf_reference.py`` is the same step written as the paper's equations with explicit sigma points; tests check
the closed form against it step by step and against filterpy's UnscentedKalmanFilter + MerweScaledSigmaPoints.

:class:`UnscentedStep` is a base class of ``ResistanceEstimator`` (``ukf.py``), which decides which filter steps
and with which effort; the step reads only its own constants (``_init_step``) and the filter it is given. Packed
covariance indices: ``covariance.py`` and docs/estimator.md.
"""

from __future__ import annotations

import math

from .config import UKFConfig
from .ukf_types import FilterState


class UnscentedStep:
    """The closed-form unscented step (docs/estimator.md, "The filter"): ``_predict`` (the resistance filter),
    ``_predict_output`` (the output filter of the look-ahead) and ``_update`` (both), each on a
    :class:`FilterState` in place."""

    _c2: float  # c^2 = L + lambda (L = 5 states): the sigma points' spread, squared
    _c: float
    _ic: float  # 1 / c
    _beta_alpha: float  # beta - alpha^2, the weight of E^2 in q
    _midpoint: bool  # integration: midpoint (a at the mid-step speed)
    _use_q_gain: bool  # update_uses_process_noise: the gain sees the (s, v) process noise
    _qa: float  # acceleration noise variance, (m/s^2)^2
    _qr: tuple[float, float, float]  # random-walk variances of r0, r1, r2, per s

    def _init_step(self, cfg: UKFConfig) -> None:
        """The step's constants from the configuration: sigma-point spread and weight, integration rule, process
        noise."""
        n = 5
        lam = cfg.lam
        self._c2 = n + lam
        self._c = math.sqrt(self._c2)
        self._ic = 1.0 / self._c
        self._beta_alpha = cfg.beta - cfg.alpha**2
        self._midpoint = cfg.integration == "midpoint"
        self._use_q_gain = bool(cfg.update_uses_process_noise)
        self._qa = cfg.accel_noise_std**2
        self._qr = (cfg.noise_r0**2, cfg.noise_r1**2, cfg.noise_r2**2)

    def _mean_acceleration(self, x: list[float], w: float, h: float) -> tuple[float, float]:
        """(a at the mean, the mid-step speed v + h a_euler), w = u - g in N/kg, h = dt/2 in s (eq. 5; the midpoint
        rule takes a at the mid-step speed)."""
        v, r0, r1, r2 = x[1], x[2], x[3], x[4]
        a0 = w - r0 - (r1 + r2 * v) * v
        vh = v + h * a0
        if self._midpoint:
            a0 = w - r0 - (r1 + r2 * vh) * vh
        return a0, vh

    def _speed_directions(
        self, x: list[float], vh: float, h: float, l10: float, l11: float
    ) -> tuple[float, float, float, float]:
        """(o0, e0, o1, e1): odd and even parts of a(x +- c L_j) - a(x) along the sigma directions j = 0, 1 when r
        enters at its mean (only the speed component c L_1j of the direction moves a); zero along j = 2, 3, 4.
        Euler rule: :meth:`_speed_directions_any`'s ``da`` written out (the same operations without its closure and
        four calls: 1.1 -> 0.6 us a step); the midpoint rule there."""
        if self._midpoint:
            return self._speed_directions_any(x, vh, h, l10, l11)
        r1, r2 = x[3], x[4]
        two_v = 2.0 * x[1]
        c = self._c
        dv = c * l10  # da(dv) = -(r1 + r2 (2 v + dv)) dv, at +dv and -dv
        ap, am = -((r1 + r2 * (two_v + dv)) * dv), -((r1 + r2 * (two_v + -dv)) * -dv)
        o0, e0 = 0.5 * (ap - am), 0.5 * (ap + am)
        dv = c * l11
        ap, am = -((r1 + r2 * (two_v + dv)) * dv), -((r1 + r2 * (two_v + -dv)) * -dv)
        return o0, e0, 0.5 * (ap - am), 0.5 * (ap + am)

    def _speed_directions_any(
        self, x: list[float], vh: float, h: float, l10: float, l11: float
    ) -> tuple[float, float, float, float]:
        """:meth:`_speed_directions` under either integration rule (the reference of its Euler fast path)."""
        v, r1, r2 = x[1], x[3], x[4]
        c = self._c
        mid = self._midpoint

        def da(dv: float) -> float:
            dr = (r1 + r2 * (2.0 * v + dv)) * dv
            if not mid:
                return -dr
            dvh = dv - h * dr
            return -(r1 + r2 * (2.0 * vh + dvh)) * dvh

        dv0 = c * l10
        ap, am = da(dv0), da(-dv0)
        o0, e0 = 0.5 * (ap - am), 0.5 * (ap + am)
        dv1 = c * l11
        ap, am = da(dv1), da(-dv1)
        return o0, e0, 0.5 * (ap - am), 0.5 * (ap + am)

    def _all_directions(self, x: list[float], vh: float, h: float, lf: tuple[float, ...]) -> tuple[float, ...]:
        """(o0, e0, ..., o4, e4): odd and even parts of a(x +- c L_j) - a(x) along the five sigma directions, r
        moving with the sigma point (lf: the packed Cholesky factor)."""
        v, r1, r2 = x[1], x[3], x[4]
        _l00, l10, l20, l30, l40, l11, l21, l31, l41, l22, l32, l42, l33, l43, l44 = lf
        c = self._c
        mid = self._midpoint

        def da(dv: float, d0: float, d1: float, d2: float) -> float:  # a(x + d) - a(x), d over (v, r0, r1, r2)
            w1 = v + dv
            dr = d0 + (d1 + d2 * w1) * w1 + (r1 + r2 * (2.0 * v + dv)) * dv
            if not mid:
                return -dr
            dvh = dv - h * dr
            wh = vh + dvh
            return -(d0 + (d1 + d2 * wh) * wh + (r1 + r2 * (2.0 * vh + dvh)) * dvh)

        dv0, d00, d10, d20 = c * l10, c * l20, c * l30, c * l40
        ap, am = da(dv0, d00, d10, d20), da(-dv0, -d00, -d10, -d20)
        o0, e0 = 0.5 * (ap - am), 0.5 * (ap + am)
        dv1, d01, d11, d21 = c * l11, c * l21, c * l31, c * l41
        ap, am = da(dv1, d01, d11, d21), da(-dv1, -d01, -d11, -d21)
        o1, e1 = 0.5 * (ap - am), 0.5 * (ap + am)
        d02, d12, d22 = c * l22, c * l32, c * l42
        ap, am = da(0.0, d02, d12, d22), da(0.0, -d02, -d12, -d22)
        o2, e2 = 0.5 * (ap - am), 0.5 * (ap + am)
        d13, d23 = c * l33, c * l43
        ap, am = da(0.0, 0.0, d13, d23), da(0.0, 0.0, -d13, -d23)
        o3, e3 = 0.5 * (ap - am), 0.5 * (ap + am)
        d24 = c * l44
        ap, am = da(0.0, 0.0, 0.0, d24), da(0.0, 0.0, 0.0, -d24)
        return o0, e0, o1, e1, o2, e2, o3, e3, 0.5 * (ap - am), 0.5 * (ap + am)

    def _propagate_sv(
        self, f: FilterState, dt: float, abar: float, m0: float, m1: float, q: float, grouped: bool
    ) -> tuple[float, float, float]:
        """Mean of s and v (eq. 4 at a_bar) in place and their predicted covariance block (n00, n01, n11):
        A P A^T + A m b^T + b m^T A^T + q b b^T + Q_a, b = (dt^2/2, dt), Q_a the acceleration noise; sets f.q_sv (the
        part left out of the gain). ``grouped``: the two terms of n00 are added as one sum (the resistance filter)
        or one by one (the output filter) -- the same maths, both kept for bit-identical outputs."""
        x = f.x
        P = f.P
        p00, p01, p11 = P[0], P[1], P[5]
        s, v = x[0], x[1]
        b0 = 0.5 * dt * dt
        b1 = dt
        am0 = m0 + dt * m1  # (A m)_s
        x[0] = s + dt * v + b0 * abar
        x[1] = v + dt * abar
        n01 = p01 + dt * p11
        base = p00 + dt * (p01 + n01)
        n00 = base + (2.0 * am0 * b0 + q * b0 * b0) if grouped else base + 2.0 * am0 * b0 + q * b0 * b0
        n01 += am0 * b1 + b0 * m1 + q * b0 * b1
        n11 = p11 + 2.0 * m1 * b1 + q * b1 * b1
        f.q_sv = (0.0, 0.0, 0.0)
        qa = self._qa
        if qa > 0.0:
            qs, qsv, qv = qa * b0 * b0, qa * b0 * b1, qa * b1 * b1
            n00 += qs
            n01 += qsv
            n11 += qv
            if not self._use_q_gain:
                f.q_sv = (qs, qsv, qv)
        return n00, n01, n11

    def _predict(self, f: FilterState, dt: float, u: float, g: float, decoupled: bool) -> None:
        """The resistance filter's prediction over dt s with effort u and track force g (N/kg), eq. 7-11 in closed
        form; ``decoupled``: r enters the process at its mean (consider step)."""
        x = f.x
        lf = f.L
        _, _, p02, p03, p04, _, p12, p13, p14, p22, p23, p24, p33, p34, p44 = f.P
        h = 0.5 * dt
        a0, vh = self._mean_acceleration(x, u - g, h)
        if decoupled:  # only the v-components of the sigma points move a
            o0, e0, o1, e1 = self._speed_directions(x, vh, h, lf[1], lf[5])
            o2 = e2 = o3 = e3 = o4 = e4 = 0.0
        else:
            o0, e0, o1, e1, o2, e2, o3, e3, o4, e4 = self._all_directions(x, vh, h, lf)
        c2 = self._c2
        big_e = (e0 + e1 + e2 + e3 + e4) / c2
        q = (
            self._beta_alpha * big_e * big_e
            + (o0 * o0 + o1 * o1 + o2 * o2 + o3 * o3 + o4 * o4 + e0 * e0 + e1 * e1 + e2 * e2 + e3 * e3 + e4 * e4) / c2
        )
        l00, l10, l20, l30, l40, l11, l21, l31, l41, l22, l32, l42, l33, l43, l44 = lf
        ic = self._ic
        m0 = l00 * o0 * ic
        m1 = (l10 * o0 + l11 * o1) * ic
        m2 = (l20 * o0 + l21 * o1 + l22 * o2) * ic
        m3 = (l30 * o0 + l31 * o1 + l32 * o2 + l33 * o3) * ic
        m4 = (l40 * o0 + l41 * o1 + l42 * o2 + l43 * o3 + l44 * o4) * ic
        f.m = (m0, m1, m2, m3, m4)
        # the s and v rows of A P A^T before the mean moves
        n02, n03, n04 = p02 + dt * p12, p03 + dt * p13, p04 + dt * p14
        n00, n01, n11 = self._propagate_sv(f, dt, a0 + big_e, m0, m1, q, True)
        b0 = h * dt
        qr0, qr1, qr2 = self._qr
        f.P = (n00, n01, n02 + b0 * m2, n03 + b0 * m3, n04 + b0 * m4, n11, p12 + dt * m2, p13 + dt * m3,
               p14 + dt * m4, p22 + qr0 * dt, p23, p24, p33 + qr1 * dt, p34, p44 + qr2 * dt)  # fmt: skip

    def _predict_output(self, f: FilterState, dt: float, u: float, g: float, with_r: bool) -> None:
        """The output filter's step (look-ahead): the unscented step of (s, v) with r at its mean (f's P is block
        diagonal after ``_sync``, so the v-directions of the sigma points carry no r), and with ``with_r`` (known
        effort) r's uncertainty as acceleration noise J P_rr J^T, J = -da/dr at the mean (a is linear in r; with the
        midpoint rule through the mid-step speed too). Only the (s, v) block of P changes: r is a consider parameter
        whose cross-covariance ``_sync`` drops."""
        x = f.x
        l00, l10, l11 = f.L[0], f.L[1], f.L[5]
        P = f.P
        h = 0.5 * dt
        a0, vh = self._mean_acceleration(x, u - g, h)
        o0, e0, o1, e1 = self._speed_directions(x, vh, h, l10, l11)
        c2 = self._c2
        big_e = (e0 + e1) / c2
        q = self._beta_alpha * big_e * big_e + (o0 * o0 + o1 * o1 + e0 * e0 + e1 * e1) / c2
        if with_r:
            v, r1, r2 = x[1], x[3], x[4]
            if self._midpoint:  # a = w - r(vh), vh = v + h (w - r(v)): da/dr_i = -(1 - h r'(vh)) (1, ., .) at vh, v
                k = h * (r1 + 2.0 * r2 * vh)
                j0, j1, j2 = 1.0 - k, vh - k * v, vh * vh - k * v * v
            else:
                j0, j1, j2 = 1.0, v, v * v
            q22, q23, q24, q33, q34, q44 = P[9], P[10], P[11], P[12], P[13], P[14]
            q += j0 * (j0 * q22 + 2.0 * (j1 * q23 + j2 * q24)) + j1 * (j1 * q33 + 2.0 * j2 * q34) + j2 * j2 * q44
        ic = self._ic
        m0 = l00 * o0 * ic
        m1 = (l10 * o0 + l11 * o1) * ic
        f.m = (m0, m1, 0.0, 0.0, 0.0)
        n00, n01, n11 = self._propagate_sv(f, dt, a0 + big_e, m0, m1, q, False)
        f.P = (n00, n01, P[2], P[3], P[4], n11, *P[6:])

    def _update(
        self, f: FilterState, zs: float, zv: float, rs: float, rv: float, s_measured: bool, dt: float, consider: bool,
        sv_only: bool = False,
    ) -> tuple[float, int]:  # fmt: skip
        """Eq. 12-18 with the linear h(x) = (s, v) (v alone when not ``s_measured``): a 2x2 (or scalar) Kalman update
        in the gain basis (P without the process noise left out of the gain, ``q_sv``); variances rs (m^2), rv
        ((m/s)^2). ``consider``: r is a consider parameter (Schmidt-Kalman): its gain is zero, so r and P_rr stay, and
        the r-(s, v) covariances get the Joseph-form update. ``sv_only`` (the output filter, whose r-(s, v)
        covariances are zero): only s, v and their block change. Returns (NIS, degrees of freedom); NaN when the
        innovation covariance is not positive."""
        x = f.x
        P = f.P
        p00, p01, p11 = P[0], P[1], P[5]
        qs, qsv, qv = f.q_sv if dt > 0.0 else (0.0, 0.0, 0.0)
        c00, c01, c11 = p00 - qs, p01 - qsv, p11 - qv  # Pxz of the s and v rows
        nu1 = zv - x[1]
        if s_measured:
            nu0 = zs - x[0]
            s00, s11 = c00 + rs, c11 + rv
            det = s00 * s11 - c01 * c01
            if not det > 0.0:
                return math.nan, 2
            i00, i01, i11 = s11 / det, -c01 / det, s00 / det
            k00, k01 = c00 * i00 + c01 * i01, c00 * i01 + c01 * i11
            k10, k11 = c01 * i00 + c11 * i01, c01 * i01 + c11 * i11
            x[0] += k00 * nu0 + k01 * nu1
            x[1] += k10 * nu0 + k11 * nu1
            nis = nu0 * nu0 * i00 + 2.0 * nu0 * nu1 * i01 + nu1 * nu1 * i11
            n00, n01, n11 = p00 - (k00 * c00 + k01 * c01), p01 - (k00 * c01 + k01 * c11), p11 - (k10 * c01 + k11 * c11)
            if sv_only:
                f.P = (n00, n01, P[2], P[3], P[4], n11, *P[6:])
                return nis, 2
            _, _, p02, p03, p04, _, p12, p13, p14, p22, p23, p24, p33, p34, p44 = P
            if consider:
                k20 = k21 = k30 = k31 = k40 = k41 = 0.0
            else:
                k20, k21 = p02 * i00 + p12 * i01, p02 * i01 + p12 * i11
                k30, k31 = p03 * i00 + p13 * i01, p03 * i01 + p13 * i11
                k40, k41 = p04 * i00 + p14 * i01, p04 * i01 + p14 * i11
            x[2] += k20 * nu0 + k21 * nu1
            x[3] += k30 * nu0 + k31 * nu1
            x[4] += k40 * nu0 + k41 * nu1
            f.P = (
                n00, n01,
                p02 - (k00 * p02 + k01 * p12), p03 - (k00 * p03 + k01 * p13), p04 - (k00 * p04 + k01 * p14),
                n11,
                p12 - (k10 * p02 + k11 * p12), p13 - (k10 * p03 + k11 * p13), p14 - (k10 * p04 + k11 * p14),
                p22 - (k20 * p02 + k21 * p12), p23 - (k20 * p03 + k21 * p13), p24 - (k20 * p04 + k21 * p14),
                p33 - (k30 * p03 + k31 * p13), p34 - (k30 * p04 + k31 * p14),
                p44 - (k40 * p04 + k41 * p14),
            )  # fmt: skip
            return nis, 2
        sv = c11 + rv
        if not sv > 0.0:
            return math.nan, 1
        k0, k1 = c01 / sv, c11 / sv
        x[0] += k0 * nu1
        x[1] += k1 * nu1
        n00, n01, n11 = p00 - k0 * c01, p01 - k0 * c11, p11 - k1 * c11
        if sv_only:
            f.P = (n00, n01, P[2], P[3], P[4], n11, *P[6:])
            return nu1 * nu1 / sv, 1
        _, _, p02, p03, p04, _, p12, p13, p14, p22, p23, p24, p33, p34, p44 = P
        k2, k3, k4 = (0.0, 0.0, 0.0) if consider else (p12 / sv, p13 / sv, p14 / sv)
        x[2] += k2 * nu1
        x[3] += k3 * nu1
        x[4] += k4 * nu1
        f.P = (
            n00, n01, p02 - k0 * p12, p03 - k0 * p13, p04 - k0 * p14,
            n11, p12 - k1 * p12, p13 - k1 * p13, p14 - k1 * p14,
            p22 - k2 * p12, p23 - k2 * p13, p24 - k2 * p14,
            p33 - k3 * p13, p34 - k3 * p14,
            p44 - k4 * p14,
        )  # fmt: skip
        return nu1 * nu1 / sv, 1
