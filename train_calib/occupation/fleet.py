"""Simulated fleets with known truth: runs of each composition, their occupation events and truth.

Each run is driven by ``train_calib.sim``'s realistic driver (:func:`~train_calib.sim.simulator.simulate_run`
with :meth:`~train_calib.sim.driver.DriverParams.sample`: traction at 75-100 % of the envelope, a
start ramp, cruising at theta * limit holding or in traction/coast cycles, b_limit per ATB-EG step,
b_stop, optional coasting before the final brake), with its own Davis coefficients drawn around the
train file's, then turned into the events a train describer logs (:mod:`.generate`) on a clock
with a random start time. A share of runs can be hindered, as by another train: a temporary speed
restriction (a yellow aspect) or a stop at a red signal (a crawl and a wait); the filter must drop them.

The truth kept per run is what the calibration should find: the effective envelope
(traction_fraction * c0, limited by adhesion at standstill, and traction_fraction * c2), the run's
r0, r2 (with the mean wind factor), the braking rates, b_stop and theta.
"""

from __future__ import annotations

import csv
import dataclasses
import math
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import ConfigError
from ..params import ParamSet, param
from ..physics import KMH, adhesion_limit
from ..piecewise import PiecewiseConstant
from ..sim.driver import DriverParams
from ..sim.sensors import SensorParams
from ..sim.simulator import simulate_run
from ..track import Track
from ..train import Davis, TrainSpec, load_train
from .compositions import TrainTypes
from .events import RunEvents
from .generate import occupation_events

HINDRANCES = ("restriction", "stop")
MIN_COAST_S = 2.0
"""Planned coasting shorter than this (s) is set to none (the driver model cannot plan a 0.1 s coast)."""

TRUTH_COLUMNS = (
    "run_id",
    "composition",
    "length_m",
    "hindrance",
    "c0",
    "c2",
    "r0",
    "r1",
    "r2",
    "b_limit",
    "b_limit_min",
    "b_limit_max",
    "b_stop",
    "theta_cruise",
    "traction_fraction",
    "cruise_style",
    "coast_before_brake_s",
    "start_ramp_s",
    "departure_s",
    "note",
)
"""Columns of truth.csv (SI units; b_limit is the mean of the per-step rates, min/max their range)."""


@dataclass(frozen=True)
class FleetConfig(ParamSet):
    """How a simulated fleet varies (defaults: the dense corridor, paper-like driving)."""

    runs_per_composition: int = param(50, "runs of each composition", low=1)
    driver: str = param(
        "realistic",
        "realistic: the sampled driver of train_calib.sim; minimum_time: Besinovic's driver with sampled "
        "c0, c2, b_limit, theta (the calibration's own model class: an identifiability test)",
        choices=("realistic", "minimum_time"),
    )
    c_min_fraction: float = param(0.75, "minimum_time: c0 and c2 = file value * U(x, 1)", low=0.05, high=1.0)
    b_limit_low: float = param(0.3, "minimum_time: b_limit ~ U(low, high)", unit="m/s^2", low=0.01)
    b_limit_high: float = param(0.85, "minimum_time: b_limit ~ U(low, high)", unit="m/s^2", low=0.01)
    theta_low: float = param(0.85, "minimum_time: theta ~ U(low, high)", low=0.3, high=1.2)
    theta_high: float = param(1.02, "minimum_time: theta ~ U(low, high)", low=0.3, high=1.2)
    r0_spread: float = param(0.12, "run r0 = file r0 * U(1 - x, 1 + x)", low=0.0, high=0.9)
    r2_spread: float = param(0.15, "run r2 = file r2 * U(1 - x, 1 + x)", low=0.0, high=0.9)
    coast_min_s: float = param(0.0, "coasting before the final brake, shortest", unit="s", low=0.0)
    coast_max_s: float = param(
        60.0, "coasting before the final brake, longest (dense corridor: little)", unit="s", low=0.0
    )
    wind: bool = param(False, "head/tail wind on r2 (slowly varying)")
    hindered_share: float = param(0.0, "share of runs hindered by another train", low=0.0, high=1.0)
    release_delay_s: float = param(0.0, "track-circuit release delay added to every release", unit="s", low=0.0)
    release_jitter_s: float = param(0.0, "extra uniform random release delay [0, x]", unit="s", low=0.0)
    dense_dt_s: float = param(
        0.25, "time step of the truth trajectory the events are read from", unit="s", low=0.01, high=2.0
    )

    def validate(self, source: str = "FleetConfig", prefix: str = "") -> None:
        if self.coast_max_s < self.coast_min_s:
            raise ConfigError(source, f"{prefix}coast_max_s", "must be at least coast_min_s")
        if self.b_limit_high < self.b_limit_low:
            raise ConfigError(source, f"{prefix}b_limit_high", "must be at least b_limit_low")
        if self.theta_high < self.theta_low:
            raise ConfigError(source, f"{prefix}theta_high", "must be at least theta_low")


