"""Benchmark of train-calib fleet: runs per second per core, 1 vs 2 workers, local (Dask) vs no Dask, peak memory.

    .venv/bin/python bench/bench_fleet.py [--runs 40] [--memory-runs 10000] [--growth-runs 2000]
        [--parts per_core,stages,scaling,growth,memory] [--out build/bench_fleet]

Bags: a simulated fleet on the 32 km intercity corridor (20-minute runs), at 10 s and at 1 Hz (GNSS and speed),
written once to --out (2 units x 2 runs each; a manifest lists them again and again under other units and dates).

- Per core: ``process_run`` (bag to row, what a worker does) in this process, serially, after one warm-up run:
  runs/s = 1 / mean time. The bag decoding (``cdr_inputs.read_input_events``, what ``run_bag`` reads the inputs
  with) is timed alone to split the time.
- Stages: the CPU time per run of each stage of ``run_bag`` run alone on the previous stage's output (decoding,
  ingest, UKF, regimes, features, window calibration, the whole run's coast regression), the minimum of --repeat
  per bag, the mean over the bags; and ``run_bag`` and ``process_run`` whole (their excess over the sum is the
  glue between the stages and the cache misses of running them interleaved).
- Scaling: ``run_fleet`` on a LocalCluster of 1 and of 2 worker processes (started before the clock runs), --runs
  runs at 1 Hz: the ratio of the rates, and this process's CPU per run (the client, the scheduler and the nannies
  run in it and, on 2 cores, compete with 2 workers).
- Local vs Dask: the serial loop (no Dask) against 1 Dask worker on the same runs: the overhead per run, and the
  rows compared (equal but for the timing column).
- Worker growth: --growth-runs runs at 10 s through ``run_fleet`` on a LocalCluster of 1 worker, with Dask's
  worker profiler on (Dask's default) and off (``runner.WORKER_CONFIG``, what the command uses): the worker's
  resident memory (VmRSS after gc) sampled 8 times; growth in MB per 1000 runs and per 100 s.
- Memory: --memory-runs runs at 10 s through ``train-calib fleet --workers 2 --quiet`` as a subprocess; peak RSS
  of the command's process and of its workers (getrusage of the children), against a run of a tenth as many.
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import pandas as pd

from train_calib.fleet.manifest import read_manifest
from train_calib.fleet.row import TIMING_COLUMNS, process_run, tune_gc
from train_calib.fleet.runner import Cluster, run_fleet
from train_calib.fleet.simulate import FleetSpec, simulate_fleet
from train_calib.pipeline import bag_messages

PARTS = ("per_core", "stages", "scaling", "growth", "memory")

REPO = Path(__file__).resolve().parent.parent
RUNS_PER_YEAR = 900_000  # a 170-unit intercity fleet (issue 20)


def bags(out: Path, period: float) -> Path:
    folder = out / f"bags_{period:g}s"
    if not (folder / "manifest.csv").exists():
        simulate_fleet(folder, FleetSpec(units=2, faulty=0, runs_per_unit=2, seed=7, period_s=period))
    return folder / "manifest.csv"


def manifest(src: Path, n: int, path: Path) -> Path:
    """n lines cycling over the bags of ``src`` under other units and dates."""
    base = list(csv.DictReader(src.open()))
    with path.open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["bag", "track", "train", "unit", "date"])
        for k in range(n):
            row = base[k % len(base)]
            bag = str((src.parent / row["bag"]).resolve())
            w.writerow([bag, row["track"], row["train"], f"u{k % 170:03d}", f"2025-{1 + k % 12:02d}-{1 + k % 28:02d}"])
    return path


def per_core(src: Path, repeat: int) -> dict[str, float]:
    rows = read_manifest(src)
    jobs = [r.columns() | {"bag_path": r.bag_path, "track_path": r.track_path, "train_path": r.train_path}
            for r in rows]  # fmt: skip
    process_run(jobs[0])  # warm-up: imports, track and train caches
    tune_gc()  # as in a fleet worker after its first run
    times: dict[int, list[float]] = {k: [] for k in range(len(jobs))}
    cpu: dict[int, list[float]] = {k: [] for k in range(len(jobs))}
    decode: dict[int, list[float]] = {k: [] for k in range(len(jobs))}
    for _ in range(repeat):
        for k, job in enumerate(jobs):
            t, c = time.perf_counter(), time.process_time()
            row = process_run(job)
            times[k].append(time.perf_counter() - t)
            cpu[k].append(time.process_time() - c)
            assert row["status"] == "ok", row["error"]
            t = time.perf_counter()
            n = len(_decoded(job["bag_path"]))
            decode[k].append(time.perf_counter() - t)
    # the best of the repeats per bag (the machine is shared), then the mean over the bags; the CPU time is the
    # steadier on a loaded machine (wall time counts the waits for a core)
    best = sum(min(v) for v in times.values()) / len(jobs)
    best_cpu = sum(min(v) for v in cpu.values()) / len(jobs)
    best_decode = sum(min(v) for v in decode.values()) / len(jobs)
    mean_all = sum(sum(v) for v in times.values()) / (len(jobs) * repeat)
    return {"seconds_per_run": best, "runs_per_s_per_core": 1.0 / best, "mean_seconds_per_run": mean_all,
            "cpu_seconds_per_run": best_cpu, "runs_per_cpu_s": 1.0 / best_cpu,
            "decode_s": best_decode, "decode_share": best_decode / best, "messages": n,
            "samples": row["samples"]}  # fmt: skip


def _decoded(bag: str) -> list:
    """The bag's input events as run_bag reads them (the generic path for a bag the direct decoder declines)."""
    from train_calib.cdr_inputs import read_input_events
    from train_calib.ingest import fix_from_msg, power_from_msg, speed_from_msg
    from train_calib.pipeline import GNSS_TOPIC, SPEED_TOPIC

    events = read_input_events(bag)
    if events is None:
        convert = {GNSS_TOPIC: fix_from_msg, SPEED_TOPIC: speed_from_msg}
        events = [convert.get(topic, power_from_msg)(msg) for topic, msg in bag_messages(bag)]
    return events


