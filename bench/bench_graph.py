"""Benchmark of the node graph: throughput at --rate 0 against a bare rclpy relay chain, latency at real time, RSS.

    .venv/bin/python bench/bench_graph.py [--bag BAG] [--repeat 3] [--latency-seconds 60] [--no-single]

Throughput: the replay (one process, same executor, same lockstep flow control, same recorder) drives
(a) the train_calib nodes and (b) a bare rclpy relay chain with the same hops, topics, QoS and messages:
plain ``rclpy.node.Node`` relays that publish, at the same points of the input stream, the very messages the
graph publishes (prebuilt from the offline pipeline), computing nothing. The ratio (a)/(b) is what the nodes'
numerics, conversions and bookkeeping cost. Two graphs are measured: the four nodes of the estimator chain
(gnss_speed, ukf, regime, feature: the graph of issue 9) and, when the bag has /train/traction_power, the whole
graph the replay starts for it (plus window_calib_node, which joins measurement and regime). Runs alternate
(a b a b) and the best of each is kept (the machine is shared). Executors: the EventsExecutor (the default) and,
for the four-node graph, the SingleThreadedExecutor (``--no-single`` skips it).

Latency: a 10 Hz simulated bag replayed at rate 1; per /train_calib/regime message, the time from the
publication of the speed sample with its stamp to the regime's arrival at a subscriber in the same
process (p50/p99). GNSS and speed of an epoch come within 0.1 s, so the pairing wait is part of it; the graph's
own latency is taken from the input that released the sample.

RSS: peak resident set size of this process (getrusage) after all runs.
"""

from __future__ import annotations

import argparse
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

from benchlib import OUT, load, print_summary, row, write_json  # noqa: E402
from rclpy.node import Node  # noqa: E402
from rclpy.qos import QoSProfile, ReliabilityPolicy  # noqa: E402

from train_calib import bagio, paths  # noqa: E402
from train_calib.commands.replay import load_truth  # noqa: E402
from train_calib.nodes.graph import InProcessGraph  # noqa: E402
from train_calib.pipeline import Pipeline, bag_messages  # noqa: E402
from train_calib.replay import ReplayOptions, replay  # noqa: E402
from train_calib.track import load_track  # noqa: E402
from train_calib.train import load_train  # noqa: E402

TARGET_RATIO = 0.8
TARGET_P99_MS = 10.0

# -- the bare relay chain ---------------------------------------------------------------------------

MEASUREMENT, RESISTANCE, REGIME, FEATURES, WINDOW = (
    "/train_calib/measurement",
    "/train_calib/resistance",
    "/train_calib/regime",
    "/train_calib/features",
    "/train_calib/window_resistance",
)


def relay_schedule(bag: Path, track, train, window: bool) -> dict:
    """What each hop publishes, and on which of its inputs: from the offline pipeline, which publishes what the
    graph does. Per hop: (messages per trigger input, messages at the end of input)."""
    from train_calib.nodes.convert import estimate_to_msg, features_to_msg, measurement_to_msg, regime_to_msg
    from train_calib.nodes.window_calib_node import window_to_msg

    p = Pipeline(track, train, window=window)
    per_input = []
    after_regime: dict[int, list] = {}  # regime index -> features / windows published on it
    windows_after: dict[int, list] = {}
    early_windows: list = []
    out = p.out
    for topic, msg in bag_messages(bag):
        n_meas, n_feat, n_win = len(out.measurements), len(out.features), len(out.windows)
        p.add_message(topic, msg)
        per_input.append(out.measurements[n_meas:])
        if len(out.features) > n_feat:
            after_regime.setdefault(len(out.regimes) - 1, []).extend(out.features[n_feat:])
        if len(out.windows) > n_win:
            target = windows_after.setdefault(len(out.regimes) - 1, []) if out.regimes else early_windows
            target.extend(out.windows[n_win:])
    n_meas, n_feat, n_win = len(out.measurements), len(out.features), len(out.windows)
    p.end_of_input()
    frame = track.name
    regimes = range(len(out.regimes))
    schedule = {
        "gnss_speed_node": ([[measurement_to_msg(m, frame) for m in ms] for ms in per_input],
                            [measurement_to_msg(m, frame) for m in out.measurements[n_meas:]]),
        "ukf_node": ([[estimate_to_msg(e, frame)] for e in out.estimates], []),
        "regime_node": ([[regime_to_msg(r, r.regime, frame)] for r in out.regimes], []),
        "feature_node": ([[features_to_msg(f, frame) for f in after_regime.get(i, [])] for i in regimes],
                         [features_to_msg(f, frame) for f in out.features[n_feat:]]),
    }  # fmt: skip
    if window:
        plan = [[window_to_msg(w, frame) for w in windows_after.get(i, [])] for i in regimes]
        if plan:
            plan[0] = [window_to_msg(w, frame) for w in early_windows] + plan[0]
        schedule["window_calib_node"] = (plan, [window_to_msg(w, frame) for w in out.windows[n_win:]])
    return schedule


