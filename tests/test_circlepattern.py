"""Fold removal by edge flips and Delaunay realisation (surfidx.sphere.circlepattern)."""

import numpy as np
import pytest

from surfidx.sphere.circlepattern import (MIN_CORNER, MIN_SPACING_RATIO, NEWTON_STEPS,
                                           against,
                                           coherent_angles, mesh_edges, layout, moebius_fit,
                                           planar_angles, log_radii,
                                           point_spacing, anneal_flips, flip_folds, lower_folds,
                                           realise)
from surfidx.sphere import MapOptions
from surfidx.geometry.unitsphere import against_normals as _folded, hull_triangles


def _sorted(t):
    s = np.sort(t, axis=1)
    return s[np.lexsort(s.T[::-1])]


@pytest.fixture(scope="module")
def points():
    rng = np.random.default_rng(1)
    v = rng.standard_normal((400, 3))
    return v / np.linalg.norm(v, axis=1)[:, None]


@pytest.fixture(scope="module")
def ellipsoid(points):
    """An ellipsoid's surfels (positions, outward normals) over the unit vectors ``points``."""
    p = points * [1.0, 2.0, 3.0]
    n = points / np.array([1.0, 4.0, 9.0])
    return p, n / np.linalg.norm(n, axis=1)[:, None]


def test_a_delaunay_map_is_its_own_realisation(points):
    y = realise(points, hull_triangles(points))
    assert y is not None
    assert np.allclose(np.linalg.norm(y, axis=1), 1.0)
    assert np.abs(y - points).max() < 1e-3           # only near-cocircular angles are raised
    assert np.array_equal(_sorted(hull_triangles(y)), _sorted(hull_triangles(points)))


def test_the_layout_keeps_its_angles_over_five_orders_of_scale():
    """Planar triangles from 1e-2 to 1e2 (circumradii over a factor 2e5, slivers of 5e-4 rad):
    the least-squares layout puts them back with their angles. With rows weighted by the
    inverse circumradius and not scaled to unit norm, the error was 0.02 rad."""
    from scipy.spatial import Delaunay

    rng = np.random.default_rng(0)
    r = np.repeat(10.0 ** np.linspace(-2, 2, 100), 24)
    phi = rng.uniform(0, 2 * np.pi, len(r))
    u = np.column_stack([r * np.cos(phi), r * np.sin(phi)])
    t = Delaunay(u).simplices
    e1, e2 = u[t[:, 1]] - u[t[:, 0]], u[t[:, 2]] - u[t[:, 0]]
    cw = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0] < 0
    t[cw] = t[cw][:, ::-1]
    ang = planar_angles(u, t)
    rho = np.log(np.linalg.norm(u[t[:, 1]] - u[t[:, 0]], axis=1) / (2 * np.sin(ang[:, 2])))
    assert np.ptp(rho) > 12 and ang.min() < 1e-3
    z = layout(t, ang, rho - rho[0], len(u) + 1, len(u))      # the last point: the pole
    laid = planar_angles(np.column_stack([z.real, z.imag]), t)
    assert np.abs(laid - ang).max() < 1e-6


def _flippable(x, tri, *, convex=True):
    """A triangulation with one quadrilateral's diagonal flipped (a convex one, or one that is
    not convex: the flip turns a triangle over): no longer Delaunay."""
    de = {(a, b): i for i, t in enumerate(tri.tolist()) for a, b in zip(t, t[1:] + t[:1])}
    edges = {tuple(sorted(e)) for e in de}
    for i, (a, b, c) in enumerate(tri.tolist()):
        j = de[(b, a)]
        d = next(v for v in tri[j] if v not in (a, b))
        new = np.array([[a, d, c], [d, b, c]])
        e1, e2 = x[new[:, 1]] - x[new[:, 0]], x[new[:, 2]] - x[new[:, 0]]
        ccw = np.einsum("ij,ij->i", np.cross(e1, e2), x[new].sum(axis=1)) > 0
        if ccw.all() == convex and tuple(sorted((c, d))) not in edges:
            out = tri.copy()
            out[[i, j]] = new
            return out, (int(c), int(d))
    raise AssertionError("no such quadrilateral")


def test_a_flipped_edge_is_realised_as_delaunay(points):
    tri, edge = _flippable(points, hull_triangles(points))
    assert not np.array_equal(_sorted(tri), _sorted(hull_triangles(points)))
    y = realise(points, tri)
    assert y is not None
    # the convex hull of the moved points is exactly the flipped triangulation
    assert np.array_equal(_sorted(hull_triangles(y)), _sorted(tri))
    assert np.abs(y - points).max() < 0.3
    # ... and it does not depend on which edges are named new when it is the only one
    z = realise(points, tri, new_edges=np.array([edge]))
    assert np.array_equal(_sorted(hull_triangles(z)), _sorted(tri))


