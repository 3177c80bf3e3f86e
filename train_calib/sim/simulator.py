"""simulate_run: a realistic run with known truth and its sensor streams."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from .. import __version__
from ..errors import ConfigError
from ..physics import KMH
from ..track import Track
from ..train import Davis, TrainSpec
from .drive import Drive, DriveResult
from .driver import DriverParams
from .limits import SpeedCeiling
from .model import MotionModel, TrackTerms
from .phases import BRAKING, COASTING, CRUISING, REGIME_NAMES, TRACTION, UNKNOWN
from .run import GnssStream, PowerStream, SimulatedRun, SpeedStream, Trajectory
from .sensors import SensorParams, gnss_errors, pantograph_power, quantise_speed, sample_times_ns

DEFAULT_START_NS = 1_583_132_400_000_000_000
"""2020-03-02 07:00:00 UTC: the first month of the data of Cunillera et al. (2022)."""


def resolve_stations(
    track: Track, start_station: str | None, stop_station: str | None
) -> tuple[str, float, str, float]:
    """(start name, s, stop name, s): defaults are the first station and the next one after it."""
    stations = sorted(track.stations, key=lambda st: st.s_m)
    where = track.source or track.name
    if len(stations) < 2 and (start_station is None or stop_station is None):
        raise ConfigError(where, "stations", f"needs at least two stations to run between, found {len(stations)}")

    def find(name: str, key: str):
        for st in stations:
            if st.name == name:
                return st
        known = ", ".join(repr(st.name) for st in stations)
        raise ConfigError(where, key, f"no station named {name!r} (stations: {known})")

    start = find(start_station, "start_station") if start_station is not None else stations[0]
    if stop_station is not None:
        stop = find(stop_station, "stop_station")
    else:
        later = [st for st in stations if st.s_m > start.s_m]
        if not later:
            raise ConfigError(where, "stations", f"no station after {start.name!r} to run to")
        stop = later[0]
    if stop.s_m <= start.s_m:
        raise ConfigError(
            where,
            "stop_station",
            f"{stop.name!r} (s={stop.s_m:g} m) must lie beyond {start.name!r} (s={start.s_m:g} m)",
        )
    return start.name, start.s_m, stop.name, stop.s_m


def make_model(train: TrainSpec, terms: TrackTerms, resistance: Davis, driver: DriverParams) -> MotionModel:
    """The run's physics: the train's envelope scaled by nothing (the driver scales), true resistance, wind."""
    return MotionModel(
        terms,
        c0=train.max_tractive_effort,
        c2=train.max_tractive_power,
        adhesive_mass_fraction=train.adhesive_mass_fraction,
        rotating_mass_factor=train.rotating_mass_factor,
        r0=resistance.r0,
        r1=resistance.r1,
        r2=resistance.r2,
        tunnel_factor=train.tunnel_factor,
        wind=driver.wind,
    )


def simulate_run(
    track: Track,
    train: TrainSpec,
    *,
    driver: DriverParams,
    sensors: SensorParams,
    rng: np.random.Generator,
    resistance: Davis | None = None,
    start_station: str | None = None,
    stop_station: str | None = None,
    start_time_ns: int = DEFAULT_START_NS,
    dense_dt_s: float = 0.5,
    seed: Any = None,
) -> SimulatedRun:
    """Drive from a stop to the next (or the named) stop and record it.

    ``resistance``: the TRUE Davis coefficients of this run (default: the train file's). ``rng``
    draws the sensor offsets and noise (the driver's randomness is in ``driver``, see
    :meth:`DriverParams.sample`). ``start_time_ns``: the recording start (pre-roll before departure).
    """
    resistance = resistance if resistance is not None else train.davis
    start_name, s0, stop_name, s1 = resolve_stations(track, start_station, stop_station)
    terms = TrackTerms(track, train.length_m)
    model = make_model(train, terms, resistance, driver)
    ceiling = SpeedCeiling(track, train.length_m, s0, s1, train.max_speed_kmh * KMH)
    result = Drive(model, ceiling, driver, s0, s1, pre_roll_s=sensors.pre_roll_s, post_roll_s=sensors.post_roll_s).run()

    start_ns = int(start_time_ns)
    end_ns = start_ns + round(result.t_end * 1e9)
    eta = sensors.power_efficiency if sensors.power_efficiency > 0 else train.transmission_efficiency

    def truth_at(t_ns: np.ndarray) -> Trajectory:
        t_rel = (t_ns - start_ns) * 1e-9
        ev = result.evaluate(t_rel)
        s, v, u = ev["s"], ev["v"], ev["u"]
        consumed, regenerated = pantograph_power(
            u,
            v,
            effective_mass_kg=train.effective_mass_kg,
            efficiency=eta,
            max_power_w=train.max_tractive_power * train.effective_mass_kg,
            electric_brake_fraction=sensors.electric_brake_fraction,
            electric_brake_min_ms=sensors.electric_brake_min_kmh * KMH,
            auxiliary_w=train.auxiliary_power_kw * 1e3,
        )
        n = t_ns.size
        return Trajectory(
            t_ns=t_ns.astype(np.int64),
            s=s,
            v=v,
            a=ev["a"],
            u=u,
            regime=ev["regime"],
            r0=np.full(n, model.r0),
            r1=np.full(n, model.r1),
            r2=model.r2_in_force(t_rel),
            track_force=terms.g_vec(s),
            tunnel_fraction=terms.tunnel_vec(s),
            speed_limit=np.asarray(track.speed_limit_at(s), dtype=float) if n else np.zeros(0),
            power_consumed=consumed,
            power_regenerated=regenerated,
        )

    # sensor sample times (offsets drawn in a fixed order)
    t_gnss = sample_times_ns(start_ns, end_ns, sensors.gnss_period_s, sensors.gnss_offset_s, rng)
    t_speed = sample_times_ns(start_ns, end_ns, sensors.speed_period_s, sensors.speed_offset_s, rng)
    with_power = sensors.power_period_s > 0
    t_power = (
        sample_times_ns(start_ns, end_ns, sensors.power_period_s, sensors.power_offset_s, rng) if with_power else None
    )

    # GNSS
    s_g, _v_g, _ = result.record.evaluate((t_gnss - start_ns) * 1e-9)
    e_err, n_err = gnss_errors((t_gnss - start_ns) * 1e-9, sensors.gnss_noise_m, sensors.gnss_correlation_s, rng)
    east, north = track.enu_at(s_g)
    lat, lon = track.frame.to_geodetic(east + e_err, north + n_err)
    status = np.zeros(t_gnss.size, dtype=np.int8)
    if sensors.gnss_tunnel_outage:
        for tun in track.tunnels:
            status[(s_g >= tun.start_m) & (s_g <= tun.end_m)] = -1
    if sensors.gnss_dropout > 0:
        status[rng.random(t_gnss.size) < sensors.gnss_dropout] = -1
    lat = np.where(status < 0, np.nan, lat)
    lon = np.where(status < 0, np.nan, lon)
    gnss = GnssStream(
        t_gnss, np.asarray(lat, float), np.asarray(lon, float), status, sensors.gnss_noise_m, s_g, e_err, n_err
    )

    # speed (the truth rows are the speed stamps)
    if sensors.speed_dropout > 0:
        t_speed = t_speed[rng.random(t_speed.size) >= sensors.speed_dropout]
    truth = truth_at(t_speed)
    speed = SpeedStream(t_speed, quantise_speed(truth.v, sensors.speed_noise_kmh, sensors.speed_quantum_kmh, rng))

    # power
    power = None
    if t_power is not None:
        if sensors.power_dropout > 0:
            t_power = t_power[rng.random(t_power.size) >= sensors.power_dropout]
        pt = truth_at(t_power)
        noise = 1.0 + sensors.power_noise * rng.standard_normal((2, t_power.size))
        power = PowerStream(
            t_power, np.maximum(pt.power_consumed * noise[0], 0.0), np.maximum(pt.power_regenerated * noise[1], 0.0)
        )

    n_dense = math.floor(result.t_end / dense_dt_s) + 1
    t_dense = start_ns + np.round(np.arange(n_dense) * dense_dt_s * 1e9).astype(np.int64)
    dense = truth_at(t_dense)

    meta = {
        "format": "train_calib.sim/1",
        "version": __version__,
        "seed": seed,
        "track": {"name": track.name, "file": _basename(track.source), "description": track.description},
        "train": {
            "name": train.name,
            "file": _basename(train.source),
            "length_m": train.length_m,
            "mass_t": train.mass_t,
            "rotating_mass_factor": train.rotating_mass_factor,
            "max_tractive_effort": train.max_tractive_effort,
            "max_tractive_power": train.max_tractive_power,
            "max_brake_decel": train.max_brake_decel,
            "transmission_efficiency": train.transmission_efficiency,
            "tunnel_factor": train.tunnel_factor,
            "manufacturer_davis": {"r0": train.davis.r0, "r1": train.davis.r1, "r2": train.davis.r2},
        },
        "resistance": {"r0": resistance.r0, "r1": resistance.r1, "r2": resistance.r2},
        "driver": _jsonable(driver.as_dict()),
        "sensors": _jsonable(sensors.as_dict()),
        "power_efficiency": eta,
        "start_station": start_name,
        "stop_station": stop_name,
        "start_s": s0,
        "stop_s": s1,
        "start_time_ns": start_ns,
        "departure_time_ns": start_ns + round(result.t_departure * 1e9),
        "arrival_time_ns": start_ns + round(result.t_arrival * 1e9),
        "end_time_ns": end_ns,
        "dense_dt_s": dense_dt_s,
        "summary": summarise(result, gnss, speed, power),
    }
    return SimulatedRun(truth=truth, dense=dense, gnss=gnss, speed=speed, power=power, meta=meta)


def regime_intervals(result: DriveResult) -> list[tuple[int, float, float]]:
    """(regime, t_start, t_end) of the run, merged over consecutive steps (s since recording start)."""
    arr = result.record.arrays()
    out: list[tuple[int, float, float]] = []
    for x0, x1, seg in zip(arr["x0"], arr["x1"], arr["seg"]):
        reg = result.phases[int(seg)].regime
        if out and out[-1][0] == reg and abs(out[-1][2] - x0) < 1e-6:
            out[-1] = (reg, out[-1][1], float(x1))
        else:
            out.append((reg, float(x0), float(x1)))
    return out


def summarise(result: DriveResult, gnss: GnssStream, speed: SpeedStream, power: PowerStream | None) -> dict:
    intervals = regime_intervals(result)
    moving = [(r, max(a, result.t_departure), min(b, result.t_arrival)) for r, a, b in intervals]
    moving = [(r, a, b) for r, a, b in moving if b > a]
    total = result.t_arrival - result.t_departure
    share = {REGIME_NAMES[k]: 0.0 for k in (TRACTION, CRUISING, COASTING, BRAKING)}
    for r, a, b in moving:
        if r != UNKNOWN:
            share[REGIME_NAMES[r]] += (b - a) / total
    last_coast = [b - a for r, a, b in moving if r == COASTING]
    last_brake = [b - a for r, a, b in moving if r == BRAKING]
    s_end, _, _ = result.record.evaluate(np.array([result.t_arrival]))
    v_max = float(np.max(result.record.evaluate(np.linspace(result.t_departure, result.t_arrival, 4001))[1]))
    return {
        "run_time_s": total,
        "distance_m": result.s_stop - result.s_start,
        "stop_error_m": float(s_end[0] - result.s_stop),
        "max_speed_kmh": v_max / KMH,
        "planned_coast_point_s_m": result.s_coast if math.isfinite(result.s_coast) else None,
        "final_coast_s": last_coast[-1] if last_coast else 0.0,
        "final_brake_s": last_brake[-1] if last_brake else 0.0,
        "regime_share": share,
        "gnss_fixes": int(np.sum(gnss.status >= 0)),
        "gnss_no_fix": int(np.sum(gnss.status < 0)),
        "speed_samples": int(speed.t_ns.size),
        "power_samples": int(power.t_ns.size) if power is not None else 0,
        "driver_events": [[round(t, 6), e] for t, e in result.events],
    }


def _basename(path: str) -> str:
    return path.replace("\\", "/").rsplit("/", 1)[-1] if path else ""


def _jsonable(values: dict) -> dict:
    return {k: (list(v) if isinstance(v, tuple) else v) for k, v in values.items()}
