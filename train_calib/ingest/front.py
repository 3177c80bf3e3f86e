"""``Ingest``: the front of the ingest. It routes each input sample through its checks and the part that owns its
state machine, counts its fate, and starts a new time base on a clock reset. Stamps in ns, SI units."""

from __future__ import annotations

import math
from collections.abc import Iterable, Iterator
from dataclasses import replace
from typing import Any

from ..geodesy import ScalarEnu
from ..measurement import Measurement
from ..track import ScalarTrackTerms, Track, WindowProjector
from ..train import TrainSpec
from .config import IngestConfig, Settings, start_position
from .matching import MapMatcher
from .odometer_checks import NO_CHANGE, OdometerChecks
from .offline import add_many
from .pairing import Pairer
from .position import Anchor
from .records import (
    DUPLICATE,
    GNSS,
    IMPLAUSIBLE_SPEED,
    NAN,
    NEGATIVE_POWER,
    NEGATIVE_SPEED,
    NO_FIX,
    NS,
    OUT_OF_ORDER,
    POWER,
    SPEED,
    SPEED_JUMP,
    STALE,
    GnssFix,
    PowerSample,
    SpeedSample,
)
from .release import Releaser
from .runs import RunSegmenter
from .speed_step import SpeedStepFilter
from .stats import IngestStats
from .timebase import ClockResetWatch, TimeBase


