"""ingest: discovery, texture pairing, skipping, failures, crashes, interruption and resuming."""

from __future__ import annotations

import hashlib
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

import ingest
from surfidx import DatabaseError, InputError, SurfidxError
from surfidx.database import Database
from surfidx.io.files import NotRegularFile, find_texture
from surfidx.pipeline import content_hash

from helpers import (bytes_name, fake_processor, kill_parent_and_watch_workers, make_tree,
                     process_dead, tiny_png, wait_dead)

TESTS = Path(__file__).resolve().parent


# ---------------------------------------------------------------------- processor doubles


def count_rows(path):
    with Database(path) as d:
        return {t: d.db[t].count for t in ("models", "assets", "descriptors", "thumbnails")}


# ---------------------------------------------------------------------- discovery
def test_discover(tmp_path):
    root = make_tree(tmp_path / "data", 4)
    explicit = tmp_path / "x.weird"
    explicit.write_text("model x")
    found = ingest.discover([root, explicit, root / "m0.ply"])
    assert found == sorted(found)
    names = [p.name for p in found]
    assert sorted(names) == ["m0.ply", "m1.obj", "m2.off", "m3.ply", "x.weird"]
    assert all(p.is_absolute() for p in found)
    with pytest.raises(InputError, match=r"missing\.ply: no such file or folder"):
        ingest.discover([root, tmp_path / "missing.ply"])
    with pytest.raises(InputError, match="at least one model file or folder"):
        ingest.discover([])


def test_find_texture(tmp_path):
    obj = "v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 0 1\nf 1/1 2/2 3/3\n"
    a = tmp_path / "a"
    a.mkdir()
    (a / "cow.obj").write_text(obj)
    assert find_texture(a / "cow.obj") is None                 # no PNG
    (a / "single.png").write_bytes(tiny_png())
    assert find_texture(a / "cow.obj") == a / "single.png"     # the only PNG
    (a / "other.png").write_bytes(tiny_png(1))
    assert find_texture(a / "cow.obj") is None                 # ambiguous
    (a / "cow.png").write_bytes(tiny_png(2))
    assert find_texture(a / "cow.obj") == a / "cow.png"
    (a / "cow_texture.png").write_bytes(tiny_png(3))
    assert find_texture(a / "cow.obj") == a / "cow_texture.png"
    (a / "plain.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")  # no UVs
    assert find_texture(a / "plain.obj") is None
    (a / "named.obj").write_text("mtllib named.mtl\n" + obj)
    (a / "named.mtl").write_text("newmtl m\nmap_Kd cow.png\n")
    assert find_texture(a / "named.obj") is None               # the MTL names one
    (a / "m.ply").write_text("ply")
    assert find_texture(a / "m.ply") is None


def test_spot_example_gets_its_texture():
    spot = TESTS.parent / "examples" / "models" / "spot" / "spot_triangulated.obj"
    tex = find_texture(spot)
    assert tex is not None and tex.name == "spot_texture.png"
    task, = ingest.make_tasks([spot])
    assert task.texture == str(tex)
    assert task.content_hash == content_hash(spot, texture=tex) != content_hash(spot)


def test_texture_bytes_change_the_hash(tmp_path, monkeypatch):
    (tmp_path / "cow.obj").write_text("v 0 0 0\nvt 0 0\nf 1/1 1/1 1/1\n")
    (tmp_path / "cow.png").write_bytes(tiny_png(1))
    db = tmp_path / "t.db"
    s1 = ingest.run([tmp_path / "cow.obj"], db=db, processor=fake_processor, progress=False,
                    workers=1)
    assert s1.stored == 1
    with Database(db) as d:
        m = d.get_model("cow")
        assert m["has_color"] and m["params"]["texture"] == str(tmp_path / "cow.png")
    (tmp_path / "cow.png").write_bytes(tiny_png(2))                  # new texture: new model
    s2 = ingest.run([tmp_path / "cow.obj"], db=db, processor=fake_processor, progress=False,
                    workers=1)
    assert (s2.stored, s2.skipped) == (1, 0)


