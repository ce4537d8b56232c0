"""The one Python API (surfidx.Database.open/ingest/query/get/export/remove), the README's
example, model management from the command line, exports opened with trimesh, Datasette."""

from __future__ import annotations

import json
import re
import shutil
import socket
import sqlite3
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

import surfidx
from surfidx import DatabaseError, InputError
from surfidx.cli import cli

from conftest import REPO, icosphere_mesh
from helpers import OBJ
from helpers import fake_processor, make_tree

trimesh = pytest.importorskip("trimesh")


def invoke(args, obj=OBJ):
    """Run the CLI; an ``ingest`` without ``--workers`` gets ``--workers 1`` (ids in file
    order; the default worker count is tested in test_ingest.py)."""
    args = [str(a) for a in args]
    if args[:1] == ["ingest"] and not {"-j", "--workers"} & set(args):
        args += ["--workers", "1"]
    return CliRunner().invoke(cli, args, obj=obj)


@pytest.fixture(scope="module")
def real(tmp_path_factory):
    """A database holding one model processed by the real pipeline (a level-2 icosphere with
    colours, 162 surfels, at 10 bits/surfel: its colour-grid header leaves 8 too little
    stream), stored as 'ball', and its folder."""
    root = tmp_path_factory.mktemp("real")
    v, f = icosphere_mesh(2)
    col = np.clip((v + 1) * 127.5, 0, 255).astype(np.uint8)
    trimesh.Trimesh(v, f, vertex_colors=col, process=False).export(root / "ball.glb")
    with surfidx.Database.open(root / "r.db") as db:
        summary = db.ingest(root / "ball.glb", tags=["demo"], workers=1, bits_per_surfel=10.0)
        assert (summary.stored, summary.failed) == (1, 0), summary.errors
    return root, root / "r.db"


def test_readme_example_runs(tmp_path, monkeypatch, capsys):
    text = (REPO / "README.md").read_text()
    block = re.search(r"^## Python.*?```python\n(.*?)```", text, re.S | re.M)
    monkeypatch.chdir(tmp_path)
    exec(compile(block.group(1), "README.md", "exec"), {})
    assert capsys.readouterr().out.splitlines()[:2] == ["['ball', 'capsule']", "capsule"]
    glb = trimesh.load(tmp_path / "capsule.glb", force="mesh")
    assert len(glb.faces) > 0
    with surfidx.Database.open("shapes.db", readonly=True) as db:
        assert [m["name"] for m in db.list_models()] == ["capsule"]