class RelayNode(Node):
    """A bare rclpy node: on each trigger input it publishes the next prebuilt messages; counters for the replay.
    ``raw``: its subscriptions take the serialized bytes and it publishes the messages serialized beforehand, so
    it converts no message at all (the middleware's own cost)."""

    def __init__(self, context, name, inputs, trigger, output, plan, final, sensor, raw=False):
        from rclpy.parameter import Parameter

        # as the real nodes in a replay: sim time (a /clock subscription each)
        super().__init__(name, context=context, parameter_overrides=[Parameter("use_sim_time", value=True)])
        self.handled: Counter = Counter()
        self.published: Counter = Counter()
        self.input_topics = [t for t, _ in inputs]
        self.pending = 0
        self.ended = False
        self.diagnostics_published = 0
        if raw:
            from rclpy.serialization import serialize_message

            plan = [[serialize_message(m) for m in msgs] for msgs in plan]
            final = [serialize_message(m) for m in final]
        self._plan, self._final, self._k = plan, final, 0
        msg_type, self._topic = output
        self._pub = self.create_publisher(
            msg_type, self._topic, QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)
        )
        reliability = ReliabilityPolicy.BEST_EFFORT if sensor else ReliabilityPolicy.RELIABLE
        qos = QoSProfile(depth=100 if sensor else 1000, reliability=reliability)
        for topic, cls in inputs:
            relay = trigger is None or topic == trigger
            callback = (
                (lambda msg, topic=topic: self._relay(topic))
                if relay
                else (lambda msg, topic=topic: self._count(topic))
            )
            self.create_subscription(cls, topic, callback, qos, raw=raw)

    def _count(self, topic):
        self.handled[topic] += 1

    def _relay(self, topic):
        msgs = self._plan[self._k] if self._k < len(self._plan) else ()
        for msg in msgs:
            self._pub.publish(msg)
        self.published[self._topic] += len(msgs)
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
    """The relay chain behind the same Graph view the replay uses for the real nodes (same names, same hops)."""

    def __init__(self, context, schedule, names, raw=False):
        from geometry_msgs.msg import TwistStamped
        from sensor_msgs.msg import NavSatFix
        from train_calib_msgs.msg import (
            DrivingFeatures,
            DrivingRegime,
            ResistanceEstimate,
            TrackMeasurement,
            TractionPower,
            WindowResistance,
        )

        sensors = [(bagio.GNSS_TOPIC, NavSatFix), (bagio.SPEED_TOPIC, TwistStamped), (bagio.POWER_TOPIC, TractionPower)]
        hops = {  # inputs, the input that releases the messages (None: every input), output
            "gnss_speed_node": (sensors, None, (TrackMeasurement, MEASUREMENT)),
            "ukf_node": ([(MEASUREMENT, TrackMeasurement)], None, (ResistanceEstimate, RESISTANCE)),
            "regime_node": ([(RESISTANCE, ResistanceEstimate)], None, (DrivingRegime, REGIME)),
            "feature_node": ([(REGIME, DrivingRegime)], None, (DrivingFeatures, FEATURES)),
            "window_calib_node": ([(MEASUREMENT, TrackMeasurement), (REGIME, DrivingRegime)], REGIME,
                                  (WindowResistance, WINDOW)),
        }  # fmt: skip
        self.names = tuple(names)
        self.nodes = {}
        for name in self.names:
            inputs, trigger, output = hops[name]
            plan, final = schedule[name]
            self.nodes[name] = RelayNode(
                context, f"relay_{name}", inputs, trigger, output, plan, final, name == "gnss_speed_node", raw
            )


# -- measurements -------------------------------------------------------------------------------------


