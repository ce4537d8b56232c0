"""Readers and writer: real files, round trips, and damaged input."""

import warnings

import numpy as np
import pytest
from plyfile import PlyData

from surfidx import FileFormatError, InputError, SurfelSet, TriangleMesh, read_mesh, read_surfels, write_ply
from surfidx.geometry.mesh import MAX_EDGE_RATIO, sample_texture

from helpers import off_sphere, write_bomb_png, write_png


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
    from surfidx.geometry.metrics import psnr_d2

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
    # no mtllib: the image beside it is paired, with a warning naming it, as an ingest pairs it
    with pytest.warns(UserWarning, match=r"spot_triangulated.obj: texture coordinates but no "
                                         r"texture named by its MTL; using spot_texture.png"):
        paired = read_surfels(models / "spot" / "spot_triangulated.obj")
    spot = read_surfels(models / "spot" / "spot_triangulated.obj",
                        texture=models / "spot" / "spot_texture.png")
    assert spot.has_color and spot.colors.std() > 10
    np.testing.assert_array_equal(paired.colors, spot.colors)


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


@pytest.mark.parametrize("quads", [False, True])
def test_binary_ply_faces_read_alike_as_triangles_or_as_lists(tmp_path, quads):
    """All-triangle faces take plyfile's one-array path, a file with a quad its row-by-row
    one: both give the mesh's triangles in the file's order."""
    from plyfile import PlyElement

    from conftest import icosphere_mesh

    v, f = icosphere_mesh(2)
    rows = [list(t) for t in f]
    tris = np.asarray(f, dtype=np.int64)
    if quads:       # a quad in place of the first two triangles, read as its fan 0-1-2, 0-2-3
        rows = [[0, 1, 2, 3]] + rows[2:]
        tris = np.concatenate([[[0, 1, 2], [0, 2, 3]], tris[2:]])
    vert = np.array([tuple(x) for x in v], dtype=[("x", "f4"), ("y", "f4"), ("z", "f4")])
    face = np.empty(len(rows), dtype=[("vertex_indices", "i4", (len(rows[0]),))]) \
        if not quads else np.array([(r,) for r in rows], dtype=[("vertex_indices", "O")])
    if not quads:
        face["vertex_indices"] = rows
    path = tmp_path / "m.ply"
    PlyData([PlyElement.describe(vert, "vertex"), PlyElement.describe(face, "face")]).write(
        str(path))
    mesh = read_mesh(path)
    np.testing.assert_array_equal(mesh.faces, tris)


def test_point_cloud_mixed_orientation_is_made_consistent():
    from surfidx import points_to_surfels
    from surfidx.geometry.pointcloud import estimate_normals, orient_normals

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
    ("model.3ds", "solid x\n", "unknown format .3ds"),
    ("model.stl", "solid x\n", "holds no triangles and no points"),
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


# ---------------------------------------------------------------------- hostile input (issue 28)
def _icosphere_obj(extra=""):
    from conftest import icosphere_mesh

    v, f = icosphere_mesh(3)
    return ("".join(f"v {a} {b} {c}\n" for a, b, c in v)
            + "".join(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in f) + extra)


def test_faces_with_a_repeated_corner_are_dropped_before_bisection(tmp_path):
    """Issue 28: these two faces made the bisection loop forever."""
    p = _write(tmp_path, "degen.obj", _icosphere_obj("f 1 1 2\nf 5 5 9\n"))
    with pytest.warns(UserWarning, match="2 degenerate faces .* of 1282 were dropped"):
        s = read_surfels(p)
    assert len(s) == 642 and len(s.faces) == 1280
    topo = TriangleMesh(s.positions, s.faces).topology()
    assert topo.closed and topo.genus == 0


def test_zero_area_and_collinear_faces_are_dropped():
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [0.5, 0, 0], [1, 0, 0]], float)
    f = np.array([[0, 1, 2], [0, 2, 3], [0, 3, 1], [1, 3, 2], [0, 1, 4], [1, 5, 2]])
    mesh = TriangleMesh(v, f)
    np.testing.assert_array_equal(mesh.nondegenerate_faces(), [1, 1, 1, 1, 0, 0])
    with pytest.warns(UserWarning, match="2 vertices referenced by no face"), \
            pytest.warns(UserWarning, match="2 degenerate faces"):
        s = mesh.to_surfels(max_edge_ratio=None)
    assert len(s.faces) == 4


