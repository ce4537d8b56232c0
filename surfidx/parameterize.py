"""Spherical parameterization of a closed genus-0 surfel set that does not fold.

Default method ``"tutte"`` (the fold-free route, coarse to fine)
----------------------------------------------------------------
0. The surface is a planar triangulation over the surfels: the mesh faces (``SurfelSet.faces``).
   Its topology is checked first (closed, one piece, manifold, Euler characteristic 2), so a
   torus, a pretzel or two pieces fail with :class:`~surfidx.TopologyError` before any mapping.
1. Multilevel hierarchy (``surfidx._decimate``): rounds of independent half-edge collapses under
   the link condition, shortest edges first, shrink the mesh by 4 per level down to at most 64
   vertices; every level triangulates the same sphere. A Tutte map squeezes a limb by
   ``exp(-2π length / girth)`` at any resolution; a mesh of a few dozen vertices has no limbs
   to squeeze.
2. The coarsest mesh is mapped as below (single-level route).
3. Each finer level: the removed vertices come back, coarsest round first, at the mean value
   combination of their ring's sphere positions (exact where the map is locally affine); the
   triangles this folds are untangled (Garanzha et al. 2021: a shape-and-area energy regularised
   so that it stays finite on inverted triangles, minimised while the regularisation shrinks;
   ``surfidx._balance.untangle``); then the map is balanced by L-BFGS on the energy
   ``Σ A (‖J‖²/det + λ (det + 1/det))`` of the map from each 3D triangle to its chord triangle
   (``det`` the area ratio, λ = 0.5), preconditioned by the 3D cotangent Laplacian, with a line
   search that rejects any inverted triangle. The energy is smallest for a similarity of unit
   area ratio and grows without bound as a triangle degenerates, so every accepted iterate is a
   fold-free embedding of the mesh; it trades angle against area distortion, so limbs keep the
   share of the sphere the grid needs (horse: holes 30 % -> 0.01 %, infinite-rate PSNR_D2
   29 -> 71 dB). Möbius normalisation (4) ends each level.
   Should a level fail to untangle, the hierarchy is built again to another coarsest size
   (``_COARSE_LADDER``), and only when every one fails is the whole surface mapped by the
   single-level route.

Single-level route (``_tutte_map``)
-----------------------------------
a. Puncture one vertex (the one of largest area share, or one far from it when that start is as
   clean, see ``_punctures``) and map the rest into the plane by a
   Tutte embedding with positive mean-value weights (Floater 2003), its 1-ring fixed on the unit
   circle (spaced by edge length). Tutte's theorem (Floater's extension to any positive weights)
   makes the planar map an embedding: no triangle folds. The inverse stereographic projection
   (the punctured vertex at the north pole) keeps it an embedding on the sphere.
b. Area reweighting (Yoshizawa, Belyaev & Seidel 2004 style): the weights toward each
   vertex are multiplied by ``exp(-gamma * s)``, ``s`` the graph-smoothed log ratio of
   3D to spherical area share around it, and the Tutte system is solved again (then normalised as
   in 4). Every iterate is again a positive-weight Tutte embedding; a step is accepted only when
   it lowers the area distortion, inverts no mesh triangle on the sphere and adds no folded
   triangle to the spherical Delaunay triangulation of the mapped surfels; otherwise ``gamma``
   is halved.
c. Balancing with the energy of 3.

4. Möbius normalisation: the Möbius automorphism of the sphere that moves the area-weighted centre
   of mass of the vertices to the origin (Gu et al. 2004, Praun & Hoppe 2003), taken in halved
   steps that never invert a mesh triangle. This fixes the three non-rotational Möbius degrees of
   freedom, so the map is canonical up to a rotation.

5. Fold repair (:mod:`surfidx._foldrepair`): single-vertex moves that lower the count of folded
   triangles of the surfels' spherical Delaunay triangulation, never inverting a mesh triangle.
   Where folds remain, a second pass tries every move afresh with the triangulation's unfolded
   triangles kept embedded too (their neighbourhoods propose other moves; ``_SECOND_PASS``).
6. Fold realisation (:mod:`surfidx._circlepattern`, ``_REALISE``): where folds still remain, edges
   of the Delaunay triangulation are flipped to lower them (any flips first, then only convex
   quadrilaterals, then ones closer to Delaunay), and the flipped triangulation is realised as
   the exact Delaunay triangulation of moved points by a circle pattern: the map's corner angles
   projected onto a coherent angle system (Bobenko & Springborn 2004; Rivin 1994), Newton's
   method on the circumradii. Up to three rounds, each kept only when it lowers the count and
   costs the resampling at most ``TOL.realise_loss`` (1 dB) of infinite-rate PSNR_D2 at the
   map's grid level (:class:`_ResamplingCheck`; a realisation changes the scale of whole limbs,
   see :mod:`surfidx._circlepattern`). Where the flips stop with folds left, an annealed flip
   search (:func:`surfidx._circlepattern.anneal_flips`) proposes triangulations with fewer,
   realised first. Measured after step 5 → after 6: scorpion 442 → 4 folded triangles of
   101,302 (flips alone: 20; map about 200 s, was 76), horse 4 → 0, homer 1 → 0; on the 77
   genus-0 retrieval meshes, folds 1688 → 570 in all (flips alone: 640), fold-free models
   40 → 64 (55), at most 0.01 % 46 → 66 (61), at most 0.1 % 61 → 73 (72), over 1 % 2 → 0,
   none losing over 1 dB of PSNR_D2 by the check (the crowding bound instead of the check:
   folds 438, four models losing 1.5-3.0 dB, d041 below 70 dB); their map time 560 → 876 s
   in all, d006 119 s (realisations of annealed triangulations that fail). The realisation is
   fitted to the map by a Möbius map, which keeps the far field in place. A few mesh faces are
   turned over (scorpion about 600, 0.6 % of the sphere), which resampling tolerates (scorpion
   81.2 dB either way). Point clouds too.

All steps use intrinsic quantities only (lengths, angles, areas, mesh connectivity; decimation
ties are broken by index), so a rotated input gives the same sphere points up to a rotation.

Point clouds (surfels without faces)
------------------------------------
A closed genus-0 proxy mesh is reconstructed from the oriented surfels (:mod:`surfidx.proxy`)
and mapped as above; each surfel takes the sphere position of its closest point on the proxy.
The folded triangles of the surfels' own spherical Delaunay triangulation are then repaired with
the triangulation's other triangles kept embedded. On the 77 genus-0 retrieval models given as
point clouds, the repair and a simplified proxy where the proxy's map fell back took the models
with at most 0.01 % folds from 20 to 45 (fold-free 12 -> 40, over 1 % 12 -> 4; mesh input: 45),
mean fold share 0.67 -> 0.16 %, single-level fallbacks 8 -> 4, at 1.3 times the map time.

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
from ._circlepattern import lower_folds
from ._foldrepair import _orientation, folded_mask, repair_folds
from ._tolerance import TOL
from ._validate import as_array, check_positive_int
from .mesh import vertex_area_shares
from .surfels import SurfelSet

__all__ = ["SphericalMap", "parameterize", "count_folds", "hull_triangles", "landmark_stress",
           "area_distortion", "sparse_sampling", "METHODS"]

METHODS = ("tutte", "mds")
"""Names accepted by :func:`parameterize` (the first is the default)."""

_MIN_SURFELS = 8
_COARSE = 64        # the multilevel map's coarsest mesh has at most this many vertices
_COARSE_LADDER = (_COARSE, 4 * _COARSE, _COARSE // 2)
"""Coarsest sizes tried in turn when a level cannot be untangled. A prolonged map of a few dozen
vertices can fold so deeply (a thin frame of glasses, armadillo's fingers) that untangling, which
on the sphere has no fixed boundary, collapses the whole map into a point; another hierarchy
rarely does. The single-level map, which squeezes every limb, is the last resort (retrieval
collection: fallbacks 4 -> 0, a pair of glasses 40 % coverage holes -> 0)."""
_RATIO = 4          # ... and each level has this many times the vertices of the next coarser
_LEVEL_STEPS = 300  # balancing steps at each level, at most, and fewer once converged:
_STRICT_STOP = dict(tol=1e-7, patience=20)   # 20 steps in a row lower the energy by < 1e-7
_LOOSE_STOP = dict(tol=1e-5, patience=5)     # ... on levels above _LOOSE_ABOVE vertices, where a
_LOOSE_ABOVE = 20000                         # step costs 10-100 ms (Igea: 11.6 -> 10 s in all)
_FINAL_STEPS = 1500  # the finest level may take more steps: long limbs still gain area after 300
_FINAL_STEPS_LARGE = 600   # ... but above _LOOSE_ABOVE vertices, where a step costs 10-100 ms
"""A finest level above :data:`_LOOSE_ABOVE` vertices stops after this many steps: about what
the 15 s budget used to allow there, as a count, so that the map is the same on every machine.
Scorpion's finest level is the only one of the benchmark models to use them all (the others
converge in 12-267 steps); it used to stop on the budget after 589-631 steps by the machine's
load, and its folds after the realisation ranged 17-54. 600 steps: 20 folds; 1500 steps (a
faster machine) leave a more anisotropic map: 84 folds. On the retrieval meshes, 600 steps for
the smaller levels too changed 14 models by up to 1.8 dB either way (they converge later)."""
_UNTANGLE_ROUNDS = 60  # eps rounds of untangling at each level, at most (30 steps each)
_SINGLE_LEVEL_WORK = 6e7
"""The single-level map's balancing takes at most ``_SINGLE_LEVEL_WORK / n`` steps (and at
most 3000): its cost per step grows with the vertex count, so a bound on steps times vertices
bounds its time on any input; see :func:`_single_level_steps`."""
_INVERTED_KEPT = 1e-3  # a level may keep this share of its triangles inverted (else: fall back)
_SECOND_PASS = True
_REALISE = True
"""Where the repair leaves folds, the triangulation is chosen by edge flips and realised as the
Delaunay triangulation of moved points (:mod:`surfidx._circlepattern`)."""
_MAX_AREA_DISTORTION = 4.0
"""A single-level fallback map (no level of the hierarchies could be untangled) whose area
distortion exceeds this is refused: on the 77 genus-0 retrieval
models, as meshes and as point clouds, every map that resampled without holes measured at most
2.1, every map that left 16-79 % of the surfels without a grid point (single-level fallbacks of
point clouds whose proxies could not be untangled) at least 5.5."""
_SECOND_SEARCH = False
_PROXY_COARSER = 0.8  # a point cloud's last proxy: this times the automatic grid resolution
_LAM = 0.5          # area weight of the balancing energy (against angle preservation)


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
    sparse_sampling : float
        :func:`sparse_sampling` of the map: how densely an even grid on the sphere samples the
        sparsest-mapped surfels, relative to their count (1 for an even map); it sets the grid
        level with the surfel count (:func:`surfidx.icosphere.choose_level`).
    """

    points: np.ndarray
    method: str
    folded: int
    triangles: int
    landmark_stress: float
    area_distortion: float
    seconds: float
    info: dict = field(default_factory=dict)
    sparse_sampling: float = 1.0

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
                "sparse_sampling": self.sparse_sampling,
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


