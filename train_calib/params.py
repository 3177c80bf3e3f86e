"""Typed, documented, range-checked parameter sets shared by the core and the ROS nodes.

A parameter set is a frozen dataclass whose fields are declared with :func:`param`::

    @dataclass(frozen=True)
    class RegimeConfig(ParamSet):
        effort_tolerance: float = param(0.025, "half-width of the coasting band", unit="N/kg", low=0.0)

The same declaration gives the core its defaults and validation (``from_mapping``), and the nodes
their ROS parameter descriptors (description, unit, range) and the check that refuses a bad value
at run time with a reason (``check``), as robot_localization does for its parameters.
"""

from __future__ import annotations

import dataclasses
import math
import typing
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, TypeVar

from .errors import ConfigError

T = TypeVar("T", bound="ParamSet")


def param(
    default: Any,
    description: str,
    *,
    unit: str = "",
    low: float | None = None,
    high: float | None = None,
    low_open: bool = False,
    choices: Sequence[str] | None = None,
    read_only: bool = False,
) -> Any:
    """A dataclass field carrying its documentation and valid range."""
    meta = {
        "description": description,
        "unit": unit,
        "low": low,
        "high": high,
        "low_open": low_open,
        "choices": tuple(choices) if choices else None,
        "read_only": read_only,
    }
    if isinstance(default, list):
        default = tuple(default)
    return field(default=default, metadata=meta)


@dataclass(frozen=True)
class ParamSpec:
    name: str
    kind: type  # float, int, bool, str or tuple (of floats)
    default: Any
    description: str
    unit: str
    low: float | None
    high: float | None
    low_open: bool
    choices: tuple[str, ...] | None
    read_only: bool

    @property
    def doc(self) -> str:
        """Description with unit and range, for parameter descriptors and the README."""
        parts = [self.description]
        if self.unit:
            parts.append(f"[{self.unit}]")
        if self.low is not None or self.high is not None:
            lo = "-inf" if self.low is None else f"{self.low:g}"
            hi = "inf" if self.high is None else f"{self.high:g}"
            parts.append(f"range {'(' if self.low_open else '['}{lo}, {hi}]")
        if self.choices:
            parts.append("one of " + ", ".join(self.choices))
        return " ".join(parts)


_SPECS: dict[type, list[ParamSpec]] = {}


class ParamSet:
    """Mixin for frozen dataclasses declared with :func:`param`."""

    @classmethod
    def specs(cls) -> list[ParamSpec]:
        """The parameters of the class, in field order (built once per class: type hints are costly to resolve)."""
        cached = _SPECS.get(cls)
        if cached is None:
            cached = _SPECS[cls] = cls._build_specs()
        return list(cached)

    @classmethod
    def _build_specs(cls) -> list[ParamSpec]:
        hints = typing.get_type_hints(cls)
        out = []
        for f in dataclasses.fields(cls):  # type: ignore[arg-type]
            hint = hints[f.name]
            origin = typing.get_origin(hint)
            kind = tuple if origin in (tuple, list) else hint
            if kind not in (float, int, bool, str, tuple):
                raise TypeError(f"{cls.__name__}.{f.name}: unsupported parameter type {hint}")
            m = f.metadata
            out.append(
                ParamSpec(
                    f.name,
                    kind,
                    f.default,
                    m.get("description", ""),
                    m.get("unit", ""),
                    m.get("low"),
                    m.get("high"),
                    m.get("low_open", False),
                    m.get("choices"),
                    m.get("read_only", False),
                )
            )
        return out

    @classmethod
    def spec(cls, name: str) -> ParamSpec:
        for s in cls.specs():
            if s.name == name:
                return s
        raise KeyError(name)

    @classmethod
    def check(cls, name: str, value: Any) -> tuple[Any, str | None]:
        """(coerced value, None) when valid, else (value, reason)."""
        try:
            spec = cls.spec(name)
        except KeyError:
            return value, "unknown parameter"
        return _coerce(spec, value)

    @classmethod
    def from_mapping(cls: type[T], values: Mapping[str, Any], source: str = "parameters", prefix: str = "") -> T:
        """Build from a mapping (e.g. a YAML section); unknown keys, wrong types and ranges are refused."""
        if not isinstance(values, Mapping):
            raise ConfigError(source, prefix.rstrip("."), f"expected a mapping, found {type(values).__name__}")
        names = {s.name for s in cls.specs()}
        for key in values:
            if key not in names:
                raise ConfigError(source, f"{prefix}{key}", f"unknown parameter (known: {', '.join(sorted(names))})")
        kwargs = {}
        for key, value in values.items():
            coerced, reason = cls.check(key, value)
            if reason:
                raise ConfigError(source, f"{prefix}{key}", reason)
            kwargs[key] = coerced
        obj = cls(**kwargs)  # type: ignore[call-arg]
        obj.validate(source, prefix)
        return obj

    def replace(self: T, **changes: Any) -> T:
        for key, value in changes.items():
            coerced, reason = self.check(key, value)
            if reason:
                raise ConfigError(type(self).__name__, key, reason)
            changes[key] = coerced
        obj = dataclasses.replace(self, **changes)  # type: ignore[type-var]
        obj.validate(type(self).__name__)
        return obj

    def validate(self, source: str = "parameters", prefix: str = "") -> None:
        """Cross-field checks; override and raise ConfigError(source, prefix + key, problem)."""

    def as_dict(self) -> dict[str, Any]:
        return {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}  # type: ignore[arg-type]


def _coerce(spec: ParamSpec, value: Any) -> tuple[Any, str | None]:
    if spec.kind is bool:
        if isinstance(value, bool):
            return value, None
        return value, f"expected true or false, found {type(value).__name__} {value!r}"
    if spec.kind is str:
        if not isinstance(value, str):
            return value, f"expected a string, found {type(value).__name__} {value!r}"
        if spec.choices and value not in spec.choices:
            return value, f"{value!r} is not one of {', '.join(spec.choices)}"
        return value, None
    if spec.kind is tuple:
        not_a_list = not isinstance(value, (Sequence, tuple)) and not hasattr(value, "tolist")
        if isinstance(value, (str, bytes)) or not_a_list:
            return value, f"expected a list of numbers, found {type(value).__name__}"
        items = list(value.tolist() if hasattr(value, "tolist") else value)
        out = []
        for i, item in enumerate(items):
            number, reason = _number(spec, item, f"[{i}] ")
            if reason:
                return value, reason
            out.append(number)
        return tuple(out), None
    number, reason = _number(spec, value, "")
    if reason is None and spec.kind is int:
        if float(number) != int(number):
            return value, f"expected an integer, found {value!r}"
        number = int(number)
    return number, reason


def _number(spec: ParamSpec, value: Any, where: str) -> tuple[Any, str | None]:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return value, f"{where}expected a number, found {type(value).__name__} {value!r}"
    number = float(value)
    if math.isnan(number) or (math.isinf(number) and spec.kind is int):
        return value, f"{where}expected a finite number, found {value!r}"
    unit = f" {spec.unit}" if spec.unit else ""
    if spec.low is not None and (number <= spec.low if spec.low_open else number < spec.low):
        bound = "greater than" if spec.low_open else "at least"
        return value, f"{where}{number:g}{unit} is out of range: must be {bound} {spec.low:g}{unit}"
    if spec.high is not None and number > spec.high:
        return value, f"{where}{number:g}{unit} is out of range: must be at most {spec.high:g}{unit}"
    return number, None
