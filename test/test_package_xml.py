"""package.xml declares what the code imports, and nothing it does not.

Every third-party top-level import in train_calib/, launch/ and test/ (found with ast, the standard library and the
repository's own modules left out) must map, through IMPORT_KEYS, to rosdep keys that package.xml declares: imports
of the package and the launch file as depend/exec_depend (they are needed at run time), the tests' as any kind. Every
key package.xml declares must come from an import, or be in USED_WITHOUT_IMPORT with a check that it is still used.
A new import without a row here fails, and so does a key nothing imports any more.

The keys are the names of rosdep's public rules (ros/rosdistro rosdep/*.yaml): python3-<name> for distribution
packages, python3-<name>-pip for PyPI-only ones. NOT_IN_PUBLIC_RULES lists the keys that have no public rule yet
(rosdep says "Cannot locate rosdep definition" for them until one is added or a local rules file provides them).
"""

from __future__ import annotations

import ast
import sys
import xml.etree.ElementTree as ET

from repo_paths import REPO

# import name -> rosdep key(s)
IMPORT_KEYS: dict[str, tuple[str, ...]] = {
    # ROS 2 packages (the key is the package name)
    "rclpy": ("rclpy",),
    "std_msgs": ("std_msgs",),
    "sensor_msgs": ("sensor_msgs",),
    "geometry_msgs": ("geometry_msgs",),
    "diagnostic_msgs": ("diagnostic_msgs",),
    "rosgraph_msgs": ("rosgraph_msgs",),
    "builtin_interfaces": ("builtin_interfaces",),
    "rcl_interfaces": ("rcl_interfaces",),
    "rosidl_parser": ("rosidl_parser",),
    "ament_index_python": ("ament_index_python",),
    "launch": ("launch",),
    "launch_ros": ("launch_ros",),
    "train_calib_msgs": ("train_calib_msgs",),
    # Python packages
    "numpy": ("python3-numpy",),
    "scipy": ("python3-scipy",),
    "yaml": ("python3-yaml",),
    "matplotlib": ("python3-matplotlib",),
    "rosbags": ("python3-rosbags-pip",),
    "mcap": ("python3-mcap-pip",),
    "zstandard": ("python3-zstandard",),
    "lz4": ("python3-lz4",),
    "distributed": ("python3-distributed", "python3-dask"),  # dask.distributed; `dask scheduler`/`dask worker`
    "dask": ("python3-dask",),  # dask.config (the workers' profiler off)
    "pyarrow": ("python3-pyarrow",),
    "tqdm": ("python3-tqdm",),
    # tests
    "pytest": ("python3-pytest",),
    "hypothesis": ("python3-hypothesis",),
    "pandas": ("python3-pandas",),
    "filterpy": ("python3-filterpy-pip",),
    "mcap_ros2": ("mcap-ros2-support",),
    "catkin_pkg": ("python3-catkin-pkg",),  # rosdep's crawl of a workspace (test_colcon_workspace)
}

# declared keys that no import names: key -> (why, a check that the reason still holds)
USED_WITHOUT_IMPORT = {
    "python3-dev": ("setup.py builds the window fit's C extension", lambda: "Extension(" in _text("setup.py")),
    "ros2launch": ("`ros2 launch` runs launch/train_calib.launch.py", lambda: (REPO / "launch").is_dir()),
    "python3-pytest-timeout": ("pytest.ini sets `timeout`", lambda: "\ntimeout =" in _text("pytest.ini")),
    "python3-colcon-common-extensions": (
        "test_colcon_workspace runs `colcon build` and `colcon test`",
        lambda: "colcon build" in _text("test/test_colcon_workspace.py"),
    ),
}

# keys with no rule in rosdep's public database (ros/rosdistro, checked 2026-08): distribution packages exist
# (Debian/Ubuntu python3-zstandard, python3-lz4, python3-dask, python3-distributed) or PyPI only (mcap, pyarrow)
NOT_IN_PUBLIC_RULES = {"python3-mcap-pip", "python3-zstandard", "python3-lz4", "python3-dask", "python3-distributed",
                       "python3-pyarrow"}  # fmt: skip

RUNTIME_TAGS = ("depend", "exec_depend")
ALL_TAGS = ("depend", "build_depend", "build_export_depend", "exec_depend", "test_depend", "buildtool_depend")


