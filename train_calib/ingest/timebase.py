"""The ingest's time base: per-stream stamps, staleness, duplicates and ordering, when a held speed sample may be
paired, and the watch for a clock reset (samples behind the time base from every active stream). Stamps in ns."""

from __future__ import annotations

from collections.abc import Callable, Iterable
from typing import Any

from .config import Settings
from .records import DUPLICATE, GNSS, OUT_OF_ORDER, POWER, STALE


class TimeBase:
    """The stamps seen on one time base: the newest per stream and of any input, each stream's last sampling
    period, and the release time (the stamp of the last speed sample released, published or not)."""

    def __init__(self, settings: Settings) -> None:
        self.settings = settings
        self.latest: dict[str, int] = {}  # newest accepted-or-validated stamp per stream
        self.period: dict[str, int] = {}  # last interval between two stamps of a stream, ns
        self.newest_ns: int | None = None  # newest stamp of any input
        self.silence_ns = 0  # time since the newest input, at the sample being checked (every input silent)
        self.released_ns: int | None = None  # stamp of the last speed sample released (published or not)

    def check(self, stream: str, t_ns: int, recent: Callable[[], Iterable[int]]) -> tuple[str | None, bool]:
        """Staleness, duplicates and ordering: (drop reason or None, late). A sample that passes in order
        advances its stream's latest stamp; a late one (older than its stream's latest, newer than the last
        released speed sample) passes with late True and is inserted in order. ``recent()``: the stream's
        recent stamps (read only for a sample behind its stream's latest)."""
        newest = self.newest_ns
        if newest is not None and (newest - t_ns) > self.settings.age_ns:
            return STALE, False
        last = self.latest.get(stream)
        if last is not None and t_ns <= last:
            if t_ns == last or t_ns in recent():
                return DUPLICATE, False
            if self.released_ns is not None and t_ns <= self.released_ns:
                return OUT_OF_ORDER, False
            return None, True
        if last is not None:
            self.period[stream] = t_ns - last  # the stream's sampling period, as last observed
        self.latest[stream] = t_ns
        self.silence_ns = t_ns - newest if newest is not None else 0
        if newest is None or t_ns > newest:
            self.newest_ns = t_ns
        return None, False

    def release(self, t_ns: int) -> None:
        """A speed sample at t is released: later samples older than it are out of order."""
        if self.released_ns is None or t_ns > self.released_ns:
            self.released_ns = t_ns

    def unreleased(self, t_ns: int) -> bool:
        """No speed sample at or after t has been released yet."""
        return self.released_ns is None or t_ns > self.released_ns

    def ready(self, t_ns: int) -> bool:
        """A speed sample at t can be paired now with the nearest sample of every other stream.

        A stream is ready when it has reached the stamp, or when its next sample (expected one observed
        period after its latest) cannot be nearer than the latest; GNSS is waited for from the start,
        power once it has been seen. A sample that has waited until an input ``max_pairing_wait`` newer
        arrived is released anyway.
        """
        assert self.newest_ns is not None
        if self.newest_ns - t_ns >= self.settings.pairing_wait_ns:
            return True
        latest = self.latest
        gnss = latest.get(GNSS)
        if gnss is None:  # GNSS is waited for from the start: _stream_ready(GNSS, t_ns, required=True)
            return False
        if gnss < t_ns:
            period = self.period.get(GNSS)
            if period is None or gnss + period - t_ns < t_ns - gnss:
                return False
        return POWER not in latest or self._stream_ready(POWER, t_ns, required=False)

    def _stream_ready(self, stream: str, t: int, required: bool) -> bool:
        latest = self.latest.get(stream)
        if latest is None:
            return not required
        if latest >= t:
            return True
        period = self.period.get(stream)
        return period is not None and latest + period - t >= t - latest


class ClockResetWatch:
    """The samples in a row behind the current time base (stale or out of order): a clock reset?

    ``clock_reset_after`` such samples, increasing per stream, from every stream active in the current time base
    (or spanning ``max_sample_age`` of their own time) are a clock reset (a bag loop, a restarted clock). A single
    stream behind the others (its clock is off) never is. It outlives the time bases it watches.
    """

    def __init__(self) -> None:
        self.behind: list[tuple[str, Any, str]] = []  # (stream, sample, drop reason)

    def clear(self) -> None:
        """A sample of the current time base arrived: no clock reset."""
        self.behind.clear()

    def take(self) -> list[tuple[str, Any, str]]:
        """The samples behind the old time base, to replay on the new one; the watch starts empty."""
        samples, self.behind = self.behind, []
        return samples

    def observe(self, stream: str, event: Any, reason: str, clock: TimeBase) -> bool:
        """Note a sample behind the time base; True when the samples noted make a clock reset."""
        behind = self.behind
        age_ns = clock.settings.age_ns
        t = event.stamp_ns
        if behind:
            same = [e.stamp_ns for s, e, _ in behind if s == stream]
            first = behind[0][1].stamp_ns
            if (same and t <= same[-1]) or t < first:
                behind.clear()
        behind.append((stream, event, reason))
        first = behind[0][1].stamp_ns
        newest = clock.newest_ns if clock.newest_ns is not None else t
        active = {s for s, latest in clock.latest.items() if newest - latest <= age_ns}
        streams = {s for s, _, _ in behind}
        return len(behind) >= clock.settings.config.clock_reset_after and (active <= streams or t - first >= age_ns)
