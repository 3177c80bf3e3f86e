"""config/train_calib.yaml equals the core ParamSet defaults, config/ukf_converging.yaml the converging preset; the
launch file describes the graph."""

from __future__ import annotations

import importlib.util
from importlib import metadata
from pathlib import Path

import pytest
import yaml
from repo_paths import REPO

from train_calib import paths
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


@pytest.mark.parametrize("name", ["converging", "paper"])
def test_preset_params_file_is_the_core_preset(name):
    from train_calib.commands.replay import preset_params_yaml
    from train_calib.nodes.config import ukf_preset_yaml

    path = REPO / "config" / f"ukf_{name}.yaml"
    text = path.read_text()
    assert text == ukf_preset_yaml(name), f"regenerate: python -m train_calib.nodes.config --preset {name}"
    values = yaml.safe_load(text)["ukf_node"]["ros__parameters"]
    preset = {k: list(v) if isinstance(v, tuple) else v for k, v in UKFConfig.preset(name).as_dict().items()}
    assert values == preset and set(yaml.safe_load(text)) == {"ukf_node"}
    assert UKFConfig.from_mapping(values, source=str(path)) == UKFConfig.preset(name)
    assert "resistance_learning: ukf\n" in text and "(default: coast_regression)" in text  # what differs says so
    assert yaml.safe_load(preset_params_yaml(name)) == yaml.safe_load(text)  # --ukf-preset NAME


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


def _launch_config_dir():
    """Where the launch file should take config/ from: the package's installed share directory when the ament index
    has one (a colcon workspace: `colcon test` runs the source tree's tests against the install), else the source
    tree's, which is what train_calib.paths finds in a checkout (make test)."""
    try:
        from ament_index_python.packages import get_package_share_directory

        installed = Path(get_package_share_directory("train_calib")) / "config"
        if (installed / "train_calib.yaml").is_file():
            return installed
    except Exception:  # no ament index, or train_calib not in it
        pass
    return paths.config_file("train_calib.yaml").parent


def test_launch_file_imports_and_describes_the_graph():
    launch = _launch_module()
    config_dir = _launch_config_dir()
    if not _installed_in_ament_index():
        assert config_dir == REPO / "config"  # make test: the checkout's files, edits seen at once
    assert (config_dir / "train_calib.yaml").read_text() == CONFIG.read_text()
    scripts = {ep.name for ep in metadata.distribution("train_calib").entry_points if ep.group == "console_scripts"}
    nodes = launch.describe(track="tunnel_line_37km", train="virm4", use_sim_time=True)
    assert [n["name"] for n in nodes] == list(GRAPH_NODES)
    for n in nodes:
        assert n["package"] == "train_calib" and n["executable"] in scripts and n["name"] in NODE_PARAMS
        params_file, overrides = n["parameters"]
        assert params_file == str(config_dir / "train_calib.yaml")
        declared = {spec.name for _, spec in node_specs(n["name"])}
        assert set(overrides) - {"use_sim_time"} <= declared
        assert overrides["use_sim_time"] is True
    assert nodes[0]["parameters"][1] == {"use_sim_time": True, "track_file": "tunnel_line_37km", "train_file": "virm4"}
    assert [n["name"] for n in launch.describe(window=True)][-1] == "window_calib_node"
    assert set(launch.ARGUMENTS) == {
        "params_file", "track", "train", "use_sim_time", "window", "traction_power", "ukf_preset", "namespace",
        "prediction",
    }  # fmt: skip
    # window: auto (the launch default) follows traction_power; true/false force it
    defaults = {name: default for name, (default, _) in launch.ARGUMENTS.items()}
    assert [n["name"] for n in launch.describe(**defaults)] == list(GRAPH_NODES)
    powered = launch.describe(**(defaults | {"traction_power": "true"}))
    assert [n["name"] for n in powered][-1] == "window_calib_node"
    assert powered[-1]["parameters"][1] == {"use_sim_time": False}
    assert len(launch.describe(**(defaults | {"traction_power": "true", "window": "false"}))) == len(GRAPH_NODES)
    # ukf_preset: converging adds config/ukf_converging.yaml to ukf_node after the params file
    ukf = next(n for n in launch.describe(ukf_preset="converging") if n["name"] == "ukf_node")
    assert ukf["parameters"][:2] == [str(config_dir / "train_calib.yaml"), str(config_dir / "ukf_converging.yaml")]
    paper = next(n for n in launch.describe(ukf_preset="paper") if n["name"] == "ukf_node")
    assert paper["parameters"][:2] == [str(config_dir / "train_calib.yaml"), str(config_dir / "ukf_paper.yaml")]
    learning = next(n for n in launch.describe(ukf_preset="learning") if n["name"] == "ukf_node")
    assert str(learning["parameters"][1]).find("ukf_") < 0  # the defaults: the params file alone
    for bad in ({"window": "maybe"}, {"ukf_preset": "fast"}, {"use_sim_time": "ja"}):
        with pytest.raises(ValueError, match=f"launch argument {next(iter(bad))}: "):
            launch.describe(**bad)


def _installed_in_ament_index() -> bool:
    try:
        from ament_index_python.packages import get_package_share_directory

        get_package_share_directory("train_calib")
    except Exception:  # no ament index, or train_calib not in it
        return False
    return True


def test_launch_description_builds_with_launch_installed():
    pytest.importorskip("launch_ros")  # first: the repository's launch/ folder shadows a missing `launch`
    pytest.importorskip("launch")
    description = _launch_module().generate_launch_description()
    assert len(description.entities) == len(_launch_module().ARGUMENTS) + 1
