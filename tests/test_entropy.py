"""Adaptive binary range coder: round trips, compression near the entropy, prefix decoding."""

from __future__ import annotations

import numpy as np
import pytest

from surfidx import BitstreamError, InputError
from surfidx.codec.entropy import (FLUSH_BYTES, cost_bits, dec_bit, dec_init, decode_bits, enc_bit,
                             enc_flush, encode_bits, new_encoder, new_models)


def _source(m, n_contexts, seed):
    rng = np.random.default_rng(seed)
    ctx = rng.integers(0, n_contexts, m)
    p1 = rng.uniform(0.001, 0.999, n_contexts) ** 2     # skewed towards rare ones
    bits = (rng.random(m) < p1[ctx]).astype(np.int64)
    return bits, ctx, p1


def _entropy(bits, ctx, p1):
    p = np.where(bits == 1, p1[ctx], 1 - p1[ctx])
    return float(-np.log2(p).sum())


def test_round_trip_many_skewed_contexts():
    bits, ctx, _ = _source(200_000, 300, 0)
    stream, n = encode_bits(bits, ctx, n_contexts=300)
    assert n == len(bits)
    np.testing.assert_array_equal(decode_bits(stream, ctx, n_contexts=300), bits)


@pytest.mark.parametrize("p1", [0.5, 0.2, 0.08])
def test_compression_near_entropy_stationary(p1):
    rng = np.random.default_rng(1)
    m = 400_000
    bits = (rng.random(m) < p1).astype(np.int64)
    h = -(p1 * np.log2(p1) + (1 - p1) * np.log2(1 - p1)) * m
    stream, _ = encode_bits(bits, 0, n_contexts=1)
    assert 8 * len(stream) < 1.02 * h
    # the coder itself (not the model) loses almost nothing
    assert 8 * len(stream) < cost_bits(bits, 0, n_contexts=1) + 64


def test_compression_many_contexts_near_entropy():
    bits, ctx, p1 = _source(600_000, 16, 2)
    stream, _ = encode_bits(bits, ctx, n_contexts=16)
    assert 8 * len(stream) < 1.03 * _entropy(bits, ctx, p1)


def test_skewed_contexts_cost_much_less_than_one_bit():
    bits = np.zeros(100_000, dtype=np.int64)
    bits[::1000] = 1
    stream, _ = encode_bits(bits, 0, n_contexts=1)
    assert 8 * len(stream) < 0.03 * len(bits)


def test_prefix_decodes_same_decisions_as_budgeted_encoding():
    bits, ctx, _ = _source(50_000, 40, 3)
    full, _ = encode_bits(bits, ctx, n_contexts=40)
    for b in [0, 3, 4, 5, 9, 64, 1000, len(full) // 2, len(full) - 1, len(full)]:
        prefix = full[:b]
        got = decode_bits(prefix, ctx, n_contexts=40)
        # the prefix decodes a leading run of the decisions, all correct
        np.testing.assert_array_equal(got, bits[:len(got)])
        if b >= FLUSH_BYTES:
            direct, n = encode_bits(bits, ctx, n_contexts=40, max_bytes=b)
            # direct encoding at that budget fills it exactly (unless it finished) and codes the
            # very same decisions the prefix decodes
            assert len(direct) == min(b, len(full))
            assert n == len(got)
            np.testing.assert_array_equal(decode_bits(direct, ctx, n_contexts=40), got)
    # information grows with the prefix: about 8 decisions' worth per byte, never fewer than 0
    counts = [len(decode_bits(full[:b], ctx, n_contexts=40)) for b in range(0, 400, 20)]
    assert all(np.diff(counts) >= 0) and counts[-1] > 300


def test_truncated_and_garbage_streams_never_crash():
    ctx = np.zeros(5000, dtype=np.int64)
    rng = np.random.default_rng(4)
    for m in [0, 1, 2, 7, 100]:
        junk = rng.integers(0, 256, m, dtype=np.uint8).tobytes()
        junk = junk.replace(b"\xff\xff\xff\xff", b"\x00\x00\x00\x00")
        out = decode_bits(junk, ctx, n_contexts=1)
        again = decode_bits(junk, ctx, n_contexts=1)
        np.testing.assert_array_equal(out, again)          # deterministic
        assert set(np.unique(out)) <= {0, 1}
    with pytest.raises(BitstreamError, match="impossible code value"):
        decode_bits(b"\xff\xff\xff\xff\x00", ctx, n_contexts=1)


def test_kernel_level_api_matches_helpers():
    bits, ctx, _ = _source(3000, 5, 5)
    st, buf, models = new_encoder(), np.zeros(4096, np.uint8), new_models(5)
    for b, c in zip(bits, ctx):
        enc_bit(st, buf, models, c, b)
    size = enc_flush(st, buf)
    assert bytes(buf[:size]) == encode_bits(bits, ctx, n_contexts=5)[0]
    dst, dmodels = np.zeros(4, np.int64), new_models(5)
    assert dec_init(dst, buf[:size])
    out = [dec_bit(dst, buf[:size], dmodels, c) for c in ctx]
    np.testing.assert_array_equal(out, bits)


def test_input_errors():
    with pytest.raises(InputError, match="0 and 1"):
        encode_bits([0, 2], 0, n_contexts=1)
    with pytest.raises(InputError, match="contexts must lie"):
        encode_bits([0, 1], [0, 3], n_contexts=2)
    with pytest.raises(InputError, match="contexts must have shape"):
        encode_bits([0, 1], [0, 1, 1], n_contexts=2)
    with pytest.raises(InputError, match="max_bytes must be at least"):
        encode_bits([0, 1], 0, n_contexts=1, max_bytes=2)
    with pytest.raises(InputError, match="one context per decision"):
        decode_bits(b"\x00" * 8, 0, n_contexts=1)
