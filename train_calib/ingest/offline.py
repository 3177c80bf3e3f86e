"""The ingest of a whole recording (``Ingest.add_many``): ``Ingest.add`` on each event, with the path almost every
sample of a clean recording takes written out in one loop.

The loop is ``for event in events: out += ingest.add(event)`` with the calls of the common path inlined: a speed
sample in order, plausible and in its level; a fix in order, valid, with a usable covariance (or none used) and
matched inside the continuity window; the release of what can be paired then, running forward. The same operations
on the same state in the same order as the parts' methods (``TimeBase.check``, ``SpeedStepFilter.check``,
``Pairer.add_speed``, ``MapMatcher.match`` / ``_window`` / ``_accept``, ``Ingest._settle`` / ``_release``,
``TimeBase.ready``, ``Releaser.release``, ``Pairer.trim``), so the Measurements and the counts are those of
``add``, float for float (``test_ingest_add_many``). Any other sample (a drop, a late or stale one, a speed step,
a fix outside the window, a re-acquisition, a clock reset, power, the records' subclasses, a ``gnss_delay``) goes
to ``Ingest.add``, or to the part's method from the point where the written-out path ends; the loop then reads the
parts again (a clock reset replaces them). The parts stay the readable reference; a change to one of them must be
made here too (the test runs both on every kind of input).
"""

from __future__ import annotations

import math
from array import array
from collections.abc import Iterable
from typing import TYPE_CHECKING, Any

from ..geodesy import _ONE_MINUS_E2, WGS84_A, WGS84_E2, ScalarEnu
from ..measurement import Measurement
from ..odometry import BACKWARD
from ..track import WindowProjector
from .pairing import nearest_in_order
from .records import GNSS, NO_POSITION, NS, POWER, SPEED, GnssFix, MatchedFix, SpeedSample

if TYPE_CHECKING:
    from .front import Ingest

try:
    from . import _kernel  # the fix's position in the window in C (setup.py builds it where a C compiler is found)
except ImportError:  # pragma: no cover - installed without a C compiler: the Python (the same floats)
    _kernel = None


def locator(enu: ScalarEnu, projector: WindowProjector) -> Any:
    """The compiled ``enu`` and ``project`` of these two (``_kernel.Locator``: their formulas in C, the same
    floats), or None without the kernel."""
    if _kernel is None:
        return None
    constants = (WGS84_A, WGS84_E2, _ONE_MINUS_E2, math.radians(1.0), *enu._constants)
    segments = array("d", [x for segment in projector._seg for x in segment])
    return _kernel.Locator(constants, segments, array("d", projector.s), math.hypot)


def _parts(ingest: Ingest) -> tuple[Any, ...]:
    """The ingest's parts of the current time base and their containers (read again after anything that may have
    replaced them: a clock reset)."""
    clock, pairer, checks, releaser = ingest.clock, ingest.pairer, ingest.checks, ingest.releaser
    return (
        clock,
        clock.latest,
        clock.period,
        pairer,
        pairer.pending,
        pairer.speeds,
        pairer.fixes,
        pairer.powers,
        ingest.steps,
        checks,
        checks.queue,
        checks.direction,
        checks.odometer,
        ingest.matcher,
        ingest.anchor,
        releaser.release,
        releaser.deferred,
    )


