"""A simulated fleet with known truth: units with their own running resistance drifting over a year, a few faulty
units whose resistance rises (a dragging brake, a damaged fairing), runs spread over the dates.

Unit u's true Davis coefficients on day t (years from the start, 0..1) are the train file's times
    f_u(t) = b_u * (1 + season * cos(2 pi t) + d_u * t) + fault_u * t
with b_u = 1 + U(-spread, spread) (the unit's own resistance), d_u = U(-drift, drift) per year (its slow
drift), season the fleet's common seasonal swing (winter higher) and fault_u = ``fault_rise`` for the faulty
units, 0 for the others. Every run is simulated by ``train_calib.sim`` (a sampled driver, the given sensors) and
written as ``train-calib simulate`` does (bag + truth files); DIR/manifest.csv lists the runs (with a ``true_r80``
column the fleet command ignores) and DIR/fleet_truth.json the units' truth (mean true r(80 km/h) over its runs,
faulty or not). The bytes depend on the seed only.
"""

from __future__ import annotations

import csv
import json
import math
from dataclasses import asdict, dataclass
from datetime import datetime, timedelta, timezone
from pathlib import Path
from typing import Any

import numpy as np

from ..paths import track_file, train_file
from ..track import load_track
from ..train import Davis, load_train

REFERENCE_DISTANCE_M = 32103.0  # as train-calib simulate: coasting 2.5-10 min on this distance


@dataclass(frozen=True)
class FleetSpec:
    units: int = 8
    faulty: int = 2
    runs_per_unit: int = 12
    seed: int = 0
    track: str = "intercity_32km"
    train: str = "virm6"
    period_s: float = 10.0
    start: str = "2025-01-06"
    days: float = 365.0
    spread: float = 0.08  # units' own resistance: +- this fraction
    drift: float = 0.02  # per year, +- this fraction
    season: float = 0.03  # common seasonal swing, fraction
    fault_rise: float = 0.35  # faulty units: rise over the year, fraction of the manufacturer's r(v)
    drivers: int = 6


def factor(spec: FleetSpec, base: float, drift: float, faulty: bool, t_years: float) -> float:
    """The unit's resistance factor on the manufacturer's values at t (years from the start)."""
    f = base * (1.0 + spec.season * math.cos(2.0 * math.pi * t_years) + drift * t_years)
    return f + (spec.fault_rise * t_years if faulty else 0.0)


def simulate_fleet(out: str | Path, spec: FleetSpec, *, quiet: bool = True) -> Path:
    """Write the fleet's bags, truth files, manifest.csv and fleet_truth.json to ``out``; returns the manifest."""
    from ..sim import DriverParams, SensorParams, simulate_run, write_run
    from ..sim.simulator import resolve_stations

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    track = load_track(track_file(spec.track))
    train = load_train(train_file(spec.train))
    _, s0, _, s1 = resolve_stations(track, None, None)
    scale = min(1.0, (s1 - s0) / REFERENCE_DISTANCE_M)
    start = datetime.fromisoformat(spec.start).replace(tzinfo=timezone.utc)
    rng_fleet = np.random.default_rng([spec.seed, 2026])
    faulty = set(rng_fleet.choice(spec.units, size=spec.faulty, replace=False).tolist()) if spec.faulty else set()
    sensors = SensorParams(gnss_period_s=spec.period_s, speed_period_s=spec.period_s)
    v80 = 80.0 / 3.6
    manuf80 = float(train.davis(v80))
    rows: list[dict[str, Any]] = []
    units: dict[str, dict[str, Any]] = {}
    for u in range(spec.units):
        name = f"unit{u:03d}"
        base = 1.0 + rng_fleet.uniform(-spec.spread, spec.spread)
        drift = rng_fleet.uniform(-spec.drift, spec.drift)
        true80 = []
        for k in range(spec.runs_per_unit):
            rng = np.random.default_rng([spec.seed, u, k])
            t_years = (k + rng.uniform(0.0, 1.0)) / spec.runs_per_unit * spec.days / 365.25
            when = start + timedelta(days=t_years * 365.25)
            f = factor(spec, base, drift, u in faulty, t_years)
            resistance = Davis(*(c * f for c in train.davis.as_tuple()))
            driver = DriverParams.sample(rng, train=train, coast_range_s=(150.0 * scale, 600.0 * scale))
            sim = simulate_run(track, train, driver=driver, sensors=sensors, rng=rng, resistance=resistance,
                               start_time_ns=int(when.timestamp()) * 1_000_000_000, seed=[spec.seed, u, k])  # fmt: skip
            sim.meta["command"] = f"train-calib simulate-fleet ({json.dumps(asdict(spec))}), unit {u}, run {k}"
            bag_name = f"{name}_{k:03d}"
            write_run(sim, out / "bags", bag_name)
            true80.append(float(resistance(v80)))
            driver_name = f"driver{int(rng.integers(spec.drivers)):02d}"
            rows.append({"bag": f"bags/{bag_name}", "track": spec.track, "train": spec.train, "unit": name,
                         "date": when.isoformat().replace("+00:00", "Z"), "driver": driver_name,
                         "line": track.name, "true_r80": f"{true80[-1]:.6g}"})  # fmt: skip
            if not quiet:
                print(f"{out / 'bags' / bag_name}: {name} {when.date()} true r(80 km/h) {true80[-1] * 1000:.2f} mN/kg")
        units[name] = {"faulty": u in faulty, "base_factor": base, "drift_per_year": drift,
                       "true_r80_mean": float(np.mean(true80)), "true_r80_first": true80[0],
                       "true_r80_last": true80[-1]}  # fmt: skip
    manifest = out / "manifest.csv"
    with manifest.open("w", newline="", encoding="utf-8") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    truth = {"spec": asdict(spec), "manufacturer_r80": manuf80, "units": units,
             "faulty": sorted(n for n, u in units.items() if u["faulty"])}  # fmt: skip
    (out / "fleet_truth.json").write_text(json.dumps(truth, indent=1) + "\n", encoding="utf-8")
    return manifest
