"""Spherical parameterization of a closed genus-0 surfel set that does not fold.

Default method ``"tutte"`` (the fold-free route)
-----------------------------------------------
1. A planar triangulation over the surfels: the mesh faces (``SurfelSet.faces``). Its topology is
   checked first (closed, one piece, manifold, Euler characteristic 2), so a torus, a pretzel or
   two pieces fail with :class:`~surfidx.TopologyError` before any mapping.
2. Puncture one triangle (the largest) and map the rest into the plane by a Tutte embedding with
   positive mean-value weights (Floater 2003), the punctured triangle as the convex boundary.
   Tutte's theorem (Floater's extension to any positive weights) makes the planar map an
   embedding: no triangle folds.
3. Area balancing (Yoshizawa, Belyaev & Seidel 2004 style reweighting): the weights toward each
   vertex are multiplied by ``rho**gamma`` where ``rho`` is the local ratio of spherical to 3D
   area share, and the Tutte system is solved again. Every iterate is again a positive-weight
   Tutte embedding, hence fold-free in the plane; steps are accepted only when they lower the
   area distortion and keep every triangle positively oriented on the sphere.
4. Inverse stereographic projection (orientation preserving); the scale of the plane (the Möbius
   dilation left free by the puncture) is chosen to minimise the area distortion. All steps use
   intrinsic quantities only (lengths, angles, areas), so the result is canonical up to a rotation
   of the sphere: a rotated input gives the same sphere points and the same figures.

Original method ``"mds"``
-------------------------
Spherical multidimensional scaling of landmark geodesic distances (classical MDS projected to the
sphere, then stress minimisation by conjugate gradients), each other surfel placed by minimising
its own stress to the landmarks. Works on point clouds too; it folds on shapes with limbs.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components, dijkstra

from ._errors import InputError, TopologyError
from ._tolerance import TOL
from ._validate import as_array, check_positive_int
from .surfels import SurfelSet

__all__ = ["SphericalMap", "parameterize", "count_folds", "hull_triangles", "landmark_stress",
           "area_distortion", "METHODS"]

METHODS = ("tutte", "mds")
"""Names accepted by :func:`parameterize` (the first is the default)."""

_MIN_SURFELS = 8


@dataclass
class SphericalMap:
    """A map of surfels onto the unit sphere and its quality figures.

    Attributes
    ----------
    points : (n, 3) float64
        Unit vectors, one per surfel, in surfel order.
    method : str
        ``"tutte"`` or ``"mds"``.
    folded : int
        Folded triangles of the spherical Delaunay triangulation (convex hull) of ``points``.
    triangles : int
        Triangles of that triangulation.
    landmark_stress : float
        Normalised stress ``sqrt(sum (r*theta - d)^2 / sum d^2)`` of landmark geodesic distances
        ``d`` against great-circle angles ``theta`` (best scale ``r``); NaN when not computed.
    area_distortion : float
        Area-weighted RMS of ``log(spherical area share / 3D area share)`` over hull triangles.
    seconds : float
        Wall time of the mapping.
    info : dict
        Method details (iterations, scale, landmark count ...).
    """

    points: np.ndarray
    method: str
    folded: int
    triangles: int
    landmark_stress: float
    area_distortion: float
    seconds: float
    info: dict = field(default_factory=dict)

    @property
    def fold_fraction(self) -> float:
        """Share of folded hull triangles."""
        return self.folded / max(self.triangles, 1)

    def figures(self) -> dict:
        """The figures as a plain dict (for JSON and tables)."""
        return {"method": self.method, "surfels": len(self.points), "folded": self.folded,
                "triangles": self.triangles, "fold_fraction": self.fold_fraction,
                "landmark_stress": self.landmark_stress,
                "area_distortion": self.area_distortion, "seconds": self.seconds,
                **{k: v for k, v in self.info.items() if np.isscalar(v)}}


# ---------------------------------------------------------------------- checks and figures
def _check_points(surfels: SurfelSet, sphere_points) -> np.ndarray:
    if not isinstance(surfels, SurfelSet):
        raise InputError(f"surfels must be a SurfelSet, got {type(surfels).__name__}")
    pts = as_array(sphere_points, "sphere_points", shape=(len(surfels), 3), min_len=4)
    nrm = np.linalg.norm(pts, axis=1)
    if np.any(np.abs(nrm - 1.0) > TOL.unit_normal):
        raise InputError("sphere_points must be unit vectors (points on the unit sphere)")
    return pts / nrm[:, None]


def hull_triangles(sphere_points) -> np.ndarray:
    """Spherical Delaunay triangulation of points on the unit sphere (their convex hull).

    Parameters
    ----------
    sphere_points : (n, 3) float64
        Unit vectors, n ≥ 4, not all on one great circle.

    Returns
    -------
    (m, 3) int64
        Triangles, counter-clockwise seen from outside (``(b - a) × (c - a) · a > 0``).

    Raises
    ------
    InputError
        When the points span no volume (all on one plane).
    """
    from scipy.spatial import ConvexHull, QhullError

    pts = as_array(sphere_points, "sphere_points", shape=(None, 3), min_len=4)
    try:
        hull = ConvexHull(pts)
    except QhullError as exc:
        raise InputError(f"the sphere points span no volume ({str(exc).splitlines()[0]})") from exc
    tri = np.ascontiguousarray(hull.simplices, dtype=np.int64)
    a, b, c = pts[tri[:, 0]], pts[tri[:, 1]], pts[tri[:, 2]]
    flip = np.einsum("ij,ij->i", np.cross(b - a, c - a), a + b + c) < 0
    tri[flip] = tri[flip][:, [0, 2, 1]]
    return tri


def count_folds(surfels: SurfelSet, sphere_points) -> tuple[int, int]:
    """Folded triangles of the spherical Delaunay triangulation of mapped surfels.

    A hull triangle (counter-clockwise seen from outside the sphere) is mapped back to the surfel
    positions; it is folded when its 3D normal points against the sum of its three surfel normals.
    A global mirror is not a fold: when more than half the triangles disagree, the complement is
    counted.

    Parameters
    ----------
    surfels : SurfelSet
    sphere_points : (n, 3) float64
        The surfels' positions on the unit sphere.

    Returns
    -------
    folded : int
    total : int
    """
    pts = _check_points(surfels, sphere_points)
    tri = hull_triangles(pts)
    p = surfels.positions
    n3 = np.cross(p[tri[:, 1]] - p[tri[:, 0]], p[tri[:, 2]] - p[tri[:, 0]])
    nsum = surfels.normals[tri].sum(axis=1)
    bad = int(np.count_nonzero(np.einsum("ij,ij->i", n3, nsum) < 0))
    return min(bad, len(tri) - bad), len(tri)


def _spherical_areas(pts, tri):
    a, b, c = pts[tri[:, 0]], pts[tri[:, 1]], pts[tri[:, 2]]
    num = np.einsum("ij,ij->i", a, np.cross(b, c))
    den = 1.0 + np.einsum("ij,ij->i", a, b) + np.einsum("ij,ij->i", b, c) \
        + np.einsum("ij,ij->i", c, a)
    return 2.0 * np.arctan2(num, den)


def _areas3(p, tri):
    return 0.5 * np.linalg.norm(np.cross(p[tri[:, 1]] - p[tri[:, 0]], p[tri[:, 2]] - p[tri[:, 0]]),
                                axis=1)


def area_distortion(surfels: SurfelSet, sphere_points, *, triangles=None) -> float:
    """Area-weighted RMS of ``log(spherical area share / 3D area share)``.

    Parameters
    ----------
    surfels : SurfelSet
    sphere_points : (n, 3) float64
    triangles : (m, 3) int64, optional
        Triangles to measure on (default: the hull of ``sphere_points``).

    Returns
    -------
    float
        0 for an area-preserving map; ``log(10)`` ≈ 2.3 means tenfold typical area errors.
    """
    pts = _check_points(surfels, sphere_points)
    tri = hull_triangles(pts) if triangles is None else as_array(
        triangles, "triangles", dtype=np.int64, shape=(None, 3))
    a3 = _areas3(surfels.positions, tri)
    asph = np.abs(_spherical_areas(pts, tri))
    w = a3 / a3.sum()
    ratio = (asph / asph.sum()) / np.maximum(w, 1e-300)
    lr = np.log(np.clip(ratio, 1e-30, 1e30))
    return float(np.sqrt(np.average(lr ** 2, weights=w)))


# ---------------------------------------------------------------------- graph and geodesics
def _edge_graph(surfels: SurfelSet, k: int = 8) -> sp.csr_matrix:
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
    floor = 1e-12 * max(surfels.diagonal, 1e-300)
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


def _geodesics(surfels: SurfelSet, k: int, seed: int):
    """Landmark indices and geodesic distances, from surfidx.geodesics when it is available."""
    try:  # the project's solver (spheres-of-influence graph) when it has landed
        from .geodesics import GeodesicSolver  # type: ignore

        solver = GeodesicSolver(surfels)
        lm = np.asarray(solver.landmarks(k, seed=seed), dtype=np.int64)
        return lm, np.asarray(solver.distances(lm))
    except Exception:  # not landed yet, or a different API: Dijkstra on the mesh/kNN graph
        return _landmarks(_edge_graph(surfels), k, seed)


def landmark_stress(sphere_points, landmarks, distances) -> float:
    """Normalised stress of landmark geodesic distances against great-circle angles.

    Parameters
    ----------
    sphere_points : (n, 3) float64
    landmarks : (k,) int64
        Surfel indices of the landmarks.
    distances : (k, n) float64
        Geodesic distances from each landmark to every surfel.

    Returns
    -------
    float
        ``sqrt(sum (r*theta - d)^2 / sum d^2)`` over landmark pairs, ``r`` the best scale.
    """
    pts = as_array(sphere_points, "sphere_points", shape=(None, 3))
    lm = as_array(landmarks, "landmarks", dtype=np.int64, shape=(None,))
    d = as_array(distances, "distances", shape=(len(lm), len(pts)), finite=False)[:, lm]
    x = pts[lm]
    th = np.arccos(np.clip(x @ x.T, -1.0, 1.0))
    ok = np.isfinite(d)
    r = (th[ok] * d[ok]).sum() / max((th[ok] ** 2).sum(), 1e-300)
    return float(np.sqrt(((r * th[ok] - d[ok]) ** 2).sum() / max((d[ok] ** 2).sum(), 1e-300)))


# ---------------------------------------------------------------------- topology
def _oriented_faces(surfels: SurfelSet) -> np.ndarray:
    """Non-degenerate faces, checked to triangulate a sphere, wound to agree with the normals."""
    from .mesh import TriangleMesh

    f = surfels.faces
    f = f[(f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 0] != f[:, 2])]
    n = len(surfels)
    topo = TriangleMesh(surfels.positions, f).topology()
    if topo.vertices < n:
        raise TopologyError(f"{n - topo.vertices} surfels belong to no triangle; the surface must "
                            "be one closed piece")
    if topo.components != 1:
        raise TopologyError(f"the surface has {topo.components} separate pieces; a spherical map "
                            "needs one connected surface (split it or keep the largest piece)")
    if not topo.closed:
        raise TopologyError(f"the surface is not closed ({topo.boundary_edges} boundary edges, "
                            f"{topo.nonmanifold_edges} non-manifold edges); fill its holes first")
    if topo.nonmanifold_vertices:
        raise TopologyError(f"the surface has {topo.nonmanifold_vertices} pinched (non-manifold) "
                            "vertices; repair them before mapping to the sphere")
    if topo.genus != 0:
        raise TopologyError(f"the surface has genus {topo.genus} (Euler characteristic "
                            f"{topo.euler}); only genus-0 (sphere-like) surfaces can be mapped "
                            "to the sphere without cuts")
    # consistent winding: every directed edge once
    he = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    if len(np.unique(he[:, 0] * n + he[:, 1])) != len(he):
        raise TopologyError("the triangles are not consistently oriented (the surface is "
                            "non-orientable or has flipped faces); fix the face winding")
    p = surfels.positions
    fn = np.cross(p[f[:, 1]] - p[f[:, 0]], p[f[:, 2]] - p[f[:, 0]])
    if np.einsum("ij,ij->", fn, surfels.normals[f].sum(axis=1)) < 0:
        f = f[:, [0, 2, 1]]
    return np.ascontiguousarray(f)


def _check_surfels(surfels) -> SurfelSet:
    if not isinstance(surfels, SurfelSet):
        raise InputError(f"surfels must be a SurfelSet, got {type(surfels).__name__}")
    if len(surfels) < _MIN_SURFELS:
        raise InputError(f"too few surfels to map to the sphere: {len(surfels)} (need at least "
                         f"{_MIN_SURFELS})")
    return surfels


# ---------------------------------------------------------------------- Tutte + balancing
def _mean_value_weights(p, f):
    n = len(p)
    rows, cols, vals = [], [], []
    for k in range(3):
        i, j, l = f[:, k], f[:, (k + 1) % 3], f[:, (k + 2) % 3]
        e1, e2 = p[j] - p[i], p[l] - p[i]
        n1, n2 = np.linalg.norm(e1, axis=1), np.linalg.norm(e2, axis=1)
        c = np.clip(np.einsum("ij,ij->i", e1, e2) / np.maximum(n1 * n2, 1e-300), -1.0, 1.0)
        t = np.tan(0.5 * np.arccos(c))
        rows += [i, i]
        cols += [j, l]
        vals += [t / np.maximum(n1, 1e-300), t / np.maximum(n2, 1e-300)]
    v = np.concatenate(vals)
    v = np.where(np.isfinite(v) & (v > 0), v, 0.0)
    w = sp.csr_matrix((v, (np.concatenate(rows), np.concatenate(cols))), shape=(n, n))
    w.sum_duplicates()
    rs = np.asarray(w.sum(axis=1)).ravel()
    # strictly positive weights (Floater's condition): floor tiny ones relative to the row
    w.data = np.maximum(w.data, 1e-6 * np.repeat(rs / np.maximum(np.diff(w.indptr), 1),
                                                 np.diff(w.indptr)))
    return w


class _TutteSystem:
    """Tutte's linear system with the vertices of one triangle fixed on a planar triangle."""

    def __init__(self, n, boundary):
        self.n = n
        self.boundary = boundary
        self.inner = np.setdiff1d(np.arange(n), boundary)
        ang = np.pi / 2 + np.array([0.0, -2.0, -4.0]) * np.pi / 3  # clockwise: see _invstereo
        self.ub = np.column_stack([np.cos(ang), np.sin(ang)])

    def solve(self, w):
        from scipy.sparse.linalg import splu

        rs = np.asarray(w.sum(axis=1)).ravel()
        lap = (sp.diags(rs) - w).tocsr()
        a = lap[self.inner][:, self.inner].tocsc()
        b = lap[self.inner][:, self.boundary]
        u = np.empty((self.n, 2))
        u[self.boundary] = self.ub
        u[self.inner] = splu(a, permc_spec="COLAMD").solve(np.asarray(-(b @ self.ub)))
        return u


