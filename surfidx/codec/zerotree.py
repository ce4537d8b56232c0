"""SPIHT set-partitioning zerotree coding over an arbitrary forest, all layers in one embedded stream.

The coder is SPIHT (Said & Pearlman 1996) generalised from the dyadic quad-tree to any forest: the
lists LIP (insignificant coefficients), LIS (sets: type A = all descendants ``D(v)``, type B = all
grand-descendants ``L(v)``) and LSP (significant coefficients), and per bit plane a sorting pass and
a refinement pass. Every root starts in the LIP and, if it has children, in the LIS as type A; a
significant set ``D(v)`` codes each child of ``v`` and becomes ``L(v)`` when ``v`` has
grandchildren; a significant ``L(v)`` splits into the sets ``D(c)`` of the children that have
children.

The ``k`` layers share the tree and have their own lists; **all layers go in one bit-plane order**:
plane ``p`` is coded as the sorting passes of layers ``0 … k-1`` followed by their refinement
passes, before anything of plane ``p - 1``. Weak layers simply become significant later.

Every decision (coefficient significance, sign, refinement, set significance) is coded by the
adaptive binary arithmetic coder of :mod:`surfidx.codec.entropy` in a context chosen from what the decoder
already knows: the layer, the tree depth, whether the parent is significant, how many siblings and
how many other layers of the same node are significant, whether the test comes straight from a
significant parent set, the refinement age, and for sets whether the node and its children are
significant.

Quantisation and reconstruction
-------------------------------
Magnitudes are quantised by rounding, ``q = floor(|c| / step + 1/2)``; plane ``p`` holds bit ``p`` of
``q``. A coefficient whose bits down to plane ``lo`` are known lies in an interval of ``2**lo``
integers and is reconstructed at the midpoint of the corresponding real interval,
``(q_known + 2**(lo-1) - 1/2) · step`` for ``lo >= 1`` and ``q · step`` once plane 0 is known, so
integer data with ``step = 1`` and ``final_plane = 0`` round-trip exactly.

Reconstruction is not biased toward zero (as suits Laplacian data): the rounding quantiser
already gives the zero bin a dead zone (``|c| < (2**p - 1/2) · step`` at plane ``p``), and a bias
on top of it lowers PSNR_D2.

Embedding and rate control
--------------------------
A decision is coded only while the arithmetic coder can still flush within the byte budget (see
:mod:`surfidx.codec.entropy`); the decoder applies the same rule to the number of bytes it is given. So
decoding the first ``B`` bytes of any stream gives **bit-identical** coefficients to decoding a
stream encoded with ``max_bytes = B`` (same decisions, same reconstruction rule), and a stream
encoded at budget ``B`` is exactly ``B`` bytes long unless it finished all planes earlier.

Header
------
:func:`encode` returns a dict ``{"version": 1, "top_plane": int, "final_plane": int,
"step": float}`` (``top_plane = -1`` when all coefficients quantise to 0); :func:`pack_header`
stores it in :data:`HEADER_SIZE` = 8 bytes (``<BbBBf``: version, top plane, final plane, reserved,
step as float32 — :func:`encode` rounds the step to float32 first, so the stored value is exact).
"""

from __future__ import annotations

import functools
import struct
from dataclasses import dataclass

import numpy as np
from ..jit import njit

from ..errors import BitstreamError, InputError
from ..validate import as_array
from .container import MAX_PLANE
from ..geometry.icosphere import MAX_LEVEL, icosphere
from .entropy import dec_bit, dec_fits, dec_init, enc_bit, enc_fits, enc_flush, new_encoder, \
    new_models

__all__ = ["encode", "decode", "prepare", "encode_prepared", "Prepared", "Forest", "forest",
           "grid_forest", "pack_header", "unpack_header", "HEADER_SIZE", "VERSION",
           "check_forest",
           "DecodedPlanes", "quantize_to_plane", "anchor_values", "plane_schedule",
           "group_schedule"]

VERSION = 1
"""Version of the zerotree stream format (the first header byte)."""

HEADER_SIZE = 8
"""Bytes of :func:`pack_header`'s output."""

_HEADER = struct.Struct("<BbBBf")

# ---------------------------------------------------------------- contexts
_NL = 8          # layer slots (layers >= 7 share the last)
_ND = 12         # depth slots (depths >= 11 share the last)
# coefficient significance: layer, depth, parent significant, other layers significant (0/1/2+),
# significant siblings (0/1/2+), from a set split (1) or the LIP (0)
_N_SIG = _NL * _ND * 4 * 3 * 3 * 2
# sign: layer, parent sign (none / + / -)
_N_SIGN = _NL * 3
# refinement: layer, planes since significance (1/2/3+), depth (0..3+)
_N_REF = _NL * 3 * 4
# type-A set: layer, depth, node significant, other layers' D significant (0/1/2+)
_N_SETA = _NL * _ND * 2 * 3
# type-B set: layer, depth, significant children (0/1/2+), other layers' L significant (0/1/2+)
_N_SETB = _NL * _ND * 3 * 3
_B_SIG = 0
_B_SIGN = _B_SIG + _N_SIG
_B_REF = _B_SIGN + _N_SIGN
_B_SETA = _B_REF + _N_REF
_B_SETB = _B_SETA + _N_SETA
N_CONTEXTS = _B_SETB + _N_SETB


# ---------------------------------------------------------------- forest tables

@njit(cache=True)
def _bfs(parent, indptr, indices):
    n = parent.shape[0]
    order = np.empty(n, dtype=np.int64)
    depth = np.full(n, -1, dtype=np.int64)
    t = 0
    for i in range(n):
        if parent[i] < 0:
            order[t] = i
            depth[i] = 0
            t += 1
    h = 0
    while h < t:
        v = order[h]
        h += 1
        for j in range(indptr[v], indptr[v + 1]):
            c = indices[j]
            if depth[c] >= 0:
                return order, depth, -1
            depth[c] = depth[v] + 1
            order[t] = c
            t += 1
    return order, depth, t


