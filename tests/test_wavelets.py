"""Lifted butterfly spherical wavelets: perfect reconstruction, vanishing integrals, compaction,
equal-error normalisation, input checks."""

from __future__ import annotations


import numpy as np
import pytest

from surfidx import TOL, InputError
from surfidx.geometry.icosphere import icosphere
from surfidx.codec.wavelets import (measure_level_norms, forward, inverse, level_norms,
                              scaling_integrals)


def _band(ico, j):
    lo = 0 if j == 0 else ico.counts[j - 1]
    return slice(int(lo), int(ico.counts[j]))


@pytest.mark.parametrize("level", range(0, 8))
@pytest.mark.parametrize("lifted", [True, False])
@pytest.mark.parametrize("normalized", [False, True])
@pytest.mark.parametrize("shape", ["1d", "2d"])
def test_perfect_reconstruction(level, lifted, normalized, shape):
    n = 10 * 4 ** level + 2
    rng = np.random.default_rng(level)
    x = rng.standard_normal((n,) if shape == "1d" else (n, 3)) * 10
    x0 = x.copy()
    c = forward(x, level, lifted=lifted, normalized=normalized)
    assert c.shape == x.shape and c.dtype == np.float64
    y = inverse(c, level, lifted=lifted, normalized=normalized)
    assert np.abs(y - x).max() < TOL.reconstruction
    assert np.array_equal(x, x0)
    # forward does not modify its input; columns are transformed independently
    if shape == "2d":
        c1 = forward(x[:, 1], level, lifted=lifted, normalized=normalized)
        np.testing.assert_allclose(c[:, 1], c1, rtol=0, atol=1e-12)


def test_constant_function():
    level = 5
    ico = icosphere(level)
    x = np.full(ico.n_vertices, 2.5)
    for lifted in (True, False):
        c = forward(x, level, lifted=lifted)
        assert np.abs(c[12:]).max() < 1e-13          # butterfly reproduces constants
        np.testing.assert_allclose(c[:12], 2.5, atol=1e-13)


@pytest.mark.parametrize("level", [3, 6])
def test_lifting_preserves_integral(level):
    """Σ I_0 s_0 equals the quadrature Σ I_L x: the coarse coefficients carry the mean."""
    ico = icosphere(level)
    rng = np.random.default_rng(1)
    x = rng.standard_normal(ico.n_vertices) + np.exp(ico.vertices[:, 0])
    i_fine, i_coarse = scaling_integrals(level, level), scaling_integrals(level, 0)
    np.testing.assert_allclose(i_fine.sum(), 4 * np.pi, rtol=1e-12)
    np.testing.assert_allclose(i_coarse.sum(), 4 * np.pi, rtol=1e-12)
    total = i_fine @ x
    c = forward(x, level)
    assert abs(i_coarse @ c[:12] - total) < 1e-10 * np.abs(x).sum()
    # without the update step the coarse coefficients are the plain samples: not the mean
    c0 = forward(x, level, lifted=False)
    assert abs(i_coarse @ c0[:12] - total) > 1e-3


def test_each_wavelet_has_vanishing_integral():
    level = 5
    ico = icosphere(level)
    w = scaling_integrals(level, level)
    idx = np.concatenate([np.arange(ico.counts[j], ico.counts[j + 1])[::97] for j in range(level)])
    coeffs = np.zeros((ico.n_vertices, len(idx)))
    coeffs[idx, np.arange(len(idx))] = 1.0
    psi = inverse(coeffs, level)
    assert np.abs(w @ psi).max() < 1e-12
    psi0 = inverse(coeffs, level, lifted=False)   # interpolating wavelets: integral ≠ 0
    assert np.abs(w @ psi0).min() > 1e-6


def _sph_harm_real(v):
    x, y, z = v.T
    return {
        "Y10": z,
        "Y21": x * z,
        "Y22": x ** 2 - y ** 2,
        "Y30": z * (5 * z ** 2 - 3),
    }


