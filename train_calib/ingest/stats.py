"""The ingest's counters per stream (``IngestStats``: /diagnostics and summary.json)."""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field
from typing import Any

from .records import STREAMS


@dataclass
class IngestStats:
    """Counts per stream: received, accepted, dropped by reason; re-acquisitions of the position."""

    received: Counter = field(default_factory=Counter)
    accepted: Counter = field(default_factory=Counter)
    dropped: dict[str, Counter] = field(default_factory=lambda: {s: Counter() for s in STREAMS})
    repaired: dict[str, Counter] = field(default_factory=lambda: {s: Counter() for s in STREAMS})
    reacquisitions: int = 0
    dead_reckoned: int = 0
    published: int = 0
    clock_resets: int = 0
    reversals: int = 0
    consecutive_dropped: Counter = field(default_factory=Counter)  # per stream, since its last accepted sample
    last_drop: dict[str, str] = field(default_factory=dict)  # per stream, the reason of its latest drop

    def drop(self, stream: str, reason: str) -> None:
        """Count a dropped sample of a stream."""
        self.dropped[stream][reason] += 1
        self.consecutive_dropped[stream] += 1
        self.last_drop[stream] = reason

    def undrop(self, stream: str, reason: str) -> None:
        """Take back the count of a drop (a sample accepted after all, or replayed after a clock reset)."""
        counter = self.dropped[stream]
        counter[reason] -= 1
        if counter[reason] <= 0:
            del counter[reason]
        self.consecutive_dropped[stream] = max(self.consecutive_dropped[stream] - 1, 0)

    def dropped_total(self) -> int:
        return sum(sum(c.values()) for c in self.dropped.values())

    def as_dict(self) -> dict[str, Any]:
        return {
            "received": dict(self.received),
            "accepted": dict(self.accepted),
            "dropped": {s: dict(c) for s, c in self.dropped.items() if c},
            "repaired": {s: dict(c) for s, c in self.repaired.items() if c},
            "reacquisitions": self.reacquisitions,
            "dead_reckoned": self.dead_reckoned,
            "published": self.published,
            "clock_resets": self.clock_resets,
            "reversals": self.reversals,
        }