def check_forest(parent, children_indptr, children_indices):
    """Validate a forest and return it with its breadth-first order and depths.

    Parameters
    ----------
    parent : (n,) int64
        Parent of every node, ``-1`` for roots.
    children_indptr : (n + 1,) int64
        CSR row pointer: the children of ``v`` are
        ``children_indices[children_indptr[v]:children_indptr[v + 1]]``.
    children_indices : (n - n_roots,) int64
        CSR column indices.

    Returns
    -------
    parent : (n,) int64
    children_indptr : (n + 1,) int64
    children_indices : (n - n_roots,) int64
    order : (n,) int64
        Breadth-first order (roots first).
    depth : (n,) int64
        Depth of every node (0 for roots).

    Raises
    ------
    InputError
        When the arrays do not describe one forest (inconsistent parent and children, a cycle, a
        node listed twice).
    """
    parent = as_array(parent, "parent", dtype=np.int64, shape=(None,))
    n = parent.shape[0]
    indptr = as_array(children_indptr, "children_indptr", dtype=np.int64, shape=(n + 1,))
    indices = as_array(children_indices, "children_indices", dtype=np.int64, shape=(None,))
    if n and (parent.min() < -1 or parent.max() >= n):
        raise InputError(f"parent must hold -1 (root) or node ids in [0, {n})")
    if indptr[0] != 0 or np.any(np.diff(indptr) < 0) or indptr[-1] != indices.shape[0]:
        raise InputError("children_indptr must rise from 0 to len(children_indices)")
    if indices.size and (indices.min() < 0 or indices.max() >= n):
        raise InputError(f"children_indices must hold node ids in [0, {n})")
    owners = np.repeat(np.arange(n, dtype=np.int64), np.diff(indptr))
    if indices.shape[0] != int((parent >= 0).sum()) or np.any(parent[indices] != owners):
        raise InputError("children CSR and parent disagree: every non-root must be listed exactly "
                         "once, under its parent; rebuild the CSR from parent")
    order, depth, reached = _bfs(parent, indptr, indices)
    if reached != n:
        raise InputError("parent does not describe a forest (a cycle or a node listed twice); "
                         "every node must reach a root (-1) by following parent")
    return parent, indptr, indices, order, depth


@dataclass(frozen=True)
class Forest:
    """A forest checked once by :func:`check_forest` (:func:`forest`), to pass as ``parent`` to
    :func:`encode`, :func:`prepare` and :func:`decode` (with the children arguments left None)
    when one forest serves many streams.

    Attributes
    ----------
    parent : (n,) int64
    indptr : (n + 1,) int64
    indices : (n - n_roots,) int64
    order : (n,) int64
        Breadth-first order (roots first).
    depth : (n,) int64
    """

    parent: np.ndarray
    indptr: np.ndarray
    indices: np.ndarray
    order: np.ndarray
    depth: np.ndarray


def forest(parent, children_indptr, children_indices) -> Forest:
    """:func:`check_forest`'s result as one :class:`Forest` (same parameters and errors)."""
    return Forest(*check_forest(parent, children_indptr, children_indices))


@functools.lru_cache(maxsize=MAX_LEVEL + 1)
def grid_forest(level: int) -> Forest:
    """The zerotree forest of the level-``level`` icosahedral grid, built once per process.

    The grid's construction makes it a forest (:class:`surfidx.geometry.icosphere.Icosphere`
    builds ``tree_parent`` and its CSR children together, a vertex's parent born one level
    above it), so it is not validated again as :func:`forest` validates foreign arrays: the
    depth of a vertex is its birth level, and the breadth-first order is that of
    :func:`check_forest`, the 12 roots, then level by level the children of each vertex in
    the order of the level above (numpy, one step per level). ``tests/test_zerotree.py``
    compares it with :func:`forest` of the same arrays.

    Parameters
    ----------
    level : int
        0 … :data:`surfidx.geometry.icosphere.MAX_LEVEL`.

    Returns
    -------
    Forest

    Raises
    ------
    InputError
        If ``level`` is not a grid level.
    """
    ico = icosphere(level)
    indptr, indices = ico.children_indptr, ico.children_indices
    frontier = np.flatnonzero(ico.tree_parent < 0).astype(np.int64)
    steps = [frontier]
    while len(frontier):
        start = indptr[frontier]
        size = indptr[frontier + 1] - start
        total = int(size.sum())
        # the concatenated ranges indices[start[i]:start[i] + size[i]], in frontier order
        first = np.cumsum(size) - size
        frontier = indices[np.repeat(start - first, size) + np.arange(total, dtype=np.int64)]
        steps.append(frontier)
    order = np.concatenate(steps)
    return Forest(ico.tree_parent, indptr, indices, order, ico.level_of)


def _checked(parent, children_indptr, children_indices):
    """The arrays of :func:`check_forest`, from a :class:`Forest` as they are."""
    if isinstance(parent, Forest):
        if children_indptr is not None or children_indices is not None:
            raise InputError("with a Forest as parent, leave children_indptr and "
                             "children_indices None (the Forest holds them)")
        return parent.parent, parent.indptr, parent.indices, parent.order, parent.depth
    return check_forest(parent, children_indptr, children_indices)


@njit(cache=True, _nrt=False)
def top_bit(m):
    """Index of the highest set bit of ``m >= 0`` (-1 for 0), by halving the width."""
    if m <= 0:
        return -1
    b = 0
    for w in (32, 16, 8, 4, 2, 1):
        if m >> w:
            m >>= w
            b += w
    return b


@njit(cache=True)
def _set_tops(mag, order, indptr, indices):
    """Top bit (-1 for 0) of each magnitude, of the max over D(v) and of the max over L(v)."""
    k, n = mag.shape
    tb = np.full((k, n), -1, dtype=np.int8)
    dtop = np.full((k, n), -1, dtype=np.int8)
    ltop = np.full((k, n), -1, dtype=np.int8)
    for l in range(k):
        for i in range(n):
            tb[l, i] = top_bit(mag[l, i])
        for t in range(n - 1, -1, -1):
            v = order[t]
            d = np.int8(-1)
            g = np.int8(-1)
            for j in range(indptr[v], indptr[v + 1]):
                c = indices[j]
                if tb[l, c] > d:
                    d = tb[l, c]
                if dtop[l, c] > d:
                    d = dtop[l, c]
                if dtop[l, c] > g:
                    g = dtop[l, c]
            dtop[l, v] = d
            ltop[l, v] = g
    return tb, dtop, ltop


