"""Driving regime per sample (Cunillera et al. 2022, Section 3.2); constants as DrivingRegime.msg.

Three methods (``RegimeConfig.method``). All are causal -- a sample's regime depends on that sample and
earlier ones only, is returned at once and is never revised -- and total: any input, NaN included, gives a
regime.

``imm`` (default) -- the regime of each sample in the physical sense (issue 19 item 5): TRACTION where the
effort exceeds what holds the speed, COASTING where it is zero, BRAKING, and CRUISING where the speed is held.
An interacting multiple-model filter (IMM: Blom & Bar-Shalom) on the measured speeds, one Kalman filter of
(speed, acceleration) per regime:

    CRUISING   a = 0                   (std ``imm_hold_accel_std``)
    COASTING   a = -(r + g)            (std ``imm_coast_accel_std`` (+) ``resistance_rel_std`` x (r + g))
    TRACTION   a walks randomly        (``imm_accel_walk_std`` per second), effort a + r + g > 0
    BRAKING    a walks randomly,       effort a + r + g < 0

observed through the measured speed (std ``imm_speed_noise_std``); a change between samples dt apart has
probability 1 - exp(-dt / ``imm_mean_dwell``) (at most ``imm_switch_max``). The innovations of each model
weigh it against the others: the speeds themselves, not a window slope, so a change shows within a few
samples at 1 Hz and traction/coast cycles around a target speed come out as traction and coasting. Beside it
the classifier keeps the ``hmm`` below, whose label is the **phase** (:attr:`RegimeClassifier.phase`): the
paper's notion, where those cycles are cruising. With ``hmm`` or ``rule`` the phase is the regime.

``rule`` -- the paper's rule, per sample and stateless: |effort| <= effort_tolerance -> COASTING; above
-> TRACTION, below -> BRAKING; a TRACTION or BRAKING sample with |acceleration| <= cruise_tolerance ->
CRUISING. Option ``hold_detection``: an in-band sample with |acceleration| < |effort| (nearer a speed
hold than coasting) is CRUISING.

``hmm`` (default) -- the forward filter of a hidden Markov model over the four regimes, on the same
signals. Each regime predicts the net acceleration y from the force w = r + g the effort works against
(the estimator's resistance plus track force; on computed-effort samples w = effort - acceleration):

    CRUISING   y = 0                                          (a speed hold: effort = w)
    COASTING   y = -w                                         (effort = 0)
    TRACTION   y = a_min + x, x ~ exponential, mean a_mean    (effort > w)
    BRAKING    y = -b, b ~ uniform [b_min, b_max]             (effort < w - b_min)

observed with Gaussian noise of std ``accel_noise_std``; between two samples the regime changes with
probability ``switch_probability`` (to each other regime alike). The published regime is the most probable
one given this and all earlier samples since the train last stood. y is the published acceleration (the
estimator's window slope of the measured speed); on a sample whose effort is known and not zero (measured
traction power) it is effort - w, which is instantaneous where the acceleration lags its window -- when
``opposing_force`` (w) and ``effort_known`` are passed. An effort of exactly 0 that is known (confirmed
coasting, ``effort_mode: exploit_known``; without ``effort_known`` every exact 0 counts) multiplies the odds
of COASTING by ``known_coast_odds``; there effort - acceleration is not r + g, and without
``opposing_force`` w is carried over from the last computed-effort sample, scaled with speed as
r(v) ~ v_c^2 + v^2 (v_c = ``resistance_shape_speed``).

Against the paper's thresholds the filter (1) resolves the 1 km/h quantisation of 10 s samples by
accumulating evidence over samples, (2) tells a slow acceleration near the target speed (traction with
a < 0.06 m/s^2) from a hold, and a low-speed hold (effort r + g inside the coasting band) from coasting, by
the acceleration each regime predicts instead of fixed bands. Its detection latency is about one sample
for a weak change (e.g. hold -> coast at 40 km/h), none for a strong one (braking). Measured accuracies and
confusion matrices: docs/estimator.md.

When the speed is given, a sample slower than ``standstill_speed`` is UNKNOWN (standing is not a regime)
and the filter restarts: the next moving sample starts a new phase sequence (departure: TRACTION most
likely). NaN effort or acceleration -> UNKNOWN with the filter left as it is; infinite values -> the rule.
"""