def _invstereo(u):
    """Inverse stereographic projection from the north pole, composed with a mirror so that the
    clockwise boundary triangle and counter-clockwise interior map orientation-preservingly."""
    r2 = (u ** 2).sum(axis=1)
    return np.column_stack([2 * u[:, 0], -2 * u[:, 1], r2 - 1.0]) / (1.0 + r2)[:, None]


def _log_ratios(s, f, share3, punct):
    asph = _spherical_areas(s, f)
    a = np.abs(asph) / (4 * np.pi)
    a[punct] = max(1.0 - (a.sum() - a[punct]), 1e-300)
    return np.log(np.clip(a / np.maximum(share3, 1e-300), 1e-300, 1e300)), asph


def _score(u, scale, f, share3, punct):
    s = _invstereo(u / scale)
    lr, asph = _log_ratios(s, f, share3, punct)
    neg = int(np.count_nonzero(np.delete(asph, punct) <= 0))
    return float(np.sqrt(np.average(lr ** 2, weights=share3))), neg, lr, s


def _best_scale(u, f, share3, punct):
    from scipy.optimize import minimize_scalar

    res = minimize_scalar(lambda ls: _score(u, np.exp(ls), f, share3, punct)[0],
                          bounds=(-15.0, 15.0), method="bounded", options={"xatol": 1e-2})
    return float(np.exp(res.x))


