"""Seeded fuzz of the bundled bags: every corrupted replay ends with a status, never a traceback, in bounded memory.

Byte flips, truncations, huge record lengths, header stamps before 1970 or at the int32 end, log times after 2038
(bagfuzz.py) on the five intercity bags; each replay (``train-calib replay``, one process for all of them, as a user
would run them one after the other) must end with exit status 0 (nothing that matters was damaged), 2 (unreadable:
nothing replayed), 3 (damaged: what could be read was replayed) or 4 (every sample dropped), with no exception and no
[FATAL] line, and the process must stay under MAX_RSS_MB. ``TRAIN_CALIB_FUZZ_CASES=300`` runs a few hundred (about
1 s each); ``make test`` runs the default 20.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
from repo_paths import REPO

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bagfuzz import KINDS, corrupt

pytestmark = pytest.mark.ros

CASES = int(os.environ.get("TRAIN_CALIB_FUZZ_CASES", "20"))
MAX_RSS_MB = 400.0  # measured 157 MB over 60 cases (the replay, the graph and the recorder in one process; VmHWM)
OK_STATUS = (0, 2, 3, 4)
KNOWN: dict[int, str] = {}  # seed -> a bug outside the replay, found by this test (not strict: passes once fixed)
# (58: the summary's coast regression on stamps that go back, fixed: coast_detection.monotonic_parts)


def _case(seed: int) -> dict:
    kind = KINDS[seed % len(KINDS)]
    name = f"intercity_32km_10s_0{(seed // len(KINDS)) % 5}"
    return {"seed": seed, "kind": kind, "source": name}


@pytest.fixture(scope="module")
def fuzzed(tmp_path_factory):
    """Every case replayed: seed -> {"status" | "exception"}, the runner's stderr and peak RSS (MB)."""
    work = tmp_path_factory.mktemp("fuzz")
    cases = []
    for seed in range(CASES):
        case = _case(seed)
        source = REPO / "bags" / case["source"]
        if case["kind"] in ("stamps", "logtime"):
            bag = corrupt(case["kind"], source, work / f"case{seed}", seed)
        else:
            bag = corrupt(case["kind"], source / f"{case['source']}.mcap", work / f"case{seed}.mcap", seed)
        cases.append({"bag": str(bag), "track": "intercity_32km", "train": "virm6"})
    (work / "cases.json").write_text(json.dumps(cases))
    runner = Path(__file__).with_name("bagfuzz.py")
    proc = subprocess.run(
        [sys.executable, str(runner), str(work / "cases.json"), str(work)],
        capture_output=True,
        text=True,
        timeout=60 + 20 * CASES,
    )
    lines = [json.loads(ln) for ln in proc.stdout.splitlines() if ln.startswith("{")]
    results = {r["case"]: r for r in lines if "case" in r}
    rss = next((r["max_rss_mb"] for r in lines if "max_rss_mb" in r), None)
    return results, proc.stderr, rss, proc.returncode


def _params() -> list:
    return [
        pytest.param(seed, marks=pytest.mark.xfail(reason=KNOWN[seed], strict=False)) if seed in KNOWN else seed
        for seed in range(CASES)
    ]


@pytest.mark.parametrize("seed", _params())
def test_a_corrupted_bag_ends_with_a_status_not_a_traceback(fuzzed, seed):
    results, _, _, _ = fuzzed
    assert seed in results, f"the runner stopped before case {seed} ({_case(seed)})"
    result = results[seed]
    assert "exception" not in result, f"{_case(seed)}: {result.get('exception')}"
    assert result["status"] in OK_STATUS, (_case(seed), result)


def test_the_fuzz_runner_prints_no_traceback_and_stays_under_the_memory_limit(fuzzed):
    results, stderr, rss, returncode = fuzzed
    assert returncode == 0 and len(results) == CASES, stderr[-2000:]
    assert "[FATAL]" not in stderr and "Traceback" not in stderr, stderr[-2000:]
    assert rss is not None and rss < MAX_RSS_MB, rss
