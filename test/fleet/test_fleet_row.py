"""The fleet row's own choices leave it equal to the full chain's: the sliding-window calibration (not run for a
row) feeds nothing the row reads, the features snapshot at each regime change (not made for a row) change
nothing of the closing ones, and the per-sample regimes (the imm, not run for a row) nothing of the phases."""

from __future__ import annotations

import math

import pytest
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


@pytest.mark.parametrize(("name", "line", "unit"), [("tunnel_line_37km_1s_00", "tunnel_line_37km", "icrm"),
                                                    ("intercity_32km_10s_01", "intercity_32km", "virm6")])  # fmt: skip
def test_row_equals_the_full_chain(monkeypatch, name: str, line: str, unit: str) -> None:
    """A 1 Hz bag with traction power (the window calibration fits every sample there) and a 10 s bag."""
    bag = str(REPO / "bags" / name)
    track, train = str(track_file(line)), str(train_file(unit))
    row = run_result(bag, track, train)
    windows: list[int] = []
    snapshots: list[int] = []
    run_bag = pipeline.run_bag

    def full_chain(*args, **configs):
        assert configs.pop("window") is False and configs.pop("feature_changes") is False
        assert configs.pop("regime_labels") is False
        out = run_bag(*args, **configs)
        assert any(r.regime != r.phase for r in out.regimes)  # the imm ran: labels of its own
        windows.append(len(out.windows))
        snapshots.append(len(out.features))
        return out

    monkeypatch.setattr(pipeline, "run_bag", full_chain)
    full = run_result(bag, track, train)
    assert snapshots and snapshots[0] > 2 * row["runs_in_bag"]  # more than the closing ones
    if "1s" in name:
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
