"""Model versions and provenance, originals kept by ``ingest --keep-original``, and the
migration of databases made by the previous schema (issue 55, items 1 and 2)."""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import sqlite3
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

import ingest
import surfidx.db.catalog as dbmod
from surfidx import DatabaseError, InputError
from surfidx.cli import cli
from surfidx.database import Database
from surfidx.db.catalog import SCHEMA_VERSION, schema_sql
from surfidx.io import original_files

from conftest import EXAMPLES
from helpers import OBJ, TESTS, fake_processor, make_tree, tiny_png

#: A database as surfidx 0.1.0 made it at schema 3 (main at 6539710): the two bundled
#: examples ingested at 1 bit per surfel, tagged "example"
#: (``surfidx ingest examples/models --db old.db --bits-per-surfel 1 --tag example``).
SCHEMA3 = TESTS / "data" / "schema3_main.db"


def invoke(args, obj=OBJ):
    args = [str(a) for a in args]
    if args[:1] == ["ingest"] and not {"-j", "--workers"} & set(args):
        args += ["--workers", "1"]
    return CliRunner().invoke(cli, args, obj=obj)


def _schema_of(conn) -> dict:
    import re

    return {r[0]: re.sub(r"\s+", " ", r[1]) for r in conn.execute(
        "SELECT name, sql FROM sqlite_master WHERE sql IS NOT NULL")}


def _old_copy(tmp_path) -> Path:
    tmp_path.mkdir(parents=True, exist_ok=True)
    path = tmp_path / "old.db"
    shutil.copy(SCHEMA3, path)
    return path


def _raw_rows(path) -> dict:
    """id -> (name, source, stream, png) of a schema-3 file, read with plain sqlite3."""
    conn = sqlite3.connect(path)
    try:
        return {r[0]: r[1:] for r in conn.execute(
            "SELECT m.id, m.name, m.source, a.stream, t.png FROM models m JOIN assets a ON "
            "a.model_id = m.id JOIN thumbnails t ON t.model_id = m.id")}
    finally:
        conn.close()


# ---------------------------------------------------------------------- migration
def test_fixture_is_a_schema3_database():
    conn = sqlite3.connect(f"file:{SCHEMA3}?mode=ro", uri=True)
    assert conn.execute("PRAGMA user_version").fetchone()[0] == 3
    cols = [r[1] for r in conn.execute("PRAGMA table_info(models)")]
    assert "version" not in cols and conn.execute("SELECT count(*) FROM models").fetchone()[0] == 2
    conn.close()


def test_schema3_database_migrates_keeping_every_model(tmp_path):
    path = _old_copy(tmp_path)
    before = _raw_rows(path)
    with pytest.warns(UserWarning, match=r"upgraded from schema version 3 to 4; the file as it "
                                         r"was is kept as .*old\.db\.schema-3\.bak"):
        db = Database(path)
    with db:
        assert db.schema_version == SCHEMA_VERSION == 4
        assert (db.upgraded_from, db.backup_path) == (3, path.with_name("old.db.schema-3.bak"))
        for mid, (name, source, stream, png) in before.items():
            rec = db.get_model(mid)
            assert (rec["name"], rec["version"], rec["latest"]) == (name, 1, True)
            assert rec["source_abs"] == source and rec["source"] == {
                "spot_triangulated": "spot/spot_triangulated.obj",
                "armadillo": "armadillo.obj"}[name]              # relative to the run's folder
            assert (rec["surfidx_version"], rec["codec_version"], rec["descriptor_version"],
                    rec["numerics_profile"]) == ("0.1.0", 4, 7, "x86-64-v3")
            assert rec["source_bytes"] is None and rec["source_mtime"] is None   # unknown
            assert rec["tags"] == ["example"] and rec["original"] == []
            assert db.get_stream(name) == stream and db.get_sfz(mid) == stream   # byte-identical
            assert db.get_thumbnail(mid) == png
        assert [r["name"] for r in db.list_models()] == ["spot_triangulated", "armadillo"]
        hits = db.query("armadillo", k=1)
        assert [h["name"] for h in hits] == ["spot_triangulated"]
        assert db.conn.execute("PRAGMA foreign_key_check").fetchall() == []
        migrated = _schema_of(db.conn)
    with Database(tmp_path / "new.db") as fresh:
        assert migrated == _schema_of(fresh.conn)
    # the copy kept is the schema-3 file as it was
    assert _raw_rows(path.with_name("old.db.schema-3.bak")) == before
    conn = sqlite3.connect(path.with_name("old.db.schema-3.bak"))
    assert conn.execute("PRAGMA user_version").fetchone()[0] == 3
    conn.close()


