"""TTOBench (BSD 2-Clause) train and track JSON files, read into this package's units.

Trains: forces in kN (r0 kN, r1 kN/(km/h), r2 kN/(km/h)^2, traction force kN, power kW) become mass-specific values
per unit of **effective** mass gamma*m (N/kg, W/kg), as the train YAML holds them. What a file does not give is
assumed and listed in :attr:`TtoTrain.assumptions` (rotating mass factor, length, adhesion, efficiency, braking);
each can be overridden. Tracks: stops, speed limits (km/h) and gradients (per mille) by position (m), see
:func:`load_ttobench_profile`.
"""

from __future__ import annotations

import json
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from .errors import ConfigError
from .train import Davis, TrainSpec, train_from_mapping

COACH_LENGTH_M = 25.0  # assumed length per coach when a file gives only the number of coaches
DEFAULT_LENGTH_M = 100.0  # assumed train length without "num coaches"
DEFAULT_ROTATING_MASS_FACTOR = 1.06  # without "rho": a typical EMU value
DEFAULT_ADHESIVE_FRACTION = 0.5  # TTOBench gives no adhesion: share of the mass on driven axles
DEFAULT_EFFICIENCY = 0.85  # when "efficiency traction" is absent or a loss table
MAX_ASSUMED_BRAKE = 1.0  # m/s^2: cap of the braking rate derived from the braking forces

_FORCE = {"kN": 1000.0, "N": 1.0}
_MASS = {"kg": 1.0, "t": 1000.0}
_POWER = {"kW": 1000.0, "W": 1.0, "MW": 1.0e6}
_printed: set[str] = set()


def load_json(path: str | Path, what: str) -> dict[str, Any]:
    """A JSON file whose top level is an object; ConfigError naming the file otherwise."""
    path = Path(path)
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise ConfigError(str(path), "", f"{what} not found") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(str(path), "", f"cannot read {what}: {exc}") from None
    except json.JSONDecodeError as exc:
        raise ConfigError(str(path), "", f"invalid JSON at line {exc.lineno}, column {exc.colno}: {exc.msg}") from None
    if not isinstance(data, dict):
        raise ConfigError(str(path), "", f"expected a JSON object at the top level, found {type(data).__name__}")
    return data


def _quantity(
    path: Path, data: dict, key: str, units: dict[str, float] | None, *, required: bool = True
) -> float | None:
    """``{"unit": u, "value": x}`` in SI via ``units`` (None: dimensionless); ConfigError naming the key."""
    entry = data.get(key)
    if entry is None:
        if required:
            raise ConfigError(str(path), key, "missing required key")
        return None
    if not isinstance(entry, dict) or "value" not in entry:
        raise ConfigError(str(path), key, 'expected {"unit": ..., "value": ...}')
    value = entry["value"]
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ConfigError(str(path), f"{key}.value", f"expected a number, found {type(value).__name__}")
    if units is None:
        return float(value)
    unit = entry.get("unit")
    if unit not in units:
        raise ConfigError(str(path), f"{key}.unit", f"unit {unit!r} not understood (expected {', '.join(units)})")
    return float(value) * units[unit]


@dataclass
class TtoTrain:
    """A TTOBench train converted: the spec and the assumptions made (one line each)."""

    spec: TrainSpec
    assumptions: list[str] = field(default_factory=list)


