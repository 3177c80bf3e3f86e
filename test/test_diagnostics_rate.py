"""/diagnostics in the data's time (issue 21): the same number of statuses at any replay rate.

Before: a timer of the simulated clock fired once per jump of /clock, so the demo bag gave 28 statuses at
``--rate 0`` and 4,528 at ``--rate 20``. Now a node under ``use_sim_time`` publishes at most once per
``diagnostics_period`` of its inputs' stamps (``DiagnosticsSchedule``), 60 s in a replay.
"""

from __future__ import annotations

import pytest

from train_calib import paths
from train_calib.diagnostics_schedule import DiagnosticsSchedule
from train_calib.replay import REPLAY_DIAGNOSTICS_PERIOD_S, ReplayOptions, replay, sets_parameter

S = 1_000_000_000  # ns


def _count(schedule: DiagnosticsSchedule, stamps_ns) -> int:
    return sum(schedule.due(t) for t in stamps_ns)


def test_schedule_counts_periods_of_the_data_not_calls():
    # 1 Hz data over 100 s with a 10 s period: the grid 10, 20, ..., 100 s after the first stamp's period
    assert _count(DiagnosticsSchedule(10.0), [k * S for k in range(101)]) == 10
    # 0.1 Hz data with a 1 s period: one status a sample (each sample is in a new period), not ten
    assert _count(DiagnosticsSchedule(1.0), [k * 10 * S for k in range(14)]) == 13
    # two topics with the same stamps (fix and speed): still one status a period
    assert _count(DiagnosticsSchedule(10.0), [k * S for k in range(101) for _ in range(2)]) == 10
    # jitter of +-0.3 s around the grid does not double a status: 0.7 .. 99.7 s crosses 10, 20, ..., 90 s
    stamps = [int((k + (0.3 if k % 2 else -0.3)) * S) for k in range(1, 101)]
    assert _count(DiagnosticsSchedule(10.0), stamps) == 9


def test_schedule_restarts_after_a_clock_reset_or_an_absurd_stamp():
    sched = DiagnosticsSchedule(10.0)
    assert _count(sched, [k * S for k in range(0, 50)]) == 4  # 10, 20, 30, 40 s
    assert sched.due(2**62)  # a corrupted stamp far in the future: one status, the grid moves there
    # back to the data's time: the grid restarts at its first stamp (50 s), then a status every 10 s again
    assert _count(sched, [k * S for k in range(50, 101)]) == 5
    with pytest.raises(ValueError, match="period"):
        DiagnosticsSchedule(0.0)


def test_replay_overrides_the_period_unless_a_params_file_sets_it(tmp_path):
    mine = tmp_path / "mine.yaml"
    mine.write_text("ukf_node:\n  ros__parameters:\n    diagnostics_period: 2.0\n")
    other = tmp_path / "other.yaml"
    other.write_text("/**:\n  ros__parameters:\n    input_timeout: 5.0\n")
    assert sets_parameter([other, mine], "diagnostics_period")
    assert not sets_parameter([other], "diagnostics_period")
    assert REPLAY_DIAGNOSTICS_PERIOD_S == 60.0


@pytest.mark.ros
def test_diagnostics_count_does_not_depend_on_the_replay_rate(tmp_path):
    """The first 240 s of the 1 Hz tunnel bag (5 nodes) at rate 0 and rate 20: the same /diagnostics count, about one
    status per node per 60 s of data plus the final one (before: 5 at rate 0, 300 for 60 s at rate 20)."""
    counts = {}
    for rate in (0.0, 20.0):
        result = replay(
            ReplayOptions(
                bag=paths.bags_dir() / "tunnel_line_37km_1s_00",
                track="tunnel_line_37km",
                train="icrm",
                out=tmp_path / f"rate_{rate:g}",
                rate=rate,
                until_s=240.0,
            )
        )
        assert result.recorded["/train_calib/measurement"] >= 230
        counts[rate] = result.recorded["/diagnostics"]
    nodes = 5
    assert counts[0.0] == counts[20.0]
    assert nodes * (240 // 60 - 1) + nodes <= counts[0.0] <= nodes * (240 // 60 + 1) + nodes
