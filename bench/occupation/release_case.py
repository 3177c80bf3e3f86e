"""The release-delay case of issue 22: a real TTOBench profile with track-detection sections of 600-1500 m.

``case_track(profile, seed)`` reads one of the independent validation tracks (the TTOBench profiles with a
synthesised geometry, ``../shared/validation/runs/track_*.yaml``) and cuts it into contiguous sections of
U(600, 1500) m; ``write_case_track`` writes it as a track file for the commands.
"""

from __future__ import annotations

import itertools
from pathlib import Path

import numpy as np
import yaml

HERE = Path(__file__).resolve().parent
VALIDATION = HERE.parents[2] / "shared" / "validation" / "runs"
PROFILES = {
    "vasteras": "track_vasteras.yaml",
    "stadelhofen": "track_stadelhofen.yaml",
    "yizhuang": "track_yizhuang.yaml",
}
TYPES = HERE / "types_virm6_flirt.yaml"


def case_track(profile: str, seed: int = 0, low_m: float = 600.0, high_m: float = 1500.0) -> dict:
    """The validation track ``profile`` as a mapping, with contiguous sections of U(low, high) m (last one shorter
    than ``low`` merged into the one before)."""
    data = yaml.safe_load((VALIDATION / PROFILES[profile]).read_text(encoding="utf-8"))
    length = float(data["length_m"])
    rng = np.random.default_rng(seed)
    edges = [0.0]
    while length - edges[-1] > high_m:
        edges.append(edges[-1] + float(rng.uniform(low_m, high_m)))
    edges.append(length)
    if len(edges) > 2 and edges[-1] - edges[-2] < low_m:
        del edges[-2]
    data["name"] = f"{profile} with {len(edges) - 1} sections of {low_m:.0f}-{high_m:.0f} m (seed {seed})"
    data["sections"] = [
        {"id": f"S{k:02d}", "start_m": round(a, 1), "end_m": round(b, 1)}
        for k, (a, b) in enumerate(itertools.pairwise(edges))
    ]
    return data


def write_case_track(profile: str, out: Path, seed: int = 0) -> Path:
    out = Path(out)
    out.write_text(yaml.safe_dump(case_track(profile, seed), sort_keys=False), encoding="utf-8")
    return out


if __name__ == "__main__":  # python bench/occupation/release_case.py PROFILE OUT.yaml [SEED]
    import sys

    if len(sys.argv) not in (3, 4) or sys.argv[1] not in PROFILES:
        sys.exit(f"usage: release_case.py {{{','.join(PROFILES)}}} OUT.yaml [SEED]")
    print(write_case_track(sys.argv[1], Path(sys.argv[2]), int(sys.argv[3]) if len(sys.argv) == 4 else 1))
