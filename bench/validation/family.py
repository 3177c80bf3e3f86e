"""The estimator's validation family: simulated runs with known truth, split into a tune and a report half.

Each family is a few runs (one seed each) of one driving style, sensor set, train and track. A run's true
resistance is the train file's Davis coefficients times a common factor of 0.7-0.9 or 1.1-1.3 (random
sign) with a per-coefficient jitter of +-4 % (bench/validation/README.md). Runs with an even index are the
``tune`` half, odd ones the ``report`` half.

Every run is written to the cache directory (default ``build/validation/family``, gitignored) as a
rosbag2 MCAP bag ``NAME/`` plus ``NAME.validation-truth.json`` in the format of the external runs of
``../shared/validation/runs`` (r0, r1, r2 in N/kg of effective mass; 1 Hz arrays ``t`` in s from the first
message, ``s`` m, ``v`` m/s, ``a`` m/s^2, ``u`` N/kg, ``regime`` 0-4 physical per sample), and listed in
``runs.csv`` with its family and split. A run is regenerated only when its files are missing; the bytes
depend on the seeds only.

    .venv/bin/python bench/validation/family.py [--out DIR] [--families NAME ...] [--force] [--jobs 2]
"""

from __future__ import annotations

import argparse
import csv
import itertools
import json
import math
import shutil
import sys
import time
import zlib
from collections.abc import Sequence
from dataclasses import dataclass, field
from functools import lru_cache
from multiprocessing import Pool
from pathlib import Path
from typing import Any

import numpy as np

from train_calib.paths import track_file, train_file
from train_calib.sim import COASTING, UNKNOWN, DriverParams, SensorParams, SimulatedRun, simulate_run
from train_calib.sim.truthio import write_bag
from train_calib.track import Track, load_track
from train_calib.train import Davis, TrainSpec, load_train

HERE = Path(__file__).resolve().parent
REPO = HERE.parent.parent
TTOBENCH = HERE / "ttobench"
DEFAULT_OUT = REPO / "build" / "validation" / "family"
BASE_SEED = 19  # issue 19
TRUTH_SUFFIX = ".validation-truth.json"
CSV_COLUMNS = (
    "bag",
    "track",
    "train",
    "driving",
    "gnss_period_s",
    "speed_period_s",
    "speed_resolution_kmh",
    "family",
    "split",
    "power_period_s",
    "legs",
)
REFERENCE_DISTANCE_M = 32103.0  # as train-calib simulate: coasting 2.5-10 min on this distance
DWELL_RANGE_S = (30.0, 60.0)  # stop-to-stop service: dwell at each intermediate stop


# -- the families ------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class SensorSet:
    """Sampling of one family: periods in s, speed resolution in km/h, GNSS noise in m per axis."""

    name: str
    gnss_period_s: float
    speed_period_s: float
    speed_quantum_kmh: float
    gnss_shift_s: tuple[float, float] = (0.0, 0.0)  # GNSS offset after the speed grid, s (uniform range)
    gnss_noise_m: float = 4.0


SENSORS = {
    "10s": SensorSet("10s", 10.0, 10.0, 1.0, (0.0, 10.0)),
    "1hz_gnss2s": SensorSet("1hz_gnss2s", 2.0, 1.0, 1.0, (0.1, 0.9)),
    "1hz_fine": SensorSet("1hz_fine", 1.0, 1.0, 0.1, (0.1, 0.9)),
}


@dataclass(frozen=True)
class Family:
    """One condition of the validation family (a driving style on a train, track and sensor set)."""

    name: str
    track: str  # bundled track name, or a file name in bench/validation/ttobench
    train: str  # bundled train name, or a file name in bench/validation/ttobench
    driving: str  # hold | cycles | eco | hard
    sensors: str  # a key of SENSORS
    power: bool = False  # traction power at 1 Hz
    stops: bool = False  # stop-to-stop over every station of the track (several run_ids in one bag)
    runs: int = 8
    note: str = ""


