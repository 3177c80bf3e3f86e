"""Fast CDR: serialized input messages decoded into read-only views, output messages encoded from values.

rclpy turns every received message into a Python object through the generated constructor and a property setter
per field, and every published one back through a getter per field: 25-50 us per message on this project's
machines, more than a node's own work on it. The nodes subscribe raw instead and decode the CDR bytes here with
precompiled ``struct`` layouts (about 3 us): the result is a *view*, a tree of named tuples with the message's
field names (``view.header.stamp.sec``, ``view.position_covariance[4]``; arrays as lists), which every duck-typed
reader of ``convert`` and ``ingest`` accepts like the message itself. The chain's messages are published as bytes
packed with the same layouts (``Layout.encode``; ``convert.*_to_cdr``), padding zeroed.

The layout is derived from the message's rosidl introspection (``SLOT_TYPES``), so a field added to a message is
decoded without touching this module. Only plain little-endian CDR (encapsulation ``CDR_LE``, what Fast DDS,
Cyclone DDS and rosbags write for these types) is decoded here; any other encapsulation (big-endian, XCDR2), a
type this module cannot lay out (sequences, wide strings) or bytes it cannot unpack go to rclpy's own
``deserialize_message``, so the fast path never decides what a message contains. A test checks the views field
for field against rclpy on random messages.
"""

from __future__ import annotations

import importlib
import struct
from collections import namedtuple
from collections.abc import Callable
from typing import Any

from rclpy.serialization import deserialize_message
from rosidl_parser import definition as rosidl

CDR_LE = b"\x00\x01"  # encapsulation kind of plain little-endian CDR (XCDR1)
_ORIGIN = 4  # alignment is counted from the end of the 4-byte encapsulation header

# rosidl basic type -> (struct code, size = CDR alignment)
_BASIC = {
    "boolean": ("?", 1),
    "octet": ("c", 1),  # rclpy: bytes of length 1
    "char": ("B", 1),
    "uint8": ("B", 1),
    "int8": ("b", 1),
    "uint16": ("H", 2),
    "int16": ("h", 2),
    "uint32": ("I", 4),
    "int32": ("i", 4),
    "uint64": ("Q", 8),
    "int64": ("q", 8),
    "float": ("f", 4),
    "double": ("d", 8),
}


class Unsupported(Exception):
    """A message type this module does not lay out (its messages are decoded by rclpy)."""


def _message_class(t: rosidl.NamespacedType) -> type:
    module = importlib.import_module(".".join(t.namespaces))
    return getattr(module, t.name)


class _Builder:
    """Walks a message type: the flat list of scalar items (struct code and size, or a string) and the expression
    that rebuilds the nested views from the flat values ``v``."""

    def __init__(self) -> None:
        self.items: list[tuple[str, int] | None] = []  # None: a string
        self.classes: dict[str, type] = {}

    def message(self, cls: type) -> str:
        fields = list(cls.get_fields_and_field_types())
        name = f"{cls.__module__.split('.')[0]}_{cls.__name__}"
        view = self.classes.get(name)
        if view is None:
            view = self.classes[name] = namedtuple(cls.__name__, fields)  # type: ignore[misc]
        args = [self.field(t) for t in cls.SLOT_TYPES]
        return f"{name}({', '.join(args)})"

    def field(self, t: Any) -> str:
        if isinstance(t, rosidl.BasicType):
            if t.typename not in _BASIC:
                raise Unsupported(t.typename)
            self.items.append(_BASIC[t.typename])
            return f"v[{len(self.items) - 1}]"
        if isinstance(t, rosidl.Array):
            if not isinstance(t.value_type, rosidl.BasicType):
                raise Unsupported("array of " + type(t.value_type).__name__)  # strings or messages: rclpy's
            first = len(self.items)
            for _ in range(t.size):
                self.field(t.value_type)
            return f"v[{first}:{len(self.items)}]"
        if isinstance(t, (rosidl.UnboundedString, rosidl.BoundedString)):
            self.items.append(None)
            return f"v[{len(self.items) - 1}]"
        if isinstance(t, rosidl.NamespacedType):
            return self.message(_message_class(t))
        raise Unsupported(type(t).__name__)  # sequences, wide strings


