"""Best-effort reading of damaged MCAP files (no ROS): truncated recordings and corrupt chunks.

A recording cut by a power loss or a killed process has no summary and ends inside a chunk; a flipped block
makes a chunk's CRC or its decompression fail. The ``mcap`` reader then gives nothing. Here the records are
parsed one by one from the raw bytes: whole records as they are, a chunk's records up to the end of what is
there (an uncompressed chunk directly; a zstd or lz4 chunk through a streaming decompressor, which yields
the complete part of a cut frame), stopping at the first record that does not parse. What is returned was
framed correctly; its content may still be garbage where the damage is (the reader decodes it and drops
what does not decode).
"""

from __future__ import annotations

import io
import struct
import zlib
from dataclasses import dataclass, field
from typing import Any

from mcap.data_stream import ReadDataStream
from mcap.opcode import Opcode
from mcap.records import Channel, Message, Schema

MAGIC = b"\x89MCAP0\r\n"
_CHUNK_HEAD = struct.Struct("<QQQI")  # message start, message end, uncompressed size, uncompressed crc


@dataclass
class Salvaged:
    """Schemas, channels and messages in file order, and what was wrong (empty: nothing)."""

    schemas: dict[int, Any] = field(default_factory=dict)
    channels: dict[int, Any] = field(default_factory=dict)
    messages: list[Any] = field(default_factory=list)
    damage: list[str] = field(default_factory=list)


def salvage_file(data: bytes) -> Salvaged:
    """Every record of an MCAP file that can still be framed, with chunks expanded."""
    out = Salvaged()
    if not data.startswith(MAGIC):
        out.damage.append("no MCAP magic")
        return out
    pos = len(MAGIC)
    size = len(data)
    while pos + 9 <= size:
        opcode = data[pos]
        length = int.from_bytes(data[pos + 1 : pos + 9], "little")
        body = data[pos + 9 : pos + 9 + length]
        complete = len(body) == length
        if opcode == Opcode.CHUNK:
            salvage_chunk(body, out, f"chunk at byte {pos}")
        elif not complete:
            break
        elif opcode in (Opcode.DATA_END, Opcode.FOOTER):
            return out
        else:
            _record(opcode, body, out)
        if not complete:
            break
        pos += 9 + length
    out.damage.append(f"truncated at byte {size}")
    return out


def salvage_chunk(body: bytes, out: Salvaged, where: str) -> None:
    """The records of one chunk record's body (possibly cut or corrupt) into `out`."""
    head = _CHUNK_HEAD.size
    if len(body) < head + 4:
        out.damage.append(f"{where}: cut in its header")
        return
    _, _, _, crc = _CHUNK_HEAD.unpack_from(body)
    n = int.from_bytes(body[head : head + 4], "little")
    compression = body[head + 4 : head + 4 + n].decode("utf-8", errors="replace")
    start = head + 4 + n + 8
    if len(body) < start:
        out.damage.append(f"{where}: cut in its header")
        return
    length = int.from_bytes(body[start - 8 : start], "little")
    raw = body[start : start + length]
    cut = len(raw) < length
    try:
        data = _decompress(compression, raw)
    except Exception as exc:  # a corrupt compressed stream: nothing of it is trustworthy
        out.damage.append(f"{where}: {compression} data unreadable ({exc.__class__.__name__})")
        return
    if cut:
        out.damage.append(f"{where}: cut after {len(raw)} of {length} bytes")
    elif zlib.crc32(data) != crc and crc != 0:
        out.damage.append(f"{where}: CRC mismatch (its records read as far as they parse)")
    pos = 0
    while pos + 9 <= len(data):
        opcode = data[pos]
        size = int.from_bytes(data[pos + 1 : pos + 9], "little")
        if pos + 9 + size > len(data):
            if not cut:
                out.damage.append(f"{where}: a record overruns the chunk")
            return
        if not _record(opcode, data[pos + 9 : pos + 9 + size], out):
            out.damage.append(f"{where}: unparsable record at byte {pos} of the chunk")
            return
        pos += 9 + size


def _decompress(compression: str, raw: bytes) -> bytes:
    if compression == "":
        return raw
    if compression == "zstd":
        import zstandard

        return zstandard.ZstdDecompressor().decompressobj().decompress(raw)
    if compression == "lz4":
        import lz4.frame

        return lz4.frame.LZ4FrameDecompressor().decompress(raw)
    raise ValueError(f"unknown compression {compression!r}")


def _record(opcode: int, body: bytes, out: Salvaged) -> bool:
    """Parse a whole record into `out` (schemas, channels, messages); False when it does not parse."""
    try:
        stream = ReadDataStream(io.BytesIO(body))
        if opcode == Opcode.SCHEMA:
            schema = Schema.read(stream)
            out.schemas[schema.id] = schema
        elif opcode == Opcode.CHANNEL:
            channel = Channel.read(stream)
            out.channels[channel.id] = channel
        elif opcode == Opcode.MESSAGE:
            out.messages.append(Message.read(stream, len(body)))
    except Exception:
        return False
    return True


__all__ = ["Salvaged", "salvage_chunk", "salvage_file"]
