"""ingest-9 (bench/mutation/mutations.py): the ingest's direction check after a speed gap depended on the order in
which a fix and a speed sample of the same stamp arrive while the fix queue was cleared at an odometer restart; it is
kept now, and ingest-9 puts the clear back (fix first: 29 samples dropped as reversing, speed first: 30; the tree: 30
and 30; pinned by test/test_ingest_line_ends.py).

Scene (test/data/small_track.yaml): forward at 10 m/s for 20 s, the speed stream silent for 40 s (longer than
max_sample_age: the odometer restarts) while the fixes go on, then backwards at 5 m/s for 40 s. Printed: the speed
samples dropped as reversing with the fix of each second first and with the speed sample first, on the tree and on a
throwaway copy with ingest-9 applied.

    PYTHONPATH=. .venv/bin/python bench/mutation/restart_order.py
"""

from __future__ import annotations

import subprocess
import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

from mutations import MUTATIONS  # noqa: E402
from run import ROOT, apply, copy_tree  # noqa: E402

SCENE = """
from train_calib.ingest import GnssFix, Ingest, SpeedSample
from train_calib.track import load_track
from train_calib.train import load_train

NS, T0 = 1_000_000_000, 1_700_000_000 * 1_000_000_000
track, train = load_track("test/data/small_track.yaml"), load_train("test/data/small_train.yaml")
for fix_first in (True, False):
    ingest = Ingest(track, train)
    for t in range(100):
        s = 1000.0 + 10.0 * t if t < 20 else 1200.0 if t < 60 else 1200.0 - 5.0 * (t - 60)
        lat, lon = track.latlon_at(s)
        events = [GnssFix(T0 + t * NS, float(lat), float(lon), 0)]
        if not 20 <= t < 60:
            events.append(SpeedSample(T0 + t * NS, 10.0 if t < 20 else 5.0))
        for e in events if fix_first else events[::-1]:
            ingest.add(e)
    ingest.flush()
    print(f"  {'fix' if fix_first else 'speed'} first: reversing {ingest.stats.dropped['speed'].get('reversing', 0)}")
"""


def scene(tree: Path) -> str:
    return subprocess.run([sys.executable, "-c", SCENE], cwd=tree, env={"PYTHONPATH": str(tree)},
                          capture_output=True, text=True, check=True).stdout  # fmt: skip


def main() -> int:
    print("the tree:\n" + scene(ROOT), end="")
    with tempfile.TemporaryDirectory(prefix="mutant-ingest-9-") as tmp:
        copy_tree(Path(tmp))
        apply(next(m for m in MUTATIONS if m.name == "ingest-9"), Path(tmp))
        print("ingest-9 applied:\n" + scene(Path(tmp)), end="")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
