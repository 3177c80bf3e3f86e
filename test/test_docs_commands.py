"""Every command the README and docs/*.md show runs as shown, or at least parses (issue 21).

The fenced shell blocks (```` ```sh ````, ```` ```bash ````, unlabelled) of README.md and docs/*.md are read line by
line (``\\`` continuations joined, ``#`` comments dropped, ``&&`` chains split); inline ```train-calib ...```
commands in the prose are read too. Then, for each command:

- ``train-calib SUB ...``: the subcommand's real parser accepts every option as shown (``--help`` exits 0); the
  repository files it names (``bags/``, ``config/``, ``docs/``, ``bench/``, ``test/``) exist; the bundled track,
  train and bag names it names resolve. The cheap ones run for real, in a temporary directory that links
  ``bags/``, ``config/`` and ``docs/`` (exit 0, no traceback): ``demo``, a ``replay`` of a bundled bag at rate 0
  without ``--live``, ``simulate`` of at most 5 runs, any ``--help``.
- ``make TARGET``: the Makefile has the target. ``.venv/bin/python FILE`` / ``-m pytest PATH``: the file or path
  exists, and a script's ``--help`` accepts the options shown. ``dask scheduler|worker``: its ``--help`` lists
  every option shown. ``ros2 run train_calib NODE --params-file F``: the node is an executable of setup.py, F
  exists; ``ros2 launch train_calib FILE``: the launch file exists (its arguments: test_readme.py).
- The rest (``colcon``, ``rosdep``, ``git clone``, ``source``...) is the workspace recipe that
  test_colcon_workspace.py builds; the vasteras CSV workflow runs in test_import_readme.py.

Expensive commands (``simulate-fleet``, ``fleet``, ``simulate-occupation``/``calibrate-occupation`` over dozens of
runs, a replay at ``--rate 20`` with a DAS, ``record`` until Ctrl-C, the soak) are only parsed here; with
``TRAIN_CALIB_DOCS_FULL=1`` in the environment each doc's commands without placeholders run in order, in one
directory per doc, as a reader would follow it (minutes: ``TRAIN_CALIB_DOCS_FULL=1 .venv/bin/python -m pytest
test/test_docs_commands.py -k top_to_bottom``).
"""

from __future__ import annotations

import argparse
import functools
import os
import re
import shlex
import subprocess
import sys
from dataclasses import dataclass, replace
from pathlib import Path

import pytest
from repo_paths import REPO

from train_calib import paths
from train_calib.cli import build_parser, command_index

DOCS = [REPO / "README.md", *sorted((REPO / "docs").glob("*.md"))]
SHELL_LANGS = {"", "sh", "bash", "shell", "console"}
REPO_PREFIXES = ("bags/", "config/", "docs/", "bench/", "test/", "launch/")
PLACEHOLDER = re.compile(r"^(BAG|T|R|DIR|FILE|NAME|MANIFEST|EVENTS\.csv|TYPES\.yaml|my\.yaml|m\.csv)$")
RUN_TIMEOUT_S = 1800
FULL = os.environ.get("TRAIN_CALIB_DOCS_FULL", "") not in ("", "0")


@dataclass(frozen=True)
class Command:
    """One command as the docs show it: where (file:line, the block's number in the file) and its words."""

    doc: str
    line: int
    block: int
    argv: tuple[str, ...]
    inline: bool = False

    @property
    def where(self) -> str:
        return f"{self.doc}:{self.line}: {' '.join(self.argv)}"