def test_migrated_model_decodes_as_the_stored_stream(tmp_path):
    from surfidx.codec import decode

    path = _old_copy(tmp_path)
    stream = _raw_rows(path)[1][2]
    with pytest.warns(UserWarning, match="upgraded"), Database(path) as db:
        got = db.get("spot_triangulated", level=3)
    want = decode(stream, level=3)
    assert np.array_equal(got.positions, want.positions)
    assert np.array_equal(got.colors, want.colors)


def test_failed_migration_leaves_the_file_as_it_was(tmp_path, monkeypatch):
    path = _old_copy(tmp_path)
    digest = hashlib.sha256(path.read_bytes()).hexdigest()

    real = dbmod.MIGRATIONS[2]

    def broken(conn):
        real(conn)
        conn.execute("SELECT * FROM no_such_table")

    monkeypatch.setattr(dbmod, "MIGRATIONS", [*dbmod.MIGRATIONS[:2], broken])
    with pytest.raises(DatabaseError, match=r"upgrading the schema to version 4 failed .*"
                                            r"the file is unchanged"):
        Database(path)
    conn = sqlite3.connect(path)
    assert conn.execute("PRAGMA user_version").fetchone()[0] == 3
    assert "version" not in [r[1] for r in conn.execute("PRAGMA table_info(models)")]
    assert conn.execute("SELECT count(*) FROM assets").fetchone()[0] == 2   # nothing cascaded
    conn.close()
    assert _raw_rows(path) == _raw_rows(SCHEMA3)
    assert hashlib.sha256(path.read_bytes()).hexdigest() == digest


def test_migration_removes_orphans_and_checks_foreign_keys(tmp_path, monkeypatch):
    path = _old_copy(tmp_path)
    conn = sqlite3.connect(path)                    # a client without foreign keys or triggers
    conn.execute("DROP TRIGGER models_delete_rows")
    conn.execute("DELETE FROM models WHERE name = 'armadillo'")
    conn.commit()
    conn.close()
    with pytest.warns(UserWarning, match="upgraded"), Database(path) as db:
        assert db.count() == 1
        for table in ("assets", "descriptors", "thumbnails", "tags"):
            ids = {r[0] for r in db.conn.execute(f"SELECT model_id FROM {table}")}
            assert ids == {1}, table
    path = _old_copy(tmp_path / "again")
    real = dbmod.MIGRATIONS[2]

    def orphan(conn):
        real(conn)
        conn.execute("INSERT INTO tags (model_id, tag) VALUES (99, 'lost')")

    monkeypatch.setattr(dbmod, "MIGRATIONS", [*dbmod.MIGRATIONS[:2], orphan])
    with pytest.raises(DatabaseError, match=r"failed \(.*row \d+ of table tags refers to a "
                                            r"missing row of models\)\); the file is unchanged"):
        Database(path)


def test_migration_refused_when_the_copy_cannot_be_kept(tmp_path, monkeypatch):
    path = _old_copy(tmp_path)
    monkeypatch.setattr(Database, "backup_name",
                        lambda self, version: tmp_path / "no" / "such" / "dir" / "x.bak")
    with pytest.raises(DatabaseError, match=r"old\.db: schema version 3 must be upgraded to 4, "
                                            r"and the copy kept before that cannot be written"):
        Database(path)
    conn = sqlite3.connect(path)
    assert conn.execute("PRAGMA user_version").fetchone()[0] == 3
    conn.close()