def _planar_folds(u, f, punct):
    e1, e2 = u[f[:, 1]] - u[f[:, 0]], u[f[:, 2]] - u[f[:, 0]]
    det = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]
    return int(np.count_nonzero(np.delete(det, punct) <= 0))


def _tutte_map(surfels: SurfelSet, *, iterations: int, gamma: float, time_budget: float):
    f = _oriented_faces(surfels)
    p = surfels.positions
    n = len(p)
    a3 = _areas3(p, f)
    if not a3.sum() > 0:
        raise InputError("the surface has zero area")
    share3 = a3 / a3.sum()
    # puncture the largest triangle (ties broken by index, so the choice is rotation invariant)
    key = np.round(a3 / a3.max(), 9)
    punct = int(np.flatnonzero(key == key.max())[0])
    system = _TutteSystem(n, f[punct])
    w = _mean_value_weights(p, f)
    vf = sp.csr_matrix((np.repeat(a3, 3), (f.ravel(), np.repeat(np.arange(len(f)), 3))),
                       shape=(n, len(f)))
    vsum = np.maximum(np.asarray(vf.sum(axis=1)).ravel(), 1e-300)
    t0 = time.perf_counter()
    u = system.solve(w)
    scale = _best_scale(u, f, share3, punct)
    sd, neg, lr, s = _score(u, scale, f, share3, punct)
    neg += _planar_folds(u, f, punct)
    best = (neg, sd, s, scale)
    accepted = 0
    for _ in range(iterations):
        if time.perf_counter() - t0 > time_budget:
            break
        lrho = (vf @ lr) / vsum
        improved = False
        for g in (gamma, 0.5 * gamma, 0.2 * gamma):
            w2 = w @ sp.diags(np.exp(g * lrho))
            u2 = system.solve(w2)
            pneg = _planar_folds(u2, f, punct)
            if pneg:
                continue
            sc2 = _best_scale(u2, f, share3, punct)
            sd2, neg2, lr2, s2 = _score(u2, sc2, f, share3, punct)
            if (neg2, sd2) < (neg, sd):  # accept only steps that do not add folds
                w, u, lr, sd, neg, s, scale = w2, u2, lr2, sd2, neg2, s2, sc2
                improved = True
                accepted += 1
                break
        if (neg, sd) < best[:2]:
            best = (neg, sd, s, scale)
        if not improved:
            break
    neg, sd, s, scale = best
    s = s / np.linalg.norm(s, axis=1)[:, None]
    return s, {"mesh_folds": neg, "mesh_area_distortion": sd, "scale": scale,
               "iterations": accepted, "punctured_triangle": punct}