FAMILIES: tuple[Family, ...] = (
    Family(
        "hold_10s",
        "intercity_32km",
        "virm6",
        "hold",
        "10s",
        note="held at the limit, long final coast, then 40 km/h held for 600 m before the stop",
    ),
    Family(
        "hold_1hz",
        "intercity_32km",
        "virm10",
        "hold",
        "1hz_gnss2s",
        note="as hold_10s at 1 Hz speed, GNSS every 2 s a fraction of a second after the speeds",
    ),
    Family(
        "cycles_1hz",
        "dense_corridor_14km",
        "virm4",
        "cycles",
        "1hz_fine",
        note="traction/coast cycles around the target on a mixed-speed line, 1 Hz at 0.1 km/h",
    ),
    Family(
        "cycles_power_1hz",
        "tunnel_line_37km",
        "icrm",
        "cycles",
        "1hz_gnss2s",
        power=True,
        note="cycles in tunnels, 1 Hz speed at 1 km/h, GNSS 2 s, traction power 1 Hz",
    ),
    Family(
        "hard_1hz",
        "tunnel_line_37km",
        "icrm",
        "hard",
        "1hz_gnss2s",
        note="full traction, brakes at the train's maximum, no coasting before the final brake",
    ),
    Family(
        "hold_power_vasteras",
        "track_vasteras.yaml",
        "train_kiss.yaml",
        "hold",
        "1hz_fine",
        power=True,
        note="real profile (TTOBench), double-deck EMU held at the limit, power 1 Hz, 0.1 km/h",
    ),
    Family(
        "hard_vasteras_loco",
        "track_vasteras.yaml",
        "train_loco.yaml",
        "hard",
        "10s",
        note="real profile, locomotive-hauled, hard traction and braking, 10 s",
    ),
    Family(
        "eco_stadelhofen",
        "track_stadelhofen.yaml",
        "train_kiss.yaml",
        "eco",
        "10s",
        stops=True,
        runs=20,  # 60 samples, 2 short coasts a run: with 4 a half, one sample more or less moved a median 5 points
        note="real profile, 3 interstations with dwell, coasting before every stop, 10 s",
    ),
    Family(
        "eco_metro_yizhuang",
        "track_yizhuang.yaml",
        "train_metro.yaml",
        "eco",
        "1hz_gnss2s",
        power=True,
        stops=True,
        runs=6,
        note="real metro profile, 13 interstations with dwell in one bag, power 1 Hz",
    ),
)


@dataclass(frozen=True)
class RunSpec:
    """One run of a family: index k (seed [BASE_SEED, crc32(family), k]) and its split."""

    family: Family
    k: int

    @property
    def name(self) -> str:
        return f"{self.family.name}_{self.k:02d}"

    @property
    def split(self) -> str:
        return split_of(self.k)

    @property
    def seed(self) -> list[int]:
        return [BASE_SEED, zlib.crc32(self.family.name.encode()), self.k]


def split_of(k: int) -> str:
    """The deterministic split: even run indices tune, odd ones report."""
    return "tune" if k % 2 == 0 else "report"


def all_specs(families: Sequence[Family] = FAMILIES) -> list[RunSpec]:
    """Every run of the given families, in family order."""
    return [RunSpec(f, k) for f in families for k in range(f.runs)]


# -- files ---------------------------------------------------------------------------------------------------
@lru_cache(maxsize=32)
def cached_track(path: Path) -> Track:
    """load_track, once per process and file."""
    return load_track(path)


@lru_cache(maxsize=32)
def cached_train(path: Path) -> TrainSpec:
    """load_train, once per process and file."""
    return load_train(path)


def resolve_track(name: str) -> Path:
    """A bundled track name or a file of bench/validation/ttobench (or any path)."""
    local = TTOBENCH / name
    return local if local.is_file() else Path(track_file(name))


def resolve_train(name: str) -> Path:
    """A bundled train name or a file of bench/validation/ttobench (or any path)."""
    local = TTOBENCH / name
    return local if local.is_file() else Path(train_file(name))


def rel(path: Path) -> str:
    """Path relative to the repository root where it lies inside it (runs.csv stays portable)."""
    try:
        return str(path.resolve().relative_to(REPO))
    except ValueError:
        return str(path.resolve())