# ---------------------------------------------------------------- the coder

@njit(cache=True, _nrt=False)
def _code(mode, est, dst, buf, models, ctx, bit, budget):
    """Encode ``bit`` (mode 0) or decode a bit (mode 1); -1 when the budget is exhausted."""
    if mode == 0:
        if not enc_fits(est, budget):
            return -1
        enc_bit(est, buf, models, ctx, bit)
        return bit
    if not dec_fits(dst, budget):
        return -1
    return dec_bit(dst, buf, models, ctx)


@njit(cache=True, _nrt=False)
def _sig_ctx(l, i, p, depth, parent, sigp, nsc, nsl, group, src):
    """Context of the significance test of coefficient ``i`` of layer ``l`` at plane ``p``.

    ``i`` is insignificant in layer ``l`` when it is tested, so ``nsc[l, parent]`` (significant
    children of its parent) counts exactly its significant siblings and ``nsl[i, group[l]]``
    (significant layers of ``i`` in that group) exactly its other significant layers."""
    lc = l if l < _NL - 1 else _NL - 1
    d = depth[i]
    if d > _ND - 1:
        d = _ND - 1
    par = parent[i]
    ps = 0
    sib = 0
    if par >= 0:
        if sigp[l, par] >= 0:
            ps = sigp[l, par] - p
            ps = 3 if ps >= 2 else ps + 1
        sib = nsc[l, par]
        if sib > 2:
            sib = 2
    oth = nsl[i, group[l]]
    if oth > 2:
        oth = 2
    return _B_SIG + ((((lc * _ND + d) * 4 + ps) * 3 + oth) * 3 + sib) * 2 + src


@njit(cache=True, _nrt=False)
def _sign_ctx(l, i, parent, sigp, neg):
    lc = l if l < _NL - 1 else _NL - 1
    par = parent[i]
    s = 0
    if par >= 0 and sigp[l, par] >= 0:
        s = 2 if neg[l, par] else 1
    return _B_SIGN + lc * 3 + s


@njit(cache=True, _nrt=False)
def _newly_significant(mode, est, dst, buf, models, budget, l, i, p, parent, depth, sigp, neg,
                       mag, sgn, lsp, lsp_len, lsp_rows, lsp_mag, nsc, nsl, group):
    """Code the sign of a coefficient found significant at plane ``p``, append it to the LSP
    and count it in its parent's significant children and its node's significant layers.

    The LSP keeps, in list order, what the refinement passes read and write: ``lsp[l, r]`` the
    node, ``lsp_rows[l, r]`` its ``(plane of significance, min(depth, 3), lowest known plane)``,
    ``lsp_mag[l, r]`` its magnitude (encoder) then its known bits."""
    b = 0
    if mode == 0:
        b = sgn[l, i]
    b = _code(mode, est, dst, buf, models, _sign_ctx(l, i, parent, sigp, neg), b, budget)
    if b < 0:
        return False
    sigp[l, i] = p
    neg[l, i] = b
    r = lsp_len[l]
    lsp[l, r] = i
    lsp_rows[l, r, 0] = p
    lsp_rows[l, r, 1] = min(depth[i], 3)
    lsp_rows[l, r, 2] = p
    lsp_mag[l, r, 0] = mag[l, i] if mode == 0 else 0
    lsp_mag[l, r, 1] = np.int64(1) << p
    lsp_len[l] = r + 1
    if parent[i] >= 0:
        nsc[l, parent[i]] += 1
    nsl[i, group[l]] += 1
    return True


@njit(cache=True)
def _run(mode, buf, budget, est, dst, models, k, n, top, final, parent, indptr, indices, depth,
         tb, dtop, ltop, mag, sgn, cut, group, dmax, sched, marks):
    """The SPIHT passes; returns (complete, sigp, neg, known, lo, done): ``done`` is the lowest
    plane whose sorting and refinement passes all finished (``top + 1`` if none did).

    ``cut[v]`` marks a node whose children the encoder's forest has and this one lacks (a forest
    cut at a depth); the passes end, as at the end of the stream, where the stream first codes
    a coefficient below one of them.

    Layer ``l`` belongs to group ``group[l]`` and lives on the forest cut below depth
    ``dmax[l]``. ``sched`` lists the passes in stream order: row ``(g, p)`` codes the sorting
    and refinement passes of plane ``p`` of group ``g``'s layers; ``marks[s]`` receives the
    coder's ``(shifts, range)`` after row ``s`` (encoder) or stays untouched. ``done`` is the
    lowest plane group 0 finished.

    A long run (a budget of more bytes than nodes: the full-rate pricing of the passes) runs
    the passes on the forest relabelled in breadth-first order (:func:`_bfs_relabel`): the
    lists then visit nodes close in memory, and as the roots keep their order and every node
    its children's order, every decision is the same. A short run keeps the caller's labels,
    as relabelling would cost more than it saves."""
    sigp = np.full((k, n), -1, dtype=np.int8)
    neg = np.zeros((k, n), dtype=np.uint8)
    lsp = np.empty((k, n), dtype=np.int64)
    lsp_len = np.zeros(k, dtype=np.int64)
    lsp_rows = np.empty((k, n, 3), dtype=np.int8)
    lsp_mag = np.empty((k, n, 2), dtype=np.int64)
    if budget > n:
        order, b_parent, b_indptr, b_indices = _bfs_relabel(parent, indptr, indices)
        if tb.shape[1] == n:      # the encoder's tables (the decoder passes (k, 1) dummies)
            tb, dtop, ltop, mag, sgn = tb[:, order], dtop[:, order], ltop[:, order], \
                mag[:, order], sgn[:, order]
        complete, gdone = _passes(mode, buf, budget, est, dst, models, k, n, top, b_parent,
                                  b_indptr, b_indices, depth[order], tb, dtop, ltop, mag, sgn,
                                  cut[order], group, dmax, sched, marks, sigp, neg, lsp,
                                  lsp_len, lsp_rows, lsp_mag)
        # back to the caller's node ids
        sigp[:, order] = sigp.copy()
        neg[:, order] = neg.copy()
        for l in range(k):
            for r in range(lsp_len[l]):
                lsp[l, r] = order[lsp[l, r]]
    else:
        complete, gdone = _passes(mode, buf, budget, est, dst, models, k, n, top, parent,
                                  indptr, indices, depth, tb, dtop, ltop, mag, sgn, cut, group,
                                  dmax, sched, marks, sigp, neg, lsp, lsp_len, lsp_rows, lsp_mag)
    # the known bits and lowest known plane of every significant coefficient, from the LSP
    known = np.zeros((k, n), dtype=np.int64)
    lo = np.zeros((k, n), dtype=np.int8)
    for l in range(k):
        for r in range(lsp_len[l]):
            known[l, lsp[l, r]] = lsp_mag[l, r, 1]
            lo[l, lsp[l, r]] = lsp_rows[l, r, 2]
    return complete, sigp, neg, known, lo, gdone


