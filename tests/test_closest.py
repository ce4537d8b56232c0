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
