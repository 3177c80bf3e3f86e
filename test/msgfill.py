"""Fill any rclpy message with distinct non-default values and turn messages into plain dicts."""

from __future__ import annotations

import array
import importlib
import itertools
import re

import numpy as np

_counter = itertools.count(1)

_INT_TYPES = {
    "uint8": 255,
    "int8": 127,
    "uint16": 65535,
    "int16": 32767,
    "uint32": 2**32 - 1,
    "int32": 2**31 - 1,
    "uint64": 2**63,
    "int64": 2**62,
    "octet": 255,
    "byte": 255,
    "char": 127,
}


def message_class(type_name: str):
    """rclpy class of 'pkg/msg/Name'."""
    pkg, _, name = type_name.split("/")
    return getattr(importlib.import_module(f"{pkg}.msg"), name)


def _scalar(base: str):
    n = next(_counter)
    if base in ("double", "float"):
        return n * 1.25 + 0.5 if base == "float" else n * 1.0123456789 + 1e-3
    if base == "boolean":
        return n % 2 == 1
    if base in _INT_TYPES:
        return n % _INT_TYPES[base] + 1
    if base in ("string", "wstring"):
        return f"value-{n}"
    raise KeyError(base)


def fill(msg):
    """Set every field of msg (recursively) to a distinct value; returns msg."""
    for field, ftype in msg.get_fields_and_field_types().items():
        if field == "regime" and ftype == "uint8":
            setattr(msg, field, 1 + next(_counter) % 4)
            continue
        m = re.fullmatch(r"sequence<([\w/]+)(?:, \d+)?>", ftype)
        fixed = re.fullmatch(r"([\w/]+)\[(\d+)\]", ftype)
        base = m.group(1) if m else fixed.group(1) if fixed else ftype
        count = int(fixed.group(2)) if fixed else (3 if m else None)
        if "/" in base:
            cls = message_class(base.replace("/", "/msg/") if base.count("/") == 1 else base)
            value = [fill(cls()) for _ in range(count)] if count is not None else fill(cls())
        elif count is not None:
            value = [_scalar(base) for _ in range(count)]
        else:
            value = _scalar(base)
        setattr(msg, field, value)
    return msg


def to_dict(msg):
    """Plain nested dict/list/float view of an rclpy or rosbags message."""
    if hasattr(msg, "get_fields_and_field_types"):
        return {f: to_dict(getattr(msg, f)) for f in msg.get_fields_and_field_types()}
    if hasattr(msg, "__dataclass_fields__"):
        return {f: to_dict(getattr(msg, f)) for f in msg.__dataclass_fields__ if f != "__msgtype__"}
    if isinstance(msg, (list, tuple, array.array, np.ndarray)):
        return [to_dict(x) for x in msg]
    if isinstance(msg, np.generic):
        return msg.item()
    return msg
