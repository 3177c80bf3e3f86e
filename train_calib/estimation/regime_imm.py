"""The ``imm`` regime filter of :mod:`.regimes` (``RegimeClassifier`` with ``method: imm``, the default): an
interacting multiple-model filter (Blom & Bar-Shalom) of four Kalman filters of (speed, acceleration), one per
regime, on the measured speeds, weighed by the traction power's state where measured. A module of its own: the
classifier's module keeps the paper's methods, the phase and the batch form.

Units: speeds m/s, accelerations m/s^2, forces N/kg, times s.
"""

from __future__ import annotations

import math
from typing import NamedTuple

from ..regime_codes import TRACTION
from .config import RegimeConfig
from .regime_model import SQRT2, most_probable

_IMM_START = (0.85, 0.05, 0.05, 0.05)
"""imm: probabilities of (TRACTION, CRUISING, COASTING, BRAKING) at the first moving sample: departing."""
_IMM_START_ACCEL = (0.3, 0.0, None, -0.3)
"""imm: the acceleration (m/s^2) each model starts from (None: the coasting -(r + g)); std _IMM_START_STD."""
_IMM_START_STD = 0.5
_POWER_EPS = 0.05
"""imm: the likelihood of a power state that contradicts a regime, against 1 where it agrees (0.01-0.15 within 0.5
points on the tune half's power families): small, not zero, so that a power sample a step late does not veto the
speeds."""
_POWER_LIKELIHOOD = (
    (_POWER_EPS, 0.1, 1.0, 0.3),  # POWER_OFF: coasting; a hold where r + g ~ 0, or braking by the friction brake
    (1.0, 1.0, _POWER_EPS, _POWER_EPS),  # POWER_TRACTION: traction or a hold against r + g > 0
    (_POWER_EPS, 1.0, _POWER_EPS, 1.0),  # POWER_REGEN: braking, or a hold downhill
)
"""imm: P(power state | TRACTION, CRUISING, COASTING, BRAKING), up to a factor per state."""
_NOISE_FLOOR = 0.2
"""imm: the learned speed noise stays above this share of ``imm_speed_noise_std``."""
_NOISE_WEIGHT = 0.05
"""imm: weight of one sample in the running mean of the absolute second differences (about 20 samples)."""
_NOISE_MAX_DT = 2.0
"""imm: the noise is learned from steps of at most this many seconds (over longer ones the acceleration changes)."""
_TWO_PI = 2.0 * math.pi
_GAUSS_ABS = math.sqrt(math.pi / 2.0)
"""sigma / mean |x| of a zero-mean Gaussian."""


