"""The icosahedral grid: ordering, topology, butterfly stencils, the zerotree forest."""

from __future__ import annotations


import numpy as np
import pytest

from surfidx import InputError
from surfidx.geometry.icosphere import (BUTTERFLY_WEIGHTS, MAX_LEVEL, SPARSE_MAX_LEVEL, Icosphere,
                                        choose_level, icosphere, vertex_count)

LEVELS = range(0, 6)


@pytest.mark.parametrize("level", LEVELS)
def test_counts_and_unit_vertices(level):
    ico = icosphere(level)
    n = 10 * 4 ** level + 2
    assert ico.vertices.shape == (n, 3) and ico.vertices.dtype == np.float64
    assert ico.faces.shape == (20 * 4 ** level, 3) and ico.faces.dtype == np.int64
    assert ico.counts.tolist() == [vertex_count(j) for j in range(level + 1)]
    np.testing.assert_allclose(np.linalg.norm(ico.vertices, axis=1), 1.0, atol=1e-14)
    assert len(np.unique(np.round(ico.vertices, 12), axis=0)) == n


@pytest.mark.parametrize("level", range(1, 6))
def test_prefix_property_and_midpoints(level):
    fine, coarse = icosphere(level), icosphere(level - 1)
    np.testing.assert_array_equal(fine.vertices[:coarse.n_vertices], coarse.vertices)
    new = np.arange(coarse.n_vertices, fine.n_vertices)
    a, b = fine.edge_parents[new].T
    assert np.all(a < b) and np.all(b < coarse.n_vertices)
    mid = coarse.vertices[a] + coarse.vertices[b]
    np.testing.assert_allclose(fine.vertices[new], mid / np.linalg.norm(mid, axis=1)[:, None],
                               atol=1e-15)
    # new vertices follow the coarse edges in (lo, hi) order
    np.testing.assert_array_equal(fine.edge_parents[new], coarse.edges)
    assert np.all(fine.level_of[new] == level) and np.all(fine.level_of[:coarse.n_vertices]
                                                         == coarse.level_of)


@pytest.mark.parametrize("level", LEVELS)
def test_euler_characteristic_and_ccw_faces(level):
    ico = icosphere(level)
    v, f = ico.vertices, ico.faces
    assert ico.n_vertices - len(ico.edges) + len(f) == 2
    a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    orient = np.einsum("ij,ij->i", np.cross(b - a, c - a), a + b + c)
    assert np.all(orient > 0)
    # every vertex is used; valence 5 at the 12 roots, 6 elsewhere
    valence = np.diff(ico.neighbor_indptr)
    assert np.all(valence[:12] == 5) and np.all(valence[12:] == 6)


def test_neighbors_csr_symmetric_and_by_level():
    ico = icosphere(4)
    indptr, indices = ico.neighbors(2)
    assert len(indptr) == vertex_count(2) + 1
    rows = np.repeat(np.arange(len(indptr) - 1), np.diff(indptr))
    pairs = set(zip(rows.tolist(), indices.tolist()))
    assert all((j, i) in pairs for i, j in pairs)
    e = icosphere(2).edges
    assert pairs == set(map(tuple, e.tolist())) | set(map(tuple, e[:, ::-1].tolist()))
    with pytest.raises(InputError, match="at most the grid level 4"):
        ico.neighbors(5)


