"""Adaptive binary arithmetic coding: a carry-less 32-bit range coder with context models.

The coder is the LZMA range coder (Pavlov; Subbotin's carry-less scheme with a cache byte and a
count of pending ``0xFF`` bytes) with two changes: probabilities are 16-bit and adapt with two
exponential rates whose average is used (a fast and a slow estimator, each with a warm-up that
starts at rate 1/2 so a fresh context learns like a counting estimator), and the always-zero first
byte of LZMA's output is not written.

Everything is a numba kernel working on preallocated arrays, so a caller running inside numba (the
zerotree coder) codes a decision with one inline call and no Python per bit.

State arrays
------------
``models : (n_contexts, 3) int32``
    One row per context: fast estimate, slow estimate (both ``2**22 · P(bit = 0)``), count of
    updates (saturating). The coder uses their mean rounded to 16 bits, clipped to
    ``[1, 65535] / 65536``. Create with :func:`new_models`; encoder and decoder start from identical
    fresh models.
``enc : (8,) int64``
    Encoder state: ``low, range, cache, cache_size, pos, shifts, drop_first``; created by
    :func:`new_encoder`. ``pos`` counts bytes produced (even those that did not fit the buffer).
``dec : (4,) int64``
    Decoder state: ``range, code, pos, shifts``; created by :func:`dec_init`.

Byte accounting and truncated streams
-------------------------------------
``shifts`` counts the renormalisation shifts; encoder and decoder count them identically, because
the range evolves the same on both sides. A flushed stream is ``shifts + 4`` bytes long, and any
decision coded while ``shifts + 4 <= B`` (:data:`FLUSH_BYTES` = 4) is decoded correctly from the
first ``B`` bytes of *any* stream that continues it: the subinterval boundary of that decision is
fixed by the first ``shifts + 4`` bytes. The decoder reads **zero bytes past the end** of its
buffer, so a prefix decodes to the same decisions as the full stream up to that point. Callers
enforce a byte budget ``B`` by coding (and decoding) a decision only while
:func:`enc_fits`/:func:`dec_fits` hold; then encoding at budget ``B`` and decoding the first ``B``
bytes of a longer stream yield exactly the same decisions.

A range decoder accepts any byte string, so garbage decodes deterministically to some decision
sequence; it never reads out of bounds. The one impossible state (``code >= range``, only reachable
when the first four bytes are ``FF FF FF FF``) is flagged by :func:`dec_init` returning ``False``.
"""

from __future__ import annotations

import numpy as np
from ..jit import njit

from ..errors import BitstreamError, InputError
from ..validate import as_array

__all__ = [
    "PROB_BITS", "FLUSH_BYTES", "new_models", "new_encoder", "enc_bit", "enc_fits", "enc_flush",
    "enc_size", "dec_init", "dec_bit", "dec_fits", "encode_bits", "decode_bits", "cost_bits",
]

PROB_BITS = 16
"""Precision of the probabilities the coder uses (``65536 · P(bit = 0)``)."""

FLUSH_BYTES = 4
"""Bytes a flush adds after the last renormalisation shift."""

_TOP = 1 << 24
_FAST_MAX = 5
_SLOW_MAX = 8
_STATE_BITS = 22
_ONE = 1 << _STATE_BITS
_COUNT_MAX = 255
# shift of the warm-up: 1 + floor(log2(count + 1)), i.e. roughly the running mean of a counter
_WARM = np.array([1 + int(np.floor(np.log2(c + 1))) for c in range(_COUNT_MAX + 1)], np.int64)

# encoder state slots
_LOW, _RANGE, _CACHE, _CSIZE, _POS, _SHIFTS, _DROP = 0, 1, 2, 3, 4, 5, 6
# decoder state slots
_DRANGE, _CODE, _DPOS, _DSHIFTS = 0, 1, 2, 3


def new_models(n_contexts: int) -> np.ndarray:
    """Fresh context models, all at ``P(0) = 1/2``.

    Parameters
    ----------
    n_contexts : int
        Number of contexts.

    Returns
    -------
    models : (n_contexts, 3) int32
    """
    m = np.zeros((int(n_contexts), 3), dtype=np.int32)
    m[:, 0] = _ONE >> 1
    m[:, 1] = _ONE >> 1
    return m


def new_encoder() -> np.ndarray:
    """Fresh encoder state.

    Returns
    -------
    enc : (8,) int64
    """
    st = np.zeros(8, dtype=np.int64)
    st[_RANGE] = 0xFFFFFFFF
    st[_CSIZE] = 1
    st[_DROP] = 1
    return st


@njit(cache=True, _nrt=False)
def _p0(models, ctx):
    p = (np.int64(models[ctx, 0]) + np.int64(models[ctx, 1])) >> (_STATE_BITS + 1 - PROB_BITS)
    if p < 1:
        return np.int64(1)
    if p > 65535:
        return np.int64(65535)
    return p


