"""Handles cut: one short non-separating cycle per handle (greedy homotopy generators).

The surface's holes are first capped by temporary cones (one apex per boundary loop, its edges
given a prohibitive length), which makes it closed without changing its genus. From a root
vertex, a shortest-path tree ``T`` is grown (Dijkstra); a maximum spanning tree ``C`` of the dual
graph over the edges not in ``T``, weighted by the length of each edge's loop through the root
(``d(u) + |uv| + d(v)``), leaves exactly ``2g`` edges out (tree-cotree decomposition, Eppstein
2003). Their loops are the greedy homotopy generators of Erickson & Whittlesey (2005); each is
non-separating. The shortest of them, trimmed to the simple cycle through the lowest common
ancestor of its edge's ends, is cut, over ``options.handle_roots`` roots in farthest-point order.
Edges at a boundary vertex count ``options.rim_penalty`` times their length, so cuts keep off the
holes.

Cutting duplicates every cycle vertex: the faces on one side of the cycle (swept around the vertex
from the edge to the next cycle vertex to the edge to the previous one) take the copy. The two
sides become two new boundary loops, which :mod:`.holes` caps.
"""

from __future__ import annotations

from ..jit import numba
import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import dijkstra, minimum_spanning_tree

from .analysis import _edge_pairs, boundary_loops, edge_table

__all__ = ["cut_shortest_handle"]


@numba.njit(cache=True)
def _cut_wedges(faces, rot, he_sorted_keys, he_sorted_idx, cycle, copies, nv):
    """Give the copy of each cycle vertex to the faces of its wedge from next to previous."""
    k = len(cycle)
    fl = faces.ravel().copy()
    out = faces.copy()
    for i in range(k):
        v, nx, pv = cycle[i], cycle[(i + 1) % k], cycle[(i - 1) % k]
        key = v * nv + nx
        j = np.searchsorted(he_sorted_keys, key)
        h = he_sorted_idx[j]
        steps = 0
        while steps < len(fl):
            f = h // 3
            to = fl[3 * f + (h % 3 + 1) % 3]
            if to == pv:
                break
            for c in range(3):
                if faces[f, c] == v:
                    out[f, c] = copies[i]
            h = rot[h]
            steps += 1
    return out


def _tree_path(pred, v):
    path = [int(v)]
    while pred[path[-1]] >= 0:
        path.append(int(pred[path[-1]]))
    return path


def _generator(V, Fc, weights, he_edge, edges, h1, h2, root, nc):
    """Shortest greedy generator cycle from ``root``: (length, cycle vertices, dist)."""
    ne = len(edges)
    g = sp.coo_matrix((weights, (edges[:, 0], edges[:, 1])), shape=(nc, nc)).tocsr()
    dist, pred = dijkstra(g, directed=False, indices=root, return_predecessors=True)
    pred = np.where(pred < 0, -1, pred)
    in_tree = np.zeros(ne, bool)
    child = np.flatnonzero(pred >= 0)
    tkeys = np.minimum(child, pred[child]) * np.int64(nc) + np.maximum(child, pred[child])
    ekeys = edges[:, 0] * np.int64(nc) + edges[:, 1]
    in_tree[np.searchsorted(ekeys, tkeys)] = True
    # edges of two faces: h1[e_rank] and h2 give the faces across each edge
    pair_edge = he_edge[h1]
    fa, fb = h1 // 3, h2 // 3
    sel = ~in_tree[pair_edge]
    pe, fa, fb = pair_edge[sel], fa[sel], fb[sel]
    sigma = dist[edges[pe, 0]] + dist[edges[pe, 1]] + weights[pe]
    mf = len(Fc)
    lo, hi = np.minimum(fa, fb), np.maximum(fa, fb)
    w = sigma.max() + 1.0 - sigma            # maximum spanning tree of sigma
    # one dual edge per face pair (the one of largest sigma)
    order = np.lexsort((w, hi, lo))
    pk = lo[order] * np.int64(mf) + hi[order]
    firsts = np.ones(len(pk), bool)
    firsts[1:] = pk[1:] != pk[:-1]
    cand = order[firsts]
    dual = sp.coo_matrix((w[cand], (lo[cand], hi[cand])), shape=(mf, mf)).tocsr()
    mst = minimum_spanning_tree(dual).tocoo()
    mkeys = np.sort(np.minimum(mst.row, mst.col) * np.int64(mf) + np.maximum(mst.row, mst.col))
    in_cotree = np.zeros(len(pe), bool)
    ck = lo[cand] * np.int64(mf) + hi[cand]
    pos = np.clip(np.searchsorted(mkeys, ck), 0, max(len(mkeys) - 1, 0))
    in_cotree[cand] = (mkeys[pos] == ck) if len(mkeys) else False
    left = np.flatnonzero(~in_cotree)
    best = None
    for i in left[np.argsort(sigma[left], kind="stable")]:
        u, v = edges[pe[i]]
        pu, pv = _tree_path(pred, u), _tree_path(pred, v)
        su = set(pu)
        lca = next(x for x in pv if x in su)
        cu = pu[:pu.index(lca) + 1][::-1]          # lca ... u
        cv = pv[:pv.index(lca)]                     # v ... (child of lca)
        length = sigma[i] - 2 * dist[lca]
        if best is not None and length >= best[0]:
            continue
        best = (float(length), np.array(cu + cv, np.int64))
    return best, dist, len(left)


