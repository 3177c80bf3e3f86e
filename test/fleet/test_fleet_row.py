"""The fleet row's own choices leave it equal to the full chain's: the sliding-window calibration (not run for a
row) feeds nothing the row reads."""

from __future__ import annotations

import math

from repo_paths import REPO

from train_calib import pipeline
from train_calib.fleet.row import run_result
from train_calib.paths import track_file, train_file


def _same(a: object, b: object) -> bool:
    if isinstance(a, float) and isinstance(b, float):
        return a == b or (math.isnan(a) and math.isnan(b))
    if isinstance(a, list) and isinstance(b, list):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b))
    return a == b


def test_row_without_the_window_calibration_equals_the_full_chain(monkeypatch) -> None:
    """A 1 Hz bag with traction power (the window calibration fits every sample there)."""
    bag = str(REPO / "bags" / "tunnel_line_37km_1s_00")
    track, train = str(track_file("tunnel_line_37km")), str(train_file("icrm"))
    row = run_result(bag, track, train)
    windows: list[int] = []
    run_bag = pipeline.run_bag

    def full_chain(*args, **configs):
        configs.pop("window")
        out = run_bag(*args, **configs)
        windows.append(len(out.windows))
        return out

    monkeypatch.setattr(pipeline, "run_bag", full_chain)
    full = run_result(bag, track, train)
    assert windows and windows[0] > 1000
    assert row.keys() == full.keys()
    assert all(_same(row[k], full[k]) for k in row), [k for k in row if not _same(row[k], full[k])]


def test_tune_gc_once_freezes_and_raises_the_threshold() -> None:
    """What a fleet worker does after its first run (process_run in a Dask worker); the test process is restored."""
    import gc

    from train_calib.fleet import row

    saved, tuned = gc.get_threshold(), row._gc_tuned
    try:
        row._gc_tuned = False
        row.tune_gc()
        assert gc.get_threshold() == (row.GC_THRESHOLD0, *saved[1:])
        assert gc.get_freeze_count() > 1000
        gc.set_threshold(*saved)
        row.tune_gc()  # once a process: no second freeze or threshold change
        assert gc.get_threshold() == saved
    finally:
        gc.unfreeze()
        gc.set_threshold(*saved)
        row._gc_tuned = tuned