# ---------------------------------------------------------------------- original method (MDS)
def _sphere_stress_fit(x0, d, r0, *, maxiter):
    """Minimise sum (r*angle(x_i, x_j) - d_ij)^2 over unit vectors x by conjugate gradients."""
    from scipy.optimize import minimize

    k = len(x0)

    def fun(z):
        y = z[:-1].reshape(k, 3)
        r = z[-1]
        nrm = np.linalg.norm(y, axis=1)
        x = y / nrm[:, None]
        c = np.clip(x @ x.T, -1 + 1e-12, 1 - 1e-12)
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


def _mds_map(surfels: SurfelSet, *, landmarks: int, seed: int, maxiter: int):
    n = len(surfels)
    graph = _edge_graph(surfels)
    ncomp, _ = connected_components(graph, directed=False)
    if ncomp != 1:
        raise TopologyError(f"the surface has {ncomp} separate pieces; a spherical map needs one "
                            "connected surface")
    k = min(landmarks, n)
    lm, dist = _geodesics(surfels, k, seed)
    d = dist[:, lm]
    d = 0.5 * (d + d.T)
    # classical MDS to 3D, projected onto the sphere
    j = np.eye(k) - 1.0 / k
    b = -0.5 * j @ (d ** 2) @ j
    val, vec = np.linalg.eigh(b)
    x = vec[:, -3:] * np.sqrt(np.maximum(val[-3:], 1e-12))
    x -= x.mean(axis=0)
    x /= np.maximum(np.linalg.norm(x, axis=1), 1e-300)[:, None]
    th = np.arccos(np.clip(x @ x.T, -1, 1))
    r0 = (th * d).sum() / max((th ** 2).sum(), 1e-300)
    x, r = _sphere_stress_fit(x, d, r0, maxiter=maxiter)
    # other surfels: start at the landmark-weighted mean, then minimise their own stress
    wgt = 1.0 / np.maximum(dist, 1e-12 * surfels.diagonal) ** 4
    y = (wgt.T @ x)
    y /= np.maximum(np.linalg.norm(y, axis=1), 1e-300)[:, None]
    for _ in range(50):
        c = np.clip(y @ x.T, -1 + 1e-12, 1 - 1e-12)
        th = np.arccos(c)
        res = r * th - dist.T
        gc = res * r * (-1.0 / np.sqrt(1 - c ** 2)) * wgt.T / wgt.T.max(axis=1, keepdims=True)
        g = gc @ x
        g -= np.einsum("ij,ij->i", g, y)[:, None] * y
        step = 0.2 / max(r, 1e-300) / np.maximum(
            (r ** 2 * wgt.T / wgt.T.max(axis=1, keepdims=True)).sum(axis=1) / r, 1e-300)
        y = y - step[:, None] * g
        y /= np.linalg.norm(y, axis=1)[:, None]
    y[lm] = x
    return y, {"landmarks": k, "radius": r}, lm, dist


