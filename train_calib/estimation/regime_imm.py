"""The ``imm`` regime filter of :mod:`.regimes` (``RegimeClassifier`` with ``method: imm``, the default): an
interacting multiple-model filter (Blom & Bar-Shalom) of four Kalman filters of (speed, acceleration), one per
regime, on the measured speeds, weighed by the traction power's state where measured. A module of its own: the
classifier's module keeps the paper's methods, the phase and the batch form.

Units: speeds m/s, accelerations m/s^2, forces N/kg, times s.
"""

from __future__ import annotations

import math

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
        self.reset()

    def reset(self) -> None:
        """An unrelated sequence follows: the configured speed noise, no regime."""
        self._noise = self._noise0  # the sensor's noise, learned over the run (kept across stops)
        self._r = self._noise0 * self._noise0
        self._mu: list[float] | None = None
        self._x: list[list[float]] = []  # per model [v, a, Pvv, Pva, Paa]
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
        (POWER_*, None: not measured)."""
        self._learn_noise(t, z)
        if self._mu is None or not t > self._t:  # first sample, or time not increasing: start over
            r, s2 = self._r, _IMM_START_STD**2
            self._mu = list(_IMM_START)
            self._x = [[z, -w if a0 is None else a0, r, 0.0, s2] for a0 in _IMM_START_ACCEL]
            self._t = t
            return TRACTION
        dt = t - self._t
        self._t = t
        switch = min(self._pmax, -math.expm1(-dt / self._dwell))
        stay, off = 1.0 - switch, switch / 3.0
        mu, xs, r = self._mu, self._x, self._r
        coast_var = self._c2 + self._rel2 * w * w
        like_power = None if power is None else _POWER_LIKELIHOOD[power]
        out_x = []
        weights = []
        # mixing: model j's prior is the models' posteriors weighed by P(i -> j) = off + (stay - off) [i == j]; the
        # sums over i of mu_i times the moments once, then each j adds its own share (moments about the first speed)
        keep = stay - off
        z0 = xs[0][0]
        s_v = s_a = s_vv = s_va = s_aa = 0.0
        moments = []
        for m_i, x in zip(mu, xs):
            dv, a_i = x[0] - z0, x[1]
            mom = (dv, a_i, x[2] + dv * dv, x[3] + dv * a_i, x[4] + a_i * a_i)
            moments.append(mom)
            s_v += m_i * mom[0]
            s_a += m_i * mom[1]
            s_vv += m_i * mom[2]
            s_va += m_i * mom[3]
            s_aa += m_i * mom[4]
        for j in range(4):
            kj = keep * mu[j]
            cj = off + kj  # sum of mu = 1
            mv, ma, mvv, mva, maa = moments[j]
            dv0 = (off * s_v + kj * mv) / cj
            a0 = (off * s_a + kj * ma) / cj
            pvv = (off * s_vv + kj * mvv) / cj - dv0 * dv0
            pva = (off * s_va + kj * mva) / cj - dv0 * a0
            paa = (off * s_aa + kj * maa) / cj - a0 * a0
            v0 = z0 + dv0
            # prediction over dt
            if j == 1 or j == 2:  # hold / coast: the model's own acceleration over the step
                ap, va = (0.0, self._h2) if j == 1 else (-w, coast_var)
                vp = v0 + dt * ap
                qvv, qva, qaa = pvv + dt * dt * va, dt * va, va
            else:  # traction / braking: a random walk
                q = self._q2 * dt
                ap = a0
                vp = v0 + dt * a0
                qaa = paa + q
                qva = pva + dt * paa + 0.5 * dt * q
                qvv = pvv + 2.0 * dt * pva + dt * dt * paa + dt * dt * q / 3.0
            # update with the measured speed
            sv = qvv + r
            nu = z - vp
            kv, ka = qvv / sv, qva / sv
            an = ap + ka * nu
            paa_n = max(qaa - ka * qva, 1e-12)
            lik = math.exp(-0.5 * nu * nu / sv) / math.sqrt(_TWO_PI * sv)
            if j == 0 or j == 3:  # the sign of the effort a + r + g: positive in traction, negative in braking
                x = (an + w) / math.sqrt(paa_n)
                lik *= 0.5 * math.erfc(-x / SQRT2 if j == 0 else x / SQRT2)
            if like_power is not None:
                lik *= like_power[j]
            weights.append(cj * lik)
            out_x.append([vp + kv * nu, an, qvv - kv * qvv, qva - kv * qva, paa_n])
        total = weights[0] + weights[1] + weights[2] + weights[3]
        if not total > 0.0 or not math.isfinite(total):  # every model rejects the sample: start over from it
            self._mu = None
            return self.step(t, z, w, power)
        self._mu = [wt / total for wt in weights]
        self._x = out_x
        return most_probable(*weights)