def test_newer_database_is_refused(tmp_path):
    path = _old_copy(tmp_path)
    conn = sqlite3.connect(path)
    conn.execute(f"PRAGMA user_version = {SCHEMA_VERSION + 1}")
    conn.close()
    for kwargs in ({}, {"readonly": True}):
        with pytest.raises(DatabaseError, match=rf"schema version {SCHEMA_VERSION + 1} was "
                                                r"written by a newer surfidx.*upgrade surfidx"):
            Database(path, **kwargs)
    r = invoke(["ls", "--db", path])
    assert r.exit_code == 1 and "written by a newer surfidx" in r.stderr


def test_read_commands_ask_for_upgrade_and_upgrade_does_it(tmp_path):
    path = _old_copy(tmp_path)
    r = invoke(["ls", "--db", path])
    assert r.exit_code == 1
    assert "schema version 3 is older than this surfidx's (4)" in r.stderr
    assert "run `surfidx upgrade` once" in r.stderr
    r = invoke(["upgrade", "--db", path, "--json"])
    assert r.exit_code == 0, r.output
    assert json.loads(r.stdout) == {"database": str(path), "schema_version": 4,
                                    "upgraded_from": 3,
                                    "backup": str(path.with_name("old.db.schema-3.bak"))}
    r = invoke(["upgrade", "--db", path])
    assert r.exit_code == 0 and "schema version 4 already" in r.stdout
    r = invoke(["ls", "--db", path, "--json"])
    rows = json.loads(r.stdout)["models"]
    assert [(m["name"], m["version"], m["versions"]) for m in rows] == [
        ("spot_triangulated", 1, 1), ("armadillo", 1, 1)]


# ---------------------------------------------------------------------- versions
@pytest.fixture
def tree(tmp_path):
    root = make_tree(tmp_path / "data", 4)
    db = tmp_path / "v.db"
    s = ingest.run([root], db=db, processor=fake_processor, progress=False, workers=1)
    assert s.stored == 4
    return root, db


def test_changed_file_becomes_the_next_version(tree):
    root, db = tree
    f = root / "m0.ply"
    with Database(db) as d:
        d.tag("m0", "keep")
        first = d.get_model("m0")
    assert first["source"] == "m0.ply" and first["source_abs"] == str(f.resolve())
    assert first["source_bytes"] == f.stat().st_size and first["source_mtime"].endswith("Z")
    f.write_text("model 0, edited\n")
    s = ingest.run([root], db=db, processor=fake_processor, progress=False, workers=1)
    assert (s.stored, s.skipped) == (1, 3)                # the unchanged ones are skipped
    with Database(db) as d:
        rec = d.get_model("m0")
        assert (rec["version"], rec["id"], rec["latest"]) == (2, 5, True)
        assert rec["tags"] == ["keep"]                      # carried to the new version
        assert rec["source_bytes"] == len("model 0, edited\n")
        assert d.resolve("m0@1") == first["id"] and d.resolve("m0@2") == d.resolve("m0") == 5
        assert d.get_model("m0@1")["latest"] is False
        assert d.get_stream("m0@1") != d.get_stream("m0")
        assert [v["version"] for v in d.versions("m0@1")] == [1, 2]
        assert [r["name"] for r in d.list_models()] == ["m2", "m1", "m3", "m0"]  # by id
        every = d.list_models(all_versions=True)
        assert [(r["name"], r["version"], r["versions"]) for r in every][0] == ("m0", 1, 2)
        assert len(every) == 5 and d.superseded() == 1
        with pytest.raises(DatabaseError, match=r"model 'm0' has no version 7 \(it has 1, 2\)"):
            d.resolve("m0@7")
        with pytest.raises(DatabaseError, match=r"no model named 'nope@1'"):
            d.resolve("nope@1")
    s = ingest.run([root], db=db, processor=fake_processor, progress=False, workers=1)
    assert (s.stored, s.skipped) == (0, 4)                # a re-run resumes: nothing new