STAGES = ("decode", "ingest", "ukf", "regimes", "features", "window", "best")


def _best_of(f, repeat: int) -> tuple[float, object]:
    """(minimum CPU ms over ``repeat`` calls, the last result)."""
    times, result = [], None
    for _ in range(repeat):
        t = time.process_time()
        result = f()
        times.append(time.process_time() - t)
    return 1e3 * min(times), result


def _stage_times(job: dict, repeat: int) -> dict[str, float]:
    """CPU ms of each stage of one bag, alone on the previous stage's output."""
    from train_calib import pipeline as P
    from train_calib.estimation.effort import PowerEffort
    from train_calib.estimation.regime_model import power_state
    from train_calib.fleet.row import _cached

    track, train, bag = _cached("track", job["track_path"]), _cached("train", job["train_path"]), job["bag_path"]
    process_run(job)  # warm-up
    ms: dict[str, float] = {}
    ms["decode"], events = _best_of(lambda: _decoded(bag), repeat)

    def ingest() -> list:  # as run_bag drives it: no delay estimate (nothing reads it), track terms in one pass
        ing = P.Ingest(track, train)
        ing.skip_delay_estimate()
        ing.defer_terms()
        out = ing.add_many(events)
        ing.fill_terms()
        return out + ing.flush()

    ms["ingest"], measurements = _best_of(ingest, repeat)

    def ukf() -> tuple[list, object]:
        est = P.ResistanceEstimator(train)
        return [(m, e if est.rejected is None else None) for m in measurements for e in [est.update(m)]], est

    ms["ukf"], (pairs, estimator) = _best_of(ukf, repeat)

    def regimes() -> list:  # as Pipeline.add_measurement classifies: with the power's state and the measurement
        stream, power, out = P.RegimeStream(), PowerEffort(train), []
        for m, e in pairs:
            if e is not None:
                out += stream.push(e, power_state(m, power), m)
        return out + stream.flush()

    ms["regimes"], triples = _best_of(regimes, repeat)

    def features() -> None:
        stream = P.FeatureStream()
        for e, _, phase in triples:
            stream.update(e, phase)
        stream.end_of_input()

    ms["features"], _ = _best_of(features, repeat)
    phases = {id(e): p for e, _, p in triples}

    def window() -> None:
        calibrator = P.WindowCalibrator(train, P.WindowConfig())
        for m, e in pairs:
            calibrator.update(m, None if e is None else phases[id(e)])

    ms["window"], _ = _best_of(window, repeat)
    ms["best"], _ = _best_of(lambda: P.whole_run_best(measurements, estimator), repeat)
    ms["run_bag"], _ = _best_of(lambda: P.run_bag(bag, track, train), repeat)
    ms["process_run"], _ = _best_of(lambda: process_run(job), repeat)
    return ms


