"""trimesh interoperability: every surfel set and mesh converts with ``to_trimesh()``, and a
trimesh object read in (``as_surfels``, ``read_geometry``) and converted back keeps its
vertices, faces, colours, texture coordinates and texture exactly."""

from __future__ import annotations

import numpy as np
import pytest

from surfidx import Icosphere, RepairOptions, SurfelSet, TriangleMesh
from surfidx.io import as_surfels, read_geometry, read_surfels
from surfidx.topology import close_surface, read_model, split_parts

from conftest import icosphere_mesh
from helpers import sphere_with_holes, tetrahedron

trimesh = pytest.importorskip("trimesh")
Image = pytest.importorskip("PIL.Image")


def _coloured_sphere(level=2):
    v, f = icosphere_mesh(level)
    col = np.full((len(v), 4), 255, np.uint8)
    col[:, :3] = np.random.default_rng(0).integers(0, 256, (len(v), 3))
    return trimesh.Trimesh(v, f, vertex_colors=col, process=False, metadata={"name": "ball"})


def _textured_soup(level=2):
    """A textured sphere with a vertex per face corner (every edge a UV seam), as glTF
    exporters write a mesh whose texture coordinates differ per face."""
    v, f = icosphere_mesh(level)
    uv = np.c_[np.arctan2(v[:, 1], v[:, 0]) / (2 * np.pi) + 0.5, v[:, 2] * 0.5 + 0.5]
    image = Image.fromarray(np.random.default_rng(1).integers(0, 256, (8, 16, 3), np.uint8))
    material = trimesh.visual.material.PBRMaterial(baseColorTexture=image)
    corners = v[f].reshape(-1, 3)
    return trimesh.Trimesh(corners, np.arange(len(corners)).reshape(-1, 3),
                           visual=trimesh.visual.TextureVisuals(uv=uv[f].reshape(-1, 2),
                                                                material=material),
                           process=False)


def _exports(obj):
    """The trimesh object writes as GLB and PLY (its attributes included)."""
    for fmt in ("glb", "ply"):
        assert len(obj.export(file_type=fmt)) > 0, fmt


def test_trimesh_with_vertex_colours_round_trips_exactly():
    t = _coloured_sphere()
    mesh = read_geometry(t)
    assert isinstance(mesh, TriangleMesh) and mesh.name == "ball"
    back = mesh.to_trimesh()
    assert isinstance(back, trimesh.Trimesh)
    assert np.array_equal(back.vertices, t.vertices) and np.array_equal(back.faces, t.faces)
    assert np.array_equal(back.visual.vertex_colors, t.visual.vertex_colors)
    assert back.metadata["name"] == "ball"
    # the normals are the surfels' (outward on this closed mesh)
    s = mesh.to_surfels()
    assert np.allclose(back.vertex_normals, s.normals)
    assert np.all(np.einsum("ij,ij->i", back.vertex_normals, back.vertices) > 0)
    _exports(back)
    # and the surfels of the same trimesh: a point cloud in surfel (vertex) order
    cloud = as_surfels(t).to_trimesh()
    assert isinstance(cloud, trimesh.PointCloud)
    assert np.array_equal(cloud.vertices, t.vertices)
    assert np.array_equal(cloud.colors, t.visual.vertex_colors)


def test_textured_trimesh_round_trips_exactly():
    t = _textured_soup()
    mesh = read_geometry(t)
    assert len(mesh.vertices) == 162 and mesh.texture.shape == (8, 16, 3)   # merged by position
    back = mesh.to_trimesh()
    assert np.array_equal(back.vertices, t.vertices) and np.array_equal(back.faces, t.faces)
    assert np.array_equal(back.visual.uv, t.visual.uv)
    assert np.array_equal(np.asarray(back.visual.material.baseColorTexture.convert("RGB")),
                          np.asarray(t.visual.material.baseColorTexture))
    _exports(back)
    again = read_geometry(back)                      # and in again: the same mesh
    for key in ("vertices", "faces", "uv", "uv_faces", "texture"):
        assert np.array_equal(getattr(again, key), getattr(mesh, key)), key
    s = read_surfels(back)
    assert len(s) == 162 and s.has_color


