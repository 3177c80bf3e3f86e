"""Train compositions (TYPES.yaml): lengths for the assignment, defaults and calibration bounds.

File layout (see ``config/train_types/ic_compositions.yaml``)::

    name: ic1900                       # any label
    bounds:                            # decision vector bounds, shared by all compositions
      c0: [0.20, 0.70]                 # N/kg
      c2: [2.5, 12.0]                  # W/kg
      r0: [0.010, 0.025]               # N/kg
      r2: [1.5e-5, 5.0e-5]             # N s^2/(m^2 kg)
      b_limit: [0.24, 0.90]            # m/s^2
      theta_cruise: [0.80, 1.02]       # fraction of the static limit
    defaults: {b_limit: 0.66, theta_cruise: 1.0, c1: 0.0}   # for every composition (optional)
    compositions:
      - name: VIRM4
        length_m: 108
        train: ../trains/virm4.yaml    # c0, c2, r0, r1, r2, b_stop from the train file
        defaults: {r1: 2.162e-4}       # overrides (optional)
        bounds: {c2: [3.0, 9.0]}       # overrides (optional)

A composition's model parameters are, in increasing priority: the train file (c0 =
max_tractive_effort, c2 = max_tractive_power, r0/r1/r2 = davis, b_stop = max_brake_decel), the
file-level ``defaults``, its own ``defaults``. ``train`` is a path relative to this file or the
name of a bundled train file; without it the defaults must give every parameter.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from .. import paths
from ..train import load_train
from ..yamlcheck import Checker, load_yaml_mapping

DECISION_NAMES: tuple[str, ...] = ("c0", "c2", "r0", "r2", "b_limit", "theta_cruise")
"""The calibrated parameters (Besinovic eq. 21), in the order of the decision vector."""

MODEL_NAMES: tuple[str, ...] = ("c0", "c1", "c2", "r0", "r1", "r2", "b_limit", "b_stop", "theta_cruise")
"""Every parameter of the running-time model (besides the train length)."""

UNITS = {
    "c0": "N/kg",
    "c1": "N s/(m kg)",
    "c2": "W/kg",
    "r0": "N/kg",
    "r1": "N s/(m kg)",
    "r2": "N s^2/(m^2 kg)",
    "b_limit": "m/s^2",
    "b_stop": "m/s^2",
    "theta_cruise": "-",
    "length_m": "m",
}

# physical plausibility of any value in the file (not the calibration bounds)
_RANGES = {
    "c0": (0.0, 5.0),
    "c1": (-0.5, 0.5),
    "c2": (0.0, 100.0),
    "r0": (0.0, 0.2),
    "r1": (0.0, 0.01),
    "r2": (0.0, 0.001),
    "b_limit": (0.0, 3.0),
    "b_stop": (0.0, 3.0),
    "theta_cruise": (0.1, 1.5),
}

_STANDARD_DEFAULTS = {"c1": 0.0, "b_limit": 0.66, "theta_cruise": 1.0}
"""The paper's values where a train file has none (Table 3: b_limit 0.66 m/s^2, 100 %; c1 = 0)."""


@dataclass(frozen=True)
class Composition:
    """One train composition: its length, model defaults and calibration bounds."""

    name: str
    length_m: float
    defaults: dict[str, float]  # every MODEL_NAMES entry
    bounds: dict[str, tuple[float, float]]  # every DECISION_NAMES entry
    train_file: str = ""

    def model_params(self, **overrides: float) -> dict[str, float]:
        """Defaults with overrides, plus ``length_m``."""
        out = dict(self.defaults)
        out.update(overrides)
        out["length_m"] = self.length_m
        return out


@dataclass(frozen=True)
class TrainTypes:
    """The compositions a line's trains may run as."""

    name: str
    compositions: tuple[Composition, ...]
    source: str = ""
    extra: dict[str, Any] = field(default_factory=dict)

    def lengths(self) -> dict[str, float]:
        return {c.name: c.length_m for c in self.compositions}

    def __getitem__(self, name: str) -> Composition:
        for c in self.compositions:
            if c.name == name:
                return c
        raise KeyError(f"{self.source}: no composition named {name!r} (known: {', '.join(self.names)})")

    def __contains__(self, name: object) -> bool:
        return any(c.name == name for c in self.compositions)

    @property
    def names(self) -> list[str]:
        return [c.name for c in self.compositions]


