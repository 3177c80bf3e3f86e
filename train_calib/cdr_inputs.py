"""A bag's input topics decoded in one pass, straight from the MCAP bytes to the ingest's records.

The offline pipeline (``pipeline.run_bag``, a fleet's worker) reads only the three input topics of INTERFACES.md,
whose message types are fixed: ``sensor_msgs/NavSatFix``, ``geometry_msgs/TwistStamped`` and
``train_calib_msgs/TractionPower``. :func:`read_input_events` parses the MCAP chunks itself and reads the few fields
the ingest uses at their CDR offsets (``struct``), instead of ``mcap``'s record objects and ``rosbags``' generic
deserialiser (one dataclass tree per message): 2 instead of 35 ms for a 20-minute run at 1 Hz.

It is a fast path, never a second reader: it gives exactly the events that ``bagio.iter_bag`` + rosbags decoding +
``ingest.fix_from_msg`` / ``speed_from_msg`` / ``power_from_msg`` give (the same order, the same values bit for bit;
a test checks both on every bundled bag), and returns None whenever the bag is anything but well formed and plain
(no summary, a damaged or short chunk, a CRC mismatch, an unknown compression, a big-endian or malformed message, a
schema other than the topic's type). The caller then takes the generic path, which salvages, decodes or raises as
it always did, so every error and every damaged bag is handled by one code.
"""

from __future__ import annotations

import heapq
import math
import operator
import struct
import zlib
from pathlib import Path

from .bagio import GNSS_TOPIC, INPUT_TOPICS, POWER_TOPIC, SPEED_TOPIC, _summary, mcap_files
from .ingest.records import NS, GnssFix, PowerSample, SpeedSample

Event = GnssFix | SpeedSample | PowerSample
_CLASSES = (GnssFix, SpeedSample, PowerSample)  # by kind, as _Decoder.by_kind

try:
    from .ingest import _kernel  # C: the input messages of a chunk (setup.py builds it where a compiler is found)
except ImportError:  # pragma: no cover - installed without a C compiler: the Python (the same events)
    _kernel = None

_OP_SCHEMA, _OP_CHANNEL, _OP_MESSAGE = 0x03, 0x04, 0x05
_KIND = {GNSS_TOPIC: 0, SPEED_TOPIC: 1, POWER_TOPIC: 2}

_U8 = struct.Struct("<B")
_U16 = struct.Struct("<H")
_U32 = struct.Struct("<I")
_U64 = struct.Struct("<Q")
_CHUNK = struct.Struct("<QQQII")  # message start and end time, uncompressed size and crc, compression length
_RECORD = struct.Struct("<BQ")  # opcode, content length
_MESSAGE = struct.Struct("<HIQQ")  # channel id, sequence, log time, publish time


class _Unusable(Exception):
    """Not for the fast path: the generic reader takes the bag."""


def read_input_events(path: str | Path) -> list[Event] | None:
    """The bag's input events (GnssFix, SpeedSample, PowerSample) in the order ``iter_bag`` gives the messages,
    or None when the generic path must read it (see the module). A missing bag raises BagError as ``iter_bag``."""
    events: list[Event] = []
    try:
        for file in mcap_files(path):
            events += _file_events(file)
    except _Unusable:
        return None
    return events


def _file_events(file: Path) -> list[Event]:
    try:
        with open(file, "rb") as stream:
            summary = _summary(stream)
            stream.seek(0)
            data = stream.read()
    except OSError:
        raise _Unusable from None
    if summary is None or not summary.chunk_indexes:
        raise _Unusable
    kinds: dict[int, int] = {}  # channel id -> 0 fix, 1 speed, 2 power (the input channels)
    for channel in summary.channels.values():
        if channel.topic in INPUT_TOPICS:
            schema = summary.schemas.get(channel.schema_id)
            if schema is None or schema.name != INPUT_TOPICS[channel.topic]:
                raise _Unusable  # decoded as its schema says by the generic path
            kinds[channel.id] = _KIND[channel.topic]
    chunks = sorted(summary.chunk_indexes, key=lambda c: (c.message_start_time, c.chunk_start_offset))
    decoder = _Decoder()
    if len(chunks) == 1:  # iter_bag's merge is then a stable sort by log time
        items = _chunk_events(data, chunks[0].chunk_start_offset, kinds, decoder)
        items.sort(key=_log_time)  # stable: equal log times keep the record order
        return [event for _, event in items]
    return _merged(data, chunks, kinds, decoder)


