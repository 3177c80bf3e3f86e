"""Node parameters: descriptors from the ParamSets, params files, bad values refused with reasons."""

from __future__ import annotations

import subprocess
import sys
import time

import pytest
from repo_paths import DATA, REPO

from train_calib.errors import ConfigError

pytestmark = pytest.mark.ros

FILES = {"track_file": str(DATA / "small_track.yaml"), "train_file": str(DATA / "small_train.yaml")}


def _node(cls, context, overrides=None, params_file=None):
    from rclpy.parameter import Parameter

    values = {**FILES, **(overrides or {})}
    cli = ["--ros-args", "--params-file", str(params_file)] if params_file else None
    return cls(context=context, cli_args=cli, parameter_overrides=[Parameter(k, value=v) for k, v in values.items()])


def _classes():
    from train_calib.nodes.feature_node import FeatureNode
    from train_calib.nodes.gnss_speed_node import GnssSpeedNode
    from train_calib.nodes.regime_node import RegimeNode
    from train_calib.nodes.ukf_node import UkfNode

    return {
        "gnss_speed_node": GnssSpeedNode,
        "ukf_node": UkfNode,
        "regime_node": RegimeNode,
        "feature_node": FeatureNode,
    }


def test_every_parameter_is_declared_with_its_descriptor_and_the_shipped_params_file_loads(rclpy_context):
    from train_calib.nodes.config import default_parameters, node_specs

    for name, cls in _classes().items():
        node = _node(cls, rclpy_context, params_file=REPO / "config" / "train_calib.yaml")
        try:
            for _, spec in node_specs(name):
                assert node.has_parameter(spec.name), (name, spec.name)
                d = node.describe_parameter(spec.name)
                assert d.description == spec.doc and d.read_only == spec.read_only
                if spec.kind is float and spec.low is not None:
                    assert d.floating_point_range[0].from_value == spec.low
                value = node.get_parameter(spec.name).value
                expected = FILES.get(spec.name, default_parameters(name)[spec.name])
                assert (list(value) if spec.kind is tuple else value) == expected, (name, spec.name)
        finally:
            node.destroy_node()
    node = _node(_classes()["ukf_node"], rclpy_context)
    d = node.describe_parameter("meas_std_s")
    assert "[m]" in d.description and d.floating_point_range[0].to_value == float("inf")
    assert node.describe_parameter("carry_over").additional_constraints == "one of: reset, keep"
    assert node.describe_parameter("output_depth").read_only
    node.destroy_node()


def test_integer_for_a_double_in_a_params_file_is_taken_as_a_double(rclpy_context, tmp_path):
    params = tmp_path / "p.yaml"
    params.write_text("gnss_speed_node:\n  ros__parameters:\n    max_cross_track: 25\n    reacquire_after: 4\n")
    node = _node(_classes()["gnss_speed_node"], rclpy_context, params_file=params)
    try:
        assert node.get_parameter("max_cross_track").value == 25.0
        assert node.ingest.config.max_cross_track == 25.0 and node.ingest.config.reacquire_after == 4
    finally:
        node.destroy_node()


@pytest.mark.parametrize(
    ("node", "overrides", "message"),
    [
        ("gnss_speed_node", {"max_cross_track": -5.0}, "max_cross_track"),
        ("gnss_speed_node", {"position_std": 0.0}, "position_std: 0 m is out of range: must be greater than 0 m"),
        ("gnss_speed_node", {"standstill_speed": 5.0, "max_speed": 4.0}, "must be below max_speed (4 m/s)"),
        ("gnss_speed_node", {"start_station": "Nowhere"}, "start_station: track small-test-line has no station"),
        ("gnss_speed_node", {"track_file": "/no/such/track.yaml"}, "/no/such/track.yaml: track file not found"),
        ("ukf_node", {"carry_over": "sometimes"}, "carry_over: 'sometimes' is not one of reset, keep"),
        ("ukf_node", {"kappa": -6.0}, "kappa"),
        ("feature_node", {"brake_step_edges": [0.0, 20.0, 10.0]}, "brake_step_edges: expected a non-empty strictly"),
    ],
)
def test_a_bad_value_at_start_stops_the_node_with_one_line(rclpy_context, node, overrides, message):
    with pytest.raises(ConfigError) as err:
        _node(_classes()[node], rclpy_context, overrides).destroy_node()
    text = str(err.value)
    assert message in text and "\n" not in text