@njit(cache=True, _nrt=False)
def _update(models, ctx, bit):
    c = models[ctx, 2]
    w = _WARM[c]
    sf = w if w < _FAST_MAX else _FAST_MAX
    ss = w if w < _SLOW_MAX else _SLOW_MAX
    pf = models[ctx, 0]
    ps = models[ctx, 1]
    if bit == 0:
        models[ctx, 0] = pf + ((_ONE - pf) >> sf)
        models[ctx, 1] = ps + ((_ONE - ps) >> ss)
    else:
        models[ctx, 0] = pf - (pf >> sf)
        models[ctx, 1] = ps - (ps >> ss)
    if c < _COUNT_MAX:
        models[ctx, 2] = c + 1


@njit(cache=True, _nrt=False)
def _shift_low(st, buf):
    low = st[_LOW]
    if low < 0xFF000000 or low >= 0x100000000:
        carry = low >> 32
        temp = st[_CACHE]
        while True:
            if st[_DROP] != 0:
                st[_DROP] = 0
            else:
                p = st[_POS]
                if p < buf.shape[0]:
                    buf[p] = (temp + carry) & 0xFF
                st[_POS] = p + 1
            temp = 0xFF
            st[_CSIZE] -= 1
            if st[_CSIZE] == 0:
                break
        st[_CACHE] = (low >> 24) & 0xFF
    st[_CSIZE] += 1
    st[_LOW] = (low & 0x00FFFFFF) << 8
    st[_SHIFTS] += 1


@njit(cache=True, _nrt=False)
def enc_bit(st, buf, models, ctx, bit):
    """Code one binary decision.

    Parameters
    ----------
    st : (8,) int64
        Encoder state (updated).
    buf : (m,) uint8
        Output buffer; bytes beyond its end are counted in ``st[4]`` but not written.
    models : (n_contexts, 3) int32
        Context models (the row ``ctx`` adapts).
    ctx : int
        Context number.
    bit : int
        The decision, 0 or 1.
    """
    rng = st[_RANGE]
    bound = (rng >> 16) * _p0(models, ctx)
    if bit == 0:
        st[_RANGE] = bound
    else:
        st[_LOW] += bound
        st[_RANGE] = rng - bound
    _update(models, ctx, bit)
    while st[_RANGE] < _TOP:
        st[_RANGE] <<= 8
        _shift_low(st, buf)


@njit(cache=True, _nrt=False)
def enc_fits(st, budget):
    """True while a decision may still be coded within ``budget`` bytes (see module notes)."""
    return st[_SHIFTS] + FLUSH_BYTES <= budget


@njit(cache=True)
def enc_flush(st, buf):
    """Flush the encoder; afterwards ``st[4]`` is the stream length (``shifts + 4``)."""
    for _ in range(5):
        _shift_low(st, buf)
    return st[_POS]


@njit(cache=True)
def enc_size(st):
    """Bytes of the stream if it were flushed now."""
    return st[_SHIFTS] + FLUSH_BYTES


@njit(cache=True, _nrt=False)
def _byte(data, pos):
    if pos < data.shape[0]:
        return np.int64(data[pos])
    return np.int64(0)


@njit(cache=True)
def dec_init(st, data):
    """Start decoding ``data : (m,) uint8`` (any length, zero-padded); returns False if the stream
    starts with an impossible code value."""
    st[_DRANGE] = 0xFFFFFFFF
    code = np.int64(0)
    for i in range(4):
        code = (code << 8) | _byte(data, i)
    st[_CODE] = code
    st[_DPOS] = 4
    st[_DSHIFTS] = 0
    return code < st[_DRANGE]


@njit(cache=True, _nrt=False)
def dec_bit(st, data, models, ctx):
    """Decode one binary decision coded with :func:`enc_bit` in context ``ctx``; returns 0 or 1."""
    rng = st[_DRANGE]
    code = st[_CODE]
    bound = (rng >> 16) * _p0(models, ctx)
    if code < bound:
        rng = bound
        bit = 0
    else:
        code -= bound
        rng -= bound
        bit = 1
    _update(models, ctx, bit)
    while rng < _TOP:
        rng <<= 8
        code = ((code << 8) | _byte(data, st[_DPOS])) & 0xFFFFFFFF
        st[_DPOS] += 1
        st[_DSHIFTS] += 1
    st[_DRANGE] = rng
    st[_CODE] = code
    return bit


@njit(cache=True, _nrt=False)
def dec_fits(st, budget):
    """True while the next decision is determined by the first ``budget`` bytes."""
    return st[_DSHIFTS] + FLUSH_BYTES <= budget


# ------------------------------------------------------------------ thin array-level helpers

@njit(cache=True)
def _encode_seq(bits, ctxs, models, buf, budget):
    st = np.zeros(8, dtype=np.int64)
    st[_RANGE] = 0xFFFFFFFF
    st[_CSIZE] = 1
    st[_DROP] = 1
    n = 0
    for i in range(bits.shape[0]):
        if not enc_fits(st, budget):
            break
        enc_bit(st, buf, models, ctxs[i], bits[i])
        n += 1
    size = enc_flush(st, buf)
    return n, size


