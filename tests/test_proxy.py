"""Proxy meshes for point clouds: closed genus-0 reconstruction, closest points, transfer."""

from __future__ import annotations

import numpy as np
import pytest

from surfidx import SurfelSet, TriangleMesh
from surfidx.errors import InputError, TopologyError
from surfidx.sphere.proxy import MIN_POINTS, closest_points, proxy_mesh, transfer


def _ellipsoid(n, axes=(1.0, 1.0, 1.0), seed=0):
    rng = np.random.default_rng(seed)
    x = rng.normal(size=(n, 3))
    x /= np.linalg.norm(x, axis=1)[:, None]
    a = np.asarray(axes, float)
    p = x * a
    nrm = x / a
    nrm /= np.linalg.norm(nrm, axis=1)[:, None]
    return SurfelSet(p, nrm, np.full(n, 0.05))


def _torus(n, big=1.0, small=0.35, seed=0):
    rng = np.random.default_rng(seed)
    u, v = rng.uniform(0, 2 * np.pi, (2, n))
    c = np.column_stack([np.cos(u), np.sin(u), np.zeros(n)])
    nrm = np.cos(v)[:, None] * c + np.sin(v)[:, None] * [0.0, 0.0, 1.0]
    return SurfelSet(big * c + small * nrm, nrm, np.full(n, 0.05))


def _ellipsoid_residual(v, axes):
    """|implicit - 1| scaled to a distance (exact for the sphere, first order otherwise)."""
    a = np.asarray(axes, float)
    q = np.sqrt(((v / a) ** 2).sum(axis=1))
    return np.abs(q - 1) * np.linalg.norm(v, axis=1) / q


def _check_closed_genus0(v, f):
    topo = TriangleMesh(v, f).topology()
    assert topo.closed and topo.components == 1 and topo.nonmanifold_vertices == 0
    assert topo.genus == 0
    # consistent winding: every directed edge once; outward: positive volume
    he = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    assert len(np.unique(he[:, 0] * len(v) + he[:, 1])) == len(he)
    assert TriangleMesh(v, f).signed_volume() > 0
    return topo


@pytest.mark.parametrize("axes", [(1.0, 1.0, 1.0), (2.0, 1.0, 0.5)])
def test_ellipsoid_proxy_is_closed_genus0_and_close(axes):
    s = _ellipsoid(4000, axes)
    v, f = proxy_mesh(s)
    assert v.dtype == np.float64 and f.dtype == np.int64
    _check_closed_genus0(v, f)
    # Hausdorff distance to the true surface, both ways
    assert _ellipsoid_residual(v, axes).max() < 0.01 * max(axes)
    _, _, d = closest_points(s.positions, v, f)
    assert d.max() < 0.01 * max(axes)
    # no more vertices than about the surfel count
    assert len(v) < 2.5 * len(s)


def test_explicit_resolution_changes_density():
    s = _ellipsoid(3000)
    v1, _ = proxy_mesh(s, resolution=20)
    v2, f2 = proxy_mesh(s, resolution=40)
    assert len(v2) > 2.5 * len(v1)
    _check_closed_genus0(v2, f2)


def test_translation_and_scale_do_not_change_topology():
    s = _ellipsoid(2000, (1.0, 0.7, 0.5))
    t = SurfelSet(s.positions * 1000.0 + [5e4, -3e3, 7.0], s.normals, s.radii * 1000.0)
    v, f = proxy_mesh(s)
    v2, f2 = proxy_mesh(t)
    _check_closed_genus0(v2, f2)
    assert len(v2) == len(v)


def test_torus_genus_is_reported():
    s = _torus(6000)
    with pytest.raises(TopologyError, match=r"genus 1 .*only genus-0") as info:
        proxy_mesh(s, resolution=40)
    assert info.value.genus == 1
    v, f = proxy_mesh(s, resolution=40, genus0=False)
    assert TriangleMesh(v, f).topology().genus == 1


def test_too_few_points():
    s = _ellipsoid(MIN_POINTS - 1)
    with pytest.raises(InputError, match=r"too few surfels for a proxy surface: 31"):
        proxy_mesh(s)


def test_not_a_surfel_set():
    with pytest.raises(InputError, match=r"surfels must be a SurfelSet, got ndarray"):
        proxy_mesh(np.zeros((100, 3)))


def test_coincident_points():
    n = 100
    s = SurfelSet(np.zeros((n, 3)), np.tile([0.0, 0.0, 1.0], (n, 1)), np.ones(n))
    with pytest.raises(InputError, match=r"all surfels coincide"):
        proxy_mesh(s)


@pytest.mark.parametrize("res, msg", [(8, r"resolution must be at least 16"),
                                      (10_000, r"resolution must be at most 512"),
                                      (2.5, r"resolution must be an integer")])
def test_bad_resolution(res, msg):
    with pytest.raises(InputError, match=msg):
        proxy_mesh(_ellipsoid(200), resolution=res)


