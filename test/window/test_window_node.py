"""window_calib_node in process: the same numbers as the core, the regime join, inactivity without power."""

from __future__ import annotations

import dataclasses
import math
import time

import numpy as np
import pytest
from build_context import EXPECTED_FIT_PATH
from repo_paths import DATA
from window_synthetic import euler_run

from train_calib.train import load_train
from train_calib.window import WindowConfig, calibrate_series

pytestmark = pytest.mark.ros

TRAIN_FILE = str(DATA / "small_train.yaml")
TRAIN = load_train(TRAIN_FILE)
FIELDS = ("window_length", "sample_count", "gof_kind", "gof_value", "a", "b", "c", "r0", "r1", "r2", "speed_span")


@pytest.fixture(scope="module")
def run():
    return euler_run(train=TRAIN, speed_noise=0.0)


class Harness:
    """A test node publishing measurements and regimes and collecting the window results."""

    def __init__(self, context, **overrides):
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.node import Node
        from rclpy.parameter import Parameter
        from train_calib_msgs.msg import DrivingRegime, TrackMeasurement, WindowResistance

        from train_calib.nodes.common import reliable_qos
        from train_calib.nodes.window_calib_node import WindowCalibNode

        values = {"train_file": TRAIN_FILE, **overrides}
        self.node = WindowCalibNode(
            context=context, parameter_overrides=[Parameter(k, value=v) for k, v in values.items()]
        )
        self.io = Node("window_test_io", context=context)
        qos = reliable_qos(10000)
        self.meas_pub = self.io.create_publisher(TrackMeasurement, "/train_calib/measurement", qos)
        self.regime_pub = self.io.create_publisher(DrivingRegime, "/train_calib/regime", qos)
        self.received = []
        self.io.create_subscription(WindowResistance, "/train_calib/window_resistance", self.received.append, qos)
        self.executor = SingleThreadedExecutor(context=context)
        self.executor.add_node(self.node)
        self.executor.add_node(self.io)
        self._wait(lambda: self.meas_pub.get_subscription_count() and self.node.count_publishers("/train_calib/regime"))

    def _wait(self, condition, timeout=20.0):
        end = time.monotonic() + timeout
        while not condition() and time.monotonic() < end:
            self.executor.spin_once(timeout_sec=0.02)
        assert condition(), "timed out"

    def measurement(self, m):
        from train_calib.nodes.convert import measurement_to_msg

        self.meas_pub.publish(measurement_to_msg(m, "test-line"))

    def regime(self, stamp_ns, regime):
        from train_calib_msgs.msg import DrivingRegime

        from train_calib.nodes.convert import time_msg

        msg = DrivingRegime(regime=int(regime))
        if hasattr(msg, "phase"):  # the paper's phase, which the node takes where the message has it
            msg.phase = int(regime)
        msg.header.stamp = time_msg(int(stamp_ns))
        self.regime_pub.publish(msg)

    def settle(self, handled: int, published: int | None = None):
        self._wait(lambda: sum(self.node.handled.values()) >= handled)
        if published is not None:
            self._wait(lambda: len(self.received) >= published)
        for _ in range(10):
            self.executor.spin_once(timeout_sec=0.01)

    def close(self):
        self.executor.shutdown()
        self.node.destroy_node()
        self.io.destroy_node()


def _head(series, n):
    return dataclasses.replace(series, **{f.name: getattr(series, f.name)[:n] for f in dataclasses.fields(series)})


def _assert_same(messages, fits):
    assert len(messages) == len(fits)
    for msg, fit in zip(messages, fits):
        assert msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec == fit.stamp_ns
        assert msg.header.frame_id == "test-line"
        assert msg.regime == fit.regime and msg.ill_posed == fit.ill_posed and msg.run_id == fit.run_id
        for name in FIELDS:
            a, b = getattr(msg, name), getattr(fit, name)
            assert (math.isnan(a) and math.isnan(b)) or a == pytest.approx(b, rel=1e-12, abs=1e-15), name
        # the window's resistance at its mean speed and the pooled r(v), as the core computes them
        published = (msg.resistance_speed, msg.resistance_at_speed, msg.resistance_at_speed_std, msg.pooled_r0,
                     msg.pooled_r1, msg.pooled_r2, *msg.pooled_covariance)  # fmt: skip
        core = (fit.resistance_speed, fit.resistance_at_speed, fit.resistance_at_speed_std, *fit.pooled,
                *fit.pooled_covariance)  # fmt: skip
        assert np.allclose(published, core, rtol=1e-12, atol=0.0, equal_nan=True)
        assert msg.pooled_windows == fit.pooled_windows