@njit(cache=True)
def _bfs_relabel(parent, indptr, indices):
    """The forest relabelled in breadth-first order: node ``u`` of the result is ``order[u]``.

    Returns
    -------
    order : (n,) int64
        :func:`_bfs` order: the roots in their order, then each node's children in its order.
    parent, indptr, indices : (n,), (n + 1,), (n - n_roots,) int64
        The relabelled forest (each node's children are consecutive ids).
    """
    n = parent.shape[0]
    order, _, _ = _bfs(parent, indptr, indices)
    inv = np.empty(n, dtype=np.int64)
    for u in range(n):
        inv[order[u]] = u
    b_parent = np.empty(n, dtype=np.int64)
    b_indptr = np.empty(n + 1, dtype=np.int64)
    b_indices = np.empty(indices.shape[0], dtype=np.int64)
    b_indptr[0] = 0
    t = 0
    for u in range(n):
        v = order[u]
        b_parent[u] = inv[parent[v]] if parent[v] >= 0 else -1
        for j in range(indptr[v], indptr[v + 1]):
            b_indices[t] = inv[indices[j]]
            t += 1
        b_indptr[u + 1] = t
    return order, b_parent, b_indptr, b_indices


@njit(cache=True)
def _passes(mode, buf, budget, est, dst, models, k, n, top, parent, indptr, indices, depth,
            tb, dtop, ltop, mag, sgn, cut, group, dmax, sched, marks, sigp, neg, lsp, lsp_len,
            lsp_rows, lsp_mag):
    """The passes of :func:`_run` on its state (``sigp``, ``neg`` and the LSP arrays of
    :func:`_newly_significant`, updated); returns ``(complete, done)``."""
    lip = np.empty((k, n), dtype=np.int64)
    cap = 3 * n + 4
    lis = np.empty((k, cap), dtype=np.int64)
    lip_len = np.zeros(k, dtype=np.int64)
    lis_len = np.zeros(k, dtype=np.int64)
    lsp_old = np.zeros(k, dtype=np.int64)
    # counts the contexts read, kept as the state changes: significant children of each node
    # (per layer), and significant coefficients, D sets and L sets of each node (per group)
    n_groups = group.max() + 1
    nsc = np.zeros((k, n), dtype=np.int32)
    nsl = np.zeros((n, n_groups), dtype=np.int32)
    nds = np.zeros((n, n_groups), dtype=np.int32)
    nls = np.zeros((n, n_groups), dtype=np.int32)
    for l in range(k):
        for i in range(n):
            if parent[i] < 0:
                lip[l, lip_len[l]] = i
                lip_len[l] += 1
                if (indptr[i + 1] > indptr[i] or cut[i]) and depth[i] < dmax[l]:
                    lis[l, lis_len[l]] = 2 * i
                    lis_len[l] += 1
    has_gc = np.zeros(n, dtype=np.uint8)
    for i in range(n):
        for j in range(indptr[i], indptr[i + 1]):
            c = indices[j]
            if indptr[c + 1] > indptr[c] or cut[c]:
                has_gc[i] = 1
                break
    gdone = top + 1

    for s in range(sched.shape[0]):
        g = sched[s, 0]
        p = sched[s, 1]
        if g == 0:
            gdone = p + 1
        for l in range(k):
            lsp_old[l] = lsp_len[l]
        # ------------------------------------------------ sorting passes
        for l in range(k):
            if group[l] != g:
                continue
            lc = l if l < _NL - 1 else _NL - 1
            # LIP
            w = 0
            m0 = lip_len[l]
            for r in range(m0):
                i = lip[l, r]
                b = 0
                if mode == 0:
                    b = 1 if tb[l, i] >= p else 0
                ctx = _sig_ctx(l, i, p, depth, parent, sigp, nsc, nsl, group, 0)
                b = _code(mode, est, dst, buf, models, ctx, b, budget)
                if b < 0:
                    return False, gdone
                if b == 1:
                    if not _newly_significant(mode, est, dst, buf, models, budget, l, i, p,
                                              parent, depth, sigp, neg, mag, sgn, lsp, lsp_len,
                                              lsp_rows, lsp_mag, nsc, nsl, group):
                        return False, gdone
                else:
                    lip[l, w] = i
                    w += 1
            lip_len[l] = w
            # LIS
            r = 0
            w = 0
            end = lis_len[l]
            while r < end:
                e = lis[l, r]
                r += 1
                v = e >> 1
                d = depth[v]
                if d > _ND - 1:
                    d = _ND - 1
                if (e & 1) == 0:
                    # type A: D(v), still insignificant in layer l: nds counts the other layers
                    oth = nds[v, g]
                    if oth > 2:
                        oth = 2
                    ss = 1 if sigp[l, v] >= 0 else 0
                    ctx = _B_SETA + ((lc * _ND + d) * 2 + ss) * 3 + oth
                    b = 0
                    if mode == 0:
                        b = 1 if dtop[l, v] >= p else 0
                    b = _code(mode, est, dst, buf, models, ctx, b, budget)
                    if b < 0:
                        return False, gdone
                    if b == 0:
                        lis[l, w] = e
                        w += 1
                        continue
                    if cut[v]:
                        return False, gdone
                    nds[v, g] += 1
                    for j in range(indptr[v], indptr[v + 1]):
                        c = indices[j]
                        b = 0
                        if mode == 0:
                            b = 1 if tb[l, c] >= p else 0
                        ctx = _sig_ctx(l, c, p, depth, parent, sigp, nsc, nsl, group, 1)
                        b = _code(mode, est, dst, buf, models, ctx, b, budget)
                        if b < 0:
                            return False, gdone
                        if b == 1:
                            if not _newly_significant(mode, est, dst, buf, models, budget, l, c,
                                                      p, parent, depth, sigp, neg, mag, sgn,
                                                      lsp, lsp_len, lsp_rows, lsp_mag, nsc,
                                                      nsl, group):
                                return False, gdone
                        else:
                            lip[l, lip_len[l]] = c
                            lip_len[l] += 1
                    if has_gc[v] and depth[v] + 1 < dmax[l]:
                        lis[l, end] = e | 1
                        end += 1
                else:
                    # type B: L(v), still insignificant in layer l: nls counts the other layers
                    oth = nls[v, g]
                    if oth > 2:
                        oth = 2
                    sc = nsc[l, v]
                    if sc > 2:
                        sc = 2
                    ctx = _B_SETB + ((lc * _ND + d) * 3 + sc) * 3 + oth
                    b = 0
                    if mode == 0:
                        b = 1 if ltop[l, v] >= p else 0
                    b = _code(mode, est, dst, buf, models, ctx, b, budget)
                    if b < 0:
                        return False, gdone
                    if b == 0:
                        lis[l, w] = e
                        w += 1
                        continue
                    nls[v, g] += 1
                    for j in range(indptr[v], indptr[v + 1]):
                        c = indices[j]
                        if (indptr[c + 1] > indptr[c] or cut[c]) and depth[c] < dmax[l]:
                            lis[l, end] = 2 * c
                            end += 1
            lis_len[l] = w
        # ------------------------------------------------ refinement passes
        for l in range(k):
            if group[l] != g:
                continue
            lc = l if l < _NL - 1 else _NL - 1
            for r in range(lsp_old[l]):
                age = lsp_rows[l, r, 0] - p - 1
                if age > 2:
                    age = 2
                ctx = _B_REF + (lc * 3 + age) * 4 + lsp_rows[l, r, 1]
                b = 0
                if mode == 0:
                    b = np.int64((lsp_mag[l, r, 0] >> p) & 1)
                b = _code(mode, est, dst, buf, models, ctx, b, budget)
                if b < 0:
                    return False, gdone
                lsp_mag[l, r, 1] |= np.int64(b) << p
                lsp_rows[l, r, 2] = p
        if g == 0:
            gdone = p
        if mode == 0:
            marks[s, 0] = est[5]
            marks[s, 1] = est[1]
    return True, gdone