class ImmFilter:
    """The ``imm`` regime filter (module docstring): four Kalman filters of (speed v, acceleration a), mixed
    between samples by the regime transition probabilities, weighed by their innovations. Plain floats: one
    sample costs four 2x2 filter steps."""

    __slots__ = (
        "_adapt",
        "_c2",
        "_dwell",
        "_h2",
        "_k",
        "_k_dt",
        "_mu",
        "_noise",
        "_noise0",
        "_noise_min",
        "_pmax",
        "_q2",
        "_r",
        "_rel2",
        "_t",
        "_x",
        "_z",
    )

    def __init__(self, cfg: RegimeConfig) -> None:
        self._adapt = cfg.imm_adapt_noise
        self._noise0 = cfg.imm_speed_noise_std
        self._noise_min = _NOISE_FLOOR * cfg.imm_speed_noise_std
        self._h2 = cfg.imm_hold_accel_std**2
        self._c2 = cfg.imm_coast_accel_std**2
        self._rel2 = cfg.resistance_rel_std**2
        self._q2 = cfg.imm_accel_walk_std**2
        self._dwell = cfg.imm_mean_dwell
        self._pmax = cfg.imm_switch_max
        self._k_dt = math.nan  # the dt of the step constants _k
        self._k: _StepConstants | None = None
        self.reset()

    def reset(self) -> None:
        """An unrelated sequence follows: the configured speed noise, no regime."""
        self._noise = self._noise0  # the sensor's noise, learned over the run (kept across stops)
        self._r = self._noise0 * self._noise0
        self._mu: list[float] | None = None
        self._x: list[Prior] = []  # per model (v, a, Pvv, Pva, Paa)
        self._t = math.nan
        self._z: tuple[float, float, float, float] | None = None  # previous speed, its time, step slope, step dt

    def _learn_noise(self, t: float, z: float) -> None:
        """The speed sensor's noise from the second differences of the measured speeds: a robust running mean of
        their absolute values (each clipped at 3 times the current estimate: changes of acceleration are rare),
        from the configured value, never below ``_NOISE_FLOOR`` of it; at sample periods up to ``_NOISE_MAX_DT``. A
        stop keeps what was learned."""
        prev = self._z
        if prev is None or not t > prev[1]:
            self._z = (z, t, math.nan, math.nan)
            return
        z1, t1, slope1, dt1 = prev
        dt = t - t1
        slope = (z - z1) / dt
        self._z = (z, t, slope, dt)
        if math.isnan(slope1) or not self._adapt or max(dt, dt1) > _NOISE_MAX_DT:
            return
        # slope - slope1 has variance sigma^2 (1/dt^2 + (1/dt + 1/dt1)^2 + 1/dt1^2) for white speed noise sigma
        scale = math.sqrt(1.0 / (dt * dt) + (1.0 / dt + 1.0 / dt1) ** 2 + 1.0 / (dt1 * dt1))
        x = min(abs(slope - slope1) / scale, 3.0 * self._noise)
        mean_abs = (1.0 - _NOISE_WEIGHT) * self._noise / _GAUSS_ABS + _NOISE_WEIGHT * x
        self._noise = max(_GAUSS_ABS * mean_abs, self._noise_min)
        self._r = self._noise * self._noise

    def restart(self) -> None:
        """A standstill: the regimes start over, the learned noise stays."""
        self._mu = None
        self._z = None

    def probabilities(self) -> tuple[float, ...] | None:
        return tuple(self._mu) if self._mu is not None else None

    @property
    def speed_noise(self) -> float:
        return self._noise

    @property
    def time(self) -> float:
        """Time (s) of the last sample filtered (NaN before the first)."""
        return self._t

    @staticmethod
    def is_start(probabilities: tuple[float, ...] | None) -> bool:
        """True for the probabilities a (re)start sets (the departure prior): the sample began a new sequence."""
        return probabilities == _IMM_START

    def step(self, t: float, z: float, w: float, power: int | None = None) -> int:
        """The regime at time t (s) given the measured speed z (m/s), r + g = w (N/kg) and the traction power's state
        (POWER_*, None: not measured).

        ``reference_step`` with its helpers written out (the mixing, the four predictions and updates): a third
        fewer instructions on a 1 Hz run; test_regimes checks that the two agree float for float."""
        self._learn_noise(t, z)
        if self._mu is None or not t > self._t:  # first sample, or time not increasing: start over
            self._start(t, z, w)
            return TRACTION
        dt = t - self._t
        self._t = t
        off, keep, q, dt2, two_dt, half_dt_q, dt2_q3 = self._constants(dt)
        r = self._r
        # the mixing (_moments_of, _moments): each model's moments about the first model's speed z0, their sums
        (z0, a_0, pvv_0, pva_0, paa_0), (v_1, a_1, pvv_1, pva_1, paa_1), x2, x3 = self._x
        v_2, a_2, pvv_2, pva_2, paa_2 = x2
        v_3, a_3, pvv_3, pva_3, paa_3 = x3
        mu0, mu1, mu2, mu3 = self._mu
        d0, d1, d2, d3 = z0 - z0, v_1 - z0, v_2 - z0, v_3 - z0
        vv0, vv1, vv2, vv3 = pvv_0 + d0 * d0, pvv_1 + d1 * d1, pvv_2 + d2 * d2, pvv_3 + d3 * d3
        va0, va1, va2, va3 = pva_0 + d0 * a_0, pva_1 + d1 * a_1, pva_2 + d2 * a_2, pva_3 + d3 * a_3
        aa0, aa1, aa2, aa3 = paa_0 + a_0 * a_0, paa_1 + a_1 * a_1, paa_2 + a_2 * a_2, paa_3 + a_3 * a_3
        o_v = off * (0.0 + mu0 * d0 + mu1 * d1 + mu2 * d2 + mu3 * d3)
        o_a = off * (0.0 + mu0 * a_0 + mu1 * a_1 + mu2 * a_2 + mu3 * a_3)
        o_vv = off * (0.0 + mu0 * vv0 + mu1 * vv1 + mu2 * vv2 + mu3 * vv3)
        o_va = off * (0.0 + mu0 * va0 + mu1 * va1 + mu2 * va2 + mu3 * va3)
        o_aa = off * (0.0 + mu0 * aa0 + mu1 * aa1 + mu2 * aa2 + mu3 * aa3)
        k0, k1, k2, k3 = keep * mu0, keep * mu1, keep * mu2, keep * mu3
        c0, c1, c2, c3 = off + k0, off + k1, off + k2, off + k3
        # TRACTION (_mixed, _predict_walk, _correct, the effort's sign)
        dv = (o_v + k0 * d0) / c0
        a = (o_a + k0 * a_0) / c0
        pvv = (o_vv + k0 * vv0) / c0 - dv * dv
        pva = (o_va + k0 * va0) / c0 - dv * a
        paa = (o_aa + k0 * aa0) / c0 - a * a
        vp = z0 + dv + dt * a
        qvv = pvv + two_dt * pva + dt2 * paa + dt2_q3
        qva = pva + dt * paa + half_dt_q
        sv = qvv + r
        nu = z - vp
        kv, ka = qvv / sv, qva / sv
        an = a + ka * nu
        pn = paa + q - ka * qva
        if pn < 1e-12:
            pn = 1e-12
        l0 = math.exp(-0.5 * nu * nu / sv) / math.sqrt(_TWO_PI * sv)
        l0 *= 0.5 * math.erfc(-((an + w) / math.sqrt(pn)) / SQRT2)
        x0 = (vp + kv * nu, an, qvv - kv * qvv, qva - kv * qva, pn)
        # BRAKING (the same with the other sign)
        dv = (o_v + k3 * d3) / c3
        a = (o_a + k3 * a_3) / c3
        pvv = (o_vv + k3 * vv3) / c3 - dv * dv
        pva = (o_va + k3 * va3) / c3 - dv * a
        paa = (o_aa + k3 * aa3) / c3 - a * a
        vp = z0 + dv + dt * a
        qvv = pvv + two_dt * pva + dt2 * paa + dt2_q3
        qva = pva + dt * paa + half_dt_q
        sv = qvv + r
        nu = z - vp
        kv, ka = qvv / sv, qva / sv
        an = a + ka * nu
        pn = paa + q - ka * qva
        if pn < 1e-12:
            pn = 1e-12
        l3 = math.exp(-0.5 * nu * nu / sv) / math.sqrt(_TWO_PI * sv)
        l3 *= 0.5 * math.erfc(((an + w) / math.sqrt(pn)) / SQRT2)
        x3 = (vp + kv * nu, an, qvv - kv * qvv, qva - kv * qva, pn)
        # CRUISING (_mixed_speed, _predict_fixed with a = 0, _correct)
        var = self._h2
        dv = (o_v + k1 * d1) / c1
        vp = z0 + dv + dt * 0.0
        qvv = (o_vv + k1 * vv1) / c1 - dv * dv + dt2 * var
        qva = dt * var
        sv = qvv + r
        nu = z - vp
        kv, ka = qvv / sv, qva / sv
        pn = var - ka * qva
        if pn < 1e-12:
            pn = 1e-12
        l1 = math.exp(-0.5 * nu * nu / sv) / math.sqrt(_TWO_PI * sv)
        x1 = (vp + kv * nu, 0.0 + ka * nu, qvv - kv * qvv, qva - kv * qva, pn)
        # COASTING (a = -w)
        var = self._c2 + self._rel2 * w * w
        dv = (o_v + k2 * d2) / c2
        vp = z0 + dv + dt * -w
        qvv = (o_vv + k2 * vv2) / c2 - dv * dv + dt2 * var
        qva = dt * var
        sv = qvv + r
        nu = z - vp
        kv, ka = qvv / sv, qva / sv
        pn = var - ka * qva
        if pn < 1e-12:
            pn = 1e-12
        l2 = math.exp(-0.5 * nu * nu / sv) / math.sqrt(_TWO_PI * sv)
        x2 = (vp + kv * nu, -w + ka * nu, qvv - kv * qvv, qva - kv * qva, pn)
        # the models' weights
        like = _NO_POWER if power is None else _POWER_LIKELIHOOD[power]
        w0, w1, w2, w3 = c0 * (l0 * like[0]), c1 * (l1 * like[1]), c2 * (l2 * like[2]), c3 * (l3 * like[3])
        total = w0 + w1 + w2 + w3
        if not total > 0.0 or not math.isfinite(total):  # every model rejects the sample: start over from it
            self._mu = None
            return self.step(t, z, w, power)
        self._mu = [w0 / total, w1 / total, w2 / total, w3 / total]
        self._x = [x0, x1, x2, x3]
        return most_probable(w0, w1, w2, w3)

    def reference_step(self, t: float, z: float, w: float, power: int | None = None) -> int:
        """``step`` written model by model with the helpers below: the reference that ``step`` (the same operations
        in the same order, written out for speed) is tested against, float for float."""
        self._learn_noise(t, z)
        if self._mu is None or not t > self._t:  # first sample, or time not increasing: start over
            self._start(t, z, w)
            return TRACTION
        dt = t - self._t
        self._t = t
        k = self._constants(dt)
        z0, o, m0, m1, m2, m3 = self._moments(k.off)
        mu0, mu1, mu2, mu3 = self._mu
        keep, off, r = k.keep, k.off, self._r
        k0, k1, k2, k3 = keep * mu0, keep * mu1, keep * mu2, keep * mu3
        c0, c1, c2, c3 = off + k0, off + k1, off + k2, off + k3  # the prior weights (sum of mu = 1)
        # traction and braking: the acceleration walks randomly, and the sign of the effort a + r + g (positive in
        # traction, negative in braking) weighs the model; hold and coast: the model's own acceleration over the step
        x0, l0 = _correct(*_predict_walk(_mixed(o, k0, c0, m0, z0), dt, k), z, r)
        l0 *= 0.5 * math.erfc(-((x0[1] + w) / math.sqrt(x0[4])) / SQRT2)
        x1, l1 = _correct(*_predict_fixed(_mixed_speed(o, k1, c1, m1, z0), dt, 0.0, self._h2, k.dt2), z, r)
        coast_var = self._c2 + self._rel2 * w * w
        x2, l2 = _correct(*_predict_fixed(_mixed_speed(o, k2, c2, m2, z0), dt, -w, coast_var, k.dt2), z, r)
        x3, l3 = _correct(*_predict_walk(_mixed(o, k3, c3, m3, z0), dt, k), z, r)
        l3 *= 0.5 * math.erfc(((x3[1] + w) / math.sqrt(x3[4])) / SQRT2)
        like = _NO_POWER if power is None else _POWER_LIKELIHOOD[power]
        w0, w1, w2, w3 = c0 * (l0 * like[0]), c1 * (l1 * like[1]), c2 * (l2 * like[2]), c3 * (l3 * like[3])
        total = w0 + w1 + w2 + w3
        if not total > 0.0 or not math.isfinite(total):  # every model rejects the sample: start over from it
            self._mu = None
            return self.reference_step(t, z, w, power)
        self._mu = [w0 / total, w1 / total, w2 / total, w3 / total]
        self._x = [x0, x1, x2, x3]
        return most_probable(w0, w1, w2, w3)

    def _start(self, t: float, z: float, w: float) -> None:
        """The first moving sample: every model at the measured speed z (m/s), its start acceleration (m/s^2)."""
        r, s2 = self._r, _IMM_START_STD**2
        self._mu = list(_IMM_START)
        self._x = [(z, -w if a0 is None else a0, r, 0.0, s2) for a0 in _IMM_START_ACCEL]
        self._t = t

    def _constants(self, dt: float) -> _StepConstants:
        """The terms of a step of dt s that depend on dt alone (the last one kept: at a fixed rate every step has the
        same dt)."""
        if dt != self._k_dt:
            self._k_dt, self._k = dt, _StepConstants.of(dt, self._dwell, self._pmax, self._q2)
        return self._k

    def _moments(self, off: float) -> tuple[float, Moments, Moments, Moments, Moments, Moments]:
        """The IMM's mixing, the part common to every model: (z0, the sums over the models i of mu_i times their
        moments, times off, and each model's moments); moments about the first model's speed z0 (m/s):
        (v - z0, a, Pvv + (v - z0)^2, Pva + (v - z0) a, Paa + a^2)."""
        x0, x1, x2, x3 = self._x
        z0 = x0[0]
        m0, m1, m2, m3 = _moments_of(x0, z0), _moments_of(x1, z0), _moments_of(x2, z0), _moments_of(x3, z0)
        mu0, mu1, mu2, mu3 = self._mu  # type: ignore[misc]
        o = (
            off * (0.0 + mu0 * m0[0] + mu1 * m1[0] + mu2 * m2[0] + mu3 * m3[0]),
            off * (0.0 + mu0 * m0[1] + mu1 * m1[1] + mu2 * m2[1] + mu3 * m3[1]),
            off * (0.0 + mu0 * m0[2] + mu1 * m1[2] + mu2 * m2[2] + mu3 * m3[2]),
            off * (0.0 + mu0 * m0[3] + mu1 * m1[3] + mu2 * m2[3] + mu3 * m3[3]),
            off * (0.0 + mu0 * m0[4] + mu1 * m1[4] + mu2 * m2[4] + mu3 * m3[4]),
        )
        return z0, o, m0, m1, m2, m3