def load_train_types(path: str | Path) -> TrainTypes:
    """Read and validate a TYPES.yaml; a problem raises ConfigError('<file>: <key>: <problem>')."""
    path = Path(path)
    data = load_yaml_mapping(path, "train types file")
    c = Checker(path)
    name = c.string(data, "name")
    top_bounds = _bounds(c, data.get("bounds"), "bounds", required=True)
    top_defaults = _defaults(c, data.get("defaults"), "defaults")
    items = c.sequence(data, "compositions", min_len=1)
    comps = []
    seen: set[str] = set()
    for i, item in enumerate(items):
        key = f"compositions[{i}]"
        if not isinstance(item, Mapping):
            raise c.fail(key, f"expected a mapping with name, length_m, train, found {type(item).__name__}")
        cname = c.string(item, "name", f"{key}.")
        if cname in seen:
            raise c.fail(f"{key}.name", f"duplicate composition {cname!r}")
        seen.add(cname)
        length = c.number(item, "length_m", f"{key}.", low=1.0, high=4000.0, unit="m")
        values: dict[str, float] = dict(_STANDARD_DEFAULTS)
        train_ref = item.get("train")
        train_path = ""
        if train_ref is not None:
            train_path = str(_resolve_train(c, path, train_ref, f"{key}.train"))
            spec = load_train(train_path)
            values.update(
                c0=spec.max_tractive_effort,
                c2=spec.max_tractive_power,
                r0=spec.davis.r0,
                r1=spec.davis.r1,
                r2=spec.davis.r2,
                b_stop=spec.max_brake_decel,
            )
        values.update(top_defaults)
        values.update(_defaults(c, item.get("defaults"), f"{key}.defaults"))
        missing = [n for n in MODEL_NAMES if n not in values]
        if missing:
            raise c.fail(key, f"no value for {', '.join(missing)}: give a train file or defaults")
        bounds = dict(top_bounds)
        bounds.update(_bounds(c, item.get("bounds"), f"{key}.bounds", required=False))
        comps.append(Composition(cname, length, values, bounds, train_path))
    extra = {k: v for k, v in data.items() if k not in ("name", "bounds", "defaults", "compositions")}
    return TrainTypes(name, tuple(comps), str(path), extra)


def _resolve_train(c: Checker, types_path: Path, ref: Any, key: str) -> Path:
    if not isinstance(ref, str) or not ref.strip():
        raise c.fail(key, f"expected a train file path or name, found {ref!r}")
    candidate = Path(ref)
    if not candidate.is_absolute():
        candidate = types_path.parent / candidate
    if candidate.is_file():
        return candidate
    bundled = paths.train_file(ref)
    if bundled.is_file():
        return bundled
    raise c.fail(key, f"train file {ref!r} not found (relative to {types_path.parent} or among the bundled trains)")


def _defaults(c: Checker, raw: Any, key: str) -> dict[str, float]:
    if raw is None:
        return {}
    if not isinstance(raw, Mapping):
        raise c.fail(key, f"expected a mapping of parameter values, found {type(raw).__name__}")
    out = {}
    for name, value in raw.items():
        if name not in _RANGES:
            raise c.fail(f"{key}.{name}", f"unknown parameter (known: {', '.join(MODEL_NAMES)})")
        low, high = _RANGES[name]
        out[name] = c.check_number(value, f"{key}.{name}", low=low, high=high, unit=UNITS[name])
    return out


def _bounds(c: Checker, raw: Any, key: str, *, required: bool) -> dict[str, tuple[float, float]]:
    if raw is None:
        if required:
            raise c.fail(key, f"missing required key (bounds of {', '.join(DECISION_NAMES)})")
        return {}
    if not isinstance(raw, Mapping):
        raise c.fail(key, f"expected a mapping of [low, high] pairs, found {type(raw).__name__}")
    out = {}
    for name, pair in raw.items():
        full = f"{key}.{name}"
        if name not in DECISION_NAMES:
            raise c.fail(full, f"not a calibrated parameter (calibrated: {', '.join(DECISION_NAMES)})")
        if not isinstance(pair, (list, tuple)) or len(pair) != 2:
            raise c.fail(full, f"expected [low, high], found {pair!r}")
        low_r, high_r = _RANGES[name]
        low = c.check_number(pair[0], f"{full}[0]", low=low_r, high=high_r, unit=UNITS[name])
        high = c.check_number(pair[1], f"{full}[1]", low=low_r, high=high_r, unit=UNITS[name])
        if high <= low:
            raise c.fail(full, f"upper bound {high:g} must exceed lower bound {low:g}")
        out[name] = (low, high)
    if required:
        missing = [n for n in DECISION_NAMES if n not in out]
        if missing:
            raise c.fail(key, f"missing bounds for {', '.join(missing)}")
    return out