def test_get_and_export(real, tmp_path):
    root, path = real
    with surfidx.Database.open(path, readonly=True) as db:
        s = db.get("ball")
        assert s.name == "ball" and len(s) == 2562     # the stream's level 4: 2562 grid vertices
        assert len(db.get(1, level=1)) == 42
        mesh = db.get("ball", mesh=True)
        assert len(mesh.faces) == 5120
        # both convert to trimesh: the surfels to a point cloud, the mesh to a mesh
        cloud, tm = s.to_trimesh(), mesh.to_trimesh()
        assert isinstance(cloud, trimesh.PointCloud) and np.array_equal(cloud.vertices, s.positions)
        assert np.array_equal(cloud.colors[:, :3], s.colors) and cloud.metadata["name"] == "ball"
        assert isinstance(tm, trimesh.Trimesh) and np.array_equal(tm.faces, mesh.faces)
        assert np.array_equal(tm.vertices, mesh.vertices) and tm.metadata["name"] == "ball"
        assert np.array_equal(tm.visual.vertex_colors[:, :3], mesh.vertex_colors)
        full = db.get_sfz("ball")
        cut = db.get_sfz("ball", bits_per_surfel=8.5)      # the header takes 159 bytes
        assert len(cut) <= -(-8.5 * 162 // 8) < len(full)         # ceil(B·n/8) bytes
        for fmt in ("ply", "obj", "glb"):
            out = db.export("ball", tmp_path / f"b.{fmt}", level=2)
            assert out["format"] == fmt and out["surfels"] == 162 and out["level"] == 2
            if fmt == "ply":                         # surfels: points, no face element
                assert len(trimesh.load(tmp_path / "b.ply", process=False).vertices) == 162
                continue
            loaded = trimesh.load(tmp_path / f"b.{fmt}", force="mesh", process=False)
            # a texture by default: the vertices split along the atlas's seams
            assert len(loaded.vertices) > 162 and len(loaded.faces) == 320
            db.export("ball", tmp_path / f"v.{fmt}", level=2, texture=False)
            loaded = trimesh.load(tmp_path / f"v.{fmt}", force="mesh", process=False)
            assert len(loaded.vertices) == 162
            assert len(loaded.faces) == 320
        out = db.export("ball", tmp_path / "b.sfz", bits_per_surfel=8.5)
        assert out["bytes"] == len(cut) == (tmp_path / "b.sfz").stat().st_size
        assert db.list_models(tag="demo")[0]["tags"] == ["demo"]
        with pytest.raises(InputError, match="cannot tell the output format"):
            db.export("ball", tmp_path / "b.stl")
        with pytest.raises(InputError, match="does not hold the"):
            db.get_sfz("ball", bits_per_surfel=0.01)
    # the CLI: decode the exported stream, get in every format, --json, errors as JSON
    r = invoke(["decode", tmp_path / "b.sfz", "-o", tmp_path / "d.glb", "--json"], obj=None)
    assert r.exit_code == 0, r.output
    assert json.loads(r.stdout)["faces"] == 5120
    r = invoke(["decode", tmp_path / "b.sfz", "-o", tmp_path / "c.sfz",
                "--bits-per-surfel", 8.5], obj=None)
    assert r.exit_code == 0 and "bytes of stream at 8.5 bits/surfel" in r.stdout, r.output
    r = invoke(["get", "ball", "--db", path, "-o", tmp_path / "g.obj"], obj=None)
    assert r.exit_code == 0 and ("mesh of 2,562 vertices and 5,120 faces (OBJ, grid level 4, "
                                 "256² texture)") in r.stdout
    r = invoke(["get", "ball", "--db", path, "-o", tmp_path / "g.x", "--format", "sfz",
                "--json"], obj=None)
    assert r.exit_code == 0 and json.loads(r.stdout)["bytes"] == len(full)
    r = invoke(["get", "ball", "--db", path, "-o", tmp_path / "g.ply", "--max-surfels", 10,
                "--json"], obj=None)
    assert r.exit_code == 1 and "more than max_surfels = 10" in json.loads(r.stdout)["error"]
    r = invoke(["get", "nobody", "--db", path, "-o", tmp_path / "g.ply"], obj=None)
    assert r.exit_code == 1 and r.output.startswith(f"Error: {path}: no model named")


def test_query_by_name_leaves_itself_out(real, tmp_path):
    root, path = real
    with surfidx.Database.open(path, readonly=True) as db:
        assert db.query("ball", k=3) == []
        assert [h["name"] for h in db.query("ball", k=3, include_self=True)] == ["ball"]
        assert db.query(root / "ball.glb", k=3) == []       # the file of a stored model
        with pytest.raises(InputError, match="nobody: no such model file, and no stored model"):
            db.query("nobody")
        with pytest.raises(InputError, match="'id:x' is not a model id"):
            db.query("id:x")


def test_a_described_example_is_queried_as_its_model(real):
    """``Database.example`` describes once (the CLI draws its thumbnail on a contact sheet and
    queries with it); the same results as a query by the model itself."""
    from surfidx.database import QueryExample

    root, path = real
    with surfidx.Database.open(path, readonly=True) as db:
        ex = db.example("ball")
        assert isinstance(ex, QueryExample) and ex.name == "ball" and ex.id is not None
        assert ex.thumbnail[:8] == b"\x89PNG\r\n\x1a\n"
        assert db.query(ex, k=3, include_self=True) == db.query("ball", k=3, include_self=True)


def test_api_with_stub_processor(tmp_path):
    root = make_tree(tmp_path / "data", 3, extra={"bad.ply": "FAIL"})
    with surfidx.Database.open(tmp_path / "s.db") as db:
        s = db.ingest([root], processor=fake_processor, tags=["scan", "x"], workers=1)
        assert (s.stored, s.failed) == (3, 1)
        assert db.tags() == {"scan": 3, "x": 3}
        assert [m["name"] for m in db.list_models(name_like="m%")] == ["m0", "m2", "m1"]
        assert db.rename("m0", "first") == {"id": 1, "old_name": "m0", "name": "first"}
        with pytest.raises(DatabaseError, match="the name 'm2' is taken by model 2"):
            db.rename("first", "m2")
        with pytest.raises(InputError, match="must not be empty"):
            db.rename("first", " ")
        assert db.untag("first", "x") == 1 and db.tags("first") == ["scan"]
        with pytest.raises(InputError, match="no empty tag"):
            db.tag("first", [""])
        with pytest.raises(DatabaseError, match="no model named 'gone'"):
            db.remove("first", "gone")                   # nothing removed
        assert db.count() == 3
        assert db.remove("first", 2) == [{"id": 1, "name": "first", "version": 1},
                                             {"id": 2, "name": "m2", "version": 1}]
        with pytest.raises(InputError, match="name at least one model"):
            db.remove()
        assert db.conn.execute("SELECT count(*) FROM tags").fetchone()[0] == 2   # m1's
        with pytest.raises(InputError, match="name= names one model; 2 were given"):
            db.ingest([root, root], name="x", processor=fake_processor, workers=1)
        with pytest.raises(InputError, match="a name names one model"):
            db.ingest([root], name="x", processor=fake_processor, workers=1)
        one = db.ingest(root / "m0.ply", name="zero", processor=fake_processor, workers=1)
        assert db.get_model(one.ids[0])["name"] == "zero"


def test_management_commands(tmp_path):
    root = make_tree(tmp_path / "data", 3)
    (root / "other").mkdir()
    (root / "other" / "m0.ply").write_text("another m0\n")       # same stem, other folder
    db = tmp_path / "s.db"
    r = invoke(["ingest", root, "--db", db, "--no-progress", "--tag", "batch1"])
    assert r.exit_code == 0, r.output
    names = [m["name"] for m in json.loads(invoke(["ls", "--db", db, "--json"]).stdout)["models"]]
    assert sorted(names) == ["m0", "m1", "m2", "other"]
    r = invoke(["rename", "other", "m0b", "--db", db])
    assert r.exit_code == 0 and "-> m0b" in r.stdout
    r = invoke(["tag", "m0b", "bird", "flat", "--db", db, "--json"])
    assert json.loads(r.stdout)["tags"] == ["batch1", "bird", "flat"]
    r = invoke(["untag", "m0b", "flat", "--db", db])
    assert r.exit_code == 0 and "removed 1; tags: batch1, bird" in r.stdout
    r = invoke(["ls", "--db", db, "--tag", "bird", "--json"])
    assert [m["name"] for m in json.loads(r.stdout)["models"]] == ["m0b"]
    r = invoke(["ls", "--db", db, "--name-like", "m0%"])
    assert r.exit_code == 0 and len(r.stdout.splitlines()) == 3 and "bird" in r.stdout
    r = invoke(["rm", "m0b", "m1", "--db", db, "--json"])
    assert [x["name"] for x in json.loads(r.stdout)["removed"]] == ["m0b", "m1"]
    r = invoke(["rm", "nobody", "--db", db, "--json"])
    assert r.exit_code == 1 and json.loads(r.stdout) == {"error": f"{db}: no model named "
                                                                  "'nobody'"}
    r = invoke(["query", "m2", "--db", db, "--json"])                    # by name
    assert r.exit_code == 0 and [x["name"] for x in json.loads(r.stdout)["results"]] == ["m0"]
    r = invoke(["ingest", root / "m0.ply", "--db", tmp_path / "n.db", "--name", "zero",
                "--no-progress", "--json"])
    assert r.exit_code == 0 and json.loads(r.stdout)["stored"] == 1
    r = invoke(["ingest", root, "--db", tmp_path / "n.db", "--name", "x"])
    assert r.exit_code == 1 and "a name names one model" in r.output
    r = invoke(["datasette-metadata", "-o", tmp_path / "meta.json"])
    assert json.loads((tmp_path / "meta.json").read_text())["databases"]["*"]["tables"][
        "models"]["label_column"] == "name"


def test_closed_pipe_is_quiet(tmp_path):
    root = make_tree(tmp_path / "data", 1)
    db = tmp_path / "s.db"
    assert invoke(["ingest", root, "--db", db, "--no-progress"]).exit_code == 0
    code = ("import sys; sys.path.insert(0, sys.argv[1]); from surfidx.cli import cli; "
            "cli.main(sys.argv[2:])")
    p = subprocess.run(f"{sys.executable} -c '{code}' {REPO / 'tests'} ls --db {db} --json "
                       "| head -c 1", shell=True, capture_output=True, text=True, timeout=120)
    assert "Broken pipe" not in p.stderr and "Traceback" not in p.stderr


def test_deleting_with_foreign_keys_off_leaves_no_orphans(tmp_path):
    root = make_tree(tmp_path / "data", 2)
    with surfidx.Database.open(tmp_path / "s.db") as db:
        db.ingest([root], processor=fake_processor, tags=["t"], workers=1)
    conn = sqlite3.connect(tmp_path / "s.db")                     # foreign keys off
    assert conn.execute("PRAGMA foreign_keys").fetchone()[0] == 0
    conn.execute("DELETE FROM models WHERE id = 1")
    conn.commit()
    for table in ("assets", "descriptors", "thumbnails", "tags"):
        assert conn.execute(f"SELECT count(*) FROM {table} WHERE model_id = 1").fetchone()[0] \
            == 0, table
    assert conn.execute("SELECT count(*) FROM thumbnails").fetchone()[0] == 1
    conn.close()
    import sqlite_utils

    sdb = sqlite_utils.Database(tmp_path / "s.db")
    sdb["models"].delete(2)
    assert sdb["assets"].count == sdb["descriptors"].count == sdb["tags"].count == 0


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_datasette_shows_names_and_thumbnails(tmp_path):
    pytest.importorskip("datasette")
    pytest.importorskip("datasette_render_images")
    exe = shutil.which("datasette") or str(Path(sys.executable).parent / "datasette")
    root = make_tree(tmp_path / "data", 2)
    db = tmp_path / "surfidx.db"
    with surfidx.Database.open(db) as d:
        d.ingest([root], processor=fake_processor)
    assert invoke(["datasette-metadata", "-o", tmp_path / "meta.json"]).exit_code == 0
    port = _free_port()
    proc = subprocess.Popen([exe, str(db), "--metadata", str(tmp_path / "meta.json"), "-h",
                             "127.0.0.1", "-p", str(port)], stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL)
    try:
        pages = {}
        deadline = time.monotonic() + 60                 # a guard against a hang, not a timing
        for page in ("model_gallery", "thumbnails", "assets_named", "tags", "descriptors"):
            while True:
                try:
                    url = f"http://127.0.0.1:{port}/surfidx/{page}"
                    pages[page] = urllib.request.urlopen(url, timeout=10).read().decode()
                    break
                except OSError:
                    if time.monotonic() > deadline or proc.poll() is not None:
                        raise
                    time.sleep(0.3)
    finally:
        proc.terminate()
        proc.wait(timeout=30)
    # datasette-render-images' data URIs, or surfidx's plugin's PNG route once installed
    assert (pages["model_gallery"].count('<img src="data:image/png;base64,')
            + pages["model_gallery"].count('<img src="/-/surfidx/surfidx/')) == 2
    assert pages["thumbnails"].count("<img") >= 2
    for page in ("model_gallery", "assets_named", "descriptors"):
        assert ">m0<" in pages[page] or ">m0 " in pages[page] or "m0</a>" in pages[page], page


def test_ingest_again_with_tags_tags_the_stored_models(tmp_path):
    """A re-run with ``tags`` stores nothing new but tags the models it finds stored."""
    root = make_tree(tmp_path / "data", 2)
    with surfidx.Database.open(tmp_path / "t.db") as db:
        db.ingest([root], processor=fake_processor, workers=1)
        assert db.tags() == {}
        s = db.ingest([root], processor=fake_processor, tags=["archive"], workers=1)
        assert (s.stored, s.skipped) == (0, 2)
        assert db.tags() == {"archive": 2}
