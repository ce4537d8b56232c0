"""Karhunen–Loève transform: exact inverse, decorrelation, ordering, invariances, storage, errors."""

from __future__ import annotations

import numpy as np
import pytest

from surfidx import TOL, BitstreamError, InputError
from surfidx.codec.klt import KLT


def _layers(n=2000, k=6, seed=0):
    rng = np.random.default_rng(seed)
    mix = rng.standard_normal((k, k))
    return rng.standard_normal((n, k)) * np.linspace(3, 0.2, k) @ mix + rng.uniform(-5, 5, k)


def _rotation(seed):
    q, r = np.linalg.qr(np.random.default_rng(seed).standard_normal((3, 3)))
    q *= np.sign(np.diag(r))
    return q if np.linalg.det(q) > 0 else -q


def test_exact_reconstruction_and_shapes():
    x = _layers()
    t = KLT.fit(x, weights=[1, 1, 1, 0.01, 0.01, 0.01])
    c = t.forward(x)
    assert c.shape == x.shape and t.k == 6
    assert t.mean.shape == (6,) and t.basis.shape == (6, 6) and t.eigenvalues.shape == (6,)
    assert np.abs(t.inverse(c) - x).max() < TOL.reconstruction
    np.testing.assert_allclose(t.basis @ t.basis.T, np.eye(6), atol=1e-12)


def test_decorrelation_and_ordering():
    x = _layers()
    t = KLT.fit(x)
    c = t.forward(x)
    cov = np.cov(c.T, bias=True)
    off = cov - np.diag(np.diag(cov))
    assert np.abs(off).max() < 1e-10 * cov.max()
    np.testing.assert_allclose(np.diag(cov), t.eigenvalues, rtol=1e-10)
    assert np.all(np.diff(t.eigenvalues) <= 0)
    np.testing.assert_allclose(c.mean(axis=0), 0, atol=1e-10)


def test_weights_trade_layers():
    """Down-weighting the colour layers moves them behind geometry in energy order."""
    rng = np.random.default_rng(2)
    geo = rng.standard_normal((3000, 3))
    col = rng.uniform(0, 255, (3000, 3))
    x = np.hstack([geo, col])
    heavy = KLT.fit(x)
    light = KLT.fit(x, weights=[1, 1, 1, 1 / 255, 1 / 255, 1 / 255])
    # the leading direction is colour with unit weights, geometry with colour scaled to [0, 1]
    assert np.abs(heavy.basis[0, 3:]).sum() > 0.99
    assert np.abs(light.basis[0, :3]).sum() > 0.99
    np.testing.assert_array_equal(light.weights, [1, 1, 1, 1 / 255, 1 / 255, 1 / 255])
    assert np.abs(light.inverse(light.forward(x)) - x).max() < TOL.reconstruction * 255


def test_rotation_covariance():
    rng = np.random.default_rng(4)
    pts = rng.standard_normal((1500, 3)) * [5.0, 2.0, 0.5]
    t = KLT.fit(pts)
    for seed in range(3):
        rot = _rotation(seed)
        tr = KLT.fit(pts @ rot.T + [1.0, -2.0, 3.0])
        np.testing.assert_allclose(tr.eigenvalues, t.eigenvalues, rtol=1e-10)
        # principal directions rotate with the data (up to sign)
        dots = np.abs(np.einsum("ij,ij->i", tr.basis, t.basis @ rot.T))
        np.testing.assert_allclose(dots, 1.0, atol=1e-8)


def test_sign_convention_deterministic():
    x = _layers(k=4, seed=5)
    t1 = KLT.fit(x)
    t2 = KLT.fit(-x[::-1] * 1.0)    # negated data: same directions up to sign, same convention
    for t in (t1, t2):
        idx = np.argmax(np.abs(t.basis), axis=1)
        assert np.all(t.basis[np.arange(4), idx] > 0)
    np.testing.assert_allclose(t1.basis, t2.basis, atol=1e-10)
    assert KLT.fit(x) == t1


def test_sample_weights():
    x = _layers(n=500, k=3)
    dup = np.vstack([x, x[:100]])
    w = np.ones(500)
    w[:100] = 2.0
    a = KLT.fit(x, sample_weights=w)
    b = KLT.fit(dup)
    np.testing.assert_allclose(a.mean, b.mean, atol=1e-12)
    np.testing.assert_allclose(a.eigenvalues, b.eigenvalues, rtol=1e-10)


