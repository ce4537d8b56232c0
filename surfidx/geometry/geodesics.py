"""Geodesic distances, shortest paths and farthest-point landmarks on surfel sets.

Distances are shortest paths (Dijkstra) on the spheres-of-influence graph of :mod:`surfidx.geometry.graph`.
Graph paths zig-zag through the surfel centres and so overestimate geodesic lengths; the optional
refinement (``refine=True``) straightens a path on the surface, as the SIG method proposes:

1. the graph path is resampled uniformly at coarse resolution (4 segments);
2. each interior point moves towards the midpoint of its neighbours, the move limited to half
   its shorter adjacent segment, then is projected back onto the surface: a
   moving-least-squares plane fitted (Gaussian weights) to the nearest surfel and its
   graph neighbours, the nearest surfel being tracked by a greedy walk on the graph (so points
   never jump to the other side of a thin part);
3. the iteration (Gauss-Seidel) runs to convergence, then every segment is split at its projected
   midpoint and the finer polyline is relaxed again, until segments are no longer than the local
   surfel spacing.

The coarse-to-fine schedule makes the low-frequency part of the straightening cheap, like a
multigrid solver.

Safety: the path must stay on the sheet of surface it started on. A move is rejected when the new
nearest surfel of the point is not linked to its current one, or (when they were linked) to the
surfels of its two polyline neighbours, or when it faces away from them (normals more than 90
degrees apart: the other side of a thin part). Consecutive points thus sit on linked surfels,
whose edge passed the graph's surface test, so a path never slides across a gap to another part
(between two legs). Refinement only shortens: a refined path longer than the graph distance is
dropped for the graph path.

Meshed inputs (surfels with ``faces``): the path is found on the triangles themselves
(:mod:`surfidx.geometry.meshpaths`): a Steiner graph on a corridor of triangles around the mesh-edge
shortest path, then its crossing points slid along their edges until the path is locally
shortest. Every segment lies in a triangle, so the length is that of a path on the surface, never
a chord cutting through the relief of a coarse, faceted mesh (the plane projection above rounds
such relief off, and chords between points on the triangles cut through it), and a mesh-edge
corridor cannot cross a narrow gap between two sheets, as a graph link that passed the surface
test can.
"""

from __future__ import annotations

from dataclasses import dataclass

from ..jit import numba
import numpy as np
from scipy.sparse.csgraph import dijkstra as _csgraph_dijkstra

from ..errors import FileFormatError, InputError
from ..tolerance import TOL
from ..validate import as_array, check_positive_int
from .graph import (DEFAULT_MAX_ANGLE, DEFAULT_MAX_OFFSET, DEFAULT_SCALE,
                    SphereOfInfluenceGraph, _nearest_among)
from .meshpaths import mesh_edge_graph, shortest_path_on_mesh
from .surfels import SurfelSet

__all__ = ["GeodesicSolver", "GeodesicPath", "geodesic_distances", "geodesic_path",
           "farthest_point_landmarks"]


@dataclass(frozen=True)
class GeodesicPath:
    """A path on the surface.

    Attributes
    ----------
    indices : (k,) int64
        The surfels of the graph path, from source to target (for a path refined on a mesh, of
        the mesh-edge path it was found around).
    points : (m, 3) float64
        The polyline: the surfel positions, or the refined points (endpoints are the surfel
        positions of the source and target).
    length : float
        The path length: for a graph path the sum of its edge weights (the graph distance; with
        arc weights slightly more than the polyline of surfel centres), for a refined path the
        length of the refined polyline.
    refined : bool
        Whether ``points`` is the refined polyline (``False`` also when refinement was asked for
        but gave a longer path than the graph, which is then returned).
    surfels : (m,) int64
        For each point, its surfel index when the point is a graph-path surfel, else -1.
    """

    indices: np.ndarray
    points: np.ndarray
    length: float
    refined: bool = False
    surfels: np.ndarray | None = None

    def write_ply(self, filename) -> None:
        """Write the path as a PLY file (``surfidx render --path`` overlays it).

        Parameters
        ----------
        filename : str or os.PathLike
            Written with one ``vertex`` element: ``x y z`` (float64, in path order) and
            ``surfel`` (int32; -1 for refined in-between points).

        Raises
        ------
        FileFormatError
            When the file cannot be written.
        """
        from plyfile import PlyData, PlyElement

        pts = self.points
        data = np.empty(len(pts), dtype=[("x", "<f8"), ("y", "<f8"), ("z", "<f8"),
                                         ("surfel", "<i4")])
        data["x"], data["y"], data["z"] = pts[:, 0], pts[:, 1], pts[:, 2]
        data["surfel"] = self.surfels if self.surfels is not None else -1
        try:
            PlyData([PlyElement.describe(data, "vertex")],
                    comments=["geodesic path written by surfidx"]).write(str(filename))
        except OSError as exc:
            raise FileFormatError(f"cannot write ({exc.strerror or exc})", path=filename) from exc


