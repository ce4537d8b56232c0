"""Colour written as a texture: decode(texture=True), GLB with TEXCOORD_0 and a
baseColorTexture, OBJ with .mtl (map_Kd) and the image, the CLI's and Database.export's
options."""

from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner

from surfidx import InputError, write_model
from surfidx.cli import cli
from surfidx.codec import decode, encode
from surfidx.io import read_mesh
from surfidx.io.texture import check_image_options
from surfidx.pipeline import export_texture

from helpers import coloured_limbs, glb_json

trimesh = pytest.importorskip("trimesh")


@pytest.fixture(scope="module")
def coded(tmp_path_factory):
    """A sphere with limbs coloured by position, coded at 8 bits/surfel, as a .sfz file."""
    s = coloured_limbs()
    data = encode(s, bits_per_surfel=8.0)
    path = tmp_path_factory.mktemp("tex") / "limbs.sfz"
    path.write_bytes(data)
    return s, data, path


def test_decode_with_texture_gives_uvs_on_the_atlas_and_an_image(coded):
    _, data, _ = coded
    plain = decode(data, mesh=True)
    m = decode(data, mesh=True, texture=True, texture_size=128)
    assert m.vertex_colors is None and m.texture.shape == (128, 128, 3)
    np.testing.assert_array_equal(m.vertices, plain.vertices)
    np.testing.assert_array_equal(m.faces, plain.faces)
    assert np.all((m.uv >= 0) & (m.uv <= 1))
    # with texels to spare, the texture read at each face corner gives back the vertex colour
    from surfidx.geometry.mesh import sample_texture

    fine = decode(data, mesh=True, texture=True, texture_size=2048)
    got = sample_texture(fine.texture, fine.uv[fine.uv_faces.ravel()])
    want = plain.vertex_colors[plain.faces.ravel()].astype(float)
    assert np.abs(got - want).max() <= 1.0


def test_glb_carries_texcoords_normals_and_a_base_colour_texture(coded, tmp_path):
    _, data, _ = coded
    m = decode(data, mesh=True, texture=True, texture_size=128)
    out = tmp_path / "m.glb"
    write_model(m, out)
    doc = glb_json(out)
    attrs = doc["meshes"][0]["primitives"][0]["attributes"]
    assert set(attrs) == {"POSITION", "NORMAL", "TEXCOORD_0"}
    assert doc["materials"][0]["pbrMetallicRoughness"]["baseColorTexture"] == {"index": 0}
    assert doc["images"][0]["mimeType"] == "image/png"
    tm = trimesh.load(out, force="mesh")
    assert tm.visual.material.baseColorTexture.size == (128, 128)
    assert tm.visual.uv.shape == (len(tm.vertices), 2)
    # vertices are split at the seams: more than the mesh's, none lost
    assert len(tm.vertices) > len(m.vertices) and len(tm.faces) == len(m.faces)


@pytest.mark.parametrize("fmt,mime", [("jpeg", "image/jpeg"), ("webp", "image/webp")])
def test_glb_lossy_images(coded, tmp_path, fmt, mime):
    _, data, _ = coded
    m = decode(data, mesh=True, texture=True, texture_size=128)
    out = tmp_path / "m.glb"
    write_model(m, out, image_format=fmt, image_quality=70)
    doc = glb_json(out)
    assert doc["images"][0]["mimeType"] == mime
    if fmt == "webp":
        assert doc["extensionsRequired"] == ["EXT_texture_webp"]
        assert doc["textures"][0]["extensions"]["EXT_texture_webp"]["source"] == 0


def test_obj_export_writes_mtl_and_image_and_reloads_with_its_texture(coded, tmp_path):
    _, data, _ = coded
    m = decode(data, mesh=True, texture=True, texture_size=128)
    out = tmp_path / "m.obj"
    write_model(m, out)
    assert (tmp_path / "m.mtl").read_text().splitlines()[-1] == "map_Kd m.png"
    assert (tmp_path / "m.png").is_file()
    assert "mtllib m.mtl" in out.read_text()
    back = read_mesh(out)
    assert back.texture is not None and back.texture.shape == (128, 128, 3)
    np.testing.assert_array_equal(back.texture, m.texture)
    tm = trimesh.load(out, force="mesh")
    assert tm.visual.material.image.size == (128, 128)


def test_exports_are_deterministic(coded, tmp_path):
    _, data, _ = coded
    for suffix in ("glb", "obj"):
        blobs = []
        for k in range(2):
            d = tmp_path / str(k)
            d.mkdir(exist_ok=True)
            m = decode(data, mesh=True, texture=True, texture_size=128)
            write_model(m, d / f"m.{suffix}", image_format="webp")
            blobs.append([p.read_bytes() for p in sorted(d.iterdir())])
        assert blobs[0] == blobs[1]


