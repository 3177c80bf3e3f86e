"""The odometer checks of one time base: the accepted fixes against the integrated speed give the running direction
(reversing) and the delay of the GNSS stamps (:mod:`train_calib.odometry`). Stamps in ns, positions in m."""

from __future__ import annotations

from collections import deque
from typing import NamedTuple

from ..odometry import BACKWARD, FORWARD, DelayEstimator, DirectionMonitor, Odometer
from .config import IngestConfig
from .records import MatchedFix


class DirectionChanges(NamedTuple):
    """What an update of the checks found: how many reversals began, and whether the fixes came back forward."""

    reversals: int
    forward_again: bool


NO_CHANGE = DirectionChanges(0, False)


class OdometerChecks:
    """Running direction and GNSS stamp delay from the accepted fixes the speed odometer has reached."""

    def __init__(self, config: IngestConfig, estimate_delay: bool = True) -> None:
        self.odometer = Odometer(max(config.max_dead_reckoning, config.max_sample_age) + 60.0, config.max_sample_age)
        self.direction = DirectionMonitor(config.reverse_distance)
        self.delay = DelayEstimator(config.delay_window, config.position_std)
        self.estimate_delay = estimate_delay  # False: no fix is fitted for the delay (its estimate stays None)
        self.queue: deque[MatchedFix] = deque(maxlen=64)  # accepted fixes the odometer has not reached yet

    @property
    def reversing(self) -> bool:
        """The fixes move against the track direction."""
        return self.direction.direction == BACKWARD

    def configure(self, old: IngestConfig, new: IngestConfig) -> None:
        """A parameter change on the fly."""
        if new.reverse_distance != old.reverse_distance:
            self.direction.distance_m = new.reverse_distance
        if new.delay_window != old.delay_window:
            self.delay.time_constant_s = new.delay_window

    def add_speed(self, t_ns: int, v: float) -> None:
        """A speed sample in order (m/s); a gap the odometer does not bridge restarts the checks."""
        odometer = self.odometer
        restarts = odometer.restarts
        odometer.add(t_ns, v)
        if odometer.restarts != restarts:  # a gap the odometer does not bridge: its distances restart
            self.restarted()

    def restarted(self) -> None:
        """The odometer restarted (a gap it does not bridge): the direction and delay checks start over."""
        self.direction.reset()
        self.delay.reset()
        # the queue is kept: a fix older than the restart finds no odometer distance and is skipped in update(),
        # and a fix of the restart's own stamp that arrived before this sample is used as if it came after
        # (clearing it made the reversing count depend on the arrival order at one stamp: 29 or 30 samples,
        # bench/mutation/restart_order.py)

    def reacquired(self) -> None:
        """The position was re-acquired elsewhere: the fixes before do not compare with those after."""
        self.delay.reset()
        self.queue.clear()
        self.direction.reset()

    def update(self) -> DirectionChanges:
        """Feed the fixes the odometer has reached to the direction monitor and the delay estimator."""
        queue = self.queue
        latest = self.odometer.latest_ns
        if not queue or latest is None or queue[0].stamp_ns > latest:
            return NO_CHANGE
        odometer, direction, delay, estimate_delay = self.odometer, self.direction, self.delay, self.estimate_delay
        reversals, forward_again = 0, False
        while queue and queue[0].stamp_ns <= latest:
            fix = queue.popleft()
            at = odometer.at(fix.stamp_ns)
            if at is None:
                continue
            d, v = at
            before = direction.direction
            after = direction.add(fix.stamp_ns, fix.s, d)
            if after != before:
                delay.reset()
                if after == BACKWARD:
                    reversals += 1
                else:
                    forward_again = True
            elif after == FORWARD and estimate_delay:
                delay.add(fix.stamp_ns, fix.s, d, v)
        return DirectionChanges(reversals, forward_again) if reversals or forward_again else NO_CHANGE