class GeodesicSolver:
    """Geodesics on a surfel set: build once, query many times.

    Parameters
    ----------
    surfels : SurfelSet
    max_angle : float
        Largest normal angle (degrees) between linked surfels; see
        :data:`surfidx.geometry.graph.DEFAULT_MAX_ANGLE`.
    radius : {"surfel", "nearest", "knn"}
        Sphere radius of each surfel (see :mod:`surfidx.geometry.graph`).
    k : int
        Neighbour rank for ``radius="knn"``.
    scale : float
        Sphere-radius multiplier; see :data:`surfidx.geometry.graph.DEFAULT_SCALE`.
    max_offset : float or None
        Edge midpoint-to-surface distance limit relative to the edge length (shortcut test); see
        :data:`surfidx.geometry.graph.DEFAULT_MAX_OFFSET`. ``None`` disables it.
    mesh_edges : bool
        Also link the mesh edges when the surfels carry faces (see :mod:`surfidx.geometry.graph`).
    arc_weights : bool
        Weight edges by tangent-arc length rather than chord length (see :mod:`surfidx.geometry.graph`).
    bridge : bool
        Join disconnected parts with straight links (with a ``UserWarning``) instead of raising.

    Raises
    ------
    TopologyError
        When the graph is disconnected and ``bridge`` is false.
    InputError
        On bad options.

    Examples
    --------
    >>> solver = GeodesicSolver(surfels)            # doctest: +SKIP
    >>> d = solver.distances([0, 10])               # (2, n) graph distances
    >>> path = solver.path(0, 10, refine=True)      # straightened polyline
    """

    def __init__(self, surfels: SurfelSet, *, max_angle: float = DEFAULT_MAX_ANGLE,
                 radius: str = "surfel", k: int = 6, scale: float = DEFAULT_SCALE,
                 max_offset: float | None = DEFAULT_MAX_OFFSET, mesh_edges: bool = True,
                 arc_weights: bool = True, bridge: bool = False):
        self.graph = SphereOfInfluenceGraph.from_surfels(
            surfels, max_angle=max_angle, radius=radius, k=k, scale=scale, max_offset=max_offset,
            mesh_edges=mesh_edges, arc_weights=arc_weights, bridge=bridge)
        self.surfels = surfels
        m = self.graph.matrix
        self._indptr = m.indptr.astype(np.int64)
        self._indices = m.indices.astype(np.int64)
        self._positions = np.ascontiguousarray(surfels.positions)
        self._normals = np.ascontiguousarray(surfels.normals)
        # local spacing per surfel: mean length of its edges (refinement resolution)
        deg = np.maximum(np.diff(self._indptr), 1)
        sums = np.add.reduceat(m.data, self._indptr[:-1]) if m.nnz else np.zeros(len(deg))
        sums[np.diff(self._indptr) == 0] = 0
        spacing = sums / deg
        spacing[spacing <= 0] = np.median(spacing[spacing > 0]) if (spacing > 0).any() else 1.0
        # the fit bandwidth: the surfel radius, but no less than the nearest link
        self._spacing = spacing / max(self.graph.scale, 1.0)
        self._bandwidth = np.maximum(surfels.radii, self._spacing)
        self._mesh_cache = None

    def __len__(self) -> int:
        return len(self.surfels)

    def __repr__(self) -> str:
        return f"GeodesicSolver({self.graph!r})"

    # ------------------------------------------------------------------ distances
    def distances(self, sources, *, targets=None, refine: bool = False) -> np.ndarray:
        """Geodesic distances from sources.

        Parameters
        ----------
        sources : (s,) int or int
            Surfel indices.
        targets : (t,) int, optional
            Restrict the output to these surfels (required with ``refine``).
        refine : bool
            Straighten each source-target path on the surface (see the module notes); costs one
            path refinement per pair.

        Returns
        -------
        (s, n) or (s, t) float64
            Row per source.

        Raises
        ------
        InputError
            On indices out of range, or ``refine`` without ``targets``.
        """
        src = self._indices_arg(sources, "sources")
        tgt = None if targets is None else self._indices_arg(targets, "targets")
        if refine and tgt is None:
            raise InputError("refine=True needs targets (refining the paths to every surfel would"
                             " be too slow); pass targets=[...]")
        if not refine:
            d = _dijkstra(self.graph.matrix, directed=True, indices=src)
            d = np.atleast_2d(d)
            return d if tgt is None else np.ascontiguousarray(d[:, tgt])
        out = np.empty((len(src), len(tgt)))
        for a, s in enumerate(src):
            d, pred = _dijkstra(self.graph.matrix, directed=True, indices=int(s),
                               return_predecessors=True)
            mesh_pred = [None]  # mesh-edge Dijkstra from s, run at the first path on a mesh
            for b, t in enumerate(tgt):
                if t == s:
                    out[a, b] = 0.0
                    continue
                out[a, b] = self._refined(int(s), int(t), pred, d[t], mesh_pred)[2]
        return out

    def distance(self, a, b, *, refine: bool = False) -> float:
        """Geodesic distance between two surfels.

        Parameters
        ----------
        a, b : int
            Surfel indices.
        refine : bool
            Straighten the path first.

        Returns
        -------
        float
        """
        a = self._index_arg(a, "a")
        b = self._index_arg(b, "b")
        if refine:
            return self.path(a, b, refine=True).length
        return float(self.distances([a], targets=[b])[0, 0])

    # ------------------------------------------------------------------ paths
    def path(self, a, b, *, refine: bool = False) -> GeodesicPath:
        """Shortest path between two surfels.

        Parameters
        ----------
        a, b : int
            Source and target surfel indices.
        refine : bool
            Straighten the graph path on the surface (see the module notes).

        Returns
        -------
        GeodesicPath
        """
        a = self._index_arg(a, "a")
        b = self._index_arg(b, "b")
        if a == b:
            idx = np.array([a], np.int64)
            pts = self._positions[idx].copy()
            return GeodesicPath(idx, pts, 0.0, refine, idx.copy())
        _, pred = _dijkstra(self.graph.matrix, directed=True, indices=a, return_predecessors=True)
        idx = _walk_predecessors(pred, a, b)
        length = float(np.asarray(self.graph.matrix[idx[:-1], idx[1:]]).sum())
        if refine:
            ridx, pts, refined_length, sid = self._refined(a, b, pred, length, [None])
            if pts is not None:
                return GeodesicPath(ridx, pts, refined_length, True, sid)
            idx, length = ridx, refined_length
        pts = self._positions[idx].copy()
        return GeodesicPath(idx, pts, length, False, idx.copy())

    # ------------------------------------------------------------------ landmarks
    def landmarks(self, k: int, *, seed: int = 0) -> np.ndarray:
        """Geodesic farthest-point sampling.

        The first landmark is the surfel farthest from a random surfel (drawn with ``seed``);
        each next one maximises the graph distance to those already chosen.

        Parameters
        ----------
        k : int
            Number of landmarks (1 ≤ k ≤ n).
        seed : int

        Returns
        -------
        (k,) int64
            Distinct surfel indices in selection order.
        """
        n = len(self.surfels)
        k = check_positive_int(k, "k")
        if k > n:
            raise InputError(f"k must be at most the number of surfels ({n}), got {k}")
        rng = np.random.default_rng(seed)
        start = int(rng.integers(n))
        d = _dijkstra(self.graph.matrix, directed=True, indices=start)
        out = np.empty(k, np.int64)
        nearest = np.full(n, np.inf)
        for i in range(k):
            cand = np.where(nearest > 0, nearest, -1.0) if i else d
            nxt = int(np.argmax(cand))
            out[i] = nxt
            di = _dijkstra(self.graph.matrix, directed=True, indices=nxt)
            np.minimum(nearest, di, out=nearest)
        return out

    # ------------------------------------------------------------------ internals
    def _index_arg(self, value, name) -> int:
        arr = as_array(value, name, dtype=np.int64, shape=())
        return int(self._indices_arg(arr.reshape(1), name)[0])

    def _indices_arg(self, value, name) -> np.ndarray:
        arr = as_array(np.atleast_1d(value), name, dtype=np.int64, shape=(None,), min_len=1)
        n = len(self.surfels)
        bad = (arr < 0) | (arr >= n)
        if bad.any():
            v = int(arr[np.flatnonzero(bad)[0]])
            raise InputError(f"{name}: surfel index {v} is out of range 0..{n - 1}")
        return arr

    def _refined(self, a, b, pred, graph_length, mesh_pred):
        """Refine the path from ``a`` to ``b`` (``pred``: graph Dijkstra predecessors).

        Without a mesh, the graph path is straightened on the surfel planes, and refinement only
        shortens: a refined polyline longer than the graph distance is dropped. With a mesh the
        path is found on its triangles (see the module notes) around the mesh-edge shortest path,
        whose Dijkstra from ``a`` is cached in ``mesh_pred[0]``; its length is kept even when
        above the graph distance (graph links are chords, which cut through the relief of a
        coarse, faceted mesh, so the graph distance is no upper bound there).

        Returns
        -------
        idx : (k,) int64
            The graph path, or on a mesh the mesh-edge path.
        points : (m, 3) float64 or None
            The refined polyline; ``None`` when the graph path is kept.
        length : float
        surfels : (m,) int64 or None
        """
        faces, edge_graph = self._mesh()
        if edge_graph is None:
            idx = _walk_predecessors(pred, a, b)
            pts = _refine_path(idx, self._positions, self._normals, self._bandwidth,
                                  self._spacing, self._indptr, self._indices,
                                  TOL.geodesic_refine, 5000, 1.0)
            length = _polyline_length(pts)
            if length > graph_length:
                return idx, None, graph_length, None
        else:
            if mesh_pred[0] is None:
                mesh_pred[0] = _dijkstra(edge_graph, directed=True, indices=a,
                                         return_predecessors=True)
            md, mp = mesh_pred[0]
            idx = _walk_predecessors(mp, a, b)
            # around the mesh-edge path and the graph path: where they pass a bump on different
            # sides, the geodesic may follow either
            spine = np.union1d(idx, _walk_predecessors(pred, a, b))
            longest = np.linalg.norm(np.diff(self._positions[idx], axis=0), axis=1).max()
            pts, length = shortest_path_on_mesh(
                a, b, spine, positions=self._positions, faces=faces, edge_graph=edge_graph,
                steiner=TOL.geodesic_steiner, width=TOL.geodesic_corridor * md[b] + 2 * longest,
                tol=TOL.geodesic_shorten * md[b])
        sid = np.full(len(pts), -1, np.int64)
        sid[0], sid[-1] = a, b
        return idx, pts, length, sid

    def _mesh(self):
        """The triangles and the mesh-edge graph; graph ``None`` when the surfels carry no faces
        (refinement then works on the surfel planes). Built at the first refinement, so graph
        queries do not pay for it."""
        if self._mesh_cache is None:
            faces = self.surfels.faces
            if faces is None or len(faces) == 0:
                self._mesh_cache = (None, None)
            else:
                faces = np.ascontiguousarray(faces, dtype=np.int64)
                self._mesh_cache = (faces, mesh_edge_graph(self._positions, faces))
        return self._mesh_cache


