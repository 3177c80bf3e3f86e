"""``--track GEOMETRY.yaml+PROFILE.json``: a track file's geometry and stations (e.g. from ``build-track``) with a
TTOBench track's gradients, speed limits and curves mapped onto them through the stops."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import ConfigError
from ..yamlcheck import load_yaml_mapping
from .profile import align, mapped_table, read_ttobench_track


def combined_track_mapping(spec: str) -> tuple[dict, str]:
    """The track file's mapping of ``GEOMETRY.yaml+PROFILE.json`` and the name to use in errors."""
    geometry_path, _, profile_path = spec.rpartition("+")
    if not geometry_path:
        raise ConfigError(spec, "", "a TTOBench track has no coordinates: give GEOMETRY.yaml+PROFILE.json "
                          "(GEOMETRY from train-calib build-track)")  # fmt: skip
    data = load_yaml_mapping(geometry_path, "track file")
    stations = data.get("stations")
    if not isinstance(stations, list) or len(stations) < 2:
        raise ConfigError(geometry_path, "stations", "needs at least 2 stations to align a TTOBench profile to")
    try:
        found = np.array([float(st["s_m"]) for st in stations])
        length = float(data["length_m"])
    except (KeyError, TypeError, ValueError):
        raise ConfigError(geometry_path, "stations", "every station needs a numeric s_m (and length_m)") from None
    profile = read_ttobench_track(Path(profile_path))
    alignment = align(profile.stops, found, profile_path)

    def to_s(p: np.ndarray) -> np.ndarray:
        return alignment(p)

    data = dict(data)
    data["gradients"] = [{"s_m": s, "permille": v} for s, v in mapped_table(profile.gradients, to_s, length)]
    data["speed_limits"] = [{"s_m": s, "kmh": v} for s, v in mapped_table(profile.limits, to_s, length)]
    if profile.curves:
        data["curves"] = [{"s_m": s, "radius_m": v} for s, v in mapped_table(profile.curves, to_s, length)]
    data["description"] = f"{data.get('description', '')} + profile {Path(profile_path).name}".strip()
    return data, spec