def stages(src: Path, repeat: int) -> dict[str, float]:
    """CPU ms per run of each stage alone (module docstring), the minimum of ``repeat`` per bag, mean over bags."""
    rows = read_manifest(src)
    total = dict.fromkeys((*STAGES, "run_bag", "process_run"), 0.0)
    for r in rows:
        job = r.columns() | {"bag_path": r.bag_path, "track_path": r.track_path, "train_path": r.train_path}
        for k, v in _stage_times(job, repeat).items():
            total[k] += v / len(rows)
    total["sum_of_stages"] = sum(total[k] for k in STAGES)
    return total


def fleet_rate(rows: list, workers: int, out: Path) -> tuple[float, Path, float]:
    """Runs/s of run_fleet on a LocalCluster of ``workers`` processes (cluster start not counted), the runs.parquet,
    and this process's CPU ms per run (the client, the scheduler and the nannies live here)."""
    from distributed import Client

    from train_calib.fleet.runner import connect

    client, local = connect(Cluster(workers=workers))
    try:
        client.run(lambda: __import__("train_calib.pipeline"))  # workers import before the clock
        run_fleet(rows[: 2 * workers], out / f"warm{workers}", Cluster(workers=workers), client=client)
        t, cpu = time.perf_counter(), time.process_time()
        run_fleet(rows, out / f"w{workers}", Cluster(workers=workers), client=client)
        dt, dcpu = time.perf_counter() - t, time.process_time() - cpu
    finally:
        client.close()
        local.close()
    assert isinstance(client, Client)
    return len(rows) / dt, out / f"w{workers}" / "runs.parquet", 1000 * dcpu / len(rows)


def serial(rows: list, out: Path) -> tuple[float, Path]:
    """The same rows without Dask, in this process."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    from train_calib.fleet.row import RUNS_SCHEMA

    t = time.perf_counter()
    result = [process_run(r.columns() | {"date_s": r.date_s, "bag_path": r.bag_path, "track_path": r.track_path,
                                         "train_path": r.train_path}) for r in rows]  # fmt: skip
    dt = time.perf_counter() - t
    out.mkdir(parents=True, exist_ok=True)
    pq.write_table(pa.Table.from_pylist(result, schema=RUNS_SCHEMA), out / "serial.parquet")
    return len(rows) / dt, out / "serial.parquet"


def memory(src: Path, n: int, out: Path) -> dict[str, float]:
    m = manifest(src, n, out / f"memory_{n}.csv")
    code = (
        "import resource, sys, time; from train_calib.cli import main; t = time.perf_counter(); "
        f"rc = main(['fleet', {str(m)!r}, '--out', {str(out / f'mem{n}')!r}, '--workers', '2', '--quiet']); "
        "print('WALL', time.perf_counter() - t); "
        "print('RSS', resource.getrusage(resource.RUSAGE_SELF).ru_maxrss, "
        "resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss); sys.exit(rc)"
    )
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    fields = {
        line.split()[0]: line.split()[1:] for line in res.stdout.splitlines() if line.split()[0] in ("WALL", "RSS")
    }
    return {"runs": n, "wall_s": float(fields["WALL"][0]), "client_peak_mb": int(fields["RSS"][0]) / 1024,
            "worker_peak_mb": int(fields["RSS"][1]) / 1024}  # fmt: skip


def _worker_rss_mb() -> float:
    """This process's resident memory (MB) after a garbage collection (Linux /proc)."""
    import gc

    gc.collect()
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return float("nan")