def _dequantize(q, lo, negative, step):
    """The reconstruction rule of the module docstring: magnitudes ``q`` known down to bit plane
    ``lo`` (array or scalar) at the midpoint of their interval, 0 where ``q`` is 0 (a coefficient
    is significant exactly when a bit of it is known to be 1), with their signs."""
    lo64 = np.asarray(lo, dtype=np.int64)
    frac = np.where(lo64 > 0, np.ldexp(1.0, lo64 - 1) - 0.5, 0.0)
    val = np.where(q > 0, (q.astype(np.float64) + frac) * step, 0.0)
    return np.where(negative, -val, val)


@njit(cache=True)
def _reconstruct(neg, known, lo, step):
    """:func:`_dequantize` of the decoder's layer-major state, node-major: ``(n, k)`` float64,
    the same floating-point operations element by element."""
    k, n = known.shape
    frac = np.zeros(MAX_PLANE + 1, dtype=np.float64)   # the midpoint offset of each lowest plane
    for b in range(1, MAX_PLANE + 1):
        frac[b] = np.ldexp(1.0, b - 1) - 0.5
    out = np.empty((n, k), dtype=np.float64)
    for i in range(n):
        for l in range(k):
            q = known[l, i]
            val = 0.0
            if q > 0:
                val = (np.float64(q) + frac[lo[l, i]]) * step
            out[i, l] = -val if neg[l, i] != 0 else val
    return out


# ---------------------------------------------------------------- anchors
@dataclass(frozen=True)
class DecodedPlanes:
    """What a decoder knows of the quantised magnitudes.

    Attributes
    ----------
    magnitudes : (n, k) int64
        The decoded bits of ``q = floor(|c| / step + 1/2)`` (bits below a coefficient's lowest
        decoded plane are 0).
    negative : (n, k) bool
    done : int
        Every plane ``>= done`` was decoded in full, so every ``q``'s bits from ``done`` up are
        known exactly.
    step : float
    """

    magnitudes: np.ndarray
    negative: np.ndarray
    done: int
    step: float


def _anchor(q: np.ndarray, negative: np.ndarray, plane: int, step: float) -> np.ndarray:
    return _dequantize((q >> plane) << plane, plane, negative, step)


def quantize_to_plane(coeffs, plane: int, step: float) -> np.ndarray:
    """Coefficients as a decoder that knows their bits down to ``plane`` reconstructs them.

    Parameters
    ----------
    coeffs : (n, k) float64
    plane : int
        Lowest known bit plane (>= 0).
    step : float
        The coder's quantisation step.

    Returns
    -------
    (n, k) float64
        ``(q_a + 2**(plane-1) - 1/2) · step`` with the sign, ``q_a`` the quantised magnitude with
        its bits below ``plane`` cleared (``q_a · step`` for plane 0; 0 where ``q_a = 0``): what
        :func:`anchor_values` gives at the decoder once plane ``plane`` is decoded.
    """
    c = np.asarray(coeffs, np.float64)
    q = np.floor(np.abs(c) / step + 0.5).astype(np.int64)
    return _anchor(q, c < 0, int(plane), float(step))


