"""Scheduling the runs and streaming the rows to ``runs.parquet``.

Both ways of running go through Dask distributed, so they share every line but the client: local processes
(a ``LocalCluster`` of ``--workers`` single-threaded worker processes, on 127.0.0.1) or an existing cluster
(``--scheduler tcp://HOST:PORT`` or ``tls://HOST:PORT`` with the CA, certificate and key that ``dask scheduler``
and ``dask worker`` take). Consecutive runs go to a worker together, as one Dask task of ``runs_per_task`` runs
(by default as many as take about ``TASK_SECONDS`` by the runs computed so far: the client and the scheduler spend
a few ms per task in this process, which on a small machine competes with the workers). At most ``window`` runs
are in flight; each finished row waits in a reorder buffer
until every earlier manifest line is written, so the rows are in manifest order whoever computed them, and
memory is bounded by the window (never by the manifest). Rows are written in row groups to part files
(``runs.parts/NNNNNN.parquet``, each closed when written, so an interrupted fleet keeps what it finished); at the
end the parts are concatenated into ``runs.parquet`` and removed.

A worker that dies mid-run: the scheduler gives its runs to another worker (Dask's own recovery); a run's row is
written once, by its manifest index, so a run computed twice cannot give two rows. The runs of a task whose
workers died ``distributed.scheduler.allowed-failures`` times become error rows.

``--resume``: the rows of ``runs.parquet`` and of leftover part files with status "ok" are reused for manifest
lines whose run key (content hash of bag, track and train) they carry; only those runs are not computed again.
"""

from __future__ import annotations

import logging
import os
import shutil
import time
from collections import OrderedDict
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pyarrow as pa
import pyarrow.parquet as pq

from ..errors import TrainCalibError
from .manifest import ManifestRow
from .params import FleetParams
from .row import MANIFEST_COLUMNS, RUNS_SCHEMA, process_run, run_key

RUNS = "runs.parquet"
PARTS = "runs.parts"


TASK_SECONDS = 1.0
"""Default size of a task: about this many worker seconds of runs (from the mean of the runs computed so far; one
run per task until the first has come back). The client and the scheduler spend about 4 ms of this process's CPU
per task (bench_fleet: parent CPU); at 1 Hz (0.1 s a run) one run per task cost 12 ms a run in this process, so on
2 cores 2 workers reached only ~1.8x one."""
MAX_RUNS_PER_TASK = 32
"""At most this many runs in one task (a worker that dies redoes no more than these)."""


