"""Bags in the rosbag2 layout with MCAP storage: written here, read by rosbags and by mcap."""

from __future__ import annotations

import numpy as np
import pytest

from train_calib import bagio
from train_calib.errors import BagError


def _write_inputs(path, n=5):
    NavSatFix = bagio.msg_class("sensor_msgs/msg/NavSatFix")
    Status = bagio.msg_class("sensor_msgs/msg/NavSatStatus")
    Twist = bagio.msg_class("geometry_msgs/msg/TwistStamped")
    TwistMsg = bagio.msg_class("geometry_msgs/msg/Twist")
    Vector3 = bagio.msg_class("geometry_msgs/msg/Vector3")
    Power = bagio.msg_class("train_calib_msgs/msg/TractionPower")
    with bagio.BagWriter(path, bagio.INPUT_TOPICS) as writer:
        for i in range(n):
            t = 1_700_000_000_000_000_000 + i * 1_000_000_000
            header = bagio.make_header(t, "gnss")
            fix = NavSatFix(
                header=header,
                status=Status(status=0, service=1),
                latitude=52.0 + i * 1e-4,
                longitude=5.0,
                altitude=0.0,
                position_covariance=np.full(9, 16.0),
                position_covariance_type=2,
            )
            writer.write(bagio.GNSS_TOPIC, fix, t)
            speed = Twist(
                header=header,
                twist=TwistMsg(linear=Vector3(x=10.0 + i, y=0.0, z=0.0), angular=Vector3(x=0.0, y=0.0, z=0.0)),
            )
            writer.write(bagio.SPEED_TOPIC, speed, t + 1)
            writer.write(bagio.POWER_TOPIC, Power(header=header, power_consumed=1e6 * i, power_regenerated=0.0), t + 2)
    return path


def test_round_trip_with_both_readers(tmp_path):
    bag = _write_inputs(tmp_path / "run")
    assert (bag / "metadata.yaml").is_file()
    assert bagio.bag_topics(bag) == bagio.INPUT_TOPICS
    messages = list(bagio.iter_bag(bag))
    assert [m.topic for m in messages[:3]] == [bagio.GNSS_TOPIC, bagio.SPEED_TOPIC, bagio.POWER_TOPIC]
    assert [m.log_time_ns for m in messages] == sorted(m.log_time_ns for m in messages)
    speeds = [m.decode().twist.linear.x for m in messages if m.topic == bagio.SPEED_TOPIC]
    assert speeds == [10.0, 11.0, 12.0, 13.0, 14.0]

    from rosbags.rosbag2 import Reader

    with Reader(bag) as reader:
        assert reader.message_count == 15
        store = bagio.typestore()
        powers = [
            store.deserialize_cdr(raw, c.msgtype).power_consumed
            for c, _, raw in reader.messages()
            if c.topic == bagio.POWER_TOPIC
        ]
    assert powers == [0.0, 1e6, 2e6, 3e6, 4e6]

    # the bare .mcap file opens too, and its schemas carry the message definitions
    (mcap_file,) = bagio.mcap_files(bag)
    assert len(list(bagio.iter_bag(mcap_file, [bagio.SPEED_TOPIC]))) == 5
    from mcap.reader import make_reader

    with open(mcap_file, "rb") as f:
        summary = make_reader(f).get_summary()
    schema = next(s for s in summary.schemas.values() if s.name == "train_calib_msgs/msg/TractionPower")
    assert b"float64 power_consumed" in schema.data


def test_rclpy_and_rosbags_serialize_identically():
    from rclpy.serialization import deserialize_message, serialize_message
    from train_calib_msgs.msg import ResistanceEstimate

    msg = ResistanceEstimate(r0=0.01, r1=2e-4, r2=4e-5, effort=0.3, run_id=7, health=1)
    msg.covariance[6] = 1.5
    msg.header.stamp.sec, msg.header.frame_id = 12, "track"
    cls = bagio.msg_class("train_calib_msgs/msg/ResistanceEstimate")
    decoded = bagio.typestore().deserialize_cdr(serialize_message(msg), cls.__msgtype__)
    assert (decoded.r0, decoded.run_id, decoded.covariance[6], decoded.header.frame_id) == (0.01, 7, 1.5, "track")
    ours, theirs = bytes(bagio.typestore().serialize_cdr(decoded, cls.__msgtype__)), serialize_message(msg)
    assert len(ours) == len(theirs)
    # rclpy (Fast-CDR) leaves alignment padding uninitialised, rosbags writes zeros there: every other byte is equal
    differing = [i for i, (a, b) in enumerate(zip(ours, theirs)) if a != b]
    assert all(ours[i] == 0 for i in differing), differing
    assert deserialize_message(ours, ResistanceEstimate) == msg


def test_missing_and_damaged_bags_give_one_line_errors(tmp_path):
    with pytest.raises(BagError, match="no such bag"):
        list(bagio.iter_bag(tmp_path / "nothing"))
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(BagError, match=r"no metadata\.yaml and no \.mcap"):
        bagio.mcap_files(empty)
    bag = _write_inputs(tmp_path / "run", n=50)
    (mcap_file,) = bagio.mcap_files(bag)
    data = mcap_file.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) // 2])
    with pytest.raises(BagError) as err:
        list(bagio.iter_bag(cut))
    assert str(err.value).startswith(f"{cut}: ") and "\n" not in str(err.value)
    garbage = tmp_path / "garbage.mcap"
    garbage.write_bytes(b"not an mcap file at all")
    with pytest.raises(BagError, match=r"garbage\.mcap"):
        list(bagio.iter_bag(garbage))


def test_writer_refuses_to_overwrite(tmp_path):
    bag = _write_inputs(tmp_path / "run", n=1)
    with pytest.raises(BagError, match="already exists"):
        bagio.BagWriter(bag, bagio.INPUT_TOPICS)