def anchor_values(decoded: DecodedPlanes, plane: int, *, rows: int | None = None,
                  layers: int | None = None) -> np.ndarray | None:
    """:func:`quantize_to_plane` of the encoder's coefficients, from a decoder's bits.

    Parameters
    ----------
    decoded : DecodedPlanes
    plane : int
    rows, layers : int, optional
        Only the first ``rows`` coefficients of the first ``layers`` layers (default all).

    Returns
    -------
    (rows, layers) float64 or None
        Bit-identical to the encoder's ``quantize_to_plane(coeffs[:rows, :layers], plane, step)``
        when every plane down to ``plane`` was decoded (``decoded.done <= plane``); else None.
    """
    if decoded.done > plane:
        return None
    sl = (slice(rows), slice(layers))
    return _anchor(decoded.magnitudes[sl], decoded.negative[sl], int(plane), decoded.step)


# ---------------------------------------------------------------- header

def pack_header(header: dict) -> bytes:
    """Store a zerotree header in :data:`HEADER_SIZE` bytes.

    Parameters
    ----------
    header : dict
        ``{"version", "top_plane", "final_plane", "step"}`` as returned by :func:`encode`.

    Returns
    -------
    bytes
    """
    try:
        return _HEADER.pack(int(header["version"]), int(header["top_plane"]),
                            int(header["final_plane"]), 0, float(header["step"]))
    except (KeyError, struct.error, TypeError, ValueError) as exc:
        raise InputError(f"invalid zerotree header {header!r} ({exc})") from exc


def unpack_header(data: bytes) -> dict:
    """Read a header written by :func:`pack_header`.

    Parameters
    ----------
    data : bytes
        Exactly :data:`HEADER_SIZE` bytes.

    Returns
    -------
    dict
        ``{"version", "top_plane", "final_plane", "step"}``.

    Raises
    ------
    BitstreamError
        Wrong length, unknown version, or out-of-range values.
    """
    if len(data) != HEADER_SIZE:
        raise BitstreamError(f"zerotree header must be {HEADER_SIZE} bytes, got {len(data)}")
    version, top, final, _, step = _HEADER.unpack(bytes(data))
    header = {"version": version, "top_plane": top, "final_plane": final, "step": step}
    _check_header(header)
    return header


def _check_header(header):
    try:
        version = int(header["version"])
        top = int(header["top_plane"])
        final = int(header["final_plane"])
        step = float(header["step"])
    except (KeyError, TypeError, ValueError) as exc:
        raise BitstreamError(f"invalid zerotree header {header!r} ({exc})") from exc
    if version != VERSION:
        raise BitstreamError(f"unsupported zerotree stream version {version} (this reader knows "
                             f"version {VERSION}); upgrade surfidx")
    if not (-1 <= top <= MAX_PLANE) or not (0 <= final <= MAX_PLANE):
        raise BitstreamError(f"zerotree header planes out of range (top {top}, final {final})")
    if not (np.isfinite(step) and step > 0):
        raise BitstreamError(f"zerotree header step must be finite and positive, got {step}")
    return top, final, step


# ---------------------------------------------------------------- public API

def encode(coeffs, parent, children_indptr, children_indices, *, step: float = 1.0,
           final_plane: int = 0, top_plane: int | None = None, max_bytes: int | None = None):
    """Code coefficients on a forest into one embedded stream.

    Parameters
    ----------
    coeffs : (n, k) float64
        Coefficients, one row per tree node, one column per layer (a 1-D array is one layer).
    parent : (n,) int64 or Forest
        Parent of every node, ``-1`` for roots; or a :class:`Forest` (:func:`forest`), the
        children arguments then None.
    children_indptr : (n + 1,) int64 or None
        CSR row pointer of the children lists.
    children_indices : (n - n_roots,) int64 or None
        CSR column indices (the children of every node).
    step : float
        Quantisation step (rounded to float32): magnitudes are coded as
        ``floor(|c| / step + 1/2)``.
    final_plane : int
        Last bit plane coded (0 = full precision of the quantised integers).
    top_plane : int, optional
        First bit plane; default the top bit of the largest quantised magnitude. A larger value
        costs a few bits per plane; a smaller one is an error.
    max_bytes : int, optional
        Byte budget; the stream stops at the last decision that fits and is then exactly
        ``max_bytes`` long. Any value ``>= 4`` is accepted.

    Returns
    -------
    stream : bytes
        The embedded stream; any prefix decodes (:func:`decode`).
    header : dict
        ``{"version": 1, "top_plane": int, "final_plane": int, "step": float}``, what
        :func:`decode` needs besides the stream (:func:`pack_header` stores it in 8 bytes).

    Raises
    ------
    InputError
        Bad shapes, a forest that is not one, non-finite coefficients, a step too small for the
        coefficients, a bad plane or budget.
    """
    return encode_prepared(prepare(coeffs, parent, children_indptr, children_indices, step=step,
                                   final_plane=final_plane, top_plane=top_plane),
                           max_bytes=max_bytes)


@dataclass(frozen=True)
class Prepared:
    """Coefficients quantised on a validated forest, ready to be coded at any budget
    (:func:`prepare`, :func:`encode_prepared`): the work of :func:`encode` that does not depend
    on the budget, done once for an encoder that codes one model at several rates.

    Attributes
    ----------
    header : dict
        ``{"version", "top_plane", "final_plane", "step"}`` (as :func:`encode` returns it).
    parent, indptr, indices : (n,), (n + 1,), (n - n_roots,) int64
        The forest (:func:`check_forest`).
    depth : (n,) int64
    magnitudes : (k, n) int64
        Quantised magnitudes, layer-major.
    negative : (k, n) uint8
    tops : tuple of three (k, n) int8
        Top bit of each magnitude, of its descendants' largest and of its grand-descendants'.
    """

    header: dict
    parent: np.ndarray
    indptr: np.ndarray
    indices: np.ndarray
    depth: np.ndarray
    magnitudes: np.ndarray
    negative: np.ndarray
    tops: tuple


