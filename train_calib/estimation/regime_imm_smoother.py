"""Whole-run regimes of the ``imm`` filter (``classify_regimes(..., smooth=True)`` with ``method: imm``, offline).

The imm (:mod:`.regime_imm`) labels a sample from that sample and earlier ones. Over a recorded run the later
samples are known too, and they tell most of what one sample leaves open: a change inside a long step, a coast
whose first seconds look like a hold. This module runs the backward recursion of the forward-backward algorithm
on the mode probabilities the imm computed, within each sequence between restarts, and labels each sample with
the regime most probable given the whole sequence (the maximum of the posterior marginal, which maximises the
expected number of right labels).

The imm's step k gives the filtered mode probabilities mu_k = c_k * L_k / sum, where c_k = T_k^T mu_{k-1} is the
predicted one (T_k: stay on the diagonal, off = switch / 3 elsewhere, switch = min(switch_max, 1 - exp(-dt /
dwell))) and L_k the likelihood of the sample under each mode (innovation, effort sign, power state). L_k is
recovered up to a factor as mu_k / c_k, and the backward messages are

    b_K = 1,    b_{k-1} = T_k (L_k * b_k) = keep (L_k * b_k) + off sum(L_k * b_k),    keep = stay - off,

each normalised; the smoothed marginal is mu_k * b_k. This treats the modes as a hidden Markov chain whose
emissions are the imm's likelihoods (each computed with the mixed prior of the filter): the usual approximation
of an IMM smoother for the mode probabilities (Helmick, Blair & Hoffman 1995 give the one for the states).

At long steps (both sides of a sample at least ``LONG_STEP_S`` apart) a label names what explains a whole step,
while a sample's regime is the one at its own instant: where a change falls inside a step, that is the regime of
the step *after* the sample when the change came before it, of the step before otherwise.
:func:`regime_at_changes` decides that from the speeds (below). Measured against per-sample truth on the
validation family: docs/estimator.md, "Regimes".
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any, NamedTuple

from ..regime_codes import COASTING, CRUISING
from .regime_imm import ImmFilter, transition
from .regime_model import backward_message, most_probable

LONG_STEP_S = 5.0
"""Samples at least this far apart (s) on both sides get :func:`regime_at_changes`; at 1 Hz a step's speed change
is within the speed noise and the smoothed label stays."""
CHANGE_RESIDUAL_STDS = 2.5
"""regime_at_changes: a step is explained by one regime alone when its speed change is within this many standard
deviations (sqrt(2) x the speed noise) of what the regime predicts (chosen on the tune half: 1.7-3.3 alike)."""


class ImmStep(NamedTuple):
    """The imm's state after one sample it filtered: ``t`` s, ``probabilities`` of (TRACTION, CRUISING, COASTING,
    BRAKING), ``restarted`` where the sequence started over (first sample, after a standstill, time not
    increasing, or every mode rejecting the sample), and its inputs: the measured ``speed`` (m/s) and the
    ``opposing_force`` r + g over the step (N/kg) the imm took."""

    t: float
    probabilities: tuple[float, float, float, float]
    restarted: bool
    speed: float = math.nan
    opposing_force: float = math.nan


def smoothed_labels(steps: Sequence[ImmStep], mean_dwell: float, switch_max: float) -> list[int]:
    """The regime code of each step given the whole sequence it belongs to (module docstring)."""
    n = len(steps)
    labels = [0] * n
    b0 = b1 = b2 = b3 = 1.0
    for k in range(n - 1, -1, -1):
        f0, f1, f2, f3 = steps[k].probabilities
        if k + 1 < n and not steps[k + 1].restarted:  # the message from step k + 1 of the same sequence
            stay, off = transition(steps[k + 1].t - steps[k].t, mean_dwell, switch_max)
            b0, b1, b2, b3 = _backward(steps[k].probabilities, steps[k + 1].probabilities, (b0, b1, b2, b3), stay, off)
        else:  # the last step of a sequence
            b0 = b1 = b2 = b3 = 1.0
        labels[k] = most_probable(f0 * b0, f1 * b1, f2 * b2, f3 * b3)
    return labels


def _backward(
    before: tuple[float, ...], after: tuple[float, ...], b: tuple[float, float, float, float], stay: float, off: float
) -> tuple[float, float, float, float]:
    """One step of the backward recursion: the message to the step with filtered probabilities ``before`` from
    the next one (``after``, its message ``b``), with the transition (``stay``, ``off``) between them."""
    keep = stay - off
    f0, f1, f2, f3 = before
    m0, m1, m2, m3 = after
    # L_{k+1} = mu_{k+1} / c_{k+1}, c = off + keep mu_k (the probabilities sum to 1)
    c0, c1 = m0 / (off + keep * f0) * b[0], m1 / (off + keep * f1) * b[1]
    c2, c3 = m2 / (off + keep * f2) * b[2], m3 / (off + keep * f3) * b[3]
    return backward_message(c0, c1, c2, c3, keep, off)


def whole_run_labels(steps: Sequence[ImmStep], mean_dwell: float, switch_max: float, speed_noise: float) -> list[int]:
    """The whole run's regime of each step: :func:`smoothed_labels`, then :func:`regime_at_changes` where the
    smoothed label changes between two long steps. ``speed_noise``: std of a measured speed (m/s)."""
    labels = smoothed_labels(steps, mean_dwell, switch_max)
    return regime_at_changes(steps, labels, CHANGE_RESIDUAL_STDS * math.sqrt(2.0) * speed_noise)


def regime_at_changes(steps: Sequence[ImmStep], labels: Sequence[int], tolerance: float) -> list[int]:
    """The regime at the instant of sample k where the labels of its step (k-1 -> k) and of the next (k -> k+1)
    differ, a then b, both steps long (``LONG_STEP_S``): a if step k is explained by a alone, b if step k+1 is by b
    alone. A regime's acceleration over a step: COASTING -(r + g) of the step, CRUISING 0, TRACTION and BRAKING the
    speed slope of the neighbouring step (k-1 for a, k+2 for b) where that has the same label (else unknown); the
    residual is |speed change - acceleration x dt| (m/s). Both known: the smaller residual's side; one known: that
    side if its residual is within ``tolerance`` (m/s), the other else; neither: the label stays a."""
    out = list(labels)
    n = len(steps)
    for k in range(1, n - 1):
        a, b = labels[k], labels[k + 1]
        if a == b or steps[k].restarted or steps[k + 1].restarted:
            continue
        dt_a, dt_b = steps[k].t - steps[k - 1].t, steps[k + 1].t - steps[k].t
        if min(dt_a, dt_b) < LONG_STEP_S:
            continue
        accel_a = _acceleration(steps, labels, k, a, k - 1)
        accel_b = _acceleration(steps, labels, k + 1, b, k + 2)
        res_a = None if accel_a is None else abs(steps[k].speed - steps[k - 1].speed - accel_a * dt_a)
        res_b = None if accel_b is None else abs(steps[k + 1].speed - steps[k].speed - accel_b * dt_b)
        if res_a is not None and res_b is not None:
            out[k] = a if res_a <= res_b else b
        elif res_a is not None:
            out[k] = a if res_a <= tolerance else b
        elif res_b is not None:
            out[k] = b if res_b <= tolerance else a
    return out


def _acceleration(steps: Sequence[ImmStep], labels: Sequence[int], k: int, regime: int, neighbour: int) -> float | None:
    """Regime's acceleration (m/s^2) over step k (steps k-1 -> k): -(r + g), 0, or the slope of step ``neighbour``
    (``neighbour - 1 -> neighbour``) where it has the same label in the same sequence; None where unknown."""
    if regime == COASTING:
        return -steps[k].opposing_force if math.isfinite(steps[k].opposing_force) else None
    if regime == CRUISING:
        return 0.0
    if not (1 <= neighbour < len(steps)) or labels[neighbour] != regime or steps[neighbour].restarted:
        return None
    before, after = steps[neighbour - 1], steps[neighbour]
    return (after.speed - before.speed) / (after.t - before.t)


class OneSampleLate:
    """``lag_samples`` 1 on board: the regime of the sample before the last, given the last too. A fixed-lag
    smoother of one sample (the backward step of :func:`smoothed_labels` from the last imm step), then the regime
    at the sample's instant (:func:`regime_at_changes`) where both steps around it are long; over the last four imm
    steps of an unbroken sequence. ``config``: a RegimeConfig (imm_mean_dwell, imm_switch_max,
    imm_speed_noise_std)."""

    __slots__ = ("_dt", "_history", "_mean_dwell", "_switch_max", "_tolerance", "_transition")

    def __init__(self, config: Any) -> None:
        self._mean_dwell, self._switch_max = config.imm_mean_dwell, config.imm_switch_max
        self._tolerance = CHANGE_RESIDUAL_STDS * math.sqrt(2.0) * config.imm_speed_noise_std
        self._history: list[ImmStep] = []
        self._dt = math.nan  # the last step's dt (s) and its transition (stay, off), reused while dt repeats
        self._transition = (1.0, 0.0)

    def clear(self) -> None:
        """A sample that did not reach the imm: the next sequence starts over."""
        self._history.clear()

    def push(self, step: ImmStep) -> int | None:
        """Take the imm's latest step; the revised regime code of the one before it (None: there is none in this
        sequence)."""
        history = self._history
        if step.restarted:
            history.clear()
        history.append(step)
        del history[:-4]
        if len(history) < 2:
            return None
        before, last = history[-2], history[-1]
        if len(history) >= 3 and min(last.t - before.t, before.t - history[-3].t) >= LONG_STEP_S:
            labels = smoothed_labels(history, self._mean_dwell, self._switch_max)
            return regime_at_changes(history, labels, self._tolerance)[-2]
        # regime_at_changes would keep the label: smoothed_labels(history[-2:])[0], its transition reused
        dt = last.t - before.t
        if dt != self._dt:
            self._dt, self._transition = dt, transition(dt, self._mean_dwell, self._switch_max)
        b0, b1, b2, b3 = _backward(before.probabilities, last.probabilities, (1.0, 1.0, 1.0, 1.0), *self._transition)
        f0, f1, f2, f3 = before.probabilities
        return most_probable(f0 * b0, f1 * b1, f2 * b2, f3 * b3)


def imm_step_after(
    imm: ImmFilter, probabilities: tuple[float, ...] | None, time: float, speed: float, opposing_force: float
) -> ImmStep | None:
    """The imm's state after a sample, given its probabilities and time before it and the speed (m/s) and r + g
    (N/kg) it was given: None where the sample did not reach the imm (standing, NaN, no time or speed: its label is
    not the imm's)."""
    after = imm.probabilities()
    if after is None or (after == probabilities and imm.time == time):
        return None
    restarted = probabilities is None or not imm.time > time or ImmFilter.is_start(after)
    return ImmStep(imm.time, after, restarted, speed, opposing_force)  # type: ignore[arg-type]
