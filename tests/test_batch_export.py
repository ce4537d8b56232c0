"""Batch export: several models, a tag or every model into a folder, models or thumbnails."""

from __future__ import annotations

import json

import pytest
from click.testing import CliRunner

from surfidx import InputError
from surfidx.cli import cli
from surfidx.database import Database

from helpers import shapes_database

trimesh = pytest.importorskip("trimesh")


@pytest.fixture(scope="module")
def shapes(tmp_path_factory):
    return shapes_database(tmp_path_factory.mktemp("batch") / "shapes.db", [
        ("ball", "ball", ["round"]), ("capsule", "capsule", ["round", "long"]),
        ("box", "a/b box", [])])


def run(args):
    return CliRunner().invoke(cli, [str(a) for a in args])


def test_export_many_writes_one_file_per_model_named_after_it(shapes, tmp_path):
    with Database.open(shapes, readonly=True) as db:
        written, failed = db.export_many(["ball", "capsule"], tmp_path / "out", format="ply",
                                         bits_per_surfel=2)
        assert failed == [] and [w["name"] for w in written] == ["ball", "capsule"]
        assert sorted(p.name for p in (tmp_path / "out").iterdir()) == ["ball.ply", "capsule.ply"]
        written, _ = db.export_many(folder=tmp_path / "all", format="sfz")      # every model
        names = sorted(p.name for p in (tmp_path / "all").iterdir())
        assert names == ["a_b box.sfz", "ball.sfz", "capsule.sfz"]           # '/' made safe
        assert (tmp_path / "all/ball.sfz").read_bytes() == db.get_sfz("ball")
        written, _ = db.export_many(tag="long", folder=tmp_path / "t", thumbnails=True)
        assert [w["name"] for w in written] == ["capsule"]
        assert (tmp_path / "t/capsule.png").read_bytes() == db.get_thumbnail("capsule")


def test_export_many_refuses_what_names_nothing(shapes, tmp_path):
    with Database.open(shapes, readonly=True) as db:
        with pytest.raises(InputError, match="format must be one of glb, obj, ply, sfz"):
            db.export_many(["ball"], tmp_path, format="stl")
        with pytest.raises(InputError, match="the selection names no stored model"):
            db.export_many(tag="none-such", folder=tmp_path)


def test_cli_get_several_tag_all_and_thumbnails(shapes, tmp_path):
    r = run(["get", "ball", "capsule", "-o", tmp_path / "two", "--db", shapes,
             "--bits-per-surfel", "2", "--json"])
    assert r.exit_code == 0, r.output
    out = json.loads(r.stdout)
    assert [w["name"] for w in out["written"]] == ["ball", "capsule"] and out["failed"] == []
    assert sorted(p.name for p in (tmp_path / "two").iterdir()) == ["ball.glb", "capsule.glb"]
    r = run(["get", "--tag", "round", "--format", "obj", "-o", tmp_path / "tag", "--db", shapes,
             "--vertex-colors"])
    assert r.exit_code == 0, r.output
    assert sorted(p.name for p in (tmp_path / "tag").iterdir()) == ["ball.obj", "capsule.obj"]
    r = run(["get", "--all", "--thumbnails", "-o", tmp_path / "th", "--db", shapes])
    assert r.exit_code == 0, r.output
    assert len(list((tmp_path / "th").glob("*.png"))) == 3
    assert r.stdout.strip().endswith("3 written, 0 failed")


def test_cli_get_refusals(shapes, tmp_path):
    r = run(["get", "--all", "ball", "-o", tmp_path / "x", "--db", shapes])
    assert r.exit_code == 1 and "--all selects every model" in r.output
    r = run(["get", "-o", tmp_path / "x", "--db", shapes])
    assert r.exit_code == 1 and "name a model (ID, id:ID or NAME)" in r.output
    (tmp_path / "d").mkdir()
    r = run(["get", "ball", "-o", tmp_path / "d", "--db", shapes])
    assert r.exit_code == 1 and "is a folder; give a file to write one model to" in r.output
    (tmp_path / "f.glb").write_bytes(b"x")
    r = run(["get", "ball", "capsule", "-o", tmp_path / "f.glb", "--db", shapes])
    assert r.exit_code == 1 and "is a file; several models go into a folder" in r.output
