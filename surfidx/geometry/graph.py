"""The spheres-of-influence graph (SIG) over a surfel set.

Two surfels ``i`` and ``j`` are linked when the spheres centred at their positions with radii
``s * r_i`` and ``s * r_j`` intersect, ``|p_i - p_j| < s * (r_i + r_j)``, **and** their (oriented)
normals differ by less than ``max_angle``; the edge weight is the Euclidean distance. ``s`` is the
``scale`` option (1 is the classical SIG). The radius ``r`` is chosen by ``radius``:

* ``"surfel"`` (default): the surfels' own radii. For a mesh these are the coverage radii of the
  incident triangles, so the graph contains (at least) every mesh edge;
* ``"nearest"``: the distance to the nearest other surfel (the classical SIG of Toussaint);
* ``"knn"``: the distance to the ``k``-th nearest surfel (a richer, still scale-adaptive stencil).

The normal test keeps the two sides of thin parts (ears, fingers, sheets) apart: their surfels are
close in space but face opposite ways. The surface test (``max_offset``, see
:data:`DEFAULT_MAX_OFFSET`) removes the shortcuts that remain: edges whose midpoint is not on the
surface near them (gaps between legs, concave folds, chords through a nearby part).

Edges are weighted by the length of the circular arc through both surfels tangent to their planes
(``arc_weights``; exact on a sphere, a little more than the chord on curved parts), which removes
the chords' systematic shortcut on coarse samplings. For a meshed input (``faces``) the mesh edges
are added (``mesh_edges``): they lie on the surface and cross the sharp creases that the normal
tests cut. A surfel that the tests leave without any edge (the tip of
a spike, whose normal is steep to all its neighbours) is linked to the surfels whose spheres meet
its own and whose normals are within 90 degrees of its normal.

Construction is O(N log N) and memory linear in the number of edges: a numba kernel scans a hashed
uniform grid (see ``_sig_edges``).
"""

from __future__ import annotations

import warnings

from ..jit import numba
import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components, minimum_spanning_tree
from scipy.spatial import cKDTree

from ..errors import InputError, TopologyError
from ..validate import as_array, check_positive_int
from .mesh import spacing_radii
from .surfels import SurfelSet

__all__ = ["SphereOfInfluenceGraph", "sphere_of_influence_graph", "DEFAULT_MAX_ANGLE",
           "DEFAULT_SCALE", "DEFAULT_MAX_OFFSET", "RADIUS_MODES"]

DEFAULT_MAX_ANGLE = 60.0
"""Default largest angle (degrees) between the normals of linked surfels.

A narrower angle disconnects models at their sharp creases; a wider one lets paths jump
between nearby parts that face away from each other (the two sides of a thin part). 60 degrees
keeps that protection with a margin for noisy normals. Chosen by measurement on the shared
models: ``benchmarks/geodesics.py`` prints the error of graph distances at each angle.
"""

DEFAULT_SCALE = 2.0
"""Default sphere-radius multiplier ``s``.

With ``s = 1`` and a mesh's coverage radii the graph is essentially the mesh's 1-ring, whose
Dijkstra distances overestimate geodesics by the zig-zag of its edges (metrication error); a
larger scale links farther neighbours, which lowers the error and adds edges. 2 reaches the full
2-ring of a regular sampling, with a margin for irregular ones. ``benchmarks/geodesics.py``
prints the error and mean degree at each scale, and the build and query times at the default.
"""

