"""Resampling on the icosahedral grid: exact point location, linear precision, reconstruction."""

import numpy as np
import pytest

from surfidx import InputError, SurfelSet
from surfidx.icosphere import icosphere
from surfidx.parameterize import parameterize
from surfidx.resample import grid_to_mesh, grid_to_surfels, layer_names, locate, resample


def _random_sites(n=500, seed=1):
    p = np.random.default_rng(seed).normal(size=(n, 3))
    return p / np.linalg.norm(p, axis=1)[:, None]


def test_every_grid_vertex_is_located():
    sites = _random_sites()
    q = icosphere(5).vertices
    tri, idx, bary = locate(sites, q)
    assert idx.shape == (len(q),) and np.all(idx >= 0)
    assert bary.min() >= -1e-12
    np.testing.assert_allclose(bary.sum(axis=1), 1.0, atol=1e-14)
    # the located triangle contains the query: its chord-plane projection is the bary combination
    proj = np.einsum("qk,qkl->ql", bary, sites[tri[idx]])
    np.testing.assert_allclose(np.cross(proj, q), 0.0, atol=1e-12)
    assert np.all(np.einsum("ij,ij->i", proj, q) > 0)


def test_queries_at_sites_and_edges():
    sites = _random_sites(200)
    mids = sites[:50] + sites[50:100]
    q = np.vstack([sites, mids / np.linalg.norm(mids, axis=1)[:, None]])
    tri, idx, bary = locate(sites, q)
    assert bary.min() >= -1e-12
    # at a site, the weight of that site is 1
    w = np.array([bary[k][tri[idx[k]] == k].sum() for k in range(200)])
    np.testing.assert_allclose(w, 1.0, atol=1e-9)


def test_linear_function_reproduced(sphere_surfels):
    s = sphere_surfels
    g = np.array([0.3, -1.2, 2.0])
    vals = s.positions @ g + 0.7
    layers = SurfelSet(np.column_stack([vals, vals, vals]), s.normals, s.radii)
    grid = icosphere(4).vertices
    out = resample(layers, s.positions, 4)
    tri, idx, bary = locate(s.positions, grid)
    proj = np.einsum("qk,qkl->ql", bary, s.positions[tri[idx]])
    np.testing.assert_allclose(out[:, 0], proj @ g + 0.7, atol=1e-12)
    const = SurfelSet(np.ones((len(s), 3)) * 5, s.normals, s.radii)
    np.testing.assert_allclose(resample(const, s.positions, 3), 5.0, atol=1e-12)


def test_resample_and_reconstruct_sphere(sphere_surfels):
    m = parameterize(sphere_surfels, stress=False)
    vals = resample(sphere_surfels, m.points, 4)
    assert vals.shape == (10 * 4 ** 4 + 2, 6)
    assert layer_names(True) == ("x", "y", "z", "r", "g", "b")
    np.testing.assert_allclose(np.linalg.norm(vals[:, :3], axis=1), 1.0, atol=0.02)
    s = grid_to_surfels(vals, name="g")
    assert len(s) == len(vals) and s.has_color
    # normals point outward on the sphere
    assert np.all(np.einsum("ij,ij->i", s.normals, s.positions) > 0.9)
    assert np.all(s.radii > 0)
    mesh = grid_to_mesh(vals)
    assert mesh.topology().genus == 0 and mesh.signed_volume() != 0


def test_grid_value_errors():
    with pytest.raises(InputError, match="10·4\\^L \\+ 2 rows"):
        grid_to_surfels(np.zeros((13, 3)))
    with pytest.raises(InputError, match="3 \\(x, y, z\\) or 6"):
        grid_to_mesh(np.zeros((12, 4)))


def test_resample_checks_points(sphere_surfels):
    with pytest.raises(InputError, match="shape"):
        resample(sphere_surfels, np.zeros((3, 3)), 2)


def test_degenerate_triangle_never_contains_a_query():
    """Sites on one great circle (a zero-volume triangle) are skipped by the walk, not divided by."""
    from surfidx.resample import _bary

    a, b = np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0])
    mid = (a + b) / np.sqrt(2.0)
    assert _bary(np.array([0.0, 0.0, 1.0]), a, mid, b)[3] <= 0
    assert _bary(np.array([0.0, 0.0, 1.0]), a, a, b)[3] <= 0


def test_locate_grid_equals_locate():
    """The coarse-to-fine walk finds the same triangles as the KD-tree-started one."""
    from surfidx.icosphere import icosphere
    from surfidx.resample import locate_grid

    rng = np.random.default_rng(3)
    p = rng.normal(size=(3000, 3))
    p /= np.linalg.norm(p, axis=1)[:, None]
    g = icosphere(5)
    tri, idx, bary = locate(p, g.vertices)
    tri2, idx2, bary2 = locate_grid(p, g, triangles=tri)
    np.testing.assert_array_equal(idx, idx2)
    np.testing.assert_allclose(bary, bary2, atol=1e-12)