def growth(src: Path, n: int, out: Path, profile: bool) -> dict[str, object]:
    """Worker memory over n runs on a LocalCluster of 1 worker, Dask's profiler on or off."""
    from train_calib.fleet import runner

    rows = read_manifest(manifest(src, n, out / f"growth_{n}.csv"))
    saved = runner.WORKER_CONFIG
    runner.WORKER_CONFIG = {"distributed.worker.profile.enabled": profile}
    try:
        client, local = runner.connect(Cluster(workers=1))
    finally:
        runner.WORKER_CONFIG = saved
    samples: list[tuple[int, float, float]] = []  # (runs done, seconds, MB)
    t0 = time.perf_counter()

    def on_row(row: dict, result: object) -> None:
        done = result.ok + result.errors  # type: ignore[attr-defined]
        if done % max(1, n // 8) == 0 or done == n:
            mb = next(iter(client.run(_worker_rss_mb).values()))
            samples.append((done, time.perf_counter() - t0, mb))

    try:
        run_fleet(rows, out / f"growth_{'on' if profile else 'off'}", Cluster(workers=1), client=client, on_row=on_row)
    finally:
        client.close()
        local.close()
    (r0, t_0, m0), (r1, t_1, m1) = samples[0], samples[-1]
    return {"profiler": profile, "runs": n, "samples": samples, "first_mb": m0, "last_mb": m1,
            "mb_per_1000_runs": 1000 * (m1 - m0) / (r1 - r0),
            "mb_per_100_s": 100 * (m1 - m0) / (t_1 - t_0)}  # fmt: skip


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=REPO / "build" / "bench_fleet")
    ap.add_argument("--runs", type=int, default=40, help="runs of the scaling and overhead measurements")
    ap.add_argument("--repeat", type=int, default=3, help="passes over the bags for the per-core rate")
    ap.add_argument("--memory-runs", type=int, default=10000, help="0 = skip the memory measurement")
    ap.add_argument("--growth-runs", type=int, default=2000, help="runs of the worker growth measurement")
    ap.add_argument("--parts", default="per_core,scaling,growth,memory",
                    help=f"which measurements (comma list of {', '.join(PARTS)})")  # fmt: skip
    args = ap.parse_args()
    parts = set(args.parts.split(","))
    if parts - set(PARTS):
        ap.error(f"--parts: unknown {', '.join(sorted(parts - set(PARTS)))}")
    args.out.mkdir(parents=True, exist_ok=True)
    report: dict[str, object] = {"cores": os.cpu_count(), "load_average_at_start": os.getloadavg(),
                                 "parts": sorted(parts)}  # fmt: skip
    print(f"load average at start: {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores")
    src = {p: bags(args.out, p) for p in (10.0, 1.0)}
    if "per_core" in parts:
        for p, m in src.items():
            report[f"per_core_{p:g}s"] = r = per_core(m, args.repeat)
            print(f"per core, {p:g} s: {r['runs_per_s_per_core']:.2f} runs/s ({1000 * r['seconds_per_run']:.0f} "
                  f"ms/run wall, {1000 * r['cpu_seconds_per_run']:.0f} ms CPU: {r['runs_per_cpu_s']:.2f} runs per CPU "
                  f"second; decoding {100 * r['decode_share']:.0f} %, {r['samples']} samples)")  # fmt: skip
    if "stages" in parts:
        for p, m in src.items():
            report[f"stages_{p:g}s_cpu_ms"] = r = stages(m, args.repeat)
            split = ", ".join(f"{k} {r[k]:.1f}" for k in STAGES)
            print(f"stages, {p:g} s, CPU ms per run: {split}; sum {r['sum_of_stages']:.1f}, run_bag "
                  f"{r['run_bag']:.1f}, process_run {r['process_run']:.1f}")  # fmt: skip
    if "scaling" in parts:
        rows = read_manifest(manifest(src[1.0], args.runs, args.out / "scaling.csv"))
        rate_serial, serial_path = serial(rows, args.out / "serial")
        rate1, path1, parent1 = fleet_rate(rows, 1, args.out)
        rate2, path2, parent2 = fleet_rate(rows, 2, args.out)
        a = pd.read_parquet(serial_path).drop(columns=list(TIMING_COLUMNS))
        same = all(a.equals(pd.read_parquet(p).drop(columns=list(TIMING_COLUMNS))) for p in (path1, path2))
        report["scaling_1hz"] = {"runs": len(rows), "serial_runs_per_s": rate_serial, "dask1_runs_per_s": rate1,
                                 "dask2_runs_per_s": rate2, "speedup_2_vs_1": rate2 / rate1,
                                 "dask_overhead_ms_per_run": 1000 * (1 / rate1 - 1 / rate_serial),
                                 "parent_cpu_ms_per_run": {"1": parent1, "2": parent2}, "rows_equal": same}  # fmt: skip
        print(f"1 Hz, {len(rows)} runs: serial {rate_serial:.2f} runs/s, dask 1 worker {rate1:.2f}, 2 workers "
              f"{rate2:.2f} (x{rate2 / rate1:.2f}); dask overhead {1000 * (1 / rate1 - 1 / rate_serial):+.1f} ms/run; "
              f"this process's CPU {parent1:.1f} / {parent2:.1f} ms/run; rows equal: {same}")  # fmt: skip
        if "per_core" in parts:
            r1 = report["per_core_1s"]["runs_per_s_per_core"]  # type: ignore[index]
            eff = (rate2 / rate1) / 2
            cores = RUNS_PER_YEAR / (r1 * eff * 3600.0)
            report["year_in_an_hour_cores"] = cores
            print(
                f"a year of a 170-unit fleet ({RUNS_PER_YEAR} runs at 1 Hz) in an hour: {cores:.0f} cores "
                f"(at {r1:.2f} runs/s per core and {100 * eff:.0f} % parallel efficiency)"
            )
    if "growth" in parts and args.growth_runs:
        for profile in (True, False):
            report[f"growth_profiler_{'on' if profile else 'off'}"] = g = growth(
                src[10.0], args.growth_runs, args.out, profile
            )
            print(f"worker memory, {g['runs']} runs at 10 s, 1 worker, Dask profiler {'on' if profile else 'off'}: "
                  f"{g['first_mb']:.0f} -> {g['last_mb']:.0f} MB ({g['mb_per_1000_runs']:+.1f} MB per 1000 runs, "
                  f"{g['mb_per_100_s']:+.1f} MB per 100 s)")  # fmt: skip
    if "memory" in parts and args.memory_runs:
        for n in (args.memory_runs // 10, args.memory_runs):
            report[f"memory_{n}"] = m = memory(src[10.0], n, args.out)
            print(
                f"memory, {n} runs at 10 s: {m['wall_s']:.0f} s, peak RSS command {m['client_peak_mb']:.0f} MB, "
                f"largest worker {m['worker_peak_mb']:.0f} MB"
            )
    report["load_average_at_end"] = os.getloadavg()
    print(f"load average at end: {os.getloadavg()[0]:.1f}")
    default = {"per_core", "scaling", "growth", "memory"}
    name = "bench_fleet.json" if parts == default else f"bench_fleet_{'_'.join(sorted(parts))}.json"
    (args.out / name).write_text(json.dumps(report, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
