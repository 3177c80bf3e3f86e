"""Reading and writing MCAP bags in the rosbag2 layout, without ROS.

Bags are written with ``rosbags`` (rosbag2 directory: ``metadata.yaml`` + ``<name>_0.mcap``, message
definitions embedded) and read with the ``mcap`` reader, which opens both such a directory and a
bare ``.mcap`` file. CDR bytes are those rclpy produces, so a recorder can store rclpy's serialized
messages as they are.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from .errors import BagError
from .paths import msg_dir

GNSS_FRAME = "gnss"  # frame_id of the input messages written by write_input_bag
SPEED_FRAME = "base_link"
POWER_FRAME = "traction"

GNSS_TOPIC = "/gnss/fix"
SPEED_TOPIC = "/train/speed"
POWER_TOPIC = "/train/traction_power"

INPUT_TOPICS: dict[str, str] = {
    GNSS_TOPIC: "sensor_msgs/msg/NavSatFix",
    SPEED_TOPIC: "geometry_msgs/msg/TwistStamped",
    POWER_TOPIC: "train_calib_msgs/msg/TractionPower",
}

OUTPUT_TOPICS: dict[str, str] = {
    "/train_calib/measurement": "train_calib_msgs/msg/TrackMeasurement",
    "/train_calib/resistance": "train_calib_msgs/msg/ResistanceEstimate",
    "/train_calib/regime": "train_calib_msgs/msg/DrivingRegime",
    "/train_calib/features": "train_calib_msgs/msg/DrivingFeatures",
    "/train_calib/window_resistance": "train_calib_msgs/msg/WindowResistance",
    "/diagnostics": "diagnostic_msgs/msg/DiagnosticArray",
}


@lru_cache(maxsize=1)
def typestore():
    """A rosbags typestore with the ROS 2 Jazzy types and train_calib_msgs registered."""
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    store = get_typestore(Stores.ROS2_JAZZY)
    types: dict[str, Any] = {}
    for path in sorted(msg_dir().glob("*.msg")):
        types.update(get_types_from_msg(path.read_text(encoding="utf-8"), f"train_calib_msgs/msg/{path.stem}"))
    store.register(types)
    return store


def msg_class(msgtype: str):
    """The rosbags dataclass of a message type, e.g. ``msg_class('sensor_msgs/msg/NavSatFix')``."""
    return typestore().types[msgtype]


def stamp_ns(header: Any) -> int:
    """Nanoseconds of a std_msgs/Header stamp (rosbags or rclpy message)."""
    return int(header.stamp.sec) * 1_000_000_000 + int(header.stamp.nanosec)


def make_header(t_ns: int, frame_id: str = ""):
    """A rosbags std_msgs/Header for a time in ns."""
    store = typestore()
    Time = store.types["builtin_interfaces/msg/Time"]
    Header = store.types["std_msgs/msg/Header"]
    return Header(stamp=Time(sec=int(t_ns // 1_000_000_000), nanosec=int(t_ns % 1_000_000_000)), frame_id=frame_id)


class BagWriter:
    """Write messages to a rosbag2 directory with MCAP storage (context manager).

    Topics are added on first use from ``topics`` (topic -> type). ``close()`` (also on exit, and
    from a signal handler) writes the MCAP summary and ``metadata.yaml``.
    """

    def __init__(self, path: str | Path, topics: dict[str, str]) -> None:
        from rosbags.rosbag2 import StoragePlugin, Writer

        self.path = Path(path)
        if self.path.exists():
            raise BagError(f"{self.path}: output bag already exists")
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._topics = dict(topics)
        self._writer = Writer(self.path, version=9, storage_plugin=StoragePlugin.MCAP)
        self._writer.open()
        self._connections: dict[str, Any] = {}
        self.count = 0
        self._closed = False

    def _connection(self, topic: str):
        conn = self._connections.get(topic)
        if conn is None:
            msgtype = self._topics.get(topic)
            if msgtype is None:
                raise BagError(f"{self.path}: topic {topic} was not declared for this bag")
            conn = self._writer.add_connection(topic, msgtype, typestore=typestore())
            self._connections[topic] = conn
        return conn

    def write(self, topic: str, msg: Any, t_ns: int) -> None:
        """Serialize a rosbags message and write it with log time t_ns."""
        conn = self._connection(topic)
        self._writer.write(conn, int(t_ns), typestore().serialize_cdr(msg, conn.msgtype))
        self.count += 1

    def write_raw(self, topic: str, cdr: bytes | memoryview, t_ns: int) -> None:
        """Write already serialized CDR bytes (e.g. from an rclpy raw subscription)."""
        self._writer.write(self._connection(topic), int(t_ns), cdr)
        self.count += 1

    def close(self) -> None:
        if not self._closed:
            self._closed = True
            self._writer.close()

    def __enter__(self) -> BagWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def write_input_bag(
    path: str | Path,
    *,
    gnss_t_ns: Any,
    lat: Any,
    lon: Any,
    altitude: Any,
    gnss_sigma_m: float,
    speed_t_ns: Any,
    speed_ms: Any,
    gnss_ok: Any = None,
    power: tuple[Any, Any, Any] | None = None,
) -> None:
    """An input bag (the input topics of INTERFACES.md) from sample arrays, in stamp order (log time = stamp; at
    one stamp the fix, then the speed, then the power). Stamps in ns, speeds m/s, power (t_ns, consumed W,
    regenerated W) declares the power topic when given. A fix whose ``gnss_ok`` is False is written as no fix
    (status -1, altitude NaN, covariance unknown); the others with the covariance of ``gnss_sigma_m`` per horizontal
    axis (twice that vertically). The simulator's and ``train-calib import``'s writer."""
    NavSatFix = msg_class("sensor_msgs/msg/NavSatFix")
    NavSatStatus = msg_class("sensor_msgs/msg/NavSatStatus")
    TwistStamped = msg_class("geometry_msgs/msg/TwistStamped")
    Twist = msg_class("geometry_msgs/msg/Twist")
    Vector3 = msg_class("geometry_msgs/msg/Vector3")
    TractionPower = msg_class("train_calib_msgs/msg/TractionPower")
    var = float(gnss_sigma_m) ** 2
    cov_fix = np.array([var, 0, 0, 0, var, 0, 0, 0, 4.0 * var], dtype=float)
    cov_none = np.zeros(9)
    zero = Vector3(x=0.0, y=0.0, z=0.0)
    oks = [True] * len(gnss_t_ns) if gnss_ok is None else [bool(x) for x in gnss_ok]
    items: list[tuple[int, int, Any]] = []
    for t, la, lo, alt, ok in zip(gnss_t_ns, lat, lon, altitude, oks):
        msg = NavSatFix(
            header=make_header(int(t), GNSS_FRAME),
            status=NavSatStatus(status=0 if ok else -1, service=1),
            latitude=float(la),
            longitude=float(lo),
            altitude=float(alt) if ok else float("nan"),
            position_covariance=cov_fix if ok else cov_none,
            position_covariance_type=2 if ok else 0,
        )
        items.append((int(t), 0, msg))
    for t, v in zip(speed_t_ns, speed_ms):
        twist = Twist(linear=Vector3(x=float(v), y=0.0, z=0.0), angular=zero)
        items.append((int(t), 1, TwistStamped(header=make_header(int(t), SPEED_FRAME), twist=twist)))
    if power is not None:
        for t, consumed, regenerated in zip(*power):
            msg = TractionPower(
                header=make_header(int(t), POWER_FRAME),
                power_consumed=float(consumed),
                power_regenerated=float(regenerated),
            )
            items.append((int(t), 2, msg))
    items.sort(key=lambda it: (it[0], it[1]))
    topics = [GNSS_TOPIC, SPEED_TOPIC, POWER_TOPIC]
    declared = {t: INPUT_TOPICS[t] for t in topics[: 3 if power is not None else 2]}
    with BagWriter(path, declared) as writer:
        for t_ns, k, msg in items:
            writer.write(topics[k], msg, t_ns)


@dataclass
class BagMessage:
    topic: str
    msgtype: str
    log_time_ns: int
    data: bytes

    def decode(self) -> Any:
        return typestore().deserialize_cdr(self.data, self.msgtype)


_SAFE_LOADER = getattr(yaml, "CSafeLoader", yaml.SafeLoader)
"""libyaml's safe loader when PyYAML has it (the same documents, 0.3 instead of 3 ms for a bag's metadata.yaml: 4 %
of a 10 s run's whole pipeline in a fleet), else PyYAML's."""


def mcap_files(path: str | Path) -> list[Path]:
    """The MCAP files of a bag: a rosbag2 directory (in metadata order) or a bare .mcap file."""
    path = Path(path)
    if path.is_file():
        return [path]
    if not path.is_dir():
        raise BagError(f"{path}: no such bag (expected a rosbag2 directory or an .mcap file)")
    meta = path / "metadata.yaml"
    if meta.is_file():
        try:
            info = yaml.load(meta.read_text(encoding="utf-8"), Loader=_SAFE_LOADER)["rosbag2_bagfile_information"]
            files = [path / rel for rel in info["relative_file_paths"]]
        except Exception as exc:
            raise BagError(f"{meta}: unreadable rosbag2 metadata: {exc}") from None
        missing = [f for f in files if not f.is_file()]
        if missing:
            raise BagError(f"{missing[0]}: listed in {meta.name} but missing")
        return files
    files = sorted(path.glob("*.mcap"))
    if not files:
        raise BagError(f"{path}: directory holds no metadata.yaml and no .mcap file")
    return files


class BagDamage(BagError):
    """A damaged MCAP file: every readable message was delivered before this was raised.

    ``messages``: how many messages were read from the damaged file; ``detail``: what was wrong.
    """

    def __init__(self, file: Path, detail: str, messages: int) -> None:
        self.file, self.detail, self.messages = file, detail, messages
        super().__init__(f"{file}: damaged MCAP ({detail}); {messages} messages were read")


def _summary(stream: Any) -> Any:
    """The MCAP summary, or None when the file has none or its end is damaged (truncated)."""
    from mcap.reader import make_reader

    try:
        return make_reader(stream).get_summary()
    except Exception:
        return None


def _open(file: Path) -> Any:
    try:
        return open(file, "rb")
    except OSError as exc:
        raise BagError(f"{file}: cannot open: {exc.strerror or exc}") from None


def bag_topics(path: str | Path) -> dict[str, str]:
    """Topic -> message type of every channel in the bag (of a damaged file: the channels that can be read)."""
    from .mcap_salvage import salvage_file

    topics: dict[str, str] = {}
    for file in mcap_files(path):
        with _open(file) as stream:
            summary = _summary(stream)
            if summary is not None:
                schemas, channels = summary.schemas, summary.channels
            else:
                stream.seek(0)
                salvaged = salvage_file(stream.read())
                schemas, channels = salvaged.schemas, salvaged.channels
                if not channels:
                    problem = salvaged.damage[0] if salvaged.damage else "no channels"
                    raise BagError(f"{file}: not a readable MCAP file ({problem})")
        for channel in channels.values():
            schema = schemas.get(channel.schema_id)
            topics[channel.topic] = schema.name if schema else ""
    return topics


def iter_bag(path: str | Path, topics: Iterable[str] | None = None) -> Iterator[BagMessage]:
    """Messages of the bag in log-time order, optionally only of some topics.

    A damaged file is salvaged (:mod:`train_calib.mcap_salvage`): with its summary readable, a damaged chunk
    is read as far as its records parse and the others normally; without a summary (a truncated recording)
    the records are read up to where the file ends. Every readable message is yielded, then
    :class:`BagDamage` (a BagError) names the file and the damage.
    """
    wanted = set(topics) if topics is not None else None
    for file in mcap_files(path):
        with _open(file) as stream:
            damage: list[str] = []
            count = 0
            summary = _summary(stream)
            if summary is not None and summary.chunk_indexes:
                messages = _indexed_messages(stream, summary, wanted, damage)
            else:
                messages = _salvaged_messages(stream, wanted, damage)
            for message in messages:
                count += 1
                yield message
            if damage:
                if count == 0 and summary is None:
                    raise BagError(f"{file}: not a readable MCAP file ({damage[0]})")
                raise BagDamage(file, "; ".join(damage), count)


def _indexed_messages(stream: Any, summary: Any, wanted: set[str] | None, damage: list[str]) -> Iterator[BagMessage]:
    """Chunk by chunk through the summary's chunk index, merged in log-time order (a damaged chunk salvaged)."""
    import heapq

    from mcap.data_stream import ReadDataStream
    from mcap.records import Chunk, Message
    from mcap.stream_reader import breakup_chunk

    from .mcap_salvage import Salvaged, salvage_chunk

    channels = summary.channels
    chunks = sorted(summary.chunk_indexes, key=lambda c: (c.message_start_time, c.chunk_start_offset))
    heap: list[tuple[int, int, int, Any]] = []
    i = 0
    order = 0
    while i < len(chunks) or heap:
        while i < len(chunks) and (not heap or chunks[i].message_start_time <= heap[0][0]):
            index = chunks[i]
            i += 1
            try:
                stream.seek(index.chunk_start_offset + 1 + 8)
                records = list(breakup_chunk(Chunk.read(ReadDataStream(stream)), validate_crc=True))
            except Exception:
                stream.seek(index.chunk_start_offset + 1 + 8)
                salvaged = Salvaged()
                salvage_chunk(
                    stream.read(max(index.chunk_length - 9, 0)), salvaged, f"chunk at byte {index.chunk_start_offset}"
                )
                damage.extend(salvaged.damage)
                records = salvaged.messages
            for record in records:
                channel = channels.get(record.channel_id) if isinstance(record, Message) else None
                if channel is not None and (wanted is None or channel.topic in wanted):
                    heapq.heappush(heap, (record.log_time, index.chunk_start_offset, order, record))
                    order += 1
        if heap:
            _, _, _, record = heapq.heappop(heap)
            channel = channels[record.channel_id]
            schema = summary.schemas.get(channel.schema_id)
            yield BagMessage(channel.topic, schema.name if schema else "", record.log_time, record.data)