def test_bisection_refuses_repeated_corners():
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], float)
    with pytest.raises(InputError, match="three distinct corners"):
        TriangleMesh(v, [[0, 1, 2], [0, 0, 1]]).bisected(0.1)


def test_mesh_with_only_degenerate_faces_is_refused(tmp_path):
    p = _write(tmp_path, "line.obj", "v 0 0 0\nv 1 0 0\nv 2 0 0\nv 3 0 0\nf 1 2 3\nf 2 3 4\n")
    with pytest.raises(InputError, match="line.obj: the mesh has zero surface area"):
        read_surfels(p)


def test_collinear_and_coincident_points_are_refused(tmp_path):
    head = "ply\nformat ascii 1.0\nelement vertex 50\nproperty float x\nproperty float y\n" \
           "property float z\nend_header\n"
    p = _write(tmp_path, "line.ply", head + "".join(f"{0.1 * i} {0.2 * i} {0.3 * i}\n"
                                                     for i in range(50)))
    with pytest.raises(InputError, match="line.ply: the 50 points are collinear"):
        read_surfels(p)
    p = _write(tmp_path, "dot.ply", head + "1.5 2 3\n" * 50)
    with pytest.raises(InputError, match="dot.ply: all 50 points coincide"):
        read_surfels(p)


def test_coordinates_beyond_the_limit_are_refused(tmp_path):
    p = _write(tmp_path, "huge.obj", "v 0 0 1e31\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 2 3\nf 1 3 4\n")
    with pytest.raises(InputError, match=r"huge.obj: 1 vertices have coordinates beyond ±1e\+30"):
        read_surfels(p)


def test_obj_face_index_overflow(tmp_path):
    p = _write(tmp_path, "big.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 99999999999999999999999\n")
    with pytest.raises(FileFormatError, match="big.obj: malformed face line"):
        read_mesh(p)


def test_ply_counts_beyond_the_file_are_refused(tmp_path):
    p = _write(tmp_path, "lie.ply", "ply\nformat binary_little_endian 1.0\nelement vertex "
               "1000000000000\nproperty float x\nproperty float y\nproperty float z\n"
               "end_header\n" + "\0" * 24)
    with pytest.raises(FileFormatError, match="lie.ply: not a readable PLY file .*announces "
                                              "1,000,000,000,000 'vertex' elements"):
        read_surfels(p)


def _tex_obj(tmp_path, mtl_line, name="m.obj"):
    """A textured level-3 icosphere OBJ whose MTL holds ``mtl_line``."""
    from conftest import icosphere_mesh

    v, f = icosphere_mesh(3)
    text = (f"mtllib {name}.mtl\n" + "".join(f"v {a} {b} {c}\n" for a, b, c in v)
            + "".join(f"vt {0.5 + 0.4 * a} {0.5 + 0.4 * b}\n" for a, b, c in v)
            + "".join(f"f {a + 1}/{a + 1} {b + 1}/{b + 1} {c + 1}/{c + 1}\n" for a, b, c in f))
    (tmp_path / f"{name}.mtl").write_text("newmtl m\n" + mtl_line + "\n")
    return _write(tmp_path, name, text)


def test_texture_bomb_is_a_clean_error(tmp_path):
    write_bomb_png(tmp_path / "bomb.png")
    p = _tex_obj(tmp_path, "map_Kd bomb.png")
    with pytest.raises(FileFormatError, match=r"bomb.png: texture image exceeds the limit of "
                       r"134,217,728 pixels \(it declares 2,500,000,000\) \(map_Kd in .*m.obj.mtl,"
                       r" used by .*m.obj\)"):
        read_surfels(p)


