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
from .regime_imm import ImmFilter
from .regime_imm_smoother import ImmStep, OneSampleLate, imm_step_after, whole_run_labels
from .regime_model import (  # noqa: F401 (POWER_* re-exported)
    DEFAULT_W,
    LOG_SQRT_2PI,
    POWER_OFF,
    POWER_REGEN,
    POWER_TRACTION,
    SQRT2,
    START_PRIOR,
    log_erfc,
    most_probable,
    power_state,
    rule,
    rule_array,
    to_float,
    to_float_or_none,
)
from .regimes_batch import classify_hmm


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
        "_imm_input",
        "_imm_streak",
        "_keep",
        "_known_log",
        "_lagged",
        "_lam",
        "_lam_s2",
        "_log_norm",
        "_log_stay",
        "_log_switch",
        "_one_late",
        "_phase",
        "_prob",
        "_revise_phase",
        "_revised",
        "_revised_regime",
        "_sigma",
        "_sqrt2_s",
        "_switch",
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
        self._imm = ImmFilter(cfg) if cfg.method == "imm" else None
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
        self._switch = math.exp(self._log_switch)  # exp(log) as the filter has always computed them
        self._keep = math.exp(self._log_stay) - self._switch
        self._lam_s2 = lam * s * s
        self._sqrt2_s = SQRT2 * s
        self._vc2 = cfg.resistance_shape_speed**2
        self._known_log = math.log(cfg.known_coast_odds)
        self._w_rel = cfg.resistance_rel_std
        self._lagged = cfg.lag_samples > 0
        # the phase is revised only where it is the regime (hmm); beside the imm it stays the paper's causal phase,
        # which the features follow (validated causal: docs/estimator.md, Features)
        self._revise_phase = self._lagged and cfg.method == "hmm"
        self.reset()

    def reset(self) -> None:
        """Forget the past samples (an unrelated sequence follows)."""
        self._prob: list[float] | None = None
        self._revised: int | None = None
        self._revised_regime: int | None = None
        self._one_late = OneSampleLate(self.config)  # lag_samples 1, imm: the last imm steps
        self._phase = UNKNOWN
        if self._imm is not None:
            self._imm.reset()
        self._imm_streak = False
        self._w_last = math.nan
        self._w_speed = math.nan
        self._imm_input = (math.nan, math.nan)  # (measured speed m/s, r + g N/kg) of the imm's last sample
        self._g_prev: tuple[float, float] | None = None  # (s m, Gamma J/kg) of the last sample that had them

    @property
    def revised_previous(self) -> int | None:
        """``method: hmm`` with ``lag_samples`` 1: the regime of the previous moving sample given the last sample too
        (one step of the backward recursion: a fixed-lag smoother of one sample); None when the last call did not
        inform it (the last sample was not filtered -- standing, NaN, the rule -- or started a new sequence), and
        always beside the imm (its phase stays causal)."""
        return self._revised

    @property
    def revised_previous_regime(self) -> int | None:
        """imm with ``lag_samples`` 1: the regime of the previous sample given the last sample too: the imm's mode
        probabilities smoothed over one more step (:func:`.regime_imm_smoother.smoothed_labels` over the last imm
        steps), then the regime at its instant where a change fell inside one of the two long steps around it
        (:func:`.regime_imm_smoother.regime_at_changes`); None when the last call did not inform it (the last sample
        did not reach the imm, or the previous one was not the imm's last)."""
        return self._revised_regime

    def revised_labels(self, regime: int, phase: int) -> tuple[int, int]:
        """The previous sample's (regime, phase), published as (``regime``, ``phase``), given the last sample too
        (``lag_samples`` 1): :attr:`revised_previous` revises the phase, and with ``hmm`` the regime, which is the
        phase; :attr:`revised_previous_regime` the imm regime; each stays where the last call did not inform it."""
        revised = self._revised
        if revised is not None:
            phase = revised
            if self._imm is None:  # hmm: the regime is the phase
                regime = revised
        if self._revised_regime is not None:
            regime = self._revised_regime
        return regime, phase

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
        self._revised_regime = None
        if self._lagged:  # lag_samples 1: the imm history holds only an unbroken run of imm steps
            streak, self._imm_streak = self._imm_streak, False  # did the previous call reach the imm?
            if not streak:
                self._one_late.clear()
        self._phase = UNKNOWN
        # (each value as a float: ``to_float``, called only where it is not one already: this runs once a sample)
        e = effort if type(effort) is float else to_float(effort)
        a = acceleration if type(acceleration) is float else to_float(acceleration)
        if e is None or a is None or math.isnan(e) or math.isnan(a):
            return UNKNOWN
        v = math.nan
        standing = False
        if speed is not None:
            v = speed if type(speed) is float else to_float(speed)
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
        w_given = opposing_force if type(opposing_force) is float else to_float_or_none(opposing_force)
        if w_given is not None and not math.isfinite(w_given):
            w_given = None
        phase = UNKNOWN if standing else self._filter(e, a, v, effort_known, w_given)
        self._phase = phase
        if self._imm is None:
            return phase
        t = time if type(time) is float else to_float_or_none(time)
        if t is None or not math.isfinite(t) or not math.isfinite(v):
            if standing:
                self._imm.restart()
            return phase
        z = speed_measured if type(speed_measured) is float else to_float_or_none(speed_measured)
        if z is None or not math.isfinite(z):
            z = v
        if not z >= self._v_imm:  # standing for the imm: the measured speed (its first step, 1 km/h, is moving)
            self._imm.restart()
            return UNKNOWN
        w_imm = w_given if w_given is not None else e - a
        g_mean = self._step_track_force(position, track_force_integral)
        g_here = track_force if type(track_force) is float else to_float_or_none(track_force)
        if g_mean is not None and g_here is not None and math.isfinite(g_here):
            w_imm += g_mean - g_here
        self._imm_input = (z, w_imm)
        if not self._lagged:
            return self._imm.step(t, z, w_imm, power)
        return self._lagged_imm_step(t, z, w_imm, power)

    def _lagged_imm_step(self, t: float, z: float, w: float, power: int | None) -> int:
        """The imm's step with ``lag_samples`` 1: also the previous sample's regime at its instant
        (:attr:`revised_previous_regime`) from the last four imm steps."""
        imm = self._imm
        before = imm.probabilities(), imm.time
        regime = imm.step(t, z, w, power)
        self._imm_streak = True
        step = imm_step_after(imm, *before, z, w)
        if step is None:
            self._one_late.clear()
            return regime
        self._revised_regime = self._one_late.push(step)
        return regime

    def _step_track_force(self, position: float | None, integral: float | None) -> float | None:
        """The mean g (N/kg) over the step from the previous (s, Gamma) to this one; None where unknown or where the
        train moved less than ``_STEP_MIN_M`` or more than ``_STEP_MAX_M``."""
        s = position if type(position) is float else to_float_or_none(position)
        gamma = integral if type(integral) is float else to_float_or_none(integral)
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
        l_t = self._t_const - lam * yt + log_erfc((self._lam_s2 - yt) / self._sqrt2_s)
        z = y / s
        l_h = self._log_norm - 0.5 * z * z
        sc = math.hypot(s, self._w_rel * w)
        z = (y + w) / sc
        l_c = _MINUS_LOG_SQRT_2PI - math.log(sc) - 0.5 * z * z
        l_b = self._log_brake(y)
        if zero_known:
            l_c += self._known_log
        return self._forward(l_t, l_h, l_c, l_b)

    def _log_brake(self, y: float) -> float:
        """log density of the net acceleration y (m/s^2) under BRAKING: uniform on [lo, hi] plus the noise."""
        lo, hi, s2 = self._b_lo, self._b_hi, self._sqrt2_s
        mass = 0.5 * (math.erf((hi - y) / s2) - math.erf((lo - y) / s2))
        if mass > 1e-300:
            return math.log(mass / (hi - lo))
        z = min(abs(y - lo), abs(y - hi)) / self._sigma  # far outside [lo, hi]: the Gaussian tail of the nearer end
        return self._log_norm - 0.5 * z * z - math.log(hi - lo)

    def _forward(self, l_t: float, l_h: float, l_c: float, l_b: float) -> int:
        """One step of the forward filter with the log likelihoods of (TRACTION, CRUISING, COASTING, BRAKING): the
        most probable regime; the probabilities in ``_prob`` (and ``_revised`` with ``lag_samples``)."""
        prev = self._prob
        top = max(l_t, l_h, l_c, l_b)
        k0, k1, k2, k3 = math.exp(l_t - top), math.exp(l_h - top), math.exp(l_c - top), math.exp(l_b - top)
        if prev is None:
            p0, p1, p2, p3 = START_PRIOR
        else:
            keep, switch = self._keep, self._switch  # P(i -> j) = keep [i == j] + switch
            q0, q1, q2, q3 = prev
            p0, p1, p2, p3 = q0 * keep + switch, q1 * keep + switch, q2 * keep + switch, q3 * keep + switch
            if self._revise_phase:  # the previous sample given this one: p_prev * (A l), A = keep I + switch
                common = switch * sum((k0, k1, k2, k3))
                self._revised = most_probable(*(p * (keep * lk + common) for p, lk in zip(prev, (k0, k1, k2, k3))))
        p0, p1, p2, p3 = p0 * k0, p1 * k1, p2 * k2, p3 * k3
        total = p0 + p1 + p2 + p3
        p0, p1, p2, p3 = p0 / total, p1 / total, p2 / total, p3 / total
        self._prob = [p0, p1, p2, p3]
        return most_probable(p0, p1, p2, p3)

    def _carried_w(self, v: float) -> float:
        """r + g where the effort is known: the last computed-effort value, scaled with speed."""
        w = self._w_last
        if math.isnan(w):
            return DEFAULT_W
        v0 = self._w_speed
        if math.isfinite(v) and math.isfinite(v0):
            w *= (self._vc2 + v * v) / (self._vc2 + v0 * v0)
        return w


