"""The driving regime codes of train_calib_msgs/msg/DrivingRegime, for every part of the core (no ROS import)."""

from __future__ import annotations

UNKNOWN, TRACTION, CRUISING, COASTING, BRAKING = 0, 1, 2, 3, 4
"""DrivingRegime.UNKNOWN (standing, or not classified) ... DrivingRegime.BRAKING."""

REGIME_NAMES = ("unknown", "traction", "cruising", "coasting", "braking")
"""Lower-case name of each code (index = code)."""


def regime_name(code: int) -> str:
    """The name of a regime code; the number as text for a code outside 0..4."""
    return REGIME_NAMES[code] if 0 <= code < len(REGIME_NAMES) else str(code)


__all__ = ["BRAKING", "COASTING", "CRUISING", "REGIME_NAMES", "TRACTION", "UNKNOWN", "regime_name"]