def test_query_uses_latest_versions_unless_told(tree):
    root, db = tree
    (root / "m0.ply").write_text("model 0, edited\n")
    ingest.run([root], db=db, processor=fake_processor, progress=False, workers=1)
    with Database(db) as d:
        latest = {r["id"] for r in d.list_models()}
        hits = d.query("m2", k=10)
        assert {h["id"] for h in hits} == latest - {d.resolve("m2")}
        assert all(h["version"] == (2 if h["name"] == "m0" else 1) for h in hits)
        every = d.query("m2", k=10, all_versions=True)
        assert len(every) == 4 and d.resolve("m0@1") in {h["id"] for h in every}
        # the exact scan and the widened index search agree on the latest versions
        assert [h["id"] for h in d.query("m2", k=2, exact=True)] == [h["id"] for h in hits[:2]]
        filtered = d.query("m2", k=10, where="version >= 1")
        assert {h["id"] for h in filtered} == {h["id"] for h in hits}
        assert [r["name"] for r in d.list_models(where="version = 2")] == ["m0"]
    r = invoke(["query", "m2", "--db", db, "--all-versions", "--json"])
    assert r.exit_code == 0 and len(json.loads(r.stdout)["results"]) == 4
    with Database(db) as d:                 # version 2 left alone: no row is superseded
        d.remove("m0@1")
        assert d.superseded() == 0 and len(d.query("m2", k=10)) == 3


def test_replace_adds_a_version_from_another_path(tree, tmp_path):
    root, db = tree
    other = tmp_path / "v2" / "edited.ply"
    other.parent.mkdir()
    other.write_text("model 0, from elsewhere\n")
    r = invoke(["ingest", other, "--db", db, "--replace", "m0", "--json"])
    assert r.exit_code == 0, r.output
    with Database(db) as d:
        rec = d.get_model("m0")
        assert (rec["version"], rec["source"], rec["source_abs"]) == (2, "edited.ply",
                                                                      str(other.resolve()))
        assert d.count() == 5 and len(d.list_models()) == 4
    r = invoke(["ingest", other, "--db", db, "--replace", "m0"])
    assert r.exit_code == 0 and "skipped 1" in r.stdout          # same content: skipped
    r = invoke(["ingest", other, "--db", db, "--replace", "gone"])
    assert r.exit_code == 1 and "no model named 'gone'" in r.stderr
    r = invoke(["ingest", root, "--db", db, "--replace", "m0"])
    assert r.exit_code == 1 and "the paths hold 4 model files" in r.stderr
    r = invoke(["ingest", other, "--db", db, "--replace", "m0", "--name", "x"])
    assert r.exit_code == 1 and "not both" in r.stderr
    with Database(db) as d:
        with pytest.raises(InputError, match="replace= stores one model as a new version"):
            d.ingest([other, other], replace="m0")


def test_replace_in_python_with_a_model_in_memory(tmp_path):
    from surfidx.pipeline import ProcessedModel

    def proc(model, *, bits_per_surfel, name=None):
        vertices = np.asarray(model[0])
        h = hashlib.sha256(vertices.tobytes()).hexdigest()
        return ProcessedModel(name=name or "blob", source="<memory>", content_hash=h,
                              n_surfels=len(vertices), has_color=False,
                              bbox=np.stack([vertices.min(0), vertices.max(0)]),
                              stream=h.encode(), format_version=4, rate=1.0,
                              quality={}, descriptors={"shape": np.ones(4, np.float32)},
                              thumbnail=tiny_png(0), params={})

    rng = np.random.default_rng(0)
    with Database(tmp_path / "m.db") as d:
        d.ingest((rng.random((3, 3)), np.array([[0, 1, 2]])), processor=proc)
        d.ingest((rng.random((3, 3)), np.array([[0, 1, 2]])), processor=proc, replace="blob")
        assert [v["version"] for v in d.versions("blob")] == [1, 2]
        rec = d.get_model("blob")
        assert (rec["source"], rec["source_abs"]) == ("<memory>", None)
        with pytest.raises(DatabaseError, match="no model named 'other'"):
            d.ingest((rng.random((3, 3)), np.array([[0, 1, 2]])), processor=proc, replace="other")