_NO_POWER = (1.0, 1.0, 1.0, 1.0)
"""imm: the power likelihoods where the power is not measured (a factor 1.0 leaves a float as it is)."""


class _StepConstants(NamedTuple):
    """The terms of an IMM step that depend on its duration dt (s) alone."""

    off: float
    """P(i -> j) for i != j: switch / 3, switch = min(imm_switch_max, 1 - exp(-dt / imm_mean_dwell))."""
    keep: float
    """P(i -> i) - off."""
    q: float
    """Variance the random-walk acceleration gains over dt, (m/s^2)^2."""
    dt2: float
    """dt^2, s^2."""
    two_dt: float
    """2 dt, s."""
    half_dt_q: float
    """dt q / 2: the walk's speed-acceleration covariance gain."""
    dt2_q3: float
    """dt^2 q / 3: the walk's speed variance gain."""

    @classmethod
    def of(cls, dt: float, dwell: float, pmax: float, q2: float) -> _StepConstants:
        """The constants of a step of dt s (``imm_mean_dwell`` dwell s, ``imm_switch_max`` pmax, the walk's q2)."""
        stay, off = transition(dt, dwell, pmax)
        q = q2 * dt
        dt2 = dt * dt
        return cls(off, stay - off, q, dt2, 2.0 * dt, 0.5 * dt * q, dt2 * q / 3.0)


