"""``--params-file``: a ROS 2 params file (the nodes' and the replay's format, e.g. config/train_calib.yaml) as the
offline pipeline's configuration for every run of a fleet.

The file is read and checked with what the nodes use: :func:`yamlcheck.load_yaml_mapping` (one line for an
unreadable file or bad YAML), the node -> ParamSets table ``nodes.config.NODE_PARAMS`` (which parameters each node
declares), ``Checker.known_keys`` (an unknown node or parameter is refused naming the nearest valid one) and
``ParamSet.from_mapping`` (types, units, ranges, cross-field checks). Every failure is a ConfigError, one line
``FILE: NODE.ros__parameters.KEY: problem``.

Sections: ``NODE: {ros__parameters: {...}}`` for the nodes of ``NODE_PARAMS`` (a leading ``/`` is allowed) and
``/**`` (every node that declares the parameter; a node's own section wins). The core parameter sets go to
:class:`pipeline.Pipeline` (``ingest``, ``ukf``, ``safeguards``, ``regime``, ``features``, ``window``); the nodes'
own parameters (diagnostics, QoS depths) and ``track_file``/``train_file`` are accepted and have no effect offline
(each run's track and train are the manifest's).
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ..errors import ConfigError
from ..params import ParamSet

WILDCARD = "**"
SECTION = "ros__parameters"


def _pipeline_argument(owner: type[ParamSet]) -> str | None:
    """The :class:`pipeline.Pipeline` keyword a ParamSet goes to (None: a node-only set)."""
    from ..estimation.config import FeatureConfig, RegimeConfig, UKFConfig
    from ..estimation.safeguards import SafeguardConfig
    from ..ingest import IngestConfig
    from ..window.config import WindowConfig

    table: dict[type[ParamSet], str] = {
        IngestConfig: "ingest",
        UKFConfig: "ukf",
        SafeguardConfig: "safeguards",
        RegimeConfig: "regime",
        FeatureConfig: "features",
        WindowConfig: "window",
    }
    return table.get(owner)


@dataclass(frozen=True)
class FleetParams:
    """The pipeline's configuration from a params file: ``configs`` (Pipeline keyword -> ParamSet, only the sets the
    file sets a value of), the file's path and the sha256 (hex) of its bytes (part of each run's key)."""

    path: str = ""
    sha256: str = ""
    configs: dict[str, ParamSet] = field(default_factory=dict)


def load_fleet_params(path: str | Path) -> FleetParams:
    """Read and check a params file (ConfigError, one line, on any problem)."""
    from ..nodes.config import NODE_PARAMS
    from ..yamlcheck import Checker, load_yaml_mapping

    source = str(path)
    data = load_yaml_mapping(path, "params file")
    raw = Path(path).read_bytes()
    check = Checker(source)
    nodes = {str(name).lstrip("/"): value for name, value in data.items()}
    check.known_keys(nodes, [WILDCARD, *NODE_PARAMS])
    label = {str(name).lstrip("/"): str(name) for name in data}  # as written in the file, for the messages
    values: dict[str, dict[str, Any]] = {}  # node -> parameter -> value
    for node, section in nodes.items():
        check.known_keys(section, [SECTION], prefix=f"{label[node]}.")
        params = check.get(section, SECTION, prefix=f"{label[node]}.", required=False, default={})
        if not isinstance(params, dict):
            raise check.fail(f"{label[node]}.{SECTION}", f"expected a mapping, found {type(params).__name__}")
        known = [s.name for owner in NODE_PARAMS.get(node, ()) for s in owner.specs()]
        if node == WILDCARD:
            known = sorted({s.name for owners in NODE_PARAMS.values() for owner in owners for s in owner.specs()})
        check.known_keys(params, known, prefix=f"{label[node]}.{SECTION}.")
        values[node] = {str(k): v for k, v in params.items()}
    configs: dict[str, ParamSet] = {}
    for node, owners in NODE_PARAMS.items():
        here = {**values.get(WILDCARD, {}), **values.get(node, {})}
        for owner in owners:
            names = {s.name for s in owner.specs()}
            mine = {k: v for k, v in here.items() if k in names}
            if not mine:
                continue
            where = label[node] if node in values and names & values[node].keys() else label[WILDCARD]
            config = owner.from_mapping(mine, source=source, prefix=f"{where}.{SECTION}.")
            argument = _pipeline_argument(owner)
            if argument is not None:
                configs[argument] = config
    return FleetParams(path=source, sha256=hashlib.sha256(raw).hexdigest(), configs=configs)


__all__ = ["ConfigError", "FleetParams", "load_fleet_params"]
