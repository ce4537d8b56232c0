"""The virtual region as a per-grid-vertex bit, coded hierarchically with the arithmetic coder.

A closed surface's virtual patches (:func:`surfidx.topology.close_surface`) become, on the
icosahedral grid of level ``L``, one bit per grid vertex (1: the grid vertex samples a virtual
patch). The bits are coded in the grid's vertex order, which is coarse to fine (the vertices of
level ``j`` are a prefix of those of level ``j + 1``), with the adaptive binary coder of
:mod:`surfidx.codec.entropy` in one stream. A vertex born at level ``j + 1`` on the level-``j`` edge
``(a, b)`` is coded in the context of its two edge parents' bits and of the two vertices
``c, d`` opposite that edge (both known to the decoder: they are coarser), per level band
(``j = 0``, ``1``, ``≥ 2``): 9 contexts per band, so deep inside a patch or inside the scan a
bit costs a few hundredths of a bit and only the patch outlines cost much. The 12 icosahedron
vertices share one more context. The stream has no header: the grid level is the container's.

Sizes on the real models' grids: ``benchmarks/topology.py --mask``.
"""

from __future__ import annotations

import numpy as np
from ..jit import njit

from ..errors import BitstreamError, InputError
from .entropy import dec_bit, dec_init, enc_bit, enc_flush, new_encoder, new_models
from ..geometry.icosphere import check_level, icosphere, vertex_count

__all__ = ["encode_mask", "decode_mask", "N_CONTEXTS"]

N_CONTEXTS = 1 + 3 * 9
"""Contexts of the mask coder: the roots, then 9 per level band."""


@njit(cache=True)
def _context(bits, v, level_of, parents, butterfly):
    if level_of[v] == 0:
        return 0
    band = min(level_of[v] - 1, 2)
    a, b = parents[v, 0], parents[v, 1]
    c, d = butterfly[v, 2], butterfly[v, 3]
    return 1 + 9 * band + 3 * (bits[a] + bits[b]) + (bits[c] + bits[d])


@njit(cache=True)
def _encode(bits, level_of, parents, butterfly, buf, st, models):
    for v in range(len(bits)):
        enc_bit(st, buf, models, _context(bits, v, level_of, parents, butterfly), bits[v])
    return enc_flush(st, buf)


@njit(cache=True)
def _decode(data, level_of, parents, butterfly, n, models):
    st = np.zeros(4, np.int64)
    bits = np.zeros(n, np.uint8)
    if not dec_init(st, data):
        return bits, False
    for v in range(n):
        bits[v] = dec_bit(st, data, models, _context(bits, v, level_of, parents, butterfly))
    return bits, True


def _tables(level: int):
    g = icosphere(level)
    return (np.ascontiguousarray(g.level_of), np.ascontiguousarray(g.edge_parents),
            np.ascontiguousarray(g.butterfly))


def encode_mask(bits, level: int) -> bytes:
    """Code one bit per vertex of the level-``level`` icosahedral grid.

    Parameters
    ----------
    bits : (n,) bool
        ``n = 10·4^level + 2``, in the grid's vertex order.
    level : int

    Returns
    -------
    bytes
        The arithmetic-coded stream (:func:`decode_mask` reads it back).

    Raises
    ------
    InputError
        When ``level`` is out of range or ``bits`` has the wrong length or values.
    """
    lev = check_level(level)
    b = np.asarray(bits)
    n = vertex_count(lev)
    if b.shape != (n,):
        raise InputError(f"bits must have one entry per vertex of the level-{lev} grid ({n}), "
                         f"got shape {b.shape}")
    if b.dtype != bool and b.size and not np.isin(b, (0, 1)).all():
        raise InputError("bits must be 0 or 1 (or bool)")
    level_of, parents, butterfly = _tables(lev)
    buf = np.zeros(n // 4 + 64, np.uint8)
    size = _encode(b.astype(np.uint8), level_of, parents, butterfly, buf, new_encoder(),
                   new_models(N_CONTEXTS))
    if size > len(buf):   # incompressible (the buffer is a quarter bit a vertex): code again
        buf = np.zeros(size + 16, np.uint8)
        size = _encode(b.astype(np.uint8), level_of, parents, butterfly, buf, new_encoder(),
                       new_models(N_CONTEXTS))
    return bytes(buf[:size])


def decode_mask(data: bytes, level: int, *, upto: int | None = None) -> np.ndarray:
    """Read back the bits :func:`encode_mask` coded.

    Parameters
    ----------
    data : bytes
    level : int
        The grid level the mask was coded at.
    upto : int, optional
        Read only the bits of the level-``upto`` grid (``upto <= level``): they come first, so
        the tables, time and memory are those of that grid.

    Returns
    -------
    (n,) bool
        ``n = 10·4^upto + 2`` (default ``upto = level``).

    Raises
    ------
    BitstreamError
        When the stream starts with an impossible code value.
    InputError
        When ``level`` or ``upto`` is out of range.
    """
    lev = check_level(level)
    upto = lev if upto is None else check_level(upto, "upto")
    if upto > lev:
        raise InputError(f"upto must be at most the mask's level {lev}, got {upto}")
    level_of, parents, butterfly = _tables(upto)
    arr = np.frombuffer(bytes(data), np.uint8)
    bits, ok = _decode(arr, level_of, parents, butterfly, vertex_count(upto),
                       new_models(N_CONTEXTS))
    if not ok:
        raise BitstreamError("the virtual-region mask starts with an impossible code value (FF FF "
                             "FF FF); the stream is damaged")
    return bits.astype(bool)


def grid_mask(surfels, sphere_map, closed, level: int) -> np.ndarray:
    """(n,) bool: grid vertices whose nearest mapped surfel is virtual.

    ``surfels`` are ``TriangleMesh(closed.vertices, closed.faces).to_surfels()`` (its first
    surfels are the mesh's used vertices, in order; vertices its bisection added take the flag
    of the nearest vertex in space), ``sphere_map`` their map.
    """
    from scipy.spatial import cKDTree

    used = np.unique(closed.faces)
    flag = np.zeros(len(surfels), bool)
    k = min(len(used), len(surfels))
    flag[:k] = closed.virtual_vertices[used[:k]]
    if len(surfels) > k:
        _, near = cKDTree(surfels.positions[:k]).query(surfels.positions[k:])
        flag[k:] = flag[near]
    g = icosphere(level)
    _, idx = cKDTree(sphere_map.points).query(g.vertices)
    return flag[idx]


def grid_mask_bytes(surfels, sphere_map, closed):
    """Size of the coded mask at the model's default grid level: ``(bytes, grid vertices)``."""
    from ..geometry.icosphere import choose_level

    level = choose_level(len(surfels), sparse_sampling=sphere_map.sparse_sampling)
    bits = grid_mask(surfels, sphere_map, closed, level)
    data = encode_mask(bits, level)
    assert np.array_equal(decode_mask(data, level), bits)
    return len(data), len(bits)
