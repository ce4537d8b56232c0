"""Density weighting: the field, its storage round trip, its interpolation and its errors."""

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from surfidx import BitstreamError, InputError
from surfidx.codec.density import (MAX_FIELD_LEVEL, Q_MAX, Q_MIN, SURFELS_PER_FIELD_VERTEX,
                             field_level, pack_field, relative_density, unpack_field,
                             vertex_scales, weight_field, weighting_gain)
from surfidx.geometry.icosphere import icosphere, vertex_count


def _uniform_sphere(n, seed=0):
    p = np.random.default_rng(seed).normal(size=(n, 3))
    return p / np.linalg.norm(p, axis=1, keepdims=True)


def test_relative_density_has_mean_one_and_sees_crowding():
    u = _uniform_sphere(1_000_000)
    d = relative_density(u, 2)
    from scipy.spatial import SphericalVoronoi

    a = SphericalVoronoi(icosphere(2).vertices).calculate_areas()
    assert abs(a @ d / a.sum() - 1) < 1e-12          # exactly: every point is in one cell
    assert np.all(np.abs(d - 1) < 0.06)   # uniform points: flat (Poisson noise 1.3 %)
    crowded = np.vstack([u, np.tile([[0.0, 0.0, 1.0]], (250_000, 1))])
    d2 = relative_density(crowded, 2)
    top = int(np.argmax(icosphere(2).vertices[:, 2]))
    assert np.argmax(d2) == top and d2[top] > 10 * np.median(d2)


def test_field_level_follows_the_surfel_count():
    assert field_level(10, 9) == 0
    assert field_level(vertex_count(3) * SURFELS_PER_FIELD_VERTEX, 9) == 3
    assert field_level(vertex_count(3) * SURFELS_PER_FIELD_VERTEX - 1, 9) == 2
    assert field_level(10 ** 7, 9) == MAX_FIELD_LEVEL
    assert field_level(10 ** 7, 2) == 2                # never finer than the grid


def test_weight_field_is_flat_for_even_sampling_and_gain_follows():
    u = _uniform_sphere(100_000, seed=1)
    q = weight_field(u, 3)
    assert np.all(q == 0) and weighting_gain(q, 3) == pytest.approx(0.0, abs=1e-12)
    # half the points crowded into one cap: the gain estimate is large and positive
    cap = u[u[:, 2] > 0.9]
    q2 = weight_field(np.vstack([u, np.repeat(cap, 20, axis=0)]), 3)
    assert q2.max() >= 2 and q2.min() <= 0
    assert weighting_gain(q2, 3) > 1.0
    assert np.all(weight_field(u, 3, mix=0.0) == 0)


@settings(max_examples=40, deadline=None)
@given(level=st.integers(0, MAX_FIELD_LEVEL), seed=st.integers(0, 2 ** 32 - 1),
       smooth=st.booleans())
def test_pack_unpack_round_trip(level, seed, smooth):
    rng = np.random.default_rng(seed)
    n = vertex_count(level)
    if smooth:
        v = icosphere(level).vertices
        q = np.clip(np.rint(4 * v[:, 0] + 2 * v[:, 1] ** 2), Q_MIN, Q_MAX).astype(np.int64)
    else:
        q = rng.integers(Q_MIN, Q_MAX + 1, size=n)
    data = pack_field(q, level)
    q2, level2 = unpack_field(data)
    assert level2 == level and np.array_equal(q, q2)
    if smooth and level >= 3:
        assert len(data) < n / 4                      # a smooth field codes compactly


def test_vertex_scales_interpolate_in_the_log_domain():
    q = np.arange(12) % 5 - 2
    s = vertex_scales(q, 0, 3)
    assert s.shape == (vertex_count(3),)
    np.testing.assert_allclose(s[:12], 2.0 ** (0.5 * q), rtol=1e-15)
    ep = icosphere(3).edge_parents
    m = np.arange(12, vertex_count(3))
    np.testing.assert_allclose(np.log2(s[m]), 0.5 * (np.log2(s[ep[m, 0]]) + np.log2(s[ep[m, 1]])),
                               atol=1e-13)
    np.testing.assert_array_equal(vertex_scales(np.zeros(42), 1, 1), np.ones(42))


def test_errors():
    with pytest.raises(InputError, match="level must be 0 … 4"):
        pack_field(np.zeros(12), 5)
    with pytest.raises(InputError, match=r"values must lie in \[-3, 12\]"):
        pack_field(np.full(12, 13), 0)
    with pytest.raises(InputError, match="field must have shape"):
        pack_field(np.zeros(13), 0)
    with pytest.raises(InputError, match="mix must be in"):
        weight_field(_uniform_sphere(100), 1, mix=1.5)
    with pytest.raises(InputError, match="field's level 3 must be 0 … the grid level 2"):
        vertex_scales(np.zeros(642), 3, 2)
    with pytest.raises(BitstreamError, match="f.sfz: corrupt density-weight field"):
        unpack_field(b"\x07abc", path="f.sfz")
    with pytest.raises(BitstreamError, match="corrupt density-weight field"):
        unpack_field(b"")
    # garbage after a valid level byte decodes to something, but never outside the range
    rng = np.random.default_rng(3)
    for _ in range(50):
        junk = bytes([int(rng.integers(0, 5))]) + rng.integers(0, 256, 40, dtype=np.uint8).tobytes()
        try:
            q, level = unpack_field(junk)
        except BitstreamError:
            continue
        assert len(q) == vertex_count(level) and Q_MIN <= q.min() and q.max() <= Q_MAX


def test_impossible_and_out_of_range_fields_are_refused():
    from surfidx.codec.density import N_CONTEXTS, encode_residuals
    from surfidx.codec.entropy import new_encoder, new_models

    with pytest.raises(BitstreamError, match="impossible code"):
        unpack_field(b"\x00\xff\xff\xff\xff\x00")
    # residuals that leave the stored range: 15 on every level-0 vertex (the coder allows it)
    r = np.full(12, 15, np.int64)
    buf = np.zeros(256, np.uint8)
    size = encode_residuals(r, np.zeros(12, np.int64), buf, new_encoder(), new_models(N_CONTEXTS))
    with pytest.raises(BitstreamError, match="values out of range"):
        unpack_field(b"\x00" + bytes(buf[:size]))
