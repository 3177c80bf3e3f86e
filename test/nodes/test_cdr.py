"""nodes/cdr.py: the views decoded from serialized input messages equal rclpy's own deserialization, field for
field, on random messages, on the bundled bags' bytes (rosbags' serializer) and on every header length; other
encodings and malformed bytes go to rclpy."""

from __future__ import annotations

import math

import numpy as np
import pytest
from geometry_msgs.msg import TwistStamped
from msgfill import fill
from rclpy.serialization import deserialize_message, serialize_message
from sensor_msgs.msg import NavSatFix
from train_calib_msgs.msg import DrivingFeatures, DrivingRegime, ResistanceEstimate, TrackMeasurement, TractionPower

from train_calib import bagio, paths
from train_calib.ingest import fix_from_msg, power_from_msg, speed_from_msg
from train_calib.nodes import cdr
from train_calib.nodes.convert import measurement_from_msg, regime_input_from_msg

INPUT_TYPES = (NavSatFix, TwistStamped, TractionPower, TrackMeasurement, ResistanceEstimate, DrivingRegime)
SPECIAL = (math.nan, math.inf, -math.inf, -0.0, 5e-324, 1.7976931348623157e308)
FRAME_IDS = ("", "a", "ab", "abc", "abcd", "abcde", "intercity_32km", "tunnel_line_37km", "Zürich–Genève")


def _plain(x):
    """Field name -> value recursively (rclpy message or view); floats by their bits, arrays as lists."""
    if hasattr(x, "get_fields_and_field_types"):
        return {f: _plain(getattr(x, f)) for f in x.get_fields_and_field_types()}
    if hasattr(x, "_fields"):  # a view
        return {f: _plain(getattr(x, f)) for f in x._fields}
    if isinstance(x, (np.ndarray, list, tuple)):
        return [_plain(v) for v in (x.tolist() if isinstance(x, np.ndarray) else x)]
    if isinstance(x, float):
        return ("float", x.hex())
    return (type(x).__name__, x)


def _randomise(msg, rng):
    """Random values (special floats among them) in every float field of msg, recursively."""
    for name, ftype in msg.get_fields_and_field_types().items():
        value = getattr(msg, name)
        if ftype == "double":
            setattr(msg, name, float(rng.choice(SPECIAL)) if rng.random() < 0.3 else float(rng.normal(0, 1e4)))
        elif ftype.startswith("double["):
            value[:] = rng.normal(0, 1e3, len(value))
        elif hasattr(value, "get_fields_and_field_types"):
            _randomise(value, rng)
    return msg


@pytest.mark.parametrize("msg_type", INPUT_TYPES, ids=lambda c: c.__name__)
def test_views_equal_rclpy_on_random_messages(msg_type):
    rng = np.random.default_rng(7)
    layout = cdr.layout(msg_type)
    assert layout.fast
    for k in range(200):
        msg = _randomise(fill(msg_type()), rng)
        msg.header.frame_id = FRAME_IDS[k % len(FRAME_IDS)]
        msg.header.stamp.sec = int(rng.integers(-(2**31), 2**31))
        msg.header.stamp.nanosec = int(rng.integers(0, 10**9))
        data = serialize_message(msg)
        view = layout.decode(data)
        assert list(view._fields) == list(msg_type.get_fields_and_field_types())
        assert _plain(view) == _plain(deserialize_message(data, msg_type))


def test_views_of_the_bundled_bag_bytes_read_as_the_messages():
    """The bags' bytes (rosbags' serializer, as the replay publishes them): the readers give equal samples."""
    readers = {bagio.GNSS_TOPIC: fix_from_msg, bagio.SPEED_TOPIC: speed_from_msg, bagio.POWER_TOPIC: power_from_msg}
    types = {bagio.GNSS_TOPIC: NavSatFix, bagio.SPEED_TOPIC: TwistStamped, bagio.POWER_TOPIC: TractionPower}
    seen = dict.fromkeys(readers, 0)
    for m in bagio.iter_bag(paths.bags_dir() / "tunnel_line_37km_1s_00", list(readers)):
        if seen[m.topic] >= 300:
            continue
        seen[m.topic] += 1
        view = cdr.layout(types[m.topic]).decode(m.data)
        assert _plain(view) == _plain(deserialize_message(m.data, types[m.topic]))
        a, b = readers[m.topic](view), readers[m.topic](m.decode())
        assert repr(a) == repr(b)  # NaN-safe equality of the samples
    assert all(n == 300 for n in seen.values())


def test_chain_readers_give_equal_records():
    rng = np.random.default_rng(3)
    for msg_type, reader in ((TrackMeasurement, measurement_from_msg), (ResistanceEstimate, regime_input_from_msg),
                             (DrivingRegime, regime_input_from_msg)):  # fmt: skip
        msg = _randomise(fill(msg_type()), rng)
        msg.header.frame_id = "intercity_32km"
        view = cdr.layout(msg_type).decode(serialize_message(msg))
        assert repr(reader(view)) == repr(reader(msg))
        assert view.header.frame_id == "intercity_32km"