@pytest.mark.parametrize("name", ["Y10", "Y21", "Y22", "Y30"])
def test_smooth_functions_have_small_decaying_details(name):
    level = 7
    ico = icosphere(level)
    f = _sph_harm_real(ico.vertices)[name]
    c = forward(f, level)
    rms = np.array([np.sqrt(np.mean(c[_band(ico, j)] ** 2)) for j in range(2, level + 1)])
    assert np.all(rms[1:] < rms[:-1] / 2)            # decays at least 2x per level
    assert rms[-1] < 1e-3 * np.abs(f).max()
    # energy compaction: the 162 coarsest coefficients hold nearly all the energy
    cn = forward(f, level, normalized=True)
    assert np.sum(cn[:162] ** 2) > 0.99 * np.sum(cn ** 2)


def test_energy_compaction_vs_noise():
    """A smooth signal compacts into few normalised coefficients; white noise does not."""
    level = 6
    ico = icosphere(level)
    v = ico.vertices
    smooth = np.exp(v[:, 0]) * np.cos(2 * v[:, 1]) + v[:, 2] ** 3
    noise = np.random.default_rng(0).standard_normal(ico.n_vertices)

    def top_fraction(sig):
        e = np.sort(forward(sig - sig.mean(), level, normalized=True) ** 2)[::-1]
        return e[: len(e) // 100].sum() / e.sum()

    assert top_fraction(smooth) > 0.99
    assert top_fraction(noise) < 0.2


@pytest.mark.parametrize("lifted", [True, False])
def test_equal_error_normalisation(lifted):
    """A unit error on a normalised coefficient gives a grid error of norm ≈ 1 at every level."""
    level = 6
    ico = icosphere(level)
    norms = level_norms(level, lifted=lifted)
    assert norms.shape == (level + 1,) and np.all(norms > 0)
    assert np.all(np.diff(norms) < 0)                 # coarser basis functions are larger
    rng = np.random.default_rng(7)
    measured = []
    for j in range(level + 1):
        band = np.arange(ico.n_vertices)[_band(ico, j)]
        pick = rng.choice(band, size=min(12, len(band)), replace=False)  # not the sampled ones
        cols = np.zeros((ico.n_vertices, len(pick)))
        cols[pick, np.arange(len(pick))] = 1.0
        out = inverse(cols, level, lifted=lifted, normalized=True)
        measured.append(np.sqrt(np.mean(np.sum(out ** 2, axis=0))))
    measured = np.array(measured)
    assert measured.max() / measured.min() < 1.2, measured
    np.testing.assert_allclose(measured, 1.0, rtol=0.2)
    # unnormalised, the same measurement spans two orders of magnitude
    raw = [np.linalg.norm(inverse(np.eye(ico.n_vertices, 1, -int(ico.counts[j - 1]) if j else 0)
                                  [:, 0], level, lifted=lifted)) for j in range(level + 1)]
    assert max(raw) / min(raw) > 20


@pytest.mark.parametrize("lifted", [True, False])
def test_norm_table_matches_measurement(lifted):
    for level in range(0, 7):
        np.testing.assert_allclose(level_norms(level, lifted=lifted),
                                   measure_level_norms(level, lifted), rtol=1e-7)


def test_normalized_is_scaled_raw():
    level = 4
    ico = icosphere(level)
    x = np.random.default_rng(3).standard_normal(ico.n_vertices)
    raw = forward(x, level)
    scaled = forward(x, level, normalized=True)
    np.testing.assert_allclose(scaled, raw * level_norms(level)[ico.level_of], rtol=1e-15)


def test_round_trip_level8():
    level = 8
    x = np.random.default_rng(0).standard_normal((10 * 4 ** level + 2, 3))
    y = inverse(forward(x, level), level)
    assert np.abs(y - x).max() < TOL.reconstruction


def test_bad_input():
    with pytest.raises(InputError, match=r"values must have shape \(162,\) or \(162, k\)"):
        forward(np.zeros(100), 2)
    with pytest.raises(InputError, match=r"coeffs must have shape \(42,\)"):
        inverse(np.zeros((162, 3)), 1)
    with pytest.raises(InputError, match=r"values must have shape"):
        forward(np.zeros((162, 2, 2)), 2)
    bad = np.zeros(162)
    bad[5] = np.nan
    with pytest.raises(InputError, match="values contains 1 NaN"):
        forward(bad, 2)
    with pytest.raises(InputError, match="coeffs contains 1 NaN"):
        inverse(bad, 2)
    with pytest.raises(InputError, match="level must be at most 9"):
        forward(np.zeros(12), 10)
    with pytest.raises(InputError, match="level must be an integer"):
        level_norms(2.0)
    with pytest.raises(InputError, match="coarse_level must be at most level=2"):
        scaling_integrals(2, 3)


# ---------------------------------------------------------------- local frames
def _bumpy(level, k=3, seed=0):
    v = icosphere(level).vertices
    rng = np.random.default_rng(seed)
    p = v * (1 + 0.2 * np.sin(3 * v[:, :1]) * np.cos(2 * v[:, 1:2]))[:, None].reshape(-1, 1)
    p = p * [1.0, 1.4, 0.7] + rng.normal(scale=1e-3, size=p.shape)
    extra = rng.normal(size=(len(v), k - 3))
    return np.hstack([p, extra])


@pytest.mark.parametrize("level", [0, 1, 3, 5])
@pytest.mark.parametrize("k", [3, 6])
@pytest.mark.parametrize("weight", [0.3, 1.0])
def test_frames_reconstruct_exactly(level, k, weight):
    x = _bumpy(level, k)
    for normalized in (False, True):
        c = forward(x, level, normalized=normalized, frames=True, tangent_weight=weight)
        y = inverse(c, level, normalized=normalized, frames=True, tangent_weight=weight)
        assert np.abs(y - x).max() < TOL.reconstruction
        if k > 3:  # the other layers are untouched by the frames
            np.testing.assert_array_equal(c[:, 3:], forward(x[:, 3:], level,
                                                            normalized=normalized))


def test_frames_rotate_with_the_surface():
    """Normal components are invariant under a rigid motion; the frames move with the surface."""
    from scipy.spatial.transform import Rotation

    level = 4
    x = _bumpy(level)
    c = forward(x, level, frames=True, tangent_weight=0.5)
    rot = Rotation.random(random_state=7).as_matrix()
    c2 = forward(x @ rot.T + [3.0, -1.0, 2.0], level, frames=True, tangent_weight=0.5)
    details = slice(12, None)
    np.testing.assert_allclose(c2[details], c[details], atol=1e-10)
    plain = forward(x, level)
    # the weight scales exactly the two tangential components
    c1 = forward(x, level, frames=True, tangent_weight=1.0)
    np.testing.assert_allclose(c[details, 1:], 0.5 * c1[details, 1:], atol=1e-14)
    np.testing.assert_allclose(np.linalg.norm(c1[details], axis=1),
                               np.linalg.norm(plain[details], axis=1), rtol=1e-10, atol=1e-14)


def test_frames_put_a_normal_displacement_on_the_normal_component():
    """A small bump along the sphere's normal changes mostly the details' normal components
    (12x the tangential change; x, y, z components share it 1 : 2)."""
    level = 5
    v = icosphere(level).vertices
    bumped = v * (1 + 0.01 * np.sin(7 * v[:, 0]) * np.cos(5 * v[:, 1]))[:, None]
    d = (forward(bumped, level, frames=True) - forward(v, level, frames=True))[12:]
    assert np.sum(d[:, 0] ** 2) > 10 * np.sum(d[:, 1:] ** 2)


def test_frames_bad_input():
    x = _bumpy(2)
    with pytest.raises(InputError, match="tangent_weight applies only with frames=True"):
        forward(x, 2, tangent_weight=0.5)
    with pytest.raises(InputError, match=r"tangent_weight must be in \(0, 1\], got 0"):
        forward(x, 2, frames=True, tangent_weight=0)
    with pytest.raises(InputError, match=r"tangent_weight must be in \(0, 1\], got 1.5"):
        inverse(x, 2, frames=True, tangent_weight=1.5)
    with pytest.raises(InputError, match="frames=True needs at least three layers"):
        forward(x[:, :2], 2, frames=True)
    with pytest.raises(InputError, match="frames=True needs at least three layers"):
        inverse(x[:, 0], 2, frames=True)


# ---------------------------------------------------------------- closed-loop frames
def _anchored_setup(level=5, k=3):
    from surfidx.codec.wavelets import choose_anchors

    x = _bumpy(level, k)
    scales = level_norms(level)[icosphere(level).level_of] * (1 + icosphere(level).vertices[:, 0]
                                                              ** 2)
    step = float(np.float32(1e-6))  # the coder stores its step as float32
    anchors = choose_anchors(forward(x, level) * scales[:, None], level, step)
    return x, scales, step, anchors


@pytest.mark.parametrize("k", [3, 6])
def test_anchored_frames_reconstruct_exactly_and_anchors_descend(k):
    from surfidx.codec.wavelets import forward_anchored, inverse_anchored
    from surfidx.codec.zerotree import quantize_to_plane

    level = 5
    x, scales, step, anchors = _anchored_setup(level, k)
    assert len(anchors) == level and np.all(np.diff(anchors) <= 0) and anchors.min() >= 0
    coded = forward_anchored(forward(x, level), level, tangent_weight=0.5, scales=scales, step=step,
                             anchors=anchors)
    y = inverse_anchored(coded, level, tangent_weight=0.5, scales=scales, anchors=anchors,
                         anchor_values=lambda a, rows: quantize_to_plane(coded[:rows], a, step))
    assert np.abs(y - x).max() < TOL.reconstruction
    # colour layers are plain scaled wavelet coefficients
    if k > 3:
        np.testing.assert_allclose(coded[:, 3:], forward(x[:, 3:], level) * scales[:, None],
                                   rtol=1e-12, atol=1e-15)


def test_anchored_frames_agree_with_the_encoder_wherever_the_anchor_was_decoded():
    """A decoder with the anchor planes of some levels computes those levels' frames exactly as
    the encoder did: its synthesis equals one given the encoder's own anchors for them."""
    from surfidx.codec.wavelets import forward_anchored, inverse_anchored
    from surfidx.codec.zerotree import anchor_values, decode as zdecode, encode as zencode, \
        quantize_to_plane

    level = 5
    ico = icosphere(level)
    x, scales, step, anchors = _anchored_setup(level)
    coded = forward_anchored(forward(x, level), level, tangent_weight=0.5, scales=scales, step=step,
                             anchors=anchors)
    for budget in (400, 3000, 30000):
        stream, header = zencode(coded, ico.tree_parent, ico.children_indptr,
                                 ico.children_indices, step=step, max_bytes=budget)
        w, planes = zdecode(stream, ico.n_vertices, 3, ico.tree_parent, ico.children_indptr,
                            ico.children_indices, header=header, planes=True)
        got = inverse_anchored(w, level, tangent_weight=0.5, scales=scales, anchors=anchors,
                               anchor_values=lambda a, rows: anchor_values(planes, a, rows=rows))
        oracle = inverse_anchored(
            w, level, tangent_weight=0.5, scales=scales, anchors=anchors,
            anchor_values=lambda a, rows: quantize_to_plane(coded[:rows], a, step)
            if a >= planes.done else None)
        np.testing.assert_array_equal(got, oracle)