@pytest.mark.parametrize("level", range(1, 6))
def test_butterfly_stencil_structure(level):
    ico = icosphere(level)
    lo = ico.counts[-2]
    st = ico.butterfly[lo:]
    assert np.all(ico.butterfly[:12] == -1)
    np.testing.assert_array_equal(st[:, :2], ico.edge_parents[lo:])
    assert np.all(st < lo) and np.all(st >= 0)
    # 8 distinct vertices, also around the 12 valence-5 vertices
    s = np.sort(st, axis=1)
    assert np.all(s[:, 1:] != s[:, :-1])
    coarse = icosphere(level - 1)
    nb = coarse.neighbor_indptr, coarse.neighbor_indices

    def adjacent(p, q):
        out = np.empty(len(p), bool)
        for i, (x, y) in enumerate(zip(p.tolist(), q.tolist())):
            out[i] = y in nb[1][nb[0][x]:nb[0][x + 1]]
        return out

    a, b, c, d, e1, e2, e3, e4 = st[:200].T
    for p, q in [(a, c), (b, c), (a, d), (b, d), (b, e1), (c, e1), (c, e2), (a, e2),
                 (a, e3), (d, e3), (d, e4), (b, e4)]:
        assert adjacent(p, q).all()
    # c is on the left of a -> b (counter-clockwise triangle a, b, c)
    v = coarse.vertices
    left = np.einsum("ij,ij->i", np.cross(v[b] - v[a], v[c] - v[a]), v[a])
    assert np.all(left > 0)


def test_butterfly_weights_and_smooth_prediction():
    assert BUTTERFLY_WEIGHTS.sum() == 1.0
    ico = icosphere(7)
    v = ico.vertices
    f = np.exp(v[:, 0] + 0.5 * v[:, 1]) + v[:, 2] ** 2
    rms_bf, rms_mid = [], []
    for j in range(1, 7):
        lo, hi = ico.counts[j], ico.counts[j + 1]
        st = ico.butterfly[lo:hi]
        rms_bf.append(np.sqrt(np.mean((f[lo:hi] - f[st] @ BUTTERFLY_WEIGHTS) ** 2)))
        rms_mid.append(np.sqrt(np.mean((f[lo:hi] - f[st[:, :2]].mean(1)) ** 2)))
    rms_bf = np.array(rms_bf)
    # constants are reproduced exactly
    const = np.full(len(v), 3.25)
    assert np.abs(const[ico.butterfly[12:]] @ BUTTERFLY_WEIGHTS - 3.25).max() < 1e-14
    # errors decay at least by 2.5x per level and are tiny at the finest
    assert np.all(rms_bf[1:] < rms_bf[:-1] / 2.5)
    assert rms_bf[-1] < 2e-4 * np.abs(f).max()
    # at coarse levels the butterfly beats the two-point midpoint predictor
    assert np.all(rms_bf[:3] < 0.6 * np.array(rms_mid[:3]))


@pytest.mark.parametrize("level", range(0, 6))
def test_zerotree_forest(level):
    ico = icosphere(level)
    n = ico.n_vertices
    parent = ico.tree_parent
    assert np.all(parent[:12] == -1) and np.all(parent[12:] >= 0)
    assert np.all(ico.level_of[parent[12:]] == ico.level_of[12:] - 1)
    # the child lies on an edge of its parent: the parent is adjacent to one edge parent ...
    # precisely, the child splits a level-j edge that has the parent as an endpoint
    kids = np.arange(12, n)
    ep = ico.edge_parents[kids]
    assert np.all((ep[:, 0] == parent[kids]) | (ep[:, 1] == parent[kids]))
    # CSR children: the inverse of tree_parent, each vertex exactly once
    counts = np.diff(ico.children_indptr)
    assert counts.sum() == n - 12
    assert np.array_equal(np.sort(ico.children_indices), kids)
    for v in [0, 5, 11, min(n - 1, 40), n - 1]:
        ch = ico.children(v)
        assert np.all(parent[ch] == v) and np.all(np.diff(ch) > 0)
    # traversal from the 12 roots reaches every vertex exactly once
    seen = np.zeros(n, int)
    frontier = np.arange(12)
    while len(frontier):
        seen[frontier] += 1
        frontier = np.concatenate([ico.children(v) for v in frontier] + [np.empty(0, np.int64)])
    assert np.all(seen == 1)
    # 4 children for every vertex born at 1 <= j < level; roots own 2 or 3
    inner = (ico.level_of >= 1) & (ico.level_of < level)
    assert np.all(counts[inner] == 4)
    assert np.all(counts[ico.level_of == level] == 0)
    if level >= 1:
        assert set(counts[:12].tolist()) <= {2, 3} and counts[:12].sum() == 30