def test_a_flip_that_turns_a_triangle_over_is_realised_as_delaunay(points):
    """A quadrilateral that is not convex on the sphere: the flipped triangulation is no
    triangulation of the points where they are, but the circle pattern moves them so that it is
    their Delaunay triangulation (coherent angles, Newton's method with a line search)."""
    tri, edge = _flippable(points, hull_triangles(points), convex=False)
    y = realise(points, tri)
    assert y is not None
    assert np.array_equal(_sorted(hull_triangles(y)), _sorted(tri))
    assert np.abs(y - points).max() < 0.5


def test_coherent_angles_meet_every_constraint_or_none(points):
    """The corner angles given to Newton's method: at least MIN_CORNER, π in every triangle,
    2π around inner vertices, the boundary sums kept, at most the cap at every edge; None when
    the caps leave no room (they would force the triangles' angles below π)."""
    tri = hull_triangles(points)
    n = len(points)
    pole = 0
    inner = ~np.any(tri == pole, axis=1)
    t = tri[inner]
    edges, opposite = mesh_edges(tri, n)
    rng = np.random.default_rng(3)
    alpha = rng.uniform(-0.5, 2.0, t.shape)     # far from any angle system, some turned over
    ring = np.unique(tri[~inner])
    ring = ring[ring != pole]
    sums = np.full(len(ring), (len(ring) - 2) * np.pi / len(ring))   # a convex ring: 2π turning
    cap = np.full(len(edges), np.pi - 0.05)
    a = coherent_angles(alpha, t, n, ring, sums, opposite[inner], cap)
    assert a is not None and a.min() >= MIN_CORNER
    assert np.allclose(a.sum(axis=1), np.pi, atol=1e-9)
    vsum = np.bincount(t.ravel(), a.ravel(), minlength=n)
    inside = np.setdiff1d(np.arange(1, n), ring)
    assert np.allclose(vsum[inside], 2 * np.pi, atol=1e-9)
    assert np.allclose(vsum[ring], sums, atol=1e-9)
    assert (np.bincount(opposite[inner].ravel(), a.ravel(), minlength=len(edges)) <= cap).all()
    assert coherent_angles(alpha, t, n, ring, sums, opposite[inner], np.full(len(edges), 1.0)) \
        is None


def test_moebius_fit_recovers_a_moebius_map():
    """The realisation is fitted to the current map by a Möbius map, which keeps its circles:
    one that is exactly a Möbius image is brought back exactly, infinity included."""
    rng = np.random.default_rng(4)
    z = rng.standard_normal(200) + 1j * rng.standard_normal(200)
    a, b, c = 1.3 - 0.4j, 0.2 + 0.7j, 0.15 - 0.1j
    target = (a * z + b) / (c * z + 1)
    out, far = moebius_fit(z, target, z)
    assert np.abs(out - target).max() < 1e-9 and abs(far - a / c) < 1e-9
    out, far = moebius_fit(z, 2 * z + 1, z)            # a similarity: infinity stays
    assert np.abs(out - (2 * z + 1)).max() < 1e-9 and abs(far) > 1e9


def _noisy(points, amplitude=0.02, seed=2):
    rng = np.random.default_rng(seed)
    x = points + amplitude * rng.standard_normal(points.shape)
    return x / np.linalg.norm(x, axis=1)[:, None]