def _block_commands(doc: Path) -> list[Command]:
    text = doc.read_text(encoding="utf-8")
    out: list[Command] = []
    for k, m in enumerate(re.finditer(r"^```([a-z]*)\n(.*?)^```", text, flags=re.S | re.M)):
        if m.group(1) not in SHELL_LANGS:
            continue
        first_line = text.count("\n", 0, m.start(2)) + 1
        lines = m.group(2).splitlines()
        i = 0
        while i < len(lines):
            start, joined = i, lines[i]
            while joined.rstrip().endswith("\\") and i + 1 < len(lines):
                i += 1
                joined = joined.rstrip()[:-1] + " " + lines[i].strip()
            i += 1
            try:
                words = shlex.split(joined, comments=True)
            except ValueError:
                continue  # not shell (a diagram, printed output)
            part: list[str] = []
            for word in [*words, "&&"]:
                if word in ("&&", ";", "||"):
                    while part and re.match(r"^[A-Z_][A-Z0-9_]*=", part[0]):  # VAR=value before a command
                        part = part[1:]
                    if part and _is_command(part[0]):
                        out.append(Command(doc.relative_to(REPO).as_posix(), first_line + start, k, tuple(part)))
                    part = []
                else:
                    part.append(word)
    return out


def _is_command(word: str) -> bool:
    return word in ("train-calib", "make", "dask", "ros2", "colcon", "rosdep", "git", "ln", "mkdir", "cd",
                    "source", "export", "python3") or word.startswith(".venv/bin/")  # fmt: skip


def _inline_commands(doc: Path) -> list[Command]:
    """```train-calib SUB ...``` in the prose, without the synopsis notation ([...], |, ..., <...>)."""
    text = doc.read_text(encoding="utf-8")
    blocks = [(m.start(), m.end()) for m in re.finditer(r"^```.*?^```", text, flags=re.S | re.M)]
    out = []
    for m in re.finditer(r"`(train-calib [^`\n]+)`", text):
        if any(a <= m.start() < b for a, b in blocks) or re.search(r"[\[\]|<>]|\.\.\.|…", m.group(1)):
            continue
        if m.group(1).split()[1].endswith(":"):  # an error message quoted: train-calib replay: error: ...
            continue
        line = text.count("\n", 0, m.start()) + 1
        out.append(Command(doc.relative_to(REPO).as_posix(), line, -1, tuple(shlex.split(m.group(1))), True))
    return out


COMMANDS = [c for doc in DOCS for c in _block_commands(doc)]
INLINE = [c for doc in DOCS for c in _inline_commands(doc)]
TRAIN_CALIB = [c for c in COMMANDS + INLINE if c.argv[0] == "train-calib"]


def _option_values(argv: tuple[str, ...], option: str) -> list[str]:
    return [argv[i + 1] for i, a in enumerate(argv[:-1]) if a == option]


def _check_repo_files(cmd: Command) -> None:
    for word in cmd.argv[1:]:
        for value in word.split("=", 1)[-1:]:
            if value.startswith(REPO_PREFIXES) and not PLACEHOLDER.match(value):
                assert (REPO / value.rstrip(".,:")).exists(), f"{cmd.where}: {value} does not exist"


def _check_bundled_names(cmd: Command) -> None:
    for option, resolve in (("--track", paths.track_file), ("--train", paths.train_file)):
        for value in _option_values(cmd.argv, option):
            if PLACEHOLDER.match(value) or "/" in value or value.endswith((".yaml", ".json")) or "+" in value:
                continue  # a file (made by an earlier command, or checked as a repository path)
            resolve(value)  # raises with the bundled names when it is none of them
    for value in _option_values(cmd.argv, "--bag"):
        if "/" not in value and not PLACEHOLDER.match(value):
            assert (paths.bags_dir() / value).is_dir(), f"{cmd.where}: no bundled bag {value}"


def test_the_docs_show_commands():
    """The extraction finds what the docs show (a guard against a silently empty parametrisation)."""
    subcommands = {c.argv[1] for c in TRAIN_CALIB if len(c.argv) > 1}
    assert {"demo", "replay", "simulate", "simulate-occupation", "calibrate-occupation", "fleet"} <= subcommands
    assert any(c.argv[:2] == ("make", "demo") for c in COMMANDS)
    assert any(c.argv[:2] == ("make", "test") for c in COMMANDS)
    assert len(TRAIN_CALIB) >= 20