@dataclass
class FleetRun:
    """One simulated run: its events and its truth."""

    run_id: str
    composition: str
    events: RunEvents
    truth: dict[str, float | str] = field(default_factory=dict)


def run_truth(
    run_id: str,
    composition: str,
    train: TrainSpec,
    driver: DriverParams,
    resistance: Davis,
    hindrance: str,
    departure_s: float,
) -> dict[str, float | str]:
    """The parameters the calibration should find for this run (see the module docstring)."""
    c0 = train.max_tractive_effort
    if train.adhesive_mass_fraction > 0:
        c0 = min(c0, float(adhesion_limit(0.0, train.adhesive_mass_fraction, train.rotating_mass_factor)))
    frac = driver.traction_fraction
    rates = np.asarray(driver.b_limit, dtype=float)
    return {
        "run_id": run_id,
        "composition": composition,
        "length_m": train.length_m,
        "hindrance": hindrance,
        "c0": frac * c0,
        "c2": frac * train.max_tractive_power,
        "r0": resistance.r0,
        "r1": resistance.r1,
        "r2": resistance.r2 * (1.0 + driver.wind_r2),
        "b_limit": float(np.mean(rates)),
        "b_limit_min": float(np.min(rates)),
        "b_limit_max": float(np.max(rates)),
        "b_stop": driver.b_stop,
        "theta_cruise": driver.theta_cruise,
        "traction_fraction": frac,
        "cruise_style": driver.cruise_style,
        "coast_before_brake_s": driver.coast_before_brake_s,
        "start_ramp_s": driver.start_ramp_s,
        "departure_s": departure_s,
    }


def hindered_track(
    track: Track, kind: str, rng: np.random.Generator, start_s: float, stop_s: float
) -> tuple[Track, dict]:
    """A copy of ``track`` with a temporary restriction (``restriction``: 40 km/h over 400-1200 m) or a
    crawl to a signal (``stop``: 10 km/h over 60 m, where the train then waits) on the open line."""
    lo, hi = start_s + 0.25 * (stop_s - start_s), start_s + 0.75 * (stop_s - start_s)
    if kind == "restriction":
        a = float(rng.uniform(lo, hi - 1200.0))
        b = a + float(rng.uniform(400.0, 1200.0))
        kmh = 40.0
    elif kind == "stop":
        a = float(rng.uniform(lo, hi - 60.0))
        b = a + 60.0
        kmh = 10.0
    else:
        raise ValueError(f"unknown hindrance {kind!r} (known: {', '.join(HINDRANCES)})")
    limit = track.speed_limit
    breaks = np.concatenate((limit.breaks, [a, b]))
    values = np.concatenate((limit.values, [np.nan, np.nan]))
    order = np.argsort(breaks, kind="stable")
    breaks, values = breaks[order], values[order]
    base = limit(breaks)
    new = np.where((breaks >= a) & (breaks < b), np.minimum(base, kmh * KMH), base)
    keep = np.concatenate(([True], np.diff(breaks) > 0))
    changed = dataclasses.replace(track, speed_limit=PiecewiseConstant(breaks[keep], new[keep]))
    return changed, {"kind": kind, "start_m": a, "end_m": b, "kmh": kmh}