# ---------------------------------------------------------------------- runs
def test_ingest_folder_counts_failures_and_rerun(tmp_path):
    root = make_tree(tmp_path / "data", 6, extra={"bad.ply": "FAIL", "boom.obj": "BOOM",
                                                   "zdup.ply": "model 0\n"})
    db = tmp_path / "s.db"
    s = ingest.run([root], db=db, processor=fake_processor, progress=False, batch=3, workers=1)
    # zdup.ply has m0.ply's bytes: skipped as a duplicate within the run
    assert (s.stored, s.skipped, s.failed, s.status) == (6, 1, 2, "finished")
    errors = dict(s.errors)
    assert errors[str(root / "bad.ply")] == f"{root / 'bad.ply'}: deliberately unusable model"
    assert errors[str(root / "boom.obj")] == "RuntimeError: kaboom"
    with Database(db) as d:
        assert sorted(m["name"] for m in d.list_models()) == [f"m{i}" for i in range(6)]
        run = d.last_run()
        assert (run["stored"], run["skipped"], run["failed"], run["status"]) == (6, 1, 2,
                                                                                  "finished")
        assert {e["path"]: e["error"] for e in d.errors(run["id"])} == errors
        assert sorted(s.ids) == [m["id"] for m in d.list_models()]
    again = ingest.run([root], db=db, processor=fake_processor, progress=False, workers=1)
    assert (again.stored, again.skipped, again.failed) == (0, 7, 2)
    assert count_rows(db)["models"] == 6


def test_stored_model_hash_is_the_task_hash(tmp_path):
    def other_hash(path, **kw):
        m = fake_processor(path, **kw)
        m.content_hash = "something else"
        return m

    (tmp_path / "a.ply").write_text("model a")
    db = tmp_path / "h.db"
    ingest.run([tmp_path], db=db, processor=other_hash, progress=False, workers=1)
    assert ingest.run([tmp_path], db=db, processor=other_hash, progress=False,
                      workers=1).skipped == 1


def test_parallel_workers_and_crash(tmp_path):
    root = make_tree(tmp_path / "data", 5, extra={"crash.ply": "CRASH", "bad.off": "FAIL"})
    db = tmp_path / "p.db"
    s = ingest.run([root], db=db, workers=2, processor=fake_processor, progress=False)
    assert (s.stored, s.skipped, s.failed) == (5, 0, 2)
    errors = dict(s.errors)
    assert errors[str(root / "crash.ply")].startswith("worker process crashed (BrokenProcessPool")
    assert "deliberately unusable" in errors[str(root / "bad.off")]
    # Same records as a serial run (without the crasher: it would end this very process).
    (root / "crash.ply").unlink()
    serial_db = tmp_path / "serial.db"
    ingest.run([root], db=serial_db, workers=1, processor=fake_processor, progress=False)
    with Database(db) as a, Database(serial_db) as b:
        key = lambda d: sorted((m["name"], m["content_hash"]) for m in d.list_models())  # noqa
        assert key(a) == key(b)


@pytest.mark.slow
def test_spawn_context(tmp_path):
    """Workers started by spawn (as on macOS/Windows) import the processor by name."""
    import multiprocessing

    make_tree(tmp_path / "data", 2)
    pool = ingest.ProcessPool(2, mp_context=multiprocessing.get_context("spawn"))
    s = ingest.run([tmp_path / "data"], db=tmp_path / "sp.db", processor=fake_processor,
                   executor=pool, progress=False)
    assert (s.stored, s.failed) == (2, 0), s.errors


def test_custom_executor(tmp_path):
    make_tree(tmp_path / "data", 3)
    calls = []

    def executor(fn, tasks):
        calls.append(len(tasks))
        for task in reversed(tasks):
            yield fn(task)

    s = ingest.run([tmp_path / "data"], db=tmp_path / "e.db", processor=fake_processor,
                   executor=executor, progress=False)
    assert s.stored == 3 and calls == [3]