def prepare(coeffs, parent, children_indptr, children_indices, *, step: float = 1.0,
            final_plane: int = 0, top_plane: int | None = None) -> Prepared:
    """Validate and quantise coefficients for :func:`encode_prepared` (see :func:`encode` for
    the parameters).

    Returns
    -------
    Prepared

    Raises
    ------
    InputError
        As :func:`encode`.
    """
    parent, indptr, indices, order, depth = _checked(parent, children_indptr, children_indices)
    n = parent.shape[0]
    c = as_array(coeffs, "coeffs", dtype=np.float64)
    if c.ndim == 1:
        c = c[:, None]
    if c.ndim != 2 or c.shape[0] != n:
        raise InputError(f"coeffs must have shape ({n}, k) to match the forest, got {c.shape}")
    step32 = float(np.float32(step)) if np.isfinite(step) else float("nan")
    if not (step32 > 0 and np.isfinite(step32)):
        raise InputError(f"step must be a positive finite float32, got {step!r}")
    if isinstance(final_plane, bool) or not isinstance(final_plane, (int, np.integer)) \
            or not 0 <= final_plane <= MAX_PLANE:
        raise InputError(f"final_plane must be an integer in [0, {MAX_PLANE}], got "
                         f"{final_plane!r}")
    with np.errstate(over="ignore"):     # a step too small overflows to inf: refused below
        q = np.floor(np.abs(c) / step32 + 0.5)
    if q.size and q.max() >= 2.0 ** MAX_PLANE:
        raise InputError(f"step {step32} is too small for coefficients up to {np.abs(c).max()}: "
                         f"quantised magnitudes must stay below 2**{MAX_PLANE}")
    mag = np.ascontiguousarray(q.T.astype(np.int64))
    sgn = np.ascontiguousarray((c < 0).T.astype(np.uint8))
    data_top = int(mag.max()).bit_length() - 1 if mag.size else -1
    top = data_top if top_plane is None else int(top_plane)
    if top < data_top or top > MAX_PLANE:
        raise InputError(f"top_plane must be in [{data_top}, {MAX_PLANE}] for these "
                         f"coefficients, got {top_plane}")
    header = {"version": VERSION, "top_plane": top, "final_plane": int(final_plane),
              "step": step32}
    return Prepared(header=header, parent=parent, indptr=indptr, indices=indices, depth=depth,
                    magnitudes=mag, negative=sgn, tops=_set_tops(mag, order, indptr, indices))


def plane_schedule(top: int, final: int) -> np.ndarray:
    """The schedule of a one-group stream: plane ``top`` down to ``final``, all layers in each.

    Returns
    -------
    (top - final + 1, 2) int64
        Rows ``(0, p)``.
    """
    planes = np.arange(int(top), int(final) - 1, -1, dtype=np.int64)
    return np.ascontiguousarray(np.column_stack([np.zeros_like(planes), planes]))


def group_schedule(order, tops, final: int) -> np.ndarray:
    """The passes of a schedule of groups: each group's planes from its own top down to
    ``final``, in the order ``order`` names the groups.

    Parameters
    ----------
    order : sequence of int
        The group of each pass in stream order; group ``g`` appears ``tops[g] - final + 1``
        times.
    tops : sequence of int
        Top plane of each group.
    final : int

    Returns
    -------
    (len(order), 2) int64
        Rows ``(group, plane)``.

    Raises
    ------
    InputError
        When a group's passes do not add up to its planes.
    """
    order = np.asarray(order, np.int64).ravel()
    nxt = [int(t) for t in tops]
    out = np.empty((len(order), 2), np.int64)
    for s, g in enumerate(order):
        if not 0 <= g < len(nxt) or nxt[g] < final:
            raise InputError(f"schedule names group {int(g)} beyond its planes "
                             f"(tops {list(tops)}, final plane {final})")
        out[s] = g, nxt[g]
        nxt[g] -= 1
    if any(t != final - 1 for t in nxt):
        raise InputError(f"schedule leaves planes of some group uncoded (tops {list(tops)}, "
                         f"final plane {final})")
    return out


def _layout(k: int, groups, depth_limits):
    """Group and depth limit of each layer (defaults: one group, the whole forest)."""
    g = np.zeros(k, np.int64) if groups is None else np.asarray(groups, np.int64).ravel()
    d = np.full(k, np.iinfo(np.int64).max, np.int64) if depth_limits is None else \
        np.asarray(depth_limits, np.int64).ravel()
    if g.shape != (k,) or d.shape != (k,) or g.min() < 0 or d.min() < 0:
        raise InputError(f"groups and depth_limits need one non-negative entry per layer "
                         f"({k}), got {g.tolist()} and {d.tolist()}")
    return np.ascontiguousarray(g), np.ascontiguousarray(d)