class Ingest:
    """Online ingest of the three input streams; every ``add_*`` returns the Measurements it releases.

    The parts, each with one state machine: ``clock`` (the time base: stamps, ordering, when a held sample may be
    paired), ``pairer`` (the samples held for pairing), ``anchor`` (the last known position), ``checks`` (running
    direction and GNSS delay against the speed odometer), ``steps`` (the speed-step filter), ``matcher`` (map
    matching with continuity and re-acquisition), ``releaser`` (a released speed sample as a Measurement) and
    ``runs`` (the run segmentation). All but ``runs`` and the clock-reset watch start anew on a clock reset.
    """

    def __init__(self, track: Track, train: TrainSpec, config: IngestConfig | None = None) -> None:
        self.track = track
        self.train = train
        config = config or IngestConfig()
        self.settings = Settings(config, start_position(track, config))
        self._terms = ScalarTrackTerms(track, train.length_m)
        self._enu = ScalarEnu(track.frame)
        self._projector = WindowProjector(track)
        self.stats = IngestStats()
        self.runs = RunSegmenter(self.settings)
        self._reset_watch = ClockResetWatch()
        self._deferred: list[Measurement] | None = None  # Measurements whose track terms wait for fill_terms
        self._estimate_delay = True  # fit the GNSS stamp delay (gnss_delay_estimate)
        self._init_state()

    def _init_state(self) -> None:
        """Everything that belongs to one time base (a clock reset starts over from here)."""
        settings, stats = self.settings, self.stats
        self.clock = TimeBase(settings)
        self.pairer = Pairer(settings)
        self.anchor = Anchor()
        self.checks = OdometerChecks(settings.config, self._estimate_delay)
        self.steps = SpeedStepFilter(settings, self.pairer)
        parts = (self.clock, self.anchor, self.pairer, self.checks)
        self.matcher = MapMatcher(settings, self.track, self._enu, self._projector, parts, stats)
        self.releaser = Releaser(settings, self.track, self._terms, (*parts, self.runs), stats)
        self.releaser.deferred = self._deferred

    # -- parameters ------------------------------------------------------------------------------
    @property
    def config(self) -> IngestConfig:
        return self.settings.config

    def start_position(self, config: IngestConfig) -> float | None:
        """s in m of the config's ``start_station`` on this track; ConfigError for an unknown station."""
        return start_position(self.track, config)

    def set_config(self, config: IngestConfig) -> None:
        """Change the parameters on the fly (the state is kept); ConfigError for an unknown start_station."""
        start_s = self.start_position(config)
        self.checks.configure(self.config, config)
        self.settings.set(config, start_s)

    # -- public API ----------------------------------------------------------------------------
    @property
    def run_id(self) -> int:
        return self.runs.run_id

    @property
    def pending(self) -> int:
        """Speed samples held for pairing."""
        return len(self.pairer.pending)

    @property
    def acquired(self) -> bool:
        return self.anchor.t is not None

    @property
    def reversing(self) -> bool:
        """The fixes move against the track direction: speed samples are dropped (``reversing``)."""
        return self.checks.reversing

    @property
    def gnss_delay_estimate(self) -> tuple[float, float] | None:
        """(delay, std) in s of the GNSS stamps behind the speed stamps, beyond ``gnss_delay``; None until known."""
        return self.checks.delay.estimate()

    def add_fix(self, fix: GnssFix) -> list[Measurement]:
        self.stats.received[GNSS] += 1
        original = fix
        delay = self.settings.config.gnss_delay
        if delay:
            fix = replace(fix, stamp_ns=fix.stamp_ns - round(delay * NS))
        reason, late = self.clock.check(GNSS, fix.stamp_ns, self.pairer.fix_stamps)
        reason = reason or fix_problem(fix) or self.matcher.match(fix, late)
        if reason is None and self.checks.queue:
            self._update_checks()
        return self._settle(GNSS, original, reason)

    def add_speed(self, sample: SpeedSample) -> list[Measurement]:
        self.stats.received[SPEED] += 1
        pairer = self.pairer
        reason, late = self.clock.check(SPEED, sample.stamp_ns, pairer.speed_stamps)
        reason = reason or speed_problem(sample, self.settings.config.max_speed) or self._speed_step(sample, late)
        if reason is None:
            pairer.add_speed(sample, late)
            if not late:
                checks = self.checks
                checks.add_speed(sample.stamp_ns, sample.v)
                if checks.queue:
                    self._update_checks()
        return self._settle(SPEED, sample, reason)

    def add_power(self, sample: PowerSample) -> list[Measurement]:
        self.stats.received[POWER] += 1
        reason, late = self.clock.check(POWER, sample.stamp_ns, self.pairer.power_stamps)
        reason = reason or power_problem(sample)
        if reason is None:
            self.pairer.add_power(sample, late)
        return self._settle(POWER, sample, reason)

    def flush(self) -> list[Measurement]:
        """Release every held speed sample with what is known now (end of input, or a timeout)."""
        out = []
        pending = self.pairer.pending
        while pending:
            m = self.releaser.release(pending.popleft())
            if m is not None:
                out.append(m)
        self.pairer.trim(self.clock)
        return out

    def skip_delay_estimate(self) -> None:
        """Fit no fix for the GNSS stamp delay (``gnss_delay_estimate`` stays None; call it before the first
        sample): offline, where nothing reads the estimate (``pipeline.run_bag``), it is a fifth of the work per fix.
        Nothing else depends on it: the Measurements and the counts are the same."""
        self._estimate_delay = self.checks.estimate_delay = False

    def defer_terms(self) -> None:
        """From now on the Measurements released leave their track terms (track_force, speed_limit,
        tunnel_fraction, track_force_integral) NaN until :meth:`fill_terms`: offline, with every Measurement of a
        bag collected before anything reads them, one numpy pass computes them all (the same floats)."""
        self._deferred = self.releaser.deferred = []

    def fill_terms(self) -> None:
        """Set the track terms of the Measurements released since :meth:`defer_terms`, and stop deferring."""
        deferred = self._deferred
        self._deferred = self.releaser.deferred = None
        if not deferred:
            return
        terms = self._terms.at_many([m.s for m in deferred])
        for m, force, limit, tunnel, integral in zip(deferred, *terms):
            m.track_force, m.speed_limit, m.tunnel_fraction, m.track_force_integral = force, limit, tunnel, integral

    def run(self, events: Iterable[GnssFix | SpeedSample | PowerSample]) -> Iterator[Measurement]:
        """Feed events in arrival order, then flush; yields the Measurements."""
        for event in events:
            yield from self.add(event)
        yield from self.flush()

    def add_many(self, events: Iterable[GnssFix | SpeedSample | PowerSample]) -> list[Measurement]:
        """:meth:`add` on each event in order: the Measurements released (not flushed). The common path of a clean
        recording written out in one loop, a fix's position in the window in C (:func:`offline.add_many`): the same
        Measurements and counts in 0.6 of the time (offline: ``pipeline.run_bag``)."""
        return add_many(self, events)

    def add(self, event: GnssFix | SpeedSample | PowerSample) -> list[Measurement]:
        kind = type(event)  # the exact types first (one dict look-up a sample), then their subclasses
        if kind is SpeedSample:
            return self.add_speed(event)  # type: ignore[arg-type]
        if kind is GnssFix:
            return self.add_fix(event)  # type: ignore[arg-type]
        if isinstance(event, SpeedSample):
            return self.add_speed(event)
        if isinstance(event, GnssFix):
            return self.add_fix(event)
        if isinstance(event, PowerSample):
            return self.add_power(event)
        raise TypeError(f"not an ingest input: {type(event).__name__}")

    # -- routing between the parts -----------------------------------------------------------------
    def _speed_step(self, sample: SpeedSample, late: bool) -> str | None:
        """The speed-step filter's verdict; the earlier samples of a new level are accepted after all (those not
        yet too late to pair: their ``speed_jump`` counts are taken back)."""
        reason, level = self.steps.check(sample, late)
        if not level:
            return reason
        for sp in level:
            if self.clock.unreleased(sp.stamp_ns):
                self.stats.undrop(SPEED, SPEED_JUMP)
                self.stats.accepted[SPEED] += 1
                self.pairer.insert_speed(sp)
                self.checks.odometer.add(sp.stamp_ns, sp.v)
        return reason

    def _update_checks(self) -> None:
        """Feed the odometer checks the fixes it has reached (the callers skip it while ``checks.queue`` is empty:
        no fix waits for the odometer, update would find nothing)."""
        changes = self.checks.update()
        if changes is NO_CHANGE:
            return
        self.stats.reversals += changes.reversals
        if changes.forward_again:
            self.runs.forward_again()

    def _settle(self, stream: str, event: Any, reason: str | None) -> list[Measurement]:
        """Count a sample's fate, watch for a clock reset, and release what can be paired now."""
        stats = self.stats
        if reason is None:
            stats.accepted[stream] += 1
            stats.consecutive_dropped[stream] = 0
            if self._reset_watch.behind:
                self._reset_watch.clear()  # a sample of the current time base: no clock reset
            return self._release()
        stats.drop(stream, reason)
        if reason in (STALE, OUT_OF_ORDER):
            if self._reset_watch.observe(stream, event, reason, self.clock):
                return self._clock_reset()
        elif reason != DUPLICATE and self._reset_watch.behind:
            self._reset_watch.clear()  # a sample of the current time base: no clock reset
        return self._release()

    def _release(self) -> list[Measurement]:
        out = []
        pending = self.pairer.pending
        if pending:
            ready, release = self.clock.ready, self.releaser.release
            while pending and ready(pending[0].stamp_ns):
                m = release(pending.popleft())
                if m is not None:
                    out.append(m)
        self.pairer.trim(self.clock)
        return out

    def _clock_reset(self) -> list[Measurement]:
        """A new time base (a bag loop, a restarted clock): what is held is released, the samples behind the old
        time base are taken back from the counts and replayed on the new one with a new run (nothing is lost)."""
        out = self.flush()
        samples = self._reset_watch.take()
        for stream, _, reason in samples:
            self.stats.received[stream] -= 1
            self.stats.undrop(stream, reason)
        self.runs.new_time_base()
        self.stats.clock_resets += 1
        self._init_state()
        for _, event, _ in samples:
            out += self.add(event)
        return out


# -- validation of a sample's values (its stamp is the time base's) ------------------------------------
def fix_problem(fix: GnssFix) -> str | None:
    if fix.status < 0:
        return NO_FIX
    if not (math.isfinite(fix.lat) and math.isfinite(fix.lon)):
        return NAN
    return None


def speed_problem(sample: SpeedSample, max_speed: float) -> str | None:
    """``max_speed`` in m/s."""
    v = sample.v
    if not math.isfinite(v):
        return NAN
    if v < 0.0:
        return NEGATIVE_SPEED
    if v > max_speed:
        return IMPLAUSIBLE_SPEED
    return None


def power_problem(sample: PowerSample) -> str | None:
    if not (math.isfinite(sample.consumed) and math.isfinite(sample.regenerated)):
        return NAN
    if sample.consumed < 0.0 or sample.regenerated < 0.0:
        return NEGATIVE_POWER
    return None