def test_keyboard_interrupt_then_resume(tmp_path):
    root = make_tree(tmp_path / "data", 6, extra={"m2z.off": "INTERRUPT"})
    db = tmp_path / "i.db"
    with pytest.raises(KeyboardInterrupt):
        ingest.run([root], db=db, processor=fake_processor, progress=False, batch=100, workers=1)
    with Database(db) as d:
        run = d.last_run()
        assert run["status"] == "interrupted"
        done = {m["name"] for m in d.list_models()}
    assert done == {"m0", "m2"}              # finished before the interrupt, written on the way out
    rows = count_rows(db)
    assert rows["models"] == rows["assets"] == rows["thumbnails"] == 2
    (root / "m2z.off").write_text("model fixed")
    s = ingest.run([root], db=db, processor=fake_processor, progress=False, workers=1)
    assert (s.stored, s.skipped, s.failed) == (5, 2, 0)
    with Database(db) as d:
        names = [m["name"] for m in d.list_models()]
    assert sorted(names) == sorted(set(names)) == sorted([f"m{i}" for i in range(6)] + ["m2z"])


_KILL_SCRIPT = """
import sys
sys.path.insert(0, {tests!r})
import ingest, helpers
ingest.run([{root!r}], db={db!r}, processor=helpers.fake_processor, progress=False,
           batch=1, workers=1)
"""


def test_sigkill_mid_run_then_resume(tmp_path, monkeypatch):
    root = tmp_path / "data"
    root.mkdir()
    for i in range(12):
        (root / f"s{i:02d}.ply").write_text(f"model {i} SLOW")
    db = tmp_path / "k.db"
    script = _KILL_SCRIPT.format(tests=str(TESTS), root=str(root), db=str(db))
    proc = subprocess.Popen([sys.executable, "-c", script], stderr=subprocess.PIPE)
    deadline = time.monotonic() + 60
    try:
        while time.monotonic() < deadline:
            time.sleep(0.2)
            if db.exists():
                try:
                    with Database(db, create=False) as d:
                        if d.count() >= 3:
                            break
                except DatabaseError:
                    pass
            assert proc.poll() is None, proc.stderr.read().decode()[-2000:]
        os.kill(proc.pid, signal.SIGKILL)
    finally:
        proc.wait()
    rows = count_rows(db)
    assert 3 <= rows["models"] < 12
    assert rows["models"] == rows["assets"] == rows["thumbnails"]
    assert rows["descriptors"] == rows["models"]
    with Database(db) as d:
        assert d.last_run()["status"] == "running"           # killed: never finished
    monkeypatch.setattr(time, "sleep", lambda seconds: None)     # the re-run need not be slow
    s = ingest.run([root], db=db, processor=fake_processor, progress=False, workers=1)
    assert s.skipped == rows["models"] and s.stored == 12 - rows["models"] and s.failed == 0
    with Database(db) as d:
        names = [m["name"] for m in d.list_models()]
    assert sorted(names) == [f"s{i:02d}" for i in range(12)]


def test_progress_bar_goes_to_stderr(tmp_path, capsys):
    make_tree(tmp_path / "data", 2)
    ingest.run([tmp_path / "data"], db=tmp_path / "b.db", processor=fake_processor,
               progress=True, workers=1)
    out, err = capsys.readouterr()
    assert out == "" and "ingest" in err and "2/2" in err


def test_run_argument_errors(tmp_path):
    make_tree(tmp_path / "data", 1)
    kw = dict(db=tmp_path / "x.db", processor=fake_processor, progress=False)
    with pytest.raises(InputError, match="workers must be at least 1"):
        ingest.run([tmp_path / "data"], workers=0, **kw)
    with pytest.raises(InputError, match="bits_per_surfel must be positive"):
        ingest.run([tmp_path / "data"], bits_per_surfel=0, **kw)
    with pytest.raises(InputError, match="batch must be at least 1"):
        ingest.run([tmp_path / "data"], batch=0, **kw)
    with pytest.raises(InputError, match="no such file or folder"):
        ingest.run([tmp_path / "nothing"], **kw)
    kw["processor"] = lambda path, **k: fake_processor(path, **k)
    with pytest.raises(InputError, match="processor must be picklable"):
        ingest.run([tmp_path / "data"], workers=2, **kw)
    assert not (tmp_path / "x.db").exists()           # argument errors come before any write


def test_default_processor_is_resolved_lazily(monkeypatch):
    import surfidx.pipeline as pipeline

    sentinel = object()
    monkeypatch.setattr(pipeline, "process_model", sentinel, raising=False)
    assert ingest.resolve_processor(None) is sentinel
    assert ingest.resolve_processor(fake_processor) is fake_processor
    monkeypatch.delattr(pipeline, "process_model")
    with pytest.raises(SurfidxError, match="process_model is not available"):
        ingest.resolve_processor(None)