def test_node_publishes_the_core_numbers_with_regimes_joined_by_stamp(rclpy_context, run):
    """Regimes arrive three samples late (the UKF and regime nodes run behind): the node waits for them."""
    n = 200  # departure, acceleration to 25 m/s, cruise, acceleration to 38 m/s
    series = _head(run.series, n)
    regimes = run.regime[:n]
    expected = calibrate_series(series, TRAIN, WindowConfig(), regimes=regimes)
    h = Harness(rclpy_context)
    try:
        for i in range(n + 3):
            if i < n:
                h.measurement(series[i])
            if i >= 3:
                h.regime(series.stamp_ns[i - 3], regimes[i - 3])
            if i % 50 == 0:
                h.settle(handled=min(i + 1, n) + max(0, i - 2))
        h.settle(handled=2 * n, published=len(expected))
        assert h.node.pending == 0
        _assert_same(h.received, expected)
        well = [m for m in h.received if not m.ill_posed]
        assert len(well) > 40
        assert well[-1].r0 == pytest.approx(run.truth.r0, rel=1e-7)
        assert h.received[-1].pooled_windows >= 3 and math.isfinite(h.received[-1].resistance_at_speed)
        assert h.node.calibrator.counts["well_posed"] == len(well)
        status = h.node.diagnostic_status()
        values = {kv.key: kv.value for kv in status.values}
        assert status.level == b"\x00" and values["windows well posed"] == str(len(well))
        assert values["window fit"] == EXPECTED_FIT_PATH
        assert int(values["windows by the reference solver"]) < len(expected) / 4
        assert values["/train_calib/window_resistance published"] == str(len(expected))
    finally:
        h.close()


def test_without_regime_node_the_regime_comes_from_power(rclpy_context, run):
    series = _head(run.series, 120)
    expected = calibrate_series(series, TRAIN, WindowConfig(), regimes=None)
    h = Harness(rclpy_context, max_regime_wait=5)
    try:
        for i in range(120):
            h.measurement(series[i])
            if i % 40 == 0:
                h.settle(handled=i + 1)
        h.settle(handled=120)
        assert h.node.pending == 0  # no regime after max_regime_wait measurements: regime_node is absent
        h.node.end_of_input()
        h.settle(handled=120, published=len(expected))
        _assert_same(h.received, expected)
    finally:
        h.close()


def test_end_of_input_releases_held_measurements(rclpy_context, run):
    series, regimes = run.series, run.regime
    h = Harness(rclpy_context)
    try:
        h.regime(series.stamp_ns[0], regimes[0])  # regime_node is there, but the others are late
        for i in range(20):
            h.measurement(series[i])
        h.settle(handled=21)
        assert h.node.pending == 19
        h.node.end_of_input()
        assert h.node.pending == 0
        expected = calibrate_series(_head(series, 20), TRAIN, WindowConfig(), regimes=[regimes[0]] + [0] * 19)
        h.settle(handled=21, published=len(expected))
        _assert_same(h.received, expected)
    finally:
        h.close()


def test_inactive_without_power_and_parameters_at_run_time(rclpy_context, run):
    from rclpy.parameter import Parameter

    h = Harness(rclpy_context, regime_source="power")
    try:
        for i in range(30):
            h.measurement(dataclasses.replace(run.series[i], power_valid=False))
        h.settle(handled=30)
        assert h.received == []
        status = h.node.diagnostic_status()
        assert status.level == b"\x01" and "inactive" in status.message
        (bad,) = h.node.set_parameters([Parameter("gof", value="l1")])
        assert not bad.successful and "gof: 'l1' is not one of sae, rmse" in bad.reason
        (bad,) = h.node.set_parameters([Parameter("r2_bounds", value=[1e-4, 1e-5])])
        assert not bad.successful and "low <= high" in bad.reason
        (ok,) = h.node.set_parameters([Parameter("window_length", value=10.0)])
        assert ok.successful and h.node.calibrator.config.window_length == 10.0
        assert {kv.key: kv.value for kv in h.node.diagnostic_status().values}["window fit"] == EXPECTED_FIT_PATH
        for i in range(30, 60):
            h.measurement(run.series[i])
        h.settle(handled=60, published=29)
        assert max(m.sample_count for m in h.received) == 10
        assert np.all([m.window_length == 10.0 for m in h.received])
    finally:
        h.close()


def test_executable_refuses_a_bad_parameter_in_one_line():
    import subprocess
    import sys

    bad = subprocess.run(
        [sys.executable, "-m", "train_calib.nodes.window_calib_node", "--ros-args", "-p", f"train_file:={TRAIN_FILE}",
         "-p", "window_length:=1.0"],
        capture_output=True, text=True, timeout=60,
    )  # fmt: skip
    assert bad.returncode == 2
    last = bad.stderr.strip().splitlines()[-1]
    assert last.startswith("window_calib_node: error: ") and "window_length" in last
