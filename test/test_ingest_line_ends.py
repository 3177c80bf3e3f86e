"""The ingest at the ends of the line, through the public ``Ingest`` API: a position dead-reckoned backwards (while
reversing, with no fix) stops at the line's start, so the fixes that come back are matched where the train can be.

Scene: test/data/small_track.yaml (a 3 km line due north), fixes and speed at 1 Hz at exactly known positions.
"""

from __future__ import annotations

import test_ingest
from test_ingest import NS, T0, fix_at

from train_calib.ingest import GNSS, SPEED, Ingest, SpeedSample

track, train = test_ingest.track, test_ingest.train  # the small track and train fixtures


def _shunt(t: int) -> float:
    """s in m at t in s: forward from 140 m to 200 m (0-20 s), back to 20 m (20-80 s), forward again; 3 m/s."""
    if t <= 20:
        return 140.0 + 3.0 * t
    if t <= 80:
        return 200.0 - 3.0 * (t - 20)
    return 20.0 + 3.0 * (t - 80)


def test_reversing_in_a_gnss_gap_dead_reckons_back_to_the_line_start_and_no_further(track, train):
    """GNSS lost from 50 s (at 110 m, reversing) to 110 s (at 110 m again, forward). Until the fixes show the
    turn the ingest takes the train as still reversing and moves its position back with the (unsigned) speed:
    60 s at 3 m/s from 110 m would be -70 m; it stops at the line's start (0 m). The continuity window around 0 m,
    grown by 1 m/s over the 60 s gap (60 + 60 m), then holds the fix at 110 m: no jump and no re-acquisition
    (from -70 m the window would end at about 56 m: two fixes dropped as jumps, then a re-acquisition). The
    speed samples stay reversing until the fixes have moved forward over reverse_distance (50 m, at 127 s): 94 of
    them, then a new run."""
    ingest = Ingest(track, train)
    out = []
    for t in range(141):
        if not 50 <= t < 110:
            out += ingest.add_fix(fix_at(track, float(t), _shunt(t)))
        out += ingest.add_speed(SpeedSample(T0 + t * NS, 3.0))
    out += ingest.flush()
    stats = ingest.stats
    assert dict(stats.dropped[GNSS]) == {} and stats.reacquisitions == 0
    assert dict(stats.dropped[SPEED]) == {"reversing": 94} and stats.reversals == 1
    seconds = [(m.stamp_ns - T0) // NS for m in out]
    assert seconds == [*range(0, 33), *range(127, 141)]  # the turn back seen from 33 s
    assert [m.run_id for m in out] == [0] * 33 + [1] * 14
    assert all(abs(m.s - _shunt(k)) < 1e-3 for m, k in zip(out, seconds))  # every one paired with its fix


def _reversing_after_a_speed_gap(track, train, fix_first: bool) -> int:
    """Forward at 10 m/s for 20 s, the speeds silent for 40 s (the odometer restarts) while the fixes go on, then
    backwards at 5 m/s for 40 s; a fix and a speed sample every second, in the given order at each stamp."""
    ingest = Ingest(track, train)
    for t in range(100):
        s = 1000.0 + 10.0 * t if t < 20 else 1200.0 if t < 60 else 1200.0 - 5.0 * (t - 60)
        pair = [("fix", fix_at(track, float(t), s))]
        if not 20 <= t < 60:
            pair.append(("speed", SpeedSample(T0 + t * NS, 10.0 if t < 20 else 5.0)))
        for kind, event in pair if fix_first else pair[::-1]:
            ingest.add_fix(event) if kind == "fix" else ingest.add_speed(event)
    ingest.flush()
    return ingest.stats.dropped[SPEED].get("reversing", 0)


def test_the_direction_check_after_a_speed_gap_does_not_depend_on_the_arrival_order(track, train):
    """The fix of the restart's stamp counts whether it comes before or after the speed sample: 30 speed samples
    dropped as reversing either way (the queue used to be cleared at the restart: 29 with the fix first,
    bench/mutation/restart_order.py, mutation ingest-9)."""
    assert _reversing_after_a_speed_gap(track, train, True) == _reversing_after_a_speed_gap(track, train, False) == 30