@njit(cache=True)
def _decode_seq(data, ctxs, models, out, budget):
    st = np.zeros(4, dtype=np.int64)
    ok = dec_init(st, data)
    n = 0
    for i in range(ctxs.shape[0]):
        if not dec_fits(st, budget):
            break
        out[i] = dec_bit(st, data, models, ctxs[i])
        n += 1
    return n, ok


def _check_ctx(contexts, n, n_contexts):
    if np.ndim(contexts) == 0:
        contexts = np.full(n, contexts)
    ctx = as_array(contexts, "contexts", dtype=np.int64)
    if ctx.shape != (n,):
        raise InputError(f"contexts must have shape ({n},) like the bits, got {ctx.shape}")
    if n and (ctx.min() < 0 or ctx.max() >= n_contexts):
        raise InputError(f"contexts must lie in [0, {n_contexts}); raise n_contexts or fix them")
    return ctx


def encode_bits(bits, contexts, *, n_contexts: int, max_bytes: int | None = None):
    """Arithmetic-code a sequence of binary decisions, each in a given context.

    Parameters
    ----------
    bits : (m,) int
        Decisions, 0 or 1.
    contexts : (m,) int or int
        Context of every decision, in ``[0, n_contexts)``.
    n_contexts : int
        Number of contexts.
    max_bytes : int, optional
        Byte budget: decisions are coded while the flushed stream stays within it.

    Returns
    -------
    stream : bytes
    n_coded : int
        Number of leading decisions the stream holds.
    """
    b = as_array(bits, "bits", dtype=np.int64)
    if b.ndim != 1 or (b.size and (b.min() < 0 or b.max() > 1)):
        raise InputError("bits must be a 1-D array of 0 and 1")
    ctx = _check_ctx(contexts, b.shape[0], n_contexts)
    budget = np.iinfo(np.int64).max if max_bytes is None else int(max_bytes)
    if budget < FLUSH_BYTES:
        raise InputError(f"max_bytes must be at least {FLUSH_BYTES}, got {max_bytes}")
    cap = (b.shape[0] * 17) // 8 + 16 if max_bytes is None else budget + 16
    buf = np.zeros(cap, dtype=np.uint8)
    n, size = _encode_seq(b.astype(np.uint8), ctx, new_models(n_contexts), buf, budget)
    return bytes(buf[:min(size, budget, cap)]), int(n)


def decode_bits(stream, contexts, *, n_contexts: int, max_bytes: int | None = None):
    """Decode decisions coded by :func:`encode_bits` with the same contexts.

    Parameters
    ----------
    stream : bytes
        A stream or any prefix of it.
    contexts : (m,) int or int
        Contexts of the decisions to decode (the decoder must know them, as in any coder).
    n_contexts : int
        Number of contexts.
    max_bytes : int, optional
        Byte budget; default ``len(stream)``. Decoding stops where the budget no longer determines
        the next decision.

    Returns
    -------
    bits : (n_decoded,) uint8
        The decisions determined by the budget (a prefix of those encoded).

    Raises
    ------
    BitstreamError
        If the stream starts with an impossible code value.
    """
    data = np.frombuffer(bytes(stream), dtype=np.uint8)
    budget = len(data) if max_bytes is None else min(int(max_bytes), len(data))
    data = data[:budget]
    if np.ndim(contexts) == 0:
        raise InputError("decode_bits needs one context per decision to decode, got a scalar")
    ctx = _check_ctx(contexts, np.shape(contexts)[0], n_contexts)
    out = np.zeros(ctx.shape[0], dtype=np.uint8)
    n, ok = _decode_seq(data, ctx, new_models(n_contexts), out, budget)
    if not ok:
        raise BitstreamError("arithmetic-coded stream starts with an impossible code value "
                             "(FF FF FF FF); the stream is damaged")
    return out[:n]


def cost_bits(bits, contexts, *, n_contexts: int) -> float:
    """Ideal adaptive code length in bits of ``bits`` under the coder's models (no coder overhead).

    Parameters
    ----------
    bits : (m,) int
    contexts : (m,) int or int
    n_contexts : int

    Returns
    -------
    float
        ``sum(-log2 P(bit))`` with the probabilities the coder uses.
    """
    b = as_array(bits, "bits", dtype=np.int64)
    ctx = _check_ctx(contexts, b.shape[0], n_contexts)
    return float(_cost(b, ctx, new_models(n_contexts)))


@njit(cache=True)
def _cost(bits, ctxs, models):
    total = 0.0
    for i in range(bits.shape[0]):
        p = _p0(models, ctxs[i]) / 65536.0
        total -= np.log2(p if bits[i] == 0 else 1.0 - p)
        _update(models, ctxs[i], bits[i])
    return total