# ---------------------------------------------------------------------- convenience functions
def geodesic_distances(surfels: SurfelSet, sources, *, targets=None, refine: bool = False,
                       **kwargs) -> np.ndarray:
    """One-call :meth:`GeodesicSolver.distances` (builds a solver with ``kwargs``).

    Parameters
    ----------
    surfels : SurfelSet
    sources : (s,) int
    targets : (t,) int, optional
    refine : bool
    **kwargs
        :class:`GeodesicSolver` options (``max_angle``, ``radius``, ``k``, ``scale``, ``bridge``).

    Returns
    -------
    (s, n) or (s, t) float64
    """
    return GeodesicSolver(surfels, **kwargs).distances(sources, targets=targets, refine=refine)


def geodesic_path(surfels: SurfelSet, a, b, *, refine: bool = False, **kwargs) -> GeodesicPath:
    """One-call :meth:`GeodesicSolver.path`.

    Parameters
    ----------
    surfels : SurfelSet
    a, b : int
    refine : bool
    **kwargs
        :class:`GeodesicSolver` options.

    Returns
    -------
    GeodesicPath
    """
    return GeodesicSolver(surfels, **kwargs).path(a, b, refine=refine)


def farthest_point_landmarks(surfels: SurfelSet, k: int, *, seed: int = 0,
                             **kwargs) -> np.ndarray:
    """One-call :meth:`GeodesicSolver.landmarks`.

    Parameters
    ----------
    surfels : SurfelSet
    k : int
    seed : int
    **kwargs
        :class:`GeodesicSolver` options.

    Returns
    -------
    (k,) int64
    """
    return GeodesicSolver(surfels, **kwargs).landmarks(k, seed=seed)