DEFAULT_MAX_OFFSET = 0.1
"""Default surface test (shortcut test) limit, relative to the edge length.

An edge ``(i, j)`` is kept only when the surfel ``k`` nearest to its midpoint ``m`` is ``i``, ``j``
or linkable to one of them (spheres meet, normals within ``max_angle``: the same sheet of
surface) and ``|n_k . (m - p_k)| <= max_offset * |p_i - p_j|`` (the midpoint lies on the surface;
a chord of a smooth surface stays within its sagitta ``L**2 / 8R``, i.e. ``L / 8R`` relative, while
an edge jumping a gap between two parts or cutting through a fold has its midpoint in the air or
inside). The nearest surfel is exact: it lies within ``2 s r_i`` of the larger surfel ``i``, whose
neighbourhood the grid scan visits anyway, so the test costs no extra search.

A smaller limit cuts valid edges on curved, coarsely sampled parts (distances come out long); a
larger one lets shortcuts back in (distances come out short). Chosen by measurement on the shared
models: ``benchmarks/geodesics.py`` prints the error at each limit. With the test in place, normal
angles wider than :data:`DEFAULT_MAX_ANGLE` do not help the thin models either.
"""

RADIUS_MODES = ("surfel", "nearest", "knn")
MIDPOINT_SLACK = 1.25
"""Surface-test length limit: an edge may be at most ``2 * MIDPOINT_SLACK * s * r_k`` long, ``r_k``
the radius of the surfel nearest its midpoint (a large surfel of a graded sampling must not link
across a finely sampled, detailed region). A tighter limit starts to cut valid edges of coarsely
sampled parts. Chosen by measurement on the shared models: ``benchmarks/geodesics.py`` prints the
error at each limit.
"""

