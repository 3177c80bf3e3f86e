"""The release of a held speed sample: its position (from the nearest fix, else dead-reckoned from the anchor),
the track terms there, the nearest power sample and its run, as one Measurement. Stamps in ns, SI units."""

from __future__ import annotations

import math

from ..measurement import Measurement
from ..odometry import BACKWARD
from ..track import ScalarTrackTerms, Track
from .config import Settings
from .odometer_checks import OdometerChecks
from .pairing import Pairer, nearest_in_order
from .position import Anchor
from .records import NO_POSITION, NS, REVERSING, SPEED, MatchedFix, SpeedSample
from .runs import RunSegmenter
from .stats import IngestStats
from .timebase import TimeBase


class Releaser:
    """Makes the Measurement of a released speed sample, or counts why there is none (``reversing``,
    ``no_position``); every release advances the time base's release time and moves the anchor."""

    def __init__(
        self,
        settings: Settings,
        track: Track,
        terms: ScalarTrackTerms,
        parts: tuple[TimeBase, Anchor, Pairer, OdometerChecks, RunSegmenter],
        stats: IngestStats,
    ) -> None:
        self.settings = settings
        self.track = track
        self.terms = terms
        self.clock, self.anchor, self.pairer, self.checks, self.runs = parts
        self.stats = stats
        self.deferred: list[Measurement] | None = None  # not None: the track terms are left to the caller (NaN)

    def release(self, sample: SpeedSample) -> Measurement | None:
        t, v = sample.stamp_ns, sample.v
        self.clock.release(t)
        if self.checks.direction.direction == BACKWARD:  # checks.reversing
            # against the track direction: the model runs along increasing s; dead-reckon backwards for the
            # continuity window and publish nothing
            self.anchor.reckon_backward(t, v, self.track.length_m)
            self.stats.drop(SPEED, REVERSING)
            return None
        position = self._locate(t, v)
        if position is None:
            self.stats.drop(SPEED, NO_POSITION)
            return None
        s, variance, fix = position
        # the measurement becomes the anchor for dead reckoning (from the fix itself when it has one)
        self.anchor.at_measurement(t, s, v, fix)
        if fix is None:
            self.stats.dead_reckoned += 1
        run_id, dt = self.runs.segment(t, v)
        m = self._measurement(t, s, v, variance, fix, run_id, dt)
        self.stats.published += 1
        return m

    def _locate(self, t: int, v: float) -> tuple[float, float, MatchedFix | None] | None:
        """(s in m within the line, its variance in m^2, the fix it was paired with or None: dead-reckoned) at t
        with speed v; None before the position is acquired or after ``max_dead_reckoning``."""
        settings, pairer = self.settings, self.pairer
        cfg = settings.config
        fix = nearest_in_order(pairer.fixes, t, settings.pair_ns)  # pairer.nearest_fix(t)
        if fix is not None:
            t_fix = fix.stamp_ns
            dt_fix = (t - t_fix) / NS
            s = fix.s + 0.5 * (pairer.speed_at(t_fix, v) + v) * dt_fix  # trapezoid: exact at constant a
            s_var = fix.variance + (cfg.speed_std * dt_fix) ** 2
        else:
            reckoned = self.anchor.dead_reckon(t, v, cfg.speed_std, cfg.max_dead_reckoning)
            if reckoned is None:
                return None
            s, s_var = reckoned
        length = self.track.length_m
        s = 0.0 if s < 0.0 else length if s > length else s  # = min(max(s, 0), length)
        return s, s_var, fix

    def _measurement(
        self, t: int, s: float, v: float, variance: float, fix: MatchedFix | None, run_id: int, dt: float
    ) -> Measurement:
        settings = self.settings
        powers = self.pairer.powers
        power = nearest_in_order(powers, t, settings.power_pair_ns) if powers else None  # pairer.nearest_power(t)
        deferred = self.deferred
        if deferred is None:
            track_force, limit, tunnel_fraction, track_force_integral = self.terms.at(s)
        else:
            track_force = limit = tunnel_fraction = track_force_integral = math.nan  # Ingest.fill_terms sets them
        m = Measurement(  # positional, in field order: stamp_ns, s, v, track_force, dt, run_id, s_measured,
            t,  # s_variance, v_variance, cross_track, speed_limit, tunnel_fraction, power_valid, power_consumed,
            s,  # power_regenerated, track_force_integral (a keyword call costs more, per sample)
            v,
            track_force,
            dt,
            run_id,
            fix is not None,
            variance,
            settings.speed_variance,
            fix.cross_track if fix is not None else 0.0,
            limit,
            tunnel_fraction,
            power is not None,
            power.consumed if power is not None else 0.0,
            power.regenerated if power is not None else 0.0,
            track_force_integral,
        )
        if deferred is not None:
            deferred.append(m)
        return m