# ---------------------------------------------------------------------- kernels
def _dijkstra(matrix, *, directed=True, **kwargs):
    """scipy's Dijkstra; the SIG matrix is symmetric, so the directed mode (which skips scipy's
    internal symmetrisation of the matrix) gives the undirected distances."""
    return _csgraph_dijkstra(matrix, directed=directed, **kwargs)


def _walk_predecessors(pred, a, b) -> np.ndarray:
    out = [b]
    cur = b
    while cur != a:
        cur = int(pred[cur])
        if cur < 0:  # pragma: no cover - the graph is connected by construction
            raise InputError(f"surfel {b} is not reachable from surfel {a}")
        out.append(cur)
    return np.asarray(out[::-1], np.int64)


def _polyline_length(pts) -> float:
    if len(pts) < 2:
        return 0.0
    return float(np.linalg.norm(np.diff(pts, axis=0), axis=1).sum())


@numba.njit(cache=True)
def _nearest_walk(x, s, pos, indptr, indices):
    """Greedy walk on the graph from surfel ``s`` to a surfel locally nearest ``x``."""
    best = s
    bd = 0.0
    for c in range(3):
        t = x[c] - pos[s, c]
        bd += t * t
    for _ in range(100000):
        nxt, bd = _nearest_among(x, pos, indices, indptr[best], indptr[best + 1], best, bd)
        if nxt == best:
            break
        best = nxt
    return best