class SphereOfInfluenceGraph:
    """A spheres-of-influence graph: symmetric sparse matrix of Euclidean edge lengths.

    Build it with :meth:`from_surfels` (or :func:`sphere_of_influence_graph`).

    Attributes
    ----------
    matrix : (n, n) scipy.sparse.csr_matrix of float64
        Symmetric; entry ``(i, j)`` is ``|p_i - p_j|`` for linked surfels (at least a tiny positive
        value, so coincident surfels stay linked).
    radii : (n,) float64
        The sphere radii used (before ``scale``).
    max_angle : float
        Normal-angle threshold in degrees.
    scale : float
        Sphere-radius multiplier.
    bridges : (b, 2) int64
        Edges added by ``bridge=True`` to join components (empty otherwise).
    """

    __slots__ = ("matrix", "radii", "max_angle", "scale", "bridges", "_labels")

    def __init__(self, matrix, radii, *, max_angle: float, scale: float, bridges=None):
        self.matrix = sp.csr_matrix(matrix)
        self.radii = radii
        self.max_angle = float(max_angle)
        self.scale = float(scale)
        self.bridges = np.zeros((0, 2), np.int64) if bridges is None else bridges
        self._labels = None

    # ------------------------------------------------------------------ construction
    @classmethod
    def from_surfels(cls, surfels: SurfelSet, *, max_angle: float = DEFAULT_MAX_ANGLE,
                     radius: str = "surfel", k: int = 6, scale: float = DEFAULT_SCALE,
                     max_offset: float | None = DEFAULT_MAX_OFFSET, mesh_edges: bool = True,
                     arc_weights: bool = True, bridge: bool = False,
                     check: bool = True) -> "SphereOfInfluenceGraph":
        """Build the graph of a surfel set.

        Parameters
        ----------
        surfels : SurfelSet
        max_angle : float
            Largest angle in degrees between the normals of linked surfels (0 < angle ≤ 180;
            180 disables the test).
        radius : {"surfel", "nearest", "knn"}
            Which sphere radius each surfel gets (see the module notes).
        k : int
            Neighbour rank for ``radius="knn"``.
        scale : float
            Multiplier of the sphere radii (1 gives the classical SIG).
        max_offset : float or None
            Surface test: an edge is kept only when its midpoint lies within ``max_offset`` times
            the edge length of a surfel disk of either endpoint's neighbourhood (see the module
            notes); ``None`` disables the test.
        mesh_edges : bool
            When the surfels carry mesh faces, also link every mesh edge (they lie on the surface
            by construction, and cross the sharp creases that the normal tests cut).
        arc_weights : bool
            Weight the SIG edges by the length of the circular arc through both surfels tangent
            to their planes instead of the chord (see the module notes).
        bridge : bool
            Join disconnected components with their shortest Euclidean links (a minimum spanning
            tree over components) and warn, instead of raising.
        check : bool
            Check connectivity at all (``False`` returns the raw graph).

        Returns
        -------
        SphereOfInfluenceGraph

        Raises
        ------
        InputError
            On a bad option or fewer than 2 surfels.
        TopologyError
            When the graph is disconnected and ``bridge`` is false; the message gives the number
            of components and the sizes of the largest ones.
        """
        if not isinstance(surfels, SurfelSet):
            raise InputError(f"surfels must be a SurfelSet, got {type(surfels).__name__}")
        n = len(surfels)
        if n < 2:
            raise InputError(f"a graph needs at least 2 surfels, got {n}")
        max_angle = _check_angle(max_angle)
        if not (isinstance(scale, (int, float, np.floating)) and np.isfinite(scale) and scale > 0):
            raise InputError(f"scale must be a positive number, got {scale!r}")
        radii = neighbour_radii(surfels.positions, surfels.radii, radius=radius, k=k)
        if max_offset is not None and not (
                isinstance(max_offset, (int, float, np.floating)) and np.isfinite(max_offset)
                and max_offset >= 0):
            raise InputError("max_offset must be a non-negative number or None, got "
                             f"{max_offset!r}")
        rows, cols, dist = _sig_edges(surfels.positions, surfels.normals, radii * float(scale),
                                      max_angle, -1.0 if max_offset is None else float(max_offset),
                                      arc_weights)
        if mesh_edges and surfels.faces is not None and len(surfels.faces):
            rows, cols, dist = _add_mesh_edges(surfels.positions, surfels.normals, surfels.faces,
                                               rows, cols, dist, arc_weights)
        rows, cols, dist = _link_isolated(surfels.positions, surfels.normals,
                                          radii * float(scale), rows, cols, dist)
        matrix = _symmetric_csr(rows, cols, dist, n)
        graph = cls(matrix, radii, max_angle=max_angle, scale=float(scale))
        if check:
            ncomp, labels = graph._components()
            if ncomp > 1:
                if not bridge:
                    raise TopologyError(_components_message(labels, ncomp, max_angle))
                graph._bridge(surfels.positions, labels, ncomp)
        return graph

    # ------------------------------------------------------------------ queries
    def __len__(self) -> int:
        return self.matrix.shape[0]

    def __repr__(self) -> str:
        return (f"SphereOfInfluenceGraph({self.n_vertices} surfels, {self.n_edges} edges, "
                f"{self.n_components} component(s))")

    @property
    def n_vertices(self) -> int:
        """Number of surfels (graph vertices)."""
        return self.matrix.shape[0]

    @property
    def n_edges(self) -> int:
        """Number of undirected edges."""
        return self.matrix.nnz // 2

    @property
    def degrees(self) -> np.ndarray:
        """(n,) int64: neighbours per surfel."""
        return np.diff(self.matrix.indptr).astype(np.int64)

    @property
    def n_components(self) -> int:
        """Number of connected components."""
        return self._components()[0]

    def components(self) -> tuple[int, np.ndarray]:
        """Connected components.

        Returns
        -------
        count : int
        labels : (n,) int64
            Component of each surfel; component 0 is the largest, then by decreasing size.
        """
        ncomp, labels = self._components()
        return ncomp, labels.copy()

    def component_sizes(self) -> np.ndarray:
        """(c,) int64: component sizes, largest first."""
        ncomp, labels = self._components()
        return np.bincount(labels, minlength=ncomp).astype(np.int64)

    # ------------------------------------------------------------------ internals
    def _components(self):
        if self._labels is None:
            ncomp, labels = connected_components(self.matrix, directed=False)
            sizes = np.bincount(labels, minlength=ncomp)
            order = np.argsort(-sizes, kind="stable")
            rank = np.empty(ncomp, np.int64)
            rank[order] = np.arange(ncomp)
            self._labels = (int(ncomp), rank[labels])
        return self._labels

    def _bridge(self, positions, labels, ncomp):
        links = _bridge_links(positions, labels, ncomp)
        d = np.linalg.norm(positions[links[:, 0]] - positions[links[:, 1]], axis=1)
        d = np.maximum(d, np.finfo(float).tiny)
        sizes = np.bincount(labels, minlength=ncomp)
        warnings.warn(
            f"the spheres-of-influence graph has {ncomp} components (sizes {_sizes_text(sizes)});"
            f" bridged them with {len(links)} straight links of length up to {d.max():.4g}, "
            "so distances across the gaps are Euclidean", UserWarning, stacklevel=3)
        coo = self.matrix.tocoo()
        add = _symmetric_csr(links[:, 0], links[:, 1], d, self.n_vertices).tocoo()
        self.matrix = sp.csr_matrix((np.concatenate([coo.data, add.data]),
                                     (np.concatenate([coo.row, add.row]),
                                      np.concatenate([coo.col, add.col]))),
                                    shape=self.matrix.shape)
        self.matrix.sum_duplicates()
        self.bridges = links
        self._labels = None


