"""What a decoded model is written as: by default the stream's own grid level or the coarser one
its output-level hints give for the prefix served, a vertex budget
met by simplification (max_vertices, --max-vertices), normals in every mesh export, surfel PLY
without faces."""

from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner

from surfidx import InputError, TriangleMesh, write_model
from surfidx.cli import cli
from surfidx.codec import CodecOptions, decode, encode, max_file_bytes, output_levels
from surfidx.codec.container import truncate, unpack
from surfidx.geometry import check_max_vertices, simplify_mesh
from surfidx.geometry.icosphere import vertex_count
from surfidx.geometry.metrics import Reference, evaluate
from surfidx.pipeline import output_level

from helpers import coloured_limbs, glb_json, limbs_surfels

trimesh = pytest.importorskip("trimesh")
plyfile = pytest.importorskip("plyfile")


@pytest.fixture(scope="module")
def coded(tmp_path_factory):
    """A sphere with limbs (1038 surfels, colour from position) coded at 8 bits/surfel, its
    stream written to a .sfz file."""
    s = coloured_limbs()
    data = encode(s, bits_per_surfel=8.0, options=CodecOptions(level_hints=True))
    path = tmp_path_factory.mktemp("out") / "limbs.sfz"
    path.write_bytes(data)
    return s, data, path


# ---------------------------------------------------------------------- default level
def test_default_output_level_is_within_0_2_db_of_the_best(coded):
    # the header's output-level hints, measured by the encoder on prefixes of the stream,
    # choose the level: at each rate never below the stream's own level, and within 0.5 dB of
    # the best (0.2 dB where the best level falls steadily with the rate; here levels 3 and 4
    # alternate between 2 and 3.5 b/s, and one step down cannot follow both)
    s, data, _ = coded
    header = unpack(data)[0]
    level = header.level
    assert header.version == 6 and len(header.level_hints) == 4
    ref = Reference(s)
    chosen = {}
    for bits in (None, 4.0, 3.0, 2.0):
        default = decode(data, bits_per_surfel=bits)
        chosen[bits] = output_level(data, bits_per_surfel=bits)
        assert output_levels(data, bits_per_surfel=bits) == [chosen[bits]]
        assert len(default) == vertex_count(chosen[bits])
        best = max(ref.psnr_d2(decode(data, bits_per_surfel=bits, level=lv))
                   for lv in range(level + 1))
        own = ref.psnr_d2(decode(data, bits_per_surfel=bits, level=level))
        assert ref.psnr_d2(default) >= max(best - 0.5, own - 0.05), bits
    # coarser at low rates, never finer for a shorter prefix
    assert chosen[None] == level and chosen[2.0] < level
    assert chosen[None] >= chosen[4.0] >= chosen[3.0] >= chosen[2.0]
    assert output_level(b"not a container") is None


def test_truncated_file_decodes_as_the_same_prefix_served(coded):
    s, data, _ = coded
    for bits in (1.6, 2.0, 3.0, 3.56):
        cut = truncate(data, max_file_bytes(bits, len(s)))
        served = decode(data, bits_per_surfel=bits)
        kept = decode(cut)
        assert output_level(cut) == output_level(data, bits_per_surfel=bits)
        assert np.array_equal(kept.positions, served.positions)
        assert np.array_equal(kept.colors, served.colors)


def test_complete_smooth_stream_decodes_at_its_own_level():
    # a ball: no finer level holds a significant coefficient, yet its own level is the best
    from conftest import icosphere_mesh

    v, f = icosphere_mesh(4)
    ball = TriangleMesh(v, f).to_surfels()
    data = encode(ball, bits_per_surfel=8.0, level=5)
    assert output_level(data) == 5
    assert len(decode(data)) == vertex_count(5)


def test_stream_without_hints_decodes_at_its_own_level(coded):
    from surfidx.codec.options import CodecOptions

    s, _, _ = coded
    data = encode(s, bits_per_surfel=8.0, options=CodecOptions(level_hints=False))
    header = unpack(data)[0]
    assert header.level_hints == () and header.version < 6
    for bits in (None, 2.0):
        assert output_level(data, bits_per_surfel=bits) == header.level
        assert len(decode(data, bits_per_surfel=bits)) == vertex_count(header.level)