# ---------------------------------------------------------------------- public entry point
def parameterize(surfels: SurfelSet, *, method: str = "tutte", seed: int = 0,
                 landmarks: int = 32, iterations: int = 40, gamma: float = 0.5,
                 time_budget: float = 60.0, stress: bool = True) -> SphericalMap:
    """Map surfels to the unit sphere.

    Parameters
    ----------
    surfels : SurfelSet
        A closed genus-0 surface; method ``"tutte"`` needs mesh faces (``surfels.faces``).
    method : {"tutte", "mds"}
        ``"tutte"``: fold-free Tutte embedding with area balancing (default); ``"mds"``: the
        original spherical MDS of landmark geodesics.
    seed : int
        Seed of the landmark choice.
    landmarks : int
        Landmarks for the stress figure and for ``"mds"``.
    iterations : int
        Most area-balancing iterations (``"tutte"``) or CG iterations / 10 (``"mds"``).
    gamma : float
        Exponent of the balancing reweighting, in (0, 2].
    time_budget : float
        Seconds after which the balancing stops and keeps its best iterate.
    stress : bool
        Compute the landmark stress figure (geodesics from ``landmarks`` sources).

    Returns
    -------
    SphericalMap

    Raises
    ------
    InputError
        Unknown method, bad options, too few surfels, or ``"tutte"`` on a point cloud.
    TopologyError
        Several pieces, holes, pinched vertices, genus > 0, inconsistent winding.
    """
    surfels = _check_surfels(surfels)
    if method not in METHODS:
        raise InputError(f"method must be one of {', '.join(METHODS)}, got {method!r}")
    check_positive_int(landmarks, "landmarks", minimum=4)
    check_positive_int(iterations, "iterations", minimum=0)
    if not (0 < float(gamma) <= 2):
        raise InputError(f"gamma must lie in (0, 2], got {gamma!r}")
    t0 = time.perf_counter()
    lm = dist = None
    if method == "tutte":
        if surfels.faces is None or not len(surfels.faces):
            raise InputError("method 'tutte' needs a triangulation over the surfels (a mesh "
                             "input); for a bare point cloud use method='mds'")
        pts, info = _tutte_map(surfels, iterations=iterations, gamma=float(gamma),
                               time_budget=float(time_budget))
    else:
        if surfels.faces is not None and len(surfels.faces):
            _oriented_faces(surfels)  # topology check before mapping
        pts, info, lm, dist = _mds_map(surfels, landmarks=landmarks, seed=seed,
                                       maxiter=max(10 * iterations, 10))
    seconds = time.perf_counter() - t0
    folded, total = count_folds(surfels, pts)
    ad = area_distortion(surfels, pts)
    st = float("nan")
    if stress:
        if lm is None:
            lm, dist = _geodesics(surfels, min(landmarks, len(surfels)), seed)
        st = landmark_stress(pts, lm, dist)
    return SphericalMap(pts, method, folded, total, st, ad, seconds, info)