def sphere_of_influence_graph(surfels: SurfelSet, **kwargs) -> SphereOfInfluenceGraph:
    """Build the spheres-of-influence graph (see :meth:`SphereOfInfluenceGraph.from_surfels`)."""
    return SphereOfInfluenceGraph.from_surfels(surfels, **kwargs)


# ---------------------------------------------------------------------- helpers
def neighbour_radii(positions, radii, *, radius: str = "surfel", k: int = 6) -> np.ndarray:
    """The sphere radius per surfel for a radius mode.

    Parameters
    ----------
    positions : (n, 3) float64
    radii : (n,) float64
        The surfels' own radii (used by ``"surfel"``).
    radius : {"surfel", "nearest", "knn"}
    k : int
        Neighbour rank for ``"knn"``.

    Returns
    -------
    (n,) float64
        Positive radii.
    """
    if radius not in RADIUS_MODES:
        raise InputError(f"radius must be one of {', '.join(map(repr, RADIUS_MODES))}, "
                         f"got {radius!r}")
    positions = as_array(positions, "positions", shape=(None, 3))
    radii = as_array(radii, "radii", shape=(len(positions),))
    if radius == "surfel":
        return radii.copy()
    kk = 1 if radius == "nearest" else check_positive_int(k, "k")
    return spacing_radii(positions, k=kk, name="surfels")


def _check_angle(max_angle) -> float:
    try:
        a = float(max_angle)
    except (TypeError, ValueError):
        raise InputError(f"max_angle must be a number of degrees, got {max_angle!r}") from None
    if not (0.0 < a <= 180.0):
        raise InputError(f"max_angle must lie in (0, 180] degrees, got {max_angle!r}")
    return a


def _sig_edges(positions, normals, radii, max_angle, max_offset=-1.0, arc=False):
    """Undirected edges (each once) passing the sphere, normal and (``max_offset >= 0``) surface
    tests, weighted by chord length or (``arc``) tangent-arc length.

    A hashed uniform grid (cell = twice the median radius, cells sorted by key and found by
    binary search, so memory is linear in N whatever the extent) is scanned by the surfel with the
    larger radius of each pair, over ``2 r_i``: typical surfels visit 27 cells, and the few large
    ones a few more, so the cost stays O(N log N) even when radii vary widely. The surfels found
    within ``2 r_i`` contain the nearest surfel to the midpoint of every edge of ``i`` (it lies
    within ``|p_i - p_j| / 2 < r_i`` of the midpoint), so the surface test needs no extra search.
    """
    cos_min = np.cos(np.radians(max_angle)) if max_angle < 180.0 else -2.0
    sin_half = np.sin(np.radians(max_angle) / 2.0) if max_angle < 180.0 else 2.0
    cell = 2.0 * float(np.median(radii))
    lo = positions.min(axis=0)
    q = np.floor((positions - lo) / cell).astype(np.int64)
    dims = q.max(axis=0) + 3
    keys = ((q[:, 0] + 1) * dims[1] + (q[:, 1] + 1)) * dims[2] + (q[:, 2] + 1)
    order = np.argsort(keys, kind="stable").astype(np.int64)
    skeys = keys[order]
    pairs, dist = _grid_pairs(positions, normals, radii, cos_min, sin_half, float(max_offset),
                              float(MIDPOINT_SLACK), bool(arc), q, dims, order, skeys, cell)
    return pairs[:, 0], pairs[:, 1], dist