def test_a_single_triangle_is_judged_as_against_normals_judges_it():
    """The flips' one-triangle fold test gives the vectorised answer exactly, for triangles in
    any listing and for nearly straight ones, whose sign is decided by rounding."""
    rng = np.random.default_rng(5)
    p, normals = rng.standard_normal((600, 3)), rng.standard_normal((600, 3))
    p[:300] = np.outer(rng.standard_normal(300), [1.0, 2.0, 3.0]) \
        + 1e-9 * rng.standard_normal((300, 3))                     # on one line, but for rounding
    t = rng.integers(0, 600, (30_000, 3))
    t = t[(t[:, 0] != t[:, 1]) & (t[:, 1] != t[:, 2]) & (t[:, 2] != t[:, 0])]
    t[: len(t) // 2] = rng.integers(0, 300, (len(t) // 2, 3))
    t = t[(t[:, 0] != t[:, 1]) & (t[:, 1] != t[:, 2]) & (t[:, 2] != t[:, 0])]
    rows = p.tolist(), normals.tolist()
    got = [against(*rows, tuple(r)) for r in t.tolist()]
    assert got == _folded(p, normals, t).tolist()
    assert 0 < sum(got) < len(got)


def test_flips_lower_the_folds_of_a_triangulation(points, ellipsoid):
    p, n = ellipsoid
    x = _noisy(points)
    tri = hull_triangles(x)
    before = int(_folded(p, n, tri).sum())
    flipped, left = flip_folds(tri, p, n, x)
    assert before > 10 and left < before
    assert left == int(_folded(p, n, flipped).sum())
    assert len(flipped) == len(tri)
    assert len({tuple(t) for t in _sorted(flipped).tolist()}) == len(tri)


def test_lower_folds_realises_the_flips(points, ellipsoid):
    p, n = ellipsoid
    x = _noisy(points)
    y, info = lower_folds(x, p, n)
    assert info["folds_before"] > 10 and info["folds"] <= info["folds_before"] // 3
    assert info["rounds"] >= 1
    assert int(_folded(p, n, hull_triangles(y)).sum()) == info["folds"]
    # no point's neighbours crowd in by more than the bound (the grid must still sample it)
    assert (point_spacing(y) / point_spacing(x)).min() >= MIN_SPACING_RATIO
    # a fold-free map is returned as it is
    z, info = lower_folds(points, p, n)
    assert info == {"folds_before": 0, "folds": 0, "rounds": 0, "refused": 0,
                    "annealed": 0, "annealing": 0} and z is points


def _is_sphere_triangulation(tri, n):
    """Every directed edge once and its reverse once: a closed oriented surface, and with
    V - E + F = 2 a sphere."""
    directed = {(a, b) for t in tri.tolist() for a, b in zip(t, t[1:] + t[:1])}
    return (len(directed) == 3 * len(tri) and all((b, a) in directed for a, b in directed)
            and n - len(directed) // 2 + len(tri) == 2)


def test_annealing_goes_below_what_the_flips_reach(points, ellipsoid):
    """Where every folded triangle needs a flip that adds a fold first, flip_folds stops (4 left
    here); the annealing takes such flips now and then and finds triangulations with fewer,
    each a triangulation of the sphere with the fold count it reports, the same for the same
    seed."""
    p, n = ellipsoid
    x = _noisy(points)
    flipped, left = flip_folds(hull_triangles(x), p, n, x)
    assert left > 0 and flip_folds(flipped, p, n, x)[1] == left
    found = anneal_flips(flipped, p, n, x, steps=20_000)
    counts = [k for _, k in found]
    assert counts and counts[-1] < left and all(a > b for a, b in zip(counts, counts[1:]))
    for tri, k in found:
        assert _is_sphere_triangulation(tri, len(x))
        assert int(_folded(p, n, tri).sum()) == k
    again = anneal_flips(flipped, p, n, x, steps=20_000)
    assert all(np.array_equal(a, b) and j == k for (a, j), (b, k) in zip(found, again))
    assert anneal_flips(hull_triangles(points), p, n, points) == []      # nothing to lower


def test_the_flip_searches_leave_the_garbage_collector_as_they_found_it(points, ellipsoid):
    """The searches pause the cyclic collector while they run and restore its state: enabled
    stays enabled, disabled stays disabled, also when a search raises."""
    import gc

    p, n = ellipsoid
    x = _noisy(points)
    tri = hull_triangles(x)
    was = gc.isenabled()
    try:
        for enabled in (True, False):
            gc.enable() if enabled else gc.disable()
            flip_folds(tri, p, n, x)
            anneal_flips(tri, p, n, x, steps=100)
            assert gc.isenabled() is enabled
            with pytest.raises(IndexError):
                flip_folds(tri, p[:5], n[:5], x)
            assert gc.isenabled() is enabled
    finally:
        gc.enable() if was else gc.disable()


def test_annealing_needs_a_positive_temperature(points, ellipsoid):
    p, n = ellipsoid
    with pytest.raises(ValueError, match="temperature must be positive, got 0"):
        anneal_flips(hull_triangles(points), p, n, points, temperature=0)


def test_lower_folds_realises_an_annealed_triangulation(points, ellipsoid):
    """The same map as above: the flips alone are realised with their 4 folds; with the
    annealing, one of its triangulations is realised instead, and nothing is left."""
    p, n = ellipsoid
    x = _noisy(points)
    y0, plain = lower_folds(x, p, n, options=MapOptions(anneal_steps=0))
    assert plain["folds"] == flip_folds(hull_triangles(x), p, n, x)[1] > 0
    assert plain["annealed"] == 0
    y, info = lower_folds(x, p, n)
    assert info["annealed"] >= 1 and info["folds"] < plain["folds"]
    assert int(_folded(p, n, hull_triangles(y)).sum()) == info["folds"]


def test_lower_folds_keeps_only_what_accept_takes(points, ellipsoid):
    """``accept`` sees every realisation: refusing all keeps the map, and then every rung of
    the ladder was realised and refused (a milder flip set is tried after each refusal)."""
    p, n = ellipsoid
    x = _noisy(points)
    seen = []

    def refuse(y):
        seen.append(y)
        return False

    z, info = lower_folds(x, p, n, accept=refuse)
    assert z is x and info["rounds"] == 0 and info["folds"] == info["folds_before"] > 10
    assert info["refused"] == len(seen) >= 2
    assert all(int(_folded(p, n, hull_triangles(y)).sum()) < info["folds_before"] for y in seen)
    y, taken = lower_folds(x, p, n, accept=lambda y: True)
    assert taken["refused"] == 0 and taken["folds"] <= info["folds_before"] // 3


def test_a_refused_annealed_triangulation_ends_the_annealing(points, ellipsoid):
    """Accepting everything, each of three rounds anneals and keeps its annealed triangulation.
    When ``accept`` refuses the first realisation (the annealed one of the first round), the
    rounds after it no longer anneal: their annealed triangulations would change the limbs'
    scale as much, at the cost of a circle pattern and a check each."""
    p, n = ellipsoid
    x = _noisy(points, 0.04, 3)
    _, taken = lower_folds(x, p, n, accept=lambda y: True)
    assert taken["rounds"] == taken["annealing"] == taken["annealed"] == 3
    calls = []

    def refuse_first(y):
        calls.append(y)
        return len(calls) > 1

    _, info = lower_folds(x, p, n, accept=refuse_first)
    assert info["refused"] == 1 and info["rounds"] >= 1
    assert info["annealing"] == 1 and info["annealed"] == 0


def test_realisation_is_rotation_equivariant(points, ellipsoid):
    p, n = ellipsoid
    rng = np.random.default_rng(2)
    x = points + 0.02 * rng.standard_normal(points.shape)
    x /= np.linalg.norm(x, axis=1)[:, None]
    q, _ = np.linalg.qr(rng.standard_normal((3, 3)))
    q *= np.sign(np.linalg.det(q))
    y, _ = lower_folds(x, p, n)
    yr, _ = lower_folds(x @ q.T, p @ q.T, n @ q.T)
    assert np.abs(yr - y @ q.T).max() < 1e-6


def test_points_the_hull_leaves_out_have_no_realisation(points, ellipsoid):
    """A duplicated point is in no hull triangle: no realisation, and the map is kept, without
    a search for flips (none could be realised)."""
    x = np.vstack([points, points[:1]])
    assert realise(x, hull_triangles(x)) is None
    p, n = ellipsoid
    rng = np.random.default_rng(2)
    y = x + 0.02 * rng.standard_normal(x.shape)
    y[-1] = y[0]
    y /= np.linalg.norm(y, axis=1)[:, None]
    z, info = lower_folds(y, np.vstack([p, p[:1]]), np.vstack([n, n[:1]]))
    assert info["rounds"] == 0 and info["folds"] == info["folds_before"] > 0 and z is y
    assert info["annealing"] == 0


def _two_triangles(b0, b1, ts):
    """Two triangles sharing one edge (intersection angle ``π - ts``), each with its other two
    edges on the boundary, their boundary angles summing to ``b0`` and ``b1``."""
    return np.array([ts]), np.array([[0, 1]]), np.array([0, 1]), np.array([b0, b1]), 2, np.zeros(2)


def test_radii_solve_a_coherent_system():
    # coherent: (b0 - π) + (b1 - π) = -ts, so both angle sums can be π
    rho, ok = log_radii(*_two_triangles(1.6, 2 * np.pi - 3.1 - 1.6, 3.1))
    assert ok and np.isfinite(rho).all()


def test_radii_stop_when_the_line_search_finds_no_descent():
    # incoherent by 0.08 rad: Newton's method stalls (no accepted point on the lines of fresh
    # steps); without the stop it ran all NEWTON_STEPS, each evaluating the residual (two
    # half-angle calls) at least once
    from unittest import mock

    import surfidx.sphere.circlepattern as cp

    with mock.patch.object(cp, "half_angle", wraps=cp.half_angle) as half:
        rho, ok = cp.log_radii(*_two_triangles(1.5, 1.6, 3.1))
    assert not ok
    assert half.call_count < 2 * NEWTON_STEPS

