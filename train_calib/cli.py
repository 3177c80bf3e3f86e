"""``train-calib``: the single command-line entry point.

Each subcommand is a module of ``train_calib.commands`` that defines ``NAME``, ``HELP``,
``add_arguments(parser)`` and ``run(args) -> int``. Only the module of the command being run is
imported (the listing reads NAME and HELP from the sources), so start-up stays fast whatever the
other commands import. Errors the user can fix (a bad file, an unreadable bag, a bad option) are
printed as one line and exit with status 2.
"""

from __future__ import annotations

import argparse
import ast
import importlib
import pkgutil
import sys
from collections.abc import Sequence
from functools import lru_cache
from pathlib import Path

from . import __version__, commands
from .errors import TrainCalibError


class OneLineErrorParser(argparse.ArgumentParser):
    """Usage errors as one line (``train-calib <command>: error: ...``) and exit status 2."""

    def error(self, message: str):  # type: ignore[override]
        print(f"{self.prog}: error: {message}", file=sys.stderr)
        raise SystemExit(2)


@lru_cache(maxsize=1)
def command_index() -> dict[str, tuple[str, str]]:
    """Command name -> (module name, one-line help), read from the module sources without importing them."""
    index = {}
    for info in sorted(pkgutil.iter_modules(commands.__path__), key=lambda i: i.name):
        if info.name.startswith("_"):
            continue
        source = Path(commands.__path__[0], f"{info.name}.py").read_text(encoding="utf-8")
        constants = {}
        for node in ast.parse(source).body:
            target = node.targets[0] if isinstance(node, ast.Assign) and len(node.targets) == 1 else None
            if isinstance(target, ast.Name) and target.id in ("NAME", "HELP"):
                constants[target.id] = ast.literal_eval(node.value)
        index[constants["NAME"]] = (info.name, constants.get("HELP", ""))
    return index


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The parser: every command listed, and the full arguments of ``command`` (only its module is imported)."""
    parser = OneLineErrorParser(
        prog="train-calib",
        description="Real-time train motion model calibration: simulate, replay bags through the ROS 2 "
        "node graph, calibrate from traction power or track occupation data.",
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True, parser_class=OneLineErrorParser)
    for name, (module_name, help_text) in command_index().items():
        if name != command:
            sub.add_parser(name, help=help_text)
            continue
        module = importlib.import_module(f"{commands.__name__}.{module_name}")
        cmd = sub.add_parser(name, help=help_text, description=module.__doc__)
        module.add_arguments(cmd)
        cmd.set_defaults(_run=module.run)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    command = next((a for a in argv if not a.startswith("-")), None)
    args = build_parser(command).parse_args(argv)
    try:
        return int(args._run(args) or 0)
    except TrainCalibError as exc:
        print(f"train-calib {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"train-calib {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
