"""config/train_calib.yaml equals the core ParamSet defaults; the launch file describes the graph."""

from __future__ import annotations

import importlib.util
from importlib import metadata

import pytest
import yaml
from repo_paths import REPO

from train_calib.estimation import FeatureConfig, RegimeConfig, UKFConfig
from train_calib.ingest import IngestConfig
from train_calib.nodes.config import GRAPH_NODES, NODE_PARAMS, default_parameters, node_specs, params_yaml
from train_calib.window import WindowConfig

CONFIG = REPO / "config" / "train_calib.yaml"


def test_params_file_holds_every_parameter_of_every_node_with_the_core_default():
    data = yaml.safe_load(CONFIG.read_text())
    assert set(data) == set(NODE_PARAMS)
    for node in NODE_PARAMS:
        values = data[node]["ros__parameters"]
        assert values == default_parameters(node), node
    # the core sets are there with their own defaults (not copies that could drift)
    assert data["ukf_node"]["ros__parameters"]["meas_std_s"] == UKFConfig().meas_std_s == 4.0
    assert data["ukf_node"]["ros__parameters"]["carry_over"] == "reset"
    assert data["regime_node"]["ros__parameters"]["effort_tolerance"] == RegimeConfig().effort_tolerance == 0.025
    assert data["feature_node"]["ros__parameters"]["brake_step_edges"] == list(FeatureConfig().brake_step_edges)
    assert data["gnss_speed_node"]["ros__parameters"]["position_std"] == IngestConfig().position_std
    assert data["window_calib_node"]["ros__parameters"]["window_length"] == WindowConfig().window_length


def test_params_file_is_the_generated_text_with_the_documentation():
    assert CONFIG.read_text() == params_yaml(), "regenerate: python -c 'from train_calib.nodes.config import ...'"
    text = CONFIG.read_text()
    assert "# initial standard deviation of r0 (Table 1) [N/kg] range (0, inf]" in text
    assert "init_std_r0: 1.0e-06" in text  # YAML 1.1 reads 1e-06 as a string


def test_parameter_names_are_unique_within_each_node():
    for node in NODE_PARAMS:
        names = [spec.name for _, spec in node_specs(node)]
        assert len(names) == len(set(names)), node


def _launch_module():
    path = REPO / "launch" / "train_calib.launch.py"
    spec = importlib.util.spec_from_file_location("train_calib_launch", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)  # must not need the `launch` package at import time
    return module


def test_launch_file_imports_and_describes_the_graph():
    launch = _launch_module()
    scripts = {ep.name for ep in metadata.distribution("train_calib").entry_points if ep.group == "console_scripts"}
    nodes = launch.describe(track="tunnel_line_37km", train="virm4", use_sim_time=True)
    assert [n["name"] for n in nodes] == list(GRAPH_NODES)
    for n in nodes:
        assert n["package"] == "train_calib" and n["executable"] in scripts and n["name"] in NODE_PARAMS
        params_file, overrides = n["parameters"]
        assert params_file == str(CONFIG)
        declared = {spec.name for _, spec in node_specs(n["name"])}
        assert set(overrides) - {"use_sim_time"} <= declared
        assert overrides["use_sim_time"] is True
    assert nodes[0]["parameters"][1] == {"use_sim_time": True, "track_file": "tunnel_line_37km", "train_file": "virm4"}
    assert [n["name"] for n in launch.describe(window=True)][-1] == "window_calib_node"
    assert set(launch.ARGUMENTS) == {"params_file", "track", "train", "use_sim_time", "window", "namespace"}


def test_launch_description_builds_with_launch_installed():
    pytest.importorskip("launch_ros")  # first: the repository's launch/ folder shadows a missing `launch`
    pytest.importorskip("launch")
    description = _launch_module().generate_launch_description()
    assert len(description.entities) == 7