@numba.njit(cache=True)
def _project(x, s, pos, nrm, bw, indptr, indices, out):
    """Project ``x`` onto the MLS plane around surfel ``s`` (after walking to the nearest one).

    Writes the point to ``out``; returns the nearest surfel.
    """
    for c in range(3):
        out[c] = x[c]
    for _ in range(2):
        s = _nearest_walk(out, s, pos, indptr, indices)
        h2 = bw[s] * bw[s]
        wsum = 0.0
        cx = 0.0
        cy = 0.0
        cz = 0.0
        nx = 0.0
        ny = 0.0
        nz = 0.0
        fimls = 0.0
        for e in range(indptr[s] - 1, indptr[s + 1]):
            j = s if e < indptr[s] else indices[e]
            d = 0.0
            for c in range(3):
                t = out[c] - pos[j, c]
                d += t * t
            w = np.exp(-d / h2)
            wsum += w
            fimls += w * ((out[0] - pos[j, 0]) * nrm[j, 0] + (out[1] - pos[j, 1]) * nrm[j, 1]
                          + (out[2] - pos[j, 2]) * nrm[j, 2])
            cx += w * pos[j, 0]
            cy += w * pos[j, 1]
            cz += w * pos[j, 2]
            nx += w * nrm[j, 0]
            ny += w * nrm[j, 1]
            nz += w * nrm[j, 2]
        ln = np.sqrt(nx * nx + ny * ny + nz * nz)
        if wsum <= 0.0 or ln <= 0.0:
            nx, ny, nz = nrm[s, 0], nrm[s, 1], nrm[s, 2]
            ln = 1.0
            cx, cy, cz = pos[s, 0], pos[s, 1], pos[s, 2]
            wsum = 1.0
            fimls = 0.0
        nx /= ln
        ny /= ln
        nz /= ln
        cx /= wsum
        cy /= wsum
        cz /= wsum
        h = (out[0] - cx) * nx + (out[1] - cy) * ny + (out[2] - cz) * nz
        h = 0.5 * (h + fimls / wsum)
        out[0] -= h * nx
        out[1] -= h * ny
        out[2] -= h * nz
    return s


