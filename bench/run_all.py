"""Run every benchmark in sequence and regenerate bench/RESULTS.md (``make bench``).

Each benchmark runs in its own subprocess with a time limit; one that fails or runs out of time is reported in
RESULTS.md (with the end of its error output) and the others still run. Each writes a JSON file in bench/out/
with its summary rows (case, target, measured, compared with, ratio, met) and, for the scaling curves, tables;
its console output goes to bench/out/<name>.log and to this console.

    .venv/bin/python bench/run_all.py [--quick] [--only NAME[,NAME...]] [--list]

``--quick``: fewer repeats and smaller cases (a smoke run of a few minutes; the figures are rougher).
``--only``: just these benchmarks (RESULTS.md then holds only them). The full run takes about 10-15 minutes on
the project's 2-core machine. Exit status 1 when a benchmark failed (after all have run and RESULTS.md is
written), else 0; a missed target is a result, not a failure.

ROS: the graph benchmarks run with ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST and, unless ROS_DOMAIN_ID is set,
a domain id of their own (1 + pid % 100), so that other ROS processes on the machine do not join the graph.
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import math
import os
import platform
import signal
import statistics
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

BENCH = Path(__file__).resolve().parent
REPO = BENCH.parent
OUT = BENCH / "out"
RESULTS = BENCH / "RESULTS.md"


@dataclass(frozen=True)
class Bench:
    name: str
    title: str
    script: str
    full: tuple[str, ...]
    quick: tuple[str, ...]
    timeout_s: float
    json_name: str
    json_arg: bool = True  # the script takes --json PATH (else it writes json_name itself)
    about: str = ""


BENCHES: tuple[Bench, ...] = (
    Bench("ukf", "1. UKF step: ours vs filterpy", "bench_ukf.py", ("--repeats", "15"), ("--repeats", "3"), 300,
          "bench_ukf.json",
          about="Per measurement (predict + update) on a simulated 1 Hz 32 km run; filterpy 1.4.5 "
                "UnscentedKalmanFilter + MerweScaledSigmaPoints on the same model, inputs and per-step logic; the "
                "outputs are checked to agree (states and covariances over the whole run)."),
    Bench("whole_run", "2. Whole run, core only", "bench_whole_run.py", ("--repeats", "51"), ("--repeats", "5"),
          300, "bench_whole_run.json",
          about="One simulated 32 km intercity run (virm6) at 10 s and at 1 Hz sampling, no ROS: estimate_run (the "
                "UKF), and the whole core (UKF + HMM regimes + features). Paper (Cunillera et al. 2022): under a "
                "second per trajectory."),
    Bench("graph", "3. Node graph: throughput, latency, RSS", "bench_graph.py",
          ("--repeat", "6", "--latency-seconds", "60"), ("--repeat", "1", "--latency-seconds", "10", "--no-single"),
          900, "bench_graph.json",
          about="Replay at rate 0 of bags/tunnel_line_37km_1s_00 (1 Hz GNSS, speed and traction power; 3 inputs per "
                "speed sample) through the nodes, against a bare rclpy relay chain with the same hops, topics, QoS "
                "and messages, driven by the same replay (lockstep flow control, recorder) in the same process run. "
                "Latency: a 10 Hz simulated bag at rate 1."),
    Bench("simulator", "4. Simulator: one 32 km run", "bench_simulator.py", ("--repeats", "50"), ("--repeats", "5"),
          300, "bench_simulator.json",
          about="Besinovic et al. (2013): 'the integration of a single train trajectory takes about 0.02 s' "
                "(MATLAB, AMD Athlon 3.3 GHz); intercity_32km, virm6."),
    Bench("window", "5. Window calibration, per window", "bench_window.py", ("timing",),
          ("timing", "--windows", "12", "--repeats", "1", "--reference-windows", "3"), 600,
          "bench_window_timing.json", json_arg=False,
          about="De Martinis & Corman (2019): 6.83 s per 10 s window (SAE, MATLAB multistart, 40 starts). Exact "
                "solvers (SAE: HiGHS LP; RMSE: LSI/NNLS) with the ill-posedness diagnostics, per GoF and window "
                "length, on a simulated 1 Hz run with traction power; the multistart search is rerun here on some "
                "of the same windows and its objective compared."),
    Bench("occupation", "6. Occupation calibration, per run", "bench_occupation.py", ("timing",),
          ("timing", "--runs", "1", "--no-scalar"), 900, "bench_occupation_timing.json", json_arg=False,
          about="Besinovic et al. (2013): calibration from track occupation data, paper under a minute per run; "
                "target under a second. Differential evolution over the running-time model, 14.3 km dense corridor, "
                "runs of four compositions."),
    Bench("scaling", "7. Scaling: samples and parallel runs", "bench_scaling.py", (),
          ("--max-samples", "1e5", "--repeats-scale", "0.3", "--runs", "8"), 900, "bench_scaling.json",
          about="Whole-run cost of the core vs the number of samples, and fleet throughput vs worker processes."),
    Bench("soak", "8. Soak: hours of data through the graph", "soak.py", ("--hours", "12"), ("--hours", "2"), 900,
          "soak.json",
          about="Simulated 1 Hz runs back to back (standstills, re-acquisitions) replayed at rate 0 through the "
                "node graph in one process: memory flat, latency not growing, nothing lost."),
    Bench("prediction", "9. Prediction per estimate (prediction_node)", "bench_prediction.py", (),
          ("--stride", "5"), 600, "bench_prediction.json",
          about="Issue 24: Predictor.predict + the Prediction message for every estimate of a bundled bag's replay "
                "core (coasting to the next station and lower limit with sigma points for both models, the nominal "
                "time for both); target under 5 ms per estimate at 1 Hz."),
)  # fmt: skip


@dataclass
class Outcome:
    bench: Bench
    status: str  # ok, failed (exit status), timeout, no output
    seconds: float
    load_before: float
    load_after: float
    command: list[str]
    probe_before: float = math.nan
    probe_after: float = math.nan
    data: dict[str, Any] = field(default_factory=dict)
    error_tail: str = ""


# -- the machine ------------------------------------------------------------------------------------


def _read(path: str) -> str:
    try:
        return Path(path).read_text(encoding="utf-8", errors="replace")
    except OSError:
        return ""


def _version(*dists: str) -> str:
    import importlib.metadata as md

    for dist in dists:
        try:
            return md.version(dist)
        except md.PackageNotFoundError:
            continue
    return "not installed"


def machine() -> dict[str, str]:
    """CPU model, cores, RAM, OS, Python and the versions of the numerical and ROS packages."""
    cpu = next((ln.split(":", 1)[1].strip() for ln in _read("/proc/cpuinfo").splitlines()
                if ln.startswith("model name")), platform.processor() or "unknown")  # fmt: skip
    mem_kb = next((int(ln.split()[1]) for ln in _read("/proc/meminfo").splitlines() if ln.startswith("MemTotal")), 0)
    os_name = next((ln.split("=", 1)[1].strip('"') for ln in _read("/etc/os-release").splitlines()
                    if ln.startswith("PRETTY_NAME=")), platform.system())  # fmt: skip
    virt = "virtual machine" if "hypervisor" in _read("/proc/cpuinfo") else ""
    flags = set(_read("/proc/cpuinfo").split())
    simd = "AVX-512" if "avx512f" in flags else "AVX2" if "avx2" in flags else "no AVX2"
    return {
        "cpu": f"{cpu} ({simd})",
        "cores": str(os.cpu_count()),
        "ram": f"{mem_kb / 1024 / 1024:.1f} GiB",
        "os": f"{os_name}, Linux {platform.release()}" + (f" ({virt})" if virt else ""),
        "python": platform.python_version(),
        "numpy": _version("numpy"),
        "scipy": _version("scipy"),
        "rclpy": _version("ros-rclpy", "rclpy"),
        "filterpy": _version("filterpy"),
    }


def git_commit() -> str:
    """Short commit of HEAD, "+dirty" when the working tree has changes (this run's own outputs, RESULTS.md and
    bench/out, do not count: an earlier run's uncommitted results change nothing that is measured)."""
    try:
        head = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=REPO, capture_output=True, text=True,
                              check=True, timeout=30).stdout.strip()  # fmt: skip
        outputs = [":(exclude)bench/RESULTS.md", ":(exclude)bench/out"]
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no", "--", ".", *outputs],
                               cwd=REPO, capture_output=True, text=True, timeout=60).stdout.strip()  # fmt: skip
    except (OSError, subprocess.SubprocessError):
        return "unknown (no git)"
    return head + ("+dirty" if dirty else "")