def _text(name: str) -> str:
    return (REPO / name).read_text()


def _declared(tags: tuple[str, ...]) -> set[str]:
    root = ET.parse(REPO / "package.xml").getroot()
    return {e.text.strip() for tag in tags for e in root.findall(tag)}


def _own_modules() -> set[str]:
    """The repository's own top-level names: the package and every test helper module."""
    return {"train_calib"} | {p.stem for p in (REPO / "test").rglob("*.py")}


def _imports(folders: tuple[str, ...]) -> dict[str, set[str]]:
    """Third-party top-level import name -> the files that import it."""
    own = _own_modules()
    found: dict[str, set[str]] = {}
    for folder in folders:
        for path in sorted((REPO / folder).rglob("*.py")):
            for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
                if isinstance(node, ast.Import):
                    names = [alias.name for alias in node.names]
                elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                    names = [node.module]
                else:
                    continue
                for name in names:
                    top = name.split(".")[0]
                    if top not in sys.stdlib_module_names and top not in own:
                        found.setdefault(top, set()).add(str(path.relative_to(REPO)))
    return found


def test_every_import_has_a_rosdep_key_in_package_xml():
    runtime, tests = _imports(("train_calib", "launch")), _imports(("test",))
    unmapped = sorted((set(runtime) | set(tests)) - set(IMPORT_KEYS))
    assert not unmapped, "imports without a rosdep key in IMPORT_KEYS: " + ", ".join(
        f"{name} ({sorted((runtime | tests)[name])[0]})" for name in unmapped
    )
    exec_keys, all_keys = _declared(RUNTIME_TAGS), _declared(ALL_TAGS)
    missing_runtime = {key: name for name in runtime for key in IMPORT_KEYS[name] if key not in exec_keys}
    assert not missing_runtime, f"package.xml lacks these depend/exec_depend (key: import): {missing_runtime}"
    missing_test = {key: name for name in tests for key in IMPORT_KEYS[name] if key not in all_keys}
    assert not missing_test, f"package.xml lacks these test_depend (key: import): {missing_test}"


def test_every_declared_key_is_imported_or_used():
    imported = set(_imports(("train_calib", "launch", "test")))
    from_imports = {key for name in imported for key in IMPORT_KEYS.get(name, ())}
    unused = sorted(_declared(ALL_TAGS) - from_imports - set(USED_WITHOUT_IMPORT))
    assert not unused, f"package.xml declares keys that nothing imports: {unused}"
    for key, (why, still_used) in USED_WITHOUT_IMPORT.items():
        assert key in _declared(ALL_TAGS), key
        assert still_used(), f"{key} is declared because {why}, which is no longer so"


def test_the_mapping_table_has_no_stale_rows():
    imported = set(_imports(("train_calib", "launch", "test")))
    assert not set(IMPORT_KEYS) - imported, f"IMPORT_KEYS rows nothing imports: {sorted(set(IMPORT_KEYS) - imported)}"


def test_keys_follow_rosdep_naming():
    """python3-* keys for Python packages (…-pip for PyPI-only ones); plain names for ROS packages."""
    ros_packages = {"rclpy", "launch", "launch_ros", "ros2launch", "ament_index_python", "rosidl_parser"}
    for key in _declared(ALL_TAGS):
        assert key == key.strip() and " " not in key, key
        if key.startswith("python3-") or key in ros_packages or key == "mcap-ros2-support":
            continue
        assert key.endswith(("_msgs", "_interfaces")), f"{key}: not a rosdep key name"
    assert "python3-psutil" not in _declared(ALL_TAGS)  # declared once, never imported
    assert _declared(ALL_TAGS) >= NOT_IN_PUBLIC_RULES


def test_the_import_scan_finds_what_it_should():
    """The scan itself: it sees a known import of each kind, and leaves the repository's own modules out."""
    found = _imports(("train_calib", "launch", "test"))
    assert "train_calib/mcap_salvage.py" in found["zstandard"] and "launch/train_calib.launch.py" in found["launch_ros"]
    assert "test/estimation/test_ukf_equivalence.py" in found["filterpy"]
    assert not {"train_calib", "repo_paths", "conftest", "os", "json"} & set(found)
