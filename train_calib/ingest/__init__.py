"""Ingest: GNSS fixes, speed and traction power samples -> paired, map-matched Measurements (no ROS).

This is the core of ``gnss_speed_node``; the offline pipeline runs the same object on a bag. The package's
modules, one job each: ``front`` (``Ingest``: routes and counts), ``timebase`` (stamps, ordering, clock
resets), ``matching`` (map matching, re-acquisition), ``odometer_checks`` (running direction, GNSS delay),
``speed_step`` (speed steps), ``pairing`` (held samples and what a stamp pairs with), ``position`` (the anchor),
``release`` (a released sample as a Measurement), ``runs`` (run segmentation), ``records``, ``config``, ``stats``.

What it does, per input stream (all times are the samples' stamps, never a clock, so a replay gives the
same result however the messages are scheduled):

* **Validation.** Each sample is checked when it arrives; a bad one is dropped and counted by reason
  (``DROP_REASONS``): non-finite values, GNSS without fix, negative or implausible speed, a speed jump
  (|dv/dt| above ``max_acceleration``; a new level only after ``speed_step_time`` of consistent samples the
  fixes do not contradict), negative power, a repeated stamp (``duplicate``), a stamp older than the last
  released speed sample (``out_of_order``; a late sample newer than that is put in order), a stamp older than
  the newest input of any stream by more than ``max_sample_age`` (``stale``). A known but unusable fix
  covariance is replaced by ``position_std`` and counted (``REPAIR_REASONS``).
* **Clock resets.** ``clock_reset_after`` samples in a row behind the time base, from every active stream,
  are a new time base (a bag loop, a restarted clock): a new run, and those samples are processed on it.
* **Odometer checks** (:mod:`train_calib.odometry`). The accepted fixes against the integrated speed give the
  running direction (moving against the track direction: speed samples dropped as ``reversing`` until the
  fixes move forward again, then a new run) and the delay of the GNSS stamps (``gnss_delay_estimate``; a
  known delay is set with ``gnss_delay``).
* **Map matching with continuity.** A fix is projected onto the track polyline only within a window
  around the position predicted from the last position and the speed (a train does not jump); the
  window grows with the time since the last accepted fix (``continuity_gate`` +
  ``continuity_gate_growth`` * dt), so the position is re-acquired after a GNSS gap. A fix near the track
  but outside the window is a ``jump``; ``reacquire_after`` consecutive, mutually consistent jumps
  re-acquire there (a wrong first lock does not persist). A fix farther than ``max_cross_track`` from
  the whole polyline is ``off_track``. The first fix is matched on the whole line, or near
  ``start_station`` when it is set (the train starts at a station).
* **Pairing.** Position and speed come at different rates (0.1-10 Hz) and unsynchronised. One
  Measurement is made per accepted speed sample at its stamp: with the nearest accepted fix within
  ``pair_tolerance`` (moved to the speed stamp with the speed; ``s_measured`` true), else dead-reckoned
  from the last position with the mean speed (``s_measured`` false, variance growing); traction power
  pairs within ``power_pair_tolerance``. A speed sample is held until every other stream has reached
  its stamp or its next sample (expected one observed period after its latest) cannot be nearer than
  the latest — so synchronised streams pair exactly even when the fix arrives a little later, and
  unsynchronised ones pair at once with the nearest fix — at most until an input ``max_pairing_wait``
  newer has arrived (power is waited for only once it has been seen). ``flush()`` releases what is
  held (end of a bag, shutdown).
* **Track terms.** g(s) averaged over the train length, the fraction of the train in a tunnel and
  the static speed limit at s, from :class:`~train_calib.track.Track`.
* **Run segmentation.** ``run_id`` starts at 0 and is incremented at a departure after a standstill of
  at least ``min_standstill`` (once the run has moved), or after a gap in the speed stream longer than
  ``run_gap``; ``dt`` is 0 for the first sample of a run.
"""

from .config import IngestConfig
from .front import Ingest
from .records import (
    BAD_COVARIANCE,
    DROP_REASONS,
    DUPLICATE,
    GNSS,
    IMPLAUSIBLE_SPEED,
    JUMP,
    NAN,
    NEGATIVE_POWER,
    NEGATIVE_SPEED,
    NO_FIX,
    NO_POSITION,
    NS,
    OFF_TRACK,
    OUT_OF_ORDER,
    POWER,
    REPAIR_REASONS,
    REVERSING,
    SPEED,
    SPEED_JUMP,
    STALE,
    STREAMS,
    GnssFix,
    PowerSample,
    SpeedSample,
    fix_from_msg,
    header_stamp_ns,
    power_from_msg,
    speed_from_msg,
)
from .stats import IngestStats

__all__ = [
    "BAD_COVARIANCE",
    "DROP_REASONS",
    "DUPLICATE",
    "GNSS",
    "IMPLAUSIBLE_SPEED",
    "JUMP",
    "NAN",
    "NEGATIVE_POWER",
    "NEGATIVE_SPEED",
    "NO_FIX",
    "NO_POSITION",
    "NS",
    "OFF_TRACK",
    "OUT_OF_ORDER",
    "POWER",
    "REPAIR_REASONS",
    "REVERSING",
    "SPEED",
    "SPEED_JUMP",
    "STALE",
    "STREAMS",
    "GnssFix",
    "Ingest",
    "IngestConfig",
    "IngestStats",
    "PowerSample",
    "SpeedSample",
    "fix_from_msg",
    "header_stamp_ns",
    "power_from_msg",
    "speed_from_msg",
]
