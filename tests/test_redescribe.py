"""Recomputing stored descriptors from stored assets: Database.set_descriptors,
pipeline.describe_stream / redescribe and ``surfidx redescribe``."""

from __future__ import annotations

import hashlib
import json

import numpy as np
import pytest
from click.testing import CliRunner
from conftest import icosphere_mesh

from surfidx import DatabaseError, InputError, TriangleMesh
from surfidx.cli import cli
from surfidx.codec import Encoder, decode_grid
from surfidx.database import Database
from surfidx.describe.descriptors import describe_grid, descriptor_params
from surfidx.pipeline import ProcessedModel, describe_stream, redescribe


@pytest.fixture(scope="module")
def encoded():
    v, f = icosphere_mesh(3)
    out = []
    for k, stretch in enumerate(([1.0, 1.3, 0.8], [1.0, 1.0, 2.0])):
        p = v * (1 + 0.25 * v[:, [0]] ** 2) * stretch
        surfels = TriangleMesh(p, f, name=f"blob{k}").to_surfels()
        enc = Encoder(surfels, level=4)
        out.append((enc, enc.encode(8.0), len(surfels)))
    return out


def _model(k, stream, n, *, shape_dim=16):
    """A model as an older surfidx stored it: descriptors of another version and size."""
    rng = np.random.default_rng(k)
    return ProcessedModel(
        name=f"m{k}", source=f"/data/m{k}.ply",
        content_hash=hashlib.sha256(f"m{k}".encode()).hexdigest(), n_surfels=n,
        has_color=False, bbox=np.array([[0.0, 0, 0], [1, 1, 1]]), stream=stream,
        format_version=1, rate=8.0 * len(stream) / n, quality={},
        descriptors={"shape": rng.standard_normal(shape_dim).astype(np.float32),
                     "spectrum": rng.random(3).astype(np.float32)},
        thumbnail=b"\x89PNG", params={"descriptors": {"lmax": 24, "version": 2}})


def test_describe_stream_describes_the_decoded_grid(encoded):
    enc, stream, _ = encoded[0]
    got = describe_stream(stream)
    values, header = decode_grid(stream)
    want = describe_grid(values, header.level)
    for kind in want.vectors:
        np.testing.assert_array_equal(got.vectors[kind], want.vectors[kind])
    assert got.params == descriptor_params()
    # close to what ingest stored (the grid before coding): the coding error at 8 bits/surfel
    exact = describe_grid(enc.grid, enc.level).vectors["shape"]
    assert np.linalg.norm(got.vectors["shape"] - exact) < 0.05 * np.linalg.norm(exact)


def test_redescribe_updates_outdated_models_only_and_records_failures(encoded, tmp_path):
    with Database(tmp_path / "old.db") as db:
        ids = [db.add(_model(k, s, n)) for k, (_, s, n) in enumerate(encoded)]
        bad = db.add(_model(9, b"SFZ?" + bytes(60), 100))
        with pytest.raises(DatabaseError, match="run `surfidx redescribe`"):
            _mixed(db, encoded)
        seen = []
        out = redescribe(db, progress=seen.append)
        assert out["redescribed"] == 2 and out["current"] == 0 and list(out["failed"]) == [bad]
        assert seen == sorted(ids + [bad])
        for i, (_, s, _) in zip(ids, encoded):
            stored = db.get_descriptors(i)
            np.testing.assert_array_equal(stored["shape"], describe_stream(s).vectors["shape"])
            assert db.get_model(i)["params"]["descriptors"] == json.loads(
                json.dumps(descriptor_params()))
        db.delete(bad)
        mids, mat = db.descriptor_matrix("shape")
        assert list(mids) == ids and mat.shape[1] == describe_stream(encoded[0][1]).vectors[
            "shape"].size
        assert redescribe(db) == {"redescribed": 0, "current": 2, "failed": {}}
        assert redescribe(db, everything=True)["redescribed"] == 2