def count_folds(surfels: SurfelSet, sphere_points, *, triangles=None) -> tuple[int, int]:
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
    triangles : (m, 3) int64, optional
        The hull of ``sphere_points`` when already computed (:func:`hull_triangles`).

    Returns
    -------
    folded : int
    total : int
    """
    pts, tri = _points_and_triangles(surfels, sphere_points, triangles)
    return int(np.count_nonzero(folded_mask(surfels.positions, surfels.normals, tri))), len(tri)


def _points_and_triangles(surfels, sphere_points, triangles):
    """Checked sphere points and the triangles to measure on (default: their hull)."""
    pts = _check_points(surfels, sphere_points)
    tri = hull_triangles(pts) if triangles is None else as_array(
        triangles, "triangles", dtype=np.int64, shape=(None, 3))
    return pts, tri


def _spherical_areas(pts, tri):
    a, b, c = pts[tri[:, 0]], pts[tri[:, 1]], pts[tri[:, 2]]
    num = np.einsum("ij,ij->i", a, np.cross(b, c))
    den = 1.0 + np.einsum("ij,ij->i", a, b) + np.einsum("ij,ij->i", b, c) \
        + np.einsum("ij,ij->i", c, a)
    return 2.0 * np.arctan2(num, den)


def _areas3(p, tri):
    return 0.5 * np.linalg.norm(np.cross(p[tri[:, 1]] - p[tri[:, 0]], p[tri[:, 2]] - p[tri[:, 0]]),
                                axis=1)


def _vertex_areas(f, a3, n):
    """Each vertex's summed 3D area of its triangles ``a3`` (floored above zero), ``(n,)``: the
    weights of the Möbius normalisation."""
    return np.maximum(np.bincount(f.ravel(), np.repeat(a3, 3), minlength=n), 1e-300)


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
    pts, tri = _points_and_triangles(surfels, sphere_points, triangles)
    a3 = _areas3(surfels.positions, tri)
    asph = np.abs(_spherical_areas(pts, tri))
    w = a3 / a3.sum()
    ratio = (asph / asph.sum()) / np.maximum(w, 1e-300)
    lr = np.log(np.clip(ratio, 1e-30, 1e30))
    return float(np.sqrt(np.average(lr ** 2, weights=w)))


SPARSE_QUANTILE = 0.05   # the "sparsest-mapped surfels" of sparse_sampling: this share of them


def sparse_sampling(surfels: SurfelSet, sphere_points, *, triangles=None,
                    quantile: float = SPARSE_QUANTILE) -> float:
    """How well an even grid on the sphere samples the surfels the map squeezes most.

    Each surfel owns a third of its triangles' spherical area ``a_i``; an even grid of ``N``
    points puts about ``N a_i / 4π`` of them near it. The figure is the ``quantile`` of
    ``n a_i / 4π`` over the ``n`` surfels: a grid of ``N`` points gives the sparsest-mapped
    ``quantile`` share of the surfels fewer than ``N / n`` times this many grid points each.
    1 for a map that spreads the surfels evenly; the benchmark models' maps give 0.03–0.57.

    Parameters
    ----------
    surfels : SurfelSet
    sphere_points : (n, 3) float64
    triangles : (m, 3) int64, optional
        Triangles to measure on (default: the hull of ``sphere_points``).
    quantile : float
        In (0, 1).

    Returns
    -------
    float
    """
    if not 0.0 < float(quantile) < 1.0:
        raise InputError(f"quantile must lie in (0, 1), got {quantile!r}")
    pts, tri = _points_and_triangles(surfels, sphere_points, triangles)
    a = np.abs(_spherical_areas(pts, tri))
    share = vertex_area_shares(tri, a, len(pts))
    return float(np.quantile(len(pts) * share / (4.0 * np.pi), float(quantile)))


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


def _punctures(adj, vertex_area):
    """Candidate vertices to puncture: the one of largest area share, and the largest area share
    among the vertices at least half the largest hop distance away from it. Ties are broken by
    index, so the choice depends on intrinsic quantities only."""
    key = np.round(vertex_area / vertex_area.max(), 9)
    v = int(np.flatnonzero(key == key.max())[0])
    hops = dijkstra(adj, indices=v, unweighted=True)
    cand = np.flatnonzero(hops >= 0.5 * hops[np.isfinite(hops)].max())
    key = np.round(vertex_area[cand] / vertex_area[cand].max(), 9)
    return v, int(cand[np.flatnonzero(key == key.max())[0]])


def _ring(f, v):
    """The 1-ring of vertex ``v`` in counter-clockwise order."""
    fv = f[np.any(f == v, axis=1)]
    k = np.argmax(fv == v, axis=1)
    a = fv[np.arange(len(fv)), (k + 1) % 3]
    b = fv[np.arange(len(fv)), (k + 2) % 3]
    nxt = dict(zip(a.tolist(), b.tolist()))
    ring = [int(a[0])]
    for _ in range(len(a) - 1):
        ring.append(nxt[ring[-1]])
    return np.array(ring, dtype=np.int64)


class _TutteSystem:
    """Tutte's linear system of the mesh punctured at one vertex, its 1-ring fixed on the unit
    circle (spaced by edge length); the punctured vertex goes to infinity (the north pole)."""

    def __init__(self, p, f, vertex, ring):
        n = len(p)
        self.n, self.vertex, self.ring = n, vertex, ring
        self.inner = np.setdiff1d(np.arange(n), np.concatenate([[vertex], ring]))
        el = np.linalg.norm(p[ring] - p[np.roll(ring, -1)], axis=1)
        ang = np.concatenate([[0.0], np.cumsum(el)[:-1]]) / el.sum() * 2 * np.pi
        self.ub = np.column_stack([np.cos(ang), np.sin(ang)])
        self.mirror = None

    def solve(self, w):
        from scipy.sparse.linalg import splu

        rs = np.asarray(w.sum(axis=1)).ravel()
        lap = (sp.diags(rs) - w).tocsr()
        rows = lap[self.inner]
        a = rows[:, self.inner].tocsc()
        b = rows[:, self.ring]
        u = np.zeros((self.n, 2))
        u[self.ring] = self.ub
        # a diagonally dominant M-matrix: no pivoting needed
        lu = splu(a, permc_spec="COLAMD", diag_pivot_thresh=0.0)
        u[self.inner] = lu.solve(np.asarray(-(b @ self.ub)))
        return u

    def sphere(self, u, f):
        """Inverse stereographic projection, oriented so that the mesh keeps its orientation."""
        r2 = (u ** 2).sum(axis=1)
        x = np.column_stack([2 * u[:, 0], 2 * u[:, 1], r2 - 1.0]) / (1.0 + r2)[:, None]
        x[self.vertex] = [0.0, 0.0, 1.0]
        if self.mirror is None:
            self.mirror = bool(np.sum(_orientation(x, f)) < 0)
        if self.mirror:
            x[:, 0] *= -1.0
        return x


def _mobius(x, a):
    """The Möbius automorphism of the unit ball sending ``a`` (``|a| < 1``) to the origin, applied
    to unit vectors ``x`` (Ahlfors): orientation preserving, maps the sphere onto itself."""
    aa = a @ a
    d = x - a
    y = (1.0 - aa) * d - (d ** 2).sum(axis=1)[:, None] * a
    y /= (1.0 - 2.0 * (x @ a) + aa)[:, None]
    return y / np.linalg.norm(y, axis=1)[:, None]


def _centre(x, weights, f, *, iterations: int = 60, tol: float = 1e-10):
    """Möbius normalisation: move the ``weights``-weighted centre of mass of ``x`` to the origin.

    Fixes the three non-rotational Möbius degrees of freedom (Gu et al. 2004; Praun & Hoppe 2003).
    A step is halved while it would invert a mesh triangle on the sphere (more of them than
    were inverted before)."""
    w = weights / weights.sum()
    inverted = np.count_nonzero(_orientation(x, f) <= 0)   # none, unless untangling left some
    for _ in range(iterations):
        c = w @ x
        if np.linalg.norm(c) < tol:
            break
        h = 0.5
        while h > 1e-3:
            y = _mobius(x, h * c)
            if np.count_nonzero(_orientation(y, f) <= 0) <= inverted:
                break
            h *= 0.5
        else:
            break
        x = y
    return x


def _tutte_map(surfels: SurfelSet, *, iterations: int, gamma: float, balance: bool = True,
               balance_steps: int | None = None, faces=None):
    """Single-level map: Tutte embedding, at most ``iterations`` reweighting steps, then (with
    ``balance``) untangling and distortion balancing, at most ``balance_steps`` steps (default
    :func:`_single_level_steps`); ``faces``: those of :func:`_oriented_faces`, when already
    computed."""
    f = _oriented_faces(surfels) if faces is None else faces
    p = surfels.positions
    n = len(p)
    a3 = _areas3(p, f)
    if not a3.sum() > 0:
        raise InputError("the surface has zero area")
    share3 = a3 / a3.sum()
    va = _vertex_areas(f, a3, n)
    w0 = _mean_value_weights(p, f)
    adj = (w0 > 0).astype(np.float64)
    adj = adj + adj.T + sp.identity(n, format="csr")
    vertex = None
    system = None

    def spread(x):
        """Area-weighted RMS of the log ratio of 3D to sphere area share over the faces."""
        asph = np.abs(_spherical_areas(x, f))
        lr = np.log(np.clip(share3 / np.maximum(asph / asph.sum(), 1e-300), 1e-300, 1e300))
        return float(np.sqrt(np.average(lr ** 2, weights=share3)))

    def evaluate(lw):
        x = system.sphere(system.solve(w0 @ sp.diags(np.exp(lw))), f)
        x = _centre(x, va, f)
        return x, spread(x), int(np.count_nonzero(_orientation(x, f) <= 0))

    # log column weights: Yoshizawa-style reweighting, the weights toward a vertex whose
    # neighbourhood is squeezed on the sphere (3D share > sphere share) are lowered, so its
    # neighbours move away from it and its region grows; every iterate is a Tutte embedding
    avg = sp.diags(1.0 / np.asarray(adj.sum(axis=1)).ravel()) @ adj
    smooth = 20
    lw = np.zeros(n)
    # two candidate punctures: the vertex of largest area share, and one far from it (puncturing
    # at the largest share can let the balancing collapse the neighbourhood of the fixed 1-ring);
    # the far one is kept when its start is as clean (mesh and Delaunay folds)
    starts = []
    for cand in _punctures(adj, va):
        system = _TutteSystem(p, f, cand, _ring(f, cand))
        x, sd, neg = evaluate(lw)
        starts.append((neg, count_folds(surfels, x), cand, system, x, sd))
    pick = starts[-1] if starts[-1][:2] <= starts[0][:2] else starts[0]
    neg, (start_folds, total), vertex, system, x, sd = pick
    # a step is accepted only when the spherical Delaunay triangulation of the mapped surfels
    # keeps at most the folds of the start (at most 0.01 % of the triangles where it had some)
    allowed = max(start_folds, int(1e-4 * total))
    g = gamma
    accepted = switches = 0
    max_switches = 0
    for _ in range(iterations):
        asph = np.bincount(f.ravel(), np.repeat(np.abs(_spherical_areas(x, f)), 3), minlength=n)
        step = np.clip(np.log(va / va.sum() / np.maximum(asph / asph.sum(), 1e-300)), -10, 10)
        for _ in range(smooth):  # a smooth reweighting keeps the map close to conformal
            step = avg @ step
        improved = False
        while g > 0.02:
            lw2 = lw - g * step
            x2, sd2, neg2 = evaluate(lw2)
            if neg2 <= neg and sd2 < sd and count_folds(surfels, x2)[0] <= allowed:
                lw, x, sd, neg = lw2, x2, sd2, neg2
                improved = True
                accepted += 1
                g = min(gamma, 1.5 * g)
                break
            g *= 0.5
        if not improved:
            if switches >= max_switches:
                break
            # the fixed 1-ring cannot adapt: puncture again, far from the current puncture
            switches += 1
            far = int(np.argmin(x @ x[system.vertex]))
            system = _TutteSystem(p, f, far, _ring(f, far))
            x, sd, neg = evaluate(lw)
            g = gamma
    x = x / np.linalg.norm(x, axis=1)[:, None]
    # distortion balancing: limbs squeezed by the harmonic start regain their share of
    # the sphere; every iterate stays a fold-free embedding of the mesh (see surfidx._balance)
    from ._balance import balance as balance_map, untangle

    if not balance:
        neg = int(np.count_nonzero(_orientation(x, f) <= 0))
        return x, {"mesh_folds": neg, "mesh_area_distortion": sd, "iterations": accepted,
                   "punctured_vertex": vertex, "balance_steps": 0}
    if neg:
        # a limb squeezed below the floating-point floor left triangles inverted (balancing
        # needs a fold-free start): untangle first, as the multilevel map does at each level
        x, _ = untangle(x, p, f)
        sd = spread(x)
    x_start, sd_start = x, sd
    steps = _single_level_steps(n) if balance_steps is None else balance_steps
    x, binfo = balance_map(x, p, f, iterations=steps, lam=_LAM, max_cot=np.inf)
    x = _centre(x, va, f)   # area-weighted centre of mass at the origin again (a tiny Möbius step)
    sd = spread(x)
    if sd > sd_start:
        # from a deeply squeezed start (energy ~1e15) the steps may end with the few tiniest
        # triangles grown at the expense of the bulk: keep the start, whose area spread is lower
        x, sd = x_start, sd_start
        binfo = dict(binfo, steps=0, energy=binfo["energy_start"])
    neg = int(np.count_nonzero(_orientation(x, f) <= 0))
    return x, {"mesh_folds": neg, "mesh_area_distortion": sd, "iterations": accepted,
               "punctured_vertex": vertex, "balance_steps": binfo["steps"],
               "balance_energy": float(binfo["energy"])}


def _multilevel_map(surfels: SurfelSet, *, iterations: int, gamma: float, balance: bool = True,
                    coarse: int = _COARSE, ratio: int = _RATIO, faces=None,
                    steps: int = _LEVEL_STEPS):
    """Coarse-to-fine map (Praun & Hoppe 2003 in spirit): decimate by ``ratio``, map the coarser
    mesh (recursively, down to ``coarse`` vertices, which :func:`_tutte_map` maps), carry the map
    to every vertex, untangle what folded on the way and balance at this level's resolution.

    A Tutte start squeezes a limb by ``exp(-2π length / girth)`` at any resolution, and balancing
    from there must undo factors of 1e20 in area; a mesh of a few dozen vertices has no limbs to
    squeeze, and each finer level starts from a map that is right at large scales."""
    from ._balance import balance as balance_map, untangle
    from ._decimate import decimate

    options = dict(iterations=iterations, gamma=gamma, balance=balance, coarse=coarse,
                   ratio=ratio)
    n = len(surfels)
    f = _oriented_faces(surfels) if faces is None else faces   # decimation keeps the topology
    p = surfels.positions
    h = decimate(p, f, max(coarse, n // ratio)) if n > coarse else None
    if h is None or len(h.vertices) >= n:
        x, info = _tutte_map(surfels, iterations=iterations, gamma=gamma, balance=balance)
        return x, dict(info, levels=1, base_vertices=n)
    kept = h.vertices
    index = np.full(n, -1, dtype=np.int64)
    index[kept] = np.arange(len(kept))
    small = SurfelSet(p[kept], surfels.normals[kept], surfels.radii[kept], faces=index[h.faces])
    xc, info = _multilevel_map(small, faces=small.faces, **options)
    x = np.zeros((n, 3))
    x[kept] = xc
    x = h.prolong(x, p, unit=True)
    # bounded by rounds of steps, never by the clock, so that the map is the same on every
    # machine at any load
    x, uinfo = untangle(x, p, f, rounds=_UNTANGLE_ROUNDS if balance else 0)
    # a few triangles left inverted (slivers of a randomly split mesh can pin the untangling)
    # cost a few folds; the single-level map instead squeezes every limb
    if uinfo["inverted"] > _INVERTED_KEPT * len(f):
        raise _Untangled(n)
    x, binfo = balance_map(x, p, f, iterations=steps if balance else 0, lam=_LAM,
                           max_cot=np.inf, **(_LOOSE_STOP if n > _LOOSE_ABOVE else _STRICT_STOP))
    x = _centre(x, _vertex_areas(f, _areas3(p, f), n), f)
    neg = int(np.count_nonzero(_orientation(x, f) <= 0))
    return x, {"mesh_folds": neg, "levels": info["levels"] + 1,
               "base_vertices": info["base_vertices"],
               "untangle_rounds": uinfo["rounds"] + info.get("untangle_rounds", 0),
               "balance_steps": binfo["steps"], "balance_energy": float(binfo["energy"])}


def _single_level_steps(n: int) -> int:
    """Balancing steps of a single-level map of ``n`` vertices: 3000 up to 20,000 vertices,
    then ``_SINGLE_LEVEL_WORK / n`` (at least 300)."""
    return int(min(3000, max(300, _SINGLE_LEVEL_WORK // max(n, 1))))


class _Untangled(Exception):
    """A level of the multilevel map kept inverted triangles (the caller falls back)."""


def _mesh_map(surfels: SurfelSet, *, repair: bool = True, **options):
    """The multilevel map, or the single-level one where a level could not be untangled; then
    the folded Delaunay triangles are repaired by local moves (:mod:`surfidx._foldrepair`)."""
    f = _oriented_faces(surfels)
    steps = _FINAL_STEPS if len(surfels) <= _LOOSE_ABOVE else _FINAL_STEPS_LARGE
    for tries, coarse in enumerate(_COARSE_LADDER):
        try:
            x, info = _multilevel_map(surfels, faces=f, steps=steps, coarse=coarse,
                                      **options)
            info = dict(info, coarse=coarse, retries=tries)
            break
        except _Untangled:
            continue
    else:
        x, info = _tutte_map(surfels, faces=f, **options)
        info = dict(info, levels=1, base_vertices=len(surfels), fallback=1,
                    retries=len(_COARSE_LADDER))
    if repair:
        x, info = _repair(x, surfels, info, mesh=f)
    return x, info


def _repair(x, surfels: SurfelSet, info: dict, *, mesh=None):
    """Fold repair (:func:`surfidx._foldrepair.repair_folds`) of the map ``x``, then, where folds
    remain, a second pass: every move tried afresh (without the random search unless
    ``_SECOND_SEARCH``), the surfels' Delaunay triangles that are not folded kept embedded too
    (their neighbourhoods propose other moves). ``mesh`` (faces) is kept embedded in both passes;
    without one (a point cloud) the first pass keeps the unfolded Delaunay triangles, and a
    triangulation with no folded triangle, or only folded ones, is left as it is."""
    p, normals = surfels.positions, surfels.normals

    def unfolded(x):
        tri = hull_triangles(x)
        bad = folded_mask(p, normals, tri)
        return bad, tri[~bad] if mesh is None else np.concatenate([mesh, tri[~bad]])

    faces = mesh
    if mesh is None:
        bad, faces = unfolded(x)
        if not bad.any() or bad.all():
            return x, info
    x, rinfo = repair_folds(x, p, normals, faces, hull=hull_triangles)
    info = dict(info, folds_repaired=rinfo["folds_before"] - rinfo["folds"],
                repair_rounds=rinfo["rounds"])
    folds = rinfo["folds"]
    if folds and _SECOND_PASS:
        x, r2 = repair_folds(x, p, normals, unfolded(x)[1], hull=hull_triangles,
                             search=_SECOND_SEARCH)
        info["folds_repaired"] += r2["folds_before"] - r2["folds"]
        folds = r2["folds"]
    if folds and _REALISE:
        x, r3 = lower_folds(x, p, normals, accept=_ResamplingCheck(surfels, x))
        info = dict(info, folds_realised=r3["folds_before"] - r3["folds"],
                    realise_rounds=r3["rounds"], realise_refused=r3["refused"],
                    realise_annealed=r3["annealed"])
    return x, info


class _ResamplingCheck:
    """Whether a fold realisation of the map ``x`` keeps the resampling's quality: its
    infinite-rate PSNR_D2 (geometry resampled at the grid level chosen for ``x``, against the
    surfels) is at most ``TOL.realise_loss`` dB below that of ``x``.

    What a realisation costs shows only in the resampling: scorpion's first crowds two
    points to 0.40 and 0.50 of their neighbours' distance and keeps 81.2 dB, while on retrieval
    mesh d074 one that crowds none below 0.46 costs 8.9 dB (75.1 -> 66.3; the flips of
    the next, milder rung cost 0.3) and one on d037 crowds none below 0.72 and costs 2.1."""

    def __init__(self, surfels: SurfelSet, x):
        from .icosphere import choose_level

        self.surfels = surfels
        self.level = choose_level(len(surfels), sparse_sampling=sparse_sampling(surfels, x))
        self.floor = self.psnr(x) - TOL.realise_loss

    def psnr(self, x) -> float:
        from .metrics import evaluate
        from .resample import grid_to_surfels, resample

        grid = grid_to_surfels(resample(self.surfels, x, self.level, color=False))
        return float(evaluate(self.surfels, grid)["psnr_d2"])

    def __call__(self, y) -> bool:
        return self.psnr(y) >= self.floor


def _proxy_tutte_map(surfels: SurfelSet, *, repair: bool = True, **options):
    """The Tutte map of a point cloud (surfels without faces) through a closed proxy mesh.

    :func:`surfidx.proxy.proxy_mesh` reconstructs a closed genus-0 triangle mesh from the oriented
    surfels; that mesh is mapped with :func:`_mesh_map` (without its repair: the surfels' hull is
    not the proxy's), and each surfel takes the sphere position of its closest point on the proxy
    (barycentric interpolation, renormalised). Where the proxy's map falls back to the
    single-level route, a proxy with half of its vertices collapsed (shortest edges first) is
    mapped instead, and should that fall back too, a proxy on a coarser grid
    (:func:`_coarser_proxy_map`). With ``repair``, the folded triangles of the surfels' own spherical Delaunay
    triangulation are then repaired as a mesh's are (:func:`surfidx._foldrepair.repair_folds`),
    the triangulation's other triangles standing in for the mesh that must stay embedded.
    """
    from ._decimate import decimate
    from .mesh import TriangleMesh
    from .proxy import proxy_mesh, transfer

    v, f = proxy_mesh(surfels)
    proxy = TriangleMesh(v, f, name=surfels.name).to_surfels()  # every proxy vertex is used
    x, info = _mesh_map(proxy, repair=False, **options)   # the surfels' hull is not the proxy's
    if info.get("fallback"):
        # the marching-cubes slivers stopped every hierarchy from untangling (an ant's point
        # cloud: the single-level map gave PSNR_D2 19 dB): map a proxy with its shortest half of
        # edges collapsed instead (65.7 dB), its vertices still on the reconstructed surface
        h = decimate(v, f, len(v) // 2)
        index = np.full(len(v), -1, dtype=np.int64)
        index[h.vertices] = np.arange(len(h.vertices))
        v2, f2 = v[h.vertices], index[h.faces]
        proxy2 = TriangleMesh(v2, f2, name=surfels.name).to_surfels()
        x2, info2 = _mesh_map(proxy2, repair=False, **options)
        if not info2.get("fallback"):
            v, f, x, info = v2, f2, x2, dict(info2, proxy_simplified=1)
        else:
            # then a proxy on a coarser grid (a pair of glasses' cloud, d062: both fell back,
            # the proxy at 0.8 times the automatic resolution maps at once)
            v, f, x, info = _coarser_proxy_map(surfels, (v, f, x, info), **options)
    pts = transfer(surfels.positions, v, f, x)
    pts /= np.linalg.norm(pts, axis=1)[:, None]
    if repair:
        # the surfels have no mesh: their own spherical Delaunay triangulation, less its folded
        # triangles, is the mesh the repair keeps embedded while it moves the folds' corners
        pts, info = _repair(pts, surfels, info)
    info = dict(info, proxy_vertices=len(v), proxy_faces=len(f))
    return pts, info


def _coarser_proxy_map(surfels: SurfelSet, current, **options):
    """The proxy at ``_PROXY_COARSER`` times the automatic grid resolution and its map, or
    ``current`` (vertices, faces, map, info) when that proxy is not genus 0 or falls back too."""
    from .mesh import TriangleMesh
    from .proxy import _spacing, proxy_mesh

    p = surfels.positions
    cells = _PROXY_COARSER * float((p.max(axis=0) - p.min(axis=0)).max()) / _spacing(p)
    try:
        v, f = proxy_mesh(surfels, resolution=int(np.clip(np.ceil(cells), 24, 200)))
    except TopologyError:
        return current
    x, info = _mesh_map(TriangleMesh(v, f, name=surfels.name).to_surfels(), repair=False,
                        **options)
    return current if info.get("fallback") else (v, f, x, dict(info, proxy_coarser=1))



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
                 landmarks: int = 32, iterations: int = 40, gamma: float = 0.15,
                 balance: bool = True, stress: bool = True) -> SphericalMap:
    """Map surfels to the unit sphere.

    Parameters
    ----------
    surfels : SurfelSet
        A closed genus-0 surface. Method ``"tutte"`` maps the mesh faces (``surfels.faces``); a
        point cloud (no faces) is mapped through a closed proxy mesh reconstructed from the
        oriented surfels (:func:`surfidx.proxy.proxy_mesh`).
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
    balance : bool
        Untangle and balance the distortion at each level (False: the Tutte start, a level
        whose prolongation folds falls back to the single-level map; for tests and
        comparisons). Every stage stops on counts of steps or rounds, never on the clock, so
        the map is the same on every machine and at any load.
    stress : bool
        Compute the landmark stress figure (geodesics from ``landmarks`` sources).

    Returns
    -------
    SphericalMap

    Raises
    ------
    InputError
        Unknown method, bad options, too few surfels.
    TopologyError
        Several pieces, holes, pinched vertices, genus > 0, inconsistent winding (for a point
        cloud: a proxy surface that is not one closed genus-0 piece); a default map that
        squeezes parts of the surface to nothing (area distortion above
        ``_MAX_AREA_DISTORTION`` after no level could be untangled).
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
            pts, info = _proxy_tutte_map(surfels, iterations=iterations, gamma=float(gamma),
                                         balance=bool(balance))
        else:
            pts, info = _mesh_map(surfels, iterations=iterations, gamma=float(gamma),
                                  balance=bool(balance))
    else:
        if surfels.faces is not None and len(surfels.faces):
            _oriented_faces(surfels)  # topology check before mapping
        pts, info, lm, dist = _mds_map(surfels, landmarks=landmarks, seed=seed,
                                       maxiter=max(10 * iterations, 10))
    seconds = time.perf_counter() - t0
    tri = hull_triangles(pts)
    folded, total = count_folds(surfels, pts, triangles=tri)
    ad = area_distortion(surfels, pts, triangles=tri)
    if method == "tutte" and info.get("fallback") and ad > _MAX_AREA_DISTORTION:
        what = "its proxy surface" if info.get("proxy_vertices") else "the mesh"
        raise TopologyError(
            f"the spherical map squeezes parts of the surface to nothing (area distortion "
            f"{ad:.1f}; maps that resample well stay below {_MAX_AREA_DISTORTION:g}): no level "
            f"of {what} could be untangled, so the grid would miss those parts; thin or touching "
            "parts are the usual cause" + (": mesh the scan, or sample it more densely"
                                           if info.get("proxy_vertices") else ""))
    sparse = sparse_sampling(surfels, pts, triangles=tri)
    st = float("nan")
    if stress:
        if lm is None:
            lm, dist = _geodesics(surfels, min(landmarks, len(surfels)), seed)
        st = landmark_stress(pts, lm, dist)
    return SphericalMap(pts, method, folded, total, st, ad, seconds, info, sparse)
