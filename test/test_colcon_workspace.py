"""The README's colcon workspace recipe, run: a throwaway workspace with this venv (the ROS 2 Jazzy wheels) as underlay.

The repository's tracked files are copied to ws/src/train_calib, and the README's commands (the `ln -s` of the
message package, the venv-underlay `export` and `colcon build` lines, `source install/setup.bash`) run there with
colcon from PyPI (requirements/python.txt). Checked: colcon finds and builds both packages, the messages and the
package import from the workspace's install (not from the venv, which holds its own copies), every node executable
in install/train_calib/lib/train_calib starts and logs a line, and `colcon test` of the modules that depend on where
the package was built passes. ROS is isolated as everywhere in the tests (the session's ROS_DOMAIN_ID, localhost
discovery), with the ROS log in the workspace. About 2-3 minutes on 2 cores, most of it the messages' CMake build;
deselect with `-k "not colcon_workspace"`.
"""

from __future__ import annotations

import json
import os
import re
import selectors
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from repo_paths import REPO

pytestmark = [pytest.mark.slow, pytest.mark.ros]

VENV = Path(sys.prefix)
SECTION = "## Building in a ROS 2 colcon workspace"
NODES = ("gnss_speed_node", "ukf_node", "regime_node", "feature_node", "window_calib_node", "prediction_node")
START_TIMEOUT_S = 60.0
STOP_TIMEOUT_S = 20.0


def _readme_blocks() -> list[list[str]]:
    """The fenced code blocks of the README's workspace section, as lists of lines."""
    text = (REPO / "README.md").read_text()
    start = text.index(SECTION)
    end = text.find("\n## ", start + len(SECTION))
    section = text[start : end if end > 0 else len(text)]
    return [block.strip().splitlines() for block in re.findall(r"```sh\n(.*?)```", section, flags=re.S)]


def recipe() -> dict[str, list[str]]:
    """The README lines the test runs: the link (ROS block) and the venv-underlay block's export/build/source lines."""
    blocks = _readme_blocks()
    assert len(blocks) >= 2, "README workspace section: expected the ROS block and the venv-underlay block"
    ros, venv = blocks[0], blocks[1]
    link = [line for line in ros if line.startswith("ln -s ")]
    assert link == ["ln -s train_calib/msg_defs train_calib_msgs"], ros
    assert any(re.fullmatch(r"colcon build( && .*)?", line) for line in ros), "the ROS block builds with plain colcon"
    assert any("source src/train_calib/.venv/bin/activate" in line for line in venv), venv
    env_lines = [line for line in venv if line.startswith("export ")]
    build = [line for line in venv if line.startswith("colcon build")]
    source = [line for line in venv if line.startswith("source install/")]
    assert env_lines and len(build) == 1 and source, venv
    assert "-DCMAKE_PROJECT_INCLUDE=$PWD/src/train_calib/cmake/prune_missing_include_dirs.cmake" in build[0]
    return {"link": link, "env": env_lines, "build": build, "source": source}


def _copy_checkout(dest: Path) -> None:
    """The repository's tracked files (what a clone holds), without build products."""
    listed = subprocess.run(["git", "ls-files", "-z"], cwd=REPO, capture_output=True, check=False)
    if listed.returncode != 0:
        pytest.skip("not a git checkout: the workspace test copies the tracked files")
    for name in filter(None, listed.stdout.decode().split("\0")):
        source = REPO / name
        if source.is_file():
            (dest / name).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(source, dest / name)


def _bash(script: str, cwd: Path, env: dict[str, str], timeout: float) -> subprocess.CompletedProcess:
    return subprocess.run(["bash", "-c", "set -eo pipefail\n" + script], cwd=cwd, env=env, text=True,
                          capture_output=True, timeout=timeout, check=False)  # fmt: skip


def _clean_env(ws: Path) -> dict[str, str]:
    dropped = {"AMENT_PREFIX_PATH", "CMAKE_PREFIX_PATH", "PYTHONPATH", "VIRTUAL_ENV", "COLCON_PREFIX_PATH",
               "PYTEST_ADDOPTS", "PYTEST_XDIST_WORKER", "PYTEST_XDIST_WORKER_COUNT", "PYTEST_CURRENT_TEST"}  # fmt: skip
    env = {k: v for k, v in os.environ.items() if k not in dropped}
    env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    env["ROS_DOMAIN_ID"] = os.environ.get("ROS_DOMAIN_ID", "42")  # the session's own (test/conftest.py)
    env["ROS_LOG_DIR"] = str(ws / "ros_log")
    env["MAKEFLAGS"] = f"-j{os.cpu_count() or 2}"  # colcon adds -l<cpus> otherwise: serial on a loaded machine
    env["PYTHONDONTWRITEBYTECODE"] = "1"
    return env


