"""package.xml, setup.py and msg_defs agree; every entry point exists and imports."""

from __future__ import annotations

import re
import sys
import xml.etree.ElementTree as ET
from importlib import metadata
from pathlib import Path

import pytest
from repo_paths import REPO

REQUIRED_DEPENDS = {"rclpy", "std_msgs", "sensor_msgs", "geometry_msgs", "diagnostic_msgs", "train_calib_msgs"}
REQUIRED_EXEC = {"python3-numpy", "python3-scipy"}


def _setup_py_value(name: str) -> str:
    match = re.search(rf"{name}=\"([^\"]+)\"", (REPO / "setup.py").read_text())
    assert match, name
    return match.group(1)


def _package_xml(path: Path):
    return ET.parse(path).getroot()


def test_package_xml_matches_setup_py():
    root = _package_xml(REPO / "package.xml")
    assert root.get("format") == "3"
    assert root.findtext("name") == "train_calib"
    assert root.findtext("version") == _setup_py_value("version")
    assert root.find("export/build_type").text == "ament_python"
    depends = {e.text for e in root.findall("depend")}
    assert depends >= REQUIRED_DEPENDS
    assert {e.text for e in root.findall("exec_depend")} >= REQUIRED_EXEC
    assert (REPO / "resource" / "train_calib").is_file()
    assert "script_dir=$base/lib/train_calib" in (REPO / "setup.cfg").read_text()


def test_installed_distribution_matches():
    dist = metadata.distribution("train_calib")
    assert dist.version == _package_xml(REPO / "package.xml").findtext("version")


def _console_scripts():
    return {ep.name: ep for ep in metadata.distribution("train_calib").entry_points if ep.group == "console_scripts"}


def test_console_scripts_cover_cli_and_every_node():
    scripts = _console_scripts()
    node_modules = sorted(p.stem for p in (REPO / "train_calib" / "nodes").glob("*_node.py"))
    assert node_modules, "no node modules"
    assert set(scripts) == {"train-calib", *node_modules}


@pytest.mark.parametrize("name", sorted(_console_scripts()))
def test_entry_point_imports_and_is_callable(name):
    target = _console_scripts()[name].load()
    assert callable(target)
    # installed where `ros2 run train_calib <name>` finds it
    assert (Path(sys.prefix) / "lib" / "train_calib" / name).is_file()


def test_msg_package_lists_every_message():
    root = _package_xml(REPO / "msg_defs" / "package.xml")
    assert root.findtext("name") == "train_calib_msgs"
    assert root.find("export/build_type").text == "ament_cmake"
    assert "rosidl_interface_packages" in {e.text for e in root.findall("member_of_group")}
    cmake = (REPO / "msg_defs" / "CMakeLists.txt").read_text()
    listed = set(re.findall(r'"msg/(\w+)\.msg"', cmake))
    assert listed == {p.stem for p in (REPO / "msg_defs" / "msg").glob("*.msg")}
