"""The train-calib entry point: command discovery, one-line errors, lazy imports."""

from __future__ import annotations

import subprocess
import sys

import pytest

from train_calib import cli


def test_every_command_module_is_listed_with_its_help():
    index = cli.command_index()
    for name in ("demo", "replay", "simulate", "calibrate-occupation"):
        assert name in index and index[name][1], name


def test_usage_errors_are_one_line_with_status_2(capsys):
    with pytest.raises(SystemExit) as exc:
        cli.main(["simulate", "--runs", "many"])
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip()
    assert err == "train-calib simulate: error: argument --runs: invalid int value: 'many'"
    with pytest.raises(SystemExit):
        cli.main(["no-such-command"])
    assert "invalid choice: 'no-such-command'" in capsys.readouterr().err


def test_only_the_requested_command_is_imported():
    code = (
        "import sys; from train_calib import cli; "
        "p = cli.build_parser('simulate'); "
        "print(sorted(m for m in sys.modules if m.startswith('train_calib.commands.')))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "['train_calib.commands.simulate']"
    # the listing imports no command at all, and neither matplotlib nor the occupation package
    code = (
        "import sys; from train_calib import cli; cli.build_parser(None); "
        "heavy = ('train_calib.commands.', 'matplotlib', 'train_calib.occupation'); "
        "print([m for m in sys.modules if m.startswith(heavy)])"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"