@pytest.fixture(scope="module")
def workspace(tmp_path_factory):
    """ws/ built with the README's venv-underlay recipe; yields (ws, the environment of install/setup.bash)."""
    if not (VENV / "share" / "ament_index" / "resource_index" / "packages" / "rclpy").is_file():
        pytest.skip(f"{VENV} is not the venv of the ROS 2 wheels (make setup): the recipe's underlay")
    assert (VENV / "bin" / "colcon").is_file(), "colcon missing: pip install -r requirements/python.txt (make setup)"
    lines = recipe()
    ws = tmp_path_factory.mktemp("colcon_ws")
    clone = ws / "src" / "train_calib"
    clone.mkdir(parents=True)
    _copy_checkout(clone)
    env = _clean_env(ws)
    script = "\n".join([
        "cd src", *lines["link"], "cd ..",
        f"source {VENV}/bin/activate",  # the README's `source src/train_calib/.venv/bin/activate`: this venv
        *lines["env"],
        "colcon list > colcon_list.txt",
        *lines["build"],
        *lines["source"],
        f"{sys.executable} -c 'import json, os; print(json.dumps(dict(os.environ)))' > setup_env.json",
    ])  # fmt: skip
    started = time.monotonic()
    done = _bash(script, ws, env, timeout=900)
    seconds = time.monotonic() - started
    logs = "\n".join(p.read_text()[-3000:] for p in sorted((ws / "log").glob("latest_build/*/stdout_stderr.log")))
    assert done.returncode == 0, (
        f"recipe failed after {seconds:.0f} s:\n{done.stdout[-3000:]}\n{done.stderr[-3000:]}\n" + logs
    )
    listed = (ws / "colcon_list.txt").read_text()
    assert re.search(r"^train_calib\s+src/train_calib\s+\(ros\.ament_python\)$", listed, flags=re.M), listed
    assert re.search(r"^train_calib_msgs\s+src/train_calib_msgs\s+\(ros\.ament_cmake\)$", listed, flags=re.M), listed
    assert "Summary: 2 packages finished" in done.stdout, done.stdout[-2000:]
    yield ws, json.loads((ws / "setup_env.json").read_text())


def test_colcon_workspace_builds_both_packages_and_imports_from_the_install(workspace):
    ws, env = workspace
    install = ws / "install"
    msgs = sorted(p.stem for p in (REPO / "msg_defs" / "msg").glob("*.msg"))
    probe = f"""
import json, train_calib, train_calib_msgs.msg as m
from ament_index_python.packages import get_package_share_directory
from train_calib import paths
from train_calib.window import fast
classes = {{name: getattr(m, name)().__class__.__module__ for name in {msgs!r}}}
print(json.dumps({{"msgs": m.__file__, "pkg": train_calib.__file__, "classes": classes, "kernel": fast.KERNEL_AVAILABLE,
                  "share": get_package_share_directory("train_calib"), "paths": str(paths.share_dir()),
                  "msg_share": get_package_share_directory("train_calib_msgs")}}))
"""
    done = subprocess.run([sys.executable, "-c", probe], cwd=ws, env=env, capture_output=True, text=True, timeout=120,
                          check=False)  # fmt: skip
    assert done.returncode == 0, done.stderr
    found = json.loads(done.stdout.strip().splitlines()[-1])
    assert Path(found["msgs"]).is_relative_to(install / "train_calib_msgs"), found
    assert Path(found["pkg"]).is_relative_to(install / "train_calib"), found
    assert set(found["classes"]) == set(msgs) and len(msgs) >= 6, found
    assert Path(found["share"]) == install / "train_calib" / "share" / "train_calib"
    assert Path(found["paths"]) == Path(found["share"]), "train_calib.paths finds the install's share directory"
    assert Path(found["msg_share"]) == install / "train_calib_msgs" / "share" / "train_calib_msgs"
    assert found["kernel"], "colcon built the window fit's C kernel"
    for name in ("train_calib.launch.py",):
        assert (install / "train_calib" / "share" / "train_calib" / "launch" / name).is_file()
    assert (install / "train_calib" / "share" / "train_calib" / "config" / "train_calib.yaml").is_file()