def test_error_message():
    assert ingest.error_message(InputError("bad", path="a.ply")) == "a.ply: bad"
    assert ingest.error_message(ValueError("nope")) == "ValueError: nope"
    assert ingest.error_message(MemoryError()) == "MemoryError"


def test_unreadable_file_is_recorded(tmp_path):
    (tmp_path / "ok.ply").write_text("model ok")
    (tmp_path / "dangling.ply").symlink_to(tmp_path / "gone.ply")     # listed, cannot be read
    s = ingest.run([tmp_path], db=tmp_path / "u.db", processor=fake_processor, progress=False,
                   workers=1)
    assert (s.stored, s.failed) == (1, 1)
    assert s.errors == [(str(tmp_path / "dangling.ply"),
                         "cannot read (No such file or directory)")]
    with Database(tmp_path / "u.db") as d:
        assert d.errors()[0]["error"] == "cannot read (No such file or directory)"


def test_sha_of_hash_matches_pipeline(tmp_path):
    f = tmp_path / "a.ply"
    f.write_bytes(b"abc")
    task, = ingest.make_tasks([f])
    assert task.content_hash == hashlib.sha256(b"abc").hexdigest()


def test_heartbeat_flushes_by_time(tmp_path):
    make_tree(tmp_path / "data", 2)
    db = tmp_path / "hb.db"
    seen = []

    def executor(fn, tasks):
        yield fn(tasks[0])
        yield None                                   # waiting: the finished model is written
        with Database(db) as d:
            seen.append(d.count())
        yield fn(tasks[1])

    s = ingest.run([tmp_path / "data"], db=db, processor=fake_processor, executor=executor,
                   progress=False, batch=100, flush_seconds=0.0)
    assert s.stored == 2 and seen == [1]


def test_process_pool_heartbeat_and_stop(tmp_path):
    import functools

    f = tmp_path / "hang.ply"
    f.write_text("HANG")
    task, = ingest.make_tasks([f])
    pool = ingest.ProcessPool(1, heartbeat=0.05)
    gen = pool(functools.partial(ingest.process_task, processor=fake_processor,
                                 bits_per_surfel=8.0), [task])
    assert next(gen) is None                         # nothing finished yet: a heartbeat
    procs = list(pool._pool._processes.values())
    t0 = time.monotonic()
    gen.close()                                      # the caller stops: workers are terminated
    # The executor's manager thread joins (reaps) the same processes concurrently, so a join
    # here may see ECHILD before that thread records the exit code: poll the exit code instead.
    # (a generous guard against a hang, not a timing assertion: a loaded machine is slow)
    while any(p.exitcode is None for p in procs) and time.monotonic() - t0 < 60:
        time.sleep(0.01)
    assert [p.exitcode is not None for p in procs] == [True] * len(procs)


def test_scheduler_without_distributed_says_how_to_install(tmp_path, monkeypatch):
    import sys

    make_tree(tmp_path / "data", 1)
    monkeypatch.setitem(sys.modules, "distributed", None)          # import distributed fails
    with pytest.raises(SurfidxError, match=r"needs dask\.distributed.*"
                                           r"pip install 'surfidx\[distributed\]'"):
        ingest.run([tmp_path / "data"], db=tmp_path / "x.db", scheduler="local",
                   processor=fake_processor, progress=False)
    assert not (tmp_path / "x.db").exists()


def test_processed_model_records_the_mesh_conversion(tmp_path):
    """The stored parameters say how a mesh became surfels: bisection threshold, or sampling."""
    from conftest import icosphere_mesh

    from surfidx.geometry.mesh import MAX_EDGE_RATIO
    from surfidx.pipeline import process_model
    from surfidx.codec.resample import PHONG_ALPHA, PHONG_SHARPNESS

    v, f = icosphere_mesh(3)
    path = tmp_path / "blob.off"
    lines = ["OFF", f"{len(v)} {len(f)} 0"] + [" ".join(map(str, p)) for p in v * [1, 1.2, 0.9]]
    path.write_text("\n".join(lines + [f"3 {a} {b} {c}" for a, b, c in f]) + "\n")
    per_vertex = process_model(path, bits_per_surfel=4.0, level=4, thumbnail_size=32)
    assert per_vertex.params["max_edge_ratio"] == MAX_EDGE_RATIO
    assert per_vertex.params["samples"] is None and per_vertex.n_surfels == len(v)
    sampled = process_model(path, bits_per_surfel=4.0, level=4, thumbnail_size=32, samples=900)
    assert sampled.params["max_edge_ratio"] is None and sampled.n_surfels == 900
    # the resampling lift is recorded with the data it produced
    assert per_vertex.params["lift"] == {"phong": PHONG_ALPHA, "sharpness": PHONG_SHARPNESS}


