"""The speed-step filter: a speed sample beyond ``max_acceleration`` from its neighbour is a speed jump, unless a
new level holds (wheel slip or slide lasts seconds; a real step does not end). Stamps in ns, speeds in m/s."""

from __future__ import annotations

import math
from collections import deque

from .config import Settings
from .pairing import Pairer
from .records import NS, SPEED_JUMP, SpeedSample

NO_SAMPLES: tuple[SpeedSample, ...] = ()


class SpeedStepFilter:
    """The consecutive, mutually consistent samples beyond ``max_acceleration`` from the last accepted one.

    A new level is accepted only when ``reacquire_after`` such samples have held it for ``speed_step_time`` s and
    the fixes of that span do not contradict it; the earlier samples of the level are then accepted too
    (retroactively: the caller takes back their ``speed_jump`` counts).
    """

    def __init__(self, settings: Settings, pairer: Pairer) -> None:
        self.settings = settings
        self.pairer = pairer
        self.step: deque[SpeedSample] = deque(maxlen=256)
        self.first_ns: int | None = None  # stamp of the step's first sample

    def _restart(self) -> None:
        self.step.clear()
        self.first_ns = None

    def check(self, sample: SpeedSample, late: bool) -> tuple[str | None, tuple[SpeedSample, ...]]:
        """(``speed_jump`` or None, the earlier samples of a new level accepted with this one)."""
        cfg = self.settings.config
        t = sample.stamp_ns
        ref = self.pairer.neighbour_speed(t) if late else self.pairer.last_speed
        if ref is None:
            return None, NO_SAMPLES
        dt = abs(t - ref.stamp_ns) / NS
        plausible = abs(sample.v - ref.v) <= cfg.max_acceleration * dt
        if plausible and self.step and not late:
            # back after rejected samples: the bound has grown with the time since the last accepted sample,
            # so the fixes of that span must agree too (a spike that merely fits the wider bound does not)
            plausible = self._fixes_agree(ref, sample)
        if dt > cfg.run_gap or plausible:
            if not late and (self.step or self.first_ns is not None):
                self._restart()
            return None, NO_SAMPLES
        if late:
            return SPEED_JUMP, NO_SAMPLES
        step = self.step
        if step and abs(sample.v - step[-1].v) > cfg.max_acceleration * (t - step[-1].stamp_ns) / NS:
            step.clear()
        if not step:
            self.first_ns = t
        step.append(sample)
        held = (t - (self.first_ns or t)) / NS
        if len(step) < cfg.reacquire_after or held < cfg.speed_step_time - 1e-9 or self._fixes_contradict(ref):
            return SPEED_JUMP, NO_SAMPLES
        # a real new level: accept it, and the samples that held it before
        earlier = tuple(step)[:-1]
        self._restart()
        return None, earlier

    def _fixes_agree(self, ref: SpeedSample, sample: SpeedSample) -> bool:
        """The mean speed of the accepted fixes between two speed samples agrees with the samples' mean (within
        3 standard deviations of the fix noise and 0.5 m/s); True when the fixes do not cover the span."""
        fixes = [f for f in self.pairer.fixes if ref.stamp_ns - NS // 2 <= f.stamp_ns <= sample.stamp_ns + NS // 2]
        if len(fixes) < 2:
            return True
        span = (fixes[-1].stamp_ns - fixes[0].stamp_ns) / NS
        if span < 2.0:
            return True
        v_gnss = abs(fixes[-1].s - fixes[0].s) / span
        noise = 3.0 * math.sqrt(fixes[0].variance + fixes[-1].variance) / span
        return abs(0.5 * (ref.v + sample.v) - v_gnss) <= noise + 0.5

    def _fixes_contradict(self, ref: SpeedSample) -> bool:
        """The accepted fixes over the speed step's span moved at a speed nearer the old level than the new."""
        step = self.step
        t0 = step[0].stamp_ns - NS
        fixes = [f for f in self.pairer.fixes if f.stamp_ns >= t0]
        if len(fixes) < 2 or fixes[-1].stamp_ns - fixes[0].stamp_ns < 3 * NS:
            return False
        v_gnss = abs(fixes[-1].s - fixes[0].s) / ((fixes[-1].stamp_ns - fixes[0].stamp_ns) / NS)
        v_new = sum(sp.v for sp in step) / len(step)
        return abs(v_gnss - ref.v) < abs(v_gnss - v_new)