# -- the truth and the driver --------------------------------------------------------------------------------
def true_resistance(train: TrainSpec, rng: np.random.Generator) -> Davis:
    """Train file's Davis x common factor (0.7-0.9 or 1.1-1.3, random sign) x (1 +- U(0, 4 %)) per coefficient."""
    sign = rng.choice([-1.0, 1.0])
    common = 1.0 + sign * rng.uniform(0.1, 0.3)
    jitter = 1.0 + rng.uniform(-0.04, 0.04, size=3)
    r = np.array(train.davis.as_tuple()) * common * jitter
    return Davis(float(r[0]), float(r[1]), float(r[2]))


def make_driver(family: Family, train: TrainSpec, distance_m: float, rng: np.random.Generator) -> DriverParams:
    """The family's driver for one interstation of ``distance_m`` metres."""
    scale = min(1.0, distance_m / REFERENCE_DISTANCE_M)
    if family.driving == "hold":
        d = DriverParams.sample(rng, train=train, coast_range_s=(300.0 * scale, 600.0 * scale), styles=("hold",))
        return d.replace(theta_cruise=float(rng.uniform(0.98, 1.0)))
    if family.driving == "cycles":
        return DriverParams.sample(rng, train=train, coast_range_s=(150.0 * scale, 600.0 * scale), styles=("cycles",))
    if family.driving == "eco":
        d = DriverParams.sample(
            rng, train=train, coast_range_s=(0.02 * distance_m, 0.05 * distance_m), styles=("hold",)
        )
        return d.replace(theta_cruise=float(rng.uniform(0.85, 0.95)))
    if family.driving == "hard":
        b = min(0.9, train.max_brake_decel)
        return DriverParams(
            theta_cruise=float(rng.uniform(0.98, 1.0)),
            traction_fraction=1.0,
            start_ramp_s=float(rng.uniform(1.0, 3.0)),
            reaccel_ramp_s=float(rng.uniform(1.0, 3.0)),
            coast_before_brake_s=0.0,
            b_limit=(b,) * 5,
            b_stop=min(1.0, train.max_brake_decel),
        )
    raise ValueError(f"unknown driving {family.driving!r}")


def make_sensors(
    sset: SensorSet, power: bool, rng: np.random.Generator, pre_roll_s: float, post_roll_s: float, gnss_offset_s: float
) -> SensorParams:
    """Speeds start with the recording (the first message), GNSS ``gnss_offset_s`` later, power at 1 Hz."""
    return SensorParams(
        gnss_period_s=sset.gnss_period_s,
        gnss_noise_m=sset.gnss_noise_m,
        gnss_offset_s=gnss_offset_s,
        speed_period_s=sset.speed_period_s,
        speed_quantum_kmh=sset.speed_quantum_kmh,
        speed_offset_s=0.0,
        power_period_s=1.0 if power else 0.0,
        power_offset_s=float(rng.uniform(0.0, 1.0)) if power else -1.0,
        pre_roll_s=pre_roll_s,
        post_roll_s=post_roll_s,
    )


# -- one run (possibly several interstations) ----------------------------------------------------------------
@dataclass
class Leg:
    """One interstation of a run with its recording start (ns)."""

    run: SimulatedRun
    start_ns: int
    driver: DriverParams


@dataclass
class Streams:
    """The concatenated sensor streams of a bag (what truthio.write_bag reads)."""

    gnss: Any
    speed: Any
    power: Any
    legs: list[Leg] = field(default_factory=list)


def station_pairs(track: Track, stops: bool) -> list[tuple[str, float, str, float]]:
    """(start, s, stop, s) of each interstation: all consecutive stations, or the first two."""
    st = sorted(track.stations, key=lambda x: x.s_m)
    pairs = [(a.name, a.s_m, b.name, b.s_m) for a, b in itertools.pairwise(st)]
    return pairs if stops else pairs[:1]


def grid_ns(sset: SensorSet, power: bool) -> int:
    """Period (ns) on which every leg starts so the streams continue on one grid across legs."""
    periods = [sset.gnss_period_s, sset.speed_period_s] + ([1.0] if power else [])
    return round(max(periods) * 1e9)


