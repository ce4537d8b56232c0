"""Readers and writer: real files, round trips, and damaged input."""

import warnings

import numpy as np
import pytest
from plyfile import PlyData

from surfidx import FileFormatError, InputError, SurfelSet, TriangleMesh, read_mesh, read_surfels, write_ply
from surfidx.mesh import MAX_EDGE_RATIO, sample_texture


def test_igea_tristrips_give_outward_surfels(models):
    s = read_surfels(models / "igea.ply")
    assert len(s) == 134345
    assert np.all(s.radii > 0)
    np.testing.assert_allclose(np.linalg.norm(s.normals, axis=1), 1.0, atol=1e-9)
    # Igea is nearly star-shaped about its centroid: normals point away from it.
    outward = np.einsum("ij,ij->i", s.positions - s.positions.mean(0), s.normals) > 0
    assert outward.mean() > 0.99
    topo = TriangleMesh(s.positions, s.faces).topology()
    assert (topo.faces, topo.closed, topo.genus) == (268686, True, 0)


@pytest.mark.parametrize("name, genus, closed", [
    ("bunny_hr.obj", 0, True), ("rocker-arm.obj", 1, True),
    ("ycb_scissors/textured_simple_reoriented.obj", 3, True), ("cow.obj", None, True),
    ("stanford-bunny.obj", None, False), ("frag_115.ply", None, False),
])
def test_topology_matches_data_readme(models, name, genus, closed):
    topo = read_mesh(models / name).topology()
    assert topo.genus == genus and topo.closed == closed


def test_cow_pinched_vertex_detected(models):
    assert read_mesh(models / "cow.obj").topology().nonmanifold_vertices == 1


def test_unused_vertices_dropped_with_warning(models):
    with pytest.warns(UserWarning, match="1113 vertices referenced by no face were dropped"):
        s = read_surfels(models / "stanford-bunny.obj")
    assert len(s) == 35947 - 1113


def test_order_follows_the_input(models):
    """The mesh's vertices come first, in file order; bisection's new vertices follow."""
    m = read_mesh(models / "homer.obj")
    s = read_surfels(models / "homer.obj")
    np.testing.assert_array_equal(s.positions[:len(m.vertices)], m.vertices)
    assert len(s) == len(m.bisected(MAX_EDGE_RATIO * m.median_edge_length()).vertices) > 6002
    flat = read_surfels(models / "homer.obj", max_edge_ratio=None)
    np.testing.assert_array_equal(flat.positions, m.vertices)


def test_bisection_is_conforming_and_keeps_the_surface(models):
    m = read_mesh(models / "falconstatue.obj")
    limit = MAX_EDGE_RATIO * m.median_edge_length()
    b = m.bisected(limit)
    v, f = b.vertices, b.faces
    np.testing.assert_array_equal(v[:len(m.vertices)], m.vertices)
    assert np.linalg.norm(v[f] - v[np.roll(f, -1, axis=1)], axis=2).max() <= limit
    t0, t1 = m.topology(), b.topology()
    assert t1.closed and t1.genus == 0 and t1.components == 1 and t1.nonmanifold_vertices == 0
    assert t1.vertices - t0.vertices == (t1.faces - t0.faces) // 2  # each new vertex: 2 faces
    # same area and volume: the new vertices lie on the old faces (off them, the area grows)
    assert b.face_areas().sum() == pytest.approx(m.face_areas().sum(), rel=1e-12)
    assert b.signed_volume() == pytest.approx(m.signed_volume(), rel=1e-12)  # winding kept
    assert m.bisected(100 * limit) is m  # no edge that long: the mesh itself


def test_bisection_makes_surfels_represent_large_faces(models):
    """The reason for bisection: on falconstatue's flat base the corner surfels are tilted by the
    sides; points of the true surface then lie far off their nearest surfel's plane (D2 of an
    exact surface sample against the surfels 47 dB per vertex, over 69 dB after bisection)."""
    from surfidx.metrics import psnr_d2

    m = read_mesh(models / "falconstatue.obj")
    exact = m.to_surfels(samples=200_000, seed=1)
    plain = m.to_surfels(max_edge_ratio=None)
    refined = m.to_surfels()
    assert len(plain) == 25839 and len(refined) < 1.05 * len(plain)
    assert psnr_d2(plain, exact) < 50 and psnr_d2(refined, exact) > 65


