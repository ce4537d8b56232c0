"""Filtered search: query and ls narrowed by tags and a filter on the stored figures."""

from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner

from surfidx import InputError
from surfidx.cli import cli
from surfidx.database import Database
from surfidx.db import where_sql

from helpers import shapes_database

trimesh = pytest.importorskip("trimesh")


@pytest.fixture(scope="module")
def shapes(tmp_path_factory):
    return shapes_database(tmp_path_factory.mktemp("filtered") / "shapes.db", [
        ("ball", "ball", ["round"]), ("capsule", "capsule", ["round", "long"]),
        ("box", "box", []), ("cylinder", "cylinder", ["long"])])


def test_where_sql_binds_values_and_names_columns():
    sql, args = where_sql("surfels >= 100 and colour = true and psnr_d1 > 45.5 and "
                          "name like 'b%'")
    assert sql == "m.n_surfels >= ? AND m.has_color = ? AND a.psnr_d1 > ? AND m.name LIKE ?"
    assert args == [100, 1, 45.5, "b%"]


@pytest.mark.parametrize("bad, match", [
    ("", "the filter is empty"),
    ("surfels >", "cannot read the filter clause 'surfels >'"),
    ("bogus = 1", "unknown filter field 'bogus'; use one of"),
    ("surfels = 1; DROP TABLE models", "cannot read the filter clause"),
])
def test_where_sql_refuses(bad, match):
    with pytest.raises(InputError, match=match):
        where_sql(bad)


def test_a_filter_that_passes_all_gives_the_unfiltered_answer(shapes):
    with Database.open(shapes, readonly=True) as db:
        plain = db.query("ball", k=3)
        passing = db.query("ball", k=3, where="id >= 1")
        assert [r["id"] for r in plain] == [r["id"] for r in passing]
        np.testing.assert_allclose([r["distance"] for r in plain],
                                   [r["distance"] for r in passing], rtol=1e-9)


def test_tags_and_where_narrow_exactly(shapes):
    with Database.open(shapes, readonly=True) as db:
        allowed = set(db.select_ids(tag="long").tolist())
        hits = db.query("ball", k=10, tag="long")
        assert {r["name"] for r in hits} == {"capsule", "cylinder"}
        assert {r["id"] for r in hits} == allowed
        n_box = db.get_model("box")["n_surfels"]
        hits = db.query("ball", k=10, where=f"surfels = {n_box}")
        assert [r["name"] for r in hits] == ["box"]
        assert db.query("ball", k=5, tag=["round", "long"], where="name = 'capsule'")[0][
            "name"] == "capsule"
        assert db.query("ball", k=5, tag="none-such") == []
        assert [m["name"] for m in db.list_models(where="name like 'c%'")] == ["capsule",
                                                                              "cylinder"]


def test_cli_query_and_ls_take_tag_and_where(shapes):
    r = CliRunner().invoke(cli, ["query", "ball", "--db", str(shapes), "--tag", "long",
                                 "--where", "surfels > 0", "--json"])
    assert r.exit_code == 0, r.output
    assert {x["name"] for x in json.loads(r.stdout)["results"]} == {"capsule", "cylinder"}
    r = CliRunner().invoke(cli, ["ls", "--db", str(shapes), "--where", "name = 'box'", "--json"])
    assert r.exit_code == 0 and [m["name"] for m in json.loads(r.stdout)["models"]] == ["box"]
    r = CliRunner().invoke(cli, ["ls", "--db", str(shapes), "--where", "size > 3"])
    assert r.exit_code == 1 and "unknown filter field 'size'" in r.output
