"""Local repair of folded Delaunay triangles: fewer folds, never more, no inverted mesh triangle."""

import numpy as np
import pytest

from surfidx import TriangleMesh
from surfidx.sphere import MapOptions
from surfidx.sphere.foldrepair import repair_folds
from surfidx.sphere.multilevel import mesh_map
from surfidx.sphere.surface import oriented_faces as _oriented_faces
from surfidx.geometry.unitsphere import folded_mask, hull_triangles, orientation as _orientation

from conftest import tube_mesh


@pytest.fixture(scope="module")
def tube_map():
    """A tube 75 girths long, mapped without the repair: its rows fold."""
    s = TriangleMesh(*tube_mesh(k=8, m=60, h=0.8), name="tube").to_surfels()
    x, _, _ = mesh_map(s, options=MapOptions(), iterations=40, gamma=0.15, balance=True)
    return s, _oriented_faces(s), x


def _folds(s, x):
    return int(folded_mask(s.positions, s.normals, hull_triangles(x)).sum())


def test_repair_lowers_folds_and_keeps_the_mesh_fold_free(tube_map):
    s, f, x = tube_map
    before = _folds(s, x)
    assert before > 0 and np.all(_orientation(x, f) > 0)
    y, info = repair_folds(x, s.positions, s.normals, f)
    assert info["folds_before"] == before
    assert info["folds"] == _folds(s, y) < before
    assert np.all(_orientation(y, f) > 0)                  # no mesh triangle inverted
    np.testing.assert_allclose(np.linalg.norm(y, axis=1), 1.0, atol=1e-12)
    moved = np.linalg.norm(y - x, axis=1) > 0
    # a vertex may move in several rounds; each move the search keeps removes a fold or more
    assert 0 < moved.sum() <= info["moved"] + info.get("searched", 0)


def test_repair_on_a_triangulation_with_isolated_vertices(tube_map):
    """A point cloud's repair mesh (its Delaunay triangulation less the folded triangles) can
    leave a fold's corner with no triangle: moves needing its neighbours are skipped, never NaN."""
    s, _, x = tube_map
    tri = hull_triangles(x)
    bad = folded_mask(s.positions, s.normals, tri)
    lonely = np.unique(tri[bad])
    mesh = tri[~bad & ~np.isin(tri, lonely).any(axis=1)]
    y, info = repair_folds(x, s.positions, s.normals, mesh)
    assert np.all(np.isfinite(y))
    assert info["folds"] == _folds(s, y) <= info["folds_before"] == int(bad.sum())


def test_second_pass_never_adds_folds_or_inverts_the_mesh(tube_map):
    """The second repair pass (the unfolded Delaunay triangles kept embedded too) ends with at
    most the first pass's folds and every mesh triangle still counter-clockwise; without its
    search, the first pass's result is where it starts."""
    from surfidx.sphere.repair import repair

    s, f, x = tube_map
    x1, (r1,), _ = repair(x, s, options=MapOptions(second_pass=False, realise=False), mesh=f)
    x2, (r2,), located = repair(x, s, options=MapOptions(realise=False), mesh=f)
    assert r1 == ("repair", dict(r1[1], second_pass=0))
    assert _folds(s, x2) <= _folds(s, x1)
    assert r2[1]["folds_repaired"] >= r1[1]["folds_repaired"]
    assert r2[1]["folds_repaired"] - r2[1]["second_pass"] == r1[1]["folds_repaired"]
    assert np.all(_orientation(x2, f) > 0)


def test_repair_without_search_stops_after_the_rounds(tube_map):
    s, f, x = tube_map
    _, searched = repair_folds(x, s.positions, s.normals, f)
    _, info = repair_folds(x, s.positions, s.normals, f, search=False)
    assert "searched" in searched and "searched" not in info
    assert info["folds"] >= searched["folds"]


def test_repair_leaves_a_fold_free_map_alone(sphere_surfels):
    s = sphere_surfels
    f = _oriented_faces(s)
    y, info = repair_folds(s.positions, s.positions, s.normals, f)
    assert info == {"folds_before": 0, "folds": 0, "rounds": 0, "moved": 0}
    np.testing.assert_array_equal(y, s.positions)