def test_zerotree_owner_rule():
    """Half-edges go to their midpoint, inner edges cyclically around each inner triangle."""
    fine = icosphere(3)
    j = 2
    coarse = icosphere(j)
    m = coarse.n_vertices
    new = np.arange(m, fine.n_vertices)
    a, b = fine.edge_parents[new].T
    both_new = (fine.level_of[a] == j) & (fine.level_of[b] == j)
    one_new = (fine.level_of[a] == j) ^ (fine.level_of[b] == j)
    assert np.all(both_new | one_new)
    owner_half = np.where(fine.level_of[a] == j, a, b)
    assert np.all(fine.tree_parent[new[one_new]] == owner_half[one_new])
    inner = coarse.faces[3::4]
    owned = {(int(x), int(y)): int(x) for x, y in np.concatenate(
        [inner[:, [0, 1]], inner[:, [1, 2]], inner[:, [2, 0]]])}
    for v, p, q in zip(new[both_new][:300], a[both_new][:300], b[both_new][:300]):
        own = owned.get((int(p), int(q)), owned.get((int(q), int(p))))
        assert fine.tree_parent[v] == own


def test_cache_readonly_and_errors():
    assert icosphere(3) is icosphere(3)
    with pytest.raises(ValueError):
        icosphere(3).vertices[0, 0] = 2.0
    with pytest.raises(InputError, match="at most 9"):
        icosphere(MAX_LEVEL + 1)
    with pytest.raises(InputError, match="at least 0"):
        icosphere(-1)
    with pytest.raises(InputError, match="must be an integer"):
        Icosphere(2.5)


def test_construction_from_scratch_level8():
    ico = Icosphere(0)
    for level in range(1, 9):  # from scratch, bypassing the cache
        ico = Icosphere(level, _coarser=ico)
    assert ico.n_vertices == 655_362 and ico.butterfly.shape == (655_362, 8)


def test_choose_level():
    assert choose_level(1) == 0
    assert choose_level(3) == 0                 # 12 >= 4 * 3
    assert choose_level(4) == 1                 # 12 < 16
    assert choose_level(40_000) == 7            # 163,842 >= 160,000
    assert choose_level(41_000) == 8            # 163,842 < 164,000
    assert choose_level(134_345) == 8           # Igea: 655,362 >= 537,380
    assert choose_level(100_000, oversampling=1.0) == 7
    assert choose_level(10 ** 9) == MAX_LEVEL
    assert choose_level(10 ** 9, max_level=6) == 6
    # a map that squeezes part of the surface: one level more when its sparsest-mapped surfels
    # get under SPARSE_MIN grid points each (homer: 6,002 surfels, sparse sampling ~0.03) ...
    assert choose_level(6002) == 6 and choose_level(6002, sparse_sampling=0.03) == 7
    assert choose_level(6002, sparse_sampling=0.08) == 6     # 40,962 * 0.08 >= 0.5 * 6,002
    assert choose_level(6002, sparse_sampling=0.07) == 7
    # ... and never more than one
    assert choose_level(6002, sparse_sampling=1e-6) == 7
    assert choose_level(6002, sparse_sampling=0.0) == 7     # squeezed to nothing
    assert choose_level(10 ** 9, sparse_sampling=1e-6) == MAX_LEVEL
    # ... nor beyond SPARSE_MAX_LEVEL (scorpion: 50,653 surfels, level 8 by the count, sparse
    # sampling ~0.035); the count alone still reaches level 9
    assert choose_level(50_653, sparse_sampling=0.035) == SPARSE_MAX_LEVEL == 8
    assert choose_level(15_496, sparse_sampling=0.03) == 8      # d019: 7 by the count
    assert choose_level(170_000, sparse_sampling=0.035) == 9
    with pytest.raises(InputError, match="sparse_sampling must lie in"):
        choose_level(10, sparse_sampling=-0.1)
    with pytest.raises(InputError, match="n_surfels must be at least 1"):
        choose_level(0)
    with pytest.raises(InputError, match="oversampling must be a positive"):
        choose_level(10, oversampling=0)
    with pytest.raises(InputError, match="max_level must be at most 9"):
        choose_level(10, max_level=12)


