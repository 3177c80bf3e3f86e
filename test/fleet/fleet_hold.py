"""A test-only wrapper of ``process_run`` for the killed-worker test: it reports the start of each run (a marker
file ``start-INDEX-PID`` in ``hold_dir``) and holds the run of manifest index ``victim`` until the file
``hold_dir/release`` exists, so the test knows which worker process is inside that run when it kills it. Imported by
the ``dask worker`` processes (the test puts this folder on their PYTHONPATH)."""

from __future__ import annotations

import os
import time
from pathlib import Path
from typing import Any

from train_calib.fleet.row import process_run

HOLD_TIMEOUT_S = 120.0  # a test that never releases still ends


def held_run(job: dict[str, Any], hold_dir: str, victim: int) -> dict[str, Any]:
    """``process_run(job)``, after writing ``start-INDEX-PID``; the victim's run waits for ``release`` first."""
    hold = Path(hold_dir)
    (hold / f"start-{job['index']}-{os.getpid()}").touch()
    if job["index"] == victim:
        deadline = time.monotonic() + HOLD_TIMEOUT_S
        while not (hold / "release").exists() and time.monotonic() < deadline:
            time.sleep(0.02)
    return process_run(job)
