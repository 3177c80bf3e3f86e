"""Map matching with continuity: a fix is projected onto the track only within a window around the position the
train can have (a train does not jump); consistent jumps re-acquire the position. Stamps in ns, positions in m."""

from __future__ import annotations

import math

from ..geodesy import ScalarEnu
from ..track import Track, WindowProjector
from .config import Settings
from .odometer_checks import OdometerChecks
from .pairing import Pairer
from .position import Anchor
from .records import BAD_COVARIANCE, GNSS, JUMP, NS, OFF_TRACK, GnssFix, MatchedFix
from .stats import IngestStats
from .timebase import TimeBase


class MapMatcher:
    """The continuity window, the re-acquisition candidates after a GNSS jump, and the acceptance of a fix (stored
    for pairing, queued for the odometer checks, moving the anchor)."""

    def __init__(
        self,
        settings: Settings,
        track: Track,
        enu: ScalarEnu,
        projector: WindowProjector,
        parts: tuple[TimeBase, Anchor, Pairer, OdometerChecks],
        stats: IngestStats,
    ) -> None:
        self.settings = settings
        self.track = track
        self.enu = enu
        self.projector = projector
        self.clock, self.anchor, self.pairer, self.checks = parts
        self.stats = stats
        self.last_fix_t: int | None = None  # stamp of the newest accepted fix
        self.candidates: list[MatchedFix] = []  # consecutive jump fixes (re-acquisition)

    def match(self, fix: GnssFix, late: bool = False) -> str | None:
        """Match a validated fix: None when it is accepted, else its drop reason (``off_track``, ``jump``)."""
        cfg = self.settings.config
        t = fix.stamp_ns
        east, north = self.enu(fix.lat, fix.lon)
        variance = self._variance(fix)
        anchor, last_fix_t = self.anchor, self.last_fix_t
        tracking = (
            anchor.t is not None
            and (last_fix_t is None or abs(t - last_fix_t) / NS <= cfg.reacquire_gap)
            and self.clock.silence_ns <= cfg.run_gap * NS  # after every input was silent that long, the whole line
        )
        if tracking:
            window: tuple[float, float] | None = self._window(t)
        elif anchor.t is None and self.settings.start_s is not None:
            start_s = self.settings.start_s
            window = (start_s - cfg.acquisition_gate, start_s + cfg.acquisition_gate)
        else:
            window = None  # (re-)acquisition on the whole line
        if window is not None:
            s, d = self.projector.project(east, north, window[0], window[1])
            if d <= cfg.max_cross_track:
                if not late and self.candidates:
                    self.candidates.clear()
                self._accept(MatchedFix(t, s, variance, d), tracking and not late)
                return None
        s_all, d_all = self.track.project(east, north)
        if d_all > cfg.max_cross_track:
            return OFF_TRACK
        candidate = MatchedFix(fix.stamp_ns, s_all, variance, d_all)
        if window is None:
            if anchor.t is not None:
                self._reacquired()
            self.candidates.clear()
            self._accept(candidate, False)
            return None
        if late:
            return JUMP
        return self._jump(candidate)

    def _jump(self, candidate: MatchedFix) -> str | None:
        """Near the track but not where the train can be: a jump; ``reacquire_after`` consistent jumps re-acquire
        there (None: accepted)."""
        cfg = self.settings.config
        if self.candidates:
            prev = self.candidates[-1]
            dt = (candidate.stamp_ns - prev.stamp_ns) / NS
            allowed = cfg.continuity_gate + cfg.continuity_gate_growth * dt
            travel = self.checks.direction.direction * self.pairer.speed_near(candidate.stamp_ns, self.anchor.v) * dt
            if abs(candidate.s - (prev.s + travel)) > allowed:
                self.candidates.clear()
        self.candidates.append(candidate)
        if len(self.candidates) >= cfg.reacquire_after:
            self.candidates.clear()
            self._reacquired()
            self._accept(candidate, False)
            return None
        return JUMP

    def _variance(self, fix: GnssFix) -> float:
        """The fix's horizontal variance (m^2); a known but unusable covariance is repaired (counted)."""
        cfg = self.settings.config
        variance = fix.horizontal_variance
        if cfg.use_fix_covariance and math.isfinite(variance) and variance > 0:
            return variance
        if cfg.use_fix_covariance and fix.covariance_known:
            self.stats.repaired[GNSS][BAD_COVARIANCE] += 1  # known but NaN, infinite or not positive
        return cfg.position_std**2

    def _window(self, t_ns: int) -> tuple[float, float]:
        """The continuity window at t: around the position predicted from the anchor and the speed, along the
        running direction; at low speed (shunting) it also covers the other direction."""
        anchor = self.anchor
        anchor_t, anchor_s, anchor_v = anchor.t, anchor.s, anchor.v
        assert anchor_t is not None
        cfg = self.settings.config
        dt = (t_ns - anchor_t) / NS
        v = self.pairer.speed_near(t_ns, anchor_v)
        travel = 0.5 * (anchor_v + v) * dt
        sign = self.checks.direction.direction
        since_fix = (t_ns - (self.last_fix_t if self.last_fix_t is not None else anchor_t)) / NS
        gate = cfg.continuity_gate + cfg.continuity_gate_growth * abs(since_fix)
        s_pred = anchor_s + sign * travel
        lo, hi = s_pred - gate, s_pred + gate
        if (v if v > anchor_v else anchor_v) <= cfg.reverse_max_speed:  # max(anchor_v, v)
            other = anchor_s - sign * travel
            lo, hi = min(lo, other - gate), max(hi, other + gate)
        return lo, hi

    def _reacquired(self) -> None:
        self.stats.reacquisitions += 1
        self.checks.reacquired()

    def _accept(self, fix: MatchedFix, checks: bool) -> None:
        """Store an accepted fix (in stamp order); ``checks``: also for the direction and delay checks."""
        pairer, t = self.pairer, fix.stamp_ns
        if pairer.add_fix(fix) and checks:
            self.checks.queue.append(fix)
        if self.last_fix_t is None or t > self.last_fix_t:
            self.last_fix_t = t
        anchor = self.anchor
        if anchor.t is None or t >= anchor.t:
            anchor.at_fix(fix, pairer.speed_near(t, anchor.v))
