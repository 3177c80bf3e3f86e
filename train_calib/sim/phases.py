"""Driver phases: the applied effort u (N/kg) and acceleration of each, and the regime label.

Each phase is smooth in (t, s, v) so the integrator never steps over a switch; every switch is an
event. The truth label of an instant is the phase the driver is in (what the driver does): traction
(ramps included, and traction that cannot quite hold the speed uphill), a speed hold (cruising, even
where the holding effort is a brake downhill), coasting (u = 0) or braking; standing is UNKNOWN.
Traction/coast cycles are labelled traction and coasting: they are what the train does, and the
recogniser's job (Cunillera et al. 2022, Fig. 6 shows its short traction and coasting phases along
the cycles). A row of the truth CSV carries the label at its stamp.

Final phases (the truth JSON summary, ``final_coast_s`` / ``final_brake_s``; Cunillera 3.3: "the
length of the final brake and of the previous coasting phase"): the final brake is the last braking
phase, the one that ends at the stop (a limit brake directly followed by the stop brake is one
phase); the final coast is the last coasting phase before it. Where the run ends brake -> hold at a
lower limit -> stop brake, the final brake is the stop brake and the final coast the coasting before
the first of those brakes. The feature extraction estimates the same quantities
(train_calib.estimation.features).
"""

from __future__ import annotations

from ..regime_codes import BRAKING, COASTING, CRUISING, REGIME_NAMES, TRACTION, UNKNOWN  # noqa: F401 (re-exported)
from .driver import BrakeSteps
from .model import MotionModel


class Phase:
    """Base: ``effort`` u and ``accel`` dv/dt at (t, s, v); ``ode`` if the motion depends on g(s)."""

    name = "phase"
    regime = UNKNOWN
    ode = True

    def __init__(self, model: MotionModel) -> None:
        self.model = model

    def effort(self, t: float, s: float, v: float) -> float:
        raise NotImplementedError

    def accel(self, t: float, s: float, v: float) -> float:
        return self.effort(t, s, v) - self.model.opposing(t, s, v)

    def rhs(self):
        accel = self.accel

        def f(t: float, s: float, v: float) -> tuple[float, float]:
            return v, accel(t, s, v)

        return f

    def describe(self) -> dict:
        return {"phase": self.name}


class Stand(Phase):
    """At a standstill with the brake applied (before departure, after arrival): u = 0, a = 0."""

    name = "stand"
    ode = False

    def effort(self, t, s, v):
        return 0.0

    def accel(self, t, s, v):
        return 0.0


class Ramp(Phase):
    """Traction ramped linearly from u0 (at t0) to fraction * envelope(v) over ramp_s seconds."""

    name = "ramp"
    regime = TRACTION

    def __init__(self, model, t0: float, ramp_s: float, u0: float, fraction: float, standing: bool = False) -> None:
        super().__init__(model)
        self.t0, self.ramp_s, self.u0, self.fraction = t0, ramp_s, u0, fraction
        self.standing = standing  # brakes still holding the train: a = 0

    def effort(self, t, s, v):
        k = (t - self.t0) / self.ramp_s
        k = 0.0 if k < 0.0 else (1.0 if k > 1.0 else k)
        return self.u0 + (self.fraction * self.model.envelope(v) - self.u0) * k

    def accel(self, t, s, v):
        if self.standing:
            return 0.0
        return self.effort(t, s, v) - self.model.opposing(t, s, v)

    def describe(self):
        return {"phase": self.name, "t0": self.t0, "ramp_s": self.ramp_s, "u0": self.u0, "fraction": self.fraction}


class Traction(Phase):
    """Traction at a fraction of the envelope."""

    name = "traction"
    regime = TRACTION

    def __init__(self, model, fraction: float) -> None:
        super().__init__(model)
        self.fraction = fraction

    def effort(self, t, s, v):
        return self.fraction * self.model.envelope(v)

    def describe(self):
        return {"phase": self.name, "fraction": self.fraction}


class Hold(Phase):
    """Speed holding: u = r + g, a = 0 (traction, or electric brake downhill)."""

    name = "hold"
    regime = CRUISING
    ode = False

    def effort(self, t, s, v):
        return self.model.opposing(t, s, v)

    def accel(self, t, s, v):
        return 0.0

    def rhs(self):
        def f(t, s, v):
            return v, 0.0

        return f


class Coast(Phase):
    """No effort: the resistance and the track decelerate the train."""

    name = "coast"
    regime = COASTING

    def __init__(self, model, final: bool) -> None:
        super().__init__(model)
        self.final = final

    def effort(self, t, s, v):
        return 0.0

    def accel(self, t, s, v):
        return -self.model.opposing(t, s, v)

    def describe(self):
        return {"phase": "coast_final" if self.final else "coast_cycle"}


class Brake(Phase):
    """Braking to a lower limit with the deceleration of the speed step (u = r + g - b(v))."""

    name = "brake"
    regime = BRAKING
    ode = False

    def __init__(self, model, steps: BrakeSteps, target: int, v_low: float) -> None:
        super().__init__(model)
        self.steps, self.target, self.v_low = steps, target, v_low

    def accel(self, t, s, v):
        return -self.steps.rate(v)

    def effort(self, t, s, v):
        return self.model.opposing(t, s, v) - self.steps.rate(v)

    def rhs(self):
        rate = self.steps.rate

        def f(t, s, v):
            return v, -rate(v)

        return f

    def describe(self):
        return {"phase": self.name, "target": self.target, "v_low": self.v_low}


class StopBrake(Phase):
    """Braking to the stop at s_stop with the constant deceleration that stops exactly there.

    The deceleration is set where the braking starts, v^2 / (2 (s_stop - s)): b_stop up to the
    event's location error, so the motion is an exact polynomial and the train stops at s_stop.
    """

    name = "stop_brake"
    regime = BRAKING
    ode = False

    def __init__(self, model, s_stop: float, b_stop: float, s: float, v: float) -> None:
        super().__init__(model)
        self.s_stop, self.b_stop = s_stop, b_stop
        d = s_stop - s
        self.b = v * v / (2.0 * d) if d > 1e-6 and v > 0.0 else b_stop

    def accel(self, t, s, v):
        return -self.b

    def effort(self, t, s, v):
        return self.model.opposing(t, s, v) - self.b

    def rhs(self):
        b = self.b

        def f(t, s, v):
            return v, -b

        return f

    def describe(self):
        return {"phase": self.name, "s_stop": self.s_stop, "b_stop": self.b_stop, "b": self.b}