# ---------------------------------------------------------------------- max_vertices
def test_max_vertices_meets_the_budget_within_a_db_of_the_full_level(coded):
    s, data, _ = coded
    n = len(s)
    full = decode(data, mesh=True)
    small = decode(data, mesh=True, max_vertices=n)
    assert len(small.vertices) <= n and small.vertex_colors is not None
    assert set(np.unique(small.faces)) == set(range(len(small.vertices)))   # all used
    # as surfaces (4 samples per input surfel on each) the two are within a decibel
    surface = {k: evaluate(s, m.to_surfels(samples=4 * n))
               for k, m in (("full", full), ("small", small))}
    assert surface["small"]["psnr_d2"] >= surface["full"]["psnr_d2"] - 1.0
    assert surface["small"]["psnr_y"] >= surface["full"]["psnr_y"] - 3.0   # colours follow
    # far above the grid level of about as many vertices (what a coarser level gives)
    coarse = max(lv for lv in range(unpack(data)[0].level + 1) if vertex_count(lv) <= 2 * n)
    ref = Reference(s)
    assert ref.psnr_d2(small.to_surfels(max_edge_ratio=None)) > \
        ref.psnr_d2(decode(data, level=coarse)) + 2.0
    # deterministic, surfels without faces, a budget above the output changes nothing
    again = decode(data, mesh=True, max_vertices=n)
    assert np.array_equal(again.vertices, small.vertices)
    assert np.array_equal(again.faces, small.faces)
    surfels = decode(data, max_vertices=300)
    assert len(surfels) <= 300 and surfels.faces is None and surfels.has_color
    assert np.allclose(np.linalg.norm(surfels.normals, axis=1), 1.0)
    assert len(decode(data, max_vertices=10 ** 7)) == len(decode(data))


@pytest.mark.parametrize("bad, match", [
    (3, "max_vertices must be at least 4"),
    (2.5, "max_vertices must be an integer of at least 4, got 2.5"),
    ("100", "max_vertices must be an integer of at least 4, got '100'"),
    (True, "max_vertices must be an integer of at least 4, got True"),
])
def test_max_vertices_refuses_bad_values(coded, bad, match):
    with pytest.raises(InputError, match=match):
        decode(coded[1], max_vertices=bad)
    with pytest.raises(InputError, match=match):
        check_max_vertices(bad)


def test_simplify_mesh_errors():
    with pytest.raises(InputError, match="simplify_mesh needs a TriangleMesh, got SurfelSet"):
        simplify_mesh(limbs_surfels(2), 100)
    tri = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], float)
    loose = TriangleMesh(np.vstack([tri + [3 * i, 0, 0] for i in range(20)]),
                         np.arange(60).reshape(20, 3))
    with pytest.raises(InputError, match="could not be simplified to 4 vertices"):
        simplify_mesh(loose, 4)
    assert simplify_mesh(loose, 60) is loose


# ---------------------------------------------------------------------- normals, faces
def test_mesh_exports_carry_unit_normals(coded, tmp_path):
    mesh = decode(coded[1], mesh=True, level=3)
    n = len(mesh.vertices)
    write_model(mesh, tmp_path / "m.glb")
    tree = glb_json(tmp_path / "m.glb")
    attrs = tree["meshes"][0]["primitives"][0]["attributes"]
    assert set(attrs) == {"POSITION", "NORMAL", "COLOR_0"}
    acc = tree["accessors"][attrs["NORMAL"]]
    assert (acc["type"], acc["componentType"], acc["count"]) == ("VEC3", 5126, n)   # float32
    geom = list(trimesh.load(tmp_path / "m.glb", process=False).geometry.values())[0]
    assert np.allclose(geom.vertex_normals, mesh.vertex_normals(), atol=1e-6)
    assert np.allclose(np.linalg.norm(geom.vertex_normals, axis=1), 1.0, atol=1e-6)
    # outward on the closed grid: normals point away from the centre almost everywhere
    out = np.einsum("ij,ij->i", mesh.vertex_normals(), mesh.vertices - mesh.vertices.mean(0))
    assert (out > 0).mean() > 0.9

    write_model(mesh, tmp_path / "m.obj")
    lines = (tmp_path / "m.obj").read_text().splitlines()
    vn = [ln for ln in lines if ln.startswith("vn ")]
    assert len(vn) == n == sum(ln.startswith("v ") for ln in lines)
    assert np.allclose(np.linalg.norm([list(map(float, ln.split()[1:])) for ln in vn], axis=1),
                       1.0, atol=1e-5)
    first = next(ln for ln in lines if ln.startswith("f ")).split()[1:]
    assert all(c.split("//")[0] == c.split("//")[1] for c in first)   # f v//vn
    back = trimesh.load(tmp_path / "m.obj", process=False)
    assert len(back.faces) == len(mesh.faces)