def test_folded_mask_does_not_depend_on_the_listed_corner():
    """Triangles straight in 3D (the rows of a squeezed limb) are judged alike from any of
    their three cyclic listings: rounding in the cross product must not turn a fold over."""
    from surfidx.geometry.unitsphere import against_normals

    rng = np.random.default_rng(7)
    a, b = rng.normal(size=(500, 3)), rng.normal(size=(500, 3))
    t = rng.uniform(0.1, 0.9, size=(500, 1))
    p = np.concatenate([a, b, a + t * (b - a) + 1e-17 * rng.normal(size=(500, 3))])
    normals = rng.normal(size=p.shape)
    tri = np.arange(1500).reshape(3, 500).T
    masks = [against_normals(p, normals, np.roll(tri, k, axis=1)) for k in range(3)]
    assert np.array_equal(masks[0], masks[1]) and np.array_equal(masks[0], masks[2])


def test_smallest_first_keeps_each_triangles_cycle():
    from surfidx.geometry.unitsphere import smallest_first

    t = np.array([[5, 2, 9], [2, 9, 5], [9, 5, 2], [3, 1, 2]])
    np.testing.assert_array_equal(smallest_first(t), [[2, 9, 5]] * 3 + [[1, 2, 3]])
    assert smallest_first(np.empty((0, 3), np.int64)).shape == (0, 3)


def test_folded_mask_ignores_a_global_mirror(sphere_surfels):
    s = sphere_surfels
    tri = hull_triangles(s.positions)
    assert not folded_mask(s.positions, s.normals, tri).any()
    assert not folded_mask(s.positions, s.normals, tri[:, [0, 2, 1]]).any()   # all mirrored


@pytest.mark.parametrize("seed", range(6))
def test_local_delaunay_update_equals_the_global_hull(seed):
    """Moving a few vertices, the locally updated triangulation is the convex hull of the moved
    map, and its folded mask that of the hull (random points: no cocircular ties); the count
    alone (:meth:`Hull.folds_if_moved`) agrees."""
    from surfidx.sphere.foldrepair import Hull

    rng = np.random.default_rng(seed)
    x = rng.normal(size=(2000, 3))
    x /= np.linalg.norm(x, axis=1)[:, None]
    p = x * rng.uniform(0.5, 1.5, size=(2000, 1))          # a bumpy star-shaped surface
    normals = x + 0.5 * rng.normal(size=x.shape)             # some folds
    state = Hull(x, p, normals)
    k = [10, 1, 3][seed % 3]         # many moved vertices (KD-tree tests) or a few (direct tests)
    for _ in range(2):               # from the start, then from the accepted result (new caches)
        moved = np.zeros(len(x), bool)
        moved[rng.choice(len(x), k, replace=False)] = True
        y = x.copy()
        y[moved] += [0.005, 0.05][seed % 2] * rng.normal(size=(k, 3))
        y /= np.linalg.norm(y, axis=1)[:, None]
        count = state.folds_if_moved(x, y, moved)      # the count alone, asked first
        tri, bad = state.moved(x, y, moved)
        assert count == np.count_nonzero(bad)
        ref = hull_triangles(y)
        assert {tuple(sorted(t)) for t in tri.tolist()} == {tuple(sorted(t)) for t in ref.tolist()}
        got = {tuple(sorted(t)) for t in tri[bad].tolist()}
        want = ref[folded_mask(p, normals, ref)]
        assert len(want) > 0 and got == {tuple(sorted(t)) for t in want.tolist()}
        x, state.tri, state.bad = y, tri, bad


@pytest.mark.parametrize("k", [3, 10])
def test_local_update_holds_where_circles_are_small(k):
    """Circumcircles of 1e-4 on the unit sphere: the corners of a cavity triangle lie on its
    circle only up to rounding (a few 1e-10 of the radius), so the test of the circles against
    the map's points skips the corners; testing them too refuses the local update, which falls
    back to the global hull."""
    from surfidx.sphere.foldrepair import Hull

    rng = np.random.default_rng(k)
    x = np.vstack([rng.normal(size=(500, 3)), [0, 0, 1] + 1e-3 * rng.normal(size=(1500, 3))])
    x /= np.linalg.norm(x, axis=1)[:, None]
    state = Hull(x, x, x + 0.3 * rng.normal(size=x.shape))
    fallbacks = 0
    for _ in range(5):
        moved = np.zeros(len(x), bool)
        moved[500 + rng.choice(1500, k, replace=False)] = True
        y = x.copy()
        y[moved] += 1e-5 * rng.normal(size=(k, 3))
        y /= np.linalg.norm(y, axis=1)[:, None]
        fallbacks += state._cavity(x, y, moved)[1] is None
        tri, _ = state.moved(x, y, moved)
        ref = hull_triangles(y)
        assert {tuple(sorted(t)) for t in tri.tolist()} == {tuple(sorted(t)) for t in ref.tolist()}
    assert fallbacks == 0


