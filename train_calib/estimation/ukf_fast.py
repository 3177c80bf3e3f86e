"""The published filter's common step in one function: the fast path of :meth:`ResistanceEstimator._step`.

Fleet runs at 1 Hz spend most of the UKF's time in the common step: effort computed from the speeds, r a consider
parameter (``decouple_unknown_effort`` or the coast regression), the Euler rule, one filter (no look-ahead), a
position that passes the gate, a finite update that needs no projection onto r >= 0 and whose covariance factors.
:func:`common_step` is that step with the chain ``_predict_published`` -> ``_predict`` (``_mean_acceleration``,
``_speed_directions``, ``_propagate_sv``) -> ``_measure`` (``_gate_position``, ``_update``) -> ``_safeguard``
(``_project_and_check``, ``cholesky``) written out in one frame: the same operations in the same order (the zero
terms of the decoupled sigma directions included: adding them may turn -0.0 into 0.0), without the dozen calls, the
intermediate tuples and the repeated unpacking of P between them (4 fleet 1 Hz runs, 98 % of whose steps are common:
the UKF stage 55.7 -> 50.0 ms CPU). It computes into locals and returns None, the estimator untouched, whenever the
step leaves the common case; ``_step`` then takes the readable chain, which stays the reference: test_fast_paths
checks that the two give the same outputs bit for bit.

The step runs in C where the package was built with a compiler (``_ukf_kernel.c``'s ``common_step``: this function's
operations in the same order, floats bit for bit): :data:`common_step` is the kernel's, or
:func:`common_step_python` (this module's, the kernel's reference) without it (:data:`KERNEL_AVAILABLE` False).
test/estimation/test_ukf_kernel.py compares the two. The kernel also runs a common sample's whole
``ResistanceEstimator.process`` (``process_common``); the UKF stage of a 20-minute 1 Hz run takes less than half the
CPU time with it (docs/estimator.md).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

from .covariance import cholesky

if TYPE_CHECKING:
    from .ukf import ResistanceEstimator, StepInput


def eligible(est: ResistanceEstimator) -> bool:
    """The configuration whose common step :func:`common_step` covers: one filter (no look-ahead), effort computed
    (``effort_mode: computed``), r a consider parameter, the Euler rule."""
    return not est._lookahead and not est._exploit and est._decouple and not est._midpoint


def common_step_python(
    est: ResistanceEstimator, m: StepInput, dt: float, a_obs: float, rs: float, rv: float
) -> tuple[float, float, float] | None:
    """The published filter's step after dt > 0 s (``_step`` after the speed slope a_obs in m/s^2; rs in m^2 and rv
    in (m/s)^2 the measurement variances) when it is the common one: the new state committed to ``est`` and (effort,
    input effort, both N/kg, NIS of the 2-dof update) returned; None, with ``est`` untouched, when the step needs
    the general chain (position not measured or gated, effort not finite, an update that is not finite or not
    positive definite, a projection onto r >= 0 or a repair)."""
    h = est._h
    x = h.x
    zv, zs = m.v, m.s
    if not m.s_measured:
        return None
    # -- _predict_published: the effort computed from the speed change (Euler: r at the filtered speed)
    s, v, r0, r1, r2 = x
    zv_prev, g_prev = est._zv_prev, est._g_prev
    dz = zv - zv_prev
    r_ref = r0 + (r1 + r2 * v) * v  # running_resistance(r0, r1, r2, v)
    effort = a_obs + r_ref + g_prev
    u = dz / dt + r_ref + g_prev
    if not math.isfinite(effort + a_obs + u):
        return None
    # -- _predict, decoupled: only the speed components of the sigma directions move a
    lf = h.L
    p00, p01, p02, p03, p04, p11, p12, p13, p14, p22, p23, p24, p33, p34, p44 = h.P
    hh = 0.5 * dt
    a0 = (u - g_prev) - r0 - (r1 + r2 * v) * v  # _mean_acceleration (Euler)
    two_v = 2.0 * v
    c = est._c
    l00, l10, l20, l30, l40, l11, l21, l31, l41, l22, l32, l42, l33, l43, l44 = lf
    dv = c * l10  # _speed_directions (Euler)
    ap, am = -((r1 + r2 * (two_v + dv)) * dv), -((r1 + r2 * (two_v + -dv)) * -dv)
    o0, e0 = 0.5 * (ap - am), 0.5 * (ap + am)
    dv = c * l11
    ap, am = -((r1 + r2 * (two_v + dv)) * dv), -((r1 + r2 * (two_v + -dv)) * -dv)
    o1, e1 = 0.5 * (ap - am), 0.5 * (ap + am)
    o2 = e2 = o3 = e3 = o4 = e4 = 0.0
    c2 = est._c2
    big_e = (e0 + e1 + e2 + e3 + e4) / c2
    q = (
        est._beta_alpha * big_e * big_e
        + (o0 * o0 + o1 * o1 + o2 * o2 + o3 * o3 + o4 * o4 + e0 * e0 + e1 * e1 + e2 * e2 + e3 * e3 + e4 * e4) / c2
    )
    ic = est._ic
    m0 = l00 * o0 * ic
    m1 = (l10 * o0 + l11 * o1) * ic
    m2 = (l20 * o0 + l21 * o1 + l22 * o2) * ic
    m3 = (l30 * o0 + l31 * o1 + l32 * o2 + l33 * o3) * ic
    m4 = (l40 * o0 + l41 * o1 + l42 * o2 + l43 * o3 + l44 * o4) * ic
    n02, n03, n04 = p02 + dt * p12, p03 + dt * p13, p04 + dt * p14
    # _propagate_sv, grouped
    abar = a0 + big_e
    b0 = 0.5 * dt * dt
    b1 = dt
    am0 = m0 + dt * m1
    xs = s + dt * v + b0 * abar
    xv = v + dt * abar
    n01 = p01 + dt * p11
    base = p00 + dt * (p01 + n01)
    n00 = base + (2.0 * am0 * b0 + q * b0 * b0)
    n01 += am0 * b1 + b0 * m1 + q * b0 * b1
    n11 = p11 + 2.0 * m1 * b1 + q * b1 * b1
    qs = qsv = qv = 0.0  # the (s, v) process noise left out of the gain (f.q_sv)
    qa = est._qa
    if qa > 0.0:
        qs_, qsv_, qv_ = qa * b0 * b0, qa * b0 * b1, qa * b1 * b1
        n00 += qs_
        n01 += qsv_
        n11 += qv_
        if not est._use_q_gain:
            qs, qsv, qv = qs_, qsv_, qv_
    b0 = hh * dt
    qr0, qr1, qr2 = est._qr
    p02, p03, p04 = n02 + b0 * m2, n03 + b0 * m3, n04 + b0 * m4
    p12, p13, p14 = p12 + dt * m2, p13 + dt * m3, p14 + dt * m4
    p22, p33, p44 = p22 + qr0 * dt, p33 + qr1 * dt, p44 + qr2 * dt
    # -- _gate_position: the position passes the gate
    nu = zs - xs
    model = est._gate_accel * 0.5 * dt * dt
    var = n00 + rs + model * model
    if not nu * nu <= est._position_gate * var:
        return None
    # -- _update with s and v measured, r a consider parameter (its gain zero)
    c00, c01, c11 = n00 - qs, n01 - qsv, n11 - qv
    nu1 = zv - xv
    nu0 = zs - xs
    s00, s11 = c00 + rs, c11 + rv
    det = s00 * s11 - c01 * c01
    if not det > 0.0:
        return None
    i00, i01, i11 = s11 / det, -c01 / det, s00 / det
    k00, k01 = c00 * i00 + c01 * i01, c00 * i01 + c01 * i11
    k10, k11 = c01 * i00 + c11 * i01, c01 * i01 + c11 * i11
    xs += k00 * nu0 + k01 * nu1
    xv += k10 * nu0 + k11 * nu1
    nis = nu0 * nu0 * i00 + 2.0 * nu0 * nu1 * i01 + nu1 * nu1 * i11
    k20 = k21 = k30 = k31 = k40 = k41 = 0.0
    r0 += k20 * nu0 + k21 * nu1
    r1 += k30 * nu0 + k31 * nu1
    r2 += k40 * nu0 + k41 * nu1
    P = (
        n00 - (k00 * c00 + k01 * c01), n01 - (k00 * c01 + k01 * c11),
        p02 - (k00 * p02 + k01 * p12), p03 - (k00 * p03 + k01 * p13), p04 - (k00 * p04 + k01 * p14),
        n11 - (k10 * c01 + k11 * c11),
        p12 - (k10 * p02 + k11 * p12), p13 - (k10 * p03 + k11 * p13), p14 - (k10 * p04 + k11 * p14),
        p22 - (k20 * p02 + k21 * p12), p23 - (k20 * p03 + k21 * p13), p24 - (k20 * p04 + k21 * p14),
        p33 - (k30 * p03 + k31 * p13), p34 - (k30 * p04 + k31 * p14),
        p44 - (k40 * p04 + k41 * p14),
    )  # fmt: skip
    # -- _safeguard: finite, nothing to project, the covariance factors
    new_x = [xs, xv, r0, r1, r2]
    if not math.isfinite(sum(new_x) + sum(P) + nis):
        return None
    if xv < 0.0 or r0 < 0.0 or r1 < 0.0 or r2 < 0.0:
        return None
    chol = cholesky(P)
    if chol is None:
        return None
    # -- commit: what the chain leaves in the estimator
    x[:] = new_x
    h.P, h.L, h.m, h.q_sv = P, chol, (m0, m1, m2, m3, m4), (qs, qsv, qv)
    est._last_effort, est._last_accel, est._last_input = effort, a_obs, u
    est._gated_since = None
    est._gated_count = 0
    est._relocked = False
    return effort, u, nis


try:
    from . import _ukf_kernel  # the C kernel of this step (setup.py builds it where a C compiler is found)
except ImportError:  # pragma: no cover - built without a compiler: the Python step
    _ukf_kernel = None

KERNEL_AVAILABLE = _ukf_kernel is not None
common_step = _ukf_kernel.common_step if _ukf_kernel is not None else common_step_python
"""The common step the estimator takes (``ResistanceEstimator._common_step``): the C kernel's where it was built,
else :func:`common_step_python`; the same signature and the same numbers."""
