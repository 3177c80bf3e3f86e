"""Recording topics to MCAP in the rosbag2 layout: ``DIR/output.mcap`` + ``DIR/metadata.yaml``.

``DIR`` is a rosbag2 bag directory (``metadata.yaml`` lists ``output.mcap`` as its only file), so
``ros2 bag info DIR``, ``rosbags.rosbag2.Reader(DIR)`` and ``bagio.iter_bag(DIR)`` open it, and
``DIR/output.mcap`` is a complete MCAP file on its own (``mcap`` readers, Foxglove): every channel has
its ``ros2msg`` schema with the full message definition, CDR messages, the rosbag2 ``offered_qos_profiles``
channel metadata and the ``rosbag2`` metadata record. Chunks are flushed as they fill (256 KiB), so an
interrupted recording keeps what was written; :meth:`McapBagWriter.close` (also on SIGINT/SIGTERM via
the recorder's owner) writes the summary and ``metadata.yaml``.

:class:`McapBagWriter` is ROS-free; :class:`Recorder` subscribes raw (serialized CDR, no
deserialisation) with rclpy and writes what arrives, stamped with the node clock (sim time under
``use_sim_time``), as ``ros2 bag record`` does.
"""

from __future__ import annotations

import importlib
import io
from collections import Counter
from pathlib import Path
from typing import Any

import yaml

from . import __version__
from .bagio import typestore
from .errors import BagError

OUTPUT_FILE = "output.mcap"
METADATA_FILE = "metadata.yaml"
CHUNK_SIZE = 256 * 1024


def qos_dict(reliable: bool = True, depth: int = 1000, transient_local: bool = False) -> dict[str, Any]:
    """An offered QoS profile in the rosbag2 v9 metadata form."""
    infinite = {"sec": 2147483647, "nsec": 4294967295}  # RMW_DURATION_INFINITE as rosbag2 writes it
    return {
        "history": "keep_last",
        "depth": depth,
        "reliability": "reliable" if reliable else "best_effort",
        "durability": "transient_local" if transient_local else "volatile",
        "deadline": infinite,
        "lifespan": infinite,
        "liveliness": "automatic",
        "liveliness_lease_duration": infinite,
        "avoid_ros_namespace_conventions": False,
    }


class McapBagWriter:
    """Write serialized (CDR) messages to ``directory/file_name`` with rosbag2 metadata (context manager)."""

    def __init__(
        self,
        directory: str | Path,
        topics: dict[str, str],
        *,
        file_name: str = OUTPUT_FILE,
        qos: dict[str, dict[str, Any]] | None = None,
    ) -> None:
        from mcap.writer import CompressionType, Writer

        self.directory = Path(directory)
        self.path = self.directory / file_name
        self.metadata_path = self.directory / METADATA_FILE
        for existing in (self.path, self.metadata_path):
            if existing.exists():
                raise BagError(f"{existing}: already exists (choose another output directory)")
        try:
            self.directory.mkdir(parents=True, exist_ok=True)
            self._stream = open(self.path, "xb")  # noqa: SIM115 - closed in close()
        except OSError as exc:
            raise BagError(f"{self.path}: cannot create: {exc.strerror or exc}") from None
        self._writer = Writer(self._stream, chunk_size=CHUNK_SIZE, compression=CompressionType.ZSTD)
        self._writer.start(profile="ros2", library=f"train_calib {__version__}")
        self.topics = dict(topics)
        self.counts: Counter[str] = Counter()
        self._channels: dict[str, int] = {}
        self._schemas: dict[str, int] = {}
        self._qos = qos or {}
        self._hashes: dict[str, str] = {}
        self.start_ns: int | None = None
        self.end_ns = 0
        self._closed = False
        for topic in self.topics:
            self._channel(topic)

    def _channel(self, topic: str) -> int:
        channel = self._channels.get(topic)
        if channel is not None:
            return channel
        msgtype = self.topics.get(topic)
        if msgtype is None:
            raise BagError(f"{self.path}: topic {topic} was not declared for this bag")
        store = typestore()
        schema = self._schemas.get(msgtype)
        if schema is None:
            msgdef, _ = store.generate_msgdef(msgtype, ros_version=2)
            schema = self._writer.register_schema(name=msgtype, encoding="ros2msg", data=msgdef.encode())
            self._schemas[msgtype] = schema
            self._hashes[msgtype] = store.hash_rihs01(msgtype)
        qos_text = yaml.safe_dump([self._qos.get(topic, qos_dict())], sort_keys=False).strip()
        channel = self._writer.register_channel(
            topic=topic,
            message_encoding="cdr",
            schema_id=schema,
            metadata={"offered_qos_profiles": qos_text, "topic_type_hash": self._hashes[msgtype]},
        )
        self._channels[topic] = channel
        self.counts[topic] += 0
        return channel

    def write_raw(
        self, topic: str, data: bytes | memoryview, log_time_ns: int, publish_time_ns: int | None = None
    ) -> None:
        """Write one serialized message (CDR, as rclpy's raw subscriptions deliver it)."""
        if self._closed:
            raise BagError(f"{self.path}: bag already closed")
        channel = self._channel(topic)
        t = int(log_time_ns)
        self._writer.add_message(
            channel_id=channel,
            log_time=t,
            data=bytes(data),
            publish_time=int(publish_time_ns if publish_time_ns is not None else t),
            sequence=self.counts[topic],
        )
        self.counts[topic] += 1
        self.start_ns = t if self.start_ns is None else min(self.start_ns, t)
        self.end_ns = max(self.end_ns, t)

    def write(self, topic: str, msg: Any, log_time_ns: int) -> None:
        """Serialize a rosbags message and write it."""
        self.write_raw(topic, typestore().serialize_cdr(msg, self.topics[topic]), log_time_ns)

    @property
    def message_count(self) -> int:
        return sum(self.counts.values())

    def metadata(self) -> dict[str, Any]:
        """The rosbag2 (version 9) bag information."""
        start = self.start_ns or 0
        duration = max(0, self.end_ns - start)
        count = self.message_count
        return {
            "version": 9,
            "storage_identifier": "mcap",
            "relative_file_paths": [self.path.name],
            "duration": {"nanoseconds": duration},
            "starting_time": {"nanoseconds_since_epoch": start},
            "message_count": count,
            "topics_with_message_count": [
                {
                    "topic_metadata": {
                        "name": topic,
                        "type": msgtype,
                        "serialization_format": "cdr",
                        "offered_qos_profiles": [self._qos.get(topic, qos_dict())],
                        "type_description_hash": self._hashes[msgtype],
                    },
                    "message_count": self.counts[topic],
                }
                for topic, msgtype in self.topics.items()
            ],
            "compression_format": "",
            "compression_mode": "",
            "files": [
                {
                    "path": self.path.name,
                    "starting_time": {"nanoseconds_since_epoch": start},
                    "duration": {"nanoseconds": duration},
                    "message_count": count,
                }
            ],
            "custom_data": None,
            "ros_distro": "jazzy",
        }

    def close(self) -> None:
        """Write the MCAP summary and metadata.yaml; idempotent."""
        if self._closed:
            return
        self._closed = True
        info = self.metadata()
        text = io.StringIO()
        yaml.safe_dump(info, text, sort_keys=False)
        self._writer.add_metadata("rosbag2", {"serialized_metadata": text.getvalue()})
        self._writer.finish()
        self._stream.close()
        tmp = self.metadata_path.with_suffix(".yaml.tmp")
        tmp.write_text(yaml.safe_dump({"rosbag2_bagfile_information": info}, sort_keys=False), encoding="utf-8")
        tmp.replace(self.metadata_path)

    def __enter__(self) -> McapBagWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def message_class(msgtype: str) -> Any:
    """The rclpy class of 'pkg/msg/Name'."""
    package, _, name = msgtype.split("/")
    return getattr(importlib.import_module(f"{package}.msg"), name)