def test_rm_one_version_or_all_and_rename_all(tree):
    root, db = tree
    (root / "m0.ply").write_text("model 0, edited\n")
    ingest.run([root], db=db, processor=fake_processor, progress=False, workers=1)
    r = invoke(["rm", "m0@2", "--db", db])
    assert r.exit_code == 0 and r.stdout == "removed model 5 (m0@2)\n"
    with Database(db) as d:
        assert d.get_model("m0")["version"] == 1               # the older one is the latest
        assert d.rename("m0", "zero")["name"] == "zero"
    (root / "m0.ply").write_text("model 0, edited twice\n")
    ingest.run([root], db=db, processor=fake_processor, progress=False, workers=1)
    with Database(db) as d:
        assert [v["version"] for v in d.versions("zero")] == [1, 2]   # found by its path
        with pytest.raises(DatabaseError, match="no model named 'gone'"):
            d.remove("zero", "gone")                           # nothing removed
        assert d.count() == 5
        assert d.remove("zero") == [{"id": 1, "name": "zero", "version": 1},
                                    {"id": 5, "name": "zero", "version": 2}]
        assert d.count() == 3


def test_a_name_with_an_at_sign_is_a_name_first(tmp_path):
    a = tmp_path / "a.ply"
    at = tmp_path / "a@1.ply"
    for f in (a, at):
        f.write_text(f"model {f.name}\n")
    with Database(tmp_path / "at.db") as d:
        d.ingest([a, at], processor=fake_processor, workers=1)
        assert d.get_model("a@1")["name"] == "a@1"          # a name first
        assert d.resolve("a@1@1") == d.resolve("a@1")      # then NAME@N
        a.write_text("model a, edited\n")
        d.ingest([a], processor=fake_processor, workers=1)
        assert d.get_model("a")["version"] == 2 and d.get_model("a@2")["version"] == 2
        assert d.get_model("a@1")["name"] == "a@1"          # still the model named so


def test_show_and_ls_list_versions(tree):
    root, db = tree
    (root / "m0.ply").write_text("model 0, edited\n")
    ingest.run([root], db=db, processor=fake_processor, progress=False, workers=1)
    r = invoke(["tag", "m0", "both", "--db", db])          # a name: every version
    assert r.exit_code == 0 and "added 2" in r.stdout
    r = invoke(["untag", "m0@1", "both", "--db", db, "--json"])   # one version
    assert json.loads(r.stdout) == {"id": 1, "removed": 1, "tags": []}
    with Database(db) as d:
        assert d.tags("m0") == ["both"] and d.tags("m0@1") == []
    r = invoke(["show", "m0@1", "--db", db])
    assert r.exit_code == 0, r.output
    assert "version          1\n" in r.stdout and "versions         2\n" in r.stdout
    assert "original         not kept" in r.stdout
    lines = [ln for ln in r.stdout.splitlines() if ln.startswith("  ") or ln.startswith(" *")]
    assert lines[0].startswith(" *   1  id 1") and lines[1].startswith("     2  id 5")
    out = json.loads(invoke(["show", "m0", "--db", db, "--json"]).stdout)["model"]
    assert out["version"] == 2 and [v["version"] for v in out["versions"]] == [1, 2]
    r = invoke(["ls", "--db", db, "--all-versions"])
    assert r.exit_code == 0 and len(r.stdout.splitlines()) == 6
    assert " 1 (2 stored) " in r.stdout and " 2 (2 stored) " in r.stdout
    invoke(["rm", "m0@1", "--db", db])
    r = invoke(["ls", "--db", db, "--all-versions"])
    assert len(r.stdout.splitlines()) == 5 and " 2 (2 stored) " not in r.stdout


# ---------------------------------------------------------------------- originals
def _textured_obj(folder: Path) -> Path:
    """An OBJ with a material library in a subfolder naming a texture and a bump map."""
    (folder / "mat").mkdir(parents=True)
    (folder / "tex").mkdir()
    (folder / "tex" / "skin.png").write_bytes(tiny_png(1))
    (folder / "tex" / "bump.png").write_bytes(tiny_png(2))
    (folder / "mat" / "scan.mtl").write_text("newmtl m\nmap_Kd ../tex/skin.png\n"
                                             "map_Bump -bm 0.5 ../tex/bump.png\n")
    obj = folder / "scan.obj"
    obj.write_text("mtllib mat/scan.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 0 1\n"
                   "usemtl m\nf 1/1 2/2 3/3\n")
    return obj


