"""Rolling stock: the train file of INTERFACES.md, validated."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from . import physics
from .yamlcheck import Checker, load_yaml_mapping


@dataclass(frozen=True)
class Davis:
    """Davis running-resistance coefficients per unit effective mass."""

    r0: float  # N/kg
    r1: float  # N/(kg m/s)
    r2: float  # N/(kg (m/s)^2)

    def __call__(self, v_ms, tunnel_fraction=0.0, tunnel_factor: float = 0.0):
        return physics.davis(v_ms, self.r0, self.r1, self.r2, tunnel_fraction, tunnel_factor)

    def as_tuple(self) -> tuple[float, float, float]:
        return (self.r0, self.r1, self.r2)


@dataclass(frozen=True)
class TrainSpec:
    """A train type. Forces are per unit of effective mass gamma*m (N/kg), as the estimators use them."""

    name: str
    mass_t: float  # t, loaded mass
    rotating_mass_factor: float  # gamma, dimensionless (>= 1)
    length_m: float
    davis: Davis  # manufacturer values
    max_tractive_effort: float  # c0, N/kg
    max_tractive_power: float  # c2, W/kg
    max_brake_decel: float  # m/s^2 (service brake, the stop brake b_stop by default)
    transmission_efficiency: float = 0.85  # eta: wheel power = eta * pantograph power
    tunnel_factor: float = 0.0  # f_tun: r2 -> (1 + f_tun) r2 inside a tunnel
    max_speed_kmh: float = 160.0
    adhesive_mass_fraction: float = 0.5  # share of the mass on driven axles (adhesion limit)
    auxiliary_power_kw: float = 0.0  # hotel load drawn at the pantograph, kW
    source: str = ""  # file it was read from

    @property
    def mass_kg(self) -> float:
        return self.mass_t * 1000.0

    @property
    def effective_mass_kg(self) -> float:
        return self.mass_kg * self.rotating_mass_factor

    @property
    def transition_speed_ms(self) -> float:
        return physics.transition_speed(self.max_tractive_effort, self.max_tractive_power)

    def tractive_envelope(self, v_ms):
        """Maximum tractive effort at speed v, N/kg, with the adhesion cap."""
        envelope = physics.tractive_envelope(v_ms, self.max_tractive_effort, self.max_tractive_power)
        cap = physics.adhesion_limit(v_ms, self.adhesive_mass_fraction, self.rotating_mass_factor)
        return envelope if self.adhesive_mass_fraction <= 0 else np.minimum(envelope, cap)


TRAIN_KEYS = (
    "name",
    "mass_t",
    "rotating_mass_factor",
    "length_m",
    "davis",
    "max_tractive_effort",
    "max_tractive_power",
    "max_brake_decel",
    "transmission_efficiency",
    "tunnel_factor",
    "max_speed_kmh",
    "adhesive_mass_fraction",
    "auxiliary_power_kw",
)
"""The keys of a train file (../shared/INTERFACES.md); any other is refused with the nearest of these."""


def load_train(path: str | Path) -> TrainSpec:
    """Read and validate a train file; a problem raises ConfigError('<file>: <key>: <problem>').

    A ``.json`` file is read as a TTOBench train (``train_calib.ttobench``: kN to N/kg, assumptions printed once).
    """
    if Path(path).suffix.lower() == ".json":
        from .ttobench import load_ttobench_train

        return load_ttobench_train(path)
    return train_from_mapping(load_yaml_mapping(path, "train file"), path)


def train_from_mapping(data: dict, path: str | Path) -> TrainSpec:
    """Validate a train file's mapping (``path`` names it in errors)."""
    c = Checker(path)
    c.known_keys(data, TRAIN_KEYS)
    davis_map = c.get(data, "davis")
    if not isinstance(davis_map, dict):
        raise c.fail("davis", f"expected a mapping with r0, r1, r2, found {type(davis_map).__name__}")
    c.known_keys(davis_map, ("r0", "r1", "r2"), "davis.")
    davis = Davis(
        r0=c.number(davis_map, "r0", "davis.", low=0.0, high=0.2, unit="N/kg"),
        r1=c.number(davis_map, "r1", "davis.", low=0.0, high=0.01, unit="N/(kg m/s)"),
        r2=c.number(davis_map, "r2", "davis.", low=0.0, high=0.001, unit="N/(kg (m/s)^2)"),
    )
    return TrainSpec(
        name=c.string(data, "name"),
        mass_t=c.number(data, "mass_t", low=1.0, high=30000.0, unit="t"),
        rotating_mass_factor=c.number(data, "rotating_mass_factor", low=1.0, high=1.6),
        length_m=c.number(data, "length_m", low=5.0, high=4000.0, unit="m"),
        davis=davis,
        max_tractive_effort=c.number(data, "max_tractive_effort", low=0.0, high=5.0, low_open=True, unit="N/kg"),
        max_tractive_power=c.number(data, "max_tractive_power", low=0.0, high=200.0, low_open=True, unit="W/kg"),
        max_brake_decel=c.number(data, "max_brake_decel", low=0.0, high=3.0, low_open=True, unit="m/s^2"),
        transmission_efficiency=c.number(
            data, "transmission_efficiency", low=0.0, high=1.0, low_open=True, required=False, default=0.85
        ),
        tunnel_factor=c.number(data, "tunnel_factor", low=0.0, high=5.0, required=False, default=0.0),
        max_speed_kmh=c.number(
            data, "max_speed_kmh", low=0.0, high=500.0, low_open=True, required=False, default=160.0
        ),
        adhesive_mass_fraction=c.number(data, "adhesive_mass_fraction", low=0.0, high=1.0, required=False, default=0.5),
        auxiliary_power_kw=c.number(data, "auxiliary_power_kw", low=0.0, high=10000.0, required=False, default=0.0),
        source=str(path),
    )