class Recorder:
    """Raw subscriptions on a node writing every message of `topics` to a McapBagWriter."""

    def __init__(
        self,
        node: Any,
        writer: McapBagWriter,
        topics: dict[str, str],
        depth: int = 10000,
        forward: dict[str, Any] | None = None,
        sim_clock: bool = False,
    ) -> None:
        """`forward`: topic -> publisher (of another context) that gets every message received, as received
        (``train-calib replay --live``). `sim_clock`: log times from /clock, followed here rather than by the node's
        use_sim_time (whose callback dies on a /clock before 1970, e.g. from a damaged bag): a /clock message that is
        not a valid time is counted in ``undecodable`` and the recording goes on with the last valid one."""
        from .nodes.qos import reliable_qos

        self.node = node
        self.writer = writer
        self.received: Counter[str] = Counter()
        self.undecodable: Counter[str] = Counter()
        qos = reliable_qos(depth)
        self.subscriptions = []
        if sim_clock:
            from rosgraph_msgs.msg import Clock

            self._sim_ns = 0

            def on_clock(msg: Any) -> None:
                sec, nanosec = int(msg.clock.sec), int(msg.clock.nanosec)
                if sec < 0 or not 0 <= nanosec < 1_000_000_000:
                    self.undecodable["/clock"] += 1
                    return
                self._sim_ns = sec * 1_000_000_000 + nanosec

            from rclpy.qos import QoSProfile, ReliabilityPolicy

            clock_qos = QoSProfile(depth=1, reliability=ReliabilityPolicy.BEST_EFFORT)  # as rclpy's TimeSource
            self.subscriptions.append(node.create_subscription(Clock, "/clock", on_clock, clock_qos))

            def now_ns() -> int:
                return self._sim_ns

        else:
            clock = node.get_clock()

            def now_ns() -> int:
                return clock.now().nanoseconds

        forward = forward or {}
        for topic, msgtype in topics.items():
            out = forward.get(topic)

            def callback(data: bytes, topic: str = topic, out: Any = out) -> None:
                writer.write_raw(topic, data, now_ns())
                self.received[topic] += 1
                if out is not None:
                    out.publish(data)

            self.received[topic] += 0
            self.subscriptions.append(node.create_subscription(message_class(msgtype), topic, callback, qos, raw=True))


__all__ = ["METADATA_FILE", "OUTPUT_FILE", "McapBagWriter", "Recorder", "message_class", "qos_dict"]
