"""train-calib fleet on a small simulated fleet: outputs read back with pandas and pyarrow, the units' truth
recovered and the faulty units flagged, an error row per bad bag, local processes and a Dask cluster of real
processes (tcp, a killed worker, tls with a CA made here) giving the same rows, and --resume by content."""

from __future__ import annotations

import functools
import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow.parquet as pq
import pytest

from train_calib.cli import main
from train_calib.fleet.manifest import read_manifest
from train_calib.fleet.row import RUNS_SCHEMA, TIMING_COLUMNS
from train_calib.fleet.runner import Cluster, connect, run_fleet
from train_calib.fleet.simulate import FleetSpec, simulate_fleet

SPEC = FleetSpec(units=6, faulty=2, runs_per_unit=8, seed=0)
DASK = Path(sys.executable).parent / "dask"
HERE = Path(__file__).resolve().parent
BAD_ROWS = 2  # a missing bag and a corrupt one, unit "broken": the manifest's first two lines
PREFIX = 20  # the cluster tests run the manifest's first 20 lines (prefix.csv)


@pytest.fixture(scope="module")
def fleet(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The simulated fleet's folder (manifest.csv with two bad lines appended), and its local run in out/."""
    root = tmp_path_factory.mktemp("fleet")
    manifest = simulate_fleet(root, SPEC)
    corrupt = root / "bags" / "corrupt"
    corrupt.mkdir()
    (corrupt / "corrupt_0.mcap").write_bytes(b"not an mcap file\n" * 10)
    header, *lines = manifest.read_text(encoding="utf-8").splitlines()
    bad = ["bags/missing,intercity_32km,virm6,broken,2025-06-01T00:00:00Z,driver00,x,",
           "bags/corrupt,intercity_32km,virm6,broken,2025-06-02T00:00:00Z,driver00,x,"]  # fmt: skip
    manifest.write_text("\n".join([header, *bad, *lines]) + "\n", encoding="utf-8")  # first: in every prefix
    (root / "prefix.csv").write_text("\n".join([header, *bad, *lines[: PREFIX - BAD_ROWS]]) + "\n")
    assert main(["fleet", str(manifest), "--out", str(root / "out"), "--workers", "2", "--quiet"]) == 0
    return root


def table(path: Path) -> pd.DataFrame:
    return pd.read_parquet(path).drop(columns=list(TIMING_COLUMNS))


def assert_same_rows(a: Path, b: Path) -> None:
    """b's rows are a's first rows, exactly (timing aside), in order, once each."""
    ta, tb = table(a), table(b)
    ta = ta.iloc[: len(tb)]
    assert list(ta["index"]) == list(range(len(ta))) and ta["index"].is_unique
    pd.testing.assert_frame_equal(ta, tb, check_exact=True)


def test_outputs_read_back(fleet: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = fleet / "out"
    n = SPEC.units * SPEC.runs_per_unit + BAD_ROWS
    runs = pq.read_table(out / "runs.parquet")
    assert runs.schema.equals(RUNS_SCHEMA) and runs.num_rows == n
    df = pd.read_parquet(out / "runs.parquet")
    manifest = read_manifest(fleet / "manifest.csv")
    assert list(df["bag"]) == [r.bag for r in manifest] and list(df["unit"]) == [r.unit for r in manifest]
    ok = df[df["status"] == "ok"]
    assert len(ok) == n - BAD_ROWS and (ok["error"] == "").all()
    assert (ok["samples"] > 50).all() and np.isfinite(ok[["r0", "r1", "r2", "r80", "r80_std", "final_r80"]]).all().all()
    assert ok["best_cov"].map(len).eq(9).all() and ok["final_cov"].map(len).eq(9).all()
    shares = ok[[c for c in df.columns if c.startswith("share_")]].sum(axis=1)
    np.testing.assert_allclose(shares, 1.0, atol=1e-9)
    assert ok["run_key"].str.fullmatch("[0-9a-f]{64}").all() and ok["run_key"].is_unique
    # each run's r(80 km/h) against its truth (the manifest's true_r80): the estimator's accuracy at 10 s
    true80 = pd.read_csv(fleet / "manifest.csv")["true_r80"].iloc[ok.index].to_numpy(float)
    err = ok["r80"].to_numpy() / true80 - 1.0
    assert np.median(np.abs(err)) < 0.05 and (np.abs(ok["r80"].to_numpy() - true80) < 4 * ok["r80_std"]).mean() > 0.9
    totals = json.loads((out / "fleet.json").read_text())
    assert totals["runs"] == n and totals["ok"] == n - BAD_ROWS and totals["errors"] == BAD_ROWS
    assert totals["units"] == SPEC.units + 1 and totals["workers"] == 2 and totals["scheduler"] == "local"
    assert set(totals["by_driver"]) <= {f"driver{k:02d}" for k in range(SPEC.drivers)}
    assert (out / "fleet.png").stat().st_size > 20_000 and not list(out.glob("runs.parts*"))


def test_bad_bags_are_error_rows(fleet: Path) -> None:
    df = pd.read_parquet(fleet / "out" / "runs.parquet")
    bad = df[df["unit"] == "broken"]
    assert list(bad["status"]) == ["error", "error"]
    missing, corrupt = bad["error"]
    assert missing == f"{fleet / 'bags' / 'missing'}: no such bag"
    assert str(fleet / "bags" / "corrupt") in corrupt and "\n" not in corrupt and len(corrupt) <= 400
    assert bad[["r0", "r80", "samples"]].isna().all().all()


def test_units_truth_recovered_and_faulty_flagged(fleet: Path) -> None:
    truth = json.loads((fleet / "fleet_truth.json").read_text())
    units = pd.read_parquet(fleet / "out" / "units.parquet").set_index("unit")
    assert units.loc["broken", "runs"] == 2 and units.loc["broken", "runs_error"] == 2
    assert not units.loc["broken", "flag"]
    flagged = sorted(units.index[units["flag"]])
    assert flagged == truth["faulty"] and len(flagged) == SPEC.faulty
    for name, t in truth["units"].items():
        u = units.loc[name]
        assert u["runs"] == u["runs_ok"] == SPEC.runs_per_unit
        # pooled r(80 km/h) against the unit's mean truth over its runs: within 3 % (the estimator's bound)
        assert abs(u["r80"] / t["true_r80_mean"] - 1.0) < 0.03, name
        if t["faulty"]:  # rising by fault_rise a year: the trend sees it
            assert u["r80_trend_pct_per_year"] > 15.0 and u["z_trend"] > 3.0
        else:
            assert abs(u["z_trend"]) < 3.0 and abs(u["z_fleet"]) < 3.0


def test_resume_by_content(fleet: Path, tmp_path: Path) -> None:
    out = tmp_path / "out"
    shutil.copytree(fleet / "out", out)
    # a bag renamed (same content) is still found; a row of the old output that is an error is redone
    shutil.copytree(fleet / "bags" / "unit000_000", tmp_path / "renamed")
    text = (fleet / "manifest.csv").read_text().replace("bags/unit000_000,", f"{tmp_path / 'renamed'},", 1)
    (tmp_path / "manifest.csv").write_text(text.replace("bags/", f"{fleet / 'bags'}/"))
    assert main(["fleet", str(tmp_path / "manifest.csv"), "--out", str(out), "--resume", "--quiet",
                 "--workers", "1"]) == 0  # fmt: skip
    totals = json.loads((out / "fleet.json").read_text())
    n = SPEC.units * SPEC.runs_per_unit
    assert totals["resumed"] == n and totals["computed"] == BAD_ROWS
    a, b = table(fleet / "out" / "runs.parquet"), table(out / "runs.parquet")
    assert b.loc[BAD_ROWS, "bag"] == str(tmp_path / "renamed")
    cols = [c for c in a.columns if c not in ("bag",)]
    pd.testing.assert_frame_equal(a[cols], b[cols], check_exact=True)


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class DaskCluster:
    """`dask scheduler` and `dask worker` subprocesses on 127.0.0.1 (tcp, or tls with the given files)."""

    def __init__(self, tmp: Path, workers: int, tls: tuple[str, str, str] | None = None) -> None:
        self.scheme = "tls" if tls else "tcp"
        self.address = f"{self.scheme}://127.0.0.1:{free_port()}"
        self.tls = tls
        opts = ["--tls-ca-file", tls[0], "--tls-cert", tls[1], "--tls-key", tls[2]] if tls else []
        env = dict(os.environ)  # the workers import fleet_hold (the killed-worker test's task) from this folder
        env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(HERE), env.get("PYTHONPATH", "")]))
        host = ["--host", "127.0.0.1", "--no-dashboard"]
        port = self.address.rsplit(":", 1)[1]
        commands = [("scheduler", [str(DASK), "scheduler", *host, "--port", port, "--no-show", *opts])]
        for k in range(workers):
            worker = [str(DASK), "worker", self.address, *host, "--nthreads", "1", "--nworkers", "1"]
            commands.append((f"worker{k}", [*worker, "--local-directory", str(tmp / f"w{k}"), *opts]))
        self.logs = [(tmp / f"{name}.log").open("w") for name, _ in commands]  # closed in close()
        self.procs = [
            subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=log, env=env)
            for (_, cmd), log in zip(commands, self.logs)
        ]
        with self.client() as c:
            c.wait_for_workers(workers, timeout=60)

    def client(self):
        from distributed import Client

        return Client(self.address, security=self.security(), timeout="30s", set_as_default=False)

    def security(self):
        if not self.tls:
            return None
        from distributed.security import Security

        ca, cert, key = self.tls
        return Security(tls_ca_file=ca, tls_client_cert=cert, tls_client_key=key, require_encryption=True)

    def close(self) -> None:
        """Workers first (each nanny ends its worker), then the scheduler; only the processes started here."""
        for group in (self.procs[1:], self.procs[:1]):
            for p in group:
                p.terminate()
            for p in group:
                try:
                    p.wait(timeout=15)
                except subprocess.TimeoutExpired:
                    p.kill()
                    p.wait()
        for log in self.logs:
            log.close()