@numba.njit(cache=True)
def _grid_pairs(pos, nrm, r, cos_min, sin_half, max_offset, mid_slack, arc, q, dims, order, skeys,
                cell):
    """The SIG edges; the points are scanned in cell order and each row of cells along z is one
    contiguous run of ``skeys`` (one binary search).

    Surface test (``max_offset >= 0``): the surfel ``k`` nearest to the edge midpoint ``m`` must be
    ``i``, ``j`` or a surfel linkable to one of them (spheres meet, normals within the angle), and
    ``|n_k . (m - p_k)| <= max_offset * |p_i - p_j|``.
    """
    n = pos.shape[0]
    sp_ = np.empty((n, 3))
    sn = np.empty((n, 3))
    sr = np.empty(n)
    for a in range(n):
        o = order[a]
        for c in range(3):
            sp_[a, c] = pos[o, c]
            sn[a, c] = nrm[o, c]
        sr[a] = r[o]
    cap = 16 * n + 16
    pairs = np.empty((cap, 2), np.int64)
    dist = np.empty(cap)
    near = np.empty(n, np.int64)  # surfels within 2 r_i of the current surfel (sorted indices)
    m = np.empty(3)
    k = 0
    for a in range(n):
        i = order[a]
        ri = sr[a]
        reach = int(np.ceil(2.0 * ri / cell))
        qi0 = q[i, 0] + 1
        qi1 = q[i, 1] + 1
        qi2 = q[i, 2] + 1
        z0 = max(qi2 - reach, 0)
        z1 = min(qi2 + reach, dims[2] - 1)
        lim_near = 4.0 * ri * ri
        nn = 0
        for cx in range(max(qi0 - reach, 0), min(qi0 + reach, dims[0] - 1) + 1):
            for cy in range(max(qi1 - reach, 0), min(qi1 + reach, dims[1] - 1) + 1):
                base = (cx * dims[1] + cy) * dims[2]
                kend = base + z1
                b = np.searchsorted(skeys, base + z0)
                while b < n and skeys[b] <= kend:
                    d2 = 0.0
                    for c in range(3):
                        t = sp_[a, c] - sp_[b, c]
                        d2 += t * t
                    if d2 < lim_near:
                        near[nn] = b
                        nn += 1
                    b += 1
        for t_ in range(nn):
            b = near[t_]
            rj = sr[b]
            if rj > ri or (rj == ri and b <= a):
                continue
            d2 = 0.0
            for c in range(3):
                t = sp_[a, c] - sp_[b, c]
                d2 += t * t
            lim = ri + rj
            if d2 >= lim * lim or (sn[a, 0] * sn[b, 0] + sn[a, 1] * sn[b, 1]
                                   + sn[a, 2] * sn[b, 2]) <= cos_min:
                continue
            # the chord must leave both tangent planes by less than max_angle / 2
            ta = 0.0
            tb = 0.0
            for c in range(3):
                t = sp_[b, c] - sp_[a, c]
                ta += t * sn[a, c]
                tb += t * sn[b, c]
            lim_t = sin_half * sin_half * d2
            if not (ta * ta < lim_t and tb * tb < lim_t):
                continue
            if max_offset >= 0.0 and not _midpoint_ok(a, b, d2, sp_, sn, sr, near, nn, cos_min,
                                                      max_offset, mid_slack, m):
                continue
            if k == cap:
                cap *= 2
                p2 = np.empty((cap, 2), np.int64)
                d2a = np.empty(cap)
                p2[:k] = pairs[:k]
                d2a[:k] = dist[:k]
                pairs = p2
                dist = d2a
            pairs[k, 0] = i
            pairs[k, 1] = order[b]
            dd = np.sqrt(d2)
            if arc and d2 > 0.0:  # tangent-arc length (see _arc_lengths)
                half = 0.5 * (np.arcsin(min(abs(ta) / dd, 1.0)) + np.arcsin(min(abs(tb) / dd, 1.0)))
                if half > 1e-6:
                    dd *= half / np.sin(half)
            dist[k] = dd
            k += 1
    return pairs[:k].copy(), dist[:k].copy()