def _simulate_one(job) -> FleetRun:
    track, composition, train_path, length_m, b_stop, seed, index, cfg, hindrance = job
    rng = np.random.default_rng(seed)
    train = load_train(train_path)
    if abs(train.length_m - length_m) > 0.5:
        train = dataclasses.replace(train, length_m=length_m)
    if cfg.driver == "minimum_time":
        # the calibration's model class: full (scaled) envelope without adhesion cap, one b_limit, no coasting
        train = dataclasses.replace(
            train,
            max_tractive_effort=train.max_tractive_effort * rng.uniform(cfg.c_min_fraction, 1.0),
            max_tractive_power=train.max_tractive_power * rng.uniform(cfg.c_min_fraction, 1.0),
            adhesive_mass_fraction=0.0,
        )
        driver = DriverParams.minimum_time(
            theta_cruise=float(rng.uniform(cfg.theta_low, cfg.theta_high)),
            b_limit=float(rng.uniform(cfg.b_limit_low, cfg.b_limit_high)),
            b_stop=b_stop,
        )
    else:
        driver = DriverParams.sample(rng, train=train, coast_range_s=(cfg.coast_min_s, cfg.coast_max_s), wind=cfg.wind)
        if driver.coast_before_brake_s < MIN_COAST_S:  # a coast of a fraction of a second is no coast
            driver = driver.replace(coast_before_brake_s=0.0)
    davis = train.davis
    resistance = Davis(
        davis.r0 * rng.uniform(1 - cfg.r0_spread, 1 + cfg.r0_spread),
        davis.r1,
        davis.r2 * rng.uniform(1 - cfg.r2_spread, 1 + cfg.r2_spread),
    )
    stations = sorted(track.stations, key=lambda st: st.s_m)
    run_track, info = track, {}
    if hindrance:
        run_track, info = hindered_track(track, hindrance, rng, stations[0].s_m, stations[-1].s_m)
    sensors = SensorParams(gnss_period_s=600.0, speed_period_s=600.0, pre_roll_s=0.0, post_roll_s=0.0)

    def simulate(drv: DriverParams):
        return simulate_run(
            run_track,
            train,
            driver=drv,
            sensors=sensors,
            rng=rng,
            resistance=resistance,
            start_station=stations[0].name,
            stop_station=stations[-1].name,
            dense_dt_s=cfg.dense_dt_s,
        )

    note = ""
    try:
        sim = simulate(driver)
    except (ValueError, RuntimeError) as exc:
        if driver.coast_before_brake_s <= 0:
            raise
        # the driver model cannot always plan the final coast (e.g. a 50 s coast on a short leg): drive
        # this run without it rather than lose it, and say so in the truth
        note = f"coasting dropped ({type(exc).__name__}: {exc})"
        driver = driver.replace(coast_before_brake_s=0.0)
        sim = simulate(driver)
    t = sim.dense.t
    s = sim.dense.s
    if hindrance == "stop":  # wait at the signal: add the dwell to every time after the crawl's middle
        mid = 0.5 * (info["start_m"] + info["end_m"])
        wait = float(rng.uniform(30.0, 120.0))
        t = np.where(s > mid, t + wait, t)
        info["wait_s"] = wait
    clock0 = float(rng.uniform(0.0, 86_400.0))  # the day's clock at the recording start
    run_id = f"{composition}-{index:03d}"
    events = occupation_events(
        t,
        s,
        length_m,
        track.sections,
        run_id=run_id,
        t0_s=clock0,
        release_delay_s=cfg.release_delay_s,
        release_jitter_s=cfg.release_jitter_s,
        rng=rng,
    )
    departure = clock0 + (sim.meta["departure_time_ns"] - sim.meta["start_time_ns"]) * 1e-9
    label = "" if not hindrance else f"{hindrance} {info['start_m']:.0f}-{info['end_m']:.0f} m"
    truth = run_truth(run_id, composition, train, driver, resistance, label, departure)
    truth["note"] = note
    return FleetRun(run_id, composition, events, truth)


