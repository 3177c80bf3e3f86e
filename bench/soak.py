"""Soak: a day of 1 Hz data replayed through the node graph at --rate 0 - memory flat, latency not growing.

    .venv/bin/python bench/soak.py [--hours 24] [--track intercity_32km] [--train virm6] [--dwell 600] [--gap 900]

The day is built from simulated runs (``train_calib.sim.simulate_run``, realistic drivers drawn per run, GNSS
and speed at 1 Hz, the true resistance 10 % off the train file): each run is recorded with ``--dwell`` s of
standstill at the arrival station after it (the simulator's post-roll), then the recording pauses ``--gap`` s
(the return trip, not recorded) and the next run starts at the first station - so the graph sees long
standstills, re-acquisitions on the whole line and a new run every time, for ``--hours`` of recorded time.

The bag is replayed in one process (the four nodes, the replay and the recorder on one EventsExecutor) at
rate 0 with the replay's flow control. Measured:

* RSS of the process (/proc/self/status VmRSS) every 2,000 inputs; start = after the first hour of bag time
  (imports, DDS and the loaded bag in place), end = after the last input. Target: end within 10 % of start.
* per input, the wall time from its publication to the next one's (the graph handling it, lockstep) and per
  speed sample the time from its publication to its /train_calib/regime arriving at a subscriber in the same
  process, in wall time and in this process's CPU time; p50/p99 over the first and the last hour of bag time
  and per hour. Target: the work per sample not growing - the Theil-Sen trend over the run of the hourly p50
  of the CPU time, moving samples only (each hour mixes running and standstill differently), at most +25 % of
  its median. The wall-time trend is reported beside it: on a shared machine one hour's wall p50 swings by up
  to 2x with the other jobs (12 h runs measured -2 .. +31 % by least squares). CPU time is less sensitive to
  them but not immune (an SMT sibling or shared cache busy elsewhere slows the work too: a 10 h run showed
  blocks of hours at 1.23 and at 1.67 ms in both clocks); the Theil-Sen trend discounts such blocks.
* that nothing is lost (one measurement, estimate and regime per accepted speed sample, drops by reason).

Results: printed and written to bench/out/soak.json. Takes about 1.5-3 min per simulated day of 1 Hz data on
a loaded 2-core machine, plus the simulation.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

from train_calib import bagio, paths  # noqa: E402
from train_calib.replay import ReplayOptions, replay  # noqa: E402
from train_calib.sim import DriverParams, SensorParams, simulate_run  # noqa: E402
from train_calib.summary import read_outputs, summarize  # noqa: E402
from train_calib.track import load_track  # noqa: E402
from train_calib.train import Davis, load_train  # noqa: E402

NS = 1_000_000_000
START_NS = 1_700_000_000 * NS


def rss_kb() -> int:
    with open("/proc/self/status", encoding="ascii") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1])
    return 0


def build_day(hours: float, track_name: str, train_name: str, dwell_s: float, gap_s: float, bag: Path) -> dict:
    """Simulated runs back to back until `hours` of 1 Hz data are recorded; writes the input bag."""
    track, train = load_track(paths.track_file(track_name)), load_train(paths.train_file(train_name))
    truth = Davis(*(c * f for c, f in zip(train.davis.as_tuple(), (1.1, 0.9, 1.1))))
    sensors = SensorParams(gnss_period_s=1.0, speed_period_s=1.0, pre_roll_s=20.0, post_roll_s=dwell_s)
    NavSatFix = bagio.msg_class("sensor_msgs/msg/NavSatFix")
    Status = bagio.msg_class("sensor_msgs/msg/NavSatStatus")
    Twist = bagio.msg_class("geometry_msgs/msg/TwistStamped")
    TwistMsg = bagio.msg_class("geometry_msgs/msg/Twist")
    Vector3 = bagio.msg_class("geometry_msgs/msg/Vector3")
    zero = Vector3(x=0.0, y=0.0, z=0.0)
    t = START_NS
    recorded_s = 0.0
    runs = samples = 0
    sim_s = 0.0
    with bagio.BagWriter(bag, {k: bagio.INPUT_TOPICS[k] for k in (bagio.GNSS_TOPIC, bagio.SPEED_TOPIC)}) as writer:
        while recorded_s < hours * 3600.0:
            rng = np.random.default_rng([2024, runs])
            t_sim = time.perf_counter()
            run = simulate_run(
                track, train, driver=DriverParams.sample(rng, train=train), sensors=sensors, rng=rng,
                resistance=truth, start_time_ns=t,
            )  # fmt: skip
            sim_s += time.perf_counter() - t_sim
            events = []
            g, s = run.gnss, run.speed
            for i in range(len(s.t_ns)):
                stamp = int(s.t_ns[i])
                msg = Twist(
                    header=bagio.make_header(stamp, "odom"),
                    twist=TwistMsg(linear=Vector3(x=float(s.v_ms[i]), y=0.0, z=0.0), angular=zero),
                )
                events.append((stamp + NS // 50, bagio.SPEED_TOPIC, msg))
            for i in range(len(g.t_ns)):
                stamp = int(g.t_ns[i])
                cov = np.array([g.sigma_m**2, 0, 0, 0, g.sigma_m**2, 0, 0, 0, 4 * g.sigma_m**2], dtype=float)
                fix = NavSatFix(
                    header=bagio.make_header(stamp, "gnss"),
                    status=Status(status=int(g.status[i]), service=1),
                    latitude=float(g.lat[i]),
                    longitude=float(g.lon[i]),
                    altitude=0.0,
                    position_covariance=cov,
                    position_covariance_type=2,
                )
                events.append((stamp + NS // 10, bagio.GNSS_TOPIC, fix))
            events.sort(key=lambda e: e[0])
            for log_ns, topic, msg in events:
                writer.write(topic, msg, log_ns)
            duration = (int(s.t_ns[-1]) - int(s.t_ns[0])) / NS
            recorded_s += duration + 1.0
            samples += len(s.t_ns)
            runs += 1
            t = int(s.t_ns[-1]) + int(gap_s * NS)
    return {
        "runs": runs,
        "speed_samples": samples,
        "recorded_hours": recorded_s / 3600.0,
        "bag_hours": (t - START_NS) / NS / 3600.0,
        "simulation_s": sim_s,
        "truth": dict(zip(("r0", "r1", "r2"), truth.as_tuple())),
        "track": str(paths.track_file(track_name)),
        "train": str(paths.train_file(train_name)),
    }


def soak(bag: Path, track: str, train: str, out: Path) -> dict:
    import rclpy
    from train_calib_msgs.msg import DrivingRegime

    from train_calib.nodes.common import reliable_qos

    speeds = [m.decode() for m in bagio.iter_bag(bag, [bagio.SPEED_TOPIC])]
    speed_stamps = [bagio.stamp_ns(m.header) for m in speeds]
    moving = np.array([m.twist.linear.x > MOVING_SPEED for m in speeds], dtype=bool)
    del speeds
    index = {s: k for k, s in enumerate(speed_stamps)}
    n = len(speed_stamps)
    # everything the measurement keeps is allocated up front: its own memory must not grow during the soak
    n_inputs = sum(1 for _ in bagio.iter_bag(bag, bagio.INPUT_TOPICS))
    published = np.zeros(n, dtype=np.int64)  # wall ns of each speed sample's publication
    arrived = np.zeros(n, dtype=np.int64)  # wall ns of its regime's arrival
    cpu_published = np.zeros(n, dtype=np.int64)  # process CPU ns at its publication
    cpu_arrived = np.zeros(n, dtype=np.int64)  # process CPU ns at its regime's arrival
    log_of_input = np.zeros(n_inputs, dtype=np.int64)
    wall_of_input = np.zeros(n_inputs, dtype=np.int64)
    rss = np.zeros((n_inputs // 2000 + 2, 2), dtype=np.int64)  # (inputs published, RSS kB)
    count = np.zeros(2, dtype=np.int64)  # inputs, RSS samples
    by_log = {}
    for m in bagio.iter_bag(bag, [bagio.SPEED_TOPIC]):
        by_log[m.log_time_ns] = index[bagio.stamp_ns(m.decode().header)]

    def on_input(topic: str, log_ns: int, wall_ns: int) -> None:
        k = count[0]
        log_of_input[k] = log_ns
        wall_of_input[k] = wall_ns
        count[0] = k + 1
        if topic == bagio.SPEED_TOPIC:
            k_speed = by_log[log_ns]
            published[k_speed] = wall_ns
            cpu_published[k_speed] = time.process_time_ns()
        if k % 2000 == 0:
            rss[count[1]] = (k + 1, rss_kb())
            count[1] += 1

    def listener(context):
        node = rclpy.create_node("soak_listener", context=context)

        def on_regime(msg) -> None:
            k = index.get(msg.header.stamp.sec * NS + msg.header.stamp.nanosec)
            if k is not None:
                arrived[k] = time.perf_counter_ns()
                cpu_arrived[k] = time.process_time_ns()

        node.create_subscription(DrivingRegime, "/train_calib/regime", on_regime, reliable_qos(1000))
        return [node]

    t0, cpu0 = time.monotonic(), time.process_time()
    result = replay(
        ReplayOptions(bag=bag, track=track, train=train, out=out, rate=0.0, on_input=on_input, extra_nodes=listener)
    )
    wall, cpu = time.monotonic() - t0, time.process_time() - cpu0
    rss[count[1]] = (count[0], rss_kb())
    rss = [(int(a), int(b)) for a, b in rss[: count[1] + 1]]
    log = log_of_input[: count[0]]
    hours = (log - log[0]) / NS / 3600.0
    step_ms = np.diff(wall_of_input[: count[0]]) * 1e-6  # input k published -> input k+1
    speed_hours = (np.array(speed_stamps, dtype=np.int64) - speed_stamps[0]) / NS / 3600.0
    ok = (published > 0) & (arrived > 0)
    latency_ms = (arrived - published) * 1e-6
    cpu_ms = (cpu_arrived - cpu_published) * 1e-6
    last_hour = hours[-1] - 1.0

    def stats(values: np.ndarray) -> dict:
        return {
            "p50_ms": float(np.percentile(values, 50)),
            "p99_ms": float(np.percentile(values, 99)),
            "n": int(values.size),
        }

    hourly, hourly_cpu = [], []
    for h in range(int(hours[-1]) + 1):
        sel = (speed_hours >= h) & (speed_hours < h + 1) & ok
        if sel.sum() > 100:
            hourly.append((h, float(np.percentile(latency_ms[sel], 50)), float(np.percentile(latency_ms[sel], 99))))
        sel &= moving
        if sel.sum() > 100:
            hourly_cpu.append((h, float(np.percentile(cpu_ms[sel], 50)), float(np.percentile(cpu_ms[sel], 99))))
    first_step, last_step = step_ms[hours[:-1] < 1.0], step_ms[hours[:-1] >= last_hour]
    first_lat = latency_ms[ok & (speed_hours < 1.0)]
    last_lat = latency_ms[ok & (speed_hours >= last_hour)]
    start_rss = next(kb for k, kb in rss if k >= np.searchsorted(hours, 1.0))
    outputs = read_outputs(out)
    summary = summarize(outputs)
    counts = summary["output_counts"]
    return {
        "inputs": int(log.size),
        "wall_s": wall,
        "cpu_s": cpu,
        "inputs_per_s": log.size / result.stream_s if result.stream_s else None,
        "load_average": os.getloadavg(),
        "rss_kb": {
            "start_after_1h": start_rss,
            "end": rss[-1][1],
            "max": max(kb for _, kb in rss),
            "growth": (rss[-1][1] - start_rss) / start_rss,
            "series": rss,
        },
        "step": {"first_hour": stats(first_step), "last_hour": stats(last_step)},
        "latency": {
            "first_hour": stats(first_lat),
            "last_hour": stats(last_lat),
            "missing": int(n - ok.sum()),
            "hourly_p50_p99_ms": hourly,
            "cpu_hourly_p50_p99_ms": hourly_cpu,
        },
        "counts": counts,
        "dropped": summary["dropped"],
        "filter": summary["filter"],
        "ingest": summary["ingest"],
        "diagnostics": summary["diagnostics"],
        "final": {c: summary["final"][c]["value"] for c in ("r0", "r1", "r2")} if summary["final"] else None,
        "runs": len(summary["runs"]),
    }


RSS_GROWTH_MAX = 0.10
LATENCY_GROWTH_MAX = 0.25
MOVING_SPEED = 0.3  # m/s: the CPU trend is taken over moving samples (standstill shares differ per hour)


def growth_over_run(hourly: np.ndarray) -> float:
    """Theil-Sen trend of the hourly p50 (column 1) over the run, relative to its median (robust to a few hours
    that the shared machine slowed down)."""
    if len(hourly) <= 2:
        return 0.0
    from scipy.stats import theilslopes

    slope = float(theilslopes(hourly[:, 1], hourly[:, 0])[0])
    return slope * (hourly[-1, 0] - hourly[0, 0]) / float(np.median(hourly[:, 1]))


def soak_summary(res: dict, hours: float) -> list[dict]:
    """The soak's targets as summary rows for run_all.py: RSS flat, latency not growing, nothing lost."""
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from benchlib import row

    r, lat, step = res["rss_kb"], res["latency"], res["step"]
    first, last = lat["first_hour"], lat["last_hour"]
    hourly = np.array(lat["hourly_p50_p99_ms"], dtype=float).reshape(-1, 3)
    p50 = hourly[:, 1] if len(hourly) else np.array([first["p50_ms"]])
    growth = growth_over_run(hourly)
    cpu = np.array(lat.get("cpu_hourly_p50_p99_ms", []), dtype=float).reshape(-1, 3)
    cpu_growth = growth_over_run(cpu)
    return [
        row(f"RSS over {hours:g} h of 1 Hz data at rate 0 ({res['inputs']} inputs, {res['runs']} runs)",
            f"{r['start_after_1h'] / 1024:.0f} -> {r['end'] / 1024:.0f} MB ({100 * r['growth']:+.1f} %)",
            f"end within {100 * RSS_GROWTH_MAX:.0f} % of start", r["growth"] <= RSS_GROWTH_MAX,
            note=f"max {r['max'] / 1024:.0f} MB"),
        row("speed sample -> /train_calib/regime at rate 0, process CPU time (moving samples): trend of the "
            "hourly p50 over the run",
            f"{100 * cpu_growth:+.0f} % (hourly p50 {cpu[:, 1].min():.2f}..{cpu[:, 1].max():.2f} ms)" if len(cpu)
            else "-",
            f"<= +{100 * LATENCY_GROWTH_MAX:.0f} % (work per sample not growing)",
            bool(len(cpu) > 2 and cpu_growth <= LATENCY_GROWTH_MAX),
            note="CPU time of this process between the sample's publication and its regime's arrival: the work "
                 "done for it, less sensitive to other jobs than wall time but not immune (a busy SMT sibling or "
                 "shared cache slows it too; see soak.py); Theil-Sen trend"),
        row("speed sample -> /train_calib/regime at rate 0, wall time: trend of the hourly p50 over the run",
            f"{100 * growth:+.0f} % (last hour p50 {last['p50_ms']:.2f} ms, p99 {last['p99_ms']:.2f} ms)",
            "-", None, f"first hour p50 {first['p50_ms']:.2f} ms, p99 {first['p99_ms']:.2f} ms",
            last["p50_ms"] / first["p50_ms"], f"last/first hour p50 {last['p50_ms'] / first['p50_ms']:.2f}",
            note=f"hourly p50 {min(p50):.2f}..{max(p50):.2f} ms (the shared machine's load shows here); per input "
                 f"(lockstep) p99 {step['first_hour']['p99_ms']:.2f} -> {step['last_hour']['p99_ms']:.2f} ms"),
        row("regimes missing (speed samples without their /train_calib/regime)", f"{lat['missing']}", "0",
            lat["missing"] == 0, note=f"throughput {res['inputs_per_s']:.0f} inputs/s"),
    ]  # fmt: skip


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--hours", type=float, default=24.0, help="recorded hours of 1 Hz data (default 24)")
    parser.add_argument("--track", default="intercity_32km")
    parser.add_argument("--train", default="virm6")
    parser.add_argument("--dwell", type=float, default=600.0, help="standstill recorded after each run, s")
    parser.add_argument("--gap", type=float, default=900.0, help="unrecorded time between runs, s")
    parser.add_argument("--json", type=Path, default=REPO / "bench" / "out" / "soak.json")
    parser.add_argument("--keep", type=Path, help="keep the bag and the outputs in this directory")
    args = parser.parse_args()
    tmp = Path(tempfile.mkdtemp(prefix="train_calib_soak_"))
    work = args.keep or tmp
    work.mkdir(parents=True, exist_ok=True)
    try:
        t = time.monotonic()
        day = build_day(args.hours, args.track, args.train, args.dwell, args.gap, work / "day")
        day["build_s"] = time.monotonic() - t
        print(f"built {day['runs']} runs, {day['speed_samples']} speed samples, {day['recorded_hours']:.1f} h recorded "
              f"({day['bag_hours']:.1f} h of bag time) in {day['build_s']:.0f} s", flush=True)  # fmt: skip
        res = soak(work / "day", day["track"], day["train"], work / "out")
        res["day"] = day
        res["summary"] = soak_summary(res, args.hours)
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(res, indent=1, default=float) + "\n", encoding="utf-8")
        r, s, lat = res["rss_kb"], res["step"], res["latency"]
        print(f"replayed {res['inputs']} inputs in {res['wall_s']:.0f} s ({res['inputs_per_s']:.0f} inputs/s, "
              f"load {res['load_average'][0]:.1f})")  # fmt: skip
        print(f"RSS: {r['start_after_1h'] / 1024:.1f} MB after the first hour, {r['end'] / 1024:.1f} MB at the end "
              f"({100 * r['growth']:+.1f} %), max {r['max'] / 1024:.1f} MB")  # fmt: skip
        for name, d in (("per input (lockstep)", s), ("speed sample -> regime", lat)):
            f, la = d["first_hour"], d["last_hour"]
            print(f"{name}: first hour p50 {f['p50_ms']:.2f} ms p99 {f['p99_ms']:.2f} ms; "
                  f"last hour p50 {la['p50_ms']:.2f} ms p99 {la['p99_ms']:.2f} ms")  # fmt: skip
        print(f"counts {res['counts']}; regime missing {lat['missing']}; runs {res['runs']}; dropped {res['dropped']}")
        print(f"filter {res['filter']}")
        print(f"results: {args.json}")
    finally:
        if args.keep is None:
            shutil.rmtree(tmp, ignore_errors=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
