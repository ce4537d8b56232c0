"""ingest on dask.distributed: a scheduler and two workers on 127.0.0.1 (``dask scheduler`` /
``dask worker`` subprocesses, and ``--scheduler local``), the same database as a local ingest,
worker deaths retried and recorded, the CLI option."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

distributed = pytest.importorskip("distributed")

import ingest  # noqa: E402
from surfidx import InputError, SurfidxError  # noqa: E402
from surfidx.database import Database  # noqa: E402

from conftest import EXAMPLES, REPO, icosphere_mesh  # noqa: E402
from helpers import fake_processor, make_tree, write_off  # noqa: E402

TESTS = Path(__file__).resolve().parent


def _on_dask_worker() -> bool:
    try:
        distributed.get_worker()
    except ValueError:
        return False
    return True


def dask_processor(path, **kw):
    """``fake_processor``; ``CRASH`` ends the process only when it is a Dask worker, ``SLOW``
    sleeps 0.5 s."""
    data = Path(path).read_bytes()
    if b"CRASH" in data:
        if not _on_dask_worker():
            raise RuntimeError("CRASH double called outside a Dask worker")
        os._exit(3)
    if b"SLOW" in data:
        time.sleep(0.5)
        data = data.replace(b"SLOW", b"")
    return fake_processor(path, **kw)


# ---------------------------------------------------------------------- a cluster on 127.0.0.1
def _dask_cli(*args):
    """``dask scheduler ...`` / ``dask worker ...`` with this interpreter."""
    return [sys.executable, "-m", f"distributed.cli.dask_{args[0]}", *args[1:]]


@pytest.fixture(scope="module")
def cluster(tmp_path_factory):
    """``dask scheduler`` and ``dask worker`` (two worker processes, one thread each) on 127.0.0.1;
    yields the scheduler address. Workers see the tests folder (for the processor doubles)."""
    d = tmp_path_factory.mktemp("dask")
    sched_file = d / "scheduler.json"
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(
        [str(TESTS), str(REPO)] + [p for p in [os.environ.get("PYTHONPATH")] if p]),
        DASK_DISTRIBUTED__SCHEDULER__ALLOWED_FAILURES="0")
    log = open(d / "cluster.log", "wb")
    procs = [subprocess.Popen(_dask_cli("scheduler", "--host", "127.0.0.1", "--port", "0",
                                        "--no-dashboard", "--scheduler-file", str(sched_file)),
                              env=env, stdout=log, stderr=subprocess.STDOUT, cwd=d)]
    try:
        deadline = time.monotonic() + 60
        while not sched_file.exists():
            assert procs[0].poll() is None, (d / "cluster.log").read_text()[-3000:]
            assert time.monotonic() < deadline, "the scheduler did not start"
            time.sleep(0.1)
        address = json.loads(sched_file.read_text())["address"]
        procs.append(subprocess.Popen(
            _dask_cli("worker", address, "--nworkers", "2", "--nthreads", "1", "--no-dashboard",
                      "--host", "127.0.0.1"),
            env=env, stdout=log, stderr=subprocess.STDOUT, cwd=d))
        with distributed.Client(address, set_as_default=False, timeout=30) as client:
            client.wait_for_workers(2, timeout=90)
        yield address
    finally:
        for p in procs[::-1]:
            p.send_signal(signal.SIGINT)
        for p in procs[::-1]:
            try:
                p.wait(20)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait()
        log.close()


def _wait_workers(address, n=2, timeout=60):
    with distributed.Client(address, set_as_default=False, timeout=30) as client:
        client.wait_for_workers(n, timeout=timeout)
        return client.run(os.getpid)


def _contents(db_path):
    """Models by content hash: name, surfel count, colour, stream, descriptors."""
    out = {}
    with Database(db_path) as d:
        for m in d.list_models():
            rec = d.get_model(m["id"])
            out[rec["content_hash"]] = {
                "name": rec["name"], "n_surfels": rec["n_surfels"],
                "has_color": rec["has_color"], "stream": d.get_stream(m["id"]),
                "descriptors": d.get_descriptors(m["id"])}
    return out


def _small_models(root: Path) -> Path:
    """A folder with the textured spot example and two small closed meshes."""
    import shutil

    root.mkdir()
    shutil.copytree(EXAMPLES / "spot", root / "spot")
    v, f = icosphere_mesh(3)
    write_off(root / "ellipsoid.off", v * [1.0, 0.7, 0.5], f)
    bumpy = v * (1 + 0.15 * np.sin(4 * v[:, :1]) * np.cos(3 * v[:, 1:2]))
    write_off(root / "bumpy.off", bumpy, f)
    return root


# ---------------------------------------------------------------------- tests
def test_real_models_same_database_as_local_ingest(cluster, tmp_path):
    """The real processor on a running cluster: same models, hashes and descriptors."""
    root = _small_models(tmp_path / "models")
    local = ingest.run([root], db=tmp_path / "local.db", progress=False)
    remote = ingest.run([root], db=tmp_path / "dask.db", scheduler=cluster, progress=False)
    assert (local.stored, local.failed) == (3, 0), local.errors
    assert (remote.stored, remote.skipped, remote.failed) == (3, 0, 0), remote.errors
    a, b = _contents(tmp_path / "local.db"), _contents(tmp_path / "dask.db")
    assert sorted(a) == sorted(b)
    for h in a:
        for key in ("name", "n_surfels", "has_color"):
            assert a[h][key] == b[h][key], (a[h]["name"], key)
        assert sorted(a[h]["descriptors"]) == sorted(b[h]["descriptors"])
        for kind, vec in a[h]["descriptors"].items():
            np.testing.assert_allclose(b[h]["descriptors"][kind], vec, rtol=0, atol=1e-6)
    with Database(tmp_path / "dask.db") as d:
        run = d.last_run()
        assert (run["status"], run["workers"]) == ("finished", 2)
    again = ingest.run([root], db=tmp_path / "dask.db", scheduler=cluster, progress=False)
    assert (again.stored, again.skipped) == (0, 3)             # content-hash skipping


def test_model_that_kills_its_worker_is_retried_then_recorded(cluster, tmp_path):
    root = make_tree(tmp_path / "data", 6, extra={"crash.ply": "CRASH", "bad.off": "FAIL"})
    s = ingest.run([root], db=tmp_path / "c.db", scheduler=cluster, processor=dask_processor,
                   retries=1, progress=False, batch=2)
    assert (s.stored, s.failed, s.status) == (6, 2, "finished"), s.errors
    errors = dict(s.errors)
    assert errors[str(root / "crash.ply")].startswith("worker process crashed 2 times "
                                                      "(KilledWorker")
    assert errors[str(root / "bad.off")].endswith("deliberately unusable model")
    with Database(tmp_path / "c.db") as d:
        assert sorted(m["name"] for m in d.list_models()) == [f"m{i}" for i in range(6)]
        assert {e["path"] for e in d.errors()} == set(errors)
    _wait_workers(cluster)                          # the nannies restart the crashed workers


def test_worker_killed_mid_run(cluster, tmp_path):
    """SIGKILL one worker process while models run: every model ends stored (re-run elsewhere)
    or recorded as failed, and the run finishes."""
    root = tmp_path / "data"
    root.mkdir()
    for i in range(8):
        (root / f"s{i}.ply").write_text(f"model {i} SLOW")
    pids = _wait_workers(cluster)
    victim = sorted(pids.values())[0]
    killed = []

    def killer():
        time.sleep(1.0)                              # models are running on both workers
        os.kill(victim, signal.SIGKILL)
        killed.append(victim)

    t = threading.Thread(target=killer)
    t.start()
    try:
        s = ingest.run([root], db=tmp_path / "k.db", scheduler=cluster, processor=dask_processor,
                       progress=False)
    finally:
        t.join()
    assert killed == [victim]
    assert s.stored + s.failed == 8 and s.status == "finished"
    assert s.failed == 0, s.errors                   # the killed worker's model ran again
    with Database(tmp_path / "k.db") as d:
        assert sorted(m["name"] for m in d.list_models()) == [f"s{i}" for i in range(8)]
    _wait_workers(cluster)


def test_cli_scheduler_address_and_local(cluster, tmp_path):
    from click.testing import CliRunner

    from surfidx.cli import cli

    root = make_tree(tmp_path / "data", 4, extra={"bad.ply": "FAIL"})
    obj = {"processor": dask_processor}
    r = CliRunner().invoke(cli, ["ingest", str(root), "--db", str(tmp_path / "a.db"),
                                 "--scheduler", cluster, "--json", "--no-progress"], obj=obj)
    assert r.exit_code == 1, r.output          # a file failed: stored what it could, exit 1
    out = json.loads(r.stdout)
    assert (out["stored"], out["failed"]) == (4, 1)
    r = CliRunner().invoke(cli, ["ingest", str(root), "--db", str(tmp_path / "b.db"),
                                 "--scheduler", "local", "--workers", "2", "--no-progress"],
                           obj=obj)
    assert r.exit_code == 1, r.output
    assert "stored 4, skipped 0, failed 1" in r.stdout
    a, b = _models(tmp_path / "a.db"), _models(tmp_path / "b.db")
    assert a == b and [name for name, _ in a] == [f"m{i}" for i in range(4)]


def _models(db):
    with Database(db) as d:
        return sorted((m["name"], m["content_hash"]) for m in d.list_models())


def test_unreachable_scheduler(tmp_path):
    make_tree(tmp_path / "data", 1)
    with pytest.raises(SurfidxError, match=r"cannot reach the Dask scheduler at "
                                           r"tcp://127\.0\.0\.1:1: .*dask scheduler"):
        ingest.DaskExecutor("tcp://127.0.0.1:1", connect_timeout=0.5).open()


def test_executor_arguments(tmp_path):
    with pytest.raises(InputError, match="retries must be a non-negative integer"):
        ingest.DaskExecutor("local", retries=-1)
    with pytest.raises(InputError, match="scheduler address is empty"):
        ingest.DaskExecutor("  ")
    with pytest.raises(InputError, match="workers must be at least 1"):
        ingest.DaskExecutor("local", workers=0)
    make_tree(tmp_path / "data", 1)
    with pytest.raises(InputError, match="either executor or scheduler"):
        ingest.run([tmp_path / "data"], db=tmp_path / "x.db", scheduler="local",
                   executor=ingest.serial, processor=fake_processor, progress=False)
    assert not (tmp_path / "x.db").exists()


def test_executor_with_a_client_is_reused(cluster, tmp_path):
    """A ``Client`` passed in is used for several runs and left open; stats are kept."""
    make_tree(tmp_path / "data", 3)
    with distributed.Client(cluster, set_as_default=False) as client:
        ex = ingest.DaskExecutor(client)
        s1 = ingest.run([tmp_path / "data"], db=tmp_path / "r1.db", executor=ex,
                        processor=dask_processor, progress=False)
        s2 = ingest.run([tmp_path / "data"], db=tmp_path / "r2.db", executor=ex,
                        processor=dask_processor, progress=False)
        assert s1.stored == s2.stored == 3
        assert client.status == "running" and len(ex.stats) == 6
        assert all(received >= submitted for _, submitted, received in ex.stats)


def test_local_cluster_workers_exit_when_the_parent_is_killed(tmp_path):
    """SIGKILL of the ingest process (the OOM killer) ends the LocalCluster's worker processes:
    dask's own watch of the parent (``distributed.process``), as exit_with_parent in a pool."""
    from helpers import kill_parent_and_watch_workers

    assert kill_parent_and_watch_workers(tmp_path, 2, extra="{'scheduler': 'local'}") == []