def _struct_for(items: list[tuple[str, int]], residue: int) -> struct.Struct:
    """The fixed items as one struct, starting `residue` bytes past an 8-aligned offset (explicit padding)."""
    fmt, at = ["<"], residue
    for code, size in items:
        pad = -at % size
        fmt.append("x" * pad + code)
        at += pad + size
    return struct.Struct("".join(fmt))


class Layout:
    """The CDR layout of one message type: ``decode(data)`` -> view, ``encode(values)`` -> bytes."""

    def __init__(self, msg_type: type) -> None:
        self.msg_type = msg_type
        self.fast = True
        try:
            builder = _Builder()
            expression = builder.message(msg_type)
        except Unsupported:
            self.fast = False
            return
        # segments: runs of fixed items (one struct per start residue mod 8) separated by strings
        self._segments: list[tuple[list[struct.Struct], int] | None] = []  # (struct per residue, values) or None
        run: list[tuple[str, int]] = []
        for item in [*builder.items, None]:
            if item is not None:
                run.append(item)
                continue
            if run:
                self._segments.append(([_struct_for(run, r) for r in range(8)], len(run)))
                run = []
            self._segments.append(None)
        self._segments.pop()  # the sentinel's string
        self._build: Callable[[list], Any] = eval(f"lambda v: {expression}", dict(builder.classes))

    def decode(self, data: bytes) -> Any:
        """The view of one serialized message (rclpy's own decoding when the fast path does not apply)."""
        if self.fast and data[:2] == CDR_LE:
            try:
                return self._decode_cdr_le(data)
            except (struct.error, UnicodeDecodeError, IndexError):
                pass  # malformed for the fast path: rclpy decides (and raises if it cannot either)
        return deserialize_message(data, self.msg_type)

    def encode(self, values: Any) -> bytes:
        """Plain little-endian CDR of a message given its scalar values in field order (nested messages and arrays
        flattened, as the view's; a header's are ``sec, nanosec, frame_id``); padding bytes are zero."""
        if not self.fast:
            raise Unsupported(f"{self.msg_type.__name__}: no CDR layout (sequences or wide strings)")
        parts, at, k = [CDR_LE, b"\x00\x00"], _ORIGIN, 0
        for seg in self._segments:
            if seg is None:
                pad = -(at - _ORIGIN) % 4
                text = values[k].encode()
                parts.append(b"\x00" * pad + struct.pack("<I", len(text) + 1) + text + b"\x00")
                at += pad + 4 + len(text) + 1
                k += 1
            else:
                structs, n = seg
                st = structs[(at - _ORIGIN) % 8]
                parts.append(st.pack(*values[k : k + n]))
                at += st.size
                k += n
        if k != len(values):
            raise ValueError(f"{self.msg_type.__name__}: {len(values)} values for {k} fields")
        return b"".join(parts)

    def _decode_cdr_le(self, data: bytes) -> Any:
        values: list = []
        at = _ORIGIN
        for seg in self._segments:
            if seg is None:  # a string: uint32 length (with the NUL) aligned to 4, then the bytes
                at += -(at - _ORIGIN) % 4
                (n,) = struct.unpack_from("<I", data, at)
                end = at + 4 + n
                if n == 0 or end > len(data) or data[end - 1] != 0:
                    raise struct.error("bad string")
                values.append(data[at + 4 : end - 1].decode())
                at = end
            else:
                s = seg[0][(at - _ORIGIN) % 8]
                values.extend(s.unpack_from(data, at))
                at += s.size
        return self._build(values)


_LAYOUTS: dict[type, Layout] = {}


def layout(msg_type: type) -> Layout:
    """The (cached) layout of a message type."""
    d = _LAYOUTS.get(msg_type)
    if d is None:
        d = _LAYOUTS[msg_type] = Layout(msg_type)
    return d