def run_chunk(task: Callable[[dict[str, Any]], dict[str, Any]], jobs: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """What a worker runs per Dask task: ``task`` on each job of consecutive manifest rows, in order."""
    return [task(job) for job in jobs]


WORKER_CONFIG = {
    "distributed.worker.profile.enabled": False,
    "distributed.admin.tick.interval": "1s",
    "distributed.admin.system-monitor.interval": "5s",
    "distributed.worker.memory.monitor-interval": "1s",
}
"""Dask configuration of the local cluster (scheduler, nannies, workers and client). Dask's statistical profiler
samples every worker thread's stack each 10 ms and keeps one call tree per 1 s cycle for the last
``distributed.admin.low-level-log-length`` (1000) cycles, twice (``profile_history``, ``profile_keys_history``): a
worker running the pipeline grew by ~18 MB a minute for its first 1000 s (181 -> 347 MB in bench_fleet's 10,000
runs), then stayed there. Off here; on a ``dask worker`` cluster, start the workers with
``DASK_DISTRIBUTED__WORKER__PROFILE__ENABLED=False`` (docs/fleet.md). The event loops' health check (every 20 ms),
the system monitor (every 500 ms, for the dashboard, which a local fleet does not serve) and the nannies' memory
check (every 100 ms) cost an idle 2-worker cluster 4.2 % of a core in this process and 3.6 % in the workers; at
1 s, 5 s and 1 s, 0.8 % and 0.7 % (the memory limits are still checked, each second)."""


class FleetError(TrainCalibError):
    """A fleet problem the user can fix (one line)."""


@dataclass
class Cluster:
    """Where the runs go: ``scheduler`` None = a LocalCluster of ``workers`` processes."""

    workers: int | None = None
    scheduler: str | None = None
    tls_ca_file: str | None = None
    tls_cert: str | None = None
    tls_key: str | None = None


@dataclass
class FleetResult:
    total: int = 0
    ok: int = 0
    errors: int = 0
    resumed: int = 0
    computed: int = 0
    wall_s: float = 0.0
    workers: int = 0
    scheduler: str = ""
    worker_seconds: float = 0.0  # sum of the runs' processing times
    params_sha256: str = ""  # of the --params-file, empty without one
    extra: dict[str, Any] = field(default_factory=dict)


def security(cluster: Cluster) -> Any:
    """Dask TLS security from the options (None for tcp); all three files are needed for tls://."""
    from distributed.security import Security

    files = (cluster.tls_ca_file, cluster.tls_cert, cluster.tls_key)
    scheme = (cluster.scheduler or "").partition("://")[0]
    if scheme == "tls" or any(files):
        if scheme != "tls":
            raise FleetError("--tls-ca-file/--tls-cert/--tls-key: need --scheduler tls://HOST:PORT")
        names = ("--tls-ca-file", "--tls-cert", "--tls-key")
        for name, value in zip(names, files):
            if not value:
                raise FleetError(f"{name}: needed with --scheduler tls://")
            if not Path(value).is_file():
                raise FleetError(f"{name}: {value}: no such file")
        return Security(
            tls_ca_file=cluster.tls_ca_file,
            tls_client_cert=cluster.tls_cert,
            tls_client_key=cluster.tls_key,
            require_encryption=True,
        )
    return None


def check_cluster(cluster: Cluster) -> Any:
    """The options' problems as a FleetError before anything is started or written; returns the security."""
    if cluster.scheduler:
        scheme = cluster.scheduler.partition("://")[0]
        if scheme not in ("tcp", "tls"):
            raise FleetError(f"--scheduler: {cluster.scheduler}: expected tcp://HOST:PORT or tls://HOST:PORT")
    return security(cluster)


def connect(cluster: Cluster) -> tuple[Any, Any]:
    """(client, local cluster or None)."""
    from distributed import Client, LocalCluster

    if cluster.scheduler:
        sec = check_cluster(cluster)
        try:
            client = Client(cluster.scheduler, security=sec, timeout="20s", set_as_default=False)
        except (OSError, TimeoutError) as exc:
            raise FleetError(f"--scheduler: {cluster.scheduler}: cannot connect ({exc})") from None
        return client, None
    import dask

    workers = cluster.workers or os.cpu_count() or 1
    with dask.config.set(WORKER_CONFIG):  # the nannies hand this config to their worker processes
        local = LocalCluster(
            n_workers=workers,
            threads_per_worker=1,
            processes=True,
            host="127.0.0.1",
            dashboard_address=None,  # no HTTP server (docs/fleet.md): 3.8 -> 2.5 % of a core idle in this process
            silence_logs=logging.ERROR,
        )
        return Client(local, set_as_default=False), local


class ResumeIndex:
    """The "ok" rows of a previous fleet in DIR, by run key; a row is read from its file when asked for."""

    def __init__(self, files: list[Path]) -> None:
        self.where: dict[str, tuple[int, int, int]] = {}  # key -> (file, row group, row in group)
        self.files = [pq.ParquetFile(p) for p in files]
        self._cache: OrderedDict[tuple[int, int], pa.Table] = OrderedDict()
        for fi, pf in enumerate(self.files):
            for g in range(pf.num_row_groups):
                t = pf.read_row_group(g, columns=["run_key", "status"])
                for i, (key, status) in enumerate(zip(t["run_key"].to_pylist(), t["status"].to_pylist())):
                    if status == "ok" and key:
                        self.where[key] = (fi, g, i)

    def row(self, key: str) -> dict[str, Any] | None:
        loc = self.where.get(key)
        if loc is None:
            return None
        fi, g, i = loc
        table = self._cache.get((fi, g))
        if table is None:
            table = self.files[fi].read_row_group(g)
            self._cache[(fi, g)] = table
            while len(self._cache) > 4:
                self._cache.popitem(last=False)
        return table.slice(i, 1).to_pylist()[0]


def _previous_outputs(out: Path) -> list[Path]:
    files = []
    if (out / RUNS).is_file():
        files.append(out / RUNS)
    for parts in sorted(out.glob(PARTS + "*")):
        if parts.is_dir():
            files += sorted(parts.glob("*.parquet"))
    good = []
    for p in files:
        try:
            pq.ParquetFile(p)
            good.append(p)
        except Exception:  # a part file cut short by a crash holds nothing usable
            continue
    return good


class RowWriter:
    """Rows in order -> part files of ``rows_per_part`` rows (or ``seconds_per_part``), then ``runs.parquet``."""

    def __init__(self, parts: Path, rows_per_part: int = 512, seconds_per_part: float = 30.0) -> None:
        self.parts = parts
        parts.mkdir(parents=True, exist_ok=True)
        self.rows: list[dict[str, Any]] = []
        self.count = 0
        self.rows_per_part = rows_per_part
        self.seconds_per_part = seconds_per_part
        self.last_flush = time.monotonic()

    def add(self, row: dict[str, Any]) -> None:
        self.rows.append(row)
        if len(self.rows) >= self.rows_per_part or time.monotonic() - self.last_flush > self.seconds_per_part:
            self.flush()

    def flush(self) -> None:
        self.last_flush = time.monotonic()
        if not self.rows:
            return
        table = pa.Table.from_pylist(self.rows, schema=RUNS_SCHEMA)
        tmp = self.parts / f".{self.count:06d}.tmp"
        pq.write_table(table, tmp)
        os.replace(tmp, self.parts / f"{self.count:06d}.parquet")
        self.count += 1
        self.rows = []

    def close(self, target: Path) -> None:
        """Concatenate the parts into ``target`` (one row group per part), atomically."""
        self.flush()
        tmp = target.with_name(target.name + ".tmp")
        with pq.ParquetWriter(tmp, RUNS_SCHEMA) as writer:
            for k in range(self.count):
                writer.write_table(pq.read_table(self.parts / f"{k:06d}.parquet", schema=RUNS_SCHEMA))
        os.replace(tmp, target)


def run_fleet(
    rows: list[ManifestRow],
    out: str | Path,
    cluster: Cluster,
    *,
    resume: bool = False,
    window: int | None = None,
    on_row: Callable[[dict[str, Any], FleetResult], None] | None = None,
    client: Any = None,
    task: Callable[[dict[str, Any]], dict[str, Any]] = process_run,
    params: FleetParams | None = None,
    runs_per_task: int | None = None,
) -> FleetResult:
    """Every manifest row through :func:`process_run`, rows streamed to ``out/runs.parquet`` in manifest order.
    ``on_row(row, result)`` is called after each row is written (progress, tests). ``client``: an existing Dask
    client to use instead of connecting (tests). ``task``: what a worker runs per job (tests wrap
    :func:`process_run` to hold a run; it must be importable on the workers). ``params``: a checked
    ``--params-file`` (:func:`params.load_fleet_params`), applied to every run and part of its key.
    ``runs_per_task``: consecutive runs per Dask task (None: about ``TASK_SECONDS`` of runs, see the module);
    ``window`` None: 4 tasks in flight per worker thread (at least 16 runs)."""
    from distributed import as_completed

    if client is None:
        check_cluster(cluster)
    out = Path(out)
    created = not out.exists()
    out.mkdir(parents=True, exist_ok=True)
    start = time.perf_counter()
    start_ns = time.time_ns()
    result = FleetResult(total=len(rows))
    previous = ResumeIndex(_previous_outputs(out)) if resume else None
    # this fleet's parts: a fresh folder; a previous one is kept until this fleet is complete (resume reads it)
    stale = [p for p in out.glob(PARTS + "*") if p.is_dir()]
    parts = out / f"{PARTS}.{os.getpid()}.{time.time_ns()}"
    writer = RowWriter(parts)

    state: dict[str, Any] = {"client": client, "local": None, "pending": None}
    result.scheduler = cluster.scheduler or "local"
    result.params_sha256 = params.sha256 if params is not None else ""

    def pending_set() -> Any:
        """The as_completed set, connecting on first use (a fully resumed fleet starts no cluster)."""
        if state["pending"] is None:
            if state["client"] is None:
                state["client"], state["local"] = connect(cluster)
            info = state["client"].scheduler_info()
            result.workers = sum(w.get("nthreads", 1) for w in info.get("workers", {}).values())
            state["pending"] = as_completed(loop=state["client"].loop)
            state["threads"] = result.workers
        return state["pending"]

    def in_flight_limit() -> int:
        """Runs that may be submitted ahead of the next row to write: 4 tasks per worker thread."""
        return window or max(16, 4 * state["threads"] * state["chunk"])

    try:
        state["threads"] = cluster.workers or os.cpu_count() or 1
        state["chunk"] = runs_per_task or 1
        computed_seconds = 0.0
        buffer: dict[int, dict[str, Any]] = {}
        index_of: dict[str, int] = {}
        next_submit = 0
        next_write = 0
        in_flight = 0
        n = len(rows)
        while next_write < n:
            while next_submit < n and next_submit < next_write + in_flight_limit():
                jobs: list[dict[str, Any]] = []
                indices: list[int] = []
                while next_submit < n and len(jobs) < state["chunk"] and next_submit < next_write + in_flight_limit():
                    row = rows[next_submit]
                    next_submit += 1
                    job = row.columns() | {"date_s": row.date_s, "bag_path": row.bag_path,
                                           "track_path": row.track_path, "train_path": row.train_path}  # fmt: skip
                    if params is not None and params.sha256:
                        job |= {"configs": params.configs, "params_sha256": params.sha256}
                    if previous is not None and previous.where:
                        old = _reuse(previous, job)
                        if old is not None:
                            buffer[row.index] = old
                            result.resumed += 1
                            continue
                    jobs.append(job)
                    indices.append(row.index)
                if not jobs:
                    continue
                pending = pending_set()
                future = state["client"].submit(
                    run_chunk, task, jobs, key=f"fleet-runs-{indices[0]}-{len(jobs)}-{os.getpid()}-{start_ns}",
                    pure=False,
                )  # fmt: skip
                index_of[future.key] = indices
                pending.add(future)
                in_flight += 1
            while next_write in buffer:
                row_out = buffer.pop(next_write)
                writer.add(row_out)
                next_write += 1
                result.ok += row_out["status"] == "ok"
                result.errors += row_out["status"] != "ok"
                if on_row is not None:
                    on_row(row_out, result)
            if next_write >= n or in_flight == 0:
                continue
            future = next(state["pending"])
            in_flight -= 1
            indices = index_of.pop(future.key)
            rows_out = _collect(future, [rows[i] for i in indices])
            future.release()
            for index, row_out in zip(indices, rows_out):
                if index >= next_write and index not in buffer:  # written once, by manifest index
                    buffer[index] = row_out
                    result.computed += 1
                    result.worker_seconds += row_out.get("seconds") or 0.0
                    computed_seconds += row_out.get("seconds") or 0.0
            if runs_per_task is None and result.computed and computed_seconds > 0.0:
                per_run = computed_seconds / result.computed
                state["chunk"] = max(1, min(MAX_RUNS_PER_TASK, round(TASK_SECONDS / per_run)))
        writer.close(out / RUNS)
    except BaseException:
        if not any(parts.glob("*.parquet")):  # nothing done: leave DIR as it was
            shutil.rmtree(parts, ignore_errors=True)
            if created and not any(out.iterdir()):
                out.rmdir()
        raise
    finally:
        if client is None and state["client"] is not None:
            state["client"].close()
            if state["local"] is not None:
                state["local"].close()
    shutil.rmtree(parts, ignore_errors=True)
    for p in stale:
        shutil.rmtree(p, ignore_errors=True)
    result.wall_s = time.perf_counter() - start
    return result


def _reuse(previous: ResumeIndex, job: dict[str, Any]) -> dict[str, Any] | None:
    try:
        key = run_key(job["bag_path"], job["track_path"], job["train_path"], job.get("params_sha256", ""))
    except OSError:
        return None
    old = previous.row(key)
    if old is None:
        return None
    return old | {name: job[name] for name in MANIFEST_COLUMNS}


def _collect(future: Any, rows: list[ManifestRow]) -> list[dict[str, Any]]:
    """The rows a task's future gives; runs that could not be computed (their workers died) are error rows."""
    from .row import empty_result, one_line

    try:
        return future.result()
    except Exception as exc:
        error = {"status": "error", "error": one_line(exc)}
        return [row.columns() | {"date_s": row.date_s} | empty_result() | error for row in rows]


def iter_rows(path: str | Path, columns: list[str] | None = None) -> Iterator[dict[str, Any]]:
    """The rows of a runs.parquet, batch by batch (bounded memory)."""
    pf = pq.ParquetFile(path)
    for batch in pf.iter_batches(columns=columns, batch_size=4096):
        yield from batch.to_pylist()
