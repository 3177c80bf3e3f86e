"""Occupation/release events from a head trajectory, against the closed-form passage times."""

from __future__ import annotations

import numpy as np
import pytest
from occupation_synthetic import even_sections, kinematic_run

from train_calib.occupation.generate import first_passage_times, occupation_events
from train_calib.track import Section


def test_first_passage_exact_on_piecewise_linear_and_standstill():
    t = np.array([0.0, 10.0, 20.0, 30.0, 40.0])
    s = np.array([0.0, 100.0, 100.0, 300.0, 290.0])  # standstill, then a small step back (noise)
    got = first_passage_times(t, s, np.array([-5.0, 0.0, 50.0, 100.0, 150.0, 300.0, 301.0]))
    np.testing.assert_allclose(got[:6], [0.0, 0.0, 5.0, 10.0, 22.5, 30.0])
    assert np.isnan(got[6])


def _analytic_time(s, a=0.5, v=30.0, b=0.5, length=6000.0):
    """Closed-form t(s) of accelerate (a) / cruise (v) / brake (b) over ``length``."""
    s1, s2 = v * v / (2 * a), length - v * v / (2 * b)
    t1 = v / a
    t2 = t1 + (s2 - s1) / v
    return np.where(
        s <= s1,
        np.sqrt(2 * s / a),
        np.where(s <= s2, t1 + (s - s1) / v, t2 + v / b - np.sqrt(2 * np.maximum(length - s, 0) / b)),
    )


def test_events_match_closed_form():
    t, s, _ = kinematic_run(6000.0, 30.0, accel=0.5, brake=0.5)
    np.testing.assert_allclose(t, _analytic_time(s), atol=1e-6)  # the helper itself is exact
    sections = [Section("A", 0.0, 400.0), *even_sections(6000.0, 12)[1:]]
    sections[1] = Section("S01", 400.0, 1000.0)
    length, t0, delay = 162.0, 30_000.3, 0.7
    run = occupation_events(t, s, length, sections, run_id="x", t0_s=t0, release_delay_s=delay)
    # head stands in A at the start: no occupation of A; every later section is occupied
    assert "A" not in run.occupy
    assert len(run.occupy) == len(sections) - 1
    for sec in sections[1:]:
        assert run.occupy[sec.id] == np.floor(t0 + _analytic_time(np.array(sec.start_m)))
    # the tail leaves a section when the head is L past its end; the last sections are never released
    for sec in sections:
        head = sec.end_m + length
        if head <= 6000.0:
            assert run.release[sec.id] == np.floor(t0 + _analytic_time(np.array(head)) + delay)
        else:
            assert sec.id not in run.release
    assert len(run.release) == sum(sec.end_m + length <= 6000.0 for sec in sections)


def test_unrounded_and_jitter():
    t, s, _ = kinematic_run(3000.0, 25.0)
    sections = even_sections(3000.0, 6)
    exact = occupation_events(t, s, 100.0, sections, round_down=False)
    assert exact.occupy["S01"] == pytest.approx(_analytic_time(np.array(500.0), v=25.0, length=3000.0), abs=1e-6)
    rng = np.random.default_rng(3)
    jit = occupation_events(t, s, 100.0, sections, round_down=False, release_jitter_s=2.0, rng=rng)
    extra = np.array([jit.release[k] - exact.release[k] for k in exact.release])
    assert np.all((extra >= 0) & (extra <= 2.0)) and np.ptp(extra) > 0.1
    with pytest.raises(ValueError):
        occupation_events(t, s, 0.0, sections)
