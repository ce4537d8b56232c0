"""SPIHT zerotree coding on forests: losslessness, embedding, rate control, robustness, errors."""

from __future__ import annotations

import lzma

import numpy as np
import pytest

from surfidx import BitstreamError, InputError
from surfidx.geometry.icosphere import icosphere
from surfidx.codec.zerotree import (HEADER_SIZE, check_forest, decode, encode, encode_prepared, forest,
                              grid_forest, pack_header, prepare, unpack_header)


def _csr(parent):
    parent = np.asarray(parent, dtype=np.int64)
    n = len(parent)
    kids = np.flatnonzero(parent >= 0)
    indices = kids[np.argsort(parent[kids], kind="stable")]
    indptr = np.zeros(n + 1, dtype=np.int64)
    np.cumsum(np.bincount(parent[kids], minlength=n), out=indptr[1:])
    return parent, indptr, indices


def random_forest(n, n_roots, seed):
    """Random forest of arbitrary fan-out: node i >= n_roots hangs under a random earlier node."""
    rng = np.random.default_rng(seed)
    parent = np.full(n, -1, dtype=np.int64)
    for i in range(n_roots, n):
        parent[i] = rng.integers(max(0, i // 2 - 50), i)
    perm = rng.permutation(n)                    # node ids need not be in tree order
    inv = np.argsort(perm)
    shuffled = np.where(parent[perm] >= 0, inv[np.maximum(parent[perm], 0)], -1)
    return _csr(shuffled)


def quad_forest(levels, n_roots=12):
    parent = [-1] * n_roots
    frontier = list(range(n_roots))
    for _ in range(levels):
        new = []
        for v in frontier:
            for _ in range(4):
                parent.append(v)
                new.append(len(parent) - 1)
        frontier = new
    return _csr(parent)


def depths(parent):
    return check_forest(*_csr(parent))[4]


def wavelet_like(tree, k, seed, decay=0.5, scale=(1000.0, 200.0, 20.0)):
    """Laplacian coefficients whose magnitude decays geometrically with the tree depth, with a
    parent-child magnitude dependence (as wavelet coefficients have)."""
    parent = tree[0]
    d = depths(parent)
    rng = np.random.default_rng(seed)
    order = np.argsort(d, kind="stable")
    env = np.ones(len(parent))
    for v in order:                      # parents first: envelope inherits from the parent
        if parent[v] >= 0:
            env[v] = decay * (0.5 * env[parent[v]] + 0.5 * rng.exponential())
    c = rng.laplace(size=(len(parent), k)) * env[:, None]
    return c * np.asarray(scale[:k])


def mse(a, b):
    return float(np.mean((a - b) ** 2))


@pytest.mark.parametrize("make", [lambda: random_forest(3000, 7, 0), lambda: quad_forest(4)])
def test_lossless_integers(make):
    tree = make()
    n = len(tree[0])
    c = np.round(wavelet_like(tree, 3, 1)).astype(np.int64)
    stream, header = encode(c, *tree, step=1.0)
    assert header["final_plane"] == 0 and header["top_plane"] == int(np.abs(c).max()).bit_length() - 1
    out = decode(stream, n, 3, *tree, header=header)
    assert out.shape == (n, 3) and out.dtype == np.float64
    np.testing.assert_array_equal(out, c)
    # the packed header gives the same result
    np.testing.assert_array_equal(decode(stream, n, 3, *tree, header=pack_header(header)), c)


def test_float_coefficients_within_half_step():
    tree = random_forest(2000, 3, 2)
    c = wavelet_like(tree, 2, 3)
    stream, header = encode(c, *tree, step=0.5)
    out = decode(stream, len(c), 2, *tree, header=header)
    assert np.abs(out - c).max() <= 0.25 + 1e-9
    # final_plane p leaves intervals of 2**p steps: significant coefficients are within half of
    # one, insignificant ones (|q| < 2**p, reconstructed as 0) within (2**p - 1/2) steps
    stream3, header3 = encode(c, *tree, step=0.5, final_plane=3)
    out3 = decode(stream3, len(c), 2, *tree, header=header3)
    assert len(stream3) < len(stream)
    err = np.abs(out3 - c)
    assert err.max() <= (2 ** 3 - 0.5) * 0.5 + 1e-9
    assert err[out3 != 0].max() <= 2 ** 2 * 0.5 + 1e-9


def test_error_decreases_with_prefix_length():
    tree = quad_forest(5)
    n = len(tree[0])
    c = wavelet_like(tree, 3, 4)
    stream, header = encode(c, *tree, step=0.01)
    sizes = np.unique(np.geomspace(4, len(stream), 25).astype(int))
    errs = [mse(decode(stream[:b], n, 3, *tree, header=header), c) for b in sizes]
    assert all(np.diff(errs) <= 0), errs
    assert errs[-1] < 1e-4 * errs[0]


@pytest.mark.parametrize("make", [lambda: random_forest(4000, 12, 5), lambda: quad_forest(5)])
def test_prefix_equals_direct_encoding_bit_exact(make):
    """Embedded property: encoder and decoder apply the same byte-budget rule to the same
    arithmetic-coder state, so a B-byte prefix yields exactly the decisions of encoding at B."""
    tree = make()
    n = len(tree[0])
    c = wavelet_like(tree, 3, 6)
    full, header = encode(c, *tree, step=0.05)
    for b in [0, 3, 4, 5, 17, 200, 1000, len(full) // 3, len(full) - 1, len(full), len(full) + 9]:
        pre = decode(full[:b], n, 3, *tree, header=header)
        if b >= 4:
            direct, h2 = encode(c, *tree, step=0.05, max_bytes=b)
            assert h2 == header
            assert len(direct) == min(b, len(full))       # a budget is filled exactly
            np.testing.assert_array_equal(decode(direct, n, 3, *tree, header=header), pre)
        # max_bytes on decode equals slicing
        np.testing.assert_array_equal(decode(full, n, 3, *tree, header=header, max_bytes=b), pre)


@pytest.mark.parametrize("make", [lambda: random_forest(2000, 5, 3), lambda: quad_forest(4)])
def test_prepared_coefficients_give_encodes_streams_at_every_budget(make):
    """One prepare (quantisation, set tops) serves every budget: the streams and headers are
    encode's, byte for byte, and coding does not change what was prepared."""
    tree = make()
    c = wavelet_like(tree, 3, 8)
    prepared = prepare(c, *tree, step=0.05)
    before = prepared.magnitudes.copy(), [t.copy() for t in prepared.tops]
    full, header = encode(c, *tree, step=0.05)
    for b in [None, 4, 5, 100, len(full) // 2, len(full), len(full) + 7]:
        assert encode_prepared(prepared, max_bytes=b) == encode(c, *tree, step=0.05, max_bytes=b)
    np.testing.assert_array_equal(prepared.magnitudes, before[0])
    for t, t0 in zip(prepared.tops, before[1]):
        np.testing.assert_array_equal(t, t0)
    assert prepared.header == header
    with pytest.raises(InputError, match="max_bytes must be"):
        encode_prepared(prepared, max_bytes=3)


def test_a_checked_forest_codes_and_decodes_as_its_arrays():
    """A Forest (checked once) in place of the three arrays: the same streams and values."""
    tree = random_forest(1500, 4, 11)
    n = len(tree[0])
    c = wavelet_like(tree, 2, 9)
    f = forest(*tree)
    stream, header = encode(c, *tree, step=0.05, max_bytes=600)
    assert encode(c, f, None, None, step=0.05, max_bytes=600) == (stream, header)
    np.testing.assert_array_equal(decode(stream, n, 2, f, None, None, header=header),
                                  decode(stream, n, 2, *tree, header=header))
    with pytest.raises(InputError, match="leave children_indptr and children_indices None"):
        decode(stream, n, 2, f, tree[1], tree[2], header=header)
    with pytest.raises(InputError, match="does not match"):
        decode(stream, n + 1, 2, f, None, None, header=header)


@pytest.mark.parametrize("level", range(0, 8))
def test_grid_forest_is_the_checked_forest_of_the_grid(level):
    """The grid's forest built without validation has check_forest's arrays (dtypes too)."""
    ico = icosphere(level)
    want = forest(ico.tree_parent, ico.children_indptr, ico.children_indices)
    got = grid_forest(level)
    assert got is grid_forest(level)
    for name in ("parent", "indptr", "indices", "order", "depth"):
        a, b = getattr(got, name), getattr(want, name)
        assert a.dtype == b.dtype
        np.testing.assert_array_equal(a, b)
    with pytest.raises(InputError, match="level must be at most 9"):
        grid_forest(10)


def test_layers_interleaved_weak_layer_later():
    tree = quad_forest(5)
    n = len(tree[0])
    c = wavelet_like(tree, 3, 7, scale=(1000.0, 30.0, 1.0))
    full, header = encode(c, *tree, step=0.01)
    # one bit-plane order over all layers: a short prefix spends everything on the strong layer,
    # a longer one reaches the middle layer's top planes, and the weak layer comes last
    nz = (decode(full[:300], n, 3, *tree, header=header) != 0).sum(axis=0)
    assert nz[0] > 0 and nz[1] == 0 and nz[2] == 0
    nz = (decode(full[:8000], n, 3, *tree, header=header) != 0).sum(axis=0)
    assert nz[0] > nz[1] > 0 and nz[2] == 0
    # ... yet a long prefix refines all layers
    long_ = decode(full[:len(full) // 2], n, 3, *tree, header=header)
    assert all((long_ != 0).sum(axis=0) > 0)


def test_rate_distortion_beats_general_purpose_compression():
    """The zerotree stream of a wavelet-like signal, coded to the last plane, is smaller than LZMA
    of the quantised integers, and within 10% of their zero-order entropy (an ideal coder that
    knows each layer's histogram for free)."""
    tree = random_forest(20000, 12, 8)
    c = wavelet_like(tree, 3, 9)
    step = 0.5
    stream, header = encode(c, *tree, step=step)
    q = (np.floor(np.abs(c) / header["step"] + 0.5) * np.sign(c)).astype(np.int64)
    h0 = 0.0
    for layer in q.T:
        _, counts = np.unique(layer, return_counts=True)
        p = counts / counts.sum()
        h0 += -(counts * np.log2(p)).sum()
    assert 8 * len(stream) < 1.10 * h0
    assert len(stream) < 0.95 * len(lzma.compress(q.T.astype(np.int32).tobytes(), preset=9))
    # distortion at half the rate is far smaller than zeroing (PSNR gain > 20 dB)
    half = decode(stream[:len(stream) // 2], len(c), 3, *tree, header=header)
    assert 10 * np.log10(mse(0 * c, c) / mse(half, c)) > 20


def test_icosphere_tree():
    ico = icosphere(4)
    tree = (ico.tree_parent, ico.children_indptr, ico.children_indices)
    c = wavelet_like(tree, 3, 10)
    full, header = encode(c, *tree, step=0.01)
    direct, _ = encode(c, *tree, step=0.01, max_bytes=len(full) // 4)
    np.testing.assert_array_equal(
        decode(direct, ico.n_vertices, 3, *tree, header=header),
        decode(full[:len(full) // 4], ico.n_vertices, 3, *tree, header=header))
    assert np.abs(decode(full, ico.n_vertices, 3, *tree, header=header) - c).max() <= 0.005 + 1e-12


def test_all_zero_and_single_layer():
    tree = random_forest(500, 4, 11)
    z = np.zeros((500, 2))
    stream, header = encode(z, *tree, step=1.0)
    assert header["top_plane"] == -1 and len(stream) <= 5
    np.testing.assert_array_equal(decode(stream, 500, 2, *tree, header=header), z)
    one = np.random.default_rng(0).standard_normal(500) * 10
    stream, header = encode(one, *tree, step=0.1)
    out = decode(stream, 500, 1, *tree, header=header)
    assert out.shape == (500, 1) and np.abs(out[:, 0] - one).max() <= 0.05 + 1e-6


def test_truncated_and_garbage_streams():
    tree = random_forest(3000, 12, 12)
    n = len(tree[0])
    c = wavelet_like(tree, 3, 13)
    full, header = encode(c, *tree, step=0.1)
    rng = np.random.default_rng(14)
    for b in rng.integers(0, len(full), 20):
        out = decode(full[:b], n, 3, *tree, header=header)
        assert np.isfinite(out).all()
    for m in [1, 10, 1000, 50_000]:
        junk = rng.integers(0, 256, m, dtype=np.uint8).tobytes()
        junk = b"\x00" + junk[1:]
        a = decode(junk, n, 3, *tree, header=header)
        b = decode(junk, n, 3, *tree, header=header)
        np.testing.assert_array_equal(a, b)                  # deterministic
        assert np.isfinite(a).all()
        assert np.abs(a).max() < 2.0 ** (header["top_plane"] + 1) * header["step"]
    with pytest.raises(BitstreamError, match="impossible code value"):
        decode(b"\xff" * 40, n, 3, *tree, header=header)


def test_header_pack_unpack_and_errors():
    h = {"version": 1, "top_plane": 17, "final_plane": 2, "step": 0.25}
    data = pack_header(h)
    assert len(data) == HEADER_SIZE == 8
    assert unpack_header(data) == h
    with pytest.raises(BitstreamError, match="must be 8 bytes"):
        unpack_header(data[:7])
    with pytest.raises(BitstreamError, match="unsupported zerotree stream version"):
        unpack_header(b"\x02" + data[1:])
    with pytest.raises(BitstreamError, match="planes out of range"):
        unpack_header(pack_header({**h, "top_plane": 99}))
    with pytest.raises(BitstreamError, match="finite and positive"):
        unpack_header(pack_header({**h, "step": -1.0}))
    with pytest.raises(BitstreamError, match="invalid zerotree header"):
        decode(b"", 1, 1, [-1], [0, 0], [], header={"version": 1})
    with pytest.raises(InputError, match="invalid zerotree header"):
        pack_header({"version": 1})


def test_input_errors():
    tree = quad_forest(2)
    n = len(tree[0])
    c = np.ones((n, 2))
    with pytest.raises(InputError, match="must have shape"):
        encode(c[:-1], *tree)
    with pytest.raises(InputError, match="step must be a positive"):
        encode(c, *tree, step=0.0)
    with pytest.raises(InputError, match="final_plane must be"):
        encode(c, *tree, final_plane=-1)
    with pytest.raises(InputError, match="top_plane must be"):
        encode(c * 100, *tree, top_plane=2)
    with pytest.raises(InputError, match="max_bytes must be"):
        encode(c, *tree, max_bytes=3)
    with pytest.raises(InputError, match="too small"):
        encode(c * 1e300, *tree, step=1e-30)
    with pytest.raises(InputError, match="NaN"):
        encode(np.full((n, 2), np.nan), *tree)
    with pytest.raises(InputError, match="does not match"):
        decode(b"", n + 1, 2, *tree, header=encode(c, *tree)[1])
    with pytest.raises(InputError, match="k must be"):
        decode(b"", n, 0, *tree, header=encode(c, *tree)[1])
    with pytest.raises(InputError, match="stream must be bytes"):
        decode("abc", n, 2, *tree, header=encode(c, *tree)[1])
    # forests that are not forests
    with pytest.raises(InputError, match="parent and children disagree|disagree"):
        encode(np.ones((3, 1)), [-1, 0, 0], [0, 1, 1, 1], [1])
    with pytest.raises(InputError, match="not describe a forest"):
        encode(np.ones((3, 1)), [-1, 2, 1], [0, 0, 1, 2], [2, 1])
    with pytest.raises(InputError, match="rise from 0"):
        encode(np.ones((2, 1)), [-1, 0], [0, 2, 1], [1])
    with pytest.raises(InputError, match="parent must hold"):
        encode(np.ones((2, 1)), [-1, 5], [0, 1, 1], [1])
    with pytest.raises(InputError, match="children_indices must hold"):
        encode(np.ones((2, 1)), [-1, 0], [0, 1, 1], [7])


def test_150k_nodes_fill_the_budget_and_decode():
    tree = quad_forest(7, n_roots=7)            # 7 * (4**8 - 1) / 3 = 152,915 nodes
    n = len(tree[0])
    c = wavelet_like(tree, 3, 15, decay=0.6)
    budget = 4 * n // 8                         # 4 bits per node
    stream, header = encode(c, *tree, step=1e-3, max_bytes=budget)
    out = decode(stream, n, 3, *tree, header=header)
    assert len(stream) == budget
    assert np.all(np.isfinite(out)) and np.abs(out - c).max() < np.abs(c).max()


def test_anchor_values_match_the_encoder_once_the_plane_is_decoded():
    from surfidx.geometry.icosphere import icosphere
    from surfidx.codec.zerotree import anchor_values, quantize_to_plane

    ico = icosphere(4)
    rng = np.random.default_rng(5)
    c = rng.laplace(size=(ico.n_vertices, 3)) * np.exp(-1.5 * ico.level_of)[:, None]
    for budget in (300, 2000, 20000):
        stream, header = encode(c, ico.tree_parent, ico.children_indptr, ico.children_indices,
                                step=1e-5, max_bytes=budget)
        values, planes = decode(stream, ico.n_vertices, 3, ico.tree_parent, ico.children_indptr,
                                ico.children_indices, header=header, planes=True)
        np.testing.assert_array_equal(values, decode(stream, ico.n_vertices, 3, ico.tree_parent,
                                                     ico.children_indptr, ico.children_indices,
                                                     header=header))
        assert header["final_plane"] <= planes.done <= header["top_plane"] + 1
        for plane in range(planes.done, header["top_plane"] + 2):
            np.testing.assert_array_equal(anchor_values(planes, plane),
                                          quantize_to_plane(c, plane, header["step"]))
        assert anchor_values(planes, planes.done - 1) is None or planes.done == 0
        np.testing.assert_array_equal(anchor_values(planes, planes.done, rows=50, layers=2),
                                      quantize_to_plane(c[:50, :2], planes.done, header["step"]))
    # a plane's anchor is the decoded value once that plane is the last one
    full, planes = decode(stream, ico.n_vertices, 3, ico.tree_parent, ico.children_indptr,
                          ico.children_indices, header=header, planes=True)
    if planes.done == 0:
        np.testing.assert_array_equal(anchor_values(planes, 0), full)


def test_top_bit_is_the_bit_length_less_one():
    from surfidx.codec.zerotree import top_bit

    values = [0, 1, 2, 3] + [(1 << b) + d for b in range(2, 62) for d in (-1, 0, 1)]
    assert [top_bit(v) for v in values] == [v.bit_length() - 1 for v in values]