def test_bisection_interpolates_colours_and_texture_coordinates():
    v = np.array([[0.0, 0, 0], [8, 0, 0], [0, 1, 0], [0, 0, 1]])
    f = np.array([[0, 1, 2], [0, 3, 1], [1, 3, 2], [0, 2, 3]])
    col = np.array([[0, 0, 0], [200, 100, 50], [0, 0, 0], [0, 0, 0]], np.uint8)
    b = TriangleMesh(v, f, vertex_colors=col).bisected(2.0)
    assert np.linalg.norm(b.vertices[b.faces] - b.vertices[np.roll(b.faces, -1, 1)],
                          axis=2).max() <= 2.0
    on_edge = np.flatnonzero((b.vertices[:, 1] == 0) & (b.vertices[:, 2] == 0))
    x = b.vertices[on_edge, 0]
    np.testing.assert_allclose(b.vertex_colors[on_edge, 0], np.round(200 * x / 8), atol=1)
    uv = np.array([[0.0, 0], [1, 0], [0, 1], [0.5, 0.5]])
    t = TriangleMesh(v, f, uv=uv, uv_faces=f, texture=np.zeros((4, 4, 3), np.uint8)).bisected(2.0)
    assert len(t.uv_faces) == len(t.faces) and t.texture is not None
    # a texture coordinate of a new corner is the midpoint rule applied along its edge
    corner_uv = t.uv[t.uv_faces]
    corner_x = t.vertices[t.faces]
    on = (corner_x[..., 1] == 0) & (corner_x[..., 2] == 0)
    np.testing.assert_allclose(corner_uv[on][:, 0], corner_x[on][:, 0] / 8, atol=1e-12)


def test_bisection_errors():
    mesh = TriangleMesh(np.eye(3), [[0, 1, 2]])
    with pytest.raises(InputError, match="max_edge must be a positive length, got 0"):
        mesh.bisected(0.0)
    with pytest.raises(InputError, match="a few triangles are vastly larger than the rest"):
        mesh.bisected(1e-4)
    with pytest.raises(InputError, match="max_edge_ratio must be a positive number or None, got -1"):
        mesh.to_surfels(max_edge_ratio=-1)


def test_textured_obj_colours(models):
    banana = read_surfels(models / "ycb_banana" / "textured_simple_reoriented.obj")
    assert banana.has_color
    r, g, b = banana.colors.astype(float).mean(0)
    assert r > 120 and g > 100 and b < 0.5 * g  # yellow
    spot = read_surfels(models / "spot" / "spot_triangulated.obj")
    assert not spot.has_color  # no mtllib: the texture must be given
    spot = read_surfels(models / "spot" / "spot_triangulated.obj",
                        texture=models / "spot" / "spot_texture.png")
    assert spot.has_color and spot.colors.std() > 10


def test_uniform_sampling_keeps_texture_and_covers(models):
    s = read_surfels(models / "ycb_banana" / "textured_simple_reoriented.obj", samples=20000)
    assert len(s) == 20000 and s.has_color
    m = read_mesh(models / "ycb_banana" / "textured_simple_reoriented.obj")
    # samples lie on the surface: their distance to the nearest vertex is below the edge scale
    from scipy.spatial import cKDTree
    d, _ = cKDTree(m.vertices).query(s.positions)
    edge = np.linalg.norm(m.vertices[m.faces[:, 0]] - m.vertices[m.faces[:, 1]], axis=1)
    assert d.max() < edge.max()


def test_vertex_coloured_ply_with_faces(models):
    s = read_surfels(models / "frag_115.ply")
    assert len(s) == 64365 and s.has_color