_MINUS_LOG_SQRT_2PI = -LOG_SQRT_2PI
_STEP_MIN_M = 50.0
"""imm: the mean g over a step is taken over at least this distance (m); shorter (standing, noise): g at the sample."""
_STEP_MAX_M = 2000.0
"""imm: ... and at most this distance (m); longer (a gap, a jump to another run): g at the sample."""


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
    power=None,
    track_force=None,
    position=None,
    track_force_integral=None,
):
    """``RegimeClassifier.classify`` over a sequence in time order: uint8 array of the broadcast shape.

    ``rule``: vectorised. ``hmm``: the classifier's filter over the (flattened) samples in order, as the node
    runs it (:mod:`.regimes_batch`: the same operations arranged for numpy), so the result is the node's
    message for message. ``smooth`` (``hmm`` and ``imm``; offline): each sample's regime given the whole run
    (forward-backward; with ``imm`` on the imm's own mode probabilities, :mod:`.regime_imm_smoother`) -- more often
    right (docs/estimator.md), never what the node publishes. ``imm``: the
    classifier per sample in order (``time`` in s and ``speed`` needed, else the regime is the phase), with the
    optional per-sample ``power`` (POWER_*; None or negative: not measured), ``track_force``, ``position`` and
    ``track_force_integral`` as ``classify`` takes them (the pipeline's labels sample for sample).
    ``phase``: return (regimes, phases), the phases as :attr:`RegimeClassifier.phase` (with ``hmm`` and ``rule``
    the regimes themselves). ``lag_samples`` 1 (the default; ``hmm`` and ``imm``, not ``smooth``): each sample's
    labels as regime_node publishes them one sample late, revised with the next sample
    (:attr:`RegimeClassifier.revised_previous`, :attr:`RegimeClassifier.revised_previous_regime`).
    """
    cfg = config if config is not None else RegimeConfig()
    e, a = np.broadcast_arrays(np.asarray(effort, dtype=float), np.asarray(acceleration, dtype=float))
    if cfg.method == "imm" or (cfg.method == "hmm" and cfg.lag_samples > 0 and not smooth):
        extra = (power, track_force, position, track_force_integral)
        out, phases = _classify_each(e, a, cfg, speed, effort_known, opposing_force, speed_measured, time, extra,
                                     smooth)  # fmt: skip
        return (out, phases) if phase else out
    if cfg.method != "hmm":
        out = rule_array(e, a, cfg, speed, smooth)
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


