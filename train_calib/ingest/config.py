"""The ingest's parameters (``IngestConfig``) and the values derived from them once per config (``Settings``)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from ..errors import ConfigError
from ..params import ParamSet, param
from ..physics import KMH
from ..track import Track
from .records import NS


def positive(default: float, description: str, *, unit: str) -> Any:
    """A parameter that must be greater than 0 (in ``unit``)."""
    return param(default, description, unit=unit, low=0.0, low_open=True)


@dataclass(frozen=True)
class IngestConfig(ParamSet):
    """Parameters of the ingest (gnss_speed_node). SI units; defaults from the papers where they say."""

    position_std: float = positive(4.0, "GNSS position std when the fix carries no covariance (paper: 4 m)", unit="m")
    use_fix_covariance: bool = param(True, "take the horizontal variance from NavSatFix.position_covariance if known")
    speed_std: float = positive(1.0 * KMH, "speed measurement std, gives v_variance (paper: 1 km/h)", unit="m/s")
    max_cross_track: float = positive(30.0, "a fix farther than this from the track polyline is off_track", unit="m")
    continuity_gate: float = param(
        60.0, "half-width of the window around the predicted position where a fix may be matched", unit="m", low=1.0
    )
    continuity_gate_growth: float = param(
        1.0, "the window grows by this per second since the last accepted fix (gaps)", unit="m/s", low=0.0
    )
    reacquire_after: int = param(
        3, "consecutive mutually consistent jump fixes that re-acquire the position there", low=1, high=1000
    )
    reacquire_gap: float = positive(
        600.0,
        "after this long without an accepted fix the position is acquired on the whole line",
        unit="s",
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
    max_sample_age: float = positive(30.0, "a sample older than the newest input by more than this is stale", unit="s")
    max_speed: float = positive(100.0, "speeds above this are implausible", unit="m/s")
    max_acceleration: float = positive(
        3.0,
        "|dv/dt| between consecutive speed samples above this is a speed jump",
        unit="m/s^2",
    )
    max_dead_reckoning: float = positive(600.0, "longest time the position is dead-reckoned from speed", unit="s")
    standstill_speed: float = param(
        0.2, "speeds at or below this are standstill (run segmentation)", unit="m/s", low=0.0
    )
    min_standstill: float = param(
        20.0, "a departure after a standstill at least this long starts a new run", unit="s", low=0.0
    )
    run_gap: float = positive(300.0, "a gap in the speed stream longer than this starts a new run", unit="s")
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
    delay_warn: float = positive(
        0.3,
        "diagnostics WARN when the estimated GNSS delay exceeds this by more than 3 standard deviations",
        unit="s",
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


def start_position(track: Track, config: IngestConfig) -> float | None:
    """s in m of ``config.start_station`` on the track (None when empty); ConfigError for an unknown station."""
    if not config.start_station:
        return None
    try:
        return track.station_named(config.start_station).s_m
    except KeyError:
        names = ", ".join(s.name for s in track.stations) or "none"
        raise ConfigError(
            "parameters",
            "start_station",
            f"track {track.name} has no station {config.start_station!r} (stations: {names})",
        ) from None


class Settings:
    """The config in force and its times in ns that the per-sample checks compare with, computed once per config.

    One object shared by the ingest's parts: ``set`` (a parameter change on the fly) is seen by all of them.
    """

    def __init__(self, config: IngestConfig, start_s: float | None) -> None:
        self.set(config, start_s)

    def set(self, config: IngestConfig, start_s: float | None) -> None:
        self.config = config
        self.start_s = start_s  # m, where the first fix is matched (start_station); None: the whole line
        self.age_ns = config.max_sample_age * NS  # stale beyond this (float ns)
        self.age_ns_int = int(config.max_sample_age * NS)
        self.keep_ns = int(config.pair_tolerance * NS) + NS  # the pairer keeps this much before its horizon
        self.pair_ns = config.pair_tolerance * NS
        self.power_pair_ns = config.power_pair_tolerance * NS
        self.pairing_wait_ns = config.max_pairing_wait * NS
        self.speed_variance = config.speed_std**2  # (m/s)^2, a Measurement's v_variance