def test_inward_normals():
    s = _ellipsoid(2000)
    inward = SurfelSet(s.positions, -s.normals, s.radii)
    with pytest.raises(TopologyError, match=r"normals point inward.*flip them so they point out"):
        proxy_mesh(inward)


def test_broken_proxy_is_not_closed():
    # the check run on every proxy: a mesh with a hole, and one with a non-manifold edge
    from surfidx.sphere.proxy import check_topology

    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], float)
    f = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2]])
    with pytest.raises(TopologyError, match=r"not one closed manifold piece \(3 boundary edges"):
        check_topology(v, f, genus0=True)
    f2 = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 3, 2], [1, 2, 3]])  # flipped twin face
    with pytest.raises(TopologyError, match=r"not one closed manifold piece"):
        check_topology(v, f2, genus0=True)


def test_inconsistent_winding_is_reported():
    from surfidx.sphere.proxy import check_topology

    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], float)
    f = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    check_topology(v, f, genus0=True)
    f[3] = [1, 3, 2]
    with pytest.raises(TopologyError, match=r"not consistently oriented"):
        check_topology(v, f, genus0=True)


# ---------------------------------------------------------------------- closest points, transfer
def _mesh():
    from conftest import icosphere_mesh

    v, f = icosphere_mesh(2)
    return v * [1.0, 0.8, 0.6], f


def test_transfer_reproduces_linear_functions_on_the_mesh():
    v, f = _mesh()
    rng = np.random.default_rng(1)
    t = rng.integers(0, len(f), 500)
    b = rng.dirichlet(np.ones(3), 500)
    pts = np.einsum("nc,ncj->nj", b, v[f[t]])
    lin = np.array([[1.0, -2.0], [0.5, 3.0], [-1.5, 0.25]])
    values = v @ lin + [0.3, -0.7]
    out = transfer(pts, v, f, values)
    np.testing.assert_allclose(out, pts @ lin + [0.3, -0.7], atol=1e-12)
    one = transfer(pts, v, f, values[:, 0])
    assert one.shape == (500,)
    np.testing.assert_allclose(one, out[:, 0], atol=1e-12)


def test_closest_points_match_brute_force():
    v, f = _mesh()
    rng = np.random.default_rng(2)
    pts = rng.normal(size=(300, 3)) * 1.5  # inside, outside and far away
    face, bary, dist = closest_points(pts, v, f, candidates=2)
    # brute force over every triangle
    from surfidx.sphere.proxy import project_to_candidates

    allc = np.tile(np.arange(len(f)), (len(pts), 1))
    _, _, d2 = project_to_candidates(pts, allc, v, f)
    np.testing.assert_allclose(dist, np.sqrt(d2), atol=1e-12)
    assert np.all(bary >= -1e-12) and np.allclose(bary.sum(axis=1), 1.0)
    q = np.einsum("nc,ncj->nj", bary, v[f[face]])
    np.testing.assert_allclose(np.linalg.norm(q - pts, axis=1), dist, atol=1e-12)


def test_transfer_of_proxy_sphere_positions():
    # the owner's use: the proxy's per-vertex sphere positions carried to the surfels
    s = _ellipsoid(3000, (1.5, 1.0, 0.8))
    v, f = proxy_mesh(s)
    sphere = v / np.linalg.norm(v, axis=1)[:, None]
    x = transfer(s.positions, v, f, sphere)
    x /= np.linalg.norm(x, axis=1)[:, None]
    want = s.positions / np.linalg.norm(s.positions, axis=1)[:, None]
    assert np.max(np.linalg.norm(x - want, axis=1)) < 0.02


def test_transfer_errors():
    v, f = _mesh()
    with pytest.raises(InputError, match=r"values must have shape \(162,\) or \(162, d\)"):
        transfer(v, v, f, np.zeros((10, 3)))
    with pytest.raises(InputError, match=r"faces index vertices outside 0\.\.161"):
        transfer(v, v, f + 1000, np.zeros(162))
    with pytest.raises(InputError, match=r"faces is empty"):
        transfer(v, v, np.zeros((0, 3), np.int64), np.zeros(162))
    with pytest.raises(InputError, match=r"points must have shape \(n, 3\)"):
        transfer(np.zeros((4, 2)), v, f, np.zeros(162))


# ---------------------------------------------------------------------- real scans
@pytest.mark.slow
@pytest.mark.parametrize("name", ["bunny_hr.obj", "armadillo.obj"])
def test_real_point_cloud_gives_closed_genus0_proxy(models, name):
    import surfidx

    s = surfidx.read_surfels(models / name, samples=20000)
    s = SurfelSet(s.positions, s.normals, s.radii)  # a point cloud: no faces
    v, f = proxy_mesh(s)
    _check_closed_genus0(v, f)
    _, _, d = closest_points(s.positions, v, f)
    diag = np.linalg.norm(np.ptp(s.positions, axis=0))
    assert d.max() < 0.01 * diag
