"""Ingest: GNSS fixes, speed and traction power samples -> paired, map-matched Measurements (no ROS).

This is the core of ``gnss_speed_node``; the offline pipeline runs the same object on a bag.

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

from __future__ import annotations

import math
from collections import Counter, deque
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field, replace
from typing import Any

from .errors import ConfigError
from .geodesy import ScalarEnu
from .measurement import Measurement
from .odometry import BACKWARD, FORWARD, DelayEstimator, DirectionMonitor, Odometer
from .params import ParamSet, param
from .physics import KMH
from .track import ScalarTrackTerms, Track, WindowProjector
from .train import TrainSpec

NS = 1_000_000_000

GNSS = "gnss"
SPEED = "speed"
POWER = "power"
STREAMS = (GNSS, SPEED, POWER)

# Drop reasons (stable names: they appear in /diagnostics and summary.json).
NAN = "nan"
NO_FIX = "no_fix"
OFF_TRACK = "off_track"
JUMP = "jump"
OUT_OF_ORDER = "out_of_order"
STALE = "stale"
NEGATIVE_SPEED = "negative_speed"
IMPLAUSIBLE_SPEED = "implausible_speed"
SPEED_JUMP = "speed_jump"
NO_POSITION = "no_position"
NEGATIVE_POWER = "negative_power"
DUPLICATE = "duplicate"
REVERSING = "reversing"

DROP_REASONS: dict[str, str] = {
    NAN: "a value is NaN or infinite",
    NO_FIX: "NavSatFix status < 0 (no fix)",
    OFF_TRACK: "fix farther than max_cross_track from the track polyline",
    JUMP: "fix near the track but not where the train can be (continuity gate)",
    OUT_OF_ORDER: "stamp older than the last speed sample already released (too late to be paired in order)",
    DUPLICATE: "stamp equal to that of a recent sample of the same stream (the first one is kept)",
    STALE: "stamp older than the newest input by more than max_sample_age",
    NEGATIVE_SPEED: "speed below 0",
    IMPLAUSIBLE_SPEED: "speed above max_speed",
    SPEED_JUMP: "|dv/dt| to the previous speed sample above max_acceleration",
    NO_POSITION: "no position yet (not acquired) or dead reckoning longer than max_dead_reckoning",
    NEGATIVE_POWER: "power_consumed or power_regenerated below 0",
    REVERSING: "the fixes move against the track direction (shunting, or the other direction's track file needed)",
}

# Repair reasons (samples used after a repair; counted like drops, in /diagnostics and summary.json).
BAD_COVARIANCE = "bad_covariance"
REPAIR_REASONS: dict[str, str] = {
    BAD_COVARIANCE: "NavSatFix covariance known but NaN, infinite or not positive: position_std used",
}


@dataclass(frozen=True)
class IngestConfig(ParamSet):
    """Parameters of the ingest (gnss_speed_node). SI units; defaults from the papers where they say."""

    position_std: float = param(
        4.0, "GNSS position std when the fix carries no covariance (paper: 4 m)", unit="m", low=0.0, low_open=True
    )
    use_fix_covariance: bool = param(True, "take the horizontal variance from NavSatFix.position_covariance if known")
    speed_std: float = param(
        1.0 * KMH, "speed measurement std, gives v_variance (paper: 1 km/h)", unit="m/s", low=0.0, low_open=True
    )
    max_cross_track: float = param(
        30.0, "a fix farther than this from the track polyline is off_track", unit="m", low=0.0, low_open=True
    )
    continuity_gate: float = param(
        60.0, "half-width of the window around the predicted position where a fix may be matched", unit="m", low=1.0
    )
    continuity_gate_growth: float = param(
        1.0, "the window grows by this per second since the last accepted fix (gaps)", unit="m/s", low=0.0
    )
    reacquire_after: int = param(
        3, "consecutive mutually consistent jump fixes that re-acquire the position there", low=1, high=1000
    )
    reacquire_gap: float = param(
        600.0,
        "after this long without an accepted fix the position is acquired on the whole line",
        unit="s",
        low=0.0,
        low_open=True,
    )
    start_station: str = param(
        "", "name of the station where the train starts (first fix matched near it); empty: the whole line"
    )
    acquisition_gate: float = param(
        1000.0, "half-width of the window around start_station for the first fix", unit="m", low=1.0
    )
    pair_tolerance: float = param(
        5.0,
        "a fix pairs with a speed sample (s moved to the speed stamp with the speed, s_measured true) when their "
        "stamps differ by at most this; half the longest sampling period (0.1 Hz)",
        unit="s",
        low=0.0,
    )
    power_pair_tolerance: float = param(
        0.5, "a traction power sample pairs with a speed sample within this (power changes fast)", unit="s", low=0.0
    )
    max_pairing_wait: float = param(
        1.0,
        "a speed sample waits for the other streams to reach its stamp until an input this much newer arrives",
        unit="s",
        low=0.0,
    )
    max_sample_age: float = param(
        30.0, "a sample older than the newest input by more than this is stale", unit="s", low=0.0, low_open=True
    )
    max_speed: float = param(100.0, "speeds above this are implausible", unit="m/s", low=0.0, low_open=True)
    max_acceleration: float = param(
        3.0,
        "|dv/dt| between consecutive speed samples above this is a speed jump",
        unit="m/s^2",
        low=0.0,
        low_open=True,
    )
    max_dead_reckoning: float = param(
        600.0, "longest time the position is dead-reckoned from speed", unit="s", low=0.0, low_open=True
    )
    standstill_speed: float = param(
        0.2, "speeds at or below this are standstill (run segmentation)", unit="m/s", low=0.0
    )
    min_standstill: float = param(
        20.0, "a departure after a standstill at least this long starts a new run", unit="s", low=0.0
    )
    run_gap: float = param(
        300.0, "a gap in the speed stream longer than this starts a new run", unit="s", low=0.0, low_open=True
    )
    speed_step_time: float = param(
        10.0,
        "a speed level beyond max_acceleration from the last accepted sample is accepted only when reacquire_after "
        "consecutive, mutually consistent samples have held it this long and the fixes do not contradict it "
        "(wheel slip or slide lasts seconds)",
        unit="s",
        low=0.0,
    )
    clock_reset_after: int = param(
        3,
        "this many consecutive samples behind the time base (stale or out of order), increasing and from every "
        "active stream, are a clock reset (bag loop, restarted clock): a new time base and a new run",
        low=1,
        high=1000,
    )
    reverse_max_speed: float = param(
        10.0,
        "at or below this speed the continuity window also covers motion against the track direction (shunting)",
        unit="m/s",
        low=0.0,
    )
    reverse_distance: float = param(
        50.0,
        "the running direction is judged over the last stretch in which the speed covered this distance: fixes "
        "moving backwards over it are reversing (speed samples dropped until the fixes move forward again)",
        unit="m",
        low=1.0,
    )
    gnss_delay: float = param(
        0.0,
        "known delay of the GNSS stamps after the measurement time, subtracted from every fix stamp (the "
        "diagnostics estimate what remains)",
        unit="s",
        low=-10.0,
        high=10.0,
    )
    delay_window: float = param(
        600.0,
        "time constant of the forgetting of the GNSS delay estimate (fixes against the speed odometer)",
        unit="s",
        low=10.0,
        high=86400.0,
    )
    delay_warn: float = param(
        0.3,
        "diagnostics WARN when the estimated GNSS delay exceeds this by more than 3 standard deviations",
        unit="s",
        low=0.0,
        low_open=True,
    )
    drop_warn_count: int = param(
        10, "diagnostics WARN when this many consecutive samples of an input were dropped", low=1, high=1000000
    )

    def validate(self, source: str = "parameters", prefix: str = "") -> None:
        if self.standstill_speed >= self.max_speed:
            raise ConfigError(
                source,
                f"{prefix}standstill_speed",
                f"{self.standstill_speed:g} m/s must be below max_speed ({self.max_speed:g} m/s)",
            )


# -- input records (duck-typed converters from rclpy or rosbags messages below) -----------------------


@dataclass
class GnssFix:
    stamp_ns: int
    lat: float  # deg
    lon: float  # deg
    status: int = 0  # NavSatStatus.status; < 0 no fix
    horizontal_variance: float = math.nan  # m^2, NaN when unknown
    covariance_known: bool = False  # position_covariance_type not UNKNOWN (a NaN variance is then a fault)


@dataclass
class SpeedSample:
    stamp_ns: int
    v: float  # m/s along the track


@dataclass
class PowerSample:
    stamp_ns: int
    consumed: float  # W
    regenerated: float  # W


def header_stamp_ns(msg: Any) -> int:
    stamp = msg.header.stamp
    return int(stamp.sec) * NS + int(stamp.nanosec)


def fix_from_msg(msg: Any) -> GnssFix:
    """A sensor_msgs/NavSatFix (rclpy or rosbags) as a GnssFix."""
    variance = math.nan
    known = int(msg.position_covariance_type) != 0  # COVARIANCE_TYPE_UNKNOWN
    if known:
        cov = msg.position_covariance
        variance = 0.5 * (float(cov[0]) + float(cov[4]))
    status = int(msg.status.status)
    return GnssFix(header_stamp_ns(msg), float(msg.latitude), float(msg.longitude), status, variance, known)


def speed_from_msg(msg: Any) -> SpeedSample:
    """A geometry_msgs/TwistStamped (rclpy or rosbags) as a SpeedSample (twist.linear.x)."""
    return SpeedSample(header_stamp_ns(msg), float(msg.twist.linear.x))


def power_from_msg(msg: Any) -> PowerSample:
    """A train_calib_msgs/TractionPower (rclpy or rosbags) as a PowerSample."""
    return PowerSample(header_stamp_ns(msg), float(msg.power_consumed), float(msg.power_regenerated))


# -- statistics ------------------------------------------------------------------------------------


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


@dataclass
class _Fix:
    t_ns: int
    s: float
    variance: float
    cross_track: float


class Ingest:
    """Online ingest of the three input streams; every ``add_*`` returns the Measurements it releases."""

    def __init__(self, track: Track, train: TrainSpec, config: IngestConfig | None = None) -> None:
        self.track = track
        self.train = train
        self.config = config or IngestConfig()
        self._derive_ns(self.config)
        self._start_s = self._station_s(self.config)
        self._terms = ScalarTrackTerms(track, train.length_m)
        self._enu = ScalarEnu(track.frame)
        self._segments = WindowProjector(track)
        self.stats = IngestStats()
        self.run_id = 0
        self._behind: list[tuple[str, Any, str]] = []  # samples behind the time base: a clock reset?
        self._init_state()

    def _init_state(self) -> None:
        """Everything that belongs to one time base (a clock reset starts over from here)."""
        cfg = self.config
        self._latest: dict[str, int] = {}  # newest accepted-or-validated stamp per stream
        self._period: dict[str, int] = {}  # last interval between two stamps of a stream, ns
        self._newest_ns: int | None = None  # newest stamp of any input
        self._silence_ns = 0  # time since the newest input, at the sample being checked (every input silent)
        self._fixes: deque[_Fix] = deque()  # accepted fixes not older than the oldest pending speed needs
        self._powers: deque[PowerSample] = deque()
        self._pending: deque[SpeedSample] = deque()
        self._last_speed: SpeedSample | None = None  # last validated speed sample (speed-jump check)
        self._speeds: deque[SpeedSample] = deque()  # recent validated speed samples (speed at a fix's time)
        # position state: last known (t, s, v) from a fix or a published measurement
        self._anchor_t: int | None = None
        self._anchor_s = 0.0
        self._anchor_v = 0.0
        self._base_t = 0  # last position from a fix and its variance: dead-reckoning error grows from there
        self._base_var = 0.0
        self._last_fix_t: int | None = None
        self._candidates: list[_Fix] = []  # consecutive jump fixes (re-acquisition)
        # run segmentation
        self._run_moved = False
        self._standstill_since: int | None = None
        self._last_meas_t: int | None = None
        self._released_t: int | None = None  # stamp of the last speed sample released (published or not)
        self._new_run_next = False
        # speed steps: consecutive, mutually consistent samples beyond max_acceleration from the last accepted one
        self._step: deque[SpeedSample] = deque(maxlen=256)
        self._step_first_ns: int | None = None
        # odometer checks: running direction and GNSS stamp delay
        self._odometer = Odometer(max(cfg.max_dead_reckoning, cfg.max_sample_age) + 60.0, cfg.max_sample_age)
        self._direction = DirectionMonitor(cfg.reverse_distance)
        self._delay = DelayEstimator(cfg.delay_window, cfg.position_std)
        self._odometer_queue: deque[_Fix] = deque(maxlen=64)  # accepted fixes the odometer has not reached yet

    def _station_s(self, config: IngestConfig) -> float | None:
        if not config.start_station:
            return None
        try:
            return self.track.station_named(config.start_station).s_m
        except KeyError:
            names = ", ".join(s.name for s in self.track.stations) or "none"
            raise ConfigError(
                "parameters",
                "start_station",
                f"track {self.track.name} has no station {config.start_station!r} (stations: {names})",
            ) from None

    def set_config(self, config: IngestConfig) -> None:
        """Change the parameters on the fly (the state is kept); ConfigError for an unknown start_station."""
        self._start_s = self._station_s(config)
        if config.reverse_distance != self.config.reverse_distance:
            self._direction.distance_m = config.reverse_distance
        if config.delay_window != self.config.delay_window:
            self._delay.time_constant_s = config.delay_window
        self.config = config
        self._derive_ns(config)

    def _derive_ns(self, config: IngestConfig) -> None:
        """The config's times in ns that the per-input checks compare with, computed once per config."""
        self._age_ns = config.max_sample_age * NS
        self._age_ns_int = int(config.max_sample_age * NS)
        self._keep_ns = int(config.pair_tolerance * NS) + NS  # _trim keeps this much before the horizon
        self._pair_ns = config.pair_tolerance * NS
        self._power_pair_ns = config.power_pair_tolerance * NS
        self._pairing_wait_ns = config.max_pairing_wait * NS

    # -- public API ----------------------------------------------------------------------------
    @property
    def pending(self) -> int:
        """Speed samples held for pairing."""
        return len(self._pending)

    @property
    def acquired(self) -> bool:
        return self._anchor_t is not None

    @property
    def reversing(self) -> bool:
        """The fixes move against the track direction: speed samples are dropped (``reversing``)."""
        return self._direction.direction == BACKWARD

    @property
    def gnss_delay_estimate(self) -> tuple[float, float] | None:
        """(delay, std) in s of the GNSS stamps behind the speed stamps, beyond ``gnss_delay``; None until known."""
        return self._delay.estimate()

    def add_fix(self, fix: GnssFix) -> list[Measurement]:
        self.stats.received[GNSS] += 1
        original = fix
        if self.config.gnss_delay:
            fix = replace(fix, stamp_ns=fix.stamp_ns - round(self.config.gnss_delay * NS))
        reason, late = self._check_fix(fix)
        if reason is None:
            reason = self._match(fix, late)
        if reason is None:
            self._update_odometer_checks()
        return self._settle(GNSS, original, reason)

    def add_speed(self, sample: SpeedSample) -> list[Measurement]:
        self.stats.received[SPEED] += 1
        reason, late = self._check_speed(sample)
        if reason is None:
            self._accept_speed(sample, late)
        return self._settle(SPEED, sample, reason)

    def add_power(self, sample: PowerSample) -> list[Measurement]:
        self.stats.received[POWER] += 1
        reason, late = self._check_power(sample)
        if reason is None:
            if late:
                _insort(self._powers, sample, _stamp)
            else:
                self._powers.append(sample)
        return self._settle(POWER, sample, reason)

    def flush(self) -> list[Measurement]:
        """Release every held speed sample with what is known now (end of input, or a timeout)."""
        out = []
        while self._pending:
            m = self._make(self._pending.popleft())
            if m is not None:
                out.append(m)
        self._trim()
        return out

    def run(self, events: Iterable[GnssFix | SpeedSample | PowerSample]) -> Iterator[Measurement]:
        """Feed events in arrival order, then flush; yields the Measurements."""
        for event in events:
            yield from self.add(event)
        yield from self.flush()

    def add(self, event: GnssFix | SpeedSample | PowerSample) -> list[Measurement]:
        if isinstance(event, SpeedSample):
            return self.add_speed(event)
        if isinstance(event, GnssFix):
            return self.add_fix(event)
        if isinstance(event, PowerSample):
            return self.add_power(event)
        raise TypeError(f"not an ingest input: {type(event).__name__}")

    # -- bookkeeping of a sample's fate ------------------------------------------------------------
    def _settle(self, stream: str, event: Any, reason: str | None) -> list[Measurement]:
        stats = self.stats
        if reason is None:
            stats.accepted[stream] += 1
            stats.consecutive_dropped[stream] = 0
        else:
            self._drop(stream, reason)
        if reason in (STALE, OUT_OF_ORDER):
            out = self._behind_time_base(stream, event, reason)
            if out is not None:
                return out
        elif reason != DUPLICATE:
            self._behind.clear()  # a sample of the current time base: no clock reset
        return self._release()

    def _drop(self, stream: str, reason: str) -> None:
        self.stats.dropped[stream][reason] += 1
        self.stats.consecutive_dropped[stream] += 1
        self.stats.last_drop[stream] = reason

    def _undrop(self, stream: str, reason: str) -> None:
        counter = self.stats.dropped[stream]
        counter[reason] -= 1
        if counter[reason] <= 0:
            del counter[reason]
        self.stats.consecutive_dropped[stream] = max(self.stats.consecutive_dropped[stream] - 1, 0)

    # -- clock resets -------------------------------------------------------------------------------
    def _behind_time_base(self, stream: str, event: Any, reason: str) -> list[Measurement] | None:
        """A sample behind the current time base (stale or out of order). ``clock_reset_after`` such samples in a
        row, increasing per stream, from every stream active in the current time base (or spanning
        ``max_sample_age`` of their own time) are a clock reset (a bag loop, a restarted clock): the ingest starts
        over on the new time base with a new run, and those samples are processed there (nothing is lost).
        A single stream behind the others (its clock is off) never resets: its samples are dropped, counted."""
        cfg = self.config
        behind = self._behind
        age_ns = self._age_ns
        t = event.stamp_ns
        if behind:
            same = [e.stamp_ns for s, e, _ in behind if s == stream]
            first = behind[0][1].stamp_ns
            if (same and t <= same[-1]) or t < first:
                behind.clear()
        behind.append((stream, event, reason))
        first = behind[0][1].stamp_ns
        newest = self._newest_ns if self._newest_ns is not None else t
        active = {s for s, latest in self._latest.items() if newest - latest <= age_ns}
        streams = {s for s, _, _ in behind}
        if len(behind) >= cfg.clock_reset_after and (active <= streams or t - first >= age_ns):
            return self._clock_reset()
        return None

    def _clock_reset(self) -> list[Measurement]:
        out = self.flush()
        samples, self._behind = self._behind, []
        for stream, _, reason in samples:
            self.stats.received[stream] -= 1
            self._undrop(stream, reason)
        if self._last_meas_t is not None:
            self.run_id += 1
        self.stats.clock_resets += 1
        self._init_state()
        for _, event, _ in samples:
            out += self.add(event)
        return out

    # -- validation ------------------------------------------------------------------------------
    def _check_time(self, stream: str, t_ns: int, recent: Callable[[], Iterable[int]]) -> tuple[str | None, bool]:
        """Staleness, duplicates and ordering: (drop reason or None, late). A sample that passes in order
        advances its stream's latest stamp; a late one (older than its stream's latest, newer than the last
        released speed sample) passes with late True and is inserted in order. ``recent()``: the stream's
        recent stamps (read only for a sample behind its stream's latest)."""
        if self._newest_ns is not None and (self._newest_ns - t_ns) > self._age_ns:
            return STALE, False
        last = self._latest.get(stream)
        if last is not None and t_ns <= last:
            if t_ns == last or t_ns in recent():
                return DUPLICATE, False
            if self._released_t is not None and t_ns <= self._released_t:
                return OUT_OF_ORDER, False
            return None, True
        if last is not None:
            self._period[stream] = t_ns - last  # the stream's sampling period, as last observed
        self._latest[stream] = t_ns
        self._silence_ns = t_ns - self._newest_ns if self._newest_ns is not None else 0
        if self._newest_ns is None or t_ns > self._newest_ns:
            self._newest_ns = t_ns
        return None, False

    def _fix_stamps(self) -> Iterator[int]:
        return (f.t_ns for f in self._fixes)

    def _speed_stamps(self) -> Iterator[int]:
        return (sp.stamp_ns for queue in (self._speeds, self._pending) for sp in queue)

    def _power_stamps(self) -> Iterator[int]:
        return (p.stamp_ns for p in self._powers)

    def _check_fix(self, fix: GnssFix) -> tuple[str | None, bool]:
        reason, late = self._check_time(GNSS, fix.stamp_ns, self._fix_stamps)
        if reason is not None:
            return reason, late
        if fix.status < 0:
            return NO_FIX, late
        if not (math.isfinite(fix.lat) and math.isfinite(fix.lon)):
            return NAN, late
        return None, late

    def _check_speed(self, sample: SpeedSample) -> tuple[str | None, bool]:
        reason, late = self._check_time(SPEED, sample.stamp_ns, self._speed_stamps)
        if reason is not None:
            return reason, late
        v = sample.v
        if not math.isfinite(v):
            return NAN, late
        if v < 0.0:
            return NEGATIVE_SPEED, late
        if v > self.config.max_speed:
            return IMPLAUSIBLE_SPEED, late
        return self._check_speed_step(sample, late), late

    def _check_speed_step(self, sample: SpeedSample, late: bool) -> str | None:
        """|dv/dt| to the neighbouring accepted sample above max_acceleration is a speed jump. A new level is
        accepted only when ``reacquire_after`` consecutive, mutually consistent samples have held it for
        ``speed_step_time`` s (wheel slip or slide lasts seconds) and the fixes of that span do not contradict it;
        those earlier samples are then accepted too."""
        cfg = self.config
        t = sample.stamp_ns
        ref = self._neighbour_speed(t) if late else self._last_speed
        if ref is None:
            return None
        dt = abs(t - ref.stamp_ns) / NS
        plausible = abs(sample.v - ref.v) <= cfg.max_acceleration * dt
        if plausible and self._step and not late:
            # back after rejected samples: the bound has grown with the time since the last accepted sample,
            # so the fixes of that span must agree too (a spike that merely fits the wider bound does not)
            plausible = self._fixes_agree(ref, sample)
        if dt > cfg.run_gap or plausible:
            if not late:
                self._step.clear()
                self._step_first_ns = None
            return None
        if late:
            return SPEED_JUMP
        step = self._step
        if step and abs(sample.v - step[-1].v) > cfg.max_acceleration * (t - step[-1].stamp_ns) / NS:
            step.clear()
        if not step:
            self._step_first_ns = t
        step.append(sample)
        held = (t - (self._step_first_ns or t)) / NS
        if len(step) < cfg.reacquire_after or held < cfg.speed_step_time - 1e-9 or self._fixes_contradict(ref):
            return SPEED_JUMP
        # a real new level: accept it, and the samples that held it before (still pending-able)
        earlier = list(step)[:-1]
        step.clear()
        self._step_first_ns = None
        for sp in earlier:
            if self._released_t is None or sp.stamp_ns > self._released_t:
                self._undrop(SPEED, SPEED_JUMP)
                self.stats.accepted[SPEED] += 1
                _insort(self._speeds, sp, _stamp)
                _insort(self._pending, sp, _stamp)
                self._odometer.add(sp.stamp_ns, sp.v)
        return None

    def _fixes_agree(self, ref: SpeedSample, sample: SpeedSample) -> bool:
        """The mean speed of the accepted fixes between two speed samples agrees with the samples' mean (within
        3 standard deviations of the fix noise and 0.5 m/s); True when the fixes do not cover the span."""
        fixes = [f for f in self._fixes if ref.stamp_ns - NS // 2 <= f.t_ns <= sample.stamp_ns + NS // 2]
        if len(fixes) < 2:
            return True
        span = (fixes[-1].t_ns - fixes[0].t_ns) / NS
        if span < 2.0:
            return True
        v_gnss = abs(fixes[-1].s - fixes[0].s) / span
        noise = 3.0 * math.sqrt(fixes[0].variance + fixes[-1].variance) / span
        return abs(0.5 * (ref.v + sample.v) - v_gnss) <= noise + 0.5

    def _fixes_contradict(self, ref: SpeedSample) -> bool:
        """The accepted fixes over the speed step's span moved at a speed nearer the old level than the new."""
        step = self._step
        t0 = step[0].stamp_ns - NS
        fixes = [f for f in self._fixes if f.t_ns >= t0]
        if len(fixes) < 2 or fixes[-1].t_ns - fixes[0].t_ns < 3 * NS:
            return False
        v_gnss = abs(fixes[-1].s - fixes[0].s) / ((fixes[-1].t_ns - fixes[0].t_ns) / NS)
        v_new = sum(sp.v for sp in step) / len(step)
        return abs(v_gnss - ref.v) < abs(v_gnss - v_new)

    def _neighbour_speed(self, t_ns: int) -> SpeedSample | None:
        """The validated speed sample nearest to t (for a late sample)."""
        best, best_dt = None, None
        for sp in (*self._speeds, *self._pending):
            dt = abs(sp.stamp_ns - t_ns)
            if best_dt is None or dt < best_dt:
                best, best_dt = sp, dt
        return best

    def _check_power(self, sample: PowerSample) -> tuple[str | None, bool]:
        reason, late = self._check_time(POWER, sample.stamp_ns, self._power_stamps)
        if reason is not None:
            return reason, late
        if not (math.isfinite(sample.consumed) and math.isfinite(sample.regenerated)):
            return NAN, late
        if sample.consumed < 0.0 or sample.regenerated < 0.0:
            return NEGATIVE_POWER, late
        return None, late

    def _accept_speed(self, sample: SpeedSample, late: bool) -> None:
        if late:
            _insort(self._speeds, sample, _stamp)
            _insort(self._pending, sample, _stamp)
            return
        self._last_speed = sample
        self._speeds.append(sample)
        self._pending.append(sample)
        restarts = self._odometer.restarts
        self._odometer.add(sample.stamp_ns, sample.v)
        if self._odometer.restarts != restarts:  # a gap the odometer does not bridge: its distances restart
            self._direction.reset()
            self._delay.reset()
            self._odometer_queue.clear()
        self._update_odometer_checks()

    # -- odometer checks: direction, GNSS delay ---------------------------------------------------------
    def _update_odometer_checks(self) -> None:
        """Feed the fixes the odometer has reached to the direction monitor and the delay estimator."""
        queue = self._odometer_queue
        latest = self._odometer.latest_ns
        while queue and latest is not None and queue[0].t_ns <= latest:
            fix = queue.popleft()
            at = self._odometer.at(fix.t_ns)
            if at is None:
                continue
            d, v = at
            before = self._direction.direction
            after = self._direction.add(fix.t_ns, fix.s, d)
            if after != before:
                self._delay.reset()
                if after == BACKWARD:
                    self.stats.reversals += 1
                else:
                    self._new_run_next = True
            elif after == FORWARD:
                self._delay.add(fix.t_ns, fix.s, d, v)

    # -- map matching ----------------------------------------------------------------------------
    def _fix_variance(self, fix: GnssFix) -> float:
        if self.config.use_fix_covariance and math.isfinite(fix.horizontal_variance) and fix.horizontal_variance > 0:
            return fix.horizontal_variance
        if self.config.use_fix_covariance and fix.covariance_known:
            self.stats.repaired[GNSS][BAD_COVARIANCE] += 1  # known but NaN, infinite or not positive
        return self.config.position_std**2

    def _window(self, t_ns: int) -> tuple[float, float]:
        """The continuity window at t: around the position predicted from the anchor and the speed, along the
        running direction; at low speed (shunting) it also covers the other direction."""
        assert self._anchor_t is not None
        cfg = self.config
        dt = (t_ns - self._anchor_t) / NS
        v = self._speed_near(t_ns)
        travel = 0.5 * (self._anchor_v + v) * dt
        sign = self._direction.direction
        since_fix = (t_ns - (self._last_fix_t if self._last_fix_t is not None else self._anchor_t)) / NS
        gate = cfg.continuity_gate + cfg.continuity_gate_growth * abs(since_fix)
        s_pred = self._anchor_s + sign * travel
        lo, hi = s_pred - gate, s_pred + gate
        if max(self._anchor_v, v) <= cfg.reverse_max_speed:
            other = self._anchor_s - sign * travel
            lo, hi = min(lo, other - gate), max(hi, other + gate)
        return lo, hi

    def _speed_near(self, t_ns: int) -> float:
        """The speed to dead-reckon towards t: the last validated speed sample; when it is older than
        ``max_sample_age`` (the speed stream is silent), the speed of the last accepted fixes; else the anchor's."""
        last = self._last_speed
        if last is not None and abs(t_ns - last.stamp_ns) <= self._age_ns:
            return last.v
        v_fix = self._fix_speed()
        if v_fix is not None:
            return v_fix
        return last.v if last is not None else self._anchor_v

    def _fix_speed(self) -> float | None:
        """Speed from the last two accepted fixes at least 1 s apart (m/s), None without them."""
        fixes = self._fixes
        if len(fixes) < 2:
            return None
        newest = fixes[-1]
        for older in reversed(fixes):
            dt = (newest.t_ns - older.t_ns) / NS
            if dt >= 1.0:
                return abs(newest.s - older.s) / dt
        return None

    def _match(self, fix: GnssFix, late: bool = False) -> str | None:
        cfg = self.config
        east, north = self._enu(fix.lat, fix.lon)
        variance = self._fix_variance(fix)
        tracking = (
            self._anchor_t is not None
            and (self._last_fix_t is None or abs(fix.stamp_ns - self._last_fix_t) / NS <= cfg.reacquire_gap)
            and self._silence_ns <= cfg.run_gap * NS  # after every input was silent that long, the whole line
        )
        if tracking:
            window: tuple[float, float] | None = self._window(fix.stamp_ns)
        elif self._anchor_t is None and self._start_s is not None:
            window = (self._start_s - cfg.acquisition_gate, self._start_s + cfg.acquisition_gate)
        else:
            window = None  # (re-)acquisition on the whole line
        if window is not None:
            s, d = self._segments.project(east, north, *window)
            if d <= cfg.max_cross_track:
                if not late:
                    self._candidates.clear()
                self._accept_fix(_Fix(fix.stamp_ns, s, variance, d), tracking and not late)
                return None
        s_all, d_all = self.track.project(east, north)
        if d_all > cfg.max_cross_track:
            return OFF_TRACK
        candidate = _Fix(fix.stamp_ns, s_all, variance, d_all)
        if window is None:
            if self._anchor_t is not None:
                self._reacquired()
            self._candidates.clear()
            self._accept_fix(candidate, False)
            return None
        if late:
            return JUMP
        # near the track but not where the train can be: a jump; consistent jumps re-acquire there
        if self._candidates:
            prev = self._candidates[-1]
            dt = (candidate.t_ns - prev.t_ns) / NS
            allowed = cfg.continuity_gate + cfg.continuity_gate_growth * dt
            travel = self._direction.direction * self._speed_near(candidate.t_ns) * dt
            if abs(candidate.s - (prev.s + travel)) > allowed:
                self._candidates.clear()
        self._candidates.append(candidate)
        if len(self._candidates) >= cfg.reacquire_after:
            self._candidates.clear()
            self._reacquired()
            self._accept_fix(candidate, False)
            return None
        return JUMP

    def _reacquired(self) -> None:
        self.stats.reacquisitions += 1
        self._delay.reset()
        self._odometer_queue.clear()
        self._direction.reset()

    def _accept_fix(self, fix: _Fix, checks: bool) -> None:
        """Store an accepted fix (in stamp order); `checks`: also for the direction and delay checks."""
        if self._fixes and fix.t_ns < self._fixes[-1].t_ns:
            _insort(self._fixes, fix, _fix_stamp)
        else:
            self._fixes.append(fix)
            if checks:
                self._odometer_queue.append(fix)
        if self._last_fix_t is None or fix.t_ns > self._last_fix_t:
            self._last_fix_t = fix.t_ns
        if self._anchor_t is None or fix.t_ns >= self._anchor_t:
            self._anchor_t = fix.t_ns
            self._anchor_s = fix.s
            self._anchor_v = self._speed_near(fix.t_ns)
            self._base_t, self._base_var = fix.t_ns, fix.variance

    # -- pairing and release ---------------------------------------------------------------------
    def _ready(self, sample: SpeedSample) -> bool:
        """A speed sample can be paired now with the nearest sample of every other stream.

        A stream is ready when it has reached the stamp, or when its next sample (expected one observed
        period after its latest) cannot be nearer than the latest; GNSS is waited for from the start,
        power once it has been seen. A sample that has waited until an input ``max_pairing_wait`` newer
        arrived is released anyway.
        """
        assert self._newest_ns is not None
        t = sample.stamp_ns
        if self._newest_ns - t >= self._pairing_wait_ns:
            return True
        if not self._stream_ready(GNSS, t, required=True):
            return False
        return self._stream_ready(POWER, t, required=False)

    def _stream_ready(self, stream: str, t: int, required: bool) -> bool:
        latest = self._latest.get(stream)
        if latest is None:
            return not required
        if latest >= t:
            return True
        period = self._period.get(stream)
        return period is not None and latest + period - t >= t - latest

    def _release(self) -> list[Measurement]:
        out = []
        while self._pending and self._ready(self._pending[0]):
            m = self._make(self._pending.popleft())
            if m is not None:
                out.append(m)
        self._trim()
        return out

    def _trim(self) -> None:
        """Forget fixes and power samples no pending or future speed sample can pair with."""
        pending = self._pending
        horizon = pending[0].stamp_ns if pending else self._latest.get(SPEED)
        newest = self._newest_ns
        if newest is not None:  # a speed stream silent for long must not let them pile up
            oldest_useful = newest - self._age_ns_int
            horizon = oldest_useful if horizon is None or oldest_useful > horizon else horizon
        if horizon is None:
            return
        keep_from = horizon - self._keep_ns
        fixes, powers, speeds = self._fixes, self._powers, self._speeds
        while len(fixes) > 1 and fixes[1].t_ns <= keep_from:
            fixes.popleft()
        while len(powers) > 1 and powers[1].stamp_ns <= keep_from:
            powers.popleft()
        while len(speeds) > 2 and speeds[1].stamp_ns <= keep_from:
            speeds.popleft()

    def _nearest_fix(self, t_ns: int) -> _Fix | None:
        best, best_dt = None, self._pair_ns
        for fix in self._fixes:
            dt = abs(fix.t_ns - t_ns)
            if dt <= best_dt:
                best, best_dt = fix, dt
        return best

    def _speed_at(self, t_ns: int, default: float) -> float:
        """Speed at t interpolated between the validated speed samples around it (nearest beyond them)."""
        before = after = None
        for sp in self._speeds:
            if sp.stamp_ns <= t_ns:
                before = sp
            else:
                after = sp
                break
        if before is None:
            return after.v if after is not None else default
        if after is None or before.stamp_ns == t_ns:
            return before.v
        w = (t_ns - before.stamp_ns) / (after.stamp_ns - before.stamp_ns)
        return before.v + w * (after.v - before.v)

    def _nearest_power(self, t_ns: int) -> PowerSample | None:
        best, best_dt = None, self._power_pair_ns
        for p in self._powers:
            dt = abs(p.stamp_ns - t_ns)
            if dt <= best_dt:
                best, best_dt = p, dt
        return best

    def _make(self, sample: SpeedSample) -> Measurement | None:
        cfg = self.config
        t = sample.stamp_ns
        v = sample.v
        if self._released_t is None or t > self._released_t:
            self._released_t = t
        if self._direction.direction == BACKWARD:
            # against the track direction: the model runs along increasing s; dead-reckon backwards for the
            # continuity window and publish nothing
            if self._anchor_t is not None and t > self._anchor_t:
                self._anchor_s -= 0.5 * (self._anchor_v + v) * (t - self._anchor_t) / NS
                self._anchor_s = min(max(self._anchor_s, 0.0), self.track.length_m)
                self._anchor_t, self._anchor_v = t, v
            self._drop(SPEED, REVERSING)
            return None
        fix = self._nearest_fix(t)
        if fix is not None:
            dt_fix = (t - fix.t_ns) / NS
            s = fix.s + 0.5 * (self._speed_at(fix.t_ns, v) + v) * dt_fix  # trapezoid: exact at constant a
            s_var = fix.variance + (cfg.speed_std * dt_fix) ** 2
            measured, cross_track = True, fix.cross_track
        elif self._anchor_t is not None and (t - self._anchor_t) / NS <= cfg.max_dead_reckoning:
            dt_a = (t - self._anchor_t) / NS
            s = self._anchor_s + 0.5 * (self._anchor_v + v) * dt_a
            # speed errors are largely systematic (calibration, quantisation of a slowly varying speed): the
            # dead-reckoning error grows linearly with the time since the last fix, not as a random walk
            s_var = self._base_var + (cfg.speed_std * (t - self._base_t) / NS) ** 2
            measured, cross_track = False, 0.0
        else:
            self._drop(SPEED, NO_POSITION)
            return None
        length = self.track.length_m
        s = 0.0 if s < 0.0 else length if s > length else s  # = min(max(s, 0), length)
        # the measurement becomes the anchor for dead reckoning
        self._anchor_t, self._anchor_s, self._anchor_v = t, s, v
        if measured:  # dead reckoning error grows from the fix itself
            self._base_t, self._base_var = fix.t_ns, fix.variance
        if not measured:
            self.stats.dead_reckoned += 1

        run_id, dt = self._segment(t, v)
        power = self._nearest_power(t)
        terms = self._terms
        m = Measurement(  # positional, in field order: stamp_ns, s, v, track_force, dt, run_id, s_measured,
            t,  # s_variance, v_variance, cross_track, speed_limit, tunnel_fraction, power_valid, power_consumed,
            s,  # power_regenerated (a keyword call costs more, per sample)
            v,
            terms.track_force(s),
            dt,
            run_id,
            measured,
            s_var,
            cfg.speed_std**2,
            cross_track,
            terms.limit(s),
            terms.tunnel_fraction(s),
            power is not None,
            power.consumed if power is not None else 0.0,
            power.regenerated if power is not None else 0.0,
        )
        self.stats.published += 1
        return m

    # -- run segmentation ------------------------------------------------------------------------
    def _segment(self, t_ns: int, v: float) -> tuple[int, float]:
        """Run id and dt of a measurement at t with speed v."""
        cfg = self.config
        new_run = False
        if self._last_meas_t is not None and (t_ns - self._last_meas_t) / NS > cfg.run_gap:
            new_run = self._run_moved
            self._standstill_since = None
        if self._new_run_next:  # back in the track direction after reversing
            new_run = self._last_meas_t is not None
            self._new_run_next = False
        if v <= cfg.standstill_speed:
            if self._standstill_since is None:
                self._standstill_since = t_ns
        else:
            if (
                self._standstill_since is not None
                and self._run_moved
                and (t_ns - self._standstill_since) / NS >= cfg.min_standstill
            ):
                new_run = True
            self._standstill_since = None
        if new_run:
            self.run_id += 1
            self._run_moved = False
        dt = 0.0 if (new_run or self._last_meas_t is None) else (t_ns - self._last_meas_t) / NS
        if v > cfg.standstill_speed:
            self._run_moved = True
        self._last_meas_t = t_ns
        return self.run_id, dt


def _stamp(sample: Any) -> int:
    return sample.stamp_ns


def _fix_stamp(fix: _Fix) -> int:
    return fix.t_ns


def _insort(queue: deque, item: Any, key: Any) -> None:
    """Insert into a deque kept in stamp order (late samples are rare: a linear scan from the end)."""
    t = key(item)
    i = len(queue)
    while i > 0 and key(queue[i - 1]) > t:
        i -= 1
    queue.insert(i, item)


__all__ = [
    "DROP_REASONS",
    "GNSS",
    "POWER",
    "REPAIR_REASONS",
    "SPEED",
    "STREAMS",
    "GnssFix",
    "Ingest",
    "IngestConfig",
    "IngestStats",
    "PowerSample",
    "SpeedSample",
    "fix_from_msg",
    "power_from_msg",
    "speed_from_msg",
]