_log_time = operator.itemgetter(0)  # (log time, event) -> log time


def _merged(data: bytes, chunks: list, kinds: dict[int, int], decoder: _Decoder) -> list[Event]:
    """``bagio._indexed_messages``' merge of several chunks (a chunk is read once the heap's first message is not
    older than its start), on the decoded events."""
    heap: list[tuple[int, int, int, Event]] = []
    out: list[Event] = []
    i = order = 0
    while i < len(chunks) or heap:
        while i < len(chunks) and (not heap or chunks[i].message_start_time <= heap[0][0]):
            offset = chunks[i].chunk_start_offset
            i += 1
            for log_time, event in _chunk_events(data, offset, kinds, decoder):
                heapq.heappush(heap, (log_time, offset, order, event))
                order += 1
        if heap:
            out.append(heapq.heappop(heap)[3])
    return out


def _chunk_events(data: bytes, offset: int, kinds: dict[int, int], decoder: _Decoder) -> list[tuple[int, Event]]:
    """(log time, event) of the input messages of the chunk at ``offset``, in record order: :func:`_record_events`,
    in C where the ingest's kernel is built (``ingest/_kernel.c``: its loop and _Decoder's checks and fields, the
    same events; 0.4 of the decoding time)."""
    records = _chunk_records(data, offset)
    if _kernel is not None:
        items = _kernel.chunk_events(records, kinds, _CLASSES, math.nan, _check_channel, _check_schema)
        if items is None:
            raise _Unusable
        return items
    return _record_events(records, kinds, decoder)


def _record_events(records: bytes, kinds: dict[int, int], decoder: _Decoder) -> list[tuple[int, Event]]:
    """(log time, event) of the input messages among a chunk's records, in record order."""
    n = len(records)
    out: list[tuple[int, Event]] = []
    pos = 0
    unpack_record, unpack_message = _RECORD.unpack_from, _MESSAGE.unpack_from
    decode = decoder.by_kind
    while pos < n:
        if pos + 9 > n:
            raise _Unusable
        opcode, length = unpack_record(records, pos)
        pos += 9
        end = pos + length
        if end > n:
            raise _Unusable
        if opcode == _OP_MESSAGE:
            if length < 22:
                raise _Unusable
            channel_id, _, log_time, _ = unpack_message(records, pos)
            kind = kinds.get(channel_id)
            if kind is not None:
                out.append((log_time, decode[kind](records, pos + 22, end)))
        elif opcode == _OP_CHANNEL:
            _check_channel(records, pos, end)
        elif opcode == _OP_SCHEMA:
            _check_schema(records, pos, end)
        pos = end
    return out


def _chunk_records(data: bytes, offset: int) -> bytes:
    """The (decompressed, CRC-checked) records of the chunk whose record starts at ``offset``."""
    pos = offset + 9
    if pos + _CHUNK.size > len(data):
        raise _Unusable
    _, _, uncompressed_size, crc, clen = _CHUNK.unpack_from(data, pos)
    pos += _CHUNK.size
    if pos + clen + 8 > len(data):
        raise _Unusable
    try:
        compression = data[pos : pos + clen].decode()
    except UnicodeDecodeError:
        raise _Unusable from None
    pos += clen
    (size,) = _U64.unpack_from(data, pos)
    pos += 8
    if size == 0 or pos + size > len(data):
        raise _Unusable
    body = data[pos : pos + size]
    try:
        if compression == "":
            records = body
        elif compression == "zstd":
            import zstandard

            records = zstandard.decompress(body, uncompressed_size)
        elif compression == "lz4":
            import lz4.frame

            records = lz4.frame.decompress(body)
        else:
            raise _Unusable
    except Exception:
        raise _Unusable from None
    if crc != 0 and zlib.crc32(records) != crc:
        raise _Unusable
    return records


def _string_end(buf: bytes, pos: int, end: int, text: bool = True) -> int:
    """End of the MCAP string or byte array (uint32 length + bytes) at pos; a string must be UTF-8 (``mcap``
    decodes it)."""
    if pos + 4 > end:
        raise _Unusable
    stop = pos + 4 + _U32.unpack_from(buf, pos)[0]
    if stop > end:
        raise _Unusable
    if text:
        try:
            buf[pos + 4 : stop].decode()
        except UnicodeDecodeError:
            raise _Unusable from None
    return stop


