"""The README tells the truth: its core example runs and converges, its commands and launch arguments exist."""

from __future__ import annotations

import importlib.util
import re

from repo_paths import REPO

from train_calib.cli import command_index
from train_calib.sim import read_truth

README = (REPO / "README.md").read_text()


def _python_blocks() -> list[str]:
    return re.findall(r"```python\n(.*?)```", README, flags=re.S)


def test_the_core_example_runs_and_ends_near_the_truth(monkeypatch, capsys):
    (example,) = [b for b in _python_blocks() if "train_calib.estimation" in b]
    monkeypatch.chdir(REPO)
    namespace: dict = {}
    exec(compile(example, "README.md", "exec"), namespace)
    assert "Davis(" in capsys.readouterr().out
    truth = read_truth(REPO / "bags" / "intercity_32km_10s_00").meta["resistance"]
    davis = namespace["est"].final_davis()
    for v in (80 / 3.6, 120 / 3.6):  # the converging preset: r(v) within 3 % where the train coasts
        true_r = truth["r0"] + truth["r1"] * v + truth["r2"] * v * v
        assert abs((davis.r0 + davis.r1 * v + davis.r2 * v * v) / true_r - 1) < 0.03
    assert abs(namespace["features"].final_coast_duration - 591) < 10  # the figure the comment states


def test_every_train_calib_command_in_the_readme_exists():
    used = set(re.findall(r"`train-calib ([a-z-]+)", README)) | set(re.findall(r"^train-calib ([a-z-]+)", README, re.M))
    assert used and used <= set(command_index()), used - set(command_index())


def test_launch_arguments_in_the_readme_are_the_launch_files():
    spec = importlib.util.spec_from_file_location("launch_file", REPO / "launch" / "train_calib.launch.py")
    launch_file = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(launch_file)
    used = set(re.findall(r"\b([a-z_]+):=", README))
    assert used and used <= set(launch_file.ARGUMENTS), used - set(launch_file.ARGUMENTS)
    listed = README.split("Launch arguments:", 1)[1].split("\n\n", 1)[0]
    assert set(re.findall(r"`([a-z_]+)`", listed)) == set(launch_file.ARGUMENTS)
