"""Driving regime per sample (Cunillera et al. 2022, Section 3.2); constants as DrivingRegime.msg.

Two methods (``RegimeConfig.method``). Both are causal -- a sample's regime depends on that sample and
earlier ones only, is returned at once and is never revised -- and total: any input, NaN included, gives a
regime.

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

_SQRT2 = math.sqrt(2.0)
_LOG_SQRT_2PI = 0.5 * math.log(2.0 * math.pi)
_START_PRIOR = (0.85, 0.05, 0.05, 0.05)
"""Probabilities of (TRACTION, CRUISING, COASTING, BRAKING) before the first moving sample: departing."""
_DEFAULT_W = 0.02
"""r + g (N/kg) assumed before any computed-effort sample was seen (r0 of an EMU on level track)."""


def _rule(e: float, a: float, cfg: RegimeConfig) -> int:
    """The paper's rule on effort e and acceleration a (not NaN)."""
    tol_a = cfg.cruise_tolerance
    if abs(e) <= cfg.effort_tolerance and not (cfg.hold_detection and abs(a) < abs(e) and abs(a) <= tol_a):
        return COASTING
    if abs(a) <= tol_a:
        return CRUISING
    return TRACTION if e > 0.0 else BRAKING


def _most_probable(p0: float, p1: float, p2: float, p3: float) -> int:
    """The regime code of the largest of the weights of (TRACTION, CRUISING, COASTING, BRAKING); the first of equal
    maxima."""
    best, top = TRACTION, p0
    if p1 > top:
        best, top = CRUISING, p1
    if p2 > top:
        best, top = COASTING, p2
    if p3 > top:
        best = BRAKING
    return best


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
        "_hmm",
        "_known_log",
        "_lagged",
        "_lam",
        "_log_norm",
        "_log_stay",
        "_log_switch",
        "_prob",
        "_revised",
        "_sigma",
        "_t_const",
        "_t_min",
        "_v",
        "_vc2",
        "_w_last",
        "_w_rel",
        "_w_speed",
        "config",
    )

    def __init__(self, config: RegimeConfig | None = None) -> None:
        self.config = cfg = config if config is not None else RegimeConfig()
        self._hmm = cfg.method == "hmm"
        self._v = cfg.standstill_speed
        s = self._sigma = cfg.accel_noise_std
        self._log_norm = -_LOG_SQRT_2PI - math.log(s)
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
        self._w_last = math.nan
        self._w_speed = math.nan

    @property
    def revised_previous(self) -> int | None:
        """hmm with ``lag_samples`` 1: the regime of the previous moving sample given the last sample too (one step
        of the backward recursion: a fixed-lag smoother of one sample); None when the last call did not inform it
        (the last sample was not filtered -- standing, NaN, the rule -- or started a new sequence)."""
        return self._revised

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
    ) -> int:
        """Regime of the next sample of the run.

        effort: applied effort u (N/kg); acceleration: published acceleration (m/s^2); speed: filtered speed
        (m/s), optional. Optional for ``hmm`` (ResistanceEstimate fields): ``effort_known`` and
        ``opposing_force`` = resistance + track_force (N/kg), the force the effort works against.
        """
        self._revised = None
        e = _float(effort)
        a = _float(acceleration)
        if e is None or a is None or math.isnan(e) or math.isnan(a):
            return UNKNOWN
        v = math.nan
        if speed is not None:
            v = _float(speed)
            if v is None:
                return UNKNOWN
            if not v >= self._v:  # NaN too
                self._prob = None
                return UNKNOWN
        if not self._hmm or not (math.isfinite(e) and math.isfinite(a)):
            return _rule(e, a, self.config)
        w_given = _float(opposing_force) if opposing_force is not None else None
        if w_given is not None and not math.isfinite(w_given):
            w_given = None
        return self._filter(e, a, v, effort_known, w_given)

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
        l_t = self._t_const - lam * yt + _log_erfc((lam * s * s - yt) / (_SQRT2 * s))
        z = y / s
        l_h = self._log_norm - 0.5 * z * z
        sc = math.hypot(s, self._w_rel * w)
        z = (y + w) / sc
        l_c = -_LOG_SQRT_2PI - math.log(sc) - 0.5 * z * z
        lo, hi = self._b_lo, self._b_hi
        mass = 0.5 * (math.erf((hi - y) / (_SQRT2 * s)) - math.erf((lo - y) / (_SQRT2 * s)))
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
            prior = _START_PRIOR
        else:
            stay, switch = math.exp(self._log_stay), math.exp(self._log_switch)
            prior = tuple(p * (stay - switch) + switch for p in prev)
        top = max(logs)
        likelihood = [math.exp(lg - top) for lg in logs]
        post = [p * lk for p, lk in zip(prior, likelihood)]
        if prev is not None and self._lagged:  # the previous sample given this one: p_prev * (A l), A = keep I + switch
            common = switch * sum(likelihood)
            keep = stay - switch
            self._revised = _most_probable(*(p * (keep * lk + common) for p, lk in zip(prev, likelihood)))
        total = post[0] + post[1] + post[2] + post[3]
        self._prob = prob = [p / total for p in post]
        return _most_probable(*prob)

    def _carried_w(self, v: float) -> float:
        """r + g where the effort is known: the last computed-effort value, scaled with speed."""
        w = self._w_last
        if math.isnan(w):
            return _DEFAULT_W
        v0 = self._w_speed
        if math.isfinite(v) and math.isfinite(v0):
            w *= (self._vc2 + v * v) / (self._vc2 + v0 * v0)
        return w


def classify_regimes(
    effort,
    acceleration,
    config: RegimeConfig | None = None,
    speed=None,
    *,
    effort_known=None,
    opposing_force=None,
    smooth: bool = False,
) -> np.ndarray:
    """``RegimeClassifier.classify`` over a sequence in time order: uint8 array of the broadcast shape.

    ``rule``: vectorised. ``hmm``: the classifier's filter over the (flattened) samples in order, as the node
    runs it (:mod:`.regimes_batch`: the same operations arranged for numpy), so the result is the node's
    message for message. ``smooth`` (``hmm`` only; offline): each sample's regime given the whole run
    (forward-backward) -- more often right (docs/estimator.md), never what the node publishes.
    """
    cfg = config if config is not None else RegimeConfig()
    e, a = np.broadcast_arrays(np.asarray(effort, dtype=float), np.asarray(acceleration, dtype=float))
    if cfg.method == "hmm":
        from .regimes_batch import classify_hmm

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
        )
        return out.reshape(e.shape)
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