def _check_channel(buf: bytes, pos: int, end: int) -> None:
    """A channel record in a chunk (``mcap`` reads it field by field): it must fill its length exactly."""
    p = _string_end(buf, pos + 4, end)  # id, schema id, topic
    p = _string_end(buf, p, end)  # message encoding
    stop = _string_end(buf, p, end, text=False)  # metadata: a map of strings, its byte length first
    p += 4
    while p < stop:
        p = _string_end(buf, _string_end(buf, p, stop), stop)
    if p != stop or p != end:
        raise _Unusable


def _check_schema(buf: bytes, pos: int, end: int) -> None:
    p = _string_end(buf, pos + 2, end)  # id, name
    p = _string_end(buf, p, end)  # encoding
    p = _string_end(buf, p, end, text=False)  # data
    if p != end:
        raise _Unusable


class _Decoder:
    """The three input types from their little-endian CDR bytes, with the checks ``rosbags`` makes (string length
    and terminator, enough bytes, no more than 3 bytes of padding after; a frame_id is UTF-8).

    The layout of a message is fixed once its frame_id's length is known: one ``struct`` per (type, length)
    reads every field in one call (the generic deserialiser walks the message field by field)."""

    def __init__(self) -> None:
        self._frames: set[bytes] = set()  # frame_ids seen (with their NUL), each checked once as UTF-8
        self._layouts: dict[tuple[int, int], tuple[struct.Struct, int]] = {}
        self.by_kind = (self.fix, self.speed, self.power)

    def _layout(self, kind: int, length: int) -> tuple[struct.Struct, int]:
        """(struct, message size in bytes) of type ``kind`` with a frame_id of ``length`` bytes (with its NUL)."""
        layout = self._layouts.get((kind, length))
        if layout is None:
            if length < 1:
                raise _Unusable
            cdr = 12 + length  # header: stamp sec, nanosec, frame_id (uint32 length + bytes); offsets after the
            head = f"<2s2xiII{length}s"  # 4-byte encapsulation
            if kind == 0:  # NavSatStatus (int8 status, uint16 service), latitude, longitude, altitude,
                service = (cdr + 2) & -2  # covariance[9] (aligned to 8), uint8 covariance type
                floats = (service + 2 + 7) & -8
                fmt = f"{head}b{service - cdr - 1}xH{floats - service - 2}x3d9dB"
                end = floats + 97
            else:  # twist (linear and angular Vector3) or the two powers, aligned to 8
                floats = (cdr + 7) & -8
                fmt = f"{head}{floats - cdr}x{6 if kind == 1 else 2}d"
                end = floats + (48 if kind == 1 else 16)
            layout = self._layouts[(kind, length)] = (struct.Struct(fmt), 4 + end)
        return layout

    def _values(self, kind: int, buf: bytes, pos: int, end: int) -> tuple:
        """Every field of the message at pos..end (its 4-byte encapsulation first), checked."""
        if end - pos < 16:
            raise _Unusable
        length = _U32.unpack_from(buf, pos + 12)[0]
        unpack, size = self._layouts.get((kind, length)) or self._layout(kind, length)
        if not size <= end - pos <= size + 3:
            raise _Unusable
        values = unpack.unpack_from(buf, pos)
        frame = values[4]
        if values[0] != b"\x00\x01" or frame[-1] != 0:
            raise _Unusable  # not little-endian CDR (the generic path decodes big-endian), or no terminator
        if frame not in self._frames:
            try:
                frame[:-1].decode()
            except UnicodeDecodeError:
                raise _Unusable from None
            self._frames.add(frame)
        return values

    def fix(self, buf: bytes, pos: int, end: int) -> GnssFix:
        v = self._values(0, buf, pos, end)
        known = v[19] != 0  # position_covariance_type != COVARIANCE_TYPE_UNKNOWN
        variance = 0.5 * (v[10] + v[14]) if known else math.nan  # covariance[0] and [4]
        return GnssFix(v[1] * NS + v[2], v[7], v[8], v[5], variance, known)

    def speed(self, buf: bytes, pos: int, end: int) -> SpeedSample:
        v = self._values(1, buf, pos, end)
        return SpeedSample(v[1] * NS + v[2], v[5])

    def power(self, buf: bytes, pos: int, end: int) -> PowerSample:
        v = self._values(2, buf, pos, end)
        return PowerSample(v[1] * NS + v[2], v[5], v[6])


__all__ = ["read_input_events"]
