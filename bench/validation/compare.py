"""Side by side: the aggregates of several scores JSON files (score.py) in one markdown table.

Per family and split: the prior's median |error| at v_ref (%), the data's limit (oracle, with and without the
correlation of the speed differences), then per scores file the median |error|, runs with the truth inside
2 sigma, the median 2 sigma / r and the runs worse than their prior by more than 2 points.

    .venv/bin/python bench/validation/compare.py build/validation/scores_default.json \
        build/validation/scores_converging.json [--out FILE]
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any


def _f(x: float | None) -> str:
    return "-" if x is None else f"{x:.1f}"


def load(path: Path) -> tuple[str, dict[tuple[str, str], dict[str, Any]]]:
    """(preset, aggregates by (family, split)) of one scores file."""
    doc = json.loads(path.read_text(encoding="utf-8"))
    return doc["preset"], {(a["family"], a["split"]): a for a in doc["aggregates"]}


def table(files: Sequence[Path]) -> str:
    """The markdown table over the (family, split) groups of the first file."""
    loaded = [load(p) for p in files]
    head = "| family | split | runs | prior | oracle | oracle, white | coast s |"
    rule = "|---|---|---|---|---|---|---|"
    for preset, _ in loaded:
        head += f" `{preset}` err | inside 2 sigma | 2 sigma / r | worse |"
        rule += "---|---|---|---|"
    lines = [head, rule]
    for key, a in loaded[0][1].items():
        row = (
            f"| {key[0]} | {key[1]} | {a['runs']} | {_f(a['median_prior_err'])} | {_f(a['median_oracle_err'])} "
            f"({a['runs_with_coast']}) | {_f(a.get('median_oracle_white_err'))} | {a['median_coast_s']:.0f} |"
        )
        for _, aggs in loaded:
            b = aggs.get(key)
            if b is None:
                row += " - | - | - | - |"
                continue
            row += (
                f" {_f(b['median_err'])} | {b['inside_2sigma']}/{b['runs']} | {_f(b['median_two_sigma_pct'])} | "
                f"{b['worse_than_prior']} |"
            )
        lines.append(row)
    return "\n".join(lines) + "\n"


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("files", nargs="+", type=Path, help="scores_<preset>.json files")
    ap.add_argument("--out", type=Path, help="also write the table here")
    args = ap.parse_args(argv)
    text = table(args.files)
    if args.out:
        args.out.write_text(text, encoding="utf-8")
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