def test_random_search_removes_folds_deterministically(tube_map):
    """The final random search (run when the move rounds leave few folds) keeps only moves that
    lower the fold count and invert no mesh triangle, and is seeded."""
    from surfidx.sphere.foldrepair import Hull, Mesh, random_search

    s, f, x = tube_map
    results = []
    for _ in range(2):
        state = Hull(x, s.positions, s.normals)
        before = int(state.bad.sum())
        y, removed = random_search(x, state, Mesh(f, len(x)), trials=MapOptions().search_trials,
                             work=MapOptions().search_work)
        assert removed >= 1 and _folds(s, y) == before - removed == int(state.bad.sum())
        assert np.all(_orientation(y, f) > 0)
        results.append(y)
    np.testing.assert_array_equal(results[0], results[1])


def test_search_trial_moves_by_its_share_of_the_edge_length(tube_map):
    """A search trial moves the vertex along the tangent part of its random direction by the
    drawn share of its mean mesh-edge length on the sphere, and is refused exactly when one of
    the vertex's mesh triangles would turn over (against the orientation of the whole map)."""
    from surfidx.sphere.foldrepair import Mesh, trial_move
    from surfidx.geometry.unitsphere import corner_orientation

    s, f, x = tube_map
    mesh = Mesh(f, len(x))
    adj, vf = mesh.adj, mesh.vf
    rng = np.random.default_rng(5)
    refused = 0
    for _ in range(300):
        v = int(rng.integers(len(x)))
        d, share = rng.standard_normal(3), float(rng.uniform(0.05, 3.0))
        new = trial_move(x, v, d, share, adj.indptr, adj.indices, vf.indptr, vf.indices, f)
        nb = adj.indices[adj.indptr[v]:adj.indptr[v + 1]]
        h = np.mean(np.linalg.norm(x[nb] - x[v], axis=1))
        t = d - (d @ x[v]) * x[v]
        want = x[v] + t / np.linalg.norm(t) * h * share
        want /= np.linalg.norm(want)
        faces = f[vf.indices[vf.indptr[v]:vf.indptr[v + 1]]]
        corners = x[faces]
        corners[faces == v] = want
        if np.any(corner_orientation(corners) <= 0):
            assert new is None
            refused += 1
        else:
            np.testing.assert_allclose(new, want, rtol=0, atol=1e-14)
    assert 0 < refused < 300          # both outcomes met


def test_parameterize_reports_the_repair(tube_map):
    from surfidx.sphere import parameterize

    s, _, x = tube_map
    m = parameterize(s, stress=False)
    assert m.info["folds_repaired"] >= 1 and m.info["mesh_folds"] == 0
    assert m.folded == _folds(s, m.points)


def test_blocked_move_is_halved_then_undone(sphere_surfels):
    """A move past a neighbour inverts mesh triangles: it is halved until none is inverted, or
    undone when halving is not allowed."""
    from surfidx.sphere.foldrepair import Mesh

    s = sphere_surfels
    f = _oriented_faces(s)
    x = s.positions
    mesh = Mesh(f, len(x))
    v = 0
    u = mesh.adj[v].indices[0]
    for halvings, kept in ((3, True), (0, False)):
        y = x.copy()
        y[v] = x[v] + 1.5 * (x[u] - x[v])          # past its neighbour u
        y[v] /= np.linalg.norm(y[v])
        moved = np.zeros(len(x), bool)
        moved[v] = True
        assert np.any(_orientation(y, f) <= 0)
        moved = mesh.undo_inverting(x, y, moved, halvings=halvings)
        assert moved[v] == kept and np.all(_orientation(y, f) > 0)
        if kept:     # moved part of the way towards u, not past it
            assert 0 < np.linalg.norm(y[v] - x[v]) < np.linalg.norm(x[u] - x[v])
        else:
            np.testing.assert_array_equal(y[v], x[v])
