"""surfidx.db.catalog and surfidx.db.search: schema, round trips, migrations, foreign files, queries."""

from __future__ import annotations

import hashlib
import io
import shutil
import sqlite3
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import surfidx
from surfidx import DatabaseError, InputError
from surfidx.db import catalog as dbmod
from surfidx.database import Database
from surfidx.db.catalog import SCHEMA_VERSION, schema_sql
from surfidx.pipeline import ProcessedModel
from surfidx.db.search import SearchIndex, search
from surfidx.describe.distance import weighted_l2

from helpers import damage_database, foreign_database, tiny_png

REPO = Path(__file__).resolve().parents[1]


# ---------------------------------------------------------------------- test doubles


def make_model(seed: int = 0, *, name=None, color: bool = True, shape_dim: int = 16,
               texture_dim: int = 8, content_hash=None, source=None) -> ProcessedModel:
    """A real ProcessedModel with random descriptors, a random-byte stream and a tiny PNG."""
    rng = np.random.default_rng(seed)
    descriptors = {"shape": rng.standard_normal(shape_dim).astype(np.float32),
                   "spectrum": rng.random(5).astype(np.float32)}
    if color:
        descriptors["texture"] = rng.standard_normal(texture_dim).astype(np.float32)
    lo = rng.standard_normal(3)
    stream = rng.integers(0, 256, int(rng.integers(16, 200)), dtype=np.uint8).tobytes()
    n = int(rng.integers(100, 10_000))
    return ProcessedModel(
        name=name or f"model{seed}", source=source or f"/data/model{seed}.ply",
        content_hash=content_hash or hashlib.sha256(f"model {seed}".encode()).hexdigest(),
        n_surfels=n, has_color=color, bbox=np.stack([lo, lo + rng.random(3) + 0.1]),
        stream=stream, format_version=1, rate=8.0 * len(stream) / n,
        quality={"psnr_d1": float(rng.uniform(30, 80)), "psnr_d2": float(rng.uniform(30, 80)),
                 "psnr_y": float(rng.uniform(20, 50)) if color else None},
        descriptors=descriptors, thumbnail=tiny_png(seed),
        params={"level": 5, "descriptors": {"lmax": 8, "normalisation": "ortho"}},
        timings={"encode": 0.5})


@pytest.fixture
def db(tmp_path):
    with Database(tmp_path / "test.db") as d:
        yield d


def assert_same(a: ProcessedModel, b: ProcessedModel):
    for f in ("name", "source", "content_hash", "n_surfels", "has_color", "stream",
              "format_version", "thumbnail", "params"):
        assert getattr(a, f) == getattr(b, f), f
    assert b.rate == pytest.approx(a.rate, rel=0, abs=0)
    np.testing.assert_array_equal(a.bbox, b.bbox)
    assert set(a.descriptors) == set(b.descriptors)
    for k, v in a.descriptors.items():
        assert b.descriptors[k].dtype == np.float32
        np.testing.assert_array_equal(np.asarray(v, np.float32), b.descriptors[k])
    for k in ("psnr_d1", "psnr_d2", "psnr_y"):
        assert b.quality[k] == a.quality.get(k)


# ---------------------------------------------------------------------- schema and packaging
def test_schema_has_one_source():
    """``surfidx/data`` holds the schema and the Datasette metadata; ``data_schema/`` links to
    them (a relative link, so the package data, wheels and sdists hold the files themselves)."""
    import os

    for name in ("schema.sql", "datasette.json"):
        link = REPO / "data_schema" / name
        assert link.is_symlink(), link
        assert os.readlink(link) == f"../surfidx/data/{name}"
        assert link.resolve() == (REPO / "surfidx" / "data" / name).resolve()
    assert schema_sql() == (REPO / "surfidx" / "data" / "schema.sql").read_text(encoding="utf-8")


def test_pyproject_ships_schema_as_package_data():
    import tomllib

    conf = tomllib.loads((REPO / "pyproject.toml").read_text())
    patterns = conf["tool"]["setuptools"]["package-data"]["surfidx"]
    assert "data/*.sql" in patterns


