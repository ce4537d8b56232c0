"""Topology-preserving decimation: the coarse mesh triangulates the same sphere, prolongation is a
partition of unity and keeps coarse values."""

import numpy as np
import pytest

from surfidx import TriangleMesh, read_surfels
from surfidx.sphere.decimate import decimate
from surfidx.sphere.surface import oriented_faces as _oriented_faces

from conftest import icosphere_mesh


def _check_sphere_like(v, f):
    topo = TriangleMesh(v, f).topology()
    assert topo.closed and topo.genus == 0 and topo.components == 1
    assert topo.nonmanifold_vertices == 0


@pytest.mark.parametrize("target", [200, 40, 4])
def test_icosphere_keeps_its_topology(target):
    v, f = icosphere_mesh(4)
    h = decimate(v, f, target)
    assert len(h.vertices) >= target and len(h.vertices) < len(v)
    assert set(np.unique(h.faces)) == set(h.vertices)
    _check_sphere_like(v, h.faces)
    # winding kept: every directed edge once, and the enclosed volume is positive
    he = np.concatenate([h.faces[:, [0, 1]], h.faces[:, [1, 2]], h.faces[:, [2, 0]]])
    assert len(np.unique(he, axis=0)) == len(he)
    a, b, c = v[h.faces[:, 0]], v[h.faces[:, 1]], v[h.faces[:, 2]]
    assert np.einsum("ij,ij->", np.cross(a, b), c) > 0


def test_real_model_keeps_its_topology(models):
    s = read_surfels(models / "spot/spot_triangulated.obj")
    f = _oriented_faces(s)
    h = decimate(s.positions, f, len(s) // 4)
    assert len(h.vertices) <= len(s) // 4 + 1
    _check_sphere_like(s.positions, h.faces)


def test_prolong_keeps_coarse_values_and_constants():
    v, f = icosphere_mesh(3)
    h = decimate(v, f, 60)
    rng = np.random.default_rng(0)
    vals = np.full((len(v), 2), np.nan)
    vals[h.vertices] = rng.normal(size=(len(h.vertices), 2))
    out = h.prolong(vals, v)
    assert np.all(np.isfinite(out))
    np.testing.assert_array_equal(out[h.vertices], vals[h.vertices])
    const = np.where(np.isnan(vals), np.nan, 3.0)
    np.testing.assert_allclose(h.prolong(const, v), 3.0, atol=1e-12)
    # on the sphere: unit vectors stay unit vectors
    x = h.prolong(np.where(np.isnan(vals[:, :1]), np.nan, 1.0) * v, v, unit=True)
    np.testing.assert_allclose(np.linalg.norm(x, axis=1), 1.0, atol=1e-12)


def test_prolong_is_exact_for_affine_values_on_a_flat_star():
    """Mean value weights reproduce affine functions of a planar neighbourhood (Floater 2003)."""
    v, f = icosphere_mesh(3)
    h = decimate(v, f, 300)
    removed, kept, ptr, ring = h.rounds[0]
    flat = v.copy()
    flat[:, 2] = 0.0   # mean value weights of a flattened star: affine values are reproduced
    i = int(np.argmax(v[removed, 2]))   # near the pole, where flattening keeps the star
    star = np.concatenate([[removed[i]], ring[ptr[i]:ptr[i + 1]]])
    vals = np.full((len(v), 1), np.nan)
    vals[:, 0] = 2.0 * flat[:, 0] - flat[:, 1] + 0.5
    from surfidx.sphere.decimate import Hierarchy

    one = Hierarchy(h.faces, np.setdiff1d(np.arange(len(v)), [removed[i]]),
                    [(removed[i:i + 1], kept[i:i + 1], np.array([0, ptr[i + 1] - ptr[i]]),
                      star[1:])])
    vals2 = vals.copy()
    vals2[removed[i]] = np.nan
    out = one.prolong(vals2, flat)
    assert out[removed[i], 0] == pytest.approx(vals[removed[i], 0], abs=1e-12)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_embedded_prolongation_never_folds(seed):
    """With ``embed``, an embedded coarse map gives an embedded map of every vertex, however
    little the coarse map resembles the 3D shape the mean value weights come from (here the
    sphere under a bumpy surface's weights); the plain mean folds some stars of the same input
    (so the check can fail)."""
    from surfidx.geometry.unitsphere import orientation

    rng = np.random.default_rng(seed)
    v, f = icosphere_mesh(4)
    h = decimate(v, f, 150)
    p = v * rng.uniform(0.2, 1.8, size=(len(v), 1))    # weights of a bumpy star-shaped surface
    x = np.full((len(v), 3), np.nan)
    x[h.vertices] = v[h.vertices]
    assert orientation(x, h.faces).min() > 0     # the coarse map is embedded
    plain = h.prolong(x, p, unit=True)
    assert np.count_nonzero(orientation(plain, f) <= 0) > 0
    out = h.prolong(x, p, unit=True, embed=True)
    assert orientation(out, f).min() > 0
    np.testing.assert_array_equal(out[h.vertices], x[h.vertices])
    np.testing.assert_allclose(np.linalg.norm(out, axis=1), 1.0, atol=1e-12)


def test_round_by_round_prolongation_matches_prolong():
    """:meth:`Hierarchy.undo` round by round is :meth:`Hierarchy.prolong`; ``settle`` is called
    once per round, finest last, with the faces of that round's mesh
    (:meth:`Hierarchy.round_faces`), whose vertices are exactly those set so far."""
    from surfidx.geometry.unitsphere import orientation

    v, f = icosphere_mesh(4)
    h = decimate(v, f, 150)
    x = np.zeros((len(v), 3))
    x[h.vertices] = v[h.vertices]
    faces = h.round_faces(f)
    assert len(faces) == len(h.rounds) and np.array_equal(faces[0], f)
    seen = []

    def settle(out, r):
        present = np.flatnonzero(np.linalg.norm(out, axis=1) > 0)
        assert np.array_equal(np.unique(faces[r]), present)
        assert orientation(out, faces[r]).min() > 0
        seen.append(r)
        return out

    out = h.prolong(x, v, unit=True, embed=True, settle=settle)
    assert seen == list(reversed(range(len(h.rounds))))
    np.testing.assert_array_equal(out, h.prolong(x, v, unit=True, embed=True))


@pytest.mark.parametrize("far", [1.0, 1e6])
def test_shortest_first_is_the_stable_order_of_rounded_lengths(far):
    """The edges go shortest first by squared length rounded to 9 decimals relative to the mean,
    ties in edge order: exactly a stable argsort of those rounded values, whether the integer
    keys fit 63 bits or (100k edges, one a million times longer) the argsort itself runs."""
    from surfidx.sphere.decimate import shortest_first

    rng = np.random.default_rng(3)
    p = np.round(rng.random((300, 3)), 2)            # a coarse lattice: many equal lengths
    p[0] *= far
    e = rng.integers(1, 300, (100_000, 2))
    e = np.vstack([[0, 1], e[e[:, 0] != e[:, 1]]])   # vertex 0 on one edge
    d = p[e[:, 0]] - p[e[:, 1]]
    rounded = np.round(np.einsum("ij,ij->i", d, d) / np.einsum("ij,ij->i", d, d).mean(), 9)
    assert len(np.unique(rounded)) < len(e)                                  # ties exist
    fits = rounded.max() * 1e9 < 2.0 ** (62 - int(len(e) - 1).bit_length())
    assert fits == (far == 1.0)
    assert np.array_equal(shortest_first(p, e), np.argsort(rounded, kind="stable"))
