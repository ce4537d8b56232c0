"""Locally shortest paths on a triangle mesh: the refinement of :mod:`surfidx.geometry.geodesics` for
surfels that carry faces.

A path between two mesh vertices is found in three steps:

1. **corridor**: the triangles whose vertices are all within ``width`` (mesh-edge distance) of
   a spine: the mesh-edge shortest path, with the graph path beside it where they pass a bump on
   different sides. Distances are measured along mesh edges, which never cross a gap between two
   sheets, and the Steiner graph below follows the triangles, so the path never jumps a gap;
2. **Steiner graph** on the corridor (Lanthier, Maheshwari & Sack 2001): ``steiner`` points
   evenly spaced inside every edge, each linked by a straight segment to every point on the other
   edges of its triangles, and to its neighbours along the edge. The mesh vertices are left out,
   except the two ends: a path through a vertex could not slide off it afterwards. Dijkstra on
   this graph gives the sequence of edges the path crosses, and a path whose every segment lies in
   a triangle (a point whose two neighbours share its triangle only touches the edge, and a
   second point on the same edge runs along it: both dropped);
3. **shortening**: the crossing points slide along their edges to the shortest chain, a convex
   problem in their edge parameters with a tridiagonal Hessian, solved by projected Newton steps
   (sweeps of one-point minimisers crawl along a long path; Newton moves it whole). The path
   stays on the surface throughout and ends locally shortest for its edge sequence;
4. **vertex flips**: crossing points that end at a mesh vertex mean the path wraps round it on
   the side Dijkstra chose; the path is moved to the vertex's other side (crossing the spokes of
   its fan there) and kept when that is shorter, until no such move shortens it.

A vertex the true geodesic passes through (a saddle) is reached by the flips; what excess
remains over the exact polyhedral geodesic is the corridor or Steiner resolution missing a
better edge sequence altogether. ``benchmarks/geodesics.py`` prints the error of these paths
against exact (MMP) geodesics and their time.
"""

from __future__ import annotations

from functools import lru_cache

from ..jit import numba
import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import dijkstra

_PIN = 1e-4  # a crossing this close to an edge end (fraction of the edge) is at the vertex

__all__ = ["mesh_edge_graph", "shortest_path_on_mesh"]


def mesh_edge_graph(positions, faces) -> sp.csr_matrix:
    """The mesh edges as a symmetric sparse graph weighted by length.

    Parameters
    ----------
    positions : (n, 3) float64
    faces : (f, 3) int64

    Returns
    -------
    (n, n) scipy.sparse.csr_matrix
    """
    e, _ = _face_edges(faces)
    e = np.concatenate([e, e[:, ::-1]])
    w = np.linalg.norm(positions[e[:, 0]] - positions[e[:, 1]], axis=1)
    n = len(positions)
    return sp.csr_matrix((np.maximum(w, np.finfo(float).tiny), (e[:, 0], e[:, 1])), shape=(n, n))


def _face_edges(faces):
    """The undirected edges of ``faces`` as sorted vertex pairs ``(e, 2)``, and for each face
    the ids of its edges ``(f, 3)`` (corner c owns edge (c, c + 1))."""
    ends = np.sort(np.stack([faces.ravel(), faces[:, [1, 2, 0]].ravel()], 1), 1)
    edges, fe = np.unique(ends, axis=0, return_inverse=True)
    return edges, fe.reshape(-1, 3)


