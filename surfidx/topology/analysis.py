"""Combinatorial analysis of a triangle mesh: edges, fans, components, orientation, boundary
loops, Euler characteristic.

Every function works on ``faces : (m, 3) int64`` over ``n`` vertices, vectorised with numpy and
scipy's sparse graphs; the one sequential walk (tracing boundary loops) is a numba kernel.
Half-edge ``h = 3 f + j`` of face ``f`` runs from corner ``j`` to corner ``j + 1 (mod 3)``;
corner ``c = 3 f + j`` is vertex ``faces[f, j]`` in face ``f``.
"""

from __future__ import annotations

import functools

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

__all__ = ["distinct_corners", "edge_table", "corner_fans", "face_components", "orientation",
           "boundary_loops", "euler_characteristic", "used_count"]


def distinct_corners(faces: np.ndarray) -> np.ndarray:
    """(m,) bool: faces whose three corners are distinct vertices."""
    return (faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2]) \
        & (faces[:, 0] != faces[:, 2])


def edge_table(faces: np.ndarray, n: int):
    """Undirected edges of the half-edges.

    Returns
    -------
    he_edge : (3m,) int64
        Index of each half-edge's undirected edge.
    edges : (e, 2) int64
        Sorted vertex pairs of the edges, in increasing key order.
    count : (e,) int64
        Faces holding each edge.
    """
    a = faces.ravel()
    b = np.roll(faces, -1, axis=1).ravel()
    base = np.int64(max(n, 1))
    key = np.minimum(a, b) * base + np.maximum(a, b)
    keys, he_edge, count = np.unique(key, return_inverse=True, return_counts=True)
    edges = np.column_stack([keys // base, keys % base])
    return he_edge.ravel().astype(np.int64), edges, count.astype(np.int64)


def _edge_pairs(he_edge: np.ndarray, count: np.ndarray):
    """The two half-edges ``(h1, h2)`` of every edge held by exactly two faces."""
    order = np.argsort(he_edge, kind="stable")
    two = count[he_edge[order]] == 2
    pairs = order[two].reshape(-1, 2)
    return pairs[:, 0], pairs[:, 1]


def corner_fans(faces: np.ndarray, n: int, *, table=None) -> np.ndarray:
    """(3m,) int64 fan label of every corner.

    Two corners of one vertex are in one fan when their faces share an edge at that vertex held
    by exactly two faces; edges of one face (boundary) or of three and more (non-manifold) do
    not join fans. A vertex whose corners carry more than one label is pinched. ``table``:
    :func:`edge_table` of these faces, when the caller has it.
    """
    m = len(faces)
    he_edge, _, count = edge_table(faces, n) if table is None else table
    h1, h2 = _edge_pairs(he_edge, count)
    f1, j1 = h1 // 3, h1 % 3
    f2, j2 = h2 // 3, h2 % 3
    s1, e1 = 3 * f1 + j1, 3 * f1 + (j1 + 1) % 3
    s2, e2 = 3 * f2 + j2, 3 * f2 + (j2 + 1) % 3
    fl = faces.ravel()
    same = fl[s1] == fl[s2]           # both half-edges run the same way (inconsistent winding)
    a = np.concatenate([s1, e1])
    b = np.concatenate([np.where(same, s2, e2), np.where(same, e2, s2)])
    g = sp.coo_matrix((np.ones(len(a), np.int8), (a, b)), shape=(3 * m, 3 * m)).tocsr()
    _, lab = connected_components(g, directed=False)
    return lab.astype(np.int64)


def face_components(faces: np.ndarray, n: int):
    """Connected components of the faces through shared vertices.

    Returns
    -------
    count : int
    label : (m,) int64
        Component of each face, numbered by first face.
    """
    m = len(faces)
    if not m:
        return 0, np.zeros(0, np.int64)
    rows = np.repeat(np.arange(m), 3)
    g = sp.coo_matrix((np.ones(3 * m, np.int8), (rows, faces.ravel())), shape=(m, n)).tocsr()
    big = sp.bmat([[None, g], [g.T, None]]).tocsr()
    _, lab = connected_components(big, directed=False)
    flab = lab[:m]
    # renumber by first occurrence so labels follow the face order
    _, first, inv = np.unique(flab, return_index=True, return_inverse=True)
    rank = np.empty(len(first), np.int64)
    rank[np.argsort(first, kind="stable")] = np.arange(len(first))
    return len(first), rank[inv.ravel()]


def orientation(faces: np.ndarray, n: int, *, table=None):
    """Face flips that wind every component consistently (``table``: :func:`edge_table` of
    these faces, when the caller has it).

    Works on the orientation double cover: node ``f`` and ``f + m`` are face ``f`` kept and
    flipped; an edge of two faces joins (kept, kept) when its half-edges run opposite ways, else
    (kept, flipped). A component is orientable when no face meets its own flip. Each component
    keeps the winding of the larger share of its faces (ties: of its first face).

    Returns
    -------
    flip : (m,) bool or None
        Faces to flip; ``None`` when a component is non-orientable.
    """
    m = len(faces)
    he_edge, _, count = edge_table(faces, n) if table is None else table
    h1, h2 = _edge_pairs(he_edge, count)
    fl = faces.ravel()
    f1, f2 = h1 // 3, h2 // 3
    same = fl[h1] == fl[3 * f2 + h2 % 3]
    a = np.concatenate([f1, f1 + m])
    b = np.concatenate([np.where(same, f2 + m, f2), np.where(same, f2, f2 + m)])
    g = sp.coo_matrix((np.ones(len(a), np.int8), (a, b)), shape=(2 * m, 2 * m)).tocsr()
    _, lab = connected_components(g, directed=False)
    keep_lab, flip_lab = lab[:m], lab[m:]
    if np.any(keep_lab == flip_lab):
        return None
    # per double-cover component: how many faces it holds as "kept"
    kept_votes = np.bincount(keep_lab, minlength=lab.max() + 1)
    # face f is flipped when the cover component holding its flipped copy has more kept faces
    a_votes, b_votes = kept_votes[keep_lab], kept_votes[flip_lab]
    flip = b_votes > a_votes
    tie = b_votes == a_votes
    if tie.any():
        # the component's first face keeps its winding: the cover component holding that
        # face's kept copy is the one chosen
        first = np.full(lab.max() + 1, m, np.int64)
        np.minimum.at(first, keep_lab, np.arange(m))
        flip[tie] = first[flip_lab[tie]] < first[keep_lab[tie]]
    return flip


@functools.cache
def _trace_kernel():
    """:func:`_trace` compiled (numba, imported here: a mesh without boundary never loads it)."""
    from ..jit import numba

    return numba.njit(cache=True)(_trace)


def _trace(nxt, starts):  # pragma: no cover - compiled
    n = len(nxt)
    seen = np.zeros(n, np.bool_)
    out = np.empty(len(starts), np.int64)
    offs = np.empty(len(starts) + 1, np.int64)
    k = 0
    loops = 0
    offs[0] = 0
    for s in starts:
        if seen[s]:
            continue
        v = s
        steps = 0
        while not seen[v] and steps <= len(starts):
            seen[v] = True
            out[k] = v
            k += 1
            v = nxt[v]
            steps += 1
        loops += 1
        offs[loops] = k
    return out[:k], offs[:loops + 1]


def boundary_loops(faces: np.ndarray, n: int) -> list:
    """The boundary loops of a manifold, consistently wound mesh.

    Returns
    -------
    list of (k,) int64
        Each loop's vertices in the direction of its faces' half-edges, starting at its smallest
        vertex; loops ordered by that vertex.

    Raises
    ------
    ValueError
        When a vertex starts two boundary half-edges (a pinched vertex not yet split).
    """
    he_edge, _, count = edge_table(faces, n)
    bnd = np.flatnonzero(count[he_edge] == 1)
    if not len(bnd):
        return []
    a = faces.ravel()[bnd]
    b = np.roll(faces, -1, axis=1).ravel()[bnd]
    if len(np.unique(a)) != len(a):
        raise ValueError("a vertex starts two boundary half-edges")
    nxt = np.full(n, -1, np.int64)
    nxt[a] = b
    out, offs = _trace_kernel()(nxt, np.sort(a))
    return [out[offs[i]:offs[i + 1]] for i in range(len(offs) - 1)]


def used_count(faces: np.ndarray, n: int) -> int:
    """Vertices referenced by at least one face."""
    used = np.zeros(n, bool)
    used[faces.ravel()] = True
    return int(used.sum())


def euler_characteristic(faces: np.ndarray, n: int) -> int:
    """V - E + F over the used vertices."""
    _, edges, _ = edge_table(faces, n)
    return used_count(faces, n) - len(edges) + len(faces)