@pytest.fixture(scope="module")
def dask_cluster(tmp_path_factory: pytest.TempPathFactory):
    cluster = DaskCluster(tmp_path_factory.mktemp("dask"), workers=2)
    yield cluster
    cluster.close()


def test_dask_scheduler_same_rows(fleet: Path, dask_cluster: DaskCluster, tmp_path: Path) -> None:
    out = tmp_path / "out"
    assert main(["fleet", str(fleet / "prefix.csv"), "--out", str(out), "--scheduler", dask_cluster.address,
                 "--quiet"]) == 0  # fmt: skip
    assert_same_rows(fleet / "out" / "runs.parquet", out / "runs.parquet")
    assert json.loads((out / "fleet.json").read_text())["scheduler"] == dask_cluster.address


def test_killed_worker_mid_run_loses_nothing(fleet: Path, dask_cluster: DaskCluster, tmp_path: Path) -> None:
    """A worker is killed (SIGKILL) while provably inside a run: the run holds (fleet_hold) after reporting its
    start with the worker's pid, the test kills that pid, then releases the hold. The run is redone by another
    worker process, and runs.parquet has every row once, equal to the local run's."""
    from fleet_hold import held_run

    with dask_cluster.client() as c:
        c.wait_for_workers(2, timeout=30)
        pids = set(c.run(os.getpid).values())
    assert len(pids) == 2
    victim = BAD_ROWS + 3  # an ok run in the middle of the first window
    hold = tmp_path / "hold"
    hold.mkdir()
    killed: list[int] = []

    def killer() -> None:
        deadline = time.monotonic() + 90
        while time.monotonic() < deadline:
            started = list(hold.glob(f"start-{victim}-*"))
            if started:
                pid = int(started[0].name.rsplit("-", 1)[1])
                os.kill(pid, signal.SIGKILL)  # the worker inside the held run (one of our cluster's: asserted below)
                killed.append(pid)
                break
            time.sleep(0.02)
        (hold / "release").touch()

    thread = threading.Thread(target=killer, daemon=True)
    thread.start()
    rows = read_manifest(fleet / "prefix.csv")
    out = tmp_path / "out"
    result = run_fleet(rows, out, Cluster(scheduler=dask_cluster.address),
                       task=functools.partial(held_run, hold_dir=str(hold), victim=victim))  # fmt: skip
    thread.join(timeout=5)
    assert len(killed) == 1 and killed[0] in pids
    # the victim's run started twice: in the killed process, then in another one
    starts = sorted(int(p.name.rsplit("-", 1)[1]) for p in hold.glob(f"start-{victim}-*"))
    assert len(starts) == 2 and killed[0] in starts and starts[0] != starts[1]
    # every run was started, none lost; the rows are complete, once each, equal to the local run's
    assert {int(p.name.split("-")[1]) for p in hold.glob("start-*")} == set(range(len(rows)))
    assert result.total == result.ok + result.errors == len(rows) and result.errors == BAD_ROWS
    assert result.computed == len(rows)
    runs = pd.read_parquet(out / "runs.parquet")
    assert list(runs["index"]) == list(range(len(rows))) and runs.loc[victim, "status"] == "ok"
    assert_same_rows(fleet / "out" / "runs.parquet", out / "runs.parquet")
    with dask_cluster.client() as c:  # the nanny restarted the killed process: the cluster is whole again
        c.wait_for_workers(2, timeout=30)
        assert killed[0] not in c.run(os.getpid).values()


