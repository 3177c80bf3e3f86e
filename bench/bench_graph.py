"""Benchmark of the node graph: throughput at --rate 0 against a bare rclpy relay chain, latency at real time, RSS.

    .venv/bin/python bench/bench_graph.py [--bag BAG] [--repeat 3] [--latency-seconds 60]

Throughput: the replay (one process, same executor, same lockstep flow control, same recorder) drives
(a) the four train_calib nodes and (b) a bare rclpy relay chain with the same hops, topics, QoS and
messages: four plain ``rclpy.node.Node`` relays that publish, at the same points of the input stream,
the very messages the graph publishes (prebuilt from the offline pipeline), computing nothing. The
ratio (a)/(b) is what the nodes' numerics, conversions and bookkeeping cost. Runs alternate (a b a b)
and the best of each is kept (the machine is shared); both executors are measured.

Latency: a 10 Hz simulated bag replayed at rate 1; per /train_calib/regime message, the time from the
publication of the speed sample with its stamp to the regime's arrival at a subscriber in the same
process (p50/p99). GNSS and speed of an epoch come within 0.1 s, so the pairing wait is part of it.

RSS: peak resident set size of this process (getrusage) after all runs.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

from rclpy.node import Node  # noqa: E402
from rclpy.qos import QoSProfile, ReliabilityPolicy  # noqa: E402

from train_calib import bagio, paths  # noqa: E402
from train_calib.commands.replay import load_truth  # noqa: E402
from train_calib.nodes.config import GRAPH_NODES  # noqa: E402
from train_calib.nodes.graph import InProcessGraph  # noqa: E402
from train_calib.pipeline import Pipeline, bag_messages  # noqa: E402
from train_calib.replay import ReplayOptions, replay  # noqa: E402
from train_calib.track import load_track  # noqa: E402
from train_calib.train import load_train  # noqa: E402

# -- the bare relay chain ---------------------------------------------------------------------------


def relay_schedule(bag: Path, track, train) -> dict:
    """What each hop publishes, and when: from the offline pipeline, which publishes what the graph does."""
    from train_calib.nodes.convert import estimate_to_msg, features_to_msg, measurement_to_msg, regime_to_msg

    p = Pipeline(track, train)
    per_input, features_after = [], {}
    for topic, msg in bag_messages(bag):
        n_meas, n_feat = len(p.out.measurements), len(p.out.features)
        p.add_message(topic, msg)
        per_input.append(p.out.measurements[n_meas:])
        if len(p.out.features) > n_feat:
            features_after[len(p.out.measurements) - 1] = p.out.features[n_feat:]
    n_meas, n_feat = len(p.out.measurements), len(p.out.features)
    p.end_of_input()
    frame = track.name
    final_meas = p.out.measurements[n_meas:]
    final_feat = p.out.features[n_feat:]
    features = [[features_to_msg(f, frame) for f in features_after.get(i, [])] for i in range(len(p.out.regimes))]
    return {
        "gnss_speed_node": ([[measurement_to_msg(m, frame) for m in ms] for ms in per_input],
                            [measurement_to_msg(m, frame) for m in final_meas]),
        "ukf_node": ([[estimate_to_msg(e, frame)] for e in p.out.estimates], []),
        "regime_node": ([[regime_to_msg(r, r.regime, frame)] for r in p.out.regimes], []),
        "feature_node": (features, [features_to_msg(f, frame) for f in final_feat]),
    }  # fmt: skip


class RelayNode(Node):
    """A bare rclpy node: on each input it publishes the next prebuilt messages; counters for the replay."""

    def __init__(self, context, name, inputs, output, plan, final, sensor):
        from rclpy.parameter import Parameter

        # as the real nodes in a replay: sim time (a /clock subscription each)
        super().__init__(name, context=context, parameter_overrides=[Parameter("use_sim_time", value=True)])
        self.handled: Counter = Counter()
        self.published: Counter = Counter()
        self.input_topics = [t for t, _ in inputs]
        self.pending = 0
        self.ended = False
        self.diagnostics_published = 0
        self._plan, self._final, self._k = plan, final, 0
        msg_type, self._topic = output
        self._pub = self.create_publisher(
            msg_type, self._topic, QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)
        )
        reliability = ReliabilityPolicy.BEST_EFFORT if sensor else ReliabilityPolicy.RELIABLE
        qos = QoSProfile(depth=100 if sensor else 1000, reliability=reliability)
        for topic, cls in inputs:
            self.create_subscription(cls, topic, lambda msg, topic=topic: self._relay(topic), qos)

    def _relay(self, topic):
        for msg in self._plan[self._k]:
            self._pub.publish(msg)
        self.published[self._topic] += len(self._plan[self._k])
        self._k += 1
        self.handled[topic] += 1

    def output_publishers(self):
        return {self._topic: self._pub}

    def mark_ended(self):
        for msg in self._final:
            self._pub.publish(msg)
        self.published[self._topic] += len(self._final)
        self.ended = True

    def finish(self):
        pass


class RelayGraph(InProcessGraph):
    """The relay chain behind the same Graph view the replay uses for the real nodes."""

    def __init__(self, context, schedule):
        from geometry_msgs.msg import TwistStamped
        from sensor_msgs.msg import NavSatFix
        from train_calib_msgs.msg import (
            DrivingFeatures,
            DrivingRegime,
            ResistanceEstimate,
            TrackMeasurement,
            TractionPower,
        )

        m, e, r, f = (
            "/train_calib/measurement",
            "/train_calib/resistance",
            "/train_calib/regime",
            "/train_calib/features",
        )
        sensors = [(bagio.GNSS_TOPIC, NavSatFix), (bagio.SPEED_TOPIC, TwistStamped), (bagio.POWER_TOPIC, TractionPower)]
        hops = {
            "gnss_speed_node": (sensors, (TrackMeasurement, m)),
            "ukf_node": ([(m, TrackMeasurement)], (ResistanceEstimate, e)),
            "regime_node": ([(e, ResistanceEstimate)], (DrivingRegime, r)),
            "feature_node": ([(r, DrivingRegime)], (DrivingFeatures, f)),
        }
        self.names = GRAPH_NODES
        self.nodes = {}
        for name in self.names:
            inputs, output = hops[name]
            plan, final = schedule[name]
            self.nodes[name] = RelayNode(
                context, f"relay_{name}", inputs, output, plan, final, name == "gnss_speed_node"
            )


# -- measurements -------------------------------------------------------------------------------------


def throughput(bag: Path, track_path: Path, train_path: Path, executor: str, schedule: dict | None = None) -> dict:
    out = Path(tempfile.mkdtemp(prefix="bench_graph_"))
    try:
        options = ReplayOptions(bag=bag, track=str(track_path), train=str(train_path), out=out, executor=executor)
        if schedule is not None:
            options.graph_factory = lambda context, names, overrides, params_files: RelayGraph(context, schedule)
        result = replay(options)
        n_inputs = sum(result.sent.values())
        return {
            "inputs": n_inputs,
            "speed_samples": result.sent.get(bagio.SPEED_TOPIC, 0),
            "stream_s": result.stream_s,
            "inputs_per_s": n_inputs / result.stream_s,
            "inputs_per_cpu_s": n_inputs / result.stream_cpu_s,
            "speed_samples_per_s": result.sent.get(bagio.SPEED_TOPIC, 0) / result.stream_s,
            "recorded": dict(result.recorded),
        }
    finally:
        shutil.rmtree(out, ignore_errors=True)


def latency(seconds: float, tmp: Path) -> dict:
    """Rate 1 on a 10 Hz simulated bag: speed sample published -> its /train_calib/regime received."""
    import rclpy
    from train_calib_msgs.msg import DrivingRegime

    from train_calib.nodes.common import reliable_qos

    sim = tmp / "sim10hz"
    cmd = [
        sys.executable,
        "-m",
        "train_calib",
        "simulate",
        "--period",
        "0.1",
        "--out",
        str(sim),
        "--quiet",
        "--name",
        "lat",
    ]
    subprocess.run(cmd, check=True)
    bag = sim / "lat_00"
    truth = load_truth(bag)
    track = paths.track_file(Path(truth["meta"]["track"]["file"]).stem)
    train = paths.train_file(Path(truth["meta"]["train"]["file"]).stem)
    speed_stamp = {m.log_time_ns: bagio.stamp_ns(m.decode().header) for m in bagio.iter_bag(bag, [bagio.SPEED_TOPIC])}
    published: dict[int, int] = {}
    all_published: list[int] = []
    arrivals: dict[int, int] = {}

    def on_input(topic, log_ns, wall_ns):
        all_published.append(wall_ns)
        if topic == bagio.SPEED_TOPIC:
            published[speed_stamp[log_ns]] = wall_ns

    def listener(context):
        node = rclpy.create_node("latency_listener", context=context)

        def arrived(msg):
            arrivals[msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec] = time.perf_counter_ns()

        node.create_subscription(DrivingRegime, "/train_calib/regime", arrived, reliable_qos(1000))
        return [node]

    result = replay(
        ReplayOptions(bag=bag, track=str(track), train=str(train), out=tmp / "lat_out", rate=1.0, until_s=seconds,
                      on_input=on_input, extra_nodes=listener)
    )  # fmt: skip
    lat = np.array([(arrivals[s] - published[s]) * 1e-6 for s in arrivals if s in published])
    # the graph's own latency: from the publication of the input that released the sample (the last one
    # published before the regime arrived) - without the wait for the GNSS fix of the same epoch
    pub = np.sort(np.array(all_published))
    arr = np.array(sorted(arrivals.values()))
    trigger = pub[np.searchsorted(pub, arr, side="right") - 1]
    graph_lat = (arr - trigger) * 1e-6
    return {
        "seconds": seconds,
        "regime_messages": int(lat.size),
        "p50_ms": float(np.percentile(lat, 50)),
        "p99_ms": float(np.percentile(lat, 99)),
        "max_ms": float(lat.max()),
        "graph_p50_ms": float(np.percentile(graph_lat, 50)),
        "graph_p99_ms": float(np.percentile(graph_lat, 99)),
        "graph_max_ms": float(graph_lat.max()),
        "max_behind_schedule_ms": result.max_behind_s * 1e3,
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--bag", type=Path, default=paths.bags_dir() / "tunnel_line_37km_1s_00")
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--latency-seconds", type=float, default=60.0)
    parser.add_argument("--json", type=Path, default=REPO / "bench" / "out" / "bench_graph.json")
    args = parser.parse_args()

    truth = load_truth(args.bag)
    meta = truth["meta"] if truth else {"track": {"file": "intercity_32km"}, "train": {"file": "virm6"}}
    track_path = paths.track_file(Path(meta["track"]["file"]).stem)
    train_path = paths.train_file(Path(meta["train"]["file"]).stem)
    schedule = relay_schedule(args.bag, load_track(track_path), load_train(train_path))
    results: dict = {"bag": str(args.bag), "load_before": os.getloadavg()[0], "cpus": os.cpu_count()}
    for executor in ("events", "single"):
        runs: dict[str, list] = {"graph": [], "relay": []}
        for _ in range(args.repeat):
            runs["graph"].append(throughput(args.bag, track_path, train_path, executor))
            runs["relay"].append(throughput(args.bag, track_path, train_path, executor, schedule))
        assert (
            runs["graph"][0]["recorded"]["/train_calib/regime"] == runs["relay"][0]["recorded"]["/train_calib/regime"]
        )
        best = {k: max(v, key=lambda r: r["inputs_per_s"]) for k, v in runs.items()}
        ratio = best["graph"]["inputs_per_s"] / best["relay"]["inputs_per_s"]
        cpu = {k: max(r["inputs_per_cpu_s"] for r in v) for k, v in runs.items()}
        cpu_ratio = cpu["graph"] / cpu["relay"]
        results[executor] = {
            "inputs": best["graph"]["inputs"],
            "graph_inputs_per_s": best["graph"]["inputs_per_s"],
            "graph_speed_samples_per_s": best["graph"]["speed_samples_per_s"],
            "relay_inputs_per_s": best["relay"]["inputs_per_s"],
            "ratio": ratio,
            "graph_inputs_per_cpu_s": cpu["graph"],
            "relay_inputs_per_cpu_s": cpu["relay"],
            "cpu_ratio": cpu_ratio,
            "all_graph": [round(r["inputs_per_s"]) for r in runs["graph"]],
            "all_relay": [round(r["inputs_per_s"]) for r in runs["relay"]],
        }
        print(
            f"{executor:6} executor: graph {best['graph']['inputs_per_s']:6.0f} inputs/s "
            f"({best['graph']['speed_samples_per_s']:.0f} speed samples/s) vs bare relay chain "
            f"{best['relay']['inputs_per_s']:6.0f} inputs/s = {100 * ratio:.0f} % (target >= 80 %); "
            f"{best['graph']['inputs']} inputs; all runs {results[executor]['all_graph']} / "
            f"{results[executor]['all_relay']}; per CPU second: graph {cpu['graph']:.0f}, relay {cpu['relay']:.0f} "
            f"= {100 * cpu_ratio:.0f} %",
            flush=True,
        )
    with tempfile.TemporaryDirectory(prefix="bench_latency_") as tmp:
        results["latency"] = lat = latency(args.latency_seconds, Path(tmp))
    print(
        f"latency at rate 1, {lat['regime_messages']} samples at 10 Hz: speed sample published -> "
        f"/train_calib/regime received p50 {lat['p50_ms']:.2f} ms, p99 {lat['p99_ms']:.2f} ms, "
        f"max {lat['max_ms']:.2f} ms "
        f"(includes waiting for the GNSS fix of the epoch); graph only (from the input that released the sample) "
        f"p50 {lat['graph_p50_ms']:.2f} ms, p99 {lat['graph_p99_ms']:.2f} ms (target p99 < 10 ms), "
        f"max {lat['graph_max_ms']:.2f} ms"
    )
    results["peak_rss_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    results["load_after"] = os.getloadavg()[0]
    print(f"peak RSS {results['peak_rss_mb']:.0f} MB (replay + graph + recorder in one process); load average "
          f"{results['load_before']:.2f} before, {results['load_after']:.2f} after, {os.cpu_count()} CPUs")  # fmt: skip
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(results, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