def test_a_bad_value_at_run_time_is_refused_with_the_reason_and_a_good_one_is_applied(rclpy_context):
    from rclpy.parameter import Parameter

    gnss = _node(_classes()["gnss_speed_node"], rclpy_context)
    regime = _node(_classes()["regime_node"], rclpy_context)
    ukf = _node(_classes()["ukf_node"], rclpy_context)
    try:
        cases = [
            (gnss, "max_cross_track", -1.0, "out of range"),  # rclpy's range check (descriptor)
            (gnss, "position_std", 0.0, "position_std: 0 m is out of range: must be greater than 0 m"),
            (gnss, "standstill_speed", 150.0, "standstill_speed: 150 m/s must be below max_speed (100 m/s)"),
            (
                gnss,
                "start_station",
                "Nowhere",
                "track small-test-line has no station 'Nowhere' (stations: Alpha, Beta)",
            ),
            (gnss, "input_depth", 5, "read-only"),
            (gnss, "track_file", "other.yaml", "read-only"),
            (ukf, "carry_over", "sometimes", "carry_over: 'sometimes' is not one of reset, keep"),
            (regime, "effort_tolerance", "wide", "Wrong parameter type"),
        ]
        for node, name, value, reason in cases:
            (result,) = node.set_parameters([Parameter(name, value=value)])
            assert not result.successful and reason in result.reason, (name, result.reason)
        assert gnss.ingest.config.position_std == 4.0
        # good values take effect: the ingest at once, the regime rule at once, the UKF at the next run
        ok = gnss.set_parameters_atomically(
            [Parameter("start_station", value="Beta"), Parameter("max_cross_track", value=12.0)]
        )
        assert ok.successful and gnss.ingest.config.max_cross_track == 12.0 and gnss.ingest.settings.start_s == 2900.0
        for _ in range(3):  # the HMM's belief after a few samples ...
            regime.classifier.classify(0.3, 0.5, 10.0)
        assert regime.classifier.probabilities is not None
        (ok,) = regime.set_parameters([Parameter("switch_probability", value=0.05)])
        assert ok.successful and regime.classifier.probabilities is None  # ... restarts with a parameter change
        assert ("classifier restarts (parameter changes)", 1) in regime.diagnostic_values()
        (ok,) = regime.set_parameters([Parameter("method", value="rule")])  # the paper's stateless rule
        assert ok.successful and regime.classifier.config.method == "rule"
        assert regime.classifier.classify(0.3, 0.5, 10.0) == 1  # traction
        (ok,) = regime.set_parameters([Parameter("effort_tolerance", value=0.5)])
        assert ok.successful and regime.classifier.classify(0.3, 0.5, 10.0) == 3  # now coasting
        (ok,) = ukf.set_parameters([Parameter("carry_over", value="keep")])
        assert ok.successful and ukf._next_config.carry_over == "keep" and ukf.estimator.config.carry_over == "reset"
    finally:
        for node in (gnss, regime, ukf):
            node.destroy_node()


def _wait_for_diagnostics_of(context, node_name: str, timeout_s: float = 60.0) -> bool:
    """True once `node_name` has published on /diagnostics (it is up and spinning)."""
    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.executors import SingleThreadedExecutor

    seen = []
    node = rclpy.create_node("diagnostics_listener", context=context)
    node.create_subscription(
        DiagnosticArray, "/diagnostics", lambda m: seen.extend(s.name for s in m.status if node_name in s.name), 10
    )
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    deadline = time.monotonic() + timeout_s
    try:
        while not seen and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.1)
    finally:
        executor.shutdown()
        node.destroy_node()
    return bool(seen)


def test_node_executable_refuses_a_bad_value_in_one_line_and_stops_cleanly_on_sigint(rclpy_context):
    bad = subprocess.run(
        [sys.executable, "-m", "train_calib.nodes.regime_node", "--ros-args", "-p", "effort_tolerance:=-1.0"],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert bad.returncode == 2
    assert bad.stderr.strip().splitlines()[-1].startswith("regime_node: error: ")
    assert "effort_tolerance" in bad.stderr

    proc = subprocess.Popen(
        [sys.executable, "-m", "train_calib.nodes.regime_node", "--ros-args", "-p", "diagnostics_period:=0.2"],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    try:
        # SIGINT once the node spins (a fixed sleep raced with the imports on a loaded machine)
        assert _wait_for_diagnostics_of(rclpy_context, "regime_node"), "regime_node published no /diagnostics"
        assert proc.poll() is None, proc.stdout.read()
        proc.send_signal(2)
        out, _ = proc.communicate(timeout=15)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, out
    assert "Traceback" not in out