# -- running ------------------------------------------------------------------------------------------


def bench_env() -> dict[str, str]:
    env = dict(os.environ)
    env.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    env.setdefault("ROS_DOMAIN_ID", str(1 + os.getpid() % 100))
    env.setdefault("ROS_LOG_DIR", str(OUT / "roslog"))
    env.setdefault("PYTHONDONTWRITEBYTECODE", "1")
    env["PYTHONUNBUFFERED"] = "1"
    return env


def speed_probe(repeats: int = 9) -> float:
    """The machine's speed now: median ms of a fixed pure-Python workload (interpreter work, as the core's hot paths).

    On the AVX2 EPYC VM of the earlier runs it was bimodal at a load average near 0 -- about 15 ms or about 25 ms,
    switching at random within minutes (the host's other tenants) -- and every absolute time of a benchmark moved
    with it (estimate_run, paper preset, 1 Hz: 26 ms in the fast state, 43 ms in the slow one); on the AVX-512 EPYC
    VM of 2026-11-25 it reads about 10 ms (the same run: 14 ms).
    """
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        x = 0.0
        for i in range(200_000):
            x += (i % 7) * 0.5
        times.append(time.perf_counter() - t0)
    return statistics.median(times) * 1e3


def run_bench(b: Bench, quick: bool) -> Outcome:
    """Run one benchmark script in a subprocess (own session, killed as a group on time-out)."""
    json_path = OUT / b.json_name
    json_path.unlink(missing_ok=True)
    cmd = [sys.executable, str(BENCH / b.script), *(b.quick if quick else b.full)]
    if b.json_arg:
        cmd += ["--json", str(json_path)]
    log_path = OUT / f"{b.name}.log"
    err_path = OUT / f"{b.name}.stderr.log"
    probe0 = speed_probe()
    load0, t0 = os.getloadavg()[0], time.monotonic()
    with open(log_path, "w", encoding="utf-8") as log, open(err_path, "w", encoding="utf-8") as err:
        proc = subprocess.Popen(cmd, cwd=REPO, env=bench_env(), stdout=subprocess.PIPE, stderr=err, text=True,
                                start_new_session=True)  # fmt: skip

        def pump() -> None:
            assert proc.stdout is not None
            for line in proc.stdout:
                log.write(line)
                sys.stdout.write("  | " + line)
                sys.stdout.flush()

        reader = threading.Thread(target=pump, daemon=True)
        reader.start()
        try:
            code = proc.wait(timeout=b.timeout_s)
            status = "ok" if code == 0 else f"failed (exit status {code})"
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGTERM)
            try:
                proc.wait(timeout=15)
            except subprocess.TimeoutExpired:
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait()
            status = f"timeout after {b.timeout_s:.0f} s"
        reader.join(timeout=5)
    seconds = time.monotonic() - t0
    out = Outcome(b, status, seconds, load0, os.getloadavg()[0], cmd, probe0, speed_probe())
    if status == "ok":
        try:
            out.data = json.loads(json_path.read_text(encoding="utf-8"))
        except (OSError, ValueError) as exc:
            out.status = f"no results ({json_path.name}: {exc.__class__.__name__})"
    if out.status != "ok":
        lines = [ln for ln in _read(str(err_path)).splitlines() if ln.strip() and "[INFO]" not in ln]
        out.error_tail = "\n".join(lines[-12:])
    return out