def test_texture_coordinates_shared_between_vertices_split_per_pair():
    # two triangles whose texture coordinate 0 is used by vertices 0 and 3: not one per vertex
    v = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]])
    f = np.array([[0, 1, 2], [1, 3, 2]])
    uv = np.array([[0.0, 0], [1, 0], [0, 1], [0.5, 0.5]])
    uv_faces = np.array([[0, 1, 2], [3, 0, 2]])
    col = np.array([[10, 20, 30], [40, 50, 60], [70, 80, 90], [1, 2, 3]], np.uint8)
    mesh = TriangleMesh(v, f, uv=uv, uv_faces=uv_faces, vertex_colors=col,
                        texture=np.full((4, 4, 3), 200, np.uint8), name="quad")
    back = mesh.to_trimesh()
    assert len(back.vertices) == 5                   # pairs in order of first use
    assert np.array_equal(back.vertices[back.faces], v[f])
    assert np.array_equal(back.visual.uv[back.faces], uv[uv_faces])
    # a mesh with a texture and vertex colours keeps the colours as a vertex attribute
    assert np.array_equal(back.vertex_attributes["color"][back.faces][..., :3], col[f])
    _exports(back)


def test_mesh_without_colour_and_with_patches():
    v, f = sphere_with_holes([0, 40])
    closed = close_surface(v, f)
    t = closed.to_trimesh()
    assert np.array_equal(t.vertices, closed.vertices) and np.array_equal(t.faces, closed.faces)
    assert np.array_equal(t.face_attributes["patch"], closed.patch)
    assert set(np.unique(t.face_attributes["patch"])) == {-1, 0, 1}
    assert len(t.metadata["patch_cut"]) == 2
    _exports(t)
    plain = TriangleMesh(v, f).to_trimesh()
    assert np.array_equal(plain.vertices, v) and plain.visual.kind is None
    assert "patch" not in plain.face_attributes


def test_surfels_to_point_cloud_keep_their_arrays_in_metadata():
    v, f = sphere_with_holes([0])
    model = read_model((v, f), name="holed")
    s = model.surfels
    cloud = s.to_trimesh()
    assert np.array_equal(cloud.vertices, s.positions) and len(cloud.colors) == 0
    meta = cloud.metadata
    assert meta["name"] == "holed"
    for key in ("normals", "radii", "faces", "patch", "patch_cut"):
        assert np.array_equal(meta[key], getattr(s, key)), key
        assert meta[key] is not getattr(s, key)      # copies: the surfels stay as they are
    assert meta["patch"].dtype == np.int32 and np.any(meta["patch"] >= 0)
    _exports(cloud)
    m = model.to_trimesh()
    assert np.array_equal(m.vertices, s.positions) and m.metadata["name"] == "holed"
    # without colour, as_surfels reads no colour back; positions and order are kept
    again = as_surfels(cloud)
    assert not again.has_color and np.array_equal(again.positions, s.positions)
    assert again.name == "holed"


def test_point_cloud_round_trips_positions_and_colours():
    v, _ = icosphere_mesh(2)
    col = np.full((len(v), 4), 255, np.uint8)
    col[:, :3] = np.random.default_rng(2).integers(0, 256, (len(v), 3))
    pc = trimesh.PointCloud(v, colors=col, metadata={"name": "dots"})
    s = as_surfels(pc)
    back = s.to_trimesh()
    assert np.array_equal(back.vertices, pc.vertices) and np.array_equal(back.colors, col)
    assert back.metadata["name"] == "dots" and "faces" not in back.metadata
    bare = SurfelSet(s.positions, s.normals, s.radii)
    assert len(bare.to_trimesh().colors) == 0


def test_parts_and_grid_convert():
    a, fa = tetrahedron()
    b, fb = tetrahedron(offset=(5, 0, 0))
    v, f = np.vstack([a, b]), np.vstack([fa, fb + len(a)])
    part = split_parts(v, f, options=RepairOptions(min_part_vertices=1)).parts[1]
    t = part.to_trimesh()
    assert np.array_equal(t.vertices, part.vertices) and np.array_equal(t.faces, part.faces)
    assert np.array_equal(t.vertex_attributes["vertex_index"], part.vertex_index)
    assert np.array_equal(t.face_attributes["face_index"], part.face_index)
    _exports(t)
    grid = Icosphere(2).to_trimesh()
    assert len(grid.vertices) == 162 and len(grid.faces) == 320 and grid.is_watertight
    assert np.allclose(np.linalg.norm(grid.vertices, axis=1), 1.0)
    assert np.array_equal(grid.vertex_attributes["level"][:12], np.zeros(12))
    assert grid.volume > 0                           # counter-clockwise seen from outside