@numba.njit(cache=True)
def _nearest_among(x, pos, cand, lo, hi, best, bd):
    """The point of ``cand[lo:hi]`` nearest ``x`` when nearer than ``best`` (squared distance
    ``bd``); returns the winner and its squared distance."""
    for q in range(lo, hi):
        j = cand[q]
        d = 0.0
        for c in range(3):
            t = x[c] - pos[j, c]
            d += t * t
        if d < bd:
            bd = d
            best = j
    return best, bd


@numba.njit(cache=True)
def _midpoint_ok(a, b, d2, sp_, sn, sr, near, nn, cos_min, max_offset, mid_slack, m):
    """The surface test of edge ``(a, b)`` (sorted indices); ``near`` holds every surfel within
    ``2 r_a`` of ``a``, which includes the nearest surfel to the midpoint."""
    for c in range(3):
        m[c] = 0.5 * (sp_[a, c] + sp_[b, c])
    best, bd = _nearest_among(m, sp_, near, 0, nn, -1, np.inf)
    h = 0.0
    for c in range(3):
        h += (m[c] - sp_[best, c]) * sn[best, c]
    if h * h > max_offset * max_offset * d2:
        return False
    # no longer than the sphere-of-influence diameter of the surface at the midpoint (graded
    # samplings: a large surfel must not link across a finely sampled, detailed region)
    lim = 2.0 * mid_slack * sr[best]
    if d2 > lim * lim:
        return False
    if best == a or best == b:
        return True
    # the nearest surfel must belong to the same sheet: linkable to a or b (sphere and normal
    # tests); a surfel of another part, nearer than the surface the edge should follow, is not
    for e in (a, b):
        dd = 0.0
        for c in range(3):
            t = sp_[e, c] - sp_[best, c]
            dd += t * t
        lim = sr[e] + sr[best]
        if dd < lim * lim and (sn[e, 0] * sn[best, 0] + sn[e, 1] * sn[best, 1]
                               + sn[e, 2] * sn[best, 2]) > cos_min:
            return True
    return False


def _arc_lengths(positions, normals, rows, cols, dist):
    """Length of the circular arc joining two surfels and tangent to their planes (chord if flat).

    The chord ``u = p_j - p_i`` leaves the tangent planes at angles ``a_i = asin(|n_i.u| / |u|)``
    and ``a_j``; the arc turning by ``t = a_i + a_j`` is ``|u| (t / 2) / sin(t / 2)`` long. Exact
    for points of a sphere with radial normals; it removes the chord's systematic shortcut on
    curved parts (a few % per edge on coarse samplings of thin parts).
    """
    u = positions[cols] - positions[rows]
    d = np.maximum(dist, np.finfo(float).tiny)
    si = np.abs(np.einsum("ij,ij->i", u, normals[rows])) / d
    sj = np.abs(np.einsum("ij,ij->i", u, normals[cols])) / d
    half = 0.5 * (np.arcsin(np.minimum(si, 1.0)) + np.arcsin(np.minimum(sj, 1.0)))
    factor = np.ones_like(half)
    big = half > 1e-6
    factor[big] = half[big] / np.sin(half[big])
    return dist * factor


