"""Spheres-of-influence graph: edges, symmetry, variants, components, bridging."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import icosphere_mesh
from scipy.spatial import cKDTree

from surfidx import SurfelSet, TopologyError, TriangleMesh
from surfidx.errors import InputError
from surfidx.geometry.graph import SphereOfInfluenceGraph, neighbour_radii, sphere_of_influence_graph


def _sphere(level=3, centre=(0.0, 0.0, 0.0)):
    v, f = icosphere_mesh(level)
    return TriangleMesh(v + np.asarray(centre), f).to_surfels()


def _two_spheres():
    a, b = _sphere(2), _sphere(2, centre=(5.0, 0.0, 0.0))
    return SurfelSet(np.vstack([a.positions, b.positions]), np.vstack([a.normals, b.normals]),
                     np.concatenate([a.radii, b.radii]))


def test_edges_match_brute_force(sphere_surfels):
    s = sphere_surfels
    g = SphereOfInfluenceGraph.from_surfels(s, max_angle=60.0, scale=1.5, max_offset=None,
                                            mesh_edges=False, arc_weights=False)
    p, n, r = s.positions, s.normals, 1.5 * s.radii
    i, j = np.triu_indices(len(s), 1)
    u = p[j] - p[i]
    d = np.linalg.norm(u, axis=1)
    half = np.sin(np.radians(30.0))
    keep = (d < r[i] + r[j]) & (np.einsum("ij,ij->i", n[i], n[j]) > np.cos(np.radians(60.0)))
    keep &= (np.abs(np.einsum("ij,ij->i", u, n[i])) < half * d)
    keep &= (np.abs(np.einsum("ij,ij->i", u, n[j])) < half * d)
    m = g.matrix.toarray()
    assert g.n_edges == keep.sum()
    assert np.allclose(m[i[keep], j[keep]], d[keep])
    assert np.allclose(m, m.T)
    assert not np.any(np.diag(m))


def test_mesh_edges_included_at_scale_one(sphere_surfels):
    g = sphere_of_influence_graph(sphere_surfels, scale=1.0)
    f = sphere_surfels.faces
    m = g.matrix.tocsr()
    for a, b in ((0, 1), (1, 2), (2, 0)):
        assert np.all(np.asarray(m[f[:, a], f[:, b]]).ravel() > 0)
    assert g.n_components == 1
    assert g.degrees.min() >= 5


def test_radius_variants(sphere_surfels):
    s = sphere_surfels
    near = neighbour_radii(s.positions, s.radii, radius="nearest")
    d, _ = cKDTree(s.positions).query(s.positions, k=2)
    assert np.allclose(near, d[:, 1])
    knn = neighbour_radii(s.positions, s.radii, radius="knn", k=4)
    d, _ = cKDTree(s.positions).query(s.positions, k=5)
    assert np.allclose(knn, d[:, 4])
    g1 = SphereOfInfluenceGraph.from_surfels(s, radius="nearest", scale=1.0)
    g2 = SphereOfInfluenceGraph.from_surfels(s, radius="knn", k=8, scale=1.0)
    assert g2.n_edges > g1.n_edges
    with pytest.raises(InputError, match="radius must be one of"):
        SphereOfInfluenceGraph.from_surfels(s, radius="huge")


def test_disconnected_raises_with_sizes():
    s = _two_spheres()
    with pytest.raises(TopologyError, match=r"2 components \(sizes 162, 162 surfels\)"):
        SphereOfInfluenceGraph.from_surfels(s)
    g = SphereOfInfluenceGraph.from_surfels(s, check=False)
    count, labels = g.components()
    assert count == 2 and list(g.component_sizes()) == [162, 162]
    assert set(labels[:162]) == {labels[0]} and labels[0] != labels[200]


def test_bridge_joins_with_warning():
    s = _two_spheres()
    with pytest.warns(UserWarning, match="2 components .* bridged them with 1 straight links"):
        g = SphereOfInfluenceGraph.from_surfels(s, bridge=True)
    assert g.n_components == 1
    assert g.bridges.shape == (1, 2)
    a, b = g.bridges[0]
    # the shortest link between the two unit spheres 5 apart is about 3 long
    assert np.linalg.norm(s.positions[a] - s.positions[b]) == pytest.approx(3.0, abs=0.1)


def test_bridge_many_components():
    parts = [_sphere(1, centre=(3.0 * k, (k % 2) * 3.0, 0.0)) for k in range(5)]
    s = SurfelSet(np.vstack([p.positions for p in parts]), np.vstack([p.normals for p in parts]),
                  np.concatenate([p.radii for p in parts]))
    with pytest.raises(TopologyError, match=r"5 components \(sizes 42, 42, 42, 42, 42"):
        SphereOfInfluenceGraph.from_surfels(s)
    with pytest.warns(UserWarning, match="bridged them with 4 straight links"):
        g = SphereOfInfluenceGraph.from_surfels(s, bridge=True)
    assert g.n_components == 1


def test_normal_angle_separates_thin_sheet():
    # two parallel planes 0.05 apart, facing away from each other: spheres reach across, normals
    # do not agree, so the sheets stay separate
    x, y = np.meshgrid(np.arange(20) * 0.1, np.arange(20) * 0.1)
    top = np.stack([x.ravel(), y.ravel(), np.full(400, 0.025)], 1)
    bot = top * [1, 1, -1]
    pos = np.vstack([top, bot])
    nrm = np.vstack([np.tile([0, 0, 1.0], (400, 1)), np.tile([0, 0, -1.0], (400, 1))])
    s = SurfelSet(pos, nrm, np.full(800, 0.08))
    g = SphereOfInfluenceGraph.from_surfels(s, check=False)
    assert g.n_components == 2
    g180 = SphereOfInfluenceGraph.from_surfels(s, max_angle=180.0)
    assert g180.n_components == 1


def test_bad_options(sphere_surfels):
    with pytest.raises(InputError, match=r"max_angle must lie in \(0, 180\]"):
        SphereOfInfluenceGraph.from_surfels(sphere_surfels, max_angle=0)
    with pytest.raises(InputError, match="max_angle must be a number"):
        SphereOfInfluenceGraph.from_surfels(sphere_surfels, max_angle="wide")
    with pytest.raises(InputError, match="scale must be a positive number"):
        SphereOfInfluenceGraph.from_surfels(sphere_surfels, scale=-1.0)
    with pytest.raises(InputError, match="surfels must be a SurfelSet"):
        SphereOfInfluenceGraph.from_surfels(np.zeros((3, 3)))
    with pytest.raises(InputError, match="at least 2 surfels"):
        SphereOfInfluenceGraph.from_surfels(sphere_surfels.subset([0]))
    with pytest.raises(InputError, match="k must be at least 1"):
        neighbour_radii(sphere_surfels.positions, sphere_surfels.radii, radius="knn", k=0)
    same = SurfelSet(np.zeros((3, 3)), np.tile([0, 0, 1.0], (3, 1)), np.ones(3))
    with pytest.raises(InputError, match="all surfels coincide"):
        neighbour_radii(same.positions, same.radii, radius="nearest")


def test_varied_radii_and_repr():
    rng = np.random.default_rng(0)
    v, f = icosphere_mesh(3)
    r = np.full(len(v), 0.08)
    r[rng.choice(len(v), 5, replace=False)] = 1.0  # a few huge surfels
    s = SurfelSet(v, v, r)
    g = SphereOfInfluenceGraph.from_surfels(s, scale=1.0, max_angle=180.0, max_offset=None)
    i, j = np.triu_indices(len(v), 1)
    d = np.linalg.norm(v[i] - v[j], axis=1)
    u = (v[j] - v[i]) / d[:, None]
    ok = (d < r[i] + r[j])
    assert g.n_edges == ok.sum()
    assert "SphereOfInfluenceGraph(642 surfels" in repr(g)


def test_isolated_tip_is_linked_to_same_side_neighbours():
    # a flat grid with one surfel whose normal is tilted by 80 degrees (like the tip of a spike):
    # the normal and tangent tests reject all its links, the fallback links it on the same side
    x, y = np.meshgrid(np.arange(9) * 0.1, np.arange(9) * 0.1)
    pos = np.stack([x.ravel(), y.ravel(), np.zeros(81)], 1)
    nrm = np.tile([0, 0, 1.0], (81, 1))
    t = np.radians(80.0)
    nrm[40] = [np.sin(t), 0.0, np.cos(t)]
    s = SurfelSet(pos, nrm, np.full(81, 0.08))
    g = SphereOfInfluenceGraph.from_surfels(s, scale=1.0)
    assert g.n_components == 1
    nb = g.matrix[40].indices
    d = np.linalg.norm(pos[nb] - pos[40], axis=1)
    assert len(nb) == 8 and np.all(d < 0.16)
    assert np.allclose(g.matrix[40].data, d) and np.allclose(g.matrix[:, 40].toarray()[nb, 0], d)
    # the other surfels keep the strict tests: no edge between two other surfels changed (the
    # surface test off: the tip's tilted plane would reject the midpoints next to it)
    flat = SurfelSet(pos, np.tile([0, 0, 1.0], (81, 1)), np.full(81, 0.08))
    g = SphereOfInfluenceGraph.from_surfels(s, scale=1.0, max_offset=None)
    gf = SphereOfInfluenceGraph.from_surfels(flat, scale=1.0, max_offset=None)
    keep = np.setdiff1d(np.arange(81), [40])
    assert (g.matrix[keep][:, keep] != gf.matrix[keep][:, keep]).nnz == 0


def _sheet(z, n=12, h=0.1, normal=(0.0, 0.0, 1.0)):
    x, y = np.meshgrid(np.arange(n) * h, np.arange(n) * h)
    pos = np.stack([x.ravel(), y.ravel(), np.full(n * n, z)], 1)
    return pos, np.tile(np.asarray(normal, float), (n * n, 1))


def test_parallel_sheets_get_no_edges_between_them():
    # two sheets 0.1 apart, same normals, spheres reaching 0.32: the sphere, normal and tangent
    # tests accept the slanted links between them; the midpoint (surface) test rejects them all
    pa, na = _sheet(0.0)
    pb, nb = _sheet(0.1)
    s = SurfelSet(np.vstack([pa, pb]), np.vstack([na, nb]), np.full(2 * len(pa), 0.08))
    raw = SphereOfInfluenceGraph.from_surfels(s, max_offset=None, check=False)
    m = raw.matrix.tocoo()
    assert np.any((m.row < len(pa)) != (m.col < len(pa)))  # the shortcut links exist without it
    g = SphereOfInfluenceGraph.from_surfels(s, check=False)
    m = g.matrix.tocoo()
    assert not np.any((m.row < len(pa)) != (m.col < len(pa)))
    assert g.n_components == 2 and list(g.component_sizes()) == [len(pa), len(pa)]
    with pytest.raises(TopologyError, match="2 components"):
        SphereOfInfluenceGraph.from_surfels(s)
    with pytest.raises(InputError, match="max_offset must be a non-negative number"):
        SphereOfInfluenceGraph.from_surfels(s, max_offset=-1.0)


def test_surface_test_keeps_curved_and_flat_edges(sphere_surfels):
    # chords of a smooth surface stay within their sagitta: the test removes nothing there
    a = SphereOfInfluenceGraph.from_surfels(sphere_surfels, max_offset=None)
    b = SphereOfInfluenceGraph.from_surfels(sphere_surfels)
    assert b.n_edges == a.n_edges
    pos, nrm = _sheet(0.0)
    flat = SurfelSet(pos, nrm, np.full(len(pos), 0.08))
    assert (SphereOfInfluenceGraph.from_surfels(flat).n_edges
            == SphereOfInfluenceGraph.from_surfels(flat, max_offset=None).n_edges)


def test_arc_weights_are_arc_lengths_on_a_sphere(sphere_surfels):
    # unit sphere with exact radial normals: arc weights are great-circle arcs
    s = SurfelSet(sphere_surfels.positions, sphere_surfels.positions, sphere_surfels.radii)
    g = SphereOfInfluenceGraph.from_surfels(s)
    m = g.matrix.tocoo()
    arc = np.arccos(np.clip(np.einsum("ij,ij->i", s.positions[m.row], s.positions[m.col]), -1, 1))
    assert np.allclose(m.data, arc, rtol=1e-6)
    chord = SphereOfInfluenceGraph.from_surfels(s, arc_weights=False).matrix
    assert np.all(g.matrix.data >= chord.data)
