"""The texture atlas of the icosahedral grid and the colour baked into it."""

from __future__ import annotations

import numpy as np
import pytest

from surfidx import InputError
from surfidx.geometry.atlas import (GridColor, atlas_uv_faces, bake_texture, default_texture_size,
                                    grid_atlas, grid_face_index, locate_on_grid)
from surfidx.geometry.icosphere import icosphere
from surfidx.geometry.mesh import sample_texture


def _pixel_triangles(atlas):
    """(m, 3, 2) pixel coordinates (x right, y down) of each grid face's chart triangle."""
    px = np.stack([atlas.uv[:, 0] * atlas.size, (1.0 - atlas.uv[:, 1]) * atlas.size], 1)
    return px[atlas.uv_faces]


def _signed_areas(tri):
    d1, d2 = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    return 0.5 * (d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0])


@pytest.mark.parametrize("level,size", [(0, 64), (2, 256), (4, 256), (5, 1024)])
def test_every_grid_face_has_a_chart_triangle_of_positive_area(level, size):
    atlas = grid_atlas(level, size=size)
    grid = icosphere(level)
    assert atlas.uv_faces.shape == grid.faces.shape
    np.testing.assert_array_equal(atlas.uv_vertex[atlas.uv_faces], grid.faces)
    area = _signed_areas(_pixel_triangles(atlas))
    # one orientation for all (a single winding in the image), never degenerate
    assert np.all(np.sign(area) == np.sign(area[0])) and np.abs(area).min() > 0
    assert np.all((atlas.uv >= 0) & (atlas.uv <= 1))


@pytest.mark.parametrize("level", [0, 3])
def test_charts_do_not_overlap_and_tile_their_base_triangles(level):
    atlas = grid_atlas(level, size=256)
    tri = _pixel_triangles(atlas)
    area = np.abs(_signed_areas(tri))
    chart = np.arange(len(tri)) // 4 ** level
    c = atlas.corners
    chart_area = np.abs(_signed_areas(c))
    np.testing.assert_allclose(np.bincount(chart, weights=area), chart_area, rtol=1e-12)
    # the charts' bounding triangles are disjoint: sample each chart's interior densely, every
    # sample falls in its own chart only
    rng = np.random.default_rng(0)
    r1, r2 = np.sqrt(rng.random(2000)), rng.random(2000)
    b = np.stack([1 - r1, r1 * (1 - r2), r1 * r2], 1)
    for k in range(20):
        pts = b @ c[k]
        for other in range(20):
            if other == k:
                continue
            a, bb, cc = c[other]
            m = np.stack([bb - a, cc - a], 1)
            st = np.linalg.solve(m, (pts - a).T).T
            inside = (st[:, 0] > 1e-9) & (st[:, 1] > 1e-9) & (st.sum(1) < 1 - 1e-9)
            assert not inside.any(), (k, other)