def test_original_files_layout(tmp_path):
    obj = _textured_obj(tmp_path / "a")
    got = original_files(obj)
    assert [(p, role) for p, _, role in got] == [
        ("scan.obj", "source"), ("mat/scan.mtl", "companion"), ("tex/skin.png", "companion"),
        ("tex/bump.png", "companion")]
    gltf = tmp_path / "g" / "model.gltf"
    (gltf.parent / "data").mkdir(parents=True)
    (gltf.parent / "data" / "mesh.bin").write_bytes(b"\0" * 12)
    (gltf.parent / "tex a.png").write_bytes(tiny_png(3))
    gltf.write_text(json.dumps({"asset": {"version": "2.0"},
                                "buffers": [{"uri": "data/mesh.bin", "byteLength": 12},
                                            {"uri": "data:application/octet-stream;base64,AA==",
                                             "byteLength": 1}],
                                "images": [{"uri": "tex%20a.png"}]}))
    assert [p for p, _, _ in original_files(gltf)] == ["model.gltf", "data/mesh.bin",
                                                        "tex a.png"]


def test_original_files_outside_the_folder(tmp_path):
    folder = tmp_path / "scans" / "one"
    folder.mkdir(parents=True)
    (tmp_path / "scans" / "shared.png").write_bytes(tiny_png(4))
    (folder / "x.mtl").write_text("map_Kd ../shared.png\nmap_Ks missing.png\n")
    obj = folder / "x.obj"
    obj.write_text("mtllib x.mtl\nv 0 0 0\n")
    with pytest.warns(UserWarning) as caught:
        got = original_files(obj)
    text = " ".join(str(w.message) for w in caught)
    assert "shared.png lies outside the model's folder" in text and "missing.png is not a file" \
        in text
    assert [p for p, _, _ in got] == ["x.obj", "x.mtl"]
    with pytest.warns(UserWarning, match="missing.png is not a file"):
        got = original_files(obj, allow_outside=True)
    assert [p for p, _, _ in got] == ["one/x.obj", "one/x.mtl", "shared.png"]  # common root


def test_keep_original_round_trip_dedup_and_rm(tmp_path):
    root = tmp_path / "data"
    obj = _textured_obj(root / "a")
    spot = root / "b"
    spot.mkdir()
    shutil.copy(EXAMPLES / "spot" / "spot_triangulated.obj", spot)
    shutil.copy(EXAMPLES / "spot" / "spot_texture.png", spot)     # paired: no MTL
    (root / "c").mkdir()
    shutil.copytree(root / "a" / "tex", root / "c" / "tex")            # the same textures
    shutil.copytree(root / "a" / "mat", root / "c" / "mat")
    (root / "c" / "other.obj").write_text(obj.read_text() + "v 0 0 1\n")
    db = tmp_path / "o.db"
    r = invoke(["ingest", root, "--db", db, "--keep-original", "--json"])
    assert r.exit_code == 0, r.output
    assert json.loads(r.stdout)["stored"] == 3
    out = tmp_path / "out"
    for name, folder in (("scan", root / "a"), ("spot_triangulated", spot),
                         ("other", root / "c")):
        r = invoke(["get", name, "--original", "-o", out / name, "--db", db, "--json"])
        assert r.exit_code == 0, r.output
        files = [f["path"] for f in json.loads(r.stdout)["files"]]
        for rel in files:                                       # byte for byte, same layout
            assert (out / name / rel).read_bytes() == (folder / rel).read_bytes()
        assert len(files) == {"scan": 4, "spot_triangulated": 2, "other": 4}[name]
    with Database(db) as d:
        # deduplicated: the two OBJs share their MTL and textures
        assert d.conn.execute("SELECT count(*) FROM blobs").fetchone()[0] == 4 + 1 + 2
        assert d.get_model("scan")["original"][0] == {
            "path": "scan.obj", "role": "source", "bytes": obj.stat().st_size,
            "sha256": hashlib.sha256(obj.read_bytes()).hexdigest()}
        assert all(r["has_original"] for r in d.list_models())
    r = invoke(["show", "scan", "--db", db])
    assert "original         scan.obj (" in r.stdout and "original kept" in r.stdout
    assert invoke(["rm", "scan", "--db", db]).exit_code == 0
    with Database(db) as d:                                       # shared blobs stay
        assert d.conn.execute("SELECT count(*) FROM blobs").fetchone()[0] == 4 + 2
        d.remove("other", "spot_triangulated")
        assert d.conn.execute("SELECT count(*) FROM blobs").fetchone()[0] == 0
    # without a client's foreign keys, the triggers do it too
    r = invoke(["ingest", root, "--db", db, "--keep-original"])
    conn = sqlite3.connect(db)
    conn.execute("DELETE FROM models")
    conn.commit()
    assert conn.execute("SELECT count(*) FROM blobs").fetchone()[0] == 0
    conn.close()


