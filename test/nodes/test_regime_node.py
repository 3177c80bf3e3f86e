"""regime_node on its own: each DrivingRegime carries the header of the estimate it classifies."""

from __future__ import annotations

import pytest

pytestmark = pytest.mark.ros


def _estimate(k: int, frame_id: str):
    from train_calib_msgs.msg import ResistanceEstimate

    msg = ResistanceEstimate()
    msg.header.stamp.sec, msg.header.frame_id = 100 + k, frame_id
    msg.run_id, msg.s, msg.v = 0, 20.0 * k, 20.0
    msg.effort, msg.acceleration, msg.resistance, msg.v_measured = 0.05, 0.0, 0.05, 20.0
    return msg


@pytest.mark.parametrize("lag", [0, 1])
def test_a_regime_is_published_with_the_stamp_and_frame_of_its_own_estimate(rclpy_context, lag):
    from rclpy.parameter import Parameter
    from rclpy.serialization import deserialize_message
    from train_calib_msgs.msg import DrivingRegime

    from train_calib.nodes.regime_node import RegimeNode

    node = RegimeNode(context=rclpy_context, parameter_overrides=[Parameter("lag_samples", value=lag)])
    published = []
    node.publish = lambda _topic, data: published.append(deserialize_message(data, DrivingRegime))
    try:
        frames = ["track_a", "track_a", "track_b", "track_c"]  # a frame change between samples
        for k, frame in enumerate(frames):
            node._on_estimate(_estimate(k, frame))
            assert len(published) == k + 1 - lag  # lag 1: each sample when the next has come
        node.end_of_input()
        assert [(m.header.stamp.sec, m.header.frame_id) for m in published] == [
            (100 + k, frame) for k, frame in enumerate(frames)
        ]
    finally:
        node.destroy_node()