def test_processed_surfel_file_records_no_mesh_conversion(tmp_path):
    """A surfel file was not converted from a mesh: no bisection threshold is recorded."""
    from conftest import icosphere_mesh

    from surfidx import SurfelSet, write_ply
    from surfidx.pipeline import process_model

    v, _ = icosphere_mesh(3)
    path = tmp_path / "blob.ply"
    write_ply(SurfelSet(v, v, np.full(len(v), 0.1)), path)
    model = process_model(path, bits_per_surfel=4.0, level=4, thumbnail_size=32)
    assert model.params["max_edge_ratio"] is None and model.params["samples"] is None


# ---------------------------------------------------------------------- whatever a file is (#30)


def _run_guarded(fn, seconds=120):
    """``fn()`` in a daemon thread; fails the test instead of hanging it."""
    import threading

    out = {}

    def target():
        try:
            out["value"] = fn()
        except BaseException as exc:  # noqa: BLE001 - re-raised below
            out["error"] = exc

    t = threading.Thread(target=target, daemon=True)
    t.start()
    t.join(seconds)
    assert not t.is_alive(), "ingest hung"
    if "error" in out:
        raise out["error"]
    return out["value"]


def test_non_utf8_file_names_are_ingested_and_stored_escaped(tmp_path):
    from surfidx.db.catalog import escape_name, storable_text, unescape_name

    root = tmp_path / "data"
    root.mkdir()
    good = bytes_name(root, b"caf\xe9.ply", b"model cafe")
    bad = bytes_name(root, b"bad\xff\\x.ply", b"FAIL")
    db = tmp_path / "n.db"
    s = ingest.run([root], db=db, processor=fake_processor, progress=False, workers=1)
    assert (s.stored, s.failed, s.status) == (1, 1, "finished")
    # the path as stored (lossless), the message with the byte escaped (backslashes kept)
    assert s.errors == [(escape_name(bad), f"{storable_text(bad)}: deliberately unusable model")]
    assert s.errors[0][0].endswith("bad\\xff\\\\x.ply")            # the byte and the backslash
    with Database(db) as d:
        m, = d.list_models()
        assert m["name"] == "caf\\xe9" and m["source"] == "caf\\xe9.ply"
        assert m["source_abs"] == escape_name(good)
        assert os.fsencode(unescape_name(m["source_abs"])) == os.fsencode(good)   # lossless
        assert d.get_model("caf\\xe9")["id"] == d.get_model(os.fsdecode(b"caf\xe9"))["id"]
        err, = d.errors()
        assert err["path"] == escape_name(bad)
        assert d.last_run()["status"] == "finished"
    again = ingest.run([root], db=db, processor=fake_processor, progress=False, workers=1)
    assert (again.stored, again.skipped, again.failed, again.status) == (0, 1, 1, "finished")


@pytest.mark.parametrize("workers", [1, 2])
def test_fifo_and_links_to_devices_are_skipped_with_the_reason(tmp_path, workers):
    root = tmp_path / "data"
    root.mkdir()
    (root / "ok.ply").write_text("model ok")
    os.mkfifo(root / "pipe.ply")
    (root / "zero.ply").symlink_to("/dev/zero")
    (root / "loop.off").symlink_to(root / "loop.off")               # cannot be read: a failure
    db = tmp_path / "f.db"
    s = _run_guarded(lambda: ingest.run([root, root / "pipe.ply"], db=db, workers=workers,
                                        processor=fake_processor, progress=False))
    assert (s.stored, s.skipped, s.failed, s.status) == (1, 2, 1, "finished")
    assert sorted(s.skips) == [
        (str(root / "pipe.ply"), "not a regular file: a named pipe (FIFO)"),
        (str(root / "zero.ply"), "not a regular file: a symbolic link to a character device")]
    assert s.errors == [(str(root / "loop.off"), "cannot read (Too many levels of symbolic "
                                                 "links)")]
    with Database(db) as d:
        recorded = {e["path"]: e["error"] for e in d.errors()}
    assert recorded == {
        str(root / "pipe.ply"): "skipped: not a regular file: a named pipe (FIFO)",
        str(root / "zero.ply"): "skipped: not a regular file: a symbolic link to a character "
                                "device",
        str(root / "loop.off"): "cannot read (Too many levels of symbolic links)"}