from __future__ import annotations

import math

import numpy as np

from ..regime_codes import BRAKING, COASTING, CRUISING, REGIME_NAMES, TRACTION, UNKNOWN  # noqa: F401 (re-exported)
from .config import RegimeConfig
from .regime_model import (  # noqa: F401 (POWER_* re-exported)
    DEFAULT_W,
    LOG_SQRT_2PI,
    POWER_OFF,
    POWER_REGEN,
    POWER_TRACTION,
    SQRT2,
    START_PRIOR,
    most_probable,
    power_state,
    rule,
)
from .regimes_batch import classify_hmm


def _log_erfc(x: float) -> float:
    """log(erfc(x)); the asymptotic series where erfc underflows."""
    if x < 5.0:
        return math.log(math.erfc(x))
    x2 = x * x
    return -x2 - math.log(x * math.sqrt(math.pi)) + math.log1p(-0.5 / x2 + 0.75 / (x2 * x2))


def _float(x) -> float | None:
    try:
        return float(x)
    except (TypeError, ValueError):
        return None


class RegimeClassifier:
    """Regime of each sample of a run, in time order (``classify``); ``classify_regimes`` for whole arrays.

    With ``method: hmm`` the classifier carries the filter from call to call: feed it the samples in time
    order (the regime node does) and :meth:`reset` it (or make a new one) for an unrelated sequence; a
    standstill sample (speed given) restarts the filter by itself.
    """

    __slots__ = (
        "_b_hi",
        "_b_lo",
        "_g_prev",
        "_hmm",
        "_imm",
        "_known_log",
        "_lagged",
        "_lam",
        "_log_norm",
        "_log_stay",
        "_log_switch",
        "_phase",
        "_prob",
        "_revised",
        "_sigma",
        "_t_const",
        "_t_min",
        "_v",
        "_v_imm",
        "_vc2",
        "_w_last",
        "_w_rel",
        "_w_speed",
        "config",
    )

    def __init__(self, config: RegimeConfig | None = None) -> None:
        self.config = cfg = config if config is not None else RegimeConfig()
        self._hmm = cfg.method in ("hmm", "imm")  # imm: the hmm gives the phase
        self._imm = _Imm(cfg) if cfg.method == "imm" else None
        self._v = cfg.standstill_speed
        self._v_imm = cfg.imm_standstill_speed
        s = self._sigma = cfg.accel_noise_std
        self._log_norm = -LOG_SQRT_2PI - math.log(s)
        lam = self._lam = 1.0 / cfg.traction_accel_mean
        self._t_const = math.log(0.5 * lam) + 0.5 * lam * lam * s * s
        self._t_min = cfg.traction_accel_min
        self._b_lo, self._b_hi = -cfg.brake_decel_max, -cfg.brake_decel_min
        p = cfg.switch_probability
        self._log_stay = math.log(1.0 - p)
        self._log_switch = math.log(p / 3.0)
        self._vc2 = cfg.resistance_shape_speed**2
        self._known_log = math.log(cfg.known_coast_odds)
        self._w_rel = cfg.resistance_rel_std
        self._lagged = cfg.lag_samples > 0
        self.reset()

    def reset(self) -> None:
        """Forget the past samples (an unrelated sequence follows)."""
        self._prob: list[float] | None = None
        self._revised: int | None = None
        self._phase = UNKNOWN
        if self._imm is not None:
            self._imm.reset()
        self._w_last = math.nan
        self._w_speed = math.nan
        self._g_prev: tuple[float, float] | None = None  # (s m, Gamma J/kg) of the last sample that had them

    @property
    def revised_previous(self) -> int | None:
        """hmm with ``lag_samples`` 1: the regime of the previous moving sample given the last sample too (one step
        of the backward recursion: a fixed-lag smoother of one sample); None when the last call did not inform it
        (the last sample was not filtered -- standing, NaN, the rule -- or started a new sequence)."""
        return self._revised

    @property
    def phase(self) -> int:
        """The paper's phase of the last sample (Cunillera 3.2: the ``hmm`` label, or the rule's); with ``imm`` it
        may differ from the regime (traction/coast cycles around a target speed: regimes TRACTION and COASTING,
        phase CRUISING); with ``hmm`` and ``rule`` it is the regime."""
        return self._phase

    @property
    def imm_speed_noise(self) -> float | None:
        """imm: the speed sensor's noise std (m/s) in use: ``imm_speed_noise_std``, learned over the run."""
        return self._imm.speed_noise if self._imm is not None else None

    @property
    def imm_probabilities(self) -> tuple[float, ...] | None:
        """imm: probabilities of (TRACTION, CRUISING, COASTING, BRAKING) after the last sample it filtered."""
        return self._imm.probabilities() if self._imm is not None else None

    @property
    def probabilities(self) -> tuple[float, ...] | None:
        """hmm: filter probabilities of (TRACTION, CRUISING, COASTING, BRAKING) after the last moving sample."""
        return tuple(self._prob) if self._prob is not None else None

    def classify(
        self,
        effort: float,
        acceleration: float,
        speed: float | None = None,
        *,
        effort_known: bool | None = None,
        opposing_force: float | None = None,
        speed_measured: float | None = None,
        time: float | None = None,
        power: int | None = None,
        track_force: float | None = None,
        position: float | None = None,
        track_force_integral: float | None = None,
    ) -> int:
        """Regime of the next sample of the run; its phase is :attr:`phase` afterwards.

        effort: applied effort u (N/kg); acceleration: published acceleration (m/s^2); speed: filtered speed
        (m/s), optional. Optional for ``hmm`` (ResistanceEstimate fields): ``effort_known`` and
        ``opposing_force`` = resistance + track_force (N/kg), the force the effort works against. ``imm`` needs
        ``time`` (s, any origin) and the speed; it uses ``speed_measured`` (m/s; the filtered speed where it is
        None or NaN) and ``opposing_force`` (effort - acceleration without it). Without ``time`` or speed the
        ``imm`` regime is the phase. ``power``: the traction power's state (POWER_*; None: not measured).
        ``track_force`` (g at the sample, N/kg, part of ``opposing_force``), ``position`` (the measured s, m) and
        ``track_force_integral`` (Gamma(s), J/kg, the integral of g over s): the imm takes the mean g over the step
        since the previous sample that had them, (Gamma - Gamma_prev) / (s - s_prev), in place of g at the sample:
        at 10 s the train runs 200-300 m in a step, over gradients that may change every few tens of metres.
        """
        self._revised = None
        self._phase = UNKNOWN
        e = _float(effort)
        a = _float(acceleration)
        if e is None or a is None or math.isnan(e) or math.isnan(a):
            return UNKNOWN
        v = math.nan
        standing = False
        if speed is not None:
            v = _float(speed)
            if v is None:
                return UNKNOWN
            standing = not v >= self._v  # NaN too
            if standing:
                self._prob = None
                if self._imm is None:
                    return UNKNOWN
        if not self._hmm or not (math.isfinite(e) and math.isfinite(a)):
            self._phase = UNKNOWN if standing else rule(e, a, self.config)
            return self._phase
        w_given = _float(opposing_force) if opposing_force is not None else None
        if w_given is not None and not math.isfinite(w_given):
            w_given = None
        phase = UNKNOWN if standing else self._filter(e, a, v, effort_known, w_given)
        self._phase = phase
        if self._imm is None:
            return phase
        t = _float(time) if time is not None else None
        if t is None or not math.isfinite(t) or not math.isfinite(v):
            if standing:
                self._imm.restart()
            return phase
        z = _float(speed_measured) if speed_measured is not None else None
        if z is None or not math.isfinite(z):
            z = v
        if not z >= self._v_imm:  # standing for the imm: the measured speed (its first step, 1 km/h, is moving)
            self._imm.restart()
            return UNKNOWN
        w_imm = w_given if w_given is not None else e - a
        g_mean = self._step_track_force(position, track_force_integral)
        g_here = _float(track_force) if track_force is not None else None
        if g_mean is not None and g_here is not None and math.isfinite(g_here):
            w_imm += g_mean - g_here
        return self._imm.step(t, z, w_imm, power)

    def _step_track_force(self, position: float | None, integral: float | None) -> float | None:
        """The mean g (N/kg) over the step from the previous (s, Gamma) to this one; None where unknown or where the
        train moved less than ``_STEP_MIN_M`` or more than ``_STEP_MAX_M``."""
        s = _float(position) if position is not None else None
        gamma = _float(integral) if integral is not None else None
        if s is None or gamma is None or not (math.isfinite(s) and math.isfinite(gamma)):
            return None
        prev, self._g_prev = self._g_prev, (s, gamma)
        if prev is None:
            return None
        ds = s - prev[0]
        if not _STEP_MIN_M < abs(ds) < _STEP_MAX_M:
            return None
        return (gamma - prev[1]) / ds

    # -- the hidden Markov model ----------------------------------------------------------------------
    def _filter(self, e: float, a: float, v: float, known: bool | None, w_given: float | None) -> int:
        zero_known = e == 0.0 and known is not False
        computed = not zero_known and not known
        # w = r + g, and the observed net acceleration y
        if computed:
            self._w_last, self._w_speed = e - a, v
        if w_given is not None:
            w = w_given
        elif computed:
            w = e - a
        else:
            w = self._carried_w(v)
        y = e - w if (known and not zero_known and w_given is not None) else a
        # log densities of y under each regime
        s, lam = self._sigma, self._lam
        yt = y - self._t_min
        l_t = self._t_const - lam * yt + _log_erfc((lam * s * s - yt) / (SQRT2 * s))
        z = y / s
        l_h = self._log_norm - 0.5 * z * z
        sc = math.hypot(s, self._w_rel * w)
        z = (y + w) / sc
        l_c = -LOG_SQRT_2PI - math.log(sc) - 0.5 * z * z
        lo, hi = self._b_lo, self._b_hi
        mass = 0.5 * (math.erf((hi - y) / (SQRT2 * s)) - math.erf((lo - y) / (SQRT2 * s)))
        if mass > 1e-300:
            l_b = math.log(mass / (hi - lo))
        else:  # far outside [lo, hi]: the Gaussian tail of the nearer end
            z = min(abs(y - lo), abs(y - hi)) / s
            l_b = self._log_norm - 0.5 * z * z - math.log(hi - lo)
        if zero_known:
            l_c += self._known_log
        logs = (l_t, l_h, l_c, l_b)
        # predict and update
        prev = self._prob
        if prev is None:
            prior = START_PRIOR
        else:
            stay, switch = math.exp(self._log_stay), math.exp(self._log_switch)
            prior = tuple(p * (stay - switch) + switch for p in prev)
        top = max(logs)
        likelihood = [math.exp(lg - top) for lg in logs]
        post = [p * lk for p, lk in zip(prior, likelihood)]
        if prev is not None and self._lagged:  # the previous sample given this one: p_prev * (A l), A = keep I + switch
            common = switch * sum(likelihood)
            keep = stay - switch
            self._revised = most_probable(*(p * (keep * lk + common) for p, lk in zip(prev, likelihood)))
        total = post[0] + post[1] + post[2] + post[3]
        self._prob = prob = [p / total for p in post]
        return most_probable(*prob)

    def _carried_w(self, v: float) -> float:
        """r + g where the effort is known: the last computed-effort value, scaled with speed."""
        w = self._w_last
        if math.isnan(w):
            return DEFAULT_W
        v0 = self._w_speed
        if math.isfinite(v) and math.isfinite(v0):
            w *= (self._vc2 + v * v) / (self._vc2 + v0 * v0)
        return w


