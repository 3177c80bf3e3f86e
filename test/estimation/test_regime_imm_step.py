"""The imm filter's fast step (``ImmFilter.step``, the helpers written out) against its readable reference
(``ImmFilter.reference_step``): the same regimes, probabilities, model states and learned noise, float for float."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from train_calib.estimation import RegimeConfig
from train_calib.estimation.regime_imm import ImmFilter


def _trace(f: ImmFilter, rows, fast: bool) -> list[str]:
    """Per row (t s, z m/s, w N/kg, power or None; None: a standstill) the regime, the probabilities, the model states
    and the learned noise, as text (repr is exact for floats, NaN included)."""
    step = f.step if fast else f.reference_step
    out = []
    for row in rows:
        if row is None:
            f.restart()
            out.append("restart")
            continue
        try:
            regime = step(*row)
        except (ArithmeticError, ValueError) as exc:  # extreme values (overflow, 1 / 0, domain): alike in both
            regime = type(exc).__name__
        out.append(repr((regime, f.probabilities(), [tuple(x) for x in f._x], f.speed_noise)))
    return out


def _agree(rows, cfg: RegimeConfig | None = None) -> None:
    cfg = cfg if cfg is not None else RegimeConfig()
    assert _trace(ImmFilter(cfg), rows, True) == _trace(ImmFilter(cfg), rows, False)


def test_fast_step_is_the_reference_on_a_noisy_run():
    """1 Hz and 10 s stretches of traction, coasting, holds and brakes with noisy, rounded speeds, power states in
    part of the run, a standstill, steps of changing length and a time that goes back once."""
    rng = np.random.default_rng(3)
    accel = np.concatenate([np.full(60, 0.4), np.full(80, 0.0), np.full(90, -0.05), np.full(40, -0.6)])
    v = np.maximum(5.0 + np.cumsum(accel), 0.0)
    rows = []
    t = 0.0
    for k, vk in enumerate(v):
        t += 1.0 if k < 150 else 10.0 if k < 200 else 0.5 + rng.random()
        z = round((vk + rng.normal(0.0, 0.1)) / 0.278) * 0.278
        w = 0.03 + 0.01 * math.sin(k / 17.0)
        power = None if k < 100 else int(rng.integers(0, 3))
        rows.append((t, z, w, power))
    rows[120] = None  # a standstill
    rows[180] = (rows[179][0] - 1.0, *rows[180][1:])  # time going back: start over
    _agree(rows)
    _agree(rows, RegimeConfig(imm_adapt_noise=False, imm_speed_noise_std=0.05))


@settings(max_examples=200, deadline=None)
@given(
    st.lists(
        st.one_of(
            st.none(),
            st.tuples(
                st.floats(-5.0, 20.0),  # time step, s (any sign)
                st.floats(allow_nan=True, allow_infinity=True, width=32),  # measured speed
                st.floats(allow_nan=True, allow_infinity=True, width=32),  # r + g
                st.one_of(st.none(), st.integers(0, 2)),  # power state
            ),
        ),
        min_size=1,
        max_size=40,
    )
)
def test_fast_step_is_the_reference_on_any_sequence(steps):
    """Any values, NaN, infinities, zero and negative steps (the restart on a sample every model rejects) included;
    where an extreme value overflows the math module, both raise alike."""
    rows, t = [], 0.0
    for s in steps:
        if s is None:
            rows.append(None)
            continue
        dt, z, w, power = s
        t += dt
        rows.append((t, z, w, power))
    _agree(rows)