# -- RESULTS.md ------------------------------------------------------------------------------------------


def _cell(value: Any) -> str:
    return str(value).replace("|", "\\|").replace("\n", " ")


def _met(value: bool | None) -> str:
    return {True: "yes", False: "**no**", None: "-"}[value]


def render(outcomes: list[Outcome], info: dict[str, str], started: str, quick: bool, total_s: float) -> str:
    rows_all = [r for o in outcomes for r in o.data.get("summary", [])]
    judged = [r for r in rows_all if r.get("met") is not None]
    met = sum(1 for r in judged if r["met"])
    kind = "quick smoke run (`--quick`: fewer repeats, rougher figures)" if quick else "full run"
    lines = [
        "# Benchmark results",
        "",
        "Generated by `make bench` (`bench/run_all.py`): do not edit by hand, rerun it. The benchmarks, their",
        "inputs and their targets are described in each `bench/bench_*.py`; issue 9 states the targets.",
        "",
        f"- Date: {started} (UTC); {kind}, {total_s / 60:.1f} min in all",
        f"- Commit: `{info['commit']}`",
        f"- Machine: {info['cpu']}, {info['cores']} cores, {info['ram']} RAM; {info['os']}",
        f"- Software: Python {info['python']}, numpy {info['numpy']}, scipy {info['scipy']}, rclpy {info['rclpy']} "
        f"(ROS 2 Jazzy), filterpy {info['filterpy']}",
        "",
        "Absolute times were taken on a **shared 2-core machine**: other jobs ran at the same time (the load average",
        "before and after each benchmark is given; a load near 1 means one of the two cores was busy elsewhere).",
        "Each ratio compares systems measured in the same process run, on the same inputs, alternating or back to",
        "back, so the ratios are robust to that load; absolute times are not, and a target on an absolute time that",
        "is met only narrowly may flip between runs. The machine's speed itself varies too, at a load average near 0:",
        "the *speed probe* column is the median time of a fixed pure-Python workload (`run_all.speed_probe`) just",
        "before and after each benchmark; absolute times scale with it. Seen so far: about 15 or 25 ms on an AVX2",
        "EPYC VM (bimodal, the host's other tenants; up to 1.7x on every absolute time), about 10 ms on an AVX-512",
        "EPYC VM. The graph's ratio moves with the machine too: the middleware (C++) gains more on a faster",
        "machine than the nodes' Python work (4-node graph: 85 % of its relay chain on the AVX2 VM, 80 % on AVX-512).",
        "",
        f"**Targets met: {met} of {len(judged)}.**",
        "",
        "| benchmark | status | time | load before -> after | speed probe before -> after | targets met |",
        "|---|---|---:|---|---|---:|",
    ]
    for o in outcomes:
        rows = o.data.get("summary", [])
        j = [r for r in rows if r.get("met") is not None]
        lines.append(
            f"| {o.bench.title} | {o.status} | {o.seconds:.0f} s | {o.load_before:.2f} -> {o.load_after:.2f} | "
            f"{o.probe_before:.1f} -> {o.probe_after:.1f} ms | {sum(1 for r in j if r['met'])} of {len(j)} |"
        )
    for o in outcomes:
        lines += ["", f"## {o.bench.title}", "", o.bench.about, ""]
        lines.append(f"`{' '.join(_short(c) for c in o.command)}` ({o.status}, {o.seconds:.0f} s, load "
                     f"{o.load_before:.2f} -> {o.load_after:.2f}, speed probe {o.probe_before:.1f} -> "
                     f"{o.probe_after:.1f} ms)")  # fmt: skip
        lines.append("")
        if o.status != "ok":
            lines += ["```", o.error_tail or "(no error output)", "```"]
            continue
        rows = o.data.get("summary", [])
        if rows:
            lines += ["| case | target | measured | compared with | ratio | met | notes |",
                      "|---|---|---|---|---|---|---|"]  # fmt: skip
            for r in rows:
                lines.append(
                    f"| {_cell(r['case'])} | {_cell(r['target'])} | {_cell(r['measured'])} | {_cell(r['reference'])} "
                    f"| {_cell(r['ratio_text'])} | {_met(r.get('met'))} | {_cell(r.get('note', ''))} |"
                )
        for table in o.data.get("tables", []):
            lines += ["", f"**{table['title']}**", "", "| " + " | ".join(_cell(h) for h in table["header"]) + " |",
                      "|" + "---|" * len(table["header"])]  # fmt: skip
            lines += ["| " + " | ".join(_cell(c) for c in r) + " |" for r in table["rows"]]
        for note in o.data.get("notes", []):
            lines += ["", note]
    lines.append("")
    return "\n".join(lines)


