"""The Datasette plugin (surfidx.browse) through Datasette's own test client: rounded figures,
thumbnails, and each model as GLB from its row, decoded on request; clean 404/400 errors."""

from __future__ import annotations

import asyncio
import io
import json
import shutil
import sqlite3

import numpy as np
import pytest

from surfidx.database import Database

datasette_app = pytest.importorskip("datasette.app")
from helpers import shapes_database

trimesh = pytest.importorskip("trimesh")


@pytest.fixture(scope="module")
def shapes(tmp_path_factory):
    return shapes_database(tmp_path_factory.mktemp("browse") / "shapes.db", [
        ("ball", "ball", ["round"]), ("box", "a/b box", [])])


@pytest.fixture(scope="module")
def plugin():
    """The plugin as the entry point registers it (registered here when the installed
    surfidx's metadata predates the entry point)."""
    from datasette.plugins import pm

    import surfidx.browse as mod

    added = pm.get_plugin("surfidx") is None and not pm.is_registered(mod)
    if added:
        pm.register(mod, name="surfidx")
    yield mod
    if added:
        pm.unregister(mod)


def fetch(paths, path):
    """Datasette responses of ``path`` (str) or of each path (list) on the database files."""
    ds = datasette_app.Datasette([str(p) for p in paths])

    async def go(many):
        return [await ds.client.get(p) for p in many]

    many = [path] if isinstance(path, str) else path
    out = asyncio.run(go(many))
    return out[0] if isinstance(path, str) else out


def test_entry_point_names_the_plugin_module():
    import tomllib
    from pathlib import Path

    meta = tomllib.loads((Path(__file__).parents[1] / "pyproject.toml").read_text())
    assert meta["project"]["entry-points"]["datasette"] == {"surfidx": "surfidx.browse"}


def test_import_surfidx_does_not_import_datasette():
    import subprocess
    import sys

    code = "import sys, surfidx; surfidx.Database; print('datasette' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout.strip()
    assert out == "False"


def test_glb_route_decodes_the_stored_model(shapes, plugin):
    with Database.open(shapes, readonly=True) as db:
        mid = db.resolve("a/b box")
        n = db.get(mid).to_trimesh().vertices.shape[0]
    r = fetch([shapes], f"/-/surfidx/shapes/{mid}.glb")
    assert r.status_code == 200
    assert r.headers["content-type"] == "model/gltf-binary"
    assert r.headers["content-disposition"] == (
        "attachment; filename=\"a_b_box.glb\"; filename*=UTF-8''a%2Fb%20box.glb")
    assert r.content[:4] == b"glTF"
    scene = trimesh.load(io.BytesIO(r.content), file_type="glb", force="mesh")
    assert scene.vertices.shape[0] == n
    # the same bytes as `surfidx get` writes, at a rate and a level
    coarse = fetch([shapes], f"/-/surfidx/shapes/{mid}.glb?bits=8&level=2")
    assert coarse.status_code == 200
    with Database.open(shapes, readonly=True) as db:
        out = shapes.parent / "coarse.glb"
        db.export(mid, out, bits_per_surfel=8, level=2)
    assert coarse.content == out.read_bytes() and coarse.content != r.content


def test_png_route_serves_the_stored_thumbnail(shapes, plugin):
    with Database.open(shapes, readonly=True) as db:
        png = db.get_thumbnail(1)
    r = fetch([shapes], "/-/surfidx/shapes/1.png")
    assert r.status_code == 200 and r.headers["content-type"] == "image/png"
    assert r.content == png