@lru_cache(maxsize=8)
def _face_pairs(m: int):
    """Pairs of a triangle's Steiner points (local numbering: edge c's points are
    ``c * m .. c * m + m - 1``) that lie on different edges."""
    i, j = np.triu_indices(3 * m, 1)
    keep = (i // m) != (j // m)
    return i[keep], j[keep]


def shortest_path_on_mesh(a: int, b: int, spine, *, positions, faces, edge_graph, steiner: int,
                          width: float, tol: float):
    """Locally shortest path between vertices ``a`` and ``b`` on the mesh (see module notes).

    Parameters
    ----------
    a, b : int
        Vertex indices.
    spine : (k,) int64
        Vertices the corridor is built around, ``a`` and ``b`` among them (a mesh-edge path
        from ``a`` to ``b``, possibly with other candidate paths).
    positions : (n, 3) float64
    faces : (f, 3) int64
    edge_graph : (n, n) scipy.sparse.csr_matrix
        :func:`mesh_edge_graph` of the mesh.
    steiner : int
        Steiner points per edge.
    width : float
        Corridor half-width (mesh-edge distance from the spine).
    tol : float
        Shortening stops when no point moves more than ``tol`` (a length).

    Returns
    -------
    points : (m, 3) float64
        The path, from ``a`` to ``b``; every segment lies in a triangle.
    length : float
    """
    if a == b:
        return positions[[a]].copy(), 0.0
    near = dijkstra(edge_graph, directed=True, indices=spine, min_only=True, limit=width)
    inside = np.isfinite(near)
    # with the spine's own triangles, which a long edge (a sliver) may take outside the width
    on_spine = np.zeros(len(positions), bool)
    on_spine[spine] = True
    tri = faces[inside[faces].all(1) | on_spine[faces].any(1)]
    edges, fe = _face_edges(tri)
    m = steiner
    t = np.arange(1, m + 1) / (m + 1)
    p0, p1 = positions[edges[:, 0]], positions[edges[:, 1]]
    pts = (p0[:, None, :] + t[None, :, None] * (p1 - p0)[:, None, :]).reshape(-1, 3)
    ne = len(edges)
    # node numbering: Steiner point q of edge e is e * m + q; then a and b
    na, nb = ne * m, ne * m + 1
    nodes = (fe[:, :, None] * m + np.arange(m)).reshape(len(tri), 3 * m)
    i, j = _face_pairs(m)
    u = [nodes[:, i].ravel(), np.arange(ne)[:, None] * m + np.arange(m - 1)]
    v = [nodes[:, j].ravel(), np.arange(ne)[:, None] * m + np.arange(1, m)]
    for vert, node in ((a, na), (b, nb)):
        # an end sees every point on the edges of its triangles (once: an edge of its own lies
        # in two of them)
        seen = np.unique(nodes[(tri == vert).any(1)])
        u.append(np.full(len(seen), node))
        v.append(seen)
    if ((tri == a).any(1) & (tri == b).any(1)).any():  # a triangle holds both ends
        u.append(np.array([na]))
        v.append(np.array([nb]))
    u = np.concatenate([x.ravel() for x in u])
    v = np.concatenate([x.ravel() for x in v])
    allpts = np.concatenate([pts, positions[[a, b]]])
    w = np.maximum(np.linalg.norm(allpts[u] - allpts[v], axis=1), np.finfo(float).tiny)
    N = len(allpts)
    g = sp.csr_matrix((np.concatenate([w, w]), (np.concatenate([u, v]), np.concatenate([v, u]))),
                      shape=(N, N))
    # connected: the triangles round every spine vertex are in, so the Steiner points of the
    # mesh-edge path's edges link up through their fans
    _, pred = dijkstra(g, directed=True, indices=na, return_predecessors=True)
    seq = [nb]
    while seq[-1] != na:
        seq.append(int(pred[seq[-1]]))
    mid = np.asarray(seq[-2:0:-1], np.int64)
    crossings = list(zip((mid // m).tolist(), t[mid % m].tolist()))
    return _straighten(crossings, a, b, positions, edges, tri, fe, tol)


def _straighten(crossings, a, b, positions, edges, tri, fe, tol, *, max_flips=200):
    """Shorten the path through the edge crossings ``[(edge, s), ...]``, then move it across
    every vertex it is pinned at (crossing points clamped to a vertex: the path wraps round it)
    to the vertex's other side, keeping each move that shortens it."""
    p0, p1 = positions[edges[:, 0]], positions[edges[:, 1]]

    def shorten(cr):
        e = np.array([c[0] for c in cr], np.int64)
        origin = np.concatenate([positions[[a]], p0[e], positions[[b]]])
        direction = np.concatenate([np.zeros((1, 3)), p1[e] - p0[e], np.zeros((1, 3))])
        s = np.concatenate([[0.0], [c[1] for c in cr], [0.0]])
        path = _shorten(origin, direction, s, tol, 500)
        length = float(np.linalg.norm(np.diff(path, axis=0), axis=1).sum())
        return path, list(zip(e.tolist(), s[1:-1].tolist())), length

    fan = _Fans(tri, fe, edges, a, b)
    path, crossings, length = shorten(fan.clean(crossings))
    for _ in range(max_flips):
        flips = []
        for i, j, v in _pinned_runs(crossings, edges):
            alt = fan.other_side(v, crossings, i, j)
            if alt is not None:
                flips.append((i, j, alt))
        if not flips:
            break
        # all at once (a kink often migrates from vertex to vertex), else one at a time
        tries = [flips] + ([[f] for f in flips] if len(flips) > 1 else [])
        for chosen in tries:
            cand = list(crossings)
            for i, j, alt in reversed(chosen):
                cand[i:j + 1] = alt
            cand = shorten(fan.clean(cand))
            if cand[2] < length - tol:
                path, crossings, length = cand
                break
        else:
            break
    return path, length


def _pinned_runs(crossings, edges):
    """Runs ``(i, j, v)`` of consecutive crossings at the same vertex ``v`` (within ``_PIN`` of
    the edge's length: a point whose neighbour sits on the vertex has its optimum there too, so
    the points of a wrap stall at the vertex without being clamped)."""
    at = [int(edges[e, 0]) if s <= _PIN else int(edges[e, 1]) if s >= 1.0 - _PIN else -1
          for e, s in crossings]
    runs = []
    i = 0
    while i < len(at):
        if at[i] < 0:
            i += 1
            continue
        j = i
        while j + 1 < len(at) and at[j + 1] == at[i]:
            j += 1
        runs.append((i, j, at[i]))
        i = j + 1
    return runs


class _Fans:
    """Triangle fans of the corridor's vertices, to route a path round a vertex's other side."""

    def __init__(self, tri, fe, edges, a, b):
        self.tri, self.fe, self.edges = tri, fe, edges
        self.edge_faces = {}
        for f, row in enumerate(fe.tolist()):
            for e in row:
                self.edge_faces.setdefault(e, []).append(f)
        self.end_faces = {a: set(np.flatnonzero((tri == a).any(1)).tolist()),
                          b: set(np.flatnonzero((tri == b).any(1)).tolist())}
        self.a, self.b = a, b

    def clean(self, crossings):
        """Merge consecutive crossings of one edge (a stretch along it), and drop crossings
        whose two neighbours share a triangle with them: there the path only touches the edge
        and turns back into the triangle, and shortening would treat it as a crossing."""
        out = []
        for e, t in crossings:
            if out and out[-1][0] == e:
                continue
            out.append((e, t))
        kept = []
        faces = [self.end_faces[self.a]]
        for e, t in out + [(-1, 0.0)]:
            nxt = self.end_faces[self.b] if e < 0 else set(self.edge_faces[e])
            while kept and faces[-2] & faces[-1] & nxt:
                kept.pop()
                faces.pop()
            if e >= 0:
                kept.append((e, t))
                faces.append(nxt)
        return kept

    def _faces(self, crossings, k, end):
        return set(self.edge_faces[crossings[k][0]]) if 0 <= k < len(crossings) else \
            self.end_faces[end]

    def other_side(self, v, crossings, i, j):
        """Crossings ``[(spoke, s), ...]`` that take the path from crossing ``i - 1`` to
        ``j + 1`` round vertex ``v`` on the side opposite to spokes ``i..j``; ``None`` when the
        fan is not whole in the corridor (or not a disc)."""
        first, last = crossings[i][0], crossings[j][0]
        f_in = self._faces(crossings, i - 1, self.a) & set(self.edge_faces[first])
        f_out = self._faces(crossings, j + 1, self.b) & set(self.edge_faces[last])
        if len(f_in) != 1 or len(f_out) != 1:
            return None
        f, f_out = f_in.pop(), f_out.pop()
        came = first  # walk away from the current side: leave f_in by its other spoke
        alt = []
        for _ in range(64):
            if f == f_out and alt:
                break
            spokes = [e for e in self.fe[f].tolist() if e != came and v in self.edges[e]]
            if len(spokes) != 1:
                return None
            e = spokes[0]
            nxt = [g for g in self.edge_faces[e] if g != f]
            if len(nxt) != 1:
                return None  # the fan leaves the corridor
            alt.append((e, 2 * _PIN if self.edges[e, 0] == v else 1.0 - 2 * _PIN))
            came, f = e, nxt[0]
            if f == f_out:
                break
        else:
            return None
        if f != f_out or any(e == last for e, _ in alt):
            return None
        return alt


@numba.njit(cache=True)
def _chain(origin, direction, s, eps, grad, diag, off):  # pragma: no cover - compiled
    """Length of the smoothed chain (segments ``sqrt(|r|^2 + eps^2)``), its gradient in ``s``
    and its tridiagonal Hessian (``diag``, ``off[i]`` = entry (i, i + 1))."""
    k = origin.shape[0]
    total = 0.0
    grad[:] = 0.0
    diag[:] = 0.0
    off[:] = 0.0
    r = np.empty(3)
    for i in range(k - 1):
        rr = eps * eps
        for c in range(3):
            r[c] = (origin[i + 1, c] + s[i + 1] * direction[i + 1, c]
                    - origin[i, c] - s[i] * direction[i, c])
            rr += r[c] * r[c]
        rho = np.sqrt(rr)
        total += rho
        # d rho / d s_i = -D_i . r / rho ;  d rho / d s_{i+1} = D_{i+1} . r / rho
        da = 0.0
        db = 0.0
        aa = 0.0
        bb = 0.0
        ab = 0.0
        for c in range(3):
            da += direction[i, c] * r[c]
            db += direction[i + 1, c] * r[c]
            aa += direction[i, c] * direction[i, c]
            bb += direction[i + 1, c] * direction[i + 1, c]
            ab += direction[i, c] * direction[i + 1, c]
        grad[i] -= da / rho
        grad[i + 1] += db / rho
        # Hessian of rho in r: (I - r r^T / rho^2) / rho
        diag[i] += (aa - da * da / rr) / rho
        diag[i + 1] += (bb - db * db / rr) / rho
        off[i] -= (ab - da * db / rr) / rho
    return total


@numba.njit(cache=True)
def _shorten(origin, direction, s, tol, max_iter):  # pragma: no cover - compiled
    """Shortest chain through point ``i`` = ``origin[i] + s[i] * direction[i]``, ``s`` in
    [0, 1] (the first and last points fixed: zero directions), by projected Newton steps on the
    convex length (segments smoothed by ``tol``), the Hessian tridiagonal; stops when a step
    moves no point more than ``tol``. Writes ``s``; returns the points."""
    k = origin.shape[0]
    grad = np.empty(k)
    diag = np.empty(k)
    off = np.empty(k)
    free = np.empty(k, np.bool_)
    step = np.empty(k)
    trial = np.empty(k)
    cp = np.empty(k)
    dp = np.empty(k)
    scale = np.empty(k)
    for i in range(k):
        scale[i] = np.sqrt(direction[i, 0] ** 2 + direction[i, 1] ** 2 + direction[i, 2] ** 2)
    f = _chain(origin, direction, s, tol, grad, diag, off)
    g2 = np.empty(k)
    d2 = np.empty(k)
    o2 = np.empty(k)
    for _ in range(max_iter):
        # free variables: movable, and not held at a bound by the gradient
        for i in range(k):
            free[i] = scale[i] > 0.0 and not ((s[i] <= 0.0 and grad[i] > 0.0)
                                              or (s[i] >= 1.0 and grad[i] < 0.0))
        # Thomas algorithm on the free rows (the others: identity, zero step)
        for i in range(k):
            a_ = off[i - 1] if i > 0 and free[i] and free[i - 1] else 0.0
            b_ = diag[i] * (1.0 + 1e-12) + 1e-300 if free[i] else 1.0
            c_ = off[i] if i < k - 1 and free[i] and free[i + 1] else 0.0
            d_ = -grad[i] if free[i] else 0.0
            if i == 0:
                cp[i] = c_ / b_
                dp[i] = d_ / b_
            else:
                m_ = b_ - a_ * cp[i - 1]
                cp[i] = c_ / m_
                dp[i] = (d_ - a_ * dp[i - 1]) / m_
        step[k - 1] = dp[k - 1]
        for i in range(k - 2, -1, -1):
            step[i] = dp[i] - cp[i] * step[i + 1]
        # projected backtracking line search
        alpha = 1.0
        accepted = False
        moved = 0.0
        for _ls in range(40):
            moved = 0.0
            for i in range(k):
                t = s[i] + alpha * step[i] if free[i] else s[i]
                t = min(max(t, 0.0), 1.0)
                trial[i] = t
                moved = max(moved, abs(t - s[i]) * scale[i])
            ft = _chain(origin, direction, trial, tol, g2, d2, o2)
            if ft <= f:
                accepted = True
                break
            alpha *= 0.5
        if not accepted:
            break
        for i in range(k):
            s[i] = trial[i]
            grad[i] = g2[i]
            diag[i] = d2[i]
            off[i] = o2[i]
        decrease = f - ft
        f = ft
        # converged: a full Newton step that moves no point, or no measurable decrease left
        if (moved <= tol and alpha == 1.0) or decrease <= 1e-15 * f:
            break
    P = np.empty((k, 3))
    for i in range(k):
        for c in range(3):
            P[i, c] = origin[i, c] + s[i] * direction[i, c]
    return P