def add_many(ingest: Ingest, events: Iterable[Any]) -> list[Measurement]:
    """``[m for e in events for m in ingest.add(e)]`` (module docstring)."""
    out: list[Measurement] = []
    settings = ingest.settings
    cfg = settings.config
    if cfg.gnss_delay:  # every fix's stamp is moved: the general path
        add = ingest.add
        for event in events:
            out += add(event)
        return out
    # the settings in force (no parameter can change inside this loop)
    age_ns, age_ns_int, keep_ns = settings.age_ns, settings.age_ns_int, settings.keep_ns
    pair_wait_ns, pair_ns, power_pair_ns = settings.pairing_wait_ns, settings.pair_ns, settings.power_pair_ns
    speed_variance = settings.speed_variance
    max_speed, max_acc, run_gap = cfg.max_speed, cfg.max_acceleration, cfg.run_gap
    reacquire_gap, run_gap_ns, max_cross = cfg.reacquire_gap, cfg.run_gap * NS, cfg.max_cross_track
    use_cov, position_var, reverse_max = cfg.use_fix_covariance, cfg.position_std**2, cfg.reverse_max_speed
    gate0, gate_growth = cfg.continuity_gate, cfg.continuity_gate_growth
    speed_std, max_dead_reckoning, length = cfg.speed_std, cfg.max_dead_reckoning, ingest.track.length_m
    # the objects that outlive the time bases
    stats = ingest.stats
    received, accepted, consecutive = stats.received, stats.accepted, stats.consecutive_dropped
    reset_watch, runs, update_checks = ingest._reset_watch, ingest.runs, ingest._update_checks
    segment, terms_at = runs.segment, ingest._terms.at
    enu, project = ingest._enu, ingest._projector.project
    compiled = locator(ingest._enu, ingest._projector)
    locate = compiled.locate if compiled is not None else None
    inf, nan = math.inf, math.nan
    (clock, latest, period, pairer, pending, speeds, fixes, powers, steps, checks, queue, direction, odometer, matcher,
     anchor, release, deferred) = _parts(ingest)  # fmt: skip
    for event in events:
        kind = type(event)
        if kind is SpeedSample:
            t, v = event.stamp_ns, event.v
            newest = clock.newest_ns
            last = latest.get(SPEED)
            if not (
                (newest is None or newest - t <= age_ns)  # TimeBase.check: not stale,
                and (last is None or t > last)  # in order (neither a duplicate nor late)
                and 0.0 <= v <= max_speed  # speed_problem: finite, not negative, plausible
                and not steps.step
                and steps.first_ns is None  # SpeedStepFilter.check: no speed step under way,
                and (
                    (ref := pairer.last_speed) is None
                    or (dt := abs(t - ref.stamp_ns) / NS) > run_gap
                    or abs(v - ref.v) <= max_acc * dt  # and no speed jump
                )
            ):
                out += ingest.add(event)
                (clock, latest, period, pairer, pending, speeds, fixes, powers, steps, checks, queue, direction,
                 odometer, matcher, anchor, release, deferred) = _parts(ingest)  # fmt: skip
                continue
            received[SPEED] += 1
            # TimeBase.check: a sample in order
            if last is not None:
                period[SPEED] = t - last
            latest[SPEED] = t
            clock.silence_ns = t - newest if newest is not None else 0
            if newest is None or t > newest:
                clock.newest_ns = t
            # Pairer.add_speed(event, late=False)
            pairer.last_speed = event
            speeds.append(event)
            pending.append(event)
            # OdometerChecks.add_speed(t, v)
            restarts = odometer.restarts
            odometer.add(t, v)
            if odometer.restarts != restarts:
                checks.restarted()
            latest_ns = odometer.latest_ns  # Ingest._update_checks where OdometerChecks.update finds a fix
            if queue and latest_ns is not None and queue[0].stamp_ns <= latest_ns:
                update_checks()
            # Ingest._settle(SPEED, event, None), its release below
            accepted[SPEED] += 1
            consecutive[SPEED] = 0
        elif kind is GnssFix:
            t, lat, lon = event.stamp_ns, event.lat, event.lon
            newest = clock.newest_ns
            last = latest.get(GNSS)
            variance = event.horizontal_variance
            if not (
                (newest is None or newest - t <= age_ns)  # TimeBase.check: not stale,
                and (last is None or t > last)  # in order
                and event.status >= 0  # fix_problem: a fix,
                and -inf < lat < inf  # finite (NaN fails every comparison)
                and -inf < lon < inf
                # MapMatcher._variance: nothing to repair
                and (not use_cov or (-inf < variance < inf and variance > 0.0) or not event.covariance_known)
            ):
                out += ingest.add(event)
                (clock, latest, period, pairer, pending, speeds, fixes, powers, steps, checks, queue, direction,
                 odometer, matcher, anchor, release, deferred) = _parts(ingest)  # fmt: skip
                continue
            received[GNSS] += 1
            # TimeBase.check: a sample in order
            if last is not None:
                period[GNSS] = t - last
            latest[GNSS] = t
            silence = clock.silence_ns = t - newest if newest is not None else 0
            if newest is None or t > newest:
                clock.newest_ns = t
            # MapMatcher.match(event, late=False): written out while tracking and inside the window
            anchor_t, last_fix_t = anchor.t, matcher.last_fix_t
            reason = None
            if (
                anchor_t is not None
                and (last_fix_t is None or abs(t - last_fix_t) / NS <= reacquire_gap)
                and silence <= run_gap_ns
            ):
                variance = variance if use_cov and -inf < variance < inf and variance > 0.0 else position_var
                # MapMatcher._window(t)
                anchor_s, anchor_v = anchor.s, anchor.v
                dt = (t - anchor_t) / NS
                last_speed = pairer.last_speed  # Pairer.speed_near(t, anchor_v)
                if last_speed is not None and abs(t - last_speed.stamp_ns) <= age_ns:
                    v = last_speed.v
                else:
                    v = pairer.speed_near(t, anchor_v)
                travel = 0.5 * (anchor_v + v) * dt
                sign = direction.direction
                since_fix = (t - (last_fix_t if last_fix_t is not None else anchor_t)) / NS
                gate = gate0 + gate_growth * abs(since_fix)
                s_pred = anchor_s + sign * travel
                lo, hi = s_pred - gate, s_pred + gate
                if (v if v > anchor_v else anchor_v) <= reverse_max:
                    other = anchor_s - sign * travel
                    lo, hi = min(lo, other - gate), max(hi, other + gate)
                if locate is not None:
                    s, d = locate(lat, lon, lo, hi)  # project(*enu(lat, lon), lo, hi) in C
                else:
                    east, north = enu(lat, lon)
                    s, d = project(east, north, lo, hi)
                if d <= max_cross:
                    if matcher.candidates:
                        matcher.candidates.clear()
                    # MapMatcher._accept(MatchedFix(t, s, variance, d), checks=True)
                    fix = MatchedFix(t, s, variance, d)
                    if fixes and t < fixes[-1].stamp_ns:
                        pairer.add_fix(fix)  # put in order; not for the checks
                    else:
                        fixes.append(fix)
                        queue.append(fix)
                    if last_fix_t is None or t > last_fix_t:
                        matcher.last_fix_t = t
                    if t >= anchor_t:
                        anchor.at_fix(fix, pairer.speed_near(t, anchor_v))
                else:
                    reason = matcher.match(event, False)  # the rest of match: the whole line
            else:
                reason = matcher.match(event, False)  # not tracking: (re-)acquisition
            if reason is not None:
                out += ingest._settle(GNSS, event, reason)
                (clock, latest, period, pairer, pending, speeds, fixes, powers, steps, checks, queue, direction,
                 odometer, matcher, anchor, release, deferred) = _parts(ingest)  # fmt: skip
                continue
            latest_ns = odometer.latest_ns  # Ingest._update_checks where OdometerChecks.update finds a fix
            if queue and latest_ns is not None and queue[0].stamp_ns <= latest_ns:
                update_checks()
            # Ingest._settle(GNSS, event, None), its release below
            accepted[GNSS] += 1
            consecutive[GNSS] = 0
        else:
            out += ingest.add(event)
            (clock, latest, period, pairer, pending, speeds, fixes, powers, steps, checks, queue, direction,
             odometer, matcher, anchor, release, deferred) = _parts(ingest)  # fmt: skip
            continue
        if reset_watch.behind:
            reset_watch.clear()  # a sample of the current time base: no clock reset
        # Ingest._release
        while pending:
            t = pending[0].stamp_ns
            # TimeBase.ready(t)
            if not clock.newest_ns - t >= pair_wait_ns:
                gnss = latest.get(GNSS)
                if gnss is None:
                    break
                if gnss < t:
                    gnss_period = period.get(GNSS)
                    if gnss_period is None or gnss + gnss_period - t < t - gnss:
                        break
                if POWER in latest and not clock._stream_ready(POWER, t, required=False):
                    break
            sample = pending.popleft()
            if direction.direction == BACKWARD:
                m = release(sample)  # reversing: dropped
                if m is not None:
                    out.append(m)
                continue
            # Releaser.release(sample) running forward, its _locate and _measurement
            t, v = sample.stamp_ns, sample.v
            if clock.released_ns is None or t > clock.released_ns:  # TimeBase.release(t)
                clock.released_ns = t
            fix = nearest_in_order(fixes, t, pair_ns)  # pairer.nearest_fix(t)
            if fix is not None:
                t_fix = fix.stamp_ns
                dt_fix = (t - t_fix) / NS
                s = fix.s + 0.5 * (pairer.speed_at(t_fix, v) + v) * dt_fix
                s_var = fix.variance + (speed_std * dt_fix) ** 2
            else:
                reckoned = anchor.dead_reckon(t, v, speed_std, max_dead_reckoning)
                if reckoned is None:
                    stats.drop(SPEED, NO_POSITION)
                    continue
                s, s_var = reckoned
            s = 0.0 if s < 0.0 else length if s > length else s
            # Anchor.at_measurement(t, s, v, fix)
            anchor.t, anchor.s, anchor.v = t, s, v
            if fix is not None:
                anchor.base_t, anchor.base_var = fix.stamp_ns, fix.variance
            else:
                stats.dead_reckoned += 1
            run_id, dt = segment(t, v)
            power = nearest_in_order(powers, t, power_pair_ns) if powers else None  # pairer.nearest_power(t)
            if deferred is None:
                track_force, limit, tunnel_fraction, track_force_integral = terms_at(s)
            else:
                track_force = limit = tunnel_fraction = track_force_integral = nan  # Ingest.fill_terms sets them
            m = Measurement(  # positional, in field order (Releaser._measurement)
                t,
                s,
                v,
                track_force,
                dt,
                run_id,
                fix is not None,
                s_var,
                speed_variance,
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
            stats.published += 1
            out.append(m)
        # Pairer.trim(clock)
        horizon = pending[0].stamp_ns if pending else latest.get(SPEED)
        newest = clock.newest_ns
        if newest is not None:
            oldest_useful = newest - age_ns_int
            horizon = oldest_useful if horizon is None or oldest_useful > horizon else horizon
        if horizon is None:
            continue
        keep_from = horizon - keep_ns
        while len(fixes) > 1 and fixes[1].stamp_ns <= keep_from:
            fixes.popleft()
        if powers:
            while len(powers) > 1 and powers[1].stamp_ns <= keep_from:
                powers.popleft()
        while len(speeds) > 2 and speeds[1].stamp_ns <= keep_from:
            speeds.popleft()
    return out