def _mixed(db, encoded):
    """A current model beside outdated ones: the matrix refuses to mix them."""
    _, s, n = encoded[0]
    m = _model(7, s, n)
    d = describe_stream(s)
    m.descriptors, m.params = d.vectors, {"descriptors": d.params}
    mid = db.add(m)
    try:
        db.descriptor_matrix("shape")
    finally:
        db.delete(mid)


def test_set_descriptors_errors(tmp_path, encoded):
    with Database(tmp_path / "x.db") as db:
        with pytest.raises(DatabaseError, match="no model with id 5"):
            db.set_descriptors(5, {"shape": np.ones(3)}, {})
        mid = db.add(_model(0, encoded[0][1], encoded[0][2]))
        with pytest.raises(InputError, match="descriptor 'shape'"):
            db.set_descriptors(mid, {"shape": np.array([1.0, np.nan])}, {})
        assert db.get_descriptors(mid)["shape"].size == 16   # untouched


def test_cli_redescribe(encoded, tmp_path):
    path = tmp_path / "cli.db"
    with Database(path) as db:
        db.add(_model(0, encoded[0][1], encoded[0][2]))
        bad = db.add(_model(9, b"garbage" * 10, 100))
    r = CliRunner().invoke(cli, ["redescribe", "--db", str(path)])
    assert r.exit_code == 1
    assert "redescribed 1, up to date 0, failed 1" in r.output
    assert f"failed id {bad}:" in r.output and "Traceback" not in r.output
    with Database(path) as db:
        db.delete(bad)
    r = CliRunner().invoke(cli, ["redescribe", "--db", str(path), "--all", "--json"])
    assert r.exit_code == 0, r.output
    assert json.loads(r.stdout) == {"redescribed": 1, "current": 0, "failed": {}}


def test_redescribe_stops_on_a_database_that_cannot_be_written(encoded, tmp_path, monkeypatch):
    """A full disk (or a read-only or damaged file) is one DatabaseError for the whole run, not
    one recorded failure per model."""
    import sqlite3

    db = Database(tmp_path / "full.db")
    for k, (_, stream, n) in enumerate(encoded):
        db.add(_model(k, stream, n))

    def full(*args, **kwargs):
        raise DatabaseError("the disk is full", path=db.path) from sqlite3.OperationalError(
            "database or disk is full")

    monkeypatch.setattr(db, "set_descriptors", full)
    with pytest.raises(DatabaseError, match="the disk is full"):
        redescribe(db)


def test_queries_refuse_the_previous_descriptor_version_until_redescribed(encoded, tmp_path):
    """Vectors of the previous descriptor version, even of the same dimensions, are never ranked
    beside this version's: the search refuses the mix, ``redescribe`` updates the old ones."""
    from surfidx.describe.descriptors import DESCRIPTOR_VERSION
    from surfidx.db.search import SearchIndex

    (_, s0, n0), (_, s1, n1) = encoded
    with Database(tmp_path / "v.db") as db:
        old = _model(0, s0, n0)
        d = describe_stream(s0)
        old.descriptors = d.vectors                       # today's dimensions ...
        old.params = {"descriptors": dict(d.params, version=DESCRIPTOR_VERSION - 1)}
        old_id = db.add(old)                              # ... under the previous version
        new = _model(1, s1, n1)
        d1 = describe_stream(s1)
        new.descriptors, new.params = d1.vectors, {"descriptors": d1.params}
        new_id = db.add(new)
        with pytest.raises(DatabaseError, match="run `surfidx redescribe`"):
            SearchIndex(db, exact=True).query(d1.vectors, k=2)
        out = redescribe(db)
        assert out == {"redescribed": 1, "current": 1, "failed": {}}
        ids, dist = SearchIndex(db, exact=True).query(d1.vectors, k=2)
        assert ids.tolist() == [new_id, old_id] and dist[0] == pytest.approx(0.0, abs=1e-6)
        assert db.get_model(old_id)["params"]["descriptors"]["version"] == DESCRIPTOR_VERSION