def fleet_jobs(
    track: Track,
    types: TrainTypes,
    config: FleetConfig | None = None,
    *,
    seed: int = 0,
    compositions: Sequence[str] | None = None,
) -> list[tuple]:
    """The runs of :func:`simulate_fleet`, one job each (``simulate_run_job(job)`` simulates one), in order."""
    cfg = config or FleetConfig()
    names = list(compositions) if compositions is not None else types.names
    jobs = []
    seeds = np.random.SeedSequence(seed).spawn(len(names) * cfg.runs_per_composition)
    picker = np.random.default_rng([seed, 7919])  # which runs are hindered, independent of the runs' seeds
    k = 0
    for name in names:
        comp = types[name]
        if not comp.train_file:
            raise ConfigError(types.source, name, "simulating a composition needs its train file")
        for i in range(cfg.runs_per_composition):
            hindrance = ""
            if picker.random() < cfg.hindered_share:
                hindrance = HINDRANCES[int(picker.integers(len(HINDRANCES)))]
            jobs.append(
                (track, name, comp.train_file, comp.length_m, comp.defaults["b_stop"], seeds[k], i, cfg, hindrance)
            )
            k += 1
    return jobs


def simulate_run_job(job: tuple) -> FleetRun:
    """One run of :func:`fleet_jobs`."""
    return _simulate_one(job)


def simulate_fleet(
    track: Track,
    types: TrainTypes,
    config: FleetConfig | None = None,
    *,
    seed: int = 0,
    compositions: Sequence[str] | None = None,
    workers: int = 1,
    progress: Callable[[int, int], None] | None = None,
) -> list[FleetRun]:
    """Simulate ``runs_per_composition`` runs of each composition from the first to the last station.

    Reproducible for a given seed whatever ``workers`` is (one seed per run, spawned in order).
    """
    jobs = fleet_jobs(track, types, config, seed=seed, compositions=compositions)
    out: list[FleetRun] = []
    if workers > 1:
        with ProcessPoolExecutor(max_workers=workers) as pool:
            for i, run in enumerate(pool.map(_simulate_one, jobs, chunksize=4)):
                out.append(run)
                if progress:
                    progress(i + 1, len(jobs))
    else:
        for i, job in enumerate(jobs):
            out.append(_simulate_one(job))
            if progress:
                progress(i + 1, len(jobs))
    return out


def write_truth(path: str | Path, runs: Sequence[FleetRun]) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("w", newline="", encoding="utf-8") as f:
        writer = csv.DictWriter(f, fieldnames=TRUTH_COLUMNS, lineterminator="\n")
        writer.writeheader()
        for run in runs:
            writer.writerow({k: _fmt(run.truth.get(k, "")) for k in TRUTH_COLUMNS})
    return path


def load_truth(path: str | Path) -> dict[str, dict[str, float | str]]:
    """truth.csv -> {run_id: {column: value}} (numbers as float); one-line ConfigError on bad files."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise ConfigError(str(path), "", f"cannot read truth file: {exc.strerror or exc}") from None
    rows = list(csv.DictReader(line for line in text.splitlines() if not line.startswith("#")))
    if not rows:
        raise ConfigError(str(path), "", "no rows")
    missing = [c for c in ("run_id", "composition") if c not in rows[0]]
    if missing:
        raise ConfigError(str(path), "line 1", f"header lacks column(s) {', '.join(missing)}")
    out = {}
    for n, row in enumerate(rows, start=2):
        values: dict[str, float | str] = {}
        for key, value in row.items():
            if key in ("run_id", "composition", "hindrance", "cruise_style", "note"):
                values[key] = value or ""
            else:
                try:
                    values[key] = float(value) if value not in ("", None) else math.nan
                except ValueError:
                    raise ConfigError(str(path), f"line {n}", f"{key} {value!r} is not a number") from None
        out[str(values["run_id"])] = values
    return out


def _fmt(value) -> str:
    if isinstance(value, float):
        return f"{value:.10g}"
    return str(value)