def _short(arg: str) -> str:
    """Paths inside the repository relative to it in the commands shown."""
    root = str(REPO) + os.sep
    return arg[len(root) :] if arg.startswith(root) else arg


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="fewer repeats and smaller cases (smoke run)")
    parser.add_argument("--only", help="comma-separated benchmark names (see --list)")
    parser.add_argument("--list", action="store_true", help="list the benchmarks and exit")
    parser.add_argument("--results", type=Path, default=RESULTS, help="where to write the Markdown results")
    args = parser.parse_args()
    if args.list:
        for b in BENCHES:
            print(f"{b.name:12s} {b.title} ({b.script})")
        return 0
    selected = list(BENCHES)
    if args.only:
        names = [n.strip() for n in args.only.split(",") if n.strip()]
        unknown = [n for n in names if n not in {b.name for b in BENCHES}]
        if unknown:
            parser.error(f"unknown benchmark {', '.join(unknown)} (known: {', '.join(b.name for b in BENCHES)})")
        selected = [b for b in BENCHES if b.name in names]
    OUT.mkdir(parents=True, exist_ok=True)
    started = dt.datetime.now(dt.timezone.utc).strftime("%Y-%m-%d %H:%M")
    info = {**machine(), "commit": git_commit()}
    print(f"{info['cpu']}, {info['cores']} cores, {info['ram']}; commit {info['commit']}; "
          f"{'quick' if args.quick else 'full'} run of {', '.join(b.name for b in selected)}", flush=True)  # fmt: skip
    t0 = time.monotonic()
    outcomes = []
    for b in selected:
        print(f"\n== {b.title} ({b.script}) ==", flush=True)
        o = run_bench(b, args.quick)
        outcomes.append(o)
        print(f"== {b.name}: {o.status} in {o.seconds:.0f} s", flush=True)
        for r in o.data.get("summary", []):
            met = {True: "met", False: "MISSED", None: "-"}[r.get("met")]
            print(f"   {met:6s} {r['case']}: {r['measured']} (target {r['target']}; vs {r['reference']}: "
                  f"{r['ratio_text']})")  # fmt: skip
        if o.error_tail:
            print("   " + o.error_tail.replace("\n", "\n   "))
    total = time.monotonic() - t0
    args.results.write_text(render(outcomes, info, started, args.quick, total), encoding="utf-8")
    failed = [o.bench.name for o in outcomes if o.status != "ok"]
    print(f"\n{len(outcomes)} benchmarks in {total / 60:.1f} min; results: {args.results}"
          + (f"; failed: {', '.join(failed)}" if failed else ""))  # fmt: skip
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