def test_mesh_radii_cover_the_surface():
    from conftest import icosphere_mesh

    v, f = icosphere_mesh(2)
    rng = np.random.default_rng(1)
    v = v + rng.normal(scale=0.02, size=v.shape)  # irregular triangles, some obtuse
    s = TriangleMesh(v, f).to_surfels()
    # random points on every triangle are within some disk's radius
    b = rng.dirichlet([1, 1, 1], size=(len(f), 20))
    pts = np.einsum("fsk,fkd->fsd", b, v[f]).reshape(-1, 3)
    d = np.linalg.norm(pts[:, None, :] - s.positions[None], axis=2) / s.radii[None]
    assert d.min(axis=1).max() <= 1.0 + 1e-9


def test_inward_winding_is_flipped_outward():
    from conftest import icosphere_mesh

    v, f = icosphere_mesh(1)
    s = TriangleMesh(v, f[:, ::-1]).to_surfels()
    assert np.all(np.einsum("ij,ij->i", s.normals, v) > 0.9)


@pytest.mark.parametrize("text", [False, True])
def test_surfel_ply_round_trip(tmp_path, sphere_surfels, text):
    out = tmp_path / "s.ply"
    write_ply(sphere_surfels, out, text=text, extra={"sx": sphere_surfels.positions[:, 0]})
    ply = PlyData.read(str(out))
    names = ply["vertex"].data.dtype.names
    assert names[:10] == ("x", "y", "z", "nx", "ny", "nz", "radius", "red", "green", "blue")
    assert "sx" in names and ply["vertex"].data["sx"].dtype == np.float64
    back = read_surfels(out)
    assert len(back) == len(sphere_surfels)
    np.testing.assert_allclose(back.positions, sphere_surfels.positions, atol=1e-6)
    np.testing.assert_allclose(back.radii, sphere_surfels.radii, rtol=1e-6)
    np.testing.assert_array_equal(back.colors, sphere_surfels.colors)


def test_point_cloud_gets_outward_normals(tmp_path, sphere_surfels):
    from plyfile import PlyElement

    p = sphere_surfels.positions * 2.0
    data = np.array([tuple(x) for x in p], dtype=[("x", "f4"), ("y", "f4"), ("z", "f4")])
    path = tmp_path / "cloud.ply"
    PlyData([PlyElement.describe(data, "vertex")]).write(str(path))
    s = read_surfels(path)
    assert np.all(np.einsum("ij,ij->i", s.normals, p / 2.0) > 0.95)
    assert np.all(s.radii > 0)


def test_point_cloud_mixed_orientation_is_made_consistent():
    from surfidx import points_to_surfels
    from surfidx.pointcloud import estimate_normals, orient_normals

    from conftest import icosphere_mesh

    v, _ = icosphere_mesh(3)
    n = estimate_normals(v)
    n[::2] *= -1
    o = orient_normals(v, n)
    assert np.all(np.einsum("ij,ij->i", o, v) > 0.95)
    with pytest.raises(InputError, match="at least 4 points"):
        points_to_surfels(v[:3])


def _write(tmp_path, name, content):
    p = tmp_path / name
    p.write_bytes(content if isinstance(content, bytes) else content.encode())
    return p


@pytest.mark.parametrize("name, content, match", [
    ("empty.ply", b"", "the file is empty"),
    ("junk.ply", b"not a ply at all\n", "not a readable PLY"),
    ("noface.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\n", "OBJ has no faces"),
    ("novert.obj", "# nothing\n", "OBJ has no vertices"),
    ("badidx.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 9\n", "a face refers to a vertex that does not exist"),
    ("badnum.obj", "v 0 0 zz\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", "malformed vertex line"),
    ("short.off", "OFF\n4 4 0\n0 0 0\n1 0 0\n", "truncated"),
    ("header.off", "XYZ\n1 2\n", "not an OFF file"),
    ("model.stl", "solid x\n", "unknown format .stl"),
])
def test_damaged_files_raise_clear_errors(tmp_path, name, content, match):
    with pytest.raises(FileFormatError, match=match) as info:
        read_surfels(_write(tmp_path, name, content))
    assert name in str(info.value)


