"""Convert a TTOBench train JSON (kN, kN/(km/h), kW) into a train file (YAML, N/kg of effective mass) to edit.

What the JSON does not give is assumed and written as comments at the top of the YAML: the rotating mass factor
(from ``rho``, else 1.06), the length (25 m per coach), the adhesive mass fraction (0.5), the efficiency and the
service brake where absent. The options override them. ``--train`` also takes the JSON directly.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from ..errors import TrainCalibError

NAME = "convert-train"
HELP = "convert a TTOBench train JSON into a train file (YAML)"


class UsageError(TrainCalibError):
    """A command-line value the user can fix (one line)."""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("file", metavar="FILE", help="TTOBench train JSON")
    parser.add_argument("--out", required=True, help="train file to write (YAML; must not exist)")
    parser.add_argument("--name", help="train name (default: the file's metadata id)")
    parser.add_argument("--rotating-mass-factor", type=float, help="gamma, >= 1 (default: 1 + rho of the file)")
    parser.add_argument("--length", type=float, help="train length, m (default: 25 m per coach)")
    parser.add_argument(
        "--adhesive-mass-fraction", type=float, help="share of the mass on driven axles, 0-1 (default 0.5)"
    )


def run(args: argparse.Namespace) -> int:
    from ..train import load_train
    from ..ttobench import checked, convert_train, train_yaml_text

    out = Path(args.out)
    if out.exists():
        raise UsageError(f"{out}: already exists")
    train = convert_train(
        args.file,
        rotating_mass_factor=args.rotating_mass_factor,
        length_m=args.length,
        adhesive_mass_fraction=args.adhesive_mass_fraction,
        name=args.name,
    )
    checked(train)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(train_yaml_text(train, Path(args.file).name), encoding="utf-8")
    spec = load_train(out)
    for note in train.assumptions:
        print(f"{args.file}: {note}")
    print(
        f"{out}: {spec.name}: {spec.mass_t:g} t, gamma {spec.rotating_mass_factor:g}, {spec.length_m:g} m, "
        f"r0 {spec.davis.r0:.4g} N/kg, r1 {spec.davis.r1:.4g} N/(kg m/s), r2 {spec.davis.r2:.4g} N/(kg (m/s)^2)"
    )
    return 0