def simulate_spec(
    spec: RunSpec,
    start_ns: int = 1_700_000_000_000_000_000,
    truth: Davis | None = None,
    noise_seed: Sequence[int] | None = None,
) -> tuple[Streams, Davis, Track, TrainSpec]:
    """Simulate every interstation of the run with one true resistance and one sensor phase.

    ``truth``: this resistance instead of the one drawn from the seed (the draw is made all the same, so the
    driver and the noise follow from the seed alone; bench/prediction/siblings.py: other runs of one unit).
    ``noise_seed``: the same run (truth, drivers, dwells, sensor phase) with other sensor noise
    (bench/validation/replicates.py): each leg is simulated with the seed's generator as usual, which keeps
    every later draw as it was, then again with the same planned driver and a generator of ``noise_seed``."""
    fam = spec.family
    track = cached_track(resolve_track(fam.track))
    train = cached_train(resolve_train(fam.train))
    rng = np.random.default_rng(spec.seed)
    drawn = true_resistance(train, rng)
    truth = drawn if truth is None else truth
    sset = SENSORS[fam.sensors]
    gnss_offset = float(rng.uniform(*sset.gnss_shift_s)) % sset.gnss_period_s
    pairs = station_pairs(track, fam.stops)
    noise_rng = None if noise_seed is None else np.random.default_rng(list(noise_seed))
    legs: list[Leg] = []
    t0 = start_ns
    grid = grid_ns(sset, fam.power)
    for i, (a, s0, b, s1) in enumerate(pairs):
        last = i == len(pairs) - 1
        pre = 20.0 if i == 0 else 0.0
        post = 20.0 if last else float(rng.uniform(*DWELL_RANGE_S))
        driver = make_driver(fam, train, s1 - s0, rng)
        sensors = make_sensors(sset, fam.power, rng, pre, post, gnss_offset)
        run, driver = simulate_leg(track, train, driver, sensors, rng, truth, (a, b), t0, spec.seed)
        if noise_rng is not None:
            run, _ = simulate_leg(track, train, driver, sensors, noise_rng, truth, (a, b), t0, spec.seed)
        legs.append(Leg(run, t0, driver))
        end_ns = 1 + max(
            int(x.t_ns[-1]) for x in (run.gnss, run.speed, run.power, run.dense) if x is not None and x.t_ns.size
        )
        t0 += math.ceil((end_ns - t0) / grid) * grid
    return concatenate(legs), truth, track, train


def simulate_leg(
    track: Track,
    train: TrainSpec,
    driver: DriverParams,
    sensors: SensorParams,
    rng: np.random.Generator,
    truth: Davis,
    stations: tuple[str, str],
    start_ns: int,
    seed: list[int],
) -> tuple[SimulatedRun, DriverParams]:
    """One interstation; a final coast the driver cannot plan is halved until it can (0 below 5 s).

    The plan fails before the simulator draws from ``rng``, so a retry keeps the run deterministic.
    """
    while True:
        try:
            run = simulate_run(
                track,
                train,
                driver=driver,
                sensors=sensors,
                rng=rng,
                resistance=truth,
                start_station=stations[0],
                stop_station=stations[1],
                start_time_ns=start_ns,
                seed=seed,
            )
            return run, driver
        except ValueError:
            if driver.coast_before_brake_s <= 0.0:
                raise
            half = driver.coast_before_brake_s / 2.0
            driver = driver.replace(coast_before_brake_s=half if half >= 5.0 else 0.0)


def _cat(items: list[Any], cls: type) -> Any:
    """Concatenate dataclass streams field by field (arrays) keeping scalars of the first."""
    if items[0] is None:
        return None
    values = {}
    for name in items[0].__dataclass_fields__:
        first = getattr(items[0], name)
        values[name] = np.concatenate([getattr(x, name) for x in items]) if isinstance(first, np.ndarray) else first
    return cls(**values)


