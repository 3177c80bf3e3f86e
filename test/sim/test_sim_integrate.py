"""The Dormand-Prince integrator: accuracy, events, stops and dense output against closed forms."""

from __future__ import annotations

import math

import numpy as np
import pytest

from train_calib.sim.integrate import Event, IntegrationError, StepRecord, integrate


def oscillator(_x, a, b):
    return b, -a


def rate(value: float):
    """da/dx = value, db/dx = 0: a grows linearly (a = value x from 0)."""
    return lambda _x, _a, _b: (value, 0.0)


def run(f, a0: float, b0: float, x_end: float, *, h: float, rtol: float, atol: float, **options):
    """integrate from x = 0 with the same absolute tolerance on a and b."""
    return integrate(f, 0.0, a0, b0, x_end, h=h, rtol=rtol, atol_a=atol, atol_b=atol, **options)


def test_harmonic_oscillator_to_tolerance():
    out = run(oscillator, 1.0, 0.0, 10.0, h=0.1, rtol=1e-10, atol=1e-12)
    assert out.tag is None and out.x == pytest.approx(10.0)
    assert out.ya == pytest.approx(math.cos(10.0), abs=1e-8)
    assert out.yb == pytest.approx(-math.sin(10.0), abs=1e-8)


def test_terminal_event_is_located_on_the_dense_output():
    # first zero of cos after 0 is pi/2; the event fires where -a goes from < 0 to >= 0
    out = run(oscillator, 1.0, 0.0, 10.0, h=0.5, rtol=1e-9, atol=1e-12, events=[Event(lambda _x, a, _b: -a, "zero")])
    assert out.tag == "zero"
    assert out.x == pytest.approx(math.pi / 2, abs=1e-8)
    assert abs(out.ya) < 1e-8


def test_event_already_satisfied_at_start_waits_until_it_was_negative():
    # a = cos x starts at 1 (>= 0): "a >= 0" must not fire at once, only at the next upward zero (3 pi / 2)
    out = run(oscillator, 1.0, 0.0, 10.0, h=0.5, rtol=1e-9, atol=1e-12, events=[Event(lambda _x, a, _b: a, "up")])
    assert out.x == pytest.approx(1.5 * math.pi, abs=1e-8)


def test_x_stops_and_ya_stops_end_steps_exactly():
    trace: list = []
    stops = [0.37, 1.234, 2.5]
    run(rate(1.0), 0.0, 0.0, 3.0, h=10.0, rtol=1e-8, atol=1e-9, x_stops=stops, trace=trace)
    xs = [p[0] for p in trace]
    for s in stops:
        assert s in xs
    # ya (= x here, but located by root finding) stops over "time"
    trace = []
    run(rate(2.0), 0.0, 0.0, 3.0, h=10.0, rtol=1e-8, atol=1e-9, ya_stops=[1.0, 3.3], trace=trace)
    hit = [p for p in trace if abs(p[1] - 1.0) < 1e-12]
    assert hit and hit[0][0] == pytest.approx(0.5, abs=1e-10)
    assert any(abs(p[1] - 3.3) < 1e-12 for p in trace)


def test_non_terminal_event_cuts_but_continues():
    trace: list = []
    out = run(
        rate(1.0),
        0.0,
        0.0,
        2.0,
        h=10.0,
        rtol=1e-8,
        atol=1e-9,
        events=[Event(lambda _x, a, _b: a - 0.7, None, terminal=False)],
        trace=trace,
    )
    assert out.tag is None and out.x == pytest.approx(2.0)
    assert any(abs(p[0] - 0.7) < 1e-9 for p in trace)


def test_dense_output_of_recorded_steps():
    rec = StepRecord()
    run(oscillator, 1.0, 0.0, 6.0, h=0.5, rtol=1e-9, atol=1e-12, record=rec)
    x = np.linspace(0.0, 6.0, 997)
    a, b, _ = rec.evaluate(x)
    # 4th-order interpolant between ~0.1-0.3 wide steps at rtol 1e-9
    assert np.max(np.abs(a - np.cos(x))) < 1e-7
    assert np.max(np.abs(b + np.sin(x))) < 1e-7


def test_analytic_pieces_in_the_record():
    rec = StepRecord()
    rec.add_poly(0.0, 2.0, 5.0, 3.0, (6.0, -2.0, 0.0, 0.0), (-4.0, 0.0, 0.0, 0.0), 0)  # s = 5 + 3t - t^2/2
    s, v, _ = rec.evaluate(np.array([0.0, 1.0, 2.0]))
    assert np.allclose(s, [5.0, 7.5, 9.0]) and np.allclose(v, [3.0, 1.0, -1.0])


def test_non_finite_derivative_raises():
    with pytest.raises(IntegrationError):
        integrate(
            lambda _x, a, _b: (1.0 / (1.0 - a), 0.0), 0.0, 0.0, 0.0, 2.0, h=0.1, rtol=1e-8, atol_a=1e-9, atol_b=1e-9
        )


def test_the_state_returned_at_an_event_satisfies_it():
    """The driver relies on it: after 's >= break' fired, s is not a hair short of the break."""
    for target in np.linspace(0.1, 9.9, 37):
        out = run(
            rate(1.3),
            0.0,
            0.0,
            10.0,
            h=3.0,
            rtol=1e-8,
            atol=1e-9,
            events=[Event(lambda _x, a, _b, t=target: a - t, "hit")],
        )
        assert out.tag == "hit" and out.ya >= target and out.ya - target < 1e-9
