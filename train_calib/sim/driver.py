"""Driver parameters of a simulated run, and their per-run randomness as the papers' fleets show it.

Ranges (documented in docs/simulator.md):
- cruise speed theta * limit, theta 0.8-1.02: most runs at the limit, 12 % above it (Cunillera
  et al. 2022, Fig. 7 left), some at 80 % (Besinovic et al. 2013, Fig. 9b, Table 4);
- cruising style: holding the speed, or traction/coast cycles below the target (Cunillera Fig. 3: brief
  re-accelerations, coasting while above the target): coast from the target down by a band of 6-15 km/h
  (20-50 s of coasting at 140 km/h, longer at lower speed), then re-accelerate at 0.8-1.0 of the envelope
  and at least ``cycle_min_accel`` net (a re-acceleration that really accelerates);
- coasting before the final brake, 2.5-10 min on the 32 km corridor (Cunillera Fig. 7 centre);
- braking to lower limits with b_limit 0.24-0.9 m/s^2 (Besinovic Table 4), per ATB-EG speed step
  (>130, 130-80, 80-60, 60-40, 40-0 km/h), higher at lower speed, the steps above 80 km/h and
  those from 40 to 80 km/h alike (Cunillera Fig. 8); braking to the stop with b_stop;
- a gentle start (traction ramped up over some seconds) and gentle re-acceleration (Cunillera 4.4),
  traction at a fraction of the envelope (Besinovic Fig. 7a: not all runs use the maximum);
- optional head/tail wind: a slowly varying factor on r2 (Besinovic: wind is part of r2).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ..errors import ConfigError
from ..params import ParamSet, param
from ..physics import KMH
from ..train import TrainSpec
from .model import Wind

ATB_EG_STEPS_KMH = (130.0, 80.0, 60.0, 40.0)
"""Upper bounds of the lower ATB-EG speed steps: >130, 130-80, 80-60, 60-40, 40-0 km/h."""


@dataclass(frozen=True)
class DriverParams(ParamSet):
    """How one run is driven. Defaults: a calm driver holding the limit, no coasting."""

    theta_cruise: float = param(1.0, "cruise speed as a fraction of the static limit", low=0.3, high=1.2)
    cruise_style: str = param(
        "hold", "cruising: hold the speed, or traction/coast cycles below the target", choices=("hold", "cycles")
    )
    cycle_band_kmh: float = param(
        8.0, "cycles: coast from the target down by this much, then traction", unit="km/h", low=0.2, high=40.0
    )
    cycle_traction_fraction: float = param(0.9, "cycles: traction as a fraction of the envelope", low=0.05, high=1.2)
    cycle_min_accel: float = param(
        0.05,
        "cycles: the re-acceleration uses at least the fraction of the envelope that gives this net acceleration "
        "where it starts (capped at the full envelope)",
        unit="m/s^2",
        low=0.0,
        high=2.0,
    )
    traction_fraction: float = param(1.0, "traction as a fraction of the tractive envelope", low=0.05, high=1.2)
    start_ramp_s: float = param(0.0, "departure: time to ramp traction up from zero", unit="s", low=0.0, high=300.0)
    reaccel_ramp_s: float = param(0.0, "re-acceleration: time to ramp traction up", unit="s", low=0.0, high=300.0)
    coast_before_brake_s: float = param(
        0.0, "planned coasting before the final brake (0: none)", unit="s", low=0.0, high=7200.0
    )
    b_limit: tuple[float, ...] = param(
        [0.66] * 5,
        "deceleration braking to a lower limit, per speed step (highest step first)",
        unit="m/s^2",
        low=0.01,
        high=2.0,
    )
    brake_steps_kmh: tuple[float, ...] = param(
        list(ATB_EG_STEPS_KMH),
        "bounds between the speed steps of b_limit, decreasing",
        unit="km/h",
        low=0.0,
        high=600.0,
    )
    b_stop: float = param(0.66, "deceleration braking to the stop", unit="m/s^2", low=0.01, high=2.0)
    min_coast_speed_kmh: float = param(
        20.0, "coasting below this speed: traction again", unit="km/h", low=0.0, high=200.0
    )
    wind_r2: float = param(0.0, "head (+) / tail (-) wind: mean relative change of r2", low=-0.9, high=3.0)
    wind_amplitude: float = param(0.0, "amplitude of the slow variation of the wind factor", low=0.0, high=2.0)
    wind_period_s: float = param(900.0, "period of the wind variation", unit="s", low=1.0)
    wind_phase_rad: float = param(0.0, "phase of the wind variation", unit="rad")

    def validate(self, source: str = "DriverParams", prefix: str = "") -> None:
        if len(self.b_limit) != len(self.brake_steps_kmh) + 1:
            raise ConfigError(
                source,
                prefix + "b_limit",
                f"needs one value per speed step ({len(self.brake_steps_kmh) + 1}), found {len(self.b_limit)}",
            )
        steps = list(self.brake_steps_kmh)
        if any(b >= a for a, b in itertools.pairwise(steps)):
            raise ConfigError(source, prefix + "brake_steps_kmh", f"must be strictly decreasing, found {steps}")
        if self.wind_r2 - self.wind_amplitude <= -1.0:
            raise ConfigError(source, prefix + "wind_amplitude", "wind_r2 - wind_amplitude must stay above -1")

    # -- derived ------------------------------------------------------------------------------
    @property
    def wind(self) -> Wind:
        return Wind(self.wind_r2, self.wind_amplitude, self.wind_period_s, self.wind_phase_rad)

    def brake_steps_ms(self) -> list[float]:
        return [b * KMH for b in self.brake_steps_kmh]

    # -- constructors -------------------------------------------------------------------------
    @classmethod
    def minimum_time(cls, theta_cruise: float = 1.0, b_limit: float = 0.66, b_stop: float = 0.66) -> DriverParams:
        """Besinovic's running-time driver: full envelope, hold theta * limit, one b_limit, no coasting."""
        return cls(
            theta_cruise=theta_cruise,
            b_limit=(b_limit,) * (len(ATB_EG_STEPS_KMH) + 1),
            b_stop=b_stop,
            min_coast_speed_kmh=0.0,
        )

    @classmethod
    def sample(
        cls,
        rng: np.random.Generator,
        *,
        train: TrainSpec | None = None,
        coast_range_s: Sequence[float] = (150.0, 600.0),
        styles: Sequence[str] = ("hold", "cycles"),
        wind: bool = False,
    ) -> DriverParams:
        """One run's driver drawn from the ranges of the papers (see the module docstring).

        ``coast_range_s``: coasting before the final brake, uniform (2.5-10 min on the long corridor).
        The brake rates are capped at the train's ``max_brake_decel`` when a train is given.
        """
        cap = 0.9 if train is None else min(0.9, train.max_brake_decel)
        lo_b = min(0.24, cap)
        if rng.random() < 0.12:
            theta = rng.uniform(1.0, 1.02)
        else:
            theta = 1.0 - 0.2 * rng.beta(1.0, 3.0)
        style = str(styles[int(rng.integers(len(styles)))])
        b_high = rng.uniform(lo_b, min(0.55, cap))
        b_mid = b_high + rng.uniform(0.0, 0.15)
        b_low = b_mid + rng.uniform(0.0, 0.15)
        steps = [b_high, b_high, b_mid, b_mid, b_low]
        jitter = rng.normal(0.0, 0.02, size=5)
        b_limit = tuple(float(np.clip(b + j, lo_b, cap)) for b, j in zip(steps, jitter))
        b_stop = float(rng.uniform(min(0.35, cap), cap))
        coast = float(rng.uniform(float(coast_range_s[0]), float(coast_range_s[1])))
        values = dict(
            theta_cruise=float(theta),
            cruise_style=style,
            cycle_band_kmh=float(rng.uniform(6.0, 15.0)),
            cycle_traction_fraction=float(rng.uniform(0.8, 1.0)),
            traction_fraction=float(rng.uniform(0.75, 1.0)),
            start_ramp_s=float(rng.uniform(4.0, 20.0)),
            reaccel_ramp_s=float(rng.uniform(3.0, 15.0)),
            coast_before_brake_s=coast,
            b_limit=b_limit,
            b_stop=b_stop,
        )
        if wind:
            values.update(
                wind_r2=float(rng.uniform(-0.15, 0.15)),
                wind_amplitude=float(rng.uniform(0.0, 0.1)),
                wind_period_s=float(rng.uniform(300.0, 1800.0)),
                wind_phase_rad=float(rng.uniform(0.0, 2.0 * math.pi)),
            )
        return cls(**values)