_IMM_START = (0.85, 0.05, 0.05, 0.05)
"""imm: probabilities of (TRACTION, CRUISING, COASTING, BRAKING) at the first moving sample: departing."""
_IMM_START_ACCEL = (0.3, 0.0, None, -0.3)
"""imm: the acceleration (m/s^2) each model starts from (None: the coasting -(r + g)); std _IMM_START_STD."""
_IMM_START_STD = 0.5
_STEP_MIN_M = 50.0
"""imm: the mean g over a step is taken over at least this distance (m); shorter (standing, noise): g at the sample."""
_STEP_MAX_M = 2000.0
"""imm: ... and at most this distance (m); longer (a gap, a jump to another run): g at the sample."""
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


class _Imm:
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


def classify_regimes(
    effort,
    acceleration,
    config: RegimeConfig | None = None,
    speed=None,
    *,
    effort_known=None,
    opposing_force=None,
    smooth: bool = False,
    speed_measured=None,
    time=None,
    phase: bool = False,
):
    """``RegimeClassifier.classify`` over a sequence in time order: uint8 array of the broadcast shape.

    ``rule``: vectorised. ``hmm``: the classifier's filter over the (flattened) samples in order, as the node
    runs it (:mod:`.regimes_batch`: the same operations arranged for numpy), so the result is the node's
    message for message. ``smooth`` (``hmm`` only; offline): each sample's regime given the whole run
    (forward-backward) -- more often right (docs/estimator.md), never what the node publishes. ``imm``: the
    classifier per sample in order (``time`` in s and ``speed`` needed, else the regime is the phase).
    ``phase``: return (regimes, phases), the phases as :attr:`RegimeClassifier.phase` (with ``hmm`` and ``rule``
    the regimes themselves).
    """
    cfg = config if config is not None else RegimeConfig()
    e, a = np.broadcast_arrays(np.asarray(effort, dtype=float), np.asarray(acceleration, dtype=float))
    if cfg.method == "imm":
        if smooth:
            raise ValueError("smooth: only with method hmm")
        out, phases = _classify_each(e, a, cfg, speed, effort_known, opposing_force, speed_measured, time)
        return (out, phases) if phase else out
    if cfg.method != "hmm":
        out = _classify_rule(e, a, cfg, speed, smooth)
        return (out, out.copy()) if phase else out

    def flat(x, dtype):
        return None if x is None else np.broadcast_to(np.asarray(x, dtype=dtype), e.shape).ravel()

    out = classify_hmm(
        e.ravel(),
        a.ravel(),
        RegimeClassifier(cfg),
        flat(speed, float),
        flat(effort_known, bool),
        flat(opposing_force, float),
        smooth,
    ).reshape(e.shape)
    return (out, out.copy()) if phase else out