def _salvaged_messages(stream: Any, wanted: set[str] | None, damage: list[str]) -> Iterator[BagMessage]:
    """No usable summary (a truncated recording): every record that can be framed, in log-time order."""
    from .mcap_salvage import salvage_file

    stream.seek(0)
    salvaged = salvage_file(stream.read())
    damage.extend(salvaged.damage)
    records = sorted(salvaged.messages, key=lambda m: m.log_time)  # stable: file order at equal times
    for record in records:
        channel = salvaged.channels.get(record.channel_id)
        if channel is None or (wanted is not None and channel.topic not in wanted):
            continue
        schema = salvaged.schemas.get(channel.schema_id)
        yield BagMessage(channel.topic, schema.name if schema else "", record.log_time, record.data)


def bag_name(path: str | Path) -> str:
    path = Path(path)
    return path.stem if path.is_file() else path.name


def file_size(path: str | Path) -> int:
    path = Path(path)
    if path.is_file():
        return path.stat().st_size
    return sum(f.stat().st_size for f in path.rglob("*") if f.is_file()) if path.is_dir() else 0


__all__ = [
    "GNSS_TOPIC",
    "INPUT_TOPICS",
    "OUTPUT_TOPICS",
    "POWER_TOPIC",
    "SPEED_TOPIC",
    "BagDamage",
    "BagMessage",
    "BagWriter",
    "bag_name",
    "bag_topics",
    "file_size",
    "iter_bag",
    "make_header",
    "mcap_files",
    "msg_class",
    "stamp_ns",
    "typestore",
]