def cut_shortest_handle(V: np.ndarray, F: np.ndarray, options):
    """Cut the surface along its shortest greedy generator cycle.

    Parameters
    ----------
    V : (n, 3) float64
    F : (m, 3) int64
        One oriented manifold piece of genus at least 1 (boundary loops allowed).
    options : RepairOptions

    Returns
    -------
    faces : (m, 3) int64
        ``F`` with the corners on one side of the cycle renumbered to the copies.
    cycle : (k,) int64
        The cycle's vertices, in order.
    copies : (k,) int64
        ``n + arange(k)``: the copy of each cycle vertex (same position).
    generators : int
        Generator loops found (``2 g``).
    """
    n = len(V)
    loops = boundary_loops(F, n)
    rim = np.zeros(n, bool)
    cone_faces, cone_pos = [], []
    for i, loop in enumerate(loops):
        rim[loop] = True
        c = n + i
        cone_faces.append(np.column_stack([np.roll(loop, -1), loop, np.full(len(loop), c)]))
        cone_pos.append(V[loop].mean(axis=0))
    nc = n + len(loops)
    Fc = np.vstack([F] + cone_faces) if loops else F
    Vc = np.vstack([V] + [np.array(cone_pos)]) if loops else V
    he_edge, edges, count = edge_table(Fc, nc)
    h1, h2 = _edge_pairs(he_edge, count)
    length = np.linalg.norm(Vc[edges[:, 0]] - Vc[edges[:, 1]], axis=1)
    scale = float(length[edges[:, 1] < n].sum()) + 1.0
    cone_edge = edges[:, 1] >= n                   # edges sorted: the cone apex is the larger
    weights = np.where(rim[np.minimum(edges[:, 0], n - 1)] | rim[np.minimum(edges[:, 1], n - 1)],
                       length * options.rim_penalty, length)
    weights = np.where(cone_edge, 10.0 * scale, weights)
    weights = np.maximum(weights, 1e-12 * scale)   # dijkstra ignores zero-length edges
    used = np.zeros(nc, bool)
    used[F.ravel()] = True
    free = np.flatnonzero(~rim[:n] & used[:n])
    root = int(free[0]) if len(free) else int(np.flatnonzero(used)[0])
    near = np.full(nc, np.inf)
    best, gens = None, 0
    for _ in range(options.handle_roots):
        found, dist, gens = _generator(Vc, Fc, weights, he_edge, edges, h1, h2, root, nc)
        if found is not None and (best is None or found[0] < best[0]):
            best = found
        near = np.minimum(near, dist)
        score = np.where((np.arange(nc) < n) & used & np.isfinite(near), near, -np.inf)
        root = int(np.argmax(score))
    cycle = best[1]
    k = len(cycle)
    copies = nc + np.arange(k, dtype=np.int64)
    # rotation of half-edges around their start vertex: rot(h) = twin(prev(h))
    mc = len(Fc)
    twin = np.empty(3 * mc, np.int64)
    twin[h1], twin[h2] = h2, h1
    hh = np.arange(3 * mc)
    prev = 3 * (hh // 3) + (hh % 3 + 2) % 3
    rot = twin[prev]
    a = Fc.ravel()
    b = np.roll(Fc, -1, axis=1).ravel()
    dkey = a * np.int64(nc) + b
    order = np.argsort(dkey)
    out = _cut_wedges(Fc, rot, dkey[order], order.astype(np.int64), cycle, copies, np.int64(nc))
    out = out[:len(F)]
    out = np.where(out >= nc, out - len(loops), out)
    return np.ascontiguousarray(out), cycle, copies - len(loops), gens