def _classify_each(e, a, cfg, speed, effort_known, opposing_force, speed_measured, time):
    """``imm``: RegimeClassifier.classify per sample in order; (regimes, phases) of e's shape."""
    clf = RegimeClassifier(cfg)

    def flat(x, dtype):
        return [None] * e.size if x is None else np.broadcast_to(np.asarray(x, dtype=dtype), e.shape).ravel().tolist()

    columns = (flat(speed, float), flat(effort_known, bool), flat(opposing_force, float))
    columns += (flat(speed_measured, float), flat(time, float))
    out = np.empty(e.size, dtype=np.uint8)
    phases = np.empty(e.size, dtype=np.uint8)
    for i, (ei, ai, v, known, w, z, t) in enumerate(zip(e.ravel().tolist(), a.ravel().tolist(), *columns)):
        out[i] = clf.classify(ei, ai, v, effort_known=known, opposing_force=w, speed_measured=z, time=t)
        phases[i] = clf.phase
    return out.reshape(e.shape), phases.reshape(e.shape)


def _classify_rule(e, a, cfg, speed, smooth) -> np.ndarray:
    """``rule`` vectorised."""
    if smooth:
        raise ValueError("smooth: only with method hmm (the rule has no state to smooth)")
    coast = np.abs(e) <= cfg.effort_tolerance
    if cfg.hold_detection:
        coast &= ~((np.abs(a) < np.abs(e)) & (np.abs(a) <= cfg.cruise_tolerance))
    out = np.where(
        coast,
        COASTING,
        np.where(np.abs(a) <= cfg.cruise_tolerance, CRUISING, np.where(e > 0.0, TRACTION, BRAKING)),
    ).astype(np.uint8)
    bad = np.isnan(e) | np.isnan(a)
    if speed is not None:
        v = np.broadcast_to(np.asarray(speed, dtype=float), e.shape)
        bad = bad | ~(v >= cfg.standstill_speed)
    out[bad] = UNKNOWN
    return out