def convert_train(
    path: str | Path,
    *,
    rotating_mass_factor: float | None = None,
    length_m: float | None = None,
    adhesive_mass_fraction: float | None = None,
    name: str | None = None,
) -> TtoTrain:
    """Read a TTOBench train JSON; keyword values override the file and the assumptions."""
    path = Path(path)
    data = load_json(path, "TTOBench train file")
    notes: list[str] = []
    mass_kg = _quantity(path, data, "mass", _MASS)
    assert mass_kg is not None
    if not 1000.0 <= mass_kg <= 3.0e7:
        raise ConfigError(str(path), "mass", f"{mass_kg:g} kg is out of range")
    rho = _quantity(path, data, "rho", {"%": 0.01, "-": 1.0}, required=False)
    if rotating_mass_factor is not None:
        gamma = rotating_mass_factor
        notes.append(f"rotating mass factor {gamma:g} (given)")
    elif rho is not None:
        gamma = 1.0 + rho
        notes.append(f"rotating mass factor {gamma:g} (from rho {rho * 100:g} %)")
    else:
        gamma = DEFAULT_ROTATING_MASS_FACTOR
        notes.append(f"rotating mass factor {gamma:g} assumed (the file has no rho)")
    coaches = _quantity(path, data, "num coaches", None, required=False)
    if length_m is not None:
        length = length_m
        notes.append(f"length {length:g} m (given)")
    elif coaches:
        length = COACH_LENGTH_M * coaches
        notes.append(f"length {length:g} m assumed ({coaches:g} coaches x {COACH_LENGTH_M:g} m)")
    else:
        length = DEFAULT_LENGTH_M
        notes.append(f"length {length:g} m assumed (the file has no length and no number of coaches)")
    adhesion = DEFAULT_ADHESIVE_FRACTION if adhesive_mass_fraction is None else adhesive_mass_fraction
    given = "given" if adhesive_mass_fraction is not None else "assumed: TTOBench gives no adhesion"
    notes.append(f"adhesive mass fraction {adhesion:g} ({given})")
    effective = mass_kg * gamma
    r0 = _quantity(path, data, "rolling resistance r0", _FORCE)
    r1 = _quantity(path, data, "rolling resistance r1", {"kN/(km/h)": 3600.0, "N/(km/h)": 3.6, "N/(m/s)": 1.0})
    r2 = _quantity(path, data, "rolling resistance r2", {"kN/(km/h)^2": 12960.0, "N/(km/h)^2": 12.96, "N/(m/s)^2": 1.0})
    force = _quantity(path, data, "max traction force", _FORCE)
    power = _quantity(path, data, "max traction power", _POWER)
    assert r0 is not None and r1 is not None and r2 is not None and force is not None and power is not None
    brake = _quantity(path, data, "max deceleration", {"m/s^2": 1.0}, required=False)
    if brake is None:
        forces = [
            _quantity(path, data, k, _FORCE, required=False) or 0.0
            for k in ("max reg braking force", "max pn braking force")
        ]
        brake = min(MAX_ASSUMED_BRAKE, sum(forces) / effective) if sum(forces) > 0 else MAX_ASSUMED_BRAKE
        notes.append(f"service brake {brake:.3g} m/s^2 assumed (braking forces / effective mass, at most 1)")
    efficiency = _efficiency(path, data, notes)
    speed = _quantity(path, data, "max speed", {"km/h": 1.0, "m/s": 3.6}, required=False) or 160.0
    meta = data.get("metadata") if isinstance(data.get("metadata"), dict) else {}
    spec = TrainSpec(
        name=name or str(meta.get("id") or path.stem),
        mass_t=mass_kg / 1000.0,
        rotating_mass_factor=gamma,
        length_m=length,
        davis=Davis(r0 / effective, r1 / effective, r2 / effective),
        max_tractive_effort=force / effective,
        max_tractive_power=power / effective,
        max_brake_decel=brake,
        transmission_efficiency=efficiency,
        max_speed_kmh=speed,
        adhesive_mass_fraction=adhesion,
        source=str(path),
    )
    return TtoTrain(spec, notes)


def _efficiency(path: Path, data: dict, notes: list[str]) -> float:
    entry = data.get("efficiency traction")
    if isinstance(entry, dict) and isinstance(entry.get("value"), (int, float)):
        value = float(entry["value"])
        value = value / 100.0 if value > 1.0 else value  # "%" files hold 0.9 as well as 70.0
        if not 0.0 < value <= 1.0:
            raise ConfigError(str(path), "efficiency traction.value", f"{entry['value']} is not an efficiency")
        return value
    why = "a loss table" if isinstance(entry, dict) else "absent"
    notes.append(f"transmission efficiency {DEFAULT_EFFICIENCY:g} assumed (efficiency traction is {why})")
    return DEFAULT_EFFICIENCY


def load_ttobench_train(path: str | Path) -> TrainSpec:
    """The train of a TTOBench JSON with the default assumptions, printed once per file to stderr."""
    converted = convert_train(path)
    spec = checked(converted)  # refused before anything is printed
    key = str(Path(path).resolve())
    if key not in _printed and converted.assumptions:
        _printed.add(key)
        print(f"{path}: TTOBench train: " + "; ".join(converted.assumptions)
              + " (override: train-calib convert-train)", file=sys.stderr)  # fmt: skip
    return spec


def train_mapping(spec: TrainSpec, digits: int = 17) -> dict[str, Any]:
    """The train file's mapping of a spec, numbers to ``digits`` significant digits."""

    def num(x: float) -> float:
        return float(f"{x:.{digits}g}")

    return {
        "name": spec.name,
        "mass_t": num(spec.mass_t),
        "rotating_mass_factor": num(spec.rotating_mass_factor),
        "length_m": num(spec.length_m),
        "davis": {"r0": num(spec.davis.r0), "r1": num(spec.davis.r1), "r2": num(spec.davis.r2)},
        "max_tractive_effort": num(spec.max_tractive_effort),
        "max_tractive_power": num(spec.max_tractive_power),
        "max_brake_decel": num(spec.max_brake_decel),
        "transmission_efficiency": num(spec.transmission_efficiency),
        "max_speed_kmh": num(spec.max_speed_kmh),
        "adhesive_mass_fraction": num(spec.adhesive_mass_fraction),
    }


def checked(train: TtoTrain) -> TrainSpec:
    """The converted spec through the train file's checks (ranges), so a JSON is refused as a YAML would be."""
    return train_from_mapping(train_mapping(train.spec), train.spec.source)


def train_yaml_text(train: TtoTrain, source: str) -> str:
    """The train file (YAML) of a converted train, with its source and assumptions as comments."""
    import yaml

    head = [f"# converted from the TTOBench train {source} (BSD 2-Clause) by train-calib convert-train",
            "# forces per unit effective mass gamma*m: N/kg, W/kg"]  # fmt: skip
    head += [f"# assumption: {a}" for a in train.assumptions]
    return "\n".join(head) + "\n" + yaml.safe_dump(train_mapping(train.spec, 6), sort_keys=False)