def throughput(
    bag: Path,
    track_path: Path,
    train_path: Path,
    executor: str,
    window: bool,
    schedule: dict | None = None,
    raw: bool = False,
) -> dict:
    """One replay at rate 0 of the real graph (schedule None) or of the relay chain (`raw`: its subscriptions
    take the serialized bytes, no message is deserialized); inputs per second of the stream (first input
    published to the last handled) and per CPU second of this process."""
    out = Path(tempfile.mkdtemp(prefix="bench_graph_"))
    try:
        options = ReplayOptions(
            bag=bag, track=str(track_path), train=str(train_path), out=out, executor=executor, window=window
        )
        if schedule is not None:
            options.graph_factory = lambda context, names, overrides, params_files: RelayGraph(
                context, schedule, names, raw
            )
        result = replay(options)
        n_inputs = sum(result.sent.values())
        return {
            "nodes": list(result.nodes),
            "executor": result.executor,
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


def compare(bag: Path, track_path: Path, train_path: Path, executor: str, window: bool, schedule: dict,
            repeat: int) -> dict:  # fmt: skip
    """Graph, relay chain and raw relay chain alternately, `repeat` times each; the best of each and the ratios."""
    runs: dict[str, list] = {"graph": [], "relay": [], "raw_relay": []}
    for _ in range(repeat):
        runs["graph"].append(throughput(bag, track_path, train_path, executor, window))
        runs["relay"].append(throughput(bag, track_path, train_path, executor, window, schedule))
        runs["raw_relay"].append(throughput(bag, track_path, train_path, executor, window, schedule, raw=True))
    graph_rec, relay_rec = runs["graph"][0]["recorded"], runs["relay"][0]["recorded"]
    for topic in (MEASUREMENT, RESISTANCE, REGIME, FEATURES, WINDOW):  # the same messages through both
        assert graph_rec.get(topic, 0) == relay_rec.get(topic, 0), (topic, graph_rec, relay_rec)
    best = {k: max(v, key=lambda r: r["inputs_per_s"]) for k, v in runs.items()}
    cpu = {k: max(r["inputs_per_cpu_s"] for r in v) for k, v in runs.items()}
    return {
        "nodes": best["graph"]["nodes"],
        "executor": best["graph"]["executor"],
        "inputs": best["graph"]["inputs"],
        "graph_inputs_per_s": best["graph"]["inputs_per_s"],
        "graph_speed_samples_per_s": best["graph"]["speed_samples_per_s"],
        "relay_inputs_per_s": best["relay"]["inputs_per_s"],
        "relay_speed_samples_per_s": best["relay"]["speed_samples_per_s"],
        "ratio": best["graph"]["inputs_per_s"] / best["relay"]["inputs_per_s"],
        "raw_relay_speed_samples_per_s": best["raw_relay"]["speed_samples_per_s"],
        "raw_ratio": best["graph"]["inputs_per_s"] / best["raw_relay"]["inputs_per_s"],
        "graph_inputs_per_cpu_s": cpu["graph"],
        "relay_inputs_per_cpu_s": cpu["relay"],
        "cpu_ratio": cpu["graph"] / cpu["relay"],
        "all_graph": [round(r["inputs_per_s"]) for r in runs["graph"]],
        "all_relay": [round(r["inputs_per_s"]) for r in runs["relay"]],
        "all_raw_relay": [round(r["inputs_per_s"]) for r in runs["raw_relay"]],
        "recorded": graph_rec,
    }


def node_costs(bag: Path, track_path: Path, train_path: Path, window: bool) -> dict:
    """One extra replay with every node callback, publish and /diagnostics timed (not used for the ratios): where
    the nodes' own time goes, in microseconds per speed sample. ``work`` is the decoding of the inputs and the
    callbacks without their publishes (the relay chain publishes the same messages)."""
    from train_calib.nodes import common

    spent: Counter = Counter()
    original = (common.TrainCalibNode._input, common.TrainCalibNode.publish, common.TrainCalibNode.publish_diagnostics,
                common.TrainCalibNode.input_decoder)  # fmt: skip
    perf = time.perf_counter
    decoding = []  # the node whose input is being created (input_decoder is called inside _input)

    def input_decoder(msg_type):
        decode, name = original[3](msg_type), decoding[-1]

        def timed_decode(data):
            t0 = perf()
            msg = decode(data)
            spent[name, "callbacks"] += perf() - t0
            return msg

        return timed_decode

    def _input(self, msg_type, topic, callback, qos):
        name = self.get_name()

        def timed_callback(msg):
            t0 = perf()
            callback(msg)
            spent[name, "callbacks"] += perf() - t0

        decoding.append(name)
        try:
            return original[0](self, msg_type, topic, timed_callback, qos)
        finally:
            decoding.pop()

    def publish(self, topic, msg):
        t0 = perf()
        original[1](self, topic, msg)
        spent[self.get_name(), "publish"] += perf() - t0

    def publish_diagnostics(self):
        t0 = perf()
        original[2](self)
        spent[self.get_name(), "diagnostics"] += perf() - t0

    common.TrainCalibNode._input, common.TrainCalibNode.publish = _input, publish
    common.TrainCalibNode.publish_diagnostics = publish_diagnostics
    common.TrainCalibNode.input_decoder = staticmethod(input_decoder)
    try:
        r = throughput(bag, track_path, train_path, "events", window)
    finally:
        cls = common.TrainCalibNode
        cls._input, cls.publish, cls.publish_diagnostics = original[:3]
        cls.input_decoder = staticmethod(original[3])
    n = r["speed_samples"]
    per = {}
    for name in r["nodes"]:
        cb, pub, diag = (spent[name, k] / n * 1e6 for k in ("callbacks", "publish", "diagnostics"))
        per[name] = {"work_us": cb - pub, "publish_us": pub, "diagnostics_us": diag}
    return {"speed_samples": n, "stream_s": r["stream_s"], "per_node": per}


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
    parser.add_argument("--no-single", action="store_true", help="skip the SingleThreadedExecutor comparison")
    parser.add_argument("--no-window", action="store_true", help="skip the whole graph (window_calib_node)")
    parser.add_argument("--json", type=Path, default=OUT / "bench_graph.json")
    args = parser.parse_args()

    truth = load_truth(args.bag)
    meta = truth["meta"] if truth else {"track": {"file": "intercity_32km"}, "train": {"file": "virm6"}}
    track_path = paths.track_file(Path(meta["track"]["file"]).stem)
    train_path = paths.train_file(Path(meta["train"]["file"]).stem)
    track, train = load_track(track_path), load_train(train_path)
    has_power = bagio.POWER_TOPIC in bagio.bag_topics(args.bag) and not args.no_window
    results: dict = {"bag": str(args.bag), "load_before": load(), "cpus": os.cpu_count(), "throughput": {},
                     "summary": []}  # fmt: skip
    cases = [("estimator chain (4 nodes)", False, "events")]
    if not args.no_single:
        cases.append(("estimator chain (4 nodes)", False, "single"))
    if has_power:
        cases.append(("whole graph (5 nodes, with window_calib_node)", True, "events"))
    schedules = {w: relay_schedule(args.bag, track, train, w) for w in sorted({w for _, w, _ in cases})}
    for label, window, executor in cases:
        r = compare(args.bag, track_path, train_path, executor, window, schedules[window], args.repeat)
        results["throughput"][f"{label}, {executor}"] = r
        print(
            f"{label}, {r['executor']}: graph {r['graph_inputs_per_s']:6.0f} inputs/s "
            f"({r['graph_speed_samples_per_s']:.0f} speed samples/s) vs bare relay chain "
            f"{r['relay_inputs_per_s']:6.0f} inputs/s = {100 * r['ratio']:.0f} % "
            f"(target >= {100 * TARGET_RATIO:.0f} %); {r['inputs']} inputs; all runs {r['all_graph']} / "
            f"{r['all_relay']}; per CPU second: graph {r['graph_inputs_per_cpu_s']:.0f}, relay "
            f"{r['relay_inputs_per_cpu_s']:.0f} = {100 * r['cpu_ratio']:.0f} %; raw relay chain (no conversion) "
            f"{r['raw_relay_speed_samples_per_s']:.0f} speed samples/s = {100 * r['raw_ratio']:.0f} %",
            flush=True,
        )
        results["summary"].append(
            row(f"{label}, {r['executor']}: speed samples/s at rate 0 ({Path(args.bag).name})",
                f"{r['graph_speed_samples_per_s']:.0f} samples/s", f">= {100 * TARGET_RATIO:.0f} % of the relay chain",
                r["ratio"] >= TARGET_RATIO, f"bare relay chain {r['relay_speed_samples_per_s']:.0f} samples/s",
                r["ratio"], f"{100 * r['ratio']:.0f} %",
                note=f"{len(r['nodes'])} hops; per CPU second {100 * r['cpu_ratio']:.0f} %; against the raw relay "
                f"chain (bytes in and out, no message converted: the middleware's floor) "
                f"{r['raw_relay_speed_samples_per_s']:.0f} samples/s, {100 * r['raw_ratio']:.0f} %")
        )  # fmt: skip
    costs = node_costs(args.bag, track_path, train_path, has_power)
    results["node_costs"] = costs
    per = costs["per_node"]
    work = sum(v["work_us"] + v["diagnostics_us"] for v in per.values())
    print("nodes' own time per speed sample (callbacks without their publishes, + /diagnostics): " + ", ".join(
        f"{k} {v['work_us']:.0f} us" for k, v in per.items()) + f"; diagnostics "
        f"{sum(v['diagnostics_us'] for v in per.values()):.0f} us; total {work:.0f} us", flush=True)  # fmt: skip
    main_case = results["throughput"].get("estimator chain (4 nodes), events")
    if main_case is not None:
        relay_us = 1e6 / main_case["relay_speed_samples_per_s"]
        raw_us = 1e6 / main_case["raw_relay_speed_samples_per_s"]
        graph_us = 1e6 / main_case["graph_speed_samples_per_s"]
        results["notes"] = [
            f"Why the ratio: per speed sample (3 inputs; 6 messages received and 3-4 published along the chain) the "
            f"bare relay chain costs {relay_us:.0f} us with the EventsExecutor - the middleware, rclpy's conversion "
            f"of every message received (deserialization) and published (serialization), the replay and the "
            f"recorder, all in this process on one thread. As a raw chain (bytes in and out, no message converted) "
            f"it costs {raw_us:.0f} us: rclpy's conversions are {relay_us - raw_us:.0f} us of it. The nodes "
            f"subscribe raw and decode with precompiled CDR layouts into read-only views, and publish the chain's "
            f"messages as bytes packed with the same layouts (train_calib/nodes/cdr.py: about 3 us a message "
            f"instead of 25-50 us each way); the four-node graph costs {graph_us:.0f} us per sample, "
            f"{graph_us - raw_us:.0f} us over the raw chain: the nodes' own Python work. Timed per node in a "
            f"separate run (decoding and callback "
            f"without its publishes, which the chain makes too; {Path(args.bag).name}, whole graph): "
            + ", ".join(f"{k} {v['work_us']:.0f} us" for k, v in per.items())
            + f", /diagnostics {sum(v['diagnostics_us'] for v in per.values()):.0f} us. The SingleThreadedExecutor "
            f"(rclpy's default) makes both chains about 5x slower (its Python wait-set rebuild per callback); the "
            f"replay keeps the EventsExecutor (see train_calib/nodes/runner.py make_executor).",
        ]
    with tempfile.TemporaryDirectory(prefix="bench_latency_") as tmp:
        results["latency"] = lat = latency(args.latency_seconds, Path(tmp))
    print(
        f"latency at rate 1, {lat['regime_messages']} samples at 10 Hz: speed sample published -> "
        f"/train_calib/regime received p50 {lat['p50_ms']:.2f} ms, p99 {lat['p99_ms']:.2f} ms, "
        f"max {lat['max_ms']:.2f} ms "
        f"(includes waiting for the GNSS fix of the epoch); graph only (from the input that released the sample) "
        f"p50 {lat['graph_p50_ms']:.2f} ms, p99 {lat['graph_p99_ms']:.2f} ms (target p99 < {TARGET_P99_MS:g} ms), "
        f"max {lat['graph_max_ms']:.2f} ms"
    )
    results["summary"] += [
        row("latency at rate 1 (10 Hz bag), graph only: input that released the sample -> /train_calib/regime",
            f"p50 {lat['graph_p50_ms']:.2f} ms, p99 {lat['graph_p99_ms']:.2f} ms", f"p99 < {TARGET_P99_MS:g} ms",
            lat["graph_p99_ms"] < TARGET_P99_MS, note=f"max {lat['graph_max_ms']:.2f} ms, "
            f"{lat['regime_messages']} samples"),
        row("latency at rate 1 (10 Hz bag), speed sample published -> /train_calib/regime (pairing wait included)",
            f"p50 {lat['p50_ms']:.2f} ms, p99 {lat['p99_ms']:.2f} ms",
            note="the GNSS fix of the epoch comes up to 0.1 s after the speed sample"),
    ]  # fmt: skip
    results["peak_rss_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    results["load_after"] = load()
    results["summary"].append(
        row("peak RSS of the replay process (replay + graph + recorder; all runs above)",
            f"{results['peak_rss_mb']:.0f} MB", note="soak.py: RSS over hours of data")
    )  # fmt: skip
    print(f"peak RSS {results['peak_rss_mb']:.0f} MB (replay + graph + recorder in one process); load average "
          f"{results['load_before']:.2f} before, {results['load_after']:.2f} after, {os.cpu_count()} CPUs")  # fmt: skip
    print_summary(results["summary"])
    write_json(args.json, results)
    return 0


if __name__ == "__main__":
    sys.exit(main())