def test_level_of_count_inverts_vertex_count():
    from surfidx.geometry.icosphere import level_of_count

    for level in range(MAX_LEVEL + 1):
        assert level_of_count(vertex_count(level)) == level
    assert level_of_count(vertex_count(3) + 1) is None
    assert level_of_count(11) is None and level_of_count(0) is None


def test_icosphere_imports_without_scipy():
    """Counting grid vertices (the container, the CLI's ``info``) imports no scipy."""
    import subprocess
    import sys

    code = "import sys, surfidx.geometry.icosphere, surfidx.codec.container; print('scipy' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


@pytest.mark.parametrize("level", [1, 2, 5])
def test_subdivided_half_edges_match_a_sort(level):
    """A subdivided level's twins follow from the coarser level's without a sort: each is the
    reversed half-edge (an involution swapping tail and head), the same the sort finds; the edges
    are the lo -> hi half-edges in lexicographic order, each half-edge numbered by its edge."""
    from surfidx.geometry.icosphere import twins_by_sorting

    ico = icosphere(level)
    he = ico._half_edges
    assert np.array_equal(he.twin[he.twin], np.arange(len(he.twin)))
    assert np.array_equal(he.tail[he.twin], he.head) and np.array_equal(he.head[he.twin], he.tail)
    assert np.array_equal(he.twin, twins_by_sorting(he.tail, he.head, ico.n_vertices))
    key = he.edges[:, 0] * ico.n_vertices + he.edges[:, 1]
    assert (he.edges[:, 0] < he.edges[:, 1]).all() and (np.diff(key) > 0).all()
    assert np.array_equal(he.edges[he.edge], np.sort(np.column_stack([he.tail, he.head]), axis=1))



@pytest.mark.parametrize("level", [0, 1, 4])
def test_face_neighbors_share_the_edge_opposite_each_corner(level):
    """``face_neighbors[f, j]`` is the face that holds the edge opposite corner ``j`` of face
    ``f`` reversed (the grid is closed and every face counter-clockwise)."""
    ico = icosphere(level)
    f, nbr = np.asarray(ico.faces), ico.face_neighbors
    assert nbr.shape == f.shape and nbr.dtype == np.int64 and not nbr.flags.writeable
    directed = {(int(a), int(b)): k for k, row in enumerate(f)
                for a, b in ((row[0], row[1]), (row[1], row[2]), (row[2], row[0]))}
    for k, row in enumerate(f):
        for j in range(3):
            a, b = int(row[(j + 1) % 3]), int(row[(j + 2) % 3])
            assert nbr[k, j] == directed[(b, a)] != k

def test_spherical_triangle_areas_of_a_grid_are_blocked_without_changing_a_bit():
    """Over more triangles than one block, ``triangle_areas`` gives each triangle the value of
    the whole-array formula to the bit; a grid's areas are positive and sum to 4π, and its
    vertex areas (a third of each incident triangle's) too."""
    from surfidx.geometry.unitsphere import triangle_areas

    ico = icosphere(6)
    pts, tri = ico.vertices, ico.faces
    assert len(tri) > 1 << 16                    # more than one block of triangle_areas
    a, b, c = pts[tri[:, 0]], pts[tri[:, 1]], pts[tri[:, 2]]
    num = np.einsum("ij,ij->i", a, np.cross(b, c))
    den = 1.0 + np.einsum("ij,ij->i", a, b) + np.einsum("ij,ij->i", b, c) \
        + np.einsum("ij,ij->i", c, a)
    whole = 2.0 * np.arctan2(num, den)
    area = triangle_areas(pts, tri)
    assert np.array_equal(area, whole)
    assert area.min() > 0 and area.sum() == pytest.approx(4 * np.pi, rel=1e-12)
    assert ico.vertex_areas().sum() == pytest.approx(4 * np.pi, rel=1e-12)
