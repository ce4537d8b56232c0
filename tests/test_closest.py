"""Closest points on triangle meshes (surfidx.geometry.closest), degenerate triangles included."""

import numpy as np
import pytest

from surfidx import InputError
from surfidx.geometry.closest import closest_points


def _segment_distance(p, a, b):
    ab = b - a
    den = float(ab @ ab)
    t = 0.0 if den == 0 else float(np.clip((p - a) @ ab / den, 0.0, 1.0))
    return float(np.linalg.norm(p - (a + t * ab)))


@pytest.mark.parametrize("tri", [[0, 1, 2], [1, 2, 0], [2, 0, 1], [0, 2, 2], [0, 0, 1]])
@pytest.mark.parametrize("middle", [[0.0, 0, 0], [0.5, 0.25, 0.1]])
def test_degenerate_triangles_give_the_closest_point_of_what_is_left(tri, middle):
    # corner 1 on corner 0 (a collapsed edge, as coarse quantisation makes them) or half-way
    # to corner 2 (collinear corners)
    rng = np.random.default_rng(3)
    v = np.array([[0.0, 0, 0], middle, [1.0, 0.5, 0.2]])
    f = np.array([tri])
    pts = rng.normal(size=(200, 3))
    face, bary, dist = closest_points(pts, v, f)
    assert np.isfinite(bary).all() and np.allclose(bary.sum(axis=1), 1.0)
    assert (bary >= 0).all()
    corners = v[f[0]]   # flat: its closest point lies on one of its edges
    want = np.array([min(_segment_distance(p, corners[i], corners[(i + 1) % 3])
                         for i in range(3)) for p in pts])
    assert np.allclose(dist, want, atol=1e-12)
    got = np.einsum("nc,ncd->nd", bary, v[f[face]])
    assert np.allclose(np.linalg.norm(got - pts, axis=1), dist, atol=1e-12)


def test_closest_points_checks_its_input():
    v = np.eye(3)
    with pytest.raises(InputError, match="faces is empty"):
        closest_points(np.zeros((1, 3)), v, np.zeros((0, 3), np.int64))
    with pytest.raises(InputError, match=r"faces index vertices outside 0\.\.2"):
        closest_points(np.zeros((1, 3)), v, [[0, 1, 3]])


def _grid_with_sliver(n, sliver):
    """An n x n vertex grid of small triangles in z = 0 plus one triangle ``sliver`` (3, 3)."""
    xs, ys = np.meshgrid(np.arange(n, dtype=float), np.arange(n, dtype=float))
    v = np.column_stack([xs.ravel(), ys.ravel(), np.zeros(n * n)])
    i = (np.arange(n - 1)[:, None] * n + np.arange(n - 1)[None, :]).ravel()
    f = np.concatenate([np.column_stack([i, i + 1, i + n]), np.column_stack([i + 1, i + n + 1, i + n])])
    v = np.vstack([v, sliver])
    f = np.vstack([f, [[n * n, n * n + 1, n * n + 2]]]).astype(np.int64)
    return v, f


def _brute_force(points, v, f):
    from surfidx.geometry.closest import project_to_candidates
    cand = np.broadcast_to(np.arange(len(f)), (len(points), len(f))).copy()
    return project_to_candidates(points, cand, v, f)


def test_one_long_sliver_and_far_points_give_the_exact_closest_points():
    # a grid of small triangles plus one sliver 1,000 times longer (as a restored mesh can hold):
    # the sliver is tried for every point apart, and points far off the surface widen their
    # search in chunks; every answer equals the brute-force one
    rng = np.random.default_rng(7)
    v, f = _grid_with_sliver(30, [[-500.0, 3.0, 2.0], [500.0, 3.2, 2.0], [0.0, 3.1, 2.5]])
    pts = np.vstack([rng.uniform([-5, -5, -3], [35, 35, 3], (300, 3)),
                     rng.uniform(-200, 200, (20, 3))])
    face, bary, dist = closest_points(pts, v, f, candidates=4)
    _, _, d2 = _brute_force(pts, v, f)
    np.testing.assert_allclose(dist, np.sqrt(d2), rtol=0, atol=1e-9)
    hit = (bary[:, :, None] * v[f[face]]).sum(axis=1)
    np.testing.assert_allclose(np.linalg.norm(hit - pts, axis=1), dist, atol=1e-9)
    assert (face == len(f) - 1).any()     # the sliver is the closest for some points


def test_a_long_sliver_does_not_widen_every_search():
    # 10,000 points over a 5,000-triangle grid with one sliver across it: the search stays
    # local (a ball as wide as the sliver for every point would take gigabytes)
    import tracemalloc
    rng = np.random.default_rng(3)
    v, f = _grid_with_sliver(51, [[-1000.0, 25.0, 1.0], [1000.0, 25.5, 1.0], [0.0, 25.2, 1.5]])
    pts = rng.uniform([0, 0, -2], [50, 50, 2], (10_000, 3))
    closest_points(pts[:10], v, f)          # compiled kernels loaded outside the measurement
    tracemalloc.start()
    try:
        face, _, dist = closest_points(pts, v, f)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 300e6
    assert np.all(dist <= np.abs(pts[:, 2]) + 1e-9)