def _add_mesh_edges(positions, normals, faces, rows, cols, dist, arc):
    """Add the mesh edges that the SIG tests left out (each once)."""
    n = len(positions)
    csr = _symmetric_csr(rows, cols, dist, n)
    f = np.asarray(faces, np.int64)
    a = f.ravel()
    b = f[:, [1, 2, 0]].ravel()
    miss = _absent(csr.indptr.astype(np.int64), csr.indices.astype(np.int64), a, b)
    if not miss.any():
        return rows, cols, dist
    pairs = np.stack([np.minimum(a[miss], b[miss]), np.maximum(a[miss], b[miss])], 1)
    pairs = np.unique(pairs[pairs[:, 0] != pairs[:, 1]], axis=0)
    d = np.linalg.norm(positions[pairs[:, 0]] - positions[pairs[:, 1]], axis=1)
    if arc:
        d = _arc_lengths(positions, normals, pairs[:, 0], pairs[:, 1], d)
    return (np.concatenate([rows, pairs[:, 0]]), np.concatenate([cols, pairs[:, 1]]),
            np.concatenate([dist, d]))


@numba.njit(cache=True)
def _absent(indptr, indices, a, b):
    out = np.ones(a.shape[0], np.bool_)
    for e in range(a.shape[0]):
        for t in range(indptr[a[e]], indptr[a[e] + 1]):
            if indices[t] == b[e]:
                out[e] = False
                break
    return out


def _link_isolated(positions, normals, radii, rows, cols, dist):
    """Link surfels left without any edge to their sphere-intersecting neighbours on the same side.

    The tip of a spike or cone (a mesh vertex whose normal averages steep faces) fails the tangent
    test with every neighbour, so the strict tests would isolate it; it is linked to the surfels
    whose spheres meet its own and whose normals lie within 90 degrees of its normal (or to its
    nearest same-side surfel when none meets it). Cheap: such surfels are rare.
    """
    n = len(positions)
    deg = np.bincount(rows, minlength=n) + np.bincount(cols, minlength=n)
    lonely = np.flatnonzero(deg == 0)
    if len(lonely) == 0:
        return rows, cols, dist
    tree = cKDTree(positions)
    reach = float(radii.max())
    add_i, add_j = [], []
    for i in lonely:  # few surfels: a Python loop over them is fine
        nb = np.asarray(tree.query_ball_point(positions[i], radii[i] + reach), np.int64)
        nb = nb[nb != i]
        d = np.linalg.norm(positions[nb] - positions[i], axis=1)
        same = normals[nb] @ normals[i] > 0.0
        ok = same & (d < radii[i] + radii[nb])
        if not ok.any():
            kk = min(16, n)
            d, nb = tree.query(positions[i], k=kk)
            nb, d = np.atleast_1d(nb), np.atleast_1d(d)
            keep = (nb != i) & (normals[nb] @ normals[i] > 0.0)
            ok = np.zeros(len(nb), bool)
            if keep.any():
                ok[np.flatnonzero(keep)[np.argmin(d[keep])]] = True
        add_i.append(np.full(int(ok.sum()), i, np.int64))
        add_j.append(nb[ok])
    ai, aj = np.concatenate(add_i), np.concatenate(add_j)
    # a pair of two lonely surfels would be listed twice
    lo, hi = np.minimum(ai, aj), np.maximum(ai, aj)
    pairs = np.unique(np.stack([lo, hi], 1), axis=0)
    ad = np.linalg.norm(positions[pairs[:, 0]] - positions[pairs[:, 1]], axis=1)
    return (np.concatenate([rows, pairs[:, 0]]), np.concatenate([cols, pairs[:, 1]]),
            np.concatenate([dist, ad]))