def test_vertex_normals_are_unit_even_where_degenerate():
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [2, 0, 0], [5, 5, 5]], float)
    f = np.array([[0, 1, 2], [0, 1, 3]])             # a flat face and a collinear one
    nrm = TriangleMesh(v, f).vertex_normals()
    assert np.allclose(np.linalg.norm(nrm, axis=1), 1.0)
    assert np.allclose(nrm[4], [0, 0, 1])            # used by no face
    assert np.allclose(TriangleMesh(v, np.zeros((0, 3), int)).vertex_normals()[:, 2], 1.0)


def test_surfel_ply_has_no_face_element_mesh_ply_has(coded, tmp_path):
    write_model(decode(coded[1]), tmp_path / "s.ply")
    assert [e.name for e in plyfile.PlyData.read(tmp_path / "s.ply").elements] == ["vertex"]
    write_model(decode(coded[1], mesh=True, level=2), tmp_path / "m.ply")
    ply = plyfile.PlyData.read(tmp_path / "m.ply")
    assert [e.name for e in ply.elements] == ["vertex", "face"] and ply["face"].count == 320


# ---------------------------------------------------------------------- command line
def test_cli_decode_max_vertices_and_default_level(coded, tmp_path):
    s, data, path = coded
    level = unpack(data)[0].level
    runner = CliRunner()
    r = runner.invoke(cli, ["decode", str(path), "-o", str(tmp_path / "d.glb"), "--json"])
    assert r.exit_code == 0, r.output
    out = json.loads(r.stdout)
    assert out["level"] == level and out["surfels"] == vertex_count(level)
    r = runner.invoke(cli, ["decode", str(path), "-o", str(tmp_path / "d.obj"),
                            "--max-vertices", "500", "--json"])
    assert r.exit_code == 0, r.output
    assert json.loads(r.stdout)["surfels"] <= 500
    r = runner.invoke(cli, ["decode", str(path), "-o", str(tmp_path / "d.ply"),
                            "--max-vertices", "500", "--bits-per-surfel", "4"])
    assert r.exit_code == 0, r.output
    assert plyfile.PlyData.read(tmp_path / "d.ply")["vertex"].count <= 500
    r = runner.invoke(cli, ["decode", str(path), "-o", str(tmp_path / "e.glb"),
                            "--max-vertices", "3"])
    assert r.exit_code == 1 and "max_vertices must be at least 4" in r.output
    assert not (tmp_path / "e.glb").exists()
    r = runner.invoke(cli, ["decode", str(path), "-o", str(tmp_path / "e.glb"),
                            "--max-vertices", "2.5"])
    assert r.exit_code == 2 and "'2.5' is not a valid integer" in r.output


def test_get_and_export_max_vertices(coded, tmp_path):
    from surfidx import Database

    s, _, _ = coded
    db_path = tmp_path / "o.db"
    with Database.open(db_path) as db:
        summary = db.ingest(s, workers=1)
        assert summary.stored == 1, summary.errors
        level = unpack(db.get_stream(1))[0].level
        assert len(db.get(1)) == vertex_count(level)
        out = db.export(1, tmp_path / "x.glb", max_vertices=400)
        assert out["surfels"] <= 400 and out["level"] == level
        with pytest.raises(InputError, match="max_vertices must be at least 4"):
            db.get(1, max_vertices=2)
    r = CliRunner().invoke(cli, ["get", "1", "--db", str(db_path), "-o",
                                 str(tmp_path / "g.obj"), "--max-vertices", "400", "--json"])
    assert r.exit_code == 0, r.output
    assert json.loads(r.stdout)["surfels"] <= 400
    r = CliRunner().invoke(cli, ["get", "1", "--db", str(db_path), "-o",
                                 str(tmp_path / "g.obj"), "--max-vertices", "1"])
    assert r.exit_code == 1 and "max_vertices must be at least 4" in r.output
