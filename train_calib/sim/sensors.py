"""Sensor models: GNSS fixes, quantised speed and pantograph power sampled from the true run.

- GNSS (``/gnss/fix``): the track point under the head plus horizontal noise, sigma 4 m per axis by
  default (Cunillera et al. 2022, 4.2), white or first-order Gauss-Markov; no fix (status -1,
  NaN position) while the head is in a tunnel and at random dropouts.
- Speed (``/train/speed``): true speed plus noise, rounded to 1 km/h ("measured in km/h with an
  accuracy of 1 km/h", Cunillera 4.1); exactly 0 at a standstill.
- Power (``/train/traction_power``): pantograph power at 1 Hz (De Martinis & Corman 2019, 4): traction
  draws u v (gamma m) / eta; electric braking returns eta * (electric share of the brake power),
  capped at the traction power rating and fading out below a speed; plus the hotel load; the net
  is reported as consumed or regenerated.

Each stream has its own period and start offset (GNSS and speed are not synchronised).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..params import ParamSet, param
from ..physics import KMH


@dataclass(frozen=True)
class SensorParams(ParamSet):
    """What is recorded and how badly. Offsets < 0 are drawn uniformly in [0, period) per run."""

    gnss_period_s: float = param(10.0, "GNSS fix period", unit="s", low=0.01, high=600.0)
    gnss_noise_m: float = param(
        4.0, "GNSS horizontal noise, standard deviation per axis", unit="m", low=0.0, high=1000.0
    )
    gnss_correlation_s: float = param(0.0, "GNSS error correlation time (Gauss-Markov); 0 = white", unit="s", low=0.0)
    gnss_offset_s: float = param(-1.0, "time of the first fix after the recording start; < 0 = random", unit="s")
    gnss_dropout: float = param(0.0, "probability that a fix is missing (status NO_FIX)", low=0.0, high=1.0)
    gnss_tunnel_outage: bool = param(True, "no fix while the head is inside a tunnel")
    speed_period_s: float = param(10.0, "speed sample period", unit="s", low=0.01, high=600.0)
    speed_noise_kmh: float = param(0.5, "speed noise before quantisation, standard deviation", unit="km/h", low=0.0)
    speed_quantum_kmh: float = param(1.0, "speed resolution (rounding); 0 = none", unit="km/h", low=0.0, high=10.0)
    speed_offset_s: float = param(-1.0, "time of the first speed sample; < 0 = random", unit="s")
    speed_dropout: float = param(0.0, "probability that a speed sample is missing", low=0.0, high=1.0)
    power_period_s: float = param(0.0, "pantograph power period; 0 = no power topic", unit="s", low=0.0, high=600.0)
    power_offset_s: float = param(-1.0, "time of the first power sample; < 0 = random", unit="s")
    power_efficiency: float = param(0.0, "transmission efficiency eta; 0 = the train file's value", low=0.0, high=1.0)
    power_noise: float = param(0.01, "power noise, relative standard deviation", low=0.0, high=1.0)
    power_dropout: float = param(0.0, "probability that a power sample is missing", low=0.0, high=1.0)
    electric_brake_fraction: float = param(
        0.8, "share of the brake effort that is electric (regenerating)", low=0.0, high=1.0
    )
    electric_brake_min_kmh: float = param(
        10.0, "the electric brake fades out linearly below this speed", unit="km/h", low=0.0
    )
    pre_roll_s: float = param(20.0, "recording at the standstill before departure", unit="s", low=0.0, high=3600.0)
    post_roll_s: float = param(20.0, "recording at the standstill after arrival", unit="s", low=0.0, high=3600.0)

    @classmethod
    def paper_10s(cls, **changes) -> SensorParams:
        """Cunillera et al. (2022): GNSS and speed every 10 s, 4 m, 1 km/h."""
        return cls(**changes)

    @classmethod
    def paper_1hz_power(cls, **changes) -> SensorParams:
        """De Martinis & Corman (2019): time, speed, GPS and pantograph power at 1 Hz."""
        values = dict(gnss_period_s=1.0, speed_period_s=1.0, power_period_s=1.0)
        values.update(changes)
        return cls(**values)


def sample_times_ns(
    start_ns: int, end_ns: int, period_s: float, offset_s: float, rng: np.random.Generator
) -> np.ndarray:
    """Stamps start + offset + k * period within [start, end] (ns); a negative offset is drawn."""
    period_ns = round(period_s * 1e9)
    offset = rng.uniform(0.0, period_s) if offset_s < 0 else offset_s
    first = start_ns + round(offset * 1e9)
    if first > end_ns:
        return np.zeros(0, dtype=np.int64)
    n = (end_ns - first) // period_ns + 1
    return first + np.arange(n, dtype=np.int64) * period_ns


def gnss_errors(t_s: np.ndarray, sigma: float, tau: float, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """East and north errors (m): white, or first-order Gauss-Markov with time constant tau."""
    n = t_s.size
    white = rng.standard_normal((2, n)) * sigma
    if tau <= 0.0 or n == 0:
        return white[0], white[1]
    out = np.empty((2, n))
    out[:, 0] = white[:, 0]
    phi = np.exp(-np.diff(t_s) / tau)
    scale = np.sqrt(1.0 - phi * phi)
    for i in range(1, n):
        out[:, i] = phi[i - 1] * out[:, i - 1] + scale[i - 1] * white[:, i]
    return out[0], out[1]


def quantise_speed(v_ms: np.ndarray, noise_kmh: float, quantum_kmh: float, rng: np.random.Generator) -> np.ndarray:
    """Measured speed (m/s): noise, then rounding to the quantum (km/h); 0 at a standstill, never < 0."""
    kmh = v_ms / KMH + rng.standard_normal(v_ms.shape) * noise_kmh
    if quantum_kmh > 0:
        kmh = np.round(kmh / quantum_kmh) * quantum_kmh
    kmh = np.maximum(kmh, 0.0)
    return np.where(v_ms > 0.0, kmh * KMH, 0.0)


def pantograph_power(
    u: np.ndarray,
    v: np.ndarray,
    *,
    effective_mass_kg: float,
    efficiency: float,
    max_power_w: float,
    electric_brake_fraction: float,
    electric_brake_min_ms: float,
    auxiliary_w: float = 0.0,
) -> tuple[np.ndarray, np.ndarray]:
    """(consumed, regenerated) pantograph power (W, both >= 0) for effort u (N/kg) at speed v (m/s)."""
    wheel = u * v * effective_mass_kg
    traction = np.where(u > 0.0, wheel / efficiency, 0.0)
    fade = np.clip(v / electric_brake_min_ms, 0.0, 1.0) if electric_brake_min_ms > 0 else np.ones_like(v)
    electric = np.minimum(np.where(u < 0.0, -wheel, 0.0) * electric_brake_fraction * fade, max_power_w)
    net = traction + auxiliary_w - efficiency * electric
    return np.maximum(net, 0.0), np.maximum(-net, 0.0)