class BrakeSteps:
    """Deceleration per speed step and braking distances through the steps (scalar, fast)."""

    def __init__(self, bounds_ms: Sequence[float], rates: Sequence[float]) -> None:
        # steps from the top: (low, high, b)
        highs = [math.inf, *bounds_ms]
        lows = [*bounds_ms, 0.0]
        self.steps = list(zip(lows, highs, rates))
        self.bounds = list(bounds_ms)

    def rate(self, v: float) -> float:
        for low, _high, b in self.steps:
            if v > low:
                return b
        return self.steps[-1][2]

    def distance(self, v: float, v_low: float) -> float:
        """Distance (m) to brake from v to v_low through the steps (0 if v <= v_low)."""
        if v <= v_low:
            return 0.0
        d = 0.0
        for low, high, b in self.steps:
            hi = v if v < high else high
            lo = v_low if v_low > low else low
            if hi > lo:
                d += (hi * hi - lo * lo) / (2.0 * b)
        return d

    def speed_at(self, distance: float, v_low: float) -> float:
        """Speed from which braking to v_low takes ``distance`` m (inverse of :meth:`distance`)."""
        v = v_low
        remaining = distance
        for low, high, b in reversed(self.steps):
            if high <= v:
                continue
            lo = max(v, low)
            full = (high * high - lo * lo) / (2.0 * b) if math.isfinite(high) else math.inf
            if remaining <= full:
                return math.sqrt(lo * lo + 2.0 * b * remaining)
            remaining -= full
            v = high
        return v
