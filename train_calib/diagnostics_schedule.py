"""When a node publishes its /diagnostics status in the data's time (ROS-free core of nodes/diagnostics.py).

On board the nodes publish on a timer of the node clock (wall time). Under ``use_sim_time`` (a replay, or
``ros2 bag play --clock``) a timer of the simulated clock fires once per jump of ``/clock``, however many periods
the jump spans, so the count followed the replay's speed: 28 statuses for the demo bag at ``--rate 0`` (``/clock``
moves at most 20 times per wall second, the graph runs 0.7 s) against 4,528 at ``--rate 20`` (1,300 s of data,
one a second for each of the four nodes). Under simulated time the nodes instead ask this schedule with the
stamp of every input they handle: a status is due at most once per ``period`` of the data's time, on the grid
of whole periods, so the count depends on the data only, never on the replay rate or the machine.
"""

from __future__ import annotations


class DiagnosticsSchedule:
    """At most one status per ``period_s`` (s) of the data's time (ns stamps), aligned to multiples of the period.

    ``due(t_ns)`` is True when ``t_ns`` reaches the next multiple of the period after the last status (or after the
    first stamp seen, which starts the grid and is not itself due). Stamps that go back by more than a period (a
    new bag, a clock reset, a corrupted stamp before it) restart the grid at that stamp, so one absurd stamp cannot
    silence the node for the rest of the data.
    """

    __slots__ = ("last_ns", "next_ns", "period_ns")

    def __init__(self, period_s: float) -> None:
        if not period_s > 0.0:
            raise ValueError(f"period must be > 0 s, got {period_s!r}")
        self.period_ns = max(1, round(period_s * 1e9))
        self.next_ns: int | None = None
        self.last_ns = 0

    def set_period(self, period_s: float) -> None:
        """A new period (s), from the next stamp on (the grid restarts there)."""
        self.__init__(period_s)  # type: ignore[misc]

    def due(self, t_ns: int) -> bool:
        """True when a status is due at data time ``t_ns`` (ns); the caller then publishes one."""
        period, nxt = self.period_ns, self.next_ns
        if nxt is None or t_ns < self.last_ns - period:
            self.next_ns, self.last_ns = (t_ns // period + 1) * period, t_ns
            return False
        self.last_ns = t_ns
        if t_ns < nxt:
            return False
        self.next_ns = (t_ns // period + 1) * period
        return True


__all__ = ["DiagnosticsSchedule"]