def _classify_each(e, a, cfg, speed, effort_known, opposing_force, speed_measured, time, extra=(None,) * 4,
                   smooth=False):  # fmt: skip
    """``imm``: RegimeClassifier.classify per sample in order; (regimes, phases) of e's shape. ``extra``: power
    (POWER_*; None or a negative value: not measured), track_force, position, track_force_integral, or None each.
    ``smooth``: the regimes the imm gave are replaced by the whole-run ones (:mod:`.regime_imm_smoother`); else,
    with ``lag_samples`` 1, each sample's labels revised with the next one as ``pipeline.RegimeStream`` does.
    ``hmm`` (with ``lag_samples`` 1) too: the regime is then the phase."""
    clf = RegimeClassifier(cfg)
    lagged = cfg.lag_samples > 0 and not smooth
    imm = clf._imm
    steps: list[ImmStep] = []
    stepped: list[int] = []

    def flat(x, dtype):
        return [None] * e.size if x is None else np.broadcast_to(np.asarray(x, dtype=dtype), e.shape).ravel().tolist()

    power, track_force, position, integral = extra
    if power is not None:
        given = np.broadcast_to(np.asarray(power, dtype=object), e.shape).ravel().tolist()
        power = [None if p is None or p < 0 else int(p) for p in given]
    columns = (flat(speed, float), flat(effort_known, bool), flat(opposing_force, float))
    columns += (flat(speed_measured, float), flat(time, float), power or [None] * e.size)
    columns += (flat(track_force, float), flat(position, float), flat(integral, float))
    out = np.empty(e.size, dtype=np.uint8)
    phases = np.empty(e.size, dtype=np.uint8)
    rows = zip(e.ravel().tolist(), a.ravel().tolist(), *columns)
    for i, (ei, ai, v, known, w, z, t, pw, g, s, gam) in enumerate(rows):
        before = (imm.probabilities(), imm.time) if smooth else None
        out[i] = clf.classify(ei, ai, v, effort_known=known, opposing_force=w, speed_measured=z, time=t, power=pw,
                              track_force=g, position=s, track_force_integral=gam)  # fmt: skip
        phases[i] = clf.phase
        if lagged and i > 0:
            out[i - 1], phases[i - 1] = clf.revised_labels(int(out[i - 1]), int(phases[i - 1]))
        if before is not None:
            step = imm_step_after(imm, *before, *clf._imm_input)
            if step is not None:
                steps.append(step)
                stepped.append(i)
    if steps:
        out[stepped] = whole_run_labels(steps, cfg.imm_mean_dwell, cfg.imm_switch_max, cfg.imm_speed_noise_std)
    return out.reshape(e.shape), phases.reshape(e.shape)