@pytest.mark.parametrize("url, status, match", [
    ("/-/surfidx/shapes/99.glb", 404, "no model with id 99"),
    ("/-/surfidx/shapes/99.png", 404, "no model with id 99"),
    ("/-/surfidx/shapes/ball.glb", 400, "model id must be an integer, got &#39;ball&#39;"),
    ("/-/surfidx/shapes/1.glb?bits=abc", 400, "bits must be a number, got &#39;abc&#39;"),
    ("/-/surfidx/shapes/1.glb?bits=-1", 400, "bits must be a positive number"),
    ("/-/surfidx/shapes/1.glb?level=x", 400, "level must be an integer, got &#39;x&#39;"),
    ("/-/surfidx/shapes/1.glb?level=42", 400, "shapes: model 1: .*level"),
    ("/-/surfidx/shapes/1.glb?bits=0.0001", 400, "shapes: model 1: "),
    ("/-/surfidx/nowhere/1.glb", 404, "no database &#39;nowhere&#39;"),
])
def test_bad_requests_get_clean_errors(shapes, plugin, url, status, match):
    import re

    r = fetch([shapes], url)
    assert r.status_code == status
    assert re.search(match, r.text), r.text[:2000]
    assert "Traceback" not in r.text


def test_damaged_row_and_foreign_database_are_refused(shapes, plugin, tmp_path):
    bad = tmp_path / "bad.db"
    shutil.copy(shapes, bad)
    with sqlite3.connect(bad) as conn:
        conn.execute("UPDATE assets SET stream = substr(stream, 1, 60) WHERE model_id = 1")
    other = tmp_path / "other.db"
    with sqlite3.connect(other) as conn:
        conn.execute("CREATE TABLE t (x REAL)")
        conn.execute("INSERT INTO t VALUES (44.22883283735754)")
    empty = tmp_path / "empty.db"                       # surfidx's mark, no schema
    with sqlite3.connect(empty) as conn:
        conn.execute(f"PRAGMA application_id = {int.from_bytes(b'SFDX', 'big')}")
        conn.execute("PRAGMA user_version = 3")
    got = fetch([bad, other, empty], ["/-/surfidx/bad/1.glb", "/-/surfidx/bad/2.glb",
                                      "/-/surfidx/other/1.glb", "/other/t",
                                      "/-/surfidx/empty/1.glb"])
    assert got[4].status_code == 400 and "empty: carries surfidx&#39;s application id but " \
        "no schema" in got[4].text and "the file is damaged" in got[4].text
    assert got[0].status_code == 400 and "bad: model 1: " in got[0].text
    assert got[1].status_code == 200 and got[1].content[:4] == b"glTF"
    assert got[2].status_code == 404 and "not a surfidx database" in got[2].text
    assert str(tmp_path) not in got[0].text + got[2].text        # no server path
    assert got[3].status_code == 200 and "44.22883283735754" in got[3].text   # left alone


def test_pages_show_rounded_figures_thumbnails_and_glb_links(shapes, plugin):
    with Database.open(shapes, readonly=True) as db:
        rec = db.list_models()
    psnr = rec[0]["psnr_d1"]
    assert round(psnr, 2) != psnr                       # a figure with more digits stored
    models, row, gallery, assets, thumbs, data = fetch([shapes], [
        "/shapes/models", "/shapes/models/1", "/shapes/model_gallery", "/shapes/assets_named",
        "/shapes/thumbnails", "/shapes/assets_named.json?_shape=array"])
    for page in (models, row, gallery):
        assert page.status_code == 200
        assert '<a href="/-/surfidx/shapes/1.glb" download' in page.text
        assert '<img src="/-/surfidx/shapes/1.png"' in page.text
    assert '<img src="/-/surfidx/shapes/2.png"' in thumbs.text
    assert f">{psnr:.2f}<" in assets.text and repr(psnr) not in assets.text
    assert f">{psnr:.2f}<" in gallery.text
    stored = {r["model_id"]: r["psnr_d1"] for r in json.loads(data.text)}
    assert stored[rec[0]["id"]] == psnr                 # the JSON keeps every digit


def test_figure_text_rounds_by_column(plugin):
    assert plugin.figure_text("psnr_d1", 44.22883283735754) == "44.23"
    assert plugin.figure_text("bits_per_surfel", 2.0004999) == "2.000"
    assert plugin.figure_text("bbox_max_x", 0.123456789) == "0.123457"
    assert plugin.figure_text("psnr_y", float("nan")) == "nan"
    assert plugin.figure_text("x", np.float64(1e-9)) == "1e-09"