def encode_prepared(prepared: Prepared, *, max_bytes: int | None = None, schedule=None,
                    groups=None, depth_limits=None, marks: bool = False):
    """:func:`encode` of prepared coefficients (:func:`prepare`): the same stream and header.

    Parameters
    ----------
    prepared : Prepared
    max_bytes : int, optional
        As for :func:`encode`.
    schedule : (s, 2) int64, optional
        Passes ``(group, plane)`` in stream order (:func:`group_schedule`); default
        :func:`plane_schedule` of the header's planes (one group).
    groups : (k,) int, optional
        Group of each layer (default all 0). Layers see only their own group's significance
        in their contexts, so each group codes as it would alone.
    depth_limits : (k,) int, optional
        Deepest forest depth of each layer (default: all); coefficients below it must be 0
        and are never coded.
    marks : bool
        Also return the coder's position after each pass: ``(s,)`` float64 bits.

    Returns
    -------
    stream : bytes
    header : dict
    bits : (s,) float64
        Only with ``marks``: bits used after each pass (NaN after the budget ran out).

    Raises
    ------
    InputError
        A bad budget.
    """
    if max_bytes is not None and (isinstance(max_bytes, bool) or int(max_bytes) < 4):
        raise InputError(f"max_bytes must be an integer >= 4, got {max_bytes!r}")
    k, n = prepared.magnitudes.shape
    top = prepared.header["top_plane"]
    final_plane = prepared.header["final_plane"]
    tb, dtop, ltop = prepared.tops
    group, dmax = _layout(k, groups, depth_limits)
    sched = plane_schedule(top, final_plane) if schedule is None else \
        np.ascontiguousarray(np.asarray(schedule, np.int64).reshape(-1, 2))
    mk = np.full((len(sched), 2), -1, np.int64)
    limit = np.iinfo(np.int64).max if max_bytes is None else int(max_bytes)
    planes = max(top - int(final_plane) + 1, 0)
    cap = min(limit, n * k * (planes + 3) // 6 + 1024) + 16
    dst = np.zeros(4, dtype=np.int64)
    while True:
        buf = np.zeros(cap, dtype=np.uint8)
        est = new_encoder()
        budget = min(limit, cap - 16)
        complete = _run(0, buf, budget, est, dst, new_models(N_CONTEXTS), k, n, top,
                        int(final_plane), prepared.parent, prepared.indptr, prepared.indices,
                        prepared.depth, tb, dtop, ltop, prepared.magnitudes,
                        prepared.negative, np.zeros(n, dtype=np.uint8), group, dmax, sched,
                        mk)[0]
        if complete or budget >= limit:
            break
        cap = 4 * cap
        mk[:] = -1
    size = enc_flush(est, buf)
    out = bytes(buf[:min(size, budget)]), dict(prepared.header)
    if not marks:
        return out
    with np.errstate(divide="ignore"):
        bits = np.where(mk[:, 0] >= 0, 8.0 * mk[:, 0] + 32.0 - np.log2(
            np.maximum(mk[:, 1], 1).astype(np.float64)), np.nan)
    return out + (bits,)


def decode(stream, n: int, k: int, parent, children_indptr, children_indices, *, header,
           max_bytes: int | None = None, planes: bool = False, cut=None, schedule=None,
           groups=None, depth_limits=None):
    """Decode a stream of :func:`encode`, or any prefix of it.

    Parameters
    ----------
    stream : bytes
        The stream or a prefix of it.
    n : int
        Number of tree nodes (must equal ``len(parent)``).
    k : int
        Number of layers.
    parent, children_indptr, children_indices : arrays
        The forest used by the encoder (see :func:`encode`), or a :class:`Forest` and None,
        None.
    header : dict or bytes
        The encoder's header, as a dict or packed by :func:`pack_header`.
    max_bytes : int, optional
        Decode only the first ``max_bytes`` bytes (default: all of ``stream``).
    planes : bool
        Also return the decoded bits (:class:`DecodedPlanes`), for :func:`anchor_values`.
    cut : (n,) bool, optional
        For a forest that is the encoder's cut at a depth (its first ``n`` nodes, closed under
        parents): the nodes whose children were cut off. Decoding then ends, as at the end of
        the stream, at the first decision about a coefficient below them, so memory and time
        follow the ``n`` nodes kept, not the encoder's forest; the coefficients are those of
        the prefix of the stream read so far.
    schedule, groups, depth_limits : optional
        As given to :func:`encode_prepared`.

    Returns
    -------
    coeffs : (n, k) float64
        Reconstruction: midpoints of the intervals the decoded bits leave, 0 where a coefficient
        is not yet significant. Bit-identical to decoding ``encode(..., max_bytes=len(prefix))``.
    decoded : DecodedPlanes
        Only with ``planes=True``.

    Raises
    ------
    BitstreamError
        A bad header, or a stream whose first bytes are an impossible code value.
    InputError
        Bad forest, ``n`` or ``k``.
    """
    if isinstance(header, (bytes, bytearray, memoryview)):
        header = unpack_header(bytes(header))
    top, final, step = _check_header(header)
    parent, indptr, indices, order, depth = _checked(parent, children_indptr, children_indices)
    if int(n) != parent.shape[0]:
        raise InputError(f"n = {n} does not match the forest's {parent.shape[0]} nodes")
    if isinstance(k, bool) or int(k) < 1:
        raise InputError(f"k must be a positive integer, got {k!r}")
    n, k = int(n), int(k)
    if not isinstance(stream, (bytes, bytearray, memoryview, np.ndarray)):
        raise InputError(f"stream must be bytes, got {type(stream).__name__}")
    data = np.frombuffer(bytes(stream), dtype=np.uint8)
    if max_bytes is not None:
        data = data[:max(int(max_bytes), 0)]
    data = data.copy()  # writable, as the shared kernel's signature wants
    budget = data.shape[0]
    dst = np.zeros(4, dtype=np.int64)
    if budget >= 4 and not dec_init(dst, data):
        raise BitstreamError("zerotree stream starts with an impossible code value (FF FF FF FF); "
                             "the stream is damaged")
    if budget < 4:
        dec_init(dst, data)
    if cut is None:
        cut = np.zeros(n, dtype=np.uint8)
    else:
        cut = as_array(np.asarray(cut, bool).astype(np.uint8), "cut", dtype=np.uint8, shape=(n,))
    est = new_encoder()
    group, dmax = _layout(k, groups, depth_limits)
    sched = plane_schedule(top, final) if schedule is None else \
        np.ascontiguousarray(np.asarray(schedule, np.int64).reshape(-1, 2))
    z8 = np.zeros((k, 1), dtype=np.int8)
    _, _, neg, known, lo, done = _run(1, data, budget, est, dst, new_models(N_CONTEXTS), k, n, top,
                                      final, parent, indptr, indices, depth, z8, z8, z8,
                                      np.zeros((k, 1), dtype=np.int64),
                                      np.zeros((k, 1), dtype=np.uint8), cut, group, dmax,
                                      sched, np.zeros((1, 2), np.int64))
    values = _reconstruct(neg, known, lo, step)
    if not planes:
        return values
    return values, DecodedPlanes(magnitudes=np.ascontiguousarray(known.T),
                                 negative=np.ascontiguousarray(neg.T.astype(bool)),
                                 done=int(done), step=float(step))
