"""The anchor: the last known position (from a fix or a published measurement), the one owner of (t, s, v) that
dead reckoning and the continuity window start from. Stamps in ns, positions in m, speeds in m/s."""

from __future__ import annotations

from .records import NS, MatchedFix


class Anchor:
    """Last known (t, s, v), and the last position from a fix with its variance (dead-reckoning error grows from
    there). ``t`` is None until the position is acquired."""

    __slots__ = ("base_t", "base_var", "s", "t", "v")

    def __init__(self) -> None:
        self.t: int | None = None
        self.s = 0.0
        self.v = 0.0
        self.base_t = 0
        self.base_var = 0.0  # m^2

    def at_fix(self, fix: MatchedFix, v: float) -> None:
        """An accepted fix newer than the anchor, with the speed there."""
        self.t, self.s, self.v = fix.stamp_ns, fix.s, v
        self.base_t, self.base_var = fix.stamp_ns, fix.variance

    def at_measurement(self, t_ns: int, s: float, v: float, fix: MatchedFix | None) -> None:
        """A published measurement; ``fix``: the fix it was paired with (the dead-reckoning error restarts)."""
        self.t, self.s, self.v = t_ns, s, v
        if fix is not None:
            self.base_t, self.base_var = fix.stamp_ns, fix.variance

    def reckon_backward(self, t_ns: int, v: float, length_m: float) -> None:
        """Against the track direction: the speed moves the anchor back along s (within the line)."""
        if self.t is not None and t_ns > self.t:
            self.s -= 0.5 * (self.v + v) * (t_ns - self.t) / NS
            self.s = min(max(self.s, 0.0), length_m)
            self.t, self.v = t_ns, v

    def dead_reckon(self, t_ns: int, v: float, speed_std: float, max_s: float) -> tuple[float, float] | None:
        """(s, variance) at t from the anchor with the mean speed, for at most ``max_s`` s; None beyond or before
        the position is acquired."""
        if self.t is None or (t_ns - self.t) / NS > max_s:
            return None
        dt_a = (t_ns - self.t) / NS
        s = self.s + 0.5 * (self.v + v) * dt_a
        # speed errors are largely systematic (calibration, quantisation of a slowly varying speed): the
        # dead-reckoning error grows linearly with the time since the last fix, not as a random walk
        return s, self.base_var + (speed_std * (t_ns - self.base_t) / NS) ** 2