def transition(dt: float, mean_dwell: float, switch_max: float) -> tuple[float, float]:
    """(stay, off): the probabilities of keeping a mode and of changing to one given other mode over dt s: switch =
    min(switch_max, 1 - exp(-dt / mean_dwell)), off = switch / 3 (``imm_mean_dwell``, ``imm_switch_max``)."""
    switch = min(switch_max, -math.expm1(-dt / mean_dwell))
    return 1.0 - switch, switch / 3.0


Prior = tuple[float, float, float, float, float]
"""A model's state (v m/s, a m/s^2) and covariance (Pvv, Pva, Paa)."""


Moments = tuple[float, float, float, float, float]
"""A model's moments about a speed z0 in the mixing: (v - z0, a, Pvv + (v - z0)^2, Pva + (v - z0) a, Paa + a^2)."""


def _moments_of(x: Prior, z0: float) -> Moments:
    """The moments of model state x about the speed z0 (m/s)."""
    v, a, pvv, pva, paa = x
    dv = v - z0
    return dv, a, pvv + dv * dv, pva + dv * a, paa + a * a


def _mixed(o: Moments, kj: float, cj: float, m: Moments, z0: float) -> Prior:
    """Model j's prior: the posteriors mixed by P(i -> j) = off + keep [i == j], from ``o`` (off times the mu-weighted
    sums of the moments), kj = keep mu_j, the prior weight cj = off + kj and the model's own moments m."""
    dv0 = (o[0] + kj * m[0]) / cj
    a0 = (o[1] + kj * m[1]) / cj
    pvv = (o[2] + kj * m[2]) / cj - dv0 * dv0
    pva = (o[3] + kj * m[3]) / cj - dv0 * a0
    paa = (o[4] + kj * m[4]) / cj - a0 * a0
    return z0 + dv0, a0, pvv, pva, paa