def test_storage_round_trips():
    x = _layers()
    t = KLT.fit(x, weights=np.linspace(1, 2, 6))
    b = KLT.from_bytes(t.to_bytes())
    assert b == t
    np.testing.assert_array_equal(b.eigenvalues, t.eigenvalues)
    d = KLT.from_dict(t.to_dict())
    assert d == t
    # float32 storage (the container): encoder and decoder agree exactly on the rounded values
    f = t.as_float32()
    dec = KLT.from_arrays(f.mean.astype(np.float32), f.basis.astype(np.float32),
                          f.weights.astype(np.float32))
    assert np.abs(dec.inverse(f.forward(x)) - x).max() < TOL.reconstruction
    assert not np.isnan(f.eigenvalues).any()
    assert np.isnan(dec.eigenvalues).all()
    assert KLT.from_bytes(dec.to_bytes()) == dec


def test_bad_input():
    x = _layers(k=3)
    t = KLT.fit(x)
    with pytest.raises(InputError, match=r"layers must have shape \(n, n\)"):
        KLT.fit(np.zeros(10))
    with pytest.raises(InputError, match="layers needs at least 2 entries"):
        KLT.fit(np.zeros((1, 3)))
    bad = x.copy()
    bad[3, 1] = np.nan
    with pytest.raises(InputError, match="layers contains 1 NaN"):
        KLT.fit(bad)
    with pytest.raises(InputError, match=r"weights must have shape \(3,\)"):
        KLT.fit(x, weights=[1, 1])
    with pytest.raises(InputError, match="weights must be positive: weight 2"):
        KLT.fit(x, weights=[1, 1, 0])
    with pytest.raises(InputError, match="sample_weights must be non-negative"):
        KLT.fit(x, sample_weights=-np.ones(len(x)))
    with pytest.raises(InputError, match=r"layers must have shape \(n, 3\)"):
        t.forward(np.zeros((5, 4)))
    with pytest.raises(InputError, match=r"coeffs must have shape \(n, 3\)"):
        t.inverse(np.zeros(5))
    with pytest.raises(InputError, match="basis must be invertible"):
        KLT.from_arrays(np.zeros(2), np.ones((2, 2)), np.ones(2))
    with pytest.raises(InputError, match="lacks 'basis'"):
        KLT.from_dict({"mean": [0.0], "weights": [1.0]})
    with pytest.raises(InputError, match="mean must have at least one layer"):
        KLT.from_arrays(np.zeros(0), np.zeros((0, 0)), np.zeros(0))
    blob = t.to_bytes()
    with pytest.raises(BitstreamError, match="bad magic"):
        KLT.from_bytes(b"XXXX" + blob[4:])
    with pytest.raises(BitstreamError, match="unsupported KLT record version 9"):
        KLT.from_bytes(blob[:4] + bytes([9]) + blob[5:])
    with pytest.raises(BitstreamError, match="must be 150 bytes, got 146"):
        KLT.from_bytes(blob[:-4])
    raw = bytearray(blob)
    raw[6 + 24:6 + 24 + 72] = np.zeros(9, "<f8").tobytes()  # singular basis
    with pytest.raises(BitstreamError, match="corrupt KLT record"):
        KLT.from_bytes(bytes(raw))


def test_groups_give_a_block_diagonal_basis():
    rng = np.random.default_rng(4)
    x = rng.normal(size=(500, 6)) @ rng.normal(size=(6, 6))   # all layers correlated
    t = KLT.fit(x, groups=(3, 3))
    assert np.all(t.basis[:3, 3:] == 0) and np.all(t.basis[3:, :3] == 0)
    np.testing.assert_allclose(t.basis @ t.basis.T, np.eye(6), atol=1e-12)
    assert np.all(np.diff(t.eigenvalues[:3]) <= 0) and np.all(np.diff(t.eigenvalues[3:]) <= 0)
    # the first group's coefficients are its own KLT: the same as fitting those layers alone
    alone = KLT.fit(x[:, :3])
    np.testing.assert_allclose(t.forward(x)[:, :3], alone.forward(x[:, :3]), atol=1e-10)
    assert np.abs(t.inverse(t.forward(x)) - x).max() < TOL.reconstruction
    np.testing.assert_array_equal(KLT.fit(x, groups=(6,)).basis, KLT.fit(x).basis)
    with pytest.raises(InputError, match=r"groups must be positive layer counts adding up to 6, "
                                         r"got \(3, 2\)"):
        KLT.fit(x, groups=(3, 2))
    with pytest.raises(InputError, match="groups must be positive"):
        KLT.fit(x, groups=(6, 0))
