"""The pairer: the accepted samples of the three streams in stamp order, the speed samples held for pairing, and
what a speed stamp pairs with (the nearest fix and power sample within their tolerances, the speed between
samples). Stamps in ns, speeds in m/s, positions in m."""

from __future__ import annotations

from collections import deque
from collections.abc import Iterable, Iterator, Sequence
from typing import TypeVar

from .config import Settings
from .records import NS, SPEED, MatchedFix, PowerSample, SpeedSample, Stamped, insort_by_stamp
from .timebase import TimeBase

S = TypeVar("S", bound=Stamped)


def nearest(samples: Iterable[S], t_ns: int, tolerance_ns: float) -> S | None:
    """The sample nearest to t within the tolerance (ns); of equally near ones, the later in the order."""
    best, best_dt = None, tolerance_ns
    for sample in samples:
        dt = abs(sample.stamp_ns - t_ns)
        if dt <= best_dt:
            best, best_dt = sample, dt
    return best


def nearest_in_order(samples: Sequence[S], t_ns: int, tolerance_ns: float) -> S | None:
    """:func:`nearest` of samples in stamp order (the pairer's queues), from the newest back: it stops at the first
    sample before t farther than the best (every older one is farther still). Per released sample."""
    best, best_dt = None, tolerance_ns
    for sample in reversed(samples):
        stamp = sample.stamp_ns
        dt = stamp - t_ns if stamp >= t_ns else t_ns - stamp  # = abs(stamp - t_ns)
        if dt < best_dt or (best is None and dt == best_dt):  # of equally near ones, the later (met first)
            best, best_dt = sample, dt
        elif stamp < t_ns and dt > best_dt:
            break
    return best


class Pairer:
    """The samples one time base holds for pairing; forgets what no pending or future speed sample can use."""

    def __init__(self, settings: Settings) -> None:
        self.settings = settings
        self.fixes: deque[MatchedFix] = deque()  # accepted fixes not older than the oldest pending speed needs
        self.powers: deque[PowerSample] = deque()
        self.pending: deque[SpeedSample] = deque()  # speed samples held for pairing
        self.speeds: deque[SpeedSample] = deque()  # recent validated speed samples (speed at a fix's time)
        self.last_speed: SpeedSample | None = None  # last validated speed sample in order (speed-jump check)

    # -- adding ----------------------------------------------------------------------------------------
    def add_speed(self, sample: SpeedSample, late: bool) -> None:
        """A validated speed sample: held for pairing (a late one put in order)."""
        if late:
            self.insert_speed(sample)
            return
        self.last_speed = sample
        self.speeds.append(sample)
        self.pending.append(sample)

    def insert_speed(self, sample: SpeedSample) -> None:
        """A validated speed sample older than the newest, put in order."""
        insort_by_stamp(self.speeds, sample)
        insort_by_stamp(self.pending, sample)

    def add_power(self, sample: PowerSample, late: bool) -> None:
        if late:
            insort_by_stamp(self.powers, sample)
        else:
            self.powers.append(sample)

    def add_fix(self, fix: MatchedFix) -> bool:
        """An accepted fix, in stamp order; True when it is the newest."""
        if self.fixes and fix.stamp_ns < self.fixes[-1].stamp_ns:
            insort_by_stamp(self.fixes, fix)
            return False
        self.fixes.append(fix)
        return True

    # -- recent stamps (duplicate checks) --------------------------------------------------------------
    def fix_stamps(self) -> Iterator[int]:
        return (f.stamp_ns for f in self.fixes)

    def speed_stamps(self) -> Iterator[int]:
        return (sp.stamp_ns for queue in (self.speeds, self.pending) for sp in queue)

    def power_stamps(self) -> Iterator[int]:
        return (p.stamp_ns for p in self.powers)

    # -- what a stamp pairs with -----------------------------------------------------------------------
    def nearest_fix(self, t_ns: int) -> MatchedFix | None:
        """The accepted fix nearest to t within ``pair_tolerance``."""
        return nearest_in_order(self.fixes, t_ns, self.settings.pair_ns)

    def nearest_power(self, t_ns: int) -> PowerSample | None:
        """The power sample nearest to t within ``power_pair_tolerance``."""
        return nearest_in_order(self.powers, t_ns, self.settings.power_pair_ns)

    def neighbour_speed(self, t_ns: int) -> SpeedSample | None:
        """The validated speed sample nearest to t (for a late sample)."""
        best, best_dt = None, None
        for sp in (*self.speeds, *self.pending):
            dt = abs(sp.stamp_ns - t_ns)
            if best_dt is None or dt < best_dt:
                best, best_dt = sp, dt
        return best

    def speed_at(self, t_ns: int, default: float) -> float:
        """Speed at t interpolated between the validated speed samples around it (nearest beyond them); they are
        in stamp order, t is mostly among the newest: searched from the newest back."""
        before = after = None
        for sp in reversed(self.speeds):
            if sp.stamp_ns <= t_ns:
                before = sp
                break
            after = sp
        if before is None:
            return after.v if after is not None else default
        if after is None or before.stamp_ns == t_ns:
            return before.v
        w = (t_ns - before.stamp_ns) / (after.stamp_ns - before.stamp_ns)
        return before.v + w * (after.v - before.v)

    def speed_near(self, t_ns: int, default: float) -> float:
        """The speed to dead-reckon towards t: the last validated speed sample; when it is older than
        ``max_sample_age`` (the speed stream is silent), the speed of the last accepted fixes; else ``default``
        (the anchor's)."""
        last = self.last_speed
        if last is not None and abs(t_ns - last.stamp_ns) <= self.settings.age_ns:
            return last.v
        v_fix = self.fix_speed()
        if v_fix is not None:
            return v_fix
        return last.v if last is not None else default

    def fix_speed(self) -> float | None:
        """Speed from the last two accepted fixes at least 1 s apart (m/s), None without them."""
        fixes = self.fixes
        if len(fixes) < 2:
            return None
        newest = fixes[-1]
        for older in reversed(fixes):
            dt = (newest.stamp_ns - older.stamp_ns) / NS
            if dt >= 1.0:
                return abs(newest.s - older.s) / dt
        return None

    def trim(self, clock: TimeBase) -> None:
        """Forget fixes and power samples no pending or future speed sample can pair with."""
        pending, settings = self.pending, self.settings
        horizon = pending[0].stamp_ns if pending else clock.latest.get(SPEED)
        newest = clock.newest_ns
        if newest is not None:  # a speed stream silent for long must not let them pile up
            oldest_useful = newest - settings.age_ns_int
            horizon = oldest_useful if horizon is None or oldest_useful > horizon else horizon
        if horizon is None:
            return
        keep_from = horizon - settings.keep_ns
        fixes, powers, speeds = self.fixes, self.powers, self.speeds
        while len(fixes) > 1 and fixes[1].stamp_ns <= keep_from:
            fixes.popleft()
        if powers:
            while len(powers) > 1 and powers[1].stamp_ns <= keep_from:
                powers.popleft()
        while len(speeds) > 2 and speeds[1].stamp_ns <= keep_from:
            speeds.popleft()