def test_several_originals_into_subfolders_and_errors(tmp_path):
    root = make_tree(tmp_path / "data", 2)
    db = tmp_path / "o.db"
    assert invoke(["ingest", root, "--db", db, "--keep-original"]).exit_code == 0
    r = invoke(["get", "--all", "--original", "-o", tmp_path / "out", "--db", db])
    assert r.exit_code == 0, r.output
    assert (tmp_path / "out" / "m0" / "m0.ply").read_bytes() == (root / "m0.ply").read_bytes()
    assert (tmp_path / "out" / "m1" / "m1.obj").is_file()
    db2 = tmp_path / "plain.db"
    assert invoke(["ingest", root, "--db", db2]).exit_code == 0
    r = invoke(["get", "m0", "--original", "-o", tmp_path / "o2", "--db", db2])
    assert r.exit_code == 1
    assert "model m0@1 (id 1) has no original: it was ingested without --keep-original" \
        in r.stderr
    r = invoke(["get", "m0", "--original", "--thumbnails", "-o", tmp_path / "o3", "--db", db])
    assert r.exit_code == 1 and "either --original or --thumbnails" in r.stderr


def test_keep_original_refuses_large_changed_and_damaged(tmp_path):
    root = make_tree(tmp_path / "data", 1)
    f = root / "m0.ply"
    with Database(tmp_path / "k.db") as d:
        d.ingest([root], processor=fake_processor, workers=1)
        files = original_files(f)
        with pytest.raises(InputError, match=r"m0\.ply: 8 bytes, more than an original file "
                                             r"may have \(4\)"):
            d.keep_original(1, files, max_bytes=4)
        with pytest.raises(InputError, match=r"m0\.ply: changed since it was read"):
            d.keep_original(1, files, content_hash="0" * 64, hashed=[f])
        with pytest.raises(DatabaseError, match="no model with id 9"):
            d.keep_original(9, files)
        h = d.get_model(1)["content_hash"]
        assert d.keep_original(1, files, content_hash=h, hashed=[f]) == {
            "files": 1, "bytes": 8, "new_bytes": 8}
        d.conn.execute("UPDATE blobs SET data = zeroblob(8)")        # damaged, same length
        with pytest.raises(DatabaseError, match=r"original file 'm0\.ply' of model 1 does not "
                                                r"match its SHA-256; the database is damaged"):
            d.export_original("m0", tmp_path / "out")
        assert not (tmp_path / "out" / "m0.ply").exists()           # nothing half-written