def _subcommand_options(name: str) -> set[str]:
    parser = build_parser(name)
    (sub,) = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    return set(sub.choices[name]._option_string_actions)


@pytest.mark.parametrize("cmd", TRAIN_CALIB, ids=lambda c: f"{c.doc}:{c.line}")
def test_train_calib_commands_parse(cmd: Command, capsys):
    """A block's command parses whole; an inline one (often a part: ``train-calib replay --ukf-preset paper``)
    names an existing command and only its options."""
    argv = list(cmd.argv[1:])
    assert argv and argv[0] in command_index(), f"{cmd.where}: no command {argv[:1]}"
    if cmd.inline:
        unknown = {a.split("=", 1)[0] for a in argv if a.startswith("--")} - _subcommand_options(argv[0])
        assert not unknown, f"{cmd.where}: train-calib {argv[0]} has no option {sorted(unknown)}"
    else:
        try:
            build_parser(argv[0]).parse_args(argv)
        except SystemExit as exc:
            error = capsys.readouterr().err.strip()
            assert exc.code == 0, f"{cmd.where}: {error}"
    _check_repo_files(cmd)
    _check_bundled_names(cmd)


def _cheap(cmd: Command) -> bool:
    """Whether the command runs in a few seconds (module docstring)."""
    argv = cmd.argv
    if len(argv) < 2 or argv[0] != "train-calib" or cmd.inline:
        return False
    if "--help" in argv:
        return True
    if argv[1] == "demo":
        return True
    if argv[1] == "replay":
        bag = argv[2] if len(argv) > 2 else ""
        rate = _option_values(argv, "--rate")
        return bag.startswith("bags/") and "--live" not in argv and rate in ([], ["0"])
    if argv[1] == "simulate":
        return all(int(v) <= 5 for v in _option_values(argv, "--runs"))
    return False


@pytest.fixture(scope="module")
def workdir(tmp_path_factory):
    """A directory with the repository's bags/, config/ and docs/ linked, as the docs' relative paths expect."""
    work = tmp_path_factory.mktemp("docs_commands")
    for name in ("bags", "config", "docs"):
        (work / name).symlink_to(REPO / name)
    return work


def _run(cmd: Command, cwd: Path) -> subprocess.CompletedProcess:
    argv = [sys.executable, "-m", "train_calib", *cmd.argv[1:]] if cmd.argv[0] == "train-calib" else list(cmd.argv)
    return subprocess.run(argv, cwd=cwd, capture_output=True, text=True, timeout=RUN_TIMEOUT_S, check=False)


CHEAP = [c for c in TRAIN_CALIB if _cheap(c)]


@pytest.mark.ros
@pytest.mark.parametrize("cmd", CHEAP, ids=lambda c: f"{c.doc}:{c.line}")
def test_cheap_commands_run_as_shown(cmd: Command, workdir):
    done = _run(cmd, workdir)
    assert done.returncode == 0, f"{cmd.where}: exit {done.returncode}\n{done.stderr[-2000:]}"
    assert "Traceback" not in done.stderr, f"{cmd.where}:\n{done.stderr[-2000:]}"
    if cmd.argv[1] == "replay" and "--out" in cmd.argv:
        out = workdir / _option_values(cmd.argv, "--out")[0]
        assert {"output.mcap", "summary.json", "report.png"} <= {p.name for p in out.iterdir()}
    if cmd.argv[1] == "demo":
        assert "Running resistance after the last sample" in done.stdout + done.stderr


def test_cheap_commands_include_the_demo_a_replay_and_a_simulation():
    assert {c.argv[1] for c in CHEAP} >= {"demo", "replay", "simulate"}


def _makefile_targets() -> set[str]:
    text = (REPO / "Makefile").read_text(encoding="utf-8")
    return set(re.findall(r"^([A-Za-z][\w-]*):", text, flags=re.M))