def test_reading_is_bounded_and_never_blocks(tmp_path):
    f = tmp_path / "a.obj"
    f.write_bytes(b"v 0 0 0\nvt 0 0\nmtllib m.mtl\nmtllib z.mtl\n")
    os.mkfifo(tmp_path / "m.mtl")                  # an MTL that is a FIFO is not read
    (tmp_path / "z.mtl").symlink_to("/dev/zero")   # nor one that never ends
    (tmp_path / "a.png").write_bytes(tiny_png())
    tex = _run_guarded(lambda: find_texture(f), 60)
    assert tex == tmp_path / "a.png"
    assert ingest.hash_files(f, texture=tex) == content_hash(f, texture=tex)
    with pytest.raises(NotRegularFile, match="not a regular file: a character device"):
        ingest.hash_files("/dev/zero")
    with pytest.raises(NotRegularFile, match=r"a named pipe \(FIFO\)"):
        _run_guarded(lambda: ingest.hash_files(tmp_path / "m.mtl"), 60)
    (tmp_path / "z.obj").symlink_to("/dev/zero")
    with pytest.raises(NotRegularFile, match="symbolic link to a character device"):
        _run_guarded(lambda: find_texture(tmp_path / "z.obj"), 60)


def test_pool_workers_exit_when_the_parent_is_killed(tmp_path):
    assert kill_parent_and_watch_workers(tmp_path, 2) == []


def test_exit_with_parent_fallback_thread(tmp_path):
    """Without prctl (not Linux), the watchdog thread alone ends an orphaned worker."""
    child = ("import sys, time; sys.platform = 'elsewhere'; import ingest; "
             "ingest.exit_with_parent(poll=0.05); print('ready', flush=True); time.sleep(120)")
    parent = ("import subprocess, sys, time; "
              f"c = subprocess.Popen([sys.executable, '-c', {child!r}], stdout=subprocess.PIPE); "
              "c.stdout.readline(); print(c.pid, flush=True); time.sleep(120)")
    proc = subprocess.Popen([sys.executable, "-c", parent], stdout=subprocess.PIPE)
    try:
        pid = int(proc.stdout.readline())
        assert not process_dead(pid)
        os.kill(proc.pid, signal.SIGKILL)
    finally:
        proc.wait()
    assert wait_dead([pid]) == []


def test_find_texture_reads_the_mtl_as_io_does(tmp_path):
    """A ``map_Kd`` without an image names no texture (as surfidx.io reads it), so the PNG beside
    the OBJ is used; an MTL that cannot be read names none either."""
    obj = "v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 0 1\nf 1/1 2/2 3/3\n"
    (tmp_path / "t.png").write_bytes(tiny_png())
    (tmp_path / "a.obj").write_text("mtllib a.mtl\n" + obj)
    (tmp_path / "a.mtl").write_text("newmtl m\nmap_Kd\n")
    assert find_texture(tmp_path / "a.obj") == tmp_path / "t.png"
    (tmp_path / "b.obj").write_text("mtllib missing.mtl\n" + obj)
    assert find_texture(tmp_path / "b.obj") == tmp_path / "t.png"


def test_run_records_a_single_path_given_as_text(tmp_path):
    """``paths`` may be one path as text: the run record holds it whole."""
    root = make_tree(tmp_path / "data", 2)
    s = ingest.run(str(root), db=tmp_path / "s.db", processor=fake_processor, progress=False,
                   workers=1)
    assert s.stored == 2
    with Database(tmp_path / "s.db") as d:
        assert d.last_run()["paths"] == [str(root)]