def concatenate(legs: list[Leg]) -> Streams:
    """One bag's streams from the legs, each leg's samples cut before the next leg's recording start."""
    cut: list[SimulatedRun] = []
    for i, leg in enumerate(legs):
        nxt = legs[i + 1].start_ns if i + 1 < len(legs) else None
        cut.append(_before(leg.run, nxt))
    first = cut[0]
    return Streams(
        gnss=_cat([r.gnss for r in cut], type(first.gnss)),
        speed=_cat([r.speed for r in cut], type(first.speed)),
        power=_cat([r.power for r in cut], type(first.power)) if first.power is not None else None,
        legs=legs,
    )


def _before(run: SimulatedRun, limit_ns: int | None) -> SimulatedRun:
    """The run's streams and dense truth restricted to stamps before ``limit_ns`` (all if None)."""
    if limit_ns is None:
        return run

    def keep(stream: Any) -> Any:
        if stream is None:
            return None
        m = stream.t_ns < limit_ns
        return type(stream)(
            **{k: (v[m] if isinstance(v, np.ndarray) and v.shape == m.shape else v) for k, v in stream.__dict__.items()}
        )

    return SimulatedRun(
        run.truth,
        run.dense.select(run.dense.t_ns < limit_ns),
        keep(run.gnss),
        keep(run.speed),
        keep(run.power),
        run.meta,
    )


# -- the truth file ------------------------------------------------------------------------------------------
def truth_1hz(streams: Streams) -> dict[str, list[float]]:
    """1 Hz truth from the dense 0.5 s grids (aligned with whole seconds from the first message).

    ``regime`` is the driver's phase with coasting made physical: every moving sample with u == 0 is
    coasting (3); standing samples are 0.
    """
    first_ns = first_message_ns(streams)
    parts = []
    for leg in streams.legs:
        d = leg.run.dense
        t = (d.t_ns - first_ns) * 1e-9
        on = np.abs(t - np.round(t)) < 1e-6
        parts.append((np.round(t[on]), d.s[on], d.v[on], d.a[on], d.u[on], d.regime[on]))
    t, s, v, a, u, regime = (np.concatenate(c) for c in zip(*parts))
    t, idx = np.unique(t, return_index=True)  # a leg's dense grid may overlap the next leg's start
    s, v, a, u, regime = s[idx], v[idx], a[idx], u[idx], regime[idx].astype(int)
    regime = np.where((v > 0.0) & (u == 0.0), COASTING, regime)
    regime = np.where(v <= 0.0, UNKNOWN, regime)
    keep = t >= 0.0
    return {
        "t": t[keep].tolist(),
        "s": s[keep].tolist(),
        "v": v[keep].tolist(),
        "a": a[keep].tolist(),
        "u": u[keep].tolist(),
        "regime": regime[keep].tolist(),
    }


def first_message_ns(streams: Streams) -> int:
    """Stamp of the bag's first message (ns)."""
    firsts = [int(x.t_ns[0]) for x in (streams.gnss, streams.speed, streams.power) if x is not None and x.t_ns.size]
    return min(firsts)


def n_messages(streams: Streams) -> int:
    """Number of messages in the bag."""
    return sum(int(x.t_ns.size) for x in (streams.gnss, streams.speed, streams.power) if x is not None)


def truth_document(spec: RunSpec, streams: Streams, truth: Davis) -> dict[str, Any]:
    """The ``<bag>.validation-truth.json`` content (format of ../shared/validation/runs, plus family fields)."""
    fam, sset = spec.family, SENSORS[spec.family.sensors]
    d0 = streams.legs[0].driver
    arrays = truth_1hz(streams)
    last_ns = max(int(x.t_ns[-1]) for x in (streams.gnss, streams.speed, streams.power) if x is not None)
    return {
        "r0": truth.r0,
        "r1": truth.r1,
        "r2": truth.r2,
        "theta": d0.theta_cruise,
        "b_limit": float(np.mean(d0.b_limit)),
        "b_stop": d0.b_stop,
        "coast_before_brake_s": [leg.driver.coast_before_brake_s for leg in streams.legs],
        "final_coast_s": [leg.run.meta["summary"]["final_coast_s"] for leg in streams.legs],
        "style": fam.driving,
        "cruise_style": d0.cruise_style,
        "track": rel(resolve_track(fam.track)),
        "train": rel(resolve_train(fam.train)),
        "gnss_period_s": sset.gnss_period_s,
        "speed_period_s": sset.speed_period_s,
        "speed_resolution_kmh": sset.speed_quantum_kmh,
        "gnss_noise_m": sset.gnss_noise_m,
        "power_period_s": 1.0 if fam.power else 0.0,
        "legs": len(streams.legs),
        "family": fam.name,
        "split": spec.split,
        "seed": spec.seed,
        "n_messages": n_messages(streams),
        "duration_s": (last_ns - first_message_ns(streams)) * 1e-9,
        **arrays,
    }