@numba.njit(cache=True)
def _relax(P, S, pos, nrm, bw, indptr, indices, tol, max_iter):
    """Gauss-Seidel shortening of the interior points of polyline ``P`` on the surface.

    Each point moves towards the midpoint of its neighbours (at most half the shorter adjacent
    segment), then is projected; stops when a sweep shortens the polyline by
    less than ``tol`` times its length.
    """
    m = P.shape[0]
    x = np.empty(3)
    out = np.empty(3)
    dx = np.empty(3)
    prev = _length(P)
    # successive over-relaxation: the optimal factor of the 1-D Laplacian, capped for stability
    omega = min(1.9, 2.0 / (1.0 + np.sin(np.pi / max(m - 1, 2))))
    for _ in range(max_iter):
        for i in range(1, m - 1):
            s = S[i]
            la = 0.0
            lb = 0.0
            for c in range(3):
                dx[c] = omega * (0.5 * (P[i - 1, c] + P[i + 1, c]) - P[i, c])
                la += (P[i, c] - P[i - 1, c]) ** 2
                lb += (P[i + 1, c] - P[i, c]) ** 2
            step_max = 0.5 * np.sqrt(min(la, lb))
            ln = np.sqrt(dx[0] * dx[0] + dx[1] * dx[1] + dx[2] * dx[2])
            if ln > step_max and ln > 0.0:
                for c in range(3):
                    dx[c] *= step_max / ln
            for c in range(3):
                x[c] = P[i, c] + dx[c]
            s = _project(x, s, pos, nrm, bw, indptr, indices, out)
            # safety: the point must stay on the same sheet of surface as the path. Its new
            # nearest surfel must be linked to its current one, and to the surfels of its two
            # polyline neighbours when the current one is: consecutive points then always sit on
            # linked surfels, whose (surface-tested) edge the segment follows, so the path can
            # never slide across a gap to another part
            if not _adjacent(s, S[i], indptr, indices):
                continue
            # nor face away from its neighbours' surfels (the other side of a thin part)
            if _dot(nrm, s, S[i - 1]) <= 0.0 or _dot(nrm, s, S[i + 1]) <= 0.0:
                continue
            if _adjacent(S[i], S[i - 1], indptr, indices) and \
                    not _adjacent(s, S[i - 1], indptr, indices):
                continue
            if _adjacent(S[i], S[i + 1], indptr, indices) and \
                    not _adjacent(s, S[i + 1], indptr, indices):
                continue
            for c in range(3):
                P[i, c] = out[c]
            S[i] = s
        cur = _length(P)
        if prev - cur < tol * cur:
            break
        prev = cur