def test_original_damage_and_bad_paths_are_named(tmp_path, monkeypatch):
    import surfidx.io.files as files_mod

    root = make_tree(tmp_path / "data", 1)
    f = root / "m0.ply"
    with Database(tmp_path / "d.db") as d:
        d.ingest([root], processor=fake_processor, workers=1)
        with pytest.raises(DatabaseError, match=r"no original file with SHA-256 0000"):
            list(d.original_pieces("0" * 64))
        calls = []
        real = files_mod.file_pieces

        def changing(path, read):                  # the second read sees other bytes
            calls.append(path)
            for piece in real(path, read):
                yield piece if len(calls) == 1 else piece[::-1]

        monkeypatch.setattr(files_mod, "file_pieces", changing)
        with pytest.raises(InputError, match=r"m0\.ply: changed while it was kept as an "
                                             r"original"):
            d.keep_original(1, original_files(f))
        monkeypatch.setattr(files_mod, "file_pieces", real)
        assert d.conn.execute("SELECT count(*) FROM blobs").fetchone()[0] == 0
        d.keep_original(1, original_files(f))
        d.conn.execute("UPDATE blobs SET data = zeroblob(4)")
        with pytest.raises(DatabaseError, match=r"damaged .*holds 4 bytes, its row says 8"):
            d.export_original("m0", tmp_path / "out")
        d.conn.execute("UPDATE original_files SET path = '../escape.ply'")
        with pytest.raises(DatabaseError, match=r"path '\.\./escape\.ply' of model 1 leaves "
                                                r"the output folder"):
            d.export_original("m0", tmp_path / "out")
    assert not (tmp_path / "escape.ply").exists()
    r = invoke(["get", "m0", "--original", "-o", f, "--db", tmp_path / "d.db"])
    assert r.exit_code == 1 and "is a file; --original writes into a folder" in r.stderr
    r = invoke(["get", "--tag", "none", "--original", "-o", tmp_path / "o",
                "--db", tmp_path / "d.db"])
    assert r.exit_code == 1 and "the selection names no stored model" in r.stderr
    bad = tmp_path / "bad.gltf"
    bad.write_text("{not json")
    from surfidx import FileFormatError

    with pytest.raises(FileFormatError, match=r"bad\.gltf: not a readable glTF file"):
        original_files(bad)


def test_an_oversized_original_fails_only_its_model(tmp_path, monkeypatch):
    root = make_tree(tmp_path / "data", 2)
    big = root / "m0.ply"
    with open(big, "r+b") as fh:                                  # sparse: no disk used
        fh.truncate(dbmod.MAX_ORIGINAL_BYTES + 1)
    s = ingest.run([root], db=tmp_path / "b.db", processor=_tiny_processor, progress=False,
                   workers=1, keep_original=True)
    assert (s.stored, s.failed) == (1, 1)
    assert "more than an original file may have" in s.errors[0][1]
    with Database(tmp_path / "b.db") as d:
        assert [r["name"] for r in d.list_models()] == ["m1"]          # m0 not half-stored


def _tiny_processor(path, *, bits_per_surfel=8.0, texture=None):
    """fake_processor without reading the file (a 512 MiB sparse file stays unread)."""
    from surfidx.pipeline import ProcessedModel

    h = hashlib.sha256(str(path).encode()).hexdigest()
    return ProcessedModel(name=Path(path).stem, source=str(Path(path).resolve()),
                          content_hash=h, n_surfels=10, has_color=False,
                          bbox=np.array([[0.0, 0, 0], [1, 1, 1]]), stream=h.encode(),
                          format_version=4, rate=1.0, quality={},
                          descriptors={"shape": np.ones(4, np.float32)},
                          thumbnail=tiny_png(0), params={})


def test_provenance_of_a_processed_model(tmp_path):
    """The columns come from what process_model records (params provenance, descriptor
    conventions, container version)."""
    from surfidx.pipeline import ProcessedModel

    m = ProcessedModel(name="p", source=str(tmp_path / "p.ply"), content_hash="a" * 64,
                       n_surfels=3, has_color=False, bbox=np.zeros((2, 3)), stream=b"s",
                       format_version=4, rate=1.0, quality={}, descriptors={},
                       thumbnail=tiny_png(0),
                       params={"provenance": {"surfidx": "9.9", "numerics_profile": "x"},
                               "descriptors": {"version": 7}},
                       source_bytes=12, source_mtime=0.5)
    with Database(tmp_path / "p.db") as d:
        rec = d.get_model(d.add(m))
    assert (rec["surfidx_version"], rec["numerics_profile"], rec["descriptor_version"],
            rec["codec_version"], rec["source_bytes"], rec["source_mtime"]) == (
        "9.9", "x", 7, 4, 12, "1970-01-01T00:00:00.500000Z")
    assert rec["source"] == "p.ply" and rec["source_abs"] == str(tmp_path / "p.ply")