def csv_row(spec: RunSpec) -> dict[str, Any]:
    """The run's row of runs.csv."""
    fam, sset = spec.family, SENSORS[spec.family.sensors]
    return {
        "bag": spec.name,
        "track": rel(resolve_track(fam.track)),
        "train": rel(resolve_train(fam.train)),
        "driving": fam.driving,
        "gnss_period_s": sset.gnss_period_s,
        "speed_period_s": sset.speed_period_s,
        "speed_resolution_kmh": sset.speed_quantum_kmh,
        "family": fam.name,
        "split": spec.split,
        "power_period_s": 1.0 if fam.power else 0.0,
        "legs": len(station_pairs(cached_track(resolve_track(fam.track)), fam.stops)),
    }


def generate(spec: RunSpec, out: Path, force: bool = False) -> tuple[str, float]:
    """Write the run's bag and truth JSON unless both exist; returns (name, seconds spent)."""
    t0 = time.perf_counter()
    bag, truth_path = out / spec.name, out / (spec.name + TRUTH_SUFFIX)
    if bag.is_dir() and truth_path.is_file() and not force:
        return spec.name, 0.0
    for p in (bag, truth_path):
        if p.is_dir():
            shutil.rmtree(p)
        elif p.exists():
            p.unlink()
    out.mkdir(parents=True, exist_ok=True)
    streams, truth, _track, _train = simulate_spec(spec)
    write_bag(streams, bag)  # type: ignore[arg-type]  # reads .gnss, .speed, .power only
    truth_path.write_text(json.dumps(truth_document(spec, streams, truth)) + "\n", encoding="utf-8")
    return spec.name, time.perf_counter() - t0


def _generate_star(args: tuple[RunSpec, Path, bool]) -> tuple[str, float]:
    return generate(*args)


def write_csv(specs: Sequence[RunSpec], out: Path) -> Path:
    """runs.csv of the family (bag, track, train, ..., family, split)."""
    path = out / "runs.csv"
    out.mkdir(parents=True, exist_ok=True)
    with open(path, "w", encoding="utf-8", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(CSV_COLUMNS))
        w.writeheader()
        for spec in specs:
            w.writerow(csv_row(spec))
    return path


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", type=Path, default=DEFAULT_OUT, help="cache directory (default %(default)s)")
    ap.add_argument("--families", nargs="*", help="only these families (default all)")
    ap.add_argument("--force", action="store_true", help="regenerate existing runs")
    ap.add_argument("--jobs", type=int, default=2, help="processes (default 2)")
    args = ap.parse_args(argv)
    fams = [f for f in FAMILIES if not args.families or f.name in args.families]
    if args.families and len(fams) != len(args.families):
        known = ", ".join(f.name for f in FAMILIES)
        print(f"--families: unknown name among {args.families} (known: {known})", file=sys.stderr)
        return 2
    specs = all_specs(fams)
    t0 = time.perf_counter()
    jobs = [(s, args.out, args.force) for s in specs]
    if args.jobs > 1:
        with Pool(args.jobs) as pool:
            done = pool.map(_generate_star, jobs, chunksize=1)
    else:
        done = [_generate_star(j) for j in jobs]
    made = [(n, dt) for n, dt in done if dt > 0]
    write_csv(specs, args.out)
    print(
        f"validation family: {len(specs)} runs in {args.out} ({len(made)} generated, {time.perf_counter() - t0:.1f} s)"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