def test_colcon_workspace_node_executables_start_and_log(workspace):
    ws, env = workspace
    lib = ws / "install" / "train_calib" / "lib" / "train_calib"
    executables = sorted(p.name for p in lib.iterdir() if p.name.endswith("_node"))
    assert executables == sorted(NODES), executables
    procs = {name: subprocess.Popen([str(lib / name)], cwd=ws, env=env, stdout=subprocess.PIPE,
                                    stderr=subprocess.STDOUT, start_new_session=True)
             for name in NODES}  # fmt: skip
    output = {name: b"" for name in NODES}
    logged: dict[str, str] = {}
    selector = selectors.DefaultSelector()
    for name, proc in procs.items():
        os.set_blocking(proc.stdout.fileno(), False)
        selector.register(proc.stdout, selectors.EVENT_READ, name)
    try:
        deadline = time.monotonic() + START_TIMEOUT_S
        while len(logged) < len(NODES) and time.monotonic() < deadline:
            for key, _ in selector.select(timeout=0.5):
                name = key.data
                chunk = key.fileobj.read() or b""
                output[name] += chunk
                for line in output[name].decode(errors="replace").splitlines():
                    if line.startswith("[INFO]") and f"[{name}]:" in line:
                        logged.setdefault(name, line)
                if not chunk and procs[name].poll() is not None:
                    selector.unregister(key.fileobj)
            if any(p.poll() is not None for n, p in procs.items() if n not in logged):
                break
        for proc in procs.values():
            if proc.poll() is None:
                proc.send_signal(signal.SIGINT)
        codes = {name: proc.wait(timeout=STOP_TIMEOUT_S) for name, proc in procs.items()}
    finally:
        selector.close()
        for proc in procs.values():
            if proc.poll() is None:
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait()
    for name, proc in procs.items():
        output[name] += proc.stdout.read() or b""
        proc.stdout.close()
    text = {name: out.decode(errors="replace") for name, out in output.items()}
    missing = {name: text[name][-800:] for name in NODES if name not in logged}
    assert not missing, f"nodes that logged no [INFO] line within {START_TIMEOUT_S:.0f} s: {missing}"
    for name in NODES:
        assert "Traceback" not in text[name], (name, text[name][-2000:])
        assert codes[name] == 0, f"{name}: exit {codes[name]} after SIGINT:\n{text[name][-2000:]}"


def test_colcon_workspace_colcon_test_of_the_build_dependent_tests(workspace):
    """`colcon test` runs the source tree's tests against the install: the kernels' tests skip, saying why."""
    ws, _ = workspace
    modules = ["test/window/test_window_kernel.py", "test/window/test_window_node.py", "test/nodes/test_config.py",
               "test/test_package_xml.py", "test/estimation/test_ukf_kernel.py"]  # fmt: skip
    env = _clean_env(ws)
    script = "\n".join([
        f"source {VENV}/bin/activate", *recipe()["env"], *recipe()["source"],
        "colcon test --packages-select train_calib --pytest-args " + " ".join(modules),
        "colcon test-result --verbose --test-result-base build/train_calib",
    ])  # fmt: skip
    done = _bash(script, ws, env, timeout=600)
    result = ws / "build" / "train_calib" / "pytest.xml"
    assert result.is_file(), done.stdout[-3000:] + done.stderr[-3000:]
    xml = result.read_text()
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    summary = re.search(r'errors="(\d+)" failures="(\d+)" skipped="(\d+)" tests="(\d+)"', xml)
    assert summary, xml[:500]
    errors, failures, _skipped, tests = map(int, summary.groups())
    assert errors == 0 and failures == 0 and tests > 10, done.stdout[-3000:]
    assert "test_window_kernel" in xml and "has no built C kernel" in xml, xml[:2000]
    assert "test_ukf_kernel" in xml and "has no built C kernel of the UKF stage" in xml, xml[:2000]


def test_rosdep_crawl_finds_both_packages_through_the_link(tmp_path):
    """`rosdep install --from-paths src --ignore-src` crawls with catkin_pkg: with the README's link it finds
    train_calib_msgs in the workspace (without it, "Cannot locate rosdep definition for [train_calib_msgs]")."""
    from catkin_pkg.packages import find_packages

    clone = tmp_path / "src" / "train_calib"
    (clone / "msg_defs").mkdir(parents=True)
    shutil.copy2(REPO / "package.xml", clone / "package.xml")
    shutil.copy2(REPO / "msg_defs" / "package.xml", clone / "msg_defs" / "package.xml")
    assert {p.name for p in find_packages(str(tmp_path / "src")).values()} == {"train_calib"}  # stops at the clone
    (link,) = recipe()["link"]
    subprocess.run(link, shell=True, cwd=tmp_path / "src", check=True)
    found = {p.name: p for p in find_packages(str(tmp_path / "src")).values()}
    assert set(found) == {"train_calib", "train_calib_msgs"}
    depends = {d.name for d in found["train_calib"].exec_depends + found["train_calib"].build_depends}
    assert "train_calib_msgs" in depends
