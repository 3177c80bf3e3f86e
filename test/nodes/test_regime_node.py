"""regime_node on its own: each DrivingRegime carries the header of the estimate it classifies; the traction power
of the estimate's measurement reaches the imm as the offline pipeline passes it."""

from __future__ import annotations

import pytest

pytestmark = pytest.mark.ros


def _estimate(k: int, frame_id: str, v: float = 20.0, run_id: int = 0):
    from train_calib_msgs.msg import ResistanceEstimate

    msg = ResistanceEstimate()
    msg.header.stamp.sec, msg.header.frame_id = 100 + k, frame_id
    msg.run_id, msg.s, msg.v = run_id, 20.0 * k, v
    msg.effort, msg.acceleration, msg.resistance, msg.v_measured = 0.05, 0.0, 0.05, v
    return msg


def _measurement(k: int, consumed_w: float = 0.0, regenerated_w: float = 0.0, valid: bool = True, run_id: int = 0):
    from train_calib_msgs.msg import TrackMeasurement

    msg = TrackMeasurement()
    msg.header.stamp.sec = 100 + k
    msg.run_id, msg.s, msg.v = run_id, 20.0 * k, 20.0
    msg.power_valid, msg.power_consumed, msg.power_regenerated = valid, consumed_w, regenerated_w
    return msg


def _node(rclpy_context, **params):
    from rclpy.parameter import Parameter
    from rclpy.serialization import deserialize_message
    from train_calib_msgs.msg import DrivingRegime

    from train_calib.nodes.regime_node import RegimeNode

    node = RegimeNode(context=rclpy_context, parameter_overrides=[Parameter(k, value=v) for k, v in params.items()])
    published = []
    node.publish = lambda _topic, data: published.append(deserialize_message(data, DrivingRegime))
    return node, published


@pytest.mark.parametrize("lag", [0, 1])
def test_a_regime_is_published_with_the_stamp_and_frame_of_its_own_estimate(rclpy_context, lag):
    node, published = _node(rclpy_context, lag_samples=lag)
    try:
        frames = ["track_a", "track_a", "track_b", "track_c"]  # a frame change between samples
        for k, frame in enumerate(frames):
            node._on_measurement(_measurement(k))  # the measurement comes first (ukf_node answers it)
            node._on_estimate(_estimate(k, frame))
            assert len(published) == k + 1 - lag  # lag 1: each sample when the next has come
        node.end_of_input()
        assert [(m.header.stamp.sec, m.header.frame_id) for m in published] == [
            (100 + k, frame) for k, frame in enumerate(frames)
        ]
    finally:
        node.destroy_node()


def test_the_power_of_each_estimates_measurement_reaches_the_classifier_as_in_the_pipeline(rclpy_context):
    """Estimates at a held 72 km/h: the speeds alone say CRUISING; with neither power drawn nor regenerated the
    imm says COASTING within a few samples, with regenerated power a hold again (downhill, braking). The node pairs
    each estimate with its own measurement, also when the measurement comes after the estimate; one without a
    measurement (none comes) goes without power."""
    from train_calib.estimation import RegimeConfig
    from train_calib.estimation.effort import PowerEffort
    from train_calib.estimation.regime_model import power_state
    from train_calib.nodes.convert import measurement_from_msg, regime_input_from_msg
    from train_calib.nodes.regime_node import MEASUREMENT_WAIT
    from train_calib.paths import train_file
    from train_calib.pipeline import RegimeStream
    from train_calib.train import load_train

    node, published = _node(rclpy_context, lag_samples=0)  # causal: one message per estimate at once
    v = 20.0
    n = 40
    # traction power (1 MW) for 10 s, nothing for 20, regenerated for 10; stamp 15 has no measurement at all
    powers = [(1e6, 0.0)] * 10 + [(0.0, 0.0)] * 20 + [(0.0, 5e5)] * 10
    measurements = {k: _measurement(k, *powers[k]) for k in range(n) if k != 15}
    estimates = [_estimate(k, "", v) for k in range(n)]
    try:
        for k in range(n):
            if k % 7 == 3:  # the estimate first, its measurement after it
                node._on_estimate(estimates[k])
                if k in measurements:
                    node._on_measurement(measurements[k])
            else:
                if k in measurements:
                    node._on_measurement(measurements[k])
                node._on_estimate(estimates[k])
            assert node.pending <= 1  # held only until its measurement has come (or a later one)
        node.end_of_input()
        got = [m.regime for m in published]
        stream = RegimeStream(RegimeConfig(lag_samples=0))
        effort = PowerEffort(load_train(train_file("virm6")))
        expected = []
        for k in range(n):
            m = measurement_from_msg(measurements[k]) if k in measurements else None
            expected.append(stream.push(regime_input_from_msg(estimates[k]), power_state(m, effort), m)[0][1])
        assert got == expected
        from train_calib.regime_codes import COASTING, CRUISING

        assert got[5:10] == [CRUISING] * 5  # a hold under traction power
        assert got[13:15] == [COASTING] * 2 and got[16:30] == [COASTING] * 14  # no power: coasting within 3 s
        assert got[33:40] == [CRUISING] * 7  # regenerated, the speed held: a hold downhill
        speeds_alone = RegimeStream(RegimeConfig(lag_samples=0))
        alone = [speeds_alone.push(regime_input_from_msg(e))[0][1] for e in estimates]
        assert alone[13:30].count(COASTING) == 0  # without the power: all held speeds are a hold
        assert MEASUREMENT_WAIT >= 10
    finally:
        node.destroy_node()


def test_without_measurements_the_estimates_go_after_the_wait_or_at_the_end(rclpy_context):
    from train_calib.nodes.regime_node import MEASUREMENT_WAIT

    node, published = _node(rclpy_context, lag_samples=0)
    try:
        for k in range(MEASUREMENT_WAIT + 5):
            node._on_estimate(_estimate(k, ""))
        assert len(published) == 5 and node.pending == MEASUREMENT_WAIT
        node.end_of_input()
        assert len(published) == MEASUREMENT_WAIT + 5 and node.pending == 0
        assert [m.header.stamp.sec for m in published] == [100 + k for k in range(MEASUREMENT_WAIT + 5)]
    finally:
        node.destroy_node()