def test_truncated_binary_ply(tmp_path, models):
    data = (models / "horse.ply").read_bytes()
    p = _write(tmp_path, "cut.ply", data[: len(data) // 3])
    with pytest.raises(FileFormatError, match="cut.ply: not a readable PLY"):
        read_surfels(p)


def test_nan_coordinates_raise(tmp_path):
    p = _write(tmp_path, "nan.obj", "v 0 0 nan\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 2 3\nf 1 3 4\n")
    with pytest.raises(InputError, match="nan.obj: vertices contains 1 NaN"):
        read_surfels(p)


def test_missing_file_and_directory(tmp_path):
    with pytest.raises(FileFormatError, match="no such file"):
        read_surfels(tmp_path / "missing.ply")
    with pytest.raises(FileFormatError, match="is a directory"):
        read_surfels(tmp_path)


def test_texture_option_errors(tmp_path, models):
    with pytest.raises(InputError, match="--texture applies to OBJ files only"):
        read_surfels(models / "horse.ply", texture=tmp_path / "t.png")
    with pytest.raises(FileFormatError, match="texture image not found"):
        read_surfels(models / "spot" / "spot_triangulated.obj", texture=tmp_path / "t.png")
    bad = _write(tmp_path, "t.png", b"garbage")
    with pytest.raises(FileFormatError, match="cannot read the texture image"):
        read_surfels(models / "spot" / "spot_triangulated.obj", texture=bad)


def test_samples_need_a_mesh(tmp_path, sphere_surfels):
    out = tmp_path / "s.ply"
    write_ply(sphere_surfels.subset(np.arange(len(sphere_surfels))), out)  # no faces
    with pytest.raises(InputError, match="--samples needs a mesh"):
        read_surfels(out, samples=100)
    with pytest.raises(InputError, match="samples must be at least 4"):
        TriangleMesh(sphere_surfels.positions, sphere_surfels.faces).to_surfels(samples=2)


def test_mesh_errors():
    with pytest.raises(InputError, match="faces index vertices outside"):
        TriangleMesh(np.zeros((3, 3)), [[0, 1, 3]])
    with pytest.raises(InputError, match="zero surface area"):
        TriangleMesh(np.zeros((3, 3)), [[0, 1, 2]]).to_surfels()
    with pytest.raises(InputError, match="the mesh has no faces"):
        TriangleMesh(np.zeros((3, 3)), np.zeros((0, 3), int)).to_surfels()
    with pytest.raises(InputError, match="texture-coordinate indices out of range"):
        TriangleMesh(np.eye(3), [[0, 1, 2]], uv=np.zeros((2, 2)), uv_faces=[[0, 1, 2]])


def test_polygon_faces_are_triangulated(tmp_path):
    p = _write(tmp_path, "quad.off",
               "OFF\n8 6 0\n0 0 0\n1 0 0\n1 1 0\n0 1 0\n0 0 1\n1 0 1\n1 1 1\n0 1 1\n"
               "4 0 3 2 1\n4 4 5 6 7\n4 0 1 5 4\n4 1 2 6 5\n4 2 3 7 6\n4 3 0 4 7\n")
    m = read_mesh(p)
    assert len(m.faces) == 12 and m.topology().genus == 0
    s = read_surfels(p)
    assert np.all(np.einsum("ij,ij->i", s.normals, s.positions - 0.5) > 0)


def test_sample_texture_bilinear():
    tex = np.zeros((2, 2, 3), np.uint8)
    tex[0, :, 0] = 255  # top row red (v = 1)
    c = sample_texture(tex, np.array([[0.25, 0.75], [0.25, 0.25], [0.5, 0.5]]))
    np.testing.assert_allclose(c[:, 0], [255, 0, 127.5])


def test_surfel_ply_with_faces_keeps_its_radii(tmp_path, sphere_surfels):
    out = tmp_path / "s.ply"
    s = SurfelSet(sphere_surfels.positions, sphere_surfels.normals, sphere_surfels.radii * 3,
                  faces=sphere_surfels.faces)
    write_ply(s, out)
    back = read_surfels(out)
    np.testing.assert_allclose(back.radii, s.radii, rtol=1e-6)
    np.testing.assert_array_equal(back.faces, s.faces)
    assert len(read_surfels(out, samples=500)) == 500  # the faces still allow sampling