@numba.njit(cache=True)
def _dot(nrm, a, b):
    return nrm[a, 0] * nrm[b, 0] + nrm[a, 1] * nrm[b, 1] + nrm[a, 2] * nrm[b, 2]


@numba.njit(cache=True)
def _adjacent(a, b, indptr, indices):
    """Whether surfels ``a`` and ``b`` are equal or linked in the graph."""
    if a == b:
        return True
    for e in range(indptr[b], indptr[b + 1]):
        if indices[e] == a:
            return True
    return False


@numba.njit(cache=True)
def _length(P):
    total = 0.0
    for i in range(1, P.shape[0]):
        d = 0.0
        for c in range(3):
            t = P[i, c] - P[i - 1, c]
            d += t * t
        total += np.sqrt(d)
    return total


@numba.njit(cache=True)
def _refine_path(idx, pos, nrm, bw, spacing, indptr, indices, tol, max_iter, coarse):
    """Coarse-to-fine straightening of the graph path ``idx`` on the surfel planes; returns the
    points."""
    k = idx.shape[0]
    if k <= 2:
        P = np.empty((k, 3))
        for i in range(k):
            P[i] = pos[idx[i]]
        return P
    # arc-length parametrisation of the graph polyline
    cum = np.zeros(k)
    for i in range(1, k):
        d = 0.0
        for c in range(3):
            t = pos[idx[i], c] - pos[idx[i - 1], c]
            d += t * t
        cum[i] = cum[i - 1] + np.sqrt(d)
    total = cum[k - 1]
    h = 0.0
    for i in range(k):
        h += spacing[idx[i]]
    h /= k
    n_fine = max(2, int(np.ceil(total / h)))
    nseg = min(n_fine, max(2, int(np.ceil(total / (coarse * h)))))
    # initial coarse polyline: resample the graph polyline, project
    P = np.empty((nseg + 1, 3))
    S = np.empty(nseg + 1, np.int64)
    out = np.empty(3)
    x = np.empty(3)
    seg = 0
    for q in range(nseg + 1):
        t = total * q / nseg
        while seg < k - 2 and cum[seg + 1] < t:
            seg += 1
        L = cum[seg + 1] - cum[seg]
        f = 0.0 if L <= 0 else (t - cum[seg]) / L
        f = min(max(f, 0.0), 1.0)
        for c in range(3):
            x[c] = (1 - f) * pos[idx[seg], c] + f * pos[idx[seg + 1], c]
        s0 = idx[seg] if f < 0.5 else idx[seg + 1]
        s = _project(x, s0, pos, nrm, bw, indptr, indices, out)
        if _adjacent(s, idx[seg], indptr, indices) or _adjacent(s, idx[seg + 1], indptr, indices):
            P[q] = out
            S[q] = s
        else:  # the projection left the edge's neighbourhood: keep the point on the edge
            P[q] = x
            S[q] = s0
    P[0] = pos[idx[0]]
    P[nseg] = pos[idx[k - 1]]
    S[0] = idx[0]
    S[nseg] = idx[k - 1]
    while True:
        _relax(P, S, pos, nrm, bw, indptr, indices, tol, max_iter)
        if nseg >= n_fine:
            break
        # split every segment at its projected midpoint
        m = P.shape[0]
        Q = np.empty((2 * m - 1, 3))
        T = np.empty(2 * m - 1, np.int64)
        for i in range(m):
            Q[2 * i] = P[i]
            T[2 * i] = S[i]
        for i in range(m - 1):
            for c in range(3):
                x[c] = 0.5 * (P[i, c] + P[i + 1, c])
            s = _project(x, S[i], pos, nrm, bw, indptr, indices, out)
            Q[2 * i + 1] = out
            T[2 * i + 1] = s
        P, S = Q, T
        nseg = 2 * nseg
    return P