def test_big_endian_cdr_is_decoded_by_rclpy():
    store = bagio.typestore()
    cls = store.types["geometry_msgs/msg/TwistStamped"]
    Header, Time = store.types["std_msgs/msg/Header"], store.types["builtin_interfaces/msg/Time"]
    Twist, Vector3 = store.types["geometry_msgs/msg/Twist"], store.types["geometry_msgs/msg/Vector3"]
    msg = cls(Header(Time(12, 345), "frame"), Twist(Vector3(27.5, 0.0, 0.0), Vector3(0.0, 0.0, 0.0)))
    big = bytes(store.serialize_cdr(msg, "geometry_msgs/msg/TwistStamped", little_endian=False))
    assert big[:2] == b"\x00\x00"  # CDR_BE: not the fast path's
    view = cdr.layout(TwistStamped).decode(big)
    assert isinstance(view, TwistStamped)  # rclpy's message
    assert view.twist.linear.x == 27.5 and view.header.stamp.nanosec == 345 and view.header.frame_id == "frame"


def test_types_with_sequences_are_decoded_by_rclpy():
    layout = cdr.layout(DrivingFeatures)
    assert not layout.fast
    msg = fill(DrivingFeatures())
    assert _plain(layout.decode(serialize_message(msg))) == _plain(msg)


@pytest.mark.parametrize("cut", [1, 7, 20, 60])
def test_truncated_bytes_are_refused(cut):
    msg = fill(TrackMeasurement())
    msg.header.frame_id = "intercity_32km"
    data = serialize_message(msg)
    with pytest.raises(Exception):  # noqa: B017 - rclpy's error type is not public
        cdr.layout(TrackMeasurement).decode(data[: len(data) - cut])


def test_a_string_without_its_terminator_is_left_to_rclpy():
    msg = fill(DrivingRegime())
    msg.header.frame_id = "abc"
    data = bytearray(serialize_message(msg))
    assert data[16:20] == b"abc\x00"
    data[19] = ord("d")  # the NUL gone: not what the fast path reads
    view = cdr.layout(DrivingRegime).decode(bytes(data))
    assert isinstance(view, DrivingRegime)
    assert _plain(view) == _plain(deserialize_message(bytes(data), DrivingRegime))


def test_the_environment_switch_gives_rclpy_messages(monkeypatch):
    from train_calib.nodes.common import RCLPY_DESERIALIZE_ENV, TrainCalibNode

    msg = fill(TwistStamped())
    data = serialize_message(msg)
    monkeypatch.delenv(RCLPY_DESERIALIZE_ENV, raising=False)
    view = TrainCalibNode.input_decoder(TwistStamped)(data)
    monkeypatch.setenv(RCLPY_DESERIALIZE_ENV, "1")
    message = TrainCalibNode.input_decoder(TwistStamped)(data)
    assert not isinstance(view, TwistStamped) and isinstance(message, TwistStamped)
    assert _plain(view) == _plain(message) == _plain(msg)


INTERFACE_PACKAGES = (
    "std_msgs",
    "builtin_interfaces",
    "geometry_msgs",
    "sensor_msgs",
    "nav_msgs",
    "diagnostic_msgs",
    "shape_msgs",
    "trajectory_msgs",
    "visualization_msgs",
    "rosgraph_msgs",
    "rcl_interfaces",
    "statistics_msgs",
    "unique_identifier_msgs",
    "actionlib_msgs",
    "stereo_msgs",
    "train_calib_msgs",
)


def test_every_installed_message_type_decodes_as_rclpy_does():
    """The layouts are derived from the introspection, so every type is checked, not only the nodes' inputs: fast
    path or rclpy's, each type's filled message reads back as rclpy reads it (byte fields as bytes, arrays of
    messages and sequences through rclpy)."""
    import importlib

    checked = fast = 0
    for package in INTERFACE_PACKAGES:
        try:
            module = importlib.import_module(package + ".msg")
        except ImportError:
            continue
        for name in dir(module):
            cls = getattr(module, name)
            if not (isinstance(cls, type) and hasattr(cls, "get_fields_and_field_types")):
                continue
            try:  # a few filled messages exceed a bounded sequence: rclpy refuses them, nothing to compare
                data = serialize_message(fill(cls()))
                reference = deserialize_message(data, cls)
            except Exception:
                continue
            layout = cdr.layout(cls)
            assert _plain(layout.decode(data)) == _plain(reference), f"{package}/{name}"
            checked += 1
            fast += layout.fast
    assert checked >= 100 and fast >= 60, (checked, fast)  # 143 and 85 with the pinned wheels