def test_local_workers_keep_no_profile(fleet: Path, tmp_path: Path) -> None:
    """Dask's worker profiler (a call tree per second, 1000 kept, twice) was the workers' memory growth
    (bench_fleet: growth): the LocalCluster's workers run without it and keep no profile after runs; the client
    holds no future after the fleet."""
    client, local = connect(Cluster(workers=1))
    try:
        rows = read_manifest(fleet / "prefix.csv")[: BAD_ROWS + 4]
        time.sleep(1.5)  # longer than a profile cycle (1 s): a profiler would have kept one by now
        result = run_fleet(rows, tmp_path, Cluster(workers=1), client=client)
        assert result.ok == 4 and result.errors == BAD_ROWS
        assert not client.futures  # every run's future released once its row is collected: nothing held back
        state = client.run(
            lambda dask_worker: (
                sorted(dask_worker.periodic_callbacks),
                len(dask_worker.profile_history),
                len(dask_worker.profile_keys_history),
            )
        )
        ((callbacks, history, keys_history),) = state.values()
    finally:
        client.close()
        local.close()
    assert "profile" not in callbacks and "profile-cycle" not in callbacks and "heartbeat" in callbacks
    assert history == keys_history == 0


def test_runs_grouped_into_tasks_give_the_same_rows(fleet: Path, tmp_path: Path) -> None:
    """Consecutive runs go to a worker as one Dask task (``runs_per_task``; the command's default sizes the tasks
    from the runs' time, fleet/out): 3 a task gives the same rows, in order, from ceil(n / 3) tasks; the local
    cluster runs with the quiet event-loop checks of ``WORKER_CONFIG`` (1 s instead of 20 ms)."""
    from distributed import get_task_stream

    from train_calib.fleet.runner import WORKER_CONFIG

    rows = read_manifest(fleet / "manifest.csv")
    client, local = connect(Cluster(workers=2))
    try:
        with get_task_stream(client) as stream:
            result = run_fleet(rows, tmp_path / "grouped", Cluster(workers=2), client=client, runs_per_task=3)
        ticks = client.run(lambda dask_worker: dask_worker._tick_interval)
        scheduler_tick = client.run_on_scheduler(lambda dask_scheduler: dask_scheduler._tick_interval)
    finally:
        client.close()
        local.close()
    assert result.computed == len(rows) == 50
    tasks = [t for t in stream.data if str(t["key"]).startswith("fleet-runs-")]
    assert len(tasks) == -(-len(rows) // 3)
    assert_same_rows(fleet / "out" / "runs.parquet", tmp_path / "grouped" / "runs.parquet")
    assert WORKER_CONFIG["distributed.admin.tick.interval"] == "1s"
    assert set(ticks.values()) == {1.0} and scheduler_tick == 1.0


def make_tls(tmp: Path) -> tuple[str, str, str]:
    """A self-signed CA and a certificate for 127.0.0.1 signed by it (openssl)."""

    def ssl(*args: str) -> None:
        subprocess.run(["openssl", *args], cwd=tmp, check=True, capture_output=True)

    ssl("req", "-x509", "-newkey", "rsa:2048", "-nodes", "-keyout", "ca.key", "-out", "ca.pem", "-days", "1",
        "-subj", "/CN=train_calib test CA")  # fmt: skip
    ssl("req", "-newkey", "rsa:2048", "-nodes", "-keyout", "node.key", "-out", "node.csr", "-subj", "/CN=127.0.0.1")
    (tmp / "ext.cnf").write_text("subjectAltName=IP:127.0.0.1\n")
    ssl("x509", "-req", "-in", "node.csr", "-CA", "ca.pem", "-CAkey", "ca.key", "-CAcreateserial", "-out",
        "node.pem", "-days", "1", "-extfile", "ext.cnf")  # fmt: skip
    return str(tmp / "ca.pem"), str(tmp / "node.pem"), str(tmp / "node.key")


@pytest.mark.skipif(shutil.which("openssl") is None, reason="needs openssl to make the test CA")
def test_tls_scheduler(fleet: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    ca, cert, key = make_tls(tmp_path)
    cluster = DaskCluster(tmp_path, workers=1, tls=(ca, cert, key))
    try:
        lines = (fleet / "manifest.csv").read_text().splitlines()
        (fleet / "tls.csv").write_text("\n".join(lines[:7]) + "\n")  # header, the 2 bad lines, 4 runs
        out = tmp_path / "out"
        tls = ["--tls-ca-file", ca, "--tls-cert", cert, "--tls-key", key]
        assert main(["fleet", str(fleet / "tls.csv"), "--out", str(out), "--scheduler", cluster.address, *tls,
                     "--quiet"]) == 0  # fmt: skip
        assert capsys.readouterr().out.count("\n") == 1  # --quiet: one line
        a = table(fleet / "out" / "runs.parquet").iloc[:6]
        pd.testing.assert_frame_equal(a, table(out / "runs.parquet"), check_exact=True, check_dtype=False)
        # a plain tcp client (no certificate) does not get in
        from distributed import Client

        t = time.monotonic()
        with pytest.raises((OSError, TimeoutError)):
            Client(cluster.address.replace("tls://", "tcp://"), timeout="3s", set_as_default=False)
        assert time.monotonic() - t < 30
    finally:
        cluster.close()
