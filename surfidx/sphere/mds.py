"""The original method ``"mds"``, and the landmark geodesics of the stress figure.

Spherical multidimensional scaling of landmark geodesic distances: classical MDS to 3D projected
onto the sphere, then stress minimisation by conjugate gradients; each other surfel is placed by
minimising its own stress to the landmarks. Works on point clouds too; it folds on shapes with
limbs. The geodesics are those of :class:`surfidx.GeodesicSolver`; where its
spheres-of-influence graph is disconnected (a sparse point cloud), Dijkstra on the mesh edges
or the k-nearest-neighbour graph stands in.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components, dijkstra

from ..errors import TopologyError
from ..geometry.geodesics import GeodesicSolver
from ..geometry.surfels import SurfelSet
from .options import MapOptions

__all__ = ["mds_map", "geodesics"]

_NEIGHBOURS = 8        # a point cloud's stand-in graph links each surfel to this many nearest
_FLOOR = 1e-12         # edge lengths and distances floored at this times the diagonal
_COS_CLIP = 1e-12      # cosines clipped to [-1 + this, 1 - this] (arccos' slope stays finite)
_TINY = 1e-300         # denominators stay positive
_WEIGHT_POWER = 4      # a placed surfel weighs each landmark by distance ** -this
_PLACEMENT_RATE = 0.2  # step of the placement's gradient descent, relative to its curvature


def _edge_graph(surfels: SurfelSet, k: int = _NEIGHBOURS) -> sp.csr_matrix:
    """Symmetric sparse graph with Euclidean edge lengths: mesh edges, or k nearest neighbours."""
    p = surfels.positions
    n = len(p)
    if surfels.faces is not None and len(surfels.faces):
        f = surfels.faces
        e = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    else:
        from scipy.spatial import cKDTree

        kk = min(k, n - 1)
        _, idx = cKDTree(p).query(p, k=kk + 1)
        e = np.column_stack([np.repeat(np.arange(n), kk), idx[:, 1:].ravel()])
    e = e[e[:, 0] != e[:, 1]]
    g = sp.coo_matrix((np.ones(2 * len(e)), (np.concatenate([e[:, 0], e[:, 1]]),
                                              np.concatenate([e[:, 1], e[:, 0]]))),
                      shape=(n, n)).tocsr()
    r, c = g.nonzero()
    floor = _FLOOR * max(surfels.diagonal, _TINY)
    g = sp.csr_matrix((np.maximum(np.linalg.norm(p[r] - p[c], axis=1), floor), (r, c)),
                      shape=(n, n))
    return g


def _landmarks(graph, k: int, seed: int):
    """Farthest-point landmarks on the graph and their distances (k, n)."""
    n = graph.shape[0]
    rng = np.random.default_rng(seed)
    start = int(rng.integers(n))
    d0 = dijkstra(graph, indices=start)
    idx = [int(np.argmax(d0))]
    rows = [dijkstra(graph, indices=idx[0])]
    mind = rows[0].copy()
    for _ in range(1, k):
        nxt = int(np.argmax(mind))
        idx.append(nxt)
        rows.append(dijkstra(graph, indices=nxt))
        np.minimum(mind, rows[-1], out=mind)
    return np.array(idx, dtype=np.int64), np.array(rows)


def geodesics(surfels: SurfelSet, k: int, seed: int):
    """``k`` farthest-point landmarks (seeded) and their geodesic distances ``(k, n)``: those of
    :class:`surfidx.GeodesicSolver`, or Dijkstra's on :func:`_edge_graph` where its graph is
    disconnected."""
    try:
        solver = GeodesicSolver(surfels)
    except TopologyError:
        return _landmarks(_edge_graph(surfels), k, seed)
    lm = np.asarray(solver.landmarks(k, seed=seed), dtype=np.int64)
    return lm, np.asarray(solver.distances(lm))


def _sphere_stress_fit(x0, d, r0, *, maxiter):
    """Minimise sum (r*angle(x_i, x_j) - d_ij)^2 over unit vectors x by conjugate gradients."""
    from scipy.optimize import minimize

    k = len(x0)

    def fun(z):
        y = z[:-1].reshape(k, 3)
        r = z[-1]
        nrm = np.linalg.norm(y, axis=1)
        x = y / nrm[:, None]
        c = np.clip(x @ x.T, -1 + _COS_CLIP, 1 - _COS_CLIP)
        th = np.arccos(c)
        res = np.where(np.isfinite(d), r * th - np.nan_to_num(d), 0.0)
        np.fill_diagonal(res, 0.0)
        e = 0.5 * (res ** 2).sum()
        dth = -1.0 / np.sqrt(1 - c ** 2)
        gc = res * r * dth
        np.fill_diagonal(gc, 0.0)
        gx = gc @ x
        gy = (gx - np.einsum("ij,ij->i", gx, x)[:, None] * x) / nrm[:, None]
        gr = (res * th).sum()
        return e, np.concatenate([gy.ravel(), [gr]])

    z0 = np.concatenate([x0.ravel(), [r0]])
    res = minimize(fun, z0, jac=True, method="CG", options={"maxiter": maxiter})
    y = res.x[:-1].reshape(k, 3)
    return y / np.linalg.norm(y, axis=1)[:, None], float(res.x[-1])


def mds_map(surfels: SurfelSet, *, options: MapOptions, landmarks: int, seed: int, maxiter: int):
    """The MDS map: points, figures (``landmarks``, ``radius``), landmarks and their distances."""
    n = len(surfels)
    graph = _edge_graph(surfels)
    ncomp, _ = connected_components(graph, directed=False)
    if ncomp != 1:
        raise TopologyError(f"the surface has {ncomp} separate pieces; a spherical map needs one "
                            "connected surface")
    k = min(landmarks, n)
    lm, dist = geodesics(surfels, k, seed)
    d = dist[:, lm]
    d = 0.5 * (d + d.T)
    # classical MDS to 3D, projected onto the sphere
    j = np.eye(k) - 1.0 / k
    b = -0.5 * j @ (d ** 2) @ j
    val, vec = np.linalg.eigh(b)
    x = vec[:, -3:] * np.sqrt(np.maximum(val[-3:], _FLOOR))
    x -= x.mean(axis=0)
    x /= np.maximum(np.linalg.norm(x, axis=1), _TINY)[:, None]
    th = np.arccos(np.clip(x @ x.T, -1, 1))
    r0 = (th * d).sum() / max((th ** 2).sum(), _TINY)
    x, r = _sphere_stress_fit(x, d, r0, maxiter=maxiter)
    # other surfels: start at the landmark-weighted mean, then minimise their own stress
    wgt = 1.0 / np.maximum(dist, _FLOOR * surfels.diagonal) ** _WEIGHT_POWER
    y = (wgt.T @ x)
    y /= np.maximum(np.linalg.norm(y, axis=1), _TINY)[:, None]
    for _ in range(options.mds_placement_steps):
        c = np.clip(y @ x.T, -1 + _COS_CLIP, 1 - _COS_CLIP)
        th = np.arccos(c)
        res = r * th - dist.T
        gc = res * r * (-1.0 / np.sqrt(1 - c ** 2)) * wgt.T / wgt.T.max(axis=1, keepdims=True)
        g = gc @ x
        g -= np.einsum("ij,ij->i", g, y)[:, None] * y
        step = _PLACEMENT_RATE / max(r, _TINY) / np.maximum(
            (r ** 2 * wgt.T / wgt.T.max(axis=1, keepdims=True)).sum(axis=1) / r, _TINY)
        y = y - step[:, None] * g
        y /= np.linalg.norm(y, axis=1)[:, None]
    y[lm] = x
    return y, {"landmarks": k, "radius": r}, lm, dist
