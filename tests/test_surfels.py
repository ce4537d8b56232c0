"""SurfelSet validation and transforms."""

import numpy as np
import pytest

from surfidx import InputError, SurfelSet


def _cloud(n=10, seed=0):
    rng = np.random.default_rng(seed)
    p = rng.normal(size=(n, 3))
    nrm = p / np.linalg.norm(p, axis=1)[:, None]
    return p, nrm, np.full(n, 0.1)


def test_valid_set_normalises_normals_and_keeps_values():
    p, n, r = _cloud()
    s = SurfelSet(p, n * (1 + 1e-5), r, np.zeros((10, 3), np.uint8), name="x")
    assert len(s) == 10 and s.has_color
    np.testing.assert_allclose(np.linalg.norm(s.normals, axis=1), 1.0, atol=1e-12)
    assert s.diagonal == pytest.approx(np.linalg.norm(p.max(0) - p.min(0)))


@pytest.mark.parametrize("mutate, match", [
    (lambda p, n, r: (np.where(np.arange(30).reshape(10, 3) == 4, np.nan, p), n, r), "NaN"),
    (lambda p, n, r: (p, n * 2, r), "unit length"),
    (lambda p, n, r: (p, n, -r), "radii must be positive"),
    (lambda p, n, r: (p, n[:5], r), r"normals must have shape \(10, 3\)"),
    (lambda p, n, r: (p[:, :2], n, r), r"positions must have shape \(n, 3\)"),
    (lambda p, n, r: (p, n, r[:3]), r"radii must have shape \(10,\)"),
])
def test_invalid_values_raise(mutate, match):
    with pytest.raises(InputError, match=match):
        SurfelSet(*mutate(*_cloud()))


def test_bad_colors_and_faces_raise():
    p, n, r = _cloud()
    with pytest.raises(InputError, match="0..255"):
        SurfelSet(p, n, r, np.full((10, 3), 300.0))
    with pytest.raises(InputError, match="colors must have shape"):
        SurfelSet(p, n, r, np.zeros((9, 3)))
    with pytest.raises(InputError, match="colors contain NaN"):
        SurfelSet(p, n, r, np.full((10, 3), np.nan))
    with pytest.raises(InputError, match="faces index surfels outside"):
        SurfelSet(p, n, r, faces=[[0, 1, 10]])


def test_empty_set_has_no_bounds():
    s = SurfelSet(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0))
    with pytest.raises(InputError, match="empty surfel set"):
        s.bounds


def test_transformed_rotates_normals_and_scales_radii():
    p, n, r = _cloud()
    q, _ = np.linalg.qr(np.random.default_rng(3).normal(size=(3, 3)))
    s = SurfelSet(p, n, r).transformed(q, [1, 2, 3], 2.5)
    np.testing.assert_allclose(s.positions, 2.5 * p @ q.T + [1, 2, 3])
    np.testing.assert_allclose(s.normals, n @ q.T, atol=1e-12)
    np.testing.assert_allclose(s.radii, 2.5 * r)
    with pytest.raises(InputError, match="orthogonal"):
        SurfelSet(p, n, r).transformed(np.ones((3, 3)))
    with pytest.raises(InputError, match="scale must be a positive"):
        SurfelSet(p, n, r).transformed(scale=0.0)


def test_subset_and_without_color():
    p, n, r = _cloud()
    s = SurfelSet(p, n, r, np.arange(30).reshape(10, 3))
    sub = s.subset([2, 5])
    np.testing.assert_array_equal(sub.positions, p[[2, 5]])
    np.testing.assert_array_equal(sub.colors, s.colors[[2, 5]])
    assert not s.without_color().has_color