@functools.cache
def _help(*argv: str) -> str:
    """``argv --help``'s output (once per program)."""
    done = subprocess.run([*argv, "--help"], capture_output=True, text=True, timeout=120, check=False)
    return done.stdout


OTHER = [c for c in COMMANDS if c.argv[0] in ("make", "dask", "ros2") or c.argv[0].startswith(".venv/bin/")]


@pytest.mark.parametrize("cmd", OTHER, ids=lambda c: f"{c.doc}:{c.line}")
def test_other_commands_name_what_exists(cmd: Command):
    argv = cmd.argv
    if argv[0] == "make":
        targets = [a for a in argv[1:] if not a.startswith("-") and "=" not in a]
        assert set(targets) <= _makefile_targets(), f"{cmd.where}: no target {set(targets) - _makefile_targets()}"
    elif argv[0] == "dask":
        help_text = _help(str(REPO / ".venv" / "bin" / "dask"), argv[1])
        options = {a.split("=", 1)[0] for a in argv[2:] if a.startswith("--")}
        assert options and all(o in help_text for o in options), f"{cmd.where}: {options}"
    elif argv[0] == "ros2":
        assert argv[1] in ("run", "launch") and argv[2] == "train_calib", cmd.where
        if argv[1] == "run":
            assert f'"{argv[3]}"' in (REPO / "setup.py").read_text(encoding="utf-8"), f"{cmd.where}: no executable"
            for f in _option_values(argv, "--params-file"):
                if f.startswith(REPO_PREFIXES):
                    assert (REPO / f).is_file(), f"{cmd.where}: {f}"
        else:
            assert (REPO / "launch" / argv[3]).is_file(), cmd.where
    else:  # .venv/bin/python FILE ... | -m pytest PATH
        assert (REPO / argv[0]).exists(), cmd.where
        if argv[1:3] == ("-m", "pytest"):
            assert all((REPO / a).exists() for a in argv[3:] if not a.startswith("-")), cmd.where
        elif len(argv) > 1 and argv[1].endswith(".py"):
            assert (REPO / argv[1]).is_file(), cmd.where
            help_text = _help(sys.executable, str(REPO / argv[1]))
            options = {a.split("=", 1)[0] for a in argv[2:] if a.startswith("--")}
            assert all(o in help_text for o in options), f"{cmd.where}: {options}"


def _full_docs() -> list[list[Command]]:
    """Per doc, its block commands in order (a reader following it top to bottom), without those that wait for
    something outside (``--live``, ``--scheduler``, ``record``) and without placeholders."""
    docs: dict[str, list[Command]] = {}
    for c in COMMANDS:
        if c.argv[0] != "train-calib" or any(PLACEHOLDER.match(a) for a in c.argv):
            continue
        if "--live" in c.argv or "--scheduler" in c.argv or c.argv[1] == "record":
            continue
        docs.setdefault(c.doc, []).append(c)
    return list(docs.values())


@pytest.mark.ros
@pytest.mark.slow
@pytest.mark.skipif(not FULL, reason="TRAIN_CALIB_DOCS_FULL=1 runs every doc's commands in order (minutes)")
@pytest.mark.parametrize("commands", _full_docs(), ids=lambda b: b[0].doc)
def test_every_doc_runs_top_to_bottom(commands: list[Command], tmp_path):
    for name in ("bags", "config", "docs"):
        (tmp_path / name).symlink_to(REPO / name)
    scratch = f"{tmp_path}/tmp/"  # a doc's /tmp/X: here, so a second run or another user's /tmp/X changes nothing
    for shown in commands:
        cmd = replace(shown, argv=tuple(a.replace("/tmp/", scratch) for a in shown.argv))
        done = _run(cmd, tmp_path)
        assert done.returncode == 0, f"{shown.where}: exit {done.returncode}\n{done.stderr[-2000:]}"
        assert "Traceback" not in done.stderr, f"{shown.where}:\n{done.stderr[-2000:]}"