def test_seam_vertices_are_duplicated_consistently():
    level = 3
    atlas = grid_atlas(level, size=256)
    grid = icosphere(level)
    copies = np.bincount(atlas.uv_vertex, minlength=grid.n_vertices)
    # the 12 base corners sit in 5 charts, base-edge vertices in 2, inner ones in 1
    assert np.all(copies[:12] == 5)
    n = 2 ** level
    assert int((copies == 2).sum()) == 30 * (n - 1)
    assert int((copies == 1).sum()) == grid.n_vertices - 12 - 30 * (n - 1)
    # the copies of a vertex are distinct texture coordinates, each used by one chart's faces
    chart_of_uv = np.empty(len(atlas.uv), np.int64)
    chart_of_uv[atlas.uv_faces.ravel()] = np.repeat(np.arange(len(grid.faces)) // 4 ** level, 3)
    key = atlas.uv_vertex * 20 + chart_of_uv
    assert len(np.unique(key)) == len(key)


def test_bilinear_lookups_inside_a_chart_read_only_that_charts_texels():
    atlas = grid_atlas(4, size=256)
    owner = atlas.texel_charts()
    size = atlas.size
    rng = np.random.default_rng(1)
    r1, r2 = np.sqrt(rng.random(5000)), rng.random(5000)
    b = np.stack([1 - r1, r1 * (1 - r2), r1 * r2], 1)
    for k in range(20):
        pts = b @ atlas.corners[k]
        x0, y0 = np.floor(pts[:, 0] - 0.5).astype(int), np.floor(pts[:, 1] - 0.5).astype(int)
        for dx in (0, 1):
            for dy in (0, 1):
                x, y = np.clip(x0 + dx, 0, size - 1), np.clip(y0 + dy, 0, size - 1)
                assert np.all(owner[y, x] == k), k


def test_constant_colour_bakes_to_that_colour_everywhere_in_charts_and_gutters():
    atlas = grid_atlas(3, size=128)
    colours = np.tile([[200.0, 40.0, 7.0]], (icosphere(3).n_vertices, 1))
    img = bake_texture(atlas, GridColor(colours))
    used = atlas.texel_charts() >= 0
    assert np.all(img[used] == [200, 40, 7])
    assert np.all(img[~used] == 0)


def test_gradient_along_z_bakes_monotonic():
    level = 4
    grid = icosphere(level)
    z = grid.vertices[:, 2]
    colours = np.repeat(((z + 1) * 127.5)[:, None], 3, axis=1)
    atlas = grid_atlas(level, size=512)
    img = bake_texture(atlas, GridColor(colours))
    rows, verts, w = atlas.texel_points()
    p = np.einsum("ij,ijk->ik", w, grid.vertices[verts])
    p /= np.linalg.norm(p, axis=1, keepdims=True)
    order = np.argsort(p[:, 2], kind="stable")
    value = img.reshape(-1, 3)[rows[order], 0].astype(int)
    # monotonic up to the rounding to 8 bits and the chord between grid vertices
    assert np.all(np.diff(value) >= -2)
    assert value[0] <= 2 and value[-1] >= 253
    # and the image read back at the grid vertices' texture coordinates gives their colours
    got = sample_texture(img, atlas.uv)[:, 0]
    np.testing.assert_allclose(got, colours[atlas.uv_vertex, 0], atol=1.0)


@pytest.mark.parametrize("level", [0, 2, 5])
def test_locate_on_grid_recovers_points(level):
    grid = icosphere(level)
    pts = np.random.default_rng(2).normal(size=(3000, 3))
    pts /= np.linalg.norm(pts, axis=1, keepdims=True)
    face, w = locate_on_grid(pts, level)
    assert np.all(w >= 0) and np.allclose(w.sum(1), 1)
    q = np.einsum("ij,ijk->ik", w, grid.vertices[grid.faces[face]])
    np.testing.assert_allclose(q / np.linalg.norm(q, axis=1, keepdims=True), pts, atol=1e-12)
    # a grid vertex's own colour comes back at the vertex
    col = GridColor(np.repeat(np.arange(grid.n_vertices, dtype=float)[:, None], 3, 1))
    np.testing.assert_allclose(col(grid.vertices)[:, 0], np.arange(grid.n_vertices), atol=1e-6)


def test_grid_face_index_finds_faces_in_any_rotation():
    grid = icosphere(2)
    f = np.asarray(grid.faces)
    idx = grid_face_index(2, np.vstack([f[[5, 9]], f[[7]][:, [1, 2, 0]], [[0, 1, 2]]]))
    assert idx.tolist() == [5, 9, 7, -1]


def test_uv_faces_of_known_grid_faces_are_those_found():
    """Grid faces given (rotated or not, some left -1) give the coordinates a search gives,
    as do the grid's own faces in order; a triangle that is no grid face takes its first
    corner's coordinate."""
    atlas = grid_atlas(2, size=128)
    f = np.asarray(icosphere(2).faces)
    tri = np.vstack([f[[5, 9]], f[[7]][:, [1, 2, 0]], [[0, 1, 2]], f[[3]]])
    want = atlas_uv_faces(atlas, tri)
    np.testing.assert_array_equal(atlas_uv_faces(atlas, tri, grid_faces=[5, 9, 7, -1, -1]), want)
    np.testing.assert_array_equal(atlas_uv_faces(atlas, tri, grid_faces=[-1] * 5), want)
    assert len(set(want[3].tolist())) == 1
    np.testing.assert_array_equal(atlas_uv_faces(atlas, f), atlas.uv_faces)
    np.testing.assert_array_equal(atlas_uv_faces(atlas, f[:, [2, 0, 1]])[:, [1, 2, 0]],
                                  atlas.uv_faces)


@pytest.mark.parametrize("grid_faces", [[0, 1], [0, 1, 2, 3, 320], [-2, 0, 0, 0, 0]])
def test_bad_grid_faces_are_refused(grid_faces):
    f = np.asarray(icosphere(2).faces)[:5]
    with pytest.raises(InputError, match="grid_faces"):
        atlas_uv_faces(grid_atlas(2, size=128), f, grid_faces=grid_faces)


def test_default_size_grows_with_the_level():
    sizes = [default_texture_size(lv) for lv in range(10)]
    assert sizes == sorted(sizes) and sizes[0] == 256 and sizes[-1] == 4096


@pytest.mark.parametrize("size", [32, 10000, 256.0, True, "512"])
def test_bad_texture_size_is_refused(size):
    with pytest.raises(InputError, match="texture_size must be an integer from 64 to 8192"):
        grid_atlas(2, size=size)


def test_bad_colour_source_is_refused():
    with pytest.raises(InputError, match="colour source must return"):
        bake_texture(grid_atlas(1, size=64), lambda p: np.zeros((len(p), 2)))
    with pytest.raises(InputError, match="colors must have 10"):
        GridColor(np.zeros((13, 3)))


@pytest.mark.parametrize("atlas_level, color_level", [(1, 1), (2, 4), (3, 3), (4, 5)])
def test_bake_started_at_texel_faces_equals_full_descent(atlas_level, color_level):
    atlas = grid_atlas(atlas_level, size=128)
    rows, faces, verts, w = atlas.texel_faces()
    grid = icosphere(atlas_level)
    # each texel's face has the texel's triangle as its corners
    np.testing.assert_array_equal(np.sort(np.asarray(grid.faces)[faces], 1), np.sort(verts, 1))
    colours = np.random.default_rng(5).uniform(0, 255, (icosphere(color_level).n_vertices, 3))
    source = GridColor(colours)
    img = bake_texture(atlas, source)
    p = np.einsum("ij,ijk->ik", w, grid.vertices[verts])
    p /= np.linalg.norm(p, axis=1, keepdims=True)
    full = np.clip(np.round(source(p)), 0, 255).astype(np.uint8)   # descent from the base
    np.testing.assert_array_equal(img.reshape(-1, 3)[rows], full)
    # a point on an edge may land in either face; both give the same point and colour
    fine = icosphere(color_level)
    f1, w1 = locate_on_grid(p, color_level, within=faces, within_level=atlas_level)
    assert np.all(w1 >= 0) and np.allclose(w1.sum(1), 1)
    q = np.einsum("ij,ijk->ik", w1, fine.vertices[fine.faces[f1]])
    np.testing.assert_allclose(q / np.linalg.norm(q, axis=1, keepdims=True), p, atol=1e-12)
    np.testing.assert_allclose(source(p, within=faces, within_level=atlas_level), source(p),
                               atol=1e-9)


def test_bad_start_faces_are_refused():
    pts = icosphere(2).vertices
    with pytest.raises(InputError, match="within_level must be an integer from 1 to level=2"):
        locate_on_grid(pts, 2, within=np.zeros(len(pts), np.int64), within_level=3)
    with pytest.raises(InputError, match="within must hold faces of the level-1 grid"):
        locate_on_grid(pts, 2, within=np.full(len(pts), 80), within_level=1)
    with pytest.raises(InputError, match="within"):
        locate_on_grid(pts, 2, within=np.zeros(3, np.int64), within_level=1)