def _symmetric_csr(i, j, d, n):
    """Symmetric CSR matrix from undirected edges listed once (no duplicates)."""
    d = np.maximum(np.asarray(d, np.float64), np.finfo(float).tiny)
    indptr, indices, data = _csr_kernel(np.asarray(i, np.int64), np.asarray(j, np.int64), d, n)
    return sp.csr_matrix((data, indices, indptr), shape=(n, n))


@numba.njit(cache=True)
def _csr_kernel(i, j, d, n):
    deg = np.zeros(n + 1, np.int64)
    for e in range(i.shape[0]):
        deg[i[e] + 1] += 1
        deg[j[e] + 1] += 1
    indptr = np.cumsum(deg)
    fill = indptr[:-1].copy()
    indices = np.empty(indptr[n], np.int32)
    data = np.empty(indptr[n])
    for e in range(i.shape[0]):
        a = i[e]
        b = j[e]
        indices[fill[a]] = b
        data[fill[a]] = d[e]
        fill[a] += 1
        indices[fill[b]] = a
        data[fill[b]] = d[e]
        fill[b] += 1
    return indptr, indices, data


def _sizes_text(sizes, show: int = 5) -> str:
    s = np.sort(np.asarray(sizes))[::-1]
    text = ", ".join(str(int(x)) for x in s[:show])
    if len(s) > show:
        text += f", ... ({len(s) - show} more)"
    return text


def _components_message(labels, ncomp, max_angle) -> str:
    sizes = np.bincount(labels, minlength=ncomp)
    return (f"the spheres-of-influence graph is disconnected: {ncomp} components (sizes "
            f"{_sizes_text(sizes)} surfels); the input has separate parts or gaps wider than the "
            f"surfel radii (or normals differing by more than {max_angle:g} degrees). Pass "
            "bridge=True to join them with straight links, a larger max_angle, or split the input")


def _bridge_links(positions, labels, ncomp):
    """Shortest Euclidean links joining the components (Boruvka rounds + MST over components)."""
    labels = labels.copy()
    tree = cKDTree(positions)
    links = []
    while ncomp > 1:
        kk = min(8, len(positions))
        _, nb = tree.query(positions, k=kk)
        nb = nb.reshape(len(positions), -1)
        cand_i, cand_j = [], []
        other = labels[nb] != labels[:, None]
        rows, cols = np.nonzero(other)
        cand_i.append(rows)
        cand_j.append(nb[rows, cols])
        covered = np.zeros(ncomp, bool)
        covered[labels[rows]] = True
        for c in np.flatnonzero(~covered):
            inside = np.flatnonzero(labels == c)
            outside = np.flatnonzero(labels != c)
            _, jj = cKDTree(positions[outside]).query(positions[inside])
            cand_i.append(inside)
            cand_j.append(outside[jj])
        ci = np.concatenate(cand_i)
        cj = np.concatenate(cand_j)
        d = np.maximum(np.linalg.norm(positions[ci] - positions[cj], axis=1),
                       np.finfo(float).tiny)
        a, b = labels[ci], labels[cj]
        # best candidate per unordered component pair
        lo, hi = np.minimum(a, b), np.maximum(a, b)
        key = lo * ncomp + hi
        order = np.lexsort((d, key))
        first = np.ones(len(order), bool)
        first[1:] = key[order][1:] != key[order][:-1]
        best = order[first]
        cg = sp.csr_matrix((d[best], (lo[best], hi[best])), shape=(ncomp, ncomp))
        mst = minimum_spanning_tree(cg).tocoo()
        pair_key = np.minimum(mst.row, mst.col) * ncomp + np.maximum(mst.row, mst.col)
        pos = {int(k): t for t, k in enumerate(key[best])}
        for k in pair_key:
            t = best[pos[int(k)]]
            links.append((int(ci[t]), int(cj[t])))
        merged = sp.csr_matrix((np.ones(len(mst.row)), (mst.row, mst.col)), shape=(ncomp, ncomp))
        ncomp, comp_labels = connected_components(merged, directed=False)
        labels = comp_labels[labels]
    return np.asarray(links, np.int64).reshape(-1, 2)