def _mixed_speed(o: Moments, kj: float, cj: float, m: Moments, z0: float) -> tuple[float, float]:
    """(v m/s, Pvv) of ``_mixed``: all that a model of a fixed acceleration (hold, coast) predicts from."""
    dv0 = (o[0] + kj * m[0]) / cj
    return z0 + dv0, (o[2] + kj * m[2]) / cj - dv0 * dv0


def _predict_walk(prior: Prior, dt: float, k: _StepConstants) -> Prior:
    """Traction / braking over dt s: the acceleration walks randomly (variance ``k.q`` gained)."""
    v0, a0, pvv, pva, paa = prior
    return (
        v0 + dt * a0, a0, pvv + k.two_dt * pva + k.dt2 * paa + k.dt2_q3, pva + dt * paa + k.half_dt_q, paa + k.q
    )  # fmt: skip


def _predict_fixed(prior: tuple[float, float], dt: float, a: float, var: float, dt2: float) -> Prior:
    """Hold / coast over dt s from (v m/s, Pvv): the model's own acceleration a (m/s^2, variance var)."""
    v0, pvv = prior
    return v0 + dt * a, a, pvv + dt2 * var, dt * var, var


def _correct(vp: float, ap: float, qvv: float, qva: float, qaa: float, z: float, r: float) -> tuple[Prior, float]:
    """The update with the measured speed z (m/s, variance r): (the posterior, the likelihood of z)."""
    sv = qvv + r
    nu = z - vp
    kv, ka = qvv / sv, qva / sv
    paa = qaa - ka * qva
    if paa < 1e-12:  # max(paa, 1e-12)
        paa = 1e-12
    lik = math.exp(-0.5 * nu * nu / sv) / math.sqrt(_TWO_PI * sv)
    return (vp + kv * nu, ap + ka * nu, qvv - kv * qvv, qva - kv * qva, paa), lik
