"""Reading YAML configuration with validation that fails in one line naming file, key and problem."""

from __future__ import annotations

import difflib
import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import yaml

from .errors import ConfigError


def load_yaml_mapping(path: str | Path, what: str = "file") -> dict[str, Any]:
    """Load a YAML file whose top level must be a mapping."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ConfigError(str(path), "", f"{what} not found") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(str(path), "", f"cannot read {what}: {exc.__class__.__name__}: {exc}") from None
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark else ""
        problem = getattr(exc, "problem", None) or str(exc).splitlines()[0]
        raise ConfigError(str(path), "", f"invalid YAML{where}: {problem}") from None
    if not isinstance(data, Mapping):
        raise ConfigError(str(path), "", f"expected a mapping of keys at the top level, found {type(data).__name__}")
    return dict(data)


class Checker:
    """Typed access to a YAML mapping; every failure is a ConfigError naming file and key path."""

    def __init__(self, source: str | Path) -> None:
        self.source = str(source)

    def fail(self, key: str, problem: str) -> ConfigError:
        return ConfigError(self.source, key, problem)

    def known_keys(self, data: Mapping[str, Any], keys: Sequence[str], prefix: str = "") -> None:
        """Refuse a key not in `keys` (a typo in an optional key would otherwise be ignored), naming the nearest
        valid one."""
        if not isinstance(data, Mapping):
            return
        for key in data:
            if key not in keys:
                close = difflib.get_close_matches(str(key), list(keys), n=1, cutoff=0.6)
                hint = f"did you mean {close[0]}?" if close else f"known keys: {', '.join(keys)}"
                raise self.fail(f"{prefix}{key}", f"unknown key ({hint})")

    def get(
        self, data: Mapping[str, Any], key: str, prefix: str = "", required: bool = True, default: Any = None
    ) -> Any:
        full = f"{prefix}{key}"
        if not isinstance(data, Mapping):
            raise self.fail(prefix.rstrip("."), f"expected a mapping, found {type(data).__name__}")
        if key not in data or data[key] is None:
            if required:
                raise self.fail(full, "missing required key")
            return default
        return data[key]

    def number(
        self,
        data: Mapping[str, Any],
        key: str,
        prefix: str = "",
        *,
        low: float | None = None,
        high: float | None = None,
        low_open: bool = False,
        unit: str = "",
        required: bool = True,
        default: float | None = None,
    ) -> float:
        """A finite real number within [low, high] (or (low, high] with low_open)."""
        full = f"{prefix}{key}"
        value = self.get(data, key, prefix, required=required, default=default)
        if value is None:
            return default  # type: ignore[return-value]
        return self.check_number(value, full, low=low, high=high, low_open=low_open, unit=unit)

    def check_number(
        self,
        value: Any,
        full: str,
        *,
        low: float | None = None,
        high: float | None = None,
        low_open: bool = False,
        unit: str = "",
    ) -> float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise self.fail(
                full, f"expected a number{' in ' + unit if unit else ''}, found {type(value).__name__} {value!r}"
            )
        value = float(value)
        if not math.isfinite(value):
            raise self.fail(full, f"expected a finite number, found {value}")
        suffix = f" {unit}" if unit else ""
        if low is not None and (value <= low if low_open else value < low):
            bound = "greater than" if low_open else "at least"
            raise self.fail(full, f"{value:g}{suffix} is out of range: must be {bound} {low:g}{suffix}")
        if high is not None and value > high:
            raise self.fail(full, f"{value:g}{suffix} is out of range: must be at most {high:g}{suffix}")
        return value

    def string(
        self, data: Mapping[str, Any], key: str, prefix: str = "", required: bool = True, default: str | None = None
    ) -> str:
        value = self.get(data, key, prefix, required=required, default=default)
        if value is None:
            return default  # type: ignore[return-value]
        if not isinstance(value, (str, int)) or isinstance(value, bool):
            raise self.fail(f"{prefix}{key}", f"expected a string, found {type(value).__name__}")
        value = str(value).strip()
        if not value:
            raise self.fail(f"{prefix}{key}", "must not be empty")
        return value

    def sequence(self, data: Mapping[str, Any], key: str, *, required: bool = True, min_len: int = 0) -> Sequence[Any]:
        value = self.get(data, key, required=required, default=[])
        if not isinstance(value, Sequence) or isinstance(value, (str, bytes)):
            raise self.fail(key, f"expected a list, found {type(value).__name__}")
        if len(value) < min_len:
            what = "an empty list" if not value else f"{len(value)} entries"
            raise self.fail(key, f"needs at least {min_len} entries, found {what}")
        return value

    def increasing(self, values: Sequence[float], key: str, field: str, *, strict: bool = True) -> None:
        """Positions must be sorted (strictly increasing unless strict=False)."""
        for i in range(1, len(values)):
            if values[i] < values[i - 1] or (strict and values[i] == values[i - 1]):
                order = "strictly increasing" if strict else "non-decreasing"
                raise self.fail(
                    f"{key}[{i}].{field}",
                    f"positions must be {order}: {values[i]:g} follows {values[i - 1]:g}",
                )