def test_texture_over_the_limit_and_damaged(tmp_path, monkeypatch):
    import surfidx.io.limits as limits

    write_png(tmp_path / "t.png", (8, 4))
    p = _tex_obj(tmp_path, "map_Kd t.png")
    assert read_surfels(p).has_color
    monkeypatch.setattr(limits, "MAX_TEXTURE_PIXELS", 31)
    with pytest.raises(FileFormatError, match="t.png: texture image of 8 × 4 pixels exceeds the "
                                              "limit of 31 pixels"):
        read_surfels(p)
    monkeypatch.undo()
    (tmp_path / "t.png").write_bytes((tmp_path / "t.png").read_bytes()[:40])
    with pytest.raises(FileFormatError, match=r"t.png: cannot read the texture image .*\(map_Kd"):
        read_surfels(p)
    (tmp_path / "t.png").unlink()
    with pytest.raises(FileFormatError, match=r"t.png: texture image not found \(map_Kd"):
        read_surfels(p)


def test_textures_outside_the_model_folder_need_the_option(tmp_path):
    inner = tmp_path / "model"
    inner.mkdir()
    write_png(tmp_path / "secret.png")
    for ref in ("../secret.png", str(tmp_path / "secret.png")):
        p = _tex_obj(inner, f"map_Kd {ref}")
        with pytest.warns(UserWarning, match=r"texture .*secret.png \(map_Kd in m.obj.mtl\) lies "
                                             "outside the model's folder; skipped"):
            s = read_surfels(p)
        assert not s.has_color
        s = read_surfels(p, allow_outside_textures=True)
        assert s.has_color and np.all(s.colors == (200, 30, 30))
    # a symlink inside the folder to an image outside is outside too
    (inner / "link.png").symlink_to(tmp_path / "secret.png")
    p = _tex_obj(inner, "map_Kd link.png")
    with pytest.warns(UserWarning, match="outside the model's folder"):
        assert not read_surfels(p).has_color
    write_png(inner / "inside.png")
    assert read_surfels(_tex_obj(inner, "map_Kd ./inside.png")).has_color


@pytest.mark.parametrize("name, content", [
    ("m.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 2 3\nf 1 3 4\n"),
    ("m.off", "OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n"),
    ("m.ply", "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\n"
              "property float z\nend_header\n0 0 0\n"),
])
def test_unreadable_file_is_a_clean_error(tmp_path, monkeypatch, name, content):
    """We run as root, where permissions do not stop reading: fake the refusal at open."""
    import builtins

    import surfidx.io.limits
    import surfidx.io.ply

    p = _write(tmp_path, name, content)
    real_open = builtins.open

    def refusing_open(file, *args, **kwargs):
        if str(file) == str(p):
            raise PermissionError(13, "Permission denied", str(file))
        return real_open(file, *args, **kwargs)

    for module in (surfidx.io.limits, surfidx.io.ply):     # the modules that open files
        monkeypatch.setattr(module, "open", refusing_open, raising=False)
    with pytest.raises(FileFormatError, match=f"{name}: cannot read \\(Permission denied\\)"):
        read_surfels(p)


def test_fifo_is_not_opened(tmp_path):
    import os

    os.mkfifo(tmp_path / "pipe.obj")
    with pytest.raises(FileFormatError, match="pipe.obj: is not a regular file"):
        read_surfels(tmp_path / "pipe.obj")


@pytest.mark.parametrize("text, color", [
    (off_sphere("OFF {nv} {nf} 0"), False),                          # counts on the first line
    (off_sphere("# made by a tool\nOFF\n# counts\n{nv} {nf} 0  # comment"), False),
    (off_sphere("COFF {nv} {nf} 0", lambda p: " ".join(map(str, p)) + " 255 128 0"), True),
    (off_sphere("COFF\n{nv} {nf} 0", lambda p: " ".join(map(str, p)) + " 1 0.5 0 1"), True),
    (off_sphere("NOFF\n{nv} {nf} 0", lambda p: (" ".join(map(str, p)) + " ") * 2), False),
    (off_sphere("STOFF\n{nv} {nf} 0", lambda p: " ".join(map(str, p)) + " 0.1 0.2"), False),
    (off_sphere("4OFF\n{nv} {nf} 0", lambda p: " ".join(map(str, 2 * p)) + " 2"), False),
])
def test_off_variants(tmp_path, text, color):
    mesh = read_mesh(_write(tmp_path, "s.off", text))
    assert mesh.vertices.shape == (642, 3) and mesh.faces.shape == (1280, 3)
    np.testing.assert_allclose(np.linalg.norm(mesh.vertices, axis=1), 1.0, atol=1e-9)
    assert (mesh.vertex_colors is not None) == color
    if color:
        np.testing.assert_array_equal(mesh.vertex_colors[0], (255, 128, 0))
    assert mesh.topology().genus == 0


