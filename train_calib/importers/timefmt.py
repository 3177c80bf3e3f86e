"""Time stamps of logs: numbers (s or ms) or ISO 8601 with a zone, to Unix ns."""

from __future__ import annotations

from datetime import datetime, timezone
from decimal import Decimal, InvalidOperation

TIME_UNITS = {"s": 1_000_000_000, "ms": 1_000_000}
MAX_NS = 2**31 * 1_000_000_000  # a ROS stamp holds int32 seconds: up to 2038-01-19
RELATIVE_LIMIT_S = 1.0e8  # numeric times below this (about 3 years) are seconds since the log's start


class TimeError(ValueError):
    """A time cell that cannot be read (the reason is the message)."""


def parse_iso_ns(text: str) -> int:
    """ISO 8601 with a zone (``Z`` or ``+01:00``) to Unix ns; a time without a zone is refused."""
    try:
        stamp = datetime.fromisoformat(text.strip().replace("Z", "+00:00").replace("z", "+00:00"))
    except ValueError:
        raise TimeError(f"time {text!r} is neither a number nor ISO 8601") from None
    if stamp.tzinfo is None:
        raise TimeError(f"ISO 8601 time {text!r} has no zone (add Z or +hh:mm)")
    stamp = stamp.astimezone(timezone.utc)
    if not 0 <= stamp.timestamp() < MAX_NS / 1e9:
        raise TimeError(f"time {text!r} is out of range (1970 to 2038)")
    whole = int(stamp.replace(microsecond=0).timestamp())
    return whole * 1_000_000_000 + stamp.microsecond * 1000


def parse_time_ns(text: str, unit: str, start_ns: int) -> int:
    """A time cell to Unix ns: a number in ``unit`` (s or ms; below 1e8 s it counts from ``start_ns``) or ISO 8601."""
    cell = text.strip()
    try:
        value = Decimal(cell)  # exact: a float loses the microseconds of an epoch time
    except InvalidOperation:
        return parse_iso_ns(cell)
    if not value.is_finite():
        raise TimeError(f"time {cell!r} is not finite")
    ns = int((value * TIME_UNITS[unit]).to_integral_value())
    ns = ns + start_ns if abs(ns) < RELATIVE_LIMIT_S * 1e9 else ns
    if not 0 <= ns < MAX_NS:
        raise TimeError(f"time {cell!r} is out of range (1970 to 2038)")
    return ns