def test_cli_decode_writes_a_texture_by_default_and_vertex_colours_on_request(coded, tmp_path):
    _, _, path = coded
    r = CliRunner().invoke(cli, ["decode", str(path), "-o", str(tmp_path / "a.glb"),
                                 "--texture-size", "128", "--json"])
    assert r.exit_code == 0, r.output
    assert json.loads(r.output)["texture"] == 128
    assert "TEXCOORD_0" in glb_json(tmp_path / "a.glb")["meshes"][0]["primitives"][0][
        "attributes"]
    r = CliRunner().invoke(cli, ["decode", str(path), "-o", str(tmp_path / "b.glb"),
                                 "--vertex-colors", "--json"])
    assert r.exit_code == 0, r.output
    attrs = glb_json(tmp_path / "b.glb")["meshes"][0]["primitives"][0]["attributes"]
    assert "COLOR_0" in attrs and "TEXCOORD_0" not in attrs
    r = CliRunner().invoke(cli, ["decode", str(path), "-o", str(tmp_path / "c.obj"),
                                 "--image-format", "jpeg", "--image-quality", "60"])
    assert r.exit_code == 0, r.output
    assert (tmp_path / "c.jpg").is_file() and "texture" in r.output


def test_database_export_and_get_take_the_texture_options(coded, tmp_path):
    from surfidx import Database

    s, _, _ = coded
    db_path = tmp_path / "t.db"
    with Database.open(db_path) as db:
        assert db.ingest(s, workers=1).stored == 1
        out = db.export(1, tmp_path / "x.glb", texture_size=128)
        assert out["texture"] == 128
        out = db.export(1, tmp_path / "y.glb", max_vertices=400)
        assert out["texture"] is None
        with pytest.raises(InputError, match="PNG texture, which is lossless"):
            db.export(1, tmp_path / "z.glb", image_quality=50)
    r = CliRunner().invoke(cli, ["get", "1", "--db", str(db_path), "-o",
                                 str(tmp_path / "g.obj"), "--texture-size", "128", "--json"])
    assert r.exit_code == 0, r.output
    assert json.loads(r.stdout)["texture"] == 128 and (tmp_path / "g.png").is_file()


@pytest.mark.parametrize("kwargs,match", [
    ({"texture": True}, "texture=True needs mesh=True"),
    ({"texture": True, "mesh": True, "max_vertices": 100}, "does not combine with max_vertices"),
    ({"texture": True, "mesh": True, "texture_size": 16}, "texture_size must be an integer"),
    ({"texture_size": 256, "mesh": True}, "texture_size was given without texture=True"),
    ({"texture": "yes", "mesh": True}, "texture must be True or False"),
])
def test_bad_decode_texture_options_fail_cleanly(coded, kwargs, match):
    with pytest.raises(InputError, match=match):
        decode(coded[1], **kwargs)


@pytest.mark.parametrize("fmt,quality,match", [
    ("gif", None, "unknown texture image format 'gif'"),
    ("png", 80, "PNG texture, which is lossless"),
    ("jpeg", 0, "image_quality must be an integer from 1 to 100"),
    ("webp", 101, "image_quality must be an integer from 1 to 100"),
])
def test_bad_image_options_fail_cleanly(fmt, quality, match):
    with pytest.raises(InputError, match=match):
        check_image_options(fmt, quality)


def test_export_texture_default_and_refusals():
    assert export_texture(None, fmt="glb", mesh=True) is True
    assert export_texture(None, fmt="glb", mesh=True, max_vertices=100) is False
    assert export_texture(None, fmt="ply", mesh=False) is False
    with pytest.raises(InputError, match="written with an OBJ or GLB mesh, not ply"):
        export_texture(True, fmt="ply", mesh=False)
    with pytest.raises(InputError, match="a texture does not combine with max_vertices"):
        export_texture(True, fmt="glb", mesh=True, max_vertices=100)
    with pytest.raises(InputError, match="texture_size=512 was given but"):
        export_texture(False, fmt="glb", mesh=True, texture_size=512)


def test_cli_refuses_bad_texture_options(coded, tmp_path):
    _, _, path = coded
    r = CliRunner().invoke(cli, ["decode", str(path), "-o", str(tmp_path / "a.glb"),
                                 "--image-quality", "80"])
    assert r.exit_code != 0 and "lossless" in r.output


def test_textured_arrays_split_at_seams_in_order_of_first_use():
    """One GLB vertex per distinct (vertex, texture coordinate) pair of the corners, in order
    of first use, also where a texture coordinate is shared by several vertices (as a zipped
    cut's strip shares its first corner's) and a vertex has several coordinates."""
    from surfidx.geometry.mesh import TriangleMesh
    from surfidx.io.gltf import textured_arrays

    rng = np.random.default_rng(7)
    verts = rng.standard_normal((9, 3))
    faces = rng.integers(0, 9, (40, 3))
    uv = rng.random((12, 2))
    owner = rng.integers(0, 12, 9)
    uv_faces = owner[faces]
    uv_faces[::5] = uv_faces[::5, :1]            # strips: the first corner's coordinate
    uv_faces[3] = rng.integers(0, 12, 3)
    mesh = TriangleMesh(verts, faces, uv=uv, uv_faces=uv_faces,
                        texture=np.zeros((4, 4, 3), np.uint8))
    pairs, corner = {}, []
    for v, t in zip(faces.ravel().tolist(), uv_faces.ravel().tolist()):
        corner.append(pairs.setdefault((v, t), len(pairs)))
    pos, nrm, tex, tri = textured_arrays(mesh)
    want_v = [v for v, _ in pairs]
    np.testing.assert_array_equal(tri.ravel(), corner)
    np.testing.assert_array_equal(pos, verts[want_v])
    np.testing.assert_array_equal(nrm, mesh.vertex_normals()[want_v])
    np.testing.assert_array_equal(tex, uv[[t for _, t in pairs]])