@pytest.mark.parametrize("content, match", [
    ("OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n1000000 0 1 2\n",
     "OFF face 0 declares 1,000,000 corners but its line holds 3 numbers"),
    ("OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n2 0 1\n", "OFF face 0 has 2 corners"),
    ("OFF\n-3 1 0\n0 0 0\n", "OFF header has negative counts"),
    ("OFF BINARY\n", "binary OFF is not supported"),
    ("nOFF\n3\n3 1 0\n", r"nOFF \(vertices of another dimension"),
    ("XOFF\n3 1 0\n", "not an OFF file"),
    ("COFF\n3 1 0\n0 0 0\n1 0 0 1 1 1\n0 1 0 1 1 1\n3 0 1 2\n", "OFF vertex line 1 has 3 numbers"),
    ("# only a comment\n", r"the file is empty \(only comments\)"),
    ("OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 99999999999999999999\n", "malformed OFF data"),
])
def test_off_errors(tmp_path, content, match):
    with pytest.raises(FileFormatError, match="bad.off: .*" + match):
        read_mesh(_write(tmp_path, "bad.off", content))


def test_write_atomic_never_follows_a_symlink_at_a_temporary_name(tmp_path, sphere_surfels):
    import os
    import stat

    from surfidx.io import write_atomic

    victim = _write(tmp_path, "victim.txt", "precious")
    out = tmp_path / "out.ply"
    (tmp_path / "out.ply.part").symlink_to(victim)  # the old, predictable temporary name
    write_ply(sphere_surfels, out)
    assert victim.read_text() == "precious" and len(read_surfels(out)) == 642
    mask = os.umask(0o027)
    try:
        write_atomic(tmp_path / "perm.bin", lambda tmp: tmp.write_bytes(b"x"))
    finally:
        os.umask(mask)
    assert stat.S_IMODE((tmp_path / "perm.bin").stat().st_mode) == 0o640
    before = set(tmp_path.iterdir())

    def failing(tmp):
        tmp.write_bytes(b"half")
        raise OSError(28, "No space left on device")

    with pytest.raises(FileFormatError, match="x.bin: cannot write the model .No space left"):
        write_atomic(tmp_path / "x.bin", failing, what="the model")
    assert set(tmp_path.iterdir()) == before  # the temporary file is gone
    with pytest.raises(FileFormatError, match="no-such-dir/y.bin: cannot write"):
        write_atomic(tmp_path / "no-such-dir" / "y.bin", lambda tmp: None)


def _strips(*rows):
    data = np.empty(len(rows), dtype=[("vertex_indices", object)])
    for k, row in enumerate(rows):
        data[k] = (np.array(row, np.int64),)
    return data


def test_tristrips_alternate_winding_and_drop_degenerate_triangles():
    from surfidx.io.ply import faces_from_strips

    faces = faces_from_strips(_strips([0, 1, 2, 3, -1, 4, 5, 6, 6, 7, 8], [9]), "s.ply")
    # strip 1: (0 1 2), odd (1 2 3) -> (2 1 3); strip 2: (4 5 6), then degenerate windows
    # (5 6 6) (6 6 7) dropped, (6 7 8) is the 4th window (odd) -> (7 6 8), then (7 8 9)
    # even, the strip going on across the list rows
    np.testing.assert_array_equal(faces, [[0, 1, 2], [2, 1, 3], [4, 5, 6], [7, 6, 8],
                                          [7, 8, 9]])


def test_tristrips_without_a_triangle_are_refused():
    from surfidx.io.ply import faces_from_strips

    with pytest.raises(FileFormatError, match="tristrips hold no triangle"):
        faces_from_strips(_strips([0, 1, -1, 2, 3, -1]), "s.ply")