@pytest.mark.slow
def test_built_package_finds_schema(tmp_path):
    """A non-editable build (setuptools build_py, as a wheel does) ships surfidx/data/schema.sql
    and the built package reads it through importlib.resources."""
    src = tmp_path / "src"
    src.mkdir()
    for name in ("pyproject.toml", "README.md"):
        shutil.copy(REPO / name, src / name)
    ignore = shutil.ignore_patterns("__pycache__", "*.nbi", "*.nbc", "*.db")
    for pkg in ("surfidx", "ingest"):
        shutil.copytree(REPO / pkg, src / pkg, ignore=ignore)
    out = tmp_path / "build"
    proc = subprocess.run([sys.executable, "-c", "from setuptools import setup; setup()", "-q",
                           "build_py", "--build-lib", str(out)], cwd=src, capture_output=True,
                          text=True)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert (out / "surfidx" / "data" / "schema.sql").read_text() == schema_sql()
    code = ("import sys; sys.path.insert(0, sys.argv[1]); import surfidx.db.catalog as d; "
            "assert d.__file__.startswith(sys.argv[1]), d.__file__; "
            "print(len(d.schema_sql()))")
    proc = subprocess.run([sys.executable, "-c", code, str(out)], capture_output=True, text=True,
                          cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert int(proc.stdout) == len(schema_sql())


def test_new_database_layout(db):
    assert db.schema_version == SCHEMA_VERSION
    assert set(db.db.table_names()) == set(dbmod.TABLES) | {"tags", "model_topology", "blobs",
                                                            "original_files"}
    assert db.conn.execute("PRAGMA journal_mode").fetchone()[0] == "wal"
    assert db.conn.execute("PRAGMA foreign_keys").fetchone()[0] == 1
    meta = dict(db.conn.execute("SELECT key, value FROM meta"))
    assert meta["schema_version"] == str(SCHEMA_VERSION)
    assert meta["created_by"] == f"surfidx {surfidx.__version__}"
    indexed = {tuple(ix.columns) for t in ("models", "descriptors")
               for ix in db.db[t].indexes}
    assert {("content_hash",), ("name", "version"), ("source_abs",), ("kind",)} <= indexed
    fks = {(fk.table, fk.other_table) for t in ("assets", "descriptors", "thumbnails",
                                                "ingest_errors") for fk in db.db[t].foreign_keys}
    assert fks == {("assets", "models"), ("descriptors", "models"), ("thumbnails", "models"),
                   ("ingest_errors", "ingest_runs")}
    assert len(dbmod.MIGRATIONS) == SCHEMA_VERSION - 1


def test_reopen_keeps_data(tmp_path):
    path = tmp_path / "a.db"
    with Database(path) as d:
        mid = d.add(make_model(1))
    with Database(path, create=False) as d:
        assert d.get_model(mid)["name"] == "model1"


# ---------------------------------------------------------------------- round trips
@settings(max_examples=25, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(seed=st.integers(0, 2**32 - 1), color=st.booleans(),
       shape_dim=st.integers(0, 40), texture_dim=st.integers(1, 12),
       name=st.text(min_size=1, max_size=20),
       vec=st.lists(st.floats(allow_nan=False, allow_infinity=False, width=32), max_size=10))
def test_round_trip(tmp_path_factory, seed, color, shape_dim, texture_dim, name, vec):
    path = tmp_path_factory.mktemp("rt") / "rt.db"
    model = make_model(seed, name=name, color=color, shape_dim=shape_dim, texture_dim=texture_dim)
    model.descriptors["extra"] = np.array(vec, np.float32)
    with Database(path) as d:
        mid = d.add(model)
        back = d.load(mid)
        assert_same(model, back)
        assert d.get_stream(mid) == model.stream
        assert d.get_thumbnail(mid) == model.thumbnail
        rec = d.get_model(mid)
        assert rec["descriptors"] == {k: v.size for k, v in model.descriptors.items()}
        assert rec["asset"]["bytes"] == len(model.stream)
        ids, mat = d.descriptor_matrix("shape")
        np.testing.assert_array_equal(mat[ids == mid][0], model.descriptors["shape"])


def test_descriptor_blob_is_float32_little_endian(db):
    m = make_model(3)
    mid = db.add(m)
    blob, dim = db.conn.execute("SELECT vector, dimension FROM descriptors WHERE model_id = ? "
                                "AND kind = 'shape'", (mid,)).fetchone()
    assert dim == 16 and len(blob) == 64
    np.testing.assert_array_equal(np.frombuffer(blob, "<f4"), m.descriptors["shape"])
    conv = db.conn.execute("SELECT convention FROM descriptors WHERE model_id = ?",
                           (mid,)).fetchone()[0]
    assert conv == '{"lmax": 8, "normalisation": "ortho"}'


def test_add_is_atomic(db):
    bad = make_model(1)
    bad.descriptors["shape"] = np.array([1.0, np.nan], np.float32)
    with pytest.raises(InputError, match="descriptor 'shape' contains 1 NaN"):
        db.add(bad)
    bad = make_model(2)
    bad.thumbnail = None
    with pytest.raises(InputError, match="thumbnail must be bytes"):
        db.add(bad)
    # A failure inside the transaction (after the models row) leaves nothing behind.
    m = make_model(4)
    m.descriptors = {"shape": np.ones(3, np.float32)}
    orig = db._rows_of

    def broken(model):
        row, asset, descs, png = orig(model)
        return row, asset, descs + [descs[0]], png        # duplicate (model_id, kind)

    db._rows_of = broken
    with pytest.raises(DatabaseError, match=r"test\.db: a record does not fit the schema "
                                            r"\(UNIQUE constraint failed: descriptors"):
        db.add(m)
    db._rows_of = orig
    for table in ("models", "assets", "descriptors", "thumbnails"):
        assert db.db[table].count == 0


def test_add_validation_errors(db):
    for field, value, msg in [("name", "", "name must not be empty"),
                              ("content_hash", "", "content_hash must not be empty"),
                              ("bbox", np.zeros(3), r"bbox must have shape \(2, 3\)"),
                              ("n_surfels", -1, "n_surfels must be >= 0"),
                              ("stream", "text", "stream must be bytes"),
                              ("params", {"x": object()}, "params must be JSON-serialisable")]:
        m = make_model(7)
        setattr(m, field, value)
        with pytest.raises(InputError, match=msg):
            db.add(m)
    assert db.count() == 0


def test_duplicate_hash_rejected(db):
    mid = db.add(make_model(1))
    with pytest.raises(DatabaseError, match=f"already stored as id {mid}"):
        db.add(make_model(2, content_hash=make_model(1).content_hash))
    assert db.count() == 1 and db.has_hash(make_model(1).content_hash)
    assert not db.has_hash("nope")


def test_get_by_name_and_errors(db):
    a = db.add(make_model(1, name="bunny"))
    db.add(make_model(2, name="twin", source="/scans/a/twin.ply"))
    db.add(make_model(3, name="twin", source="/scans/b/twin.ply"))     # named after its folder
    db.add(make_model(4, name="twin", source="/scans/b/twin.obj"))     # folder taken: twin-2
    db.add(make_model(5, name="twin", source="/scans/b/twin.off"))
    assert db.get_model("bunny")["id"] == a
    assert [db.get_model(n)["id"] for n in ("twin", "b", "twin-2", "twin-3")] == [2, 3, 4, 5]
    with pytest.raises(DatabaseError, match="no model named 'nobody'"):
        db.get_model("nobody")
    with pytest.raises(DatabaseError, match="the name 'twin' is taken by model 2"):
        db.add(make_model(6, name="twin"), exact_name=True)
    with pytest.raises(DatabaseError, match="no model with id 99"):
        db.get_stream(99)
    with pytest.raises(InputError, match="model id must be an integer"):
        db.get_model(1.5)
    db.conn.execute("DELETE FROM thumbnails WHERE model_id = ?", (a,))
    db.conn.execute("DELETE FROM assets WHERE model_id = ?", (a,))
    with pytest.raises(DatabaseError, match="has no thumbnail"):
        db.get_thumbnail(a)
    with pytest.raises(DatabaseError, match="has no stored stream"):
        db.get_stream(a)


def test_list_and_delete(db):
    ids = [db.add(make_model(i)) for i in range(3)]
    rows = db.list_models()
    assert [r["id"] for r in rows] == ids
    assert rows[0]["bytes"] == len(make_model(0).stream)
    db.delete(ids[1])
    assert [r["id"] for r in db.list_models()] == [ids[0], ids[2]]
    for table in ("assets", "descriptors", "thumbnails"):
        assert db.conn.execute(f"SELECT count(*) FROM {table} WHERE model_id = ?",
                               (ids[1],)).fetchone()[0] == 0
    with pytest.raises(DatabaseError, match=f"no model with id {ids[1]}"):
        db.delete(ids[1])


def test_descriptor_matrix_cache_and_kinds(db):
    for i in range(4):
        db.add(make_model(i, color=i % 2 == 0))
    ids, shape = db.descriptor_matrix("shape")
    assert ids.tolist() == [1, 2, 3, 4] and shape.shape == (4, 16) and shape.dtype == np.float32
    assert db.descriptor_matrix("shape")[1] is shape                     # cached
    both_ids, both = db.descriptor_matrix(["shape", "texture"])
    assert both_ids.tolist() == [1, 3] and both.shape == (2, 24)
    np.testing.assert_array_equal(both[1, 16:], make_model(2).descriptors["texture"])
    db.add(make_model(10))
    ids2, shape2 = db.descriptor_matrix("shape")                          # invalidated on write
    assert ids2.tolist() == [1, 2, 3, 4, 5]
    assert db.descriptor_kinds() == {"shape": 5, "spectrum": 5, "texture": 3}
    empty_ids, empty = db.descriptor_matrix("nothing")
    assert empty_ids.size == 0 and empty.shape == (0, 0)
    with pytest.raises(InputError, match="at least one descriptor kind"):
        db.descriptor_matrix([])


def test_descriptor_matrix_sees_other_connections(tmp_path):
    path = tmp_path / "two.db"
    with Database(path) as a, Database(path) as b:
        a.add(make_model(1))
        assert a.descriptor_matrix("shape")[0].tolist() == [1]
        b.add(make_model(2))
        assert a.descriptor_matrix("shape")[0].tolist() == [1, 2]


def test_descriptor_matrix_refuses_mixed_settings(db):
    db.add(make_model(1))
    db.add(make_model(2, shape_dim=9))
    with pytest.raises(DatabaseError, match=r"kind 'shape' have different dimensions \[9, 16\]"):
        db.descriptor_matrix("shape")
    other = make_model(3)
    other.params = {"descriptors": {"lmax": 4}}
    db.delete(2)
    db.add(other)
    with pytest.raises(DatabaseError, match="kind 'shape' were made with different conventions"):
        db.descriptor_matrix("shape")


def test_runs_and_errors(db):
    rid = db.start_run(["a", Path("b")], workers=3, bits_per_surfel=2.0)
    db.record_error(rid, "a/x.ply", "broken file")
    db.update_run(rid, stored=1, skipped=0, failed=1)
    assert db.last_run()["status"] == "running" and db.last_run()["stored"] == 1
    db.finish_run(rid, stored=2, skipped=1, failed=1)
    run = db.last_run()
    assert run["paths"] == ["a", "b"] and run["workers"] == 3 and run["status"] == "finished"
    assert run["finished_at"] is not None and (run["stored"], run["skipped"]) == (2, 1)
    assert [e["error"] for e in db.errors(rid)] == ["broken file"]
    assert db.errors(rid + 1) == [] and len(db.errors()) == 1
    with pytest.raises(InputError, match="status must be 'finished'"):
        db.finish_run(rid, stored=0, skipped=0, failed=0, status="done")
    with pytest.raises(DatabaseError, match="no ingest run with id 99"):
        db.finish_run(99, stored=0, skipped=0, failed=0)


def test_transaction_rolls_back_everything_on_interrupt(db):
    db.add(make_model(0))
    with pytest.raises(KeyboardInterrupt):
        with db.transaction():
            db.add(make_model(1))
            db.add(make_model(2))
            raise KeyboardInterrupt
    assert db.count() == 1
    with db.transaction():                       # a failing nested add only undoes itself
        db.add(make_model(3))
        with pytest.raises(DatabaseError, match="already stored"):
            db.add(make_model(3))
    assert db.count() == 2


# ---------------------------------------------------------------------- opening: errors, migrations
def test_missing_file_without_create(tmp_path):
    with pytest.raises(DatabaseError, match=r"nope\.db: no such database"):
        Database(tmp_path / "nope.db", create=False)
    assert not (tmp_path / "nope.db").exists()


def test_directory_and_garbage_files(tmp_path):
    with pytest.raises(DatabaseError, match="is a directory"):
        Database(tmp_path)
    import os

    os.mkfifo(tmp_path / "pipe.db")
    for kwargs in ({}, {"readonly": True}):
        with pytest.raises(DatabaseError, match=r"pipe\.db: is not a regular file \(a FIFO"):
            Database(tmp_path / "pipe.db", **kwargs)
    with pytest.raises(DatabaseError, match=r"null: is not a regular file"):
        Database("/dev/null")
    with pytest.raises(DatabaseError, match=r"no/such/dir/x\.db: cannot open"):
        Database(tmp_path / "no" / "such" / "dir" / "x.db")
    junk = tmp_path / "junk.db"
    junk.write_bytes(b"this is not sqlite at all" * 100)
    with pytest.raises(DatabaseError, match=r"junk\.db: not an SQLite database"):
        Database(junk)


def test_foreign_database(tmp_path):
    path = tmp_path / "other.db"
    conn = sqlite3.connect(path)
    conn.execute("CREATE TABLE customers (id INTEGER PRIMARY KEY, name TEXT)")
    conn.commit()
    conn.close()
    with pytest.raises(DatabaseError, match=r"other\.db: not a surfidx database .*customers"):
        Database(path)
    conn = sqlite3.connect(path)          # untouched: still its own journal mode and table
    assert conn.execute("PRAGMA journal_mode").fetchone()[0] == "delete"
    assert conn.execute("PRAGMA user_version").fetchone()[0] == 0
    conn.close()
    conn = sqlite3.connect(tmp_path / "v.db")
    conn.execute("PRAGMA user_version = 1")
    conn.close()
    with pytest.raises(DatabaseError, match=r"user_version 1 but no tables"):
        Database(tmp_path / "v.db")


def test_future_version(tmp_path):
    path = tmp_path / "future.db"
    Database(path).close()
    conn = sqlite3.connect(path)
    conn.execute(f"PRAGMA user_version = {SCHEMA_VERSION + 1}")
    conn.close()
    with pytest.raises(DatabaseError, match=rf"future\.db: schema version {SCHEMA_VERSION + 1} "
                                            "was written by a newer surfidx"):
        Database(path)


def test_version0_empty_file_is_upgraded(tmp_path):
    path = tmp_path / "v0.db"
    sqlite3.connect(path).close()                       # an empty SQLite file: version 0
    with Database(path) as d:
        assert d.schema_version == SCHEMA_VERSION and d.count() == 0


def _v1_database(path):
    """A version-1 database made by hand (the schema file executed with plain sqlite3)."""
    conn = sqlite3.connect(path)
    conn.executescript(schema_sql())
    conn.execute("INSERT INTO meta VALUES ('schema_version', '1')")
    conn.execute("INSERT INTO models (name, source, content_hash, n_surfels, has_color, "
                 "bbox_min_x, bbox_min_y, bbox_min_z, bbox_max_x, bbox_max_y, bbox_max_z, "
                 "ingested_at) VALUES ('old', '/o.ply', 'h', 3, 0, 0, 0, 0, 1, 1, 1, 'then')")
    conn.execute("PRAGMA user_version = 1")
    conn.commit()
    conn.close()


def test_migration_from_older_version(tmp_path, monkeypatch):
    path = tmp_path / "v1.db"
    _v1_database(path)

    def to_v2(conn):
        conn.execute("ALTER TABLE models ADD COLUMN license TEXT NOT NULL DEFAULT 'unknown'")

    monkeypatch.setattr(dbmod, "SCHEMA_VERSION", 2)
    monkeypatch.setattr(dbmod, "MIGRATIONS", [to_v2])
    with Database(path) as d:
        assert d.schema_version == 2
        assert d.conn.execute("SELECT name, license FROM models").fetchall() == [("old", "unknown")]
        assert dict(d.conn.execute("SELECT key, value FROM meta"))["schema_version"] == "2"
    with Database(path) as d:                        # opening again runs nothing
        assert d.schema_version == 2


def test_failing_migration_leaves_file_unchanged(tmp_path, monkeypatch):
    path = tmp_path / "v1.db"
    _v1_database(path)

    def half(conn):
        conn.execute("ALTER TABLE models ADD COLUMN license TEXT")
        conn.execute("SELECT * FROM no_such_table")

    monkeypatch.setattr(dbmod, "SCHEMA_VERSION", 2)
    monkeypatch.setattr(dbmod, "MIGRATIONS", [half])
    with pytest.raises(DatabaseError,
                       match=r"upgrading the schema to version 2 failed .*unchanged"):
        Database(path)
    conn = sqlite3.connect(path)
    assert conn.execute("PRAGMA user_version").fetchone()[0] == 1
    cols = [r[1] for r in conn.execute("PRAGMA table_info(models)")]
    assert "license" not in cols
    conn.close()


def test_closed_database(tmp_path):
    d = Database(tmp_path / "c.db")
    d.close()
    d.close()
    with pytest.raises(DatabaseError, match="the database is closed"):
        d.count()


# ---------------------------------------------------------------------- search
def test_weighted_l2_definition():
    rng = np.random.default_rng(0)
    stored = {"shape": rng.standard_normal((5, 4)).astype(np.float32),
              "texture": rng.standard_normal((5, 3)).astype(np.float32)}
    present = {"shape": np.ones(5, bool), "texture": np.array([1, 0, 1, 0, 1], bool)}
    q = {"shape": rng.standard_normal(4).astype(np.float32),
         "texture": rng.standard_normal(3).astype(np.float32)}
    ds = np.linalg.norm(stored["shape"] - q["shape"], axis=1)
    dt = np.linalg.norm(stored["texture"] - q["texture"], axis=1)
    d = weighted_l2(q, stored, present, shape_weight=0.3)
    np.testing.assert_allclose(d, np.where(present["texture"], 0.3 * ds + 0.7 * dt, ds), rtol=1e-6)
    np.testing.assert_allclose(weighted_l2({"shape": q["shape"]}, stored, present,
                                           shape_weight=0.3), ds, rtol=1e-6)
    # The spectrum is appended to the shape vector where the model has one.
    stored["spectrum"] = rng.random((5, 2)).astype(np.float32)
    present["spectrum"] = np.array([1, 1, 1, 1, 0], bool)
    q["spectrum"] = rng.random(2).astype(np.float32)
    dsp = np.linalg.norm(stored["spectrum"] - q["spectrum"], axis=1)
    ds2 = np.sqrt(ds ** 2 + np.where(present["spectrum"], dsp ** 2, 0))
    np.testing.assert_allclose(weighted_l2(q, stored, present, shape_weight=1.0), ds2, rtol=1e-6)


def test_default_distance_is_descriptor_distance(db):
    """The vectorised scan computes surfidx.describe.descriptors.descriptor_distance for every model."""
    descriptors = pytest.importorskip("surfidx.describe.descriptors")
    from surfidx.describe.distance import DEFAULT_SHAPE_WEIGHT

    models = [make_model(i, color=i % 2 == 0) for i in range(12)]
    for m in models:
        db.add(m)
    index = SearchIndex(db)
    for qm in (models[0], models[1]):
        q = {k: v for k, v in qm.descriptors.items() if qm.has_color or k != "texture"}
        for w in (0.0, 0.3, DEFAULT_SHAPE_WEIGHT, 1.0):
            ids, dist = index.query(q, k=12, shape_weight=w)
            want = {i + 1: descriptors.descriptor_distance(
                q, {k: v for k, v in m.descriptors.items() if m.has_color or k != "texture"},
                shape_weight=w) for i, m in enumerate(models)}
            np.testing.assert_allclose(dist, [want[i] for i in ids.tolist()], rtol=1e-6,
                                       atol=1e-9)
            assert dist.tolist() == sorted(dist.tolist())


def test_search_example_first_and_matches_brute_force(db):
    models = [make_model(i, color=i % 3 != 0) for i in range(40)]
    for m in models:
        db.add(m)
    index = SearchIndex(db)
    for i in (0, 1, 17):
        q = models[i].descriptors
        if not models[i].has_color:
            q = {k: v for k, v in q.items() if k != "texture"}
        ids, dist = index.query(q, k=5, shape_weight=0.4)
        assert ids[0] == i + 1 and dist[0] == pytest.approx(0, abs=1e-6)
        full = weighted_l2({k: np.asarray(v, np.float32) for k, v in q.items()},
                           index.stored, index.present, shape_weight=0.4)
        brute = np.lexsort((index.ids, full))[:5]
        assert ids.tolist() == index.ids[brute].tolist()
        np.testing.assert_allclose(dist, full[brute], rtol=1e-9)
    ids, _ = search(db, models[5].descriptors, k=3, exclude=[6])
    assert 6 not in ids.tolist() and len(ids) == 3
    ids, _ = search(db, models[5].descriptors, k=100)
    assert len(ids) == 40
    custom = lambda q, s, p, *, shape_weight: np.arange(len(s["shape"]), 0, -1.0)  # noqa: E731
    assert search(db, models[0].descriptors, k=2, distance=custom)[0].tolist() == [40, 39]


def test_search_errors_and_empty(db):
    assert search(db, {"shape": np.ones(16)}, k=3)[0].size == 0
    db.add(make_model(1))
    with pytest.raises(InputError, match="query has no 'shape' descriptor"):
        search(db, {"texture": np.ones(8)})
    with pytest.raises(InputError, match=r"has 3 values but the stored ones have 16; .*surfidx redescribe"):
        search(db, {"shape": np.ones(3)})
    with pytest.raises(InputError, match=r"shape_weight must be in \[0, 1\]"):
        search(db, {"shape": np.ones(16)}, shape_weight=1.5)
    with pytest.raises(InputError, match="k must be at least 1"):
        search(db, {"shape": np.ones(16)}, k=0)
    with pytest.raises(InputError, match="distance function returned shape"):
        search(db, {"shape": np.ones(16)}, distance=lambda q, s, p, shape_weight: np.zeros(7))
    with pytest.raises(InputError, match="default distance compares 'shape'"):
        SearchIndex(db, kinds=("spectrum",)).query({"spectrum": np.ones(5)})
    with pytest.raises(InputError, match="at least one descriptor kind"):
        SearchIndex(db, kinds=())
    # No texture stored anywhere: a coloured query is compared by shape only.
    d2 = Database(db.path.with_name("nocolor.db"))
    d2.add(make_model(2, color=False))
    ids, dist = search(d2, make_model(2, color=True).descriptors)
    assert ids.tolist() == [1]
    d2.close()


def test_package_exports_lazily():
    code = ("import sys, surfidx; assert 'sqlite_utils' not in sys.modules; "
            "from surfidx import Database, SearchIndex; "
            "assert Database.__module__ == 'surfidx.database'; "
            "assert SearchIndex.__module__ == 'surfidx.db.search'")
    assert subprocess.run([sys.executable, "-c", code]).returncode == 0
    with pytest.raises(AttributeError, match="nothing_here"):
        surfidx.nothing_here


# ---------------------------------------------------------------------- whose file, errors (#30)
def _digest(path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def test_new_database_carries_the_application_id(db):
    assert db.conn.execute("PRAGMA application_id").fetchone()[0] == dbmod.APPLICATION_ID
    assert dbmod.APPLICATION_ID.to_bytes(4, "big") == b"SFDX"


def test_foreign_file_with_surfidx_table_names_is_refused_untouched(tmp_path):
    path = tmp_path / "other.db"
    foreign_database(path, user_version=1)                      # user_version 1, tables meta and models
    before = _digest(path)
    for kwargs in ({}, {"readonly": True}, {"create": False}):
        with pytest.raises(DatabaseError, match=r"other\.db: not a surfidx database \(it holds "
                                                r"other tables: meta, models\)"):
            Database(path, **kwargs)
    assert _digest(path) == before                       # not even the journal mode changed
    conn = sqlite3.connect(path)
    assert conn.execute("PRAGMA journal_mode").fetchone()[0] == "delete"
    conn.close()


def test_other_application_id_and_marker_without_schema(tmp_path):
    path = tmp_path / "app.db"
    foreign_database(path, application_id=0x12345678, tables=("things",))
    before = _digest(path)
    with pytest.raises(DatabaseError, match=r"application_id 0x12345678 is another "
                                            r"application's"):
        Database(path)
    assert _digest(path) == before
    path = tmp_path / "marked.db"
    foreign_database(path, application_id=dbmod.APPLICATION_ID, tables=())
    with pytest.raises(DatabaseError, match=r"carries surfidx's application id but no schema"):
        Database(path)


def test_database_made_before_the_marker_opens_and_is_marked_on_write(tmp_path):
    path = tmp_path / "old.db"
    with Database(path) as d:
        d.add(make_model(1))
    conn = sqlite3.connect(path)                         # as the previous surfidx left it
    conn.execute("PRAGMA application_id = 0")
    conn.commit()
    conn.close()
    before = _digest(path)
    with Database(path, readonly=True) as d:             # recognised: meta rows and schema
        assert d.count() == 1
    with Database(path) as d:                            # opening for writing writes nothing
        assert d.count() == 1
        assert d.conn.execute("PRAGMA application_id").fetchone()[0] == 0
    assert _digest(path) == before
    with Database(path) as d:
        with pytest.raises(KeyboardInterrupt):
            with d.transaction():
                raise KeyboardInterrupt
        assert d.conn.execute("PRAGMA application_id").fetchone()[0] == 0   # rolled back
        d.add(make_model(2))
        assert d.conn.execute("PRAGMA application_id").fetchone()[0] == dbmod.APPLICATION_ID
    _v1_database(tmp_path / "hand.db")                   # the schema file and its meta row
    with Database(tmp_path / "hand.db") as d:
        assert d.count() == 1


def test_readonly_open_never_writes(tmp_path):
    path = tmp_path / "r.db"
    with Database(path) as d:
        d.add(make_model(1))
    before = _digest(path)
    with Database(path, readonly=True) as d:
        assert d.readonly and d.count() == 1 and d.get_model(1)["name"] == "model1"
        with pytest.raises(DatabaseError, match=r"r\.db: opened read-only; open it without "
                                                "readonly=True to write"):
            d.add(make_model(2))
    assert _digest(path) == before
    with pytest.raises(DatabaseError, match=r"missing\.db: no such database"):
        Database(tmp_path / "missing.db", readonly=True)
    assert not (tmp_path / "missing.db").exists()
    (tmp_path / "zero.db").write_bytes(b"")
    with pytest.raises(DatabaseError, match=r"zero\.db: is an empty file, not a surfidx database "
                                            "yet; create it with `surfidx ingest`"):
        Database(tmp_path / "zero.db", readonly=True)
    assert (tmp_path / "zero.db").read_bytes() == b""
    conn = sqlite3.connect(tmp_path / "blank.db")      # an SQLite file without tables
    conn.execute("PRAGMA page_size = 1024")
    conn.execute("VACUUM")
    conn.close()
    before = _digest(tmp_path / "blank.db")
    with pytest.raises(DatabaseError, match=r"holds no surfidx schema yet"):
        Database(tmp_path / "blank.db", readonly=True)
    assert _digest(tmp_path / "blank.db") == before


def test_readonly_open_of_an_older_schema(tmp_path, monkeypatch):
    path = tmp_path / "v1.db"
    _v1_database(path)
    monkeypatch.setattr(dbmod, "SCHEMA_VERSION", 2)
    monkeypatch.setattr(dbmod, "MIGRATIONS", [lambda conn: None])
    with pytest.raises(DatabaseError, match=r"schema version 1 is older than this surfidx's "
                                            r"\(2\) and a read-only open cannot upgrade it"):
        Database(path, readonly=True)


def test_damaged_file_is_one_database_error(tmp_path):
    path = tmp_path / "bad.db"
    with Database(path) as d:
        for i in range(8):
            d.add(make_model(i))
    damage_database(path)
    with pytest.raises(DatabaseError, match=r"bad\.db: the database file is damaged \(database "
                                            r"disk image is malformed\); restore it"):
        with Database(path, readonly=True) as d:
            d.list_models()
            d.get_model(1)


class _FakeConn:
    """A connection that raises ``error`` on every statement once ``armed`` (after opening)."""

    armed = False

    def __init__(self, real, error):
        self.real, self.error = real, error

    def __getattr__(self, name):
        return getattr(self.real, name)

    def execute(self, sql, *args):
        if _FakeConn.armed and not sql.startswith(("ROLLBACK", "RELEASE")):
            raise self.error
        return self.real.execute(sql, *args)

    executemany = execute


@pytest.mark.parametrize("error, message", [
    (sqlite3.OperationalError("database is locked"), r"locked by another process \(database "
                                                     r"is locked\) for longer than 30 s"),
    (sqlite3.OperationalError("attempt to write a readonly database"),
     r"cannot write: the database is read-only"),
    (sqlite3.OperationalError("database or disk is full"), r"the disk is full"),
    (sqlite3.DatabaseError("database disk image is malformed"), r"the database file is damaged"),
    (sqlite3.OperationalError("disk I/O error"), r"input/output error \(disk I/O error\)"),
    (sqlite3.OperationalError("something else"), r"SQLite error \(something else\)"),
])
def test_every_sqlite_error_is_a_database_error(tmp_path, monkeypatch, error, message):
    path = tmp_path / "f.db"
    Database(path).close()
    real_connect = dbmod.connect
    monkeypatch.setattr(dbmod, "connect", lambda *a: _FakeConn(real_connect(*a), error))
    monkeypatch.setattr(_FakeConn, "armed", False)
    with Database(path) as d:
        _FakeConn.armed = True
        for call in (d.count, d.list_models, lambda: d.get_model(1), d.runs,
                     lambda: d.start_run(["x"]), lambda: d.add(make_model(1))):
            with pytest.raises(DatabaseError, match=r"f\.db: .*" + message) as info:
                call()
            assert "\n" not in str(info.value) and info.value.__cause__ is error


def test_read_only_file_real_error(tmp_path, monkeypatch):
    """SQLite's own SQLITE_READONLY (the file opened mode=ro underneath, as on a read-only
    mount): one DatabaseError, the file unchanged."""
    path = tmp_path / "ro.db"
    Database(path).close()
    before = _digest(path)
    real_connect = dbmod.connect
    monkeypatch.setattr(dbmod, "connect", lambda p, mode, t: real_connect(p, "ro", t))
    with Database(path) as d:
        with pytest.raises(DatabaseError, match=r"ro\.db: cannot write: the database is read-only "
                                                r"\(attempt to write a readonly database\)"):
            d.start_run(["x"])
    assert _digest(path) == before


def test_full_disk_real_error_rolls_back(tmp_path, monkeypatch):
    """SQLite's own SQLITE_FULL (max_page_count reached): the model is not stored, earlier
    ones stay whole, the file passes the integrity check."""
    path = tmp_path / "full.db"
    real_connect = dbmod.connect

    def small(p, mode, t):
        conn = real_connect(p, mode, t)
        conn.execute("PRAGMA max_page_count = 40")
        return conn

    monkeypatch.setattr(dbmod, "connect", small)
    stored = 0
    with Database(path) as d:
        with pytest.raises(DatabaseError, match=r"full\.db: the disk is full \(database or disk "
                                                r"is full\); the transaction was rolled back"):
            for i in range(50):
                m = make_model(i)
                m.stream = bytes(np.random.default_rng(i).integers(0, 256, 20000, np.uint8))
                d.add(m)
                stored += 1
        assert d.count() == stored > 0
        assert not d.conn.in_transaction
    monkeypatch.undo()
    with Database(path) as d:
        assert d.conn.execute("PRAGMA integrity_check").fetchone()[0] == "ok"
        assert d.count() == d.db["assets"].count == d.db["thumbnails"].count == stored


def test_lock_held_past_the_timeout(tmp_path):
    path = tmp_path / "l.db"
    Database(path).close()
    other = sqlite3.connect(path, isolation_level=None)
    other.execute("BEGIN IMMEDIATE")                    # another process holds the write lock
    try:
        with Database(path, timeout=0.05) as d:
            with pytest.raises(DatabaseError, match=r"l\.db: the database is locked by another "
                                                    r"process \(database is locked\) for longer "
                                                    r"than 0\.05 s"):
                d.start_run(["x"])
            assert d.count() == 0                         # reading goes on (WAL)
    finally:
        other.execute("ROLLBACK")
        other.close()


def test_ids_beyond_64_bits_are_no_model(db):
    db.add(make_model(1))
    for big in (2 ** 63, -(2 ** 63) - 1, 10 ** 30):
        with pytest.raises(DatabaseError, match=rf"no model with id {big} \(ids are 64-bit"):
            db.get_model(big)
    assert db.errors(2 ** 63) == []


@settings(max_examples=200, deadline=None)
@given(st.binary(max_size=40))
def test_escape_name_is_lossless_and_storable(raw):
    import os

    name = os.fsdecode(raw.replace(b"\x00", b"").replace(b"/", b""))
    stored = dbmod.escape_name(name)
    stored.encode("utf-8")                               # always storable
    assert dbmod.unescape_name(stored) == name
    if "\\" not in name and name.encode("utf-8", "surrogateescape").decode("utf-8",
                                                                           "replace") == name:
        assert stored == name                             # valid UTF-8 names are unchanged


def test_escape_name_examples():
    import os

    assert dbmod.escape_name(os.fsdecode(b"caf\xe9.ply")) == "caf\\xe9.ply"
    assert dbmod.escape_name("café.ply") == "café.ply"
    assert dbmod.escape_name("C:\\scans\\bunny.ply") == "C:\\scans\\bunny.ply"
    assert dbmod.escape_name("a\\xe9") == "a\\\\xe9"        # a literal backslash-x: doubled
    assert dbmod.escape_name("\ud800") == "\\ud800"
    assert dbmod.storable_text(os.fsdecode(b"bad \xff \\x")) == "bad \\xff \\x"


def test_non_utf8_names_are_stored(db):
    import os

    name = os.fsdecode(b"caf\xe9")
    m = make_model(1, name=name, source=os.fsdecode(b"/d/caf\xe9.ply"))
    mid = db.add(m)
    rec = db.get_model(mid)
    assert (rec["name"], rec["source"], rec["source_abs"]) == ("caf\\xe9", "caf\\xe9.ply",
                                                             "/d/caf\\xe9.ply")
    assert db.resolve(name) == db.resolve("caf\\xe9") == mid
    run = db.start_run([os.fsdecode(b"/d/\xff")])
    db.record_error(run, os.fsdecode(b"/d/\xff.ply"), os.fsdecode(b"/d/\xff.ply: bad"))
    assert db.errors() == [{"run_id": run, "path": "/d/\\xff.ply", "error": "/d/\\xff.ply: bad",
                            "at": db.errors()[0]["at"]}]
    assert db.runs()[-1]["paths"] == ["/d/\\xff"]
    with pytest.raises(DatabaseError, match=r"no model named 'x\\\\xff'"):
        db.resolve(os.fsdecode(b"x\xff"))


def _real_v1_database(path):
    """A database as surfidx schema 1 made it (no tags, triggers or views; a name index that
    is not unique), holding two models of one name and rows a delete without foreign keys
    left behind."""
    conn = sqlite3.connect(path)
    for stmt in dbmod.split_statements(schema_sql()):
        code = "\n".join(ln for ln in stmt.splitlines() if not ln.strip().startswith("--"))
        if __import__("re").search(r"\b(tags|TRIGGER|VIEW|model_topology)\b", code):
            continue
        conn.execute(stmt.replace("CREATE UNIQUE INDEX models_name", "CREATE INDEX models_name"))
    conn.execute("INSERT INTO meta VALUES ('schema_version', '1')")
    for i, src in enumerate(("/a/twin.obj", "/b/twin.obj", "/c/gone.obj")):
        conn.execute("INSERT INTO models (name, source, content_hash, n_surfels, has_color, "
                     "bbox_min_x, bbox_min_y, bbox_min_z, bbox_max_x, bbox_max_y, bbox_max_z, "
                     "ingested_at) VALUES (?, ?, ?, 3, 0, 0, 0, 0, 1, 1, 1, 'then')",
                     ("gone" if i == 2 else "twin", src, f"h{i}"))
        conn.execute("INSERT INTO thumbnails VALUES (?, x'00')", (i + 1,))
    conn.execute("DELETE FROM models WHERE id = 3")             # foreign keys off: an orphan
    conn.execute(f"PRAGMA application_id = {dbmod.APPLICATION_ID}")
    conn.execute("PRAGMA user_version = 1")
    conn.commit()
    conn.close()


def test_real_migration_1_to_2(tmp_path):
    path = tmp_path / "v1.db"
    _real_v1_database(path)
    with Database(path) as d:
        assert d.schema_version == SCHEMA_VERSION
        assert d.conn.execute("SELECT id, name FROM models ORDER BY id").fetchall() == [
            (1, "twin"), (2, "b")]
        assert d.conn.execute("SELECT model_id FROM thumbnails").fetchall() == [(1,), (2,)]
        migrated = _schema_of(d.conn)
    with Database(tmp_path / "new.db") as d:
        fresh = _schema_of(d.conn)
    assert migrated == fresh


def _schema_of(conn) -> dict:
    """Name -> SQL (whitespace collapsed) of every table, index and trigger of a database."""
    import re

    return {r[0]: re.sub(r"\s+", " ", r[1]) for r in conn.execute(
        "SELECT name, sql FROM sqlite_master WHERE sql IS NOT NULL")}


def test_real_migration_2_to_3(tmp_path):
    """A schema-2 database (no model_topology, the old delete trigger) opens as schema 3 with
    the schema a new database has; its models are kept and have no topology record."""
    path = tmp_path / "v2.db"
    with Database(path):
        pass
    conn = sqlite3.connect(path)
    conn.execute("DROP TABLE model_topology")
    conn.execute("DROP TRIGGER models_delete_rows")
    conn.execute("CREATE TRIGGER models_delete_rows AFTER DELETE ON models BEGIN "
                 "DELETE FROM assets WHERE model_id = OLD.id; "
                 "DELETE FROM descriptors WHERE model_id = OLD.id; "
                 "DELETE FROM thumbnails WHERE model_id = OLD.id; "
                 "DELETE FROM tags WHERE model_id = OLD.id; END")
    conn.execute("INSERT INTO models (name, source, content_hash, n_surfels, has_color, "
                 "bbox_min_x, bbox_min_y, bbox_min_z, bbox_max_x, bbox_max_y, bbox_max_z, "
                 "ingested_at) VALUES ('old', '/a/old.obj', 'h', 3, 0, 0, 0, 0, 1, 1, 1, 'then')")
    conn.execute("UPDATE meta SET value = '2' WHERE key = 'schema_version'")
    conn.execute("PRAGMA user_version = 2")
    conn.commit()
    conn.close()
    with Database(path) as d:
        assert d.schema_version == SCHEMA_VERSION
        assert d.get_model("old")["topology"] is None
        d.conn.execute("INSERT INTO model_topology (model_id, parts) VALUES (1, 1)")
        d.conn.execute("PRAGMA foreign_keys = OFF")
        d.conn.execute("DELETE FROM models WHERE id = 1")        # the trigger removes the row
        assert d.conn.execute("SELECT count(*) FROM model_topology").fetchone()[0] == 0
        migrated = _schema_of(d.conn)
    with Database(tmp_path / "new.db") as d:
        fresh = _schema_of(d.conn)
    assert migrated == fresh
