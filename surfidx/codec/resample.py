"""Resampling mapped surfels on the icosahedral grid, and reconstruction from grid values.

The layers (x, y, z and, with colour, r, g, b) are interpolated at the grid vertices with
barycentric coordinates in a spherical triangulation of the mapped surfels
(:func:`map_triangles`): a mesh's own faces when the map embeds them (every face
counter-clockwise, covering the sphere once: the default map of :mod:`surfidx.sphere` always
does), so grid points land on the input's triangles; otherwise (a point cloud, or a map that
inverts a face) the spherical Delaunay triangulation of the mapped surfels (their convex hull). Point location is exact: every query walks from the triangle of
its nearest site across the edge it lies beyond (a numba kernel over all queries), so every grid
vertex finds its triangle. Only where the triangulation is no proper one of the sphere (the hull of
a folded map that leaves part of the sphere empty) can a walk fail; such a query takes the best of
the triangles around nearby sites, or of all triangles, or else the nearest site's value.

Barycentric coordinates are those of the central (gnomonic) projection of the query onto the
plane of its chord triangle: they are non-negative inside, sum to 1, reproduce constants exactly
and reproduce exactly any function that is affine on each chord triangle.

Positions are then lifted off the flat triangle by a Phong tessellation (Boubekeur & Alexa
2008) whose corner weights are sharpened like blended splats:
``p* = p - α Σ_i w_i ((p - v_i) · n_i) n_i``, with ``p = Σ_i b_i v_i`` the linear point,
``(p - v_i) · n_i`` its height above the tangent plane (the disk) of corner ``i`` and
``w_i = b_i^s / Σ_j b_j^s``. ``s = 1`` is the paper's Phong point ``(1 - α) p + α Σ_i b_i π_i(p)``;
a larger ``s`` lets the disk of the nearest corner dominate near it, so a grid point lies on the
surface the surfels' disks describe (the point-to-plane error against the surfels measures
exactly this), continuous across every edge (a corner off the edge has ``b = 0``) and exact on
planes. ``α = PHONG_ALPHA = 0.9``, ``s = PHONG_SHARPNESS = 4`` (``phong=0`` keeps the linear
point). Colours stay linear.

The sharpened lift and interpolation in the mesh's own faces both raise the infinite-rate
PSNR_D2 of the resampling against the input; ``benchmarks/parameterization.py`` measures it.
"""

from __future__ import annotations

from functools import cached_property

from ..jit import numba
import numpy as np

from ..errors import InputError
from ..validate import as_array
from ..geometry.icosphere import icosphere, level_of_count, vertex_count
from ..geometry.mesh import TriangleMesh
from ..tolerance import TOL
from ..geometry.unitsphere import hull_triangles, map_points, triangle_areas
from ..geometry.surfels import SurfelSet

__all__ = ["PHONG_ALPHA", "PHONG_SHARPNESS", "locate", "locate_grid", "map_triangles", "resample",
           "grid_to_surfels", "grid_to_mesh", "layer_names", "locate_surfels", "grid_patches"]

PHONG_ALPHA = 0.9
"""Blend of the Phong-tessellation lift in :func:`resample` (0: linear, 1: full projection)."""

PHONG_SHARPNESS = 4.0
"""Exponent of the lift's corner weights ``b_i^s / Σ b_j^s`` in :func:`resample` (1: Phong)."""


def layer_names(has_color: bool) -> tuple[str, ...]:
    """Names of the resampled layers: ``("x", "y", "z")`` plus ``("r", "g", "b")`` with colour."""
    return ("x", "y", "z", "r", "g", "b") if has_color else ("x", "y", "z")


@numba.njit(cache=True)
def barycentric(q, a, b, c):
    """Barycentric coordinates of ``q`` in the triangle ``a, b, c`` (central projection onto the
    chord plane), normalised to sum 1.

    Parameters
    ----------
    q, a, b, c : ndarray of float64, shape (3,)
        The query and the triangle's corners.

    Returns
    -------
    l0, l1, l2 : float
        The coordinates (all at least 0 inside); -1 each for a degenerate triangle.
    s : float
        Their sum before normalising (-1 for a degenerate triangle).
    """
    # solve q = l0 a + l1 b + l2 c, then normalise (central projection onto the chord plane)
    m00, m01, m02 = a[0], b[0], c[0]
    m10, m11, m12 = a[1], b[1], c[1]
    m20, m21, m22 = a[2], b[2], c[2]
    det = (m00 * (m11 * m22 - m12 * m21) - m01 * (m10 * m22 - m12 * m20)
           + m02 * (m10 * m21 - m11 * m20))
    if det == 0.0:  # degenerate (collinear or repeated) sites: never contains a query
        return -1.0, -1.0, -1.0, -1.0
    l0 = (q[0] * (m11 * m22 - m12 * m21) - m01 * (q[1] * m22 - m12 * q[2])
          + m02 * (q[1] * m21 - m11 * q[2])) / det
    l1 = (m00 * (q[1] * m22 - m12 * q[2]) - q[0] * (m10 * m22 - m12 * m20)
          + m02 * (m10 * q[2] - q[1] * m20)) / det
    l2 = (m00 * (m11 * q[2] - q[1] * m21) - m01 * (m10 * q[2] - q[1] * m20)
          + q[0] * (m10 * m21 - m11 * m20)) / det
    s = l0 + l1 + l2
    if s == 0.0:
        return -1.0, -1.0, -1.0, -1.0
    return l0 / s, l1 / s, l2 / s, s


@numba.njit(cache=True)
def _walk(queries, pts, tri, nbr, start, eps):
    nq = queries.shape[0]
    out_t = np.empty(nq, np.int64)
    out_b = np.empty((nq, 3))
    # a walk crosses O(sqrt(m)) triangles of a triangulation of the sphere; one that goes on much
    # longer is cycling among degenerate triangles (folded maps) and is cut short
    steps = 2 * int(np.sqrt(tri.shape[0])) + 50
    for k in range(nq):
        q = queries[k]
        t = start[k]
        found = False
        for step in range(steps):
            i0, i1, i2 = tri[t, 0], tri[t, 1], tri[t, 2]
            l0, l1, l2, s = barycentric(q, pts[i0], pts[i1], pts[i2])
            if s > 0 and l0 >= -eps and l1 >= -eps and l2 >= -eps:
                found = True
                break
            # cross the edge opposite the most negative coordinate; out of a degenerate triangle
            # by each edge in turn (always the same one can cycle between two of them)
            if s <= 0:
                j = (step + k) % 3
            elif l0 <= l1 and l0 <= l2:
                j = 0
            elif l1 <= l2:
                j = 1
            else:
                j = 2
            t = nbr[t, j]
            if t < 0:
                break
        if not found:
            t = -1
        else:
            l0, l1, l2, s = barycentric(q, pts[tri[t, 0]], pts[tri[t, 1]], pts[tri[t, 2]])
            out_b[k, 0] = l0
            out_b[k, 1] = l1
            out_b[k, 2] = l2
        out_t[k] = t
    return out_t, out_b


@numba.njit(cache=True)
def _scan(queries, pts, tri, ptr, cand):
    """For each query, the triangle with the largest smallest coordinate among ``cand[ptr[k]:
    ptr[k + 1]]`` (all triangles when that range is empty), and its coordinates."""
    nq = queries.shape[0]
    out_t = np.zeros(nq, np.int64)
    out_b = np.full((nq, 3), -1.0)         # -1: no triangle in front of the query
    for k in range(nq):
        q = queries[k]
        lo, hi = ptr[k], ptr[k + 1]
        count = hi - lo if hi > lo else tri.shape[0]
        best = -np.inf
        for i in range(count):
            tt = cand[lo + i] if hi > lo else i
            l0, l1, l2, s = barycentric(q, pts[tri[tt, 0]], pts[tri[tt, 1]], pts[tri[tt, 2]])
            if s > 0:
                m = min(l0, min(l1, l2))
                if m > best:
                    best = m
                    out_t[k] = tt
                    out_b[k, 0] = l0
                    out_b[k, 1] = l1
                    out_b[k, 2] = l2
    return out_t, out_b


_SCAN_WORK = 5e7   # most query-triangle tests of the exhaustive fallback in one call


class _Sites:
    """What :func:`_settle` needs of a triangulation, built on first use (walks rarely fail):
    each site's triangles and a KD-tree of the sites."""

    def __init__(self, pts, tri):
        self.pts, self.tri = pts, tri

    @cached_property
    def incidence(self):
        """(triangles by corner, start of each site's run in it)."""
        order = np.argsort(self.tri.ravel(), kind="stable")
        return order // 3, np.searchsorted(self.tri.ravel()[order], np.arange(len(self.pts) + 1))

    @cached_property
    def tree(self):
        from scipy.spatial import cKDTree

        return cKDTree(self.pts)


def _settle(queries, sites, idx, bary, eps=1e-12):
    """Locate the queries a walk could not settle (``idx < 0``; only where the triangulation is
    not a proper one of the sphere, e.g. a folded map's hull): among the triangles around 8 near
    sites, then, where none holds the query and the work stays bounded, among all; a query no
    triangle faces takes the nearest site's value."""
    bad = np.flatnonzero(idx < 0)
    if not len(bad):
        return
    pts, tri = sites.pts, sites.tri
    inc, first = sites.incidence
    # approximate neighbours (within twice the nearest distance): an exact search from a query
    # far from every site (a map that left part of the sphere empty) visits all of them
    _, near = sites.tree.query(queries[bad], k=min(8, len(pts)), eps=1.0)
    near = near.reshape(len(bad), -1).ravel()
    lens = first[near + 1] - first[near]
    ptr = np.concatenate([[0], np.cumsum(lens.reshape(len(bad), -1).sum(axis=1))])
    offset = np.arange(lens.sum()) - np.repeat(np.cumsum(lens) - lens, lens)
    cand = inc[np.repeat(first[near], lens) + offset]
    t, b = _scan(queries[bad], pts, tri, ptr, cand)
    idx[bad], bary[bad] = t, b
    left = bad[b.min(axis=1) < -eps]
    if len(left) and len(left) * len(tri) <= _SCAN_WORK:
        t, b = _scan(queries[left], pts, tri, np.zeros(len(left) + 1, np.int64),
                     np.zeros(0, np.int64))
        better = b.min(axis=1) > bary[left].min(axis=1)
        idx[left[better]], bary[left[better]] = t[better], b[better]
    none = bad[bary[bad].min(axis=1) <= -1.0]     # no triangle faces it: take the nearest site
    if len(none):
        site = near.reshape(len(bad), -1)[np.searchsorted(bad, none), 0]
        idx[none] = inc[first[site]]
        bary[none] = (tri[idx[none]] == site[:, None]).astype(np.float64)


@numba.njit(cache=True)
def _grid_normals_radii(p, f, ptr, nb):
    """Area-weighted vertex normals (outward by the sign of the enclosed volume) and the longest
    incident edge / √3 of a closed grid surface."""
    n = p.shape[0]
    nrm = _grid_normals(p, f)
    rad = np.zeros(n)
    for v in range(n):
        m = 0.0
        for k in range(ptr[v], ptr[v + 1]):
            w = nb[k]
            d = ((p[w, 0] - p[v, 0]) ** 2 + (p[w, 1] - p[v, 1]) ** 2 + (p[w, 2] - p[v, 2]) ** 2)
            if d > m:
                m = d
        rad[v] = np.sqrt(m / 3.0)
    return nrm, rad


@numba.njit(cache=True)
def _grid_normals(p, f):
    """Area-weighted vertex normals of a closed grid surface, outward by the sign of the
    enclosed volume (not normalised)."""
    n = p.shape[0]
    nrm = np.zeros((n, 3))
    vol = 0.0
    for t in range(f.shape[0]):
        a, b, c = f[t, 0], f[t, 1], f[t, 2]
        ux, uy, uz = p[b, 0] - p[a, 0], p[b, 1] - p[a, 1], p[b, 2] - p[a, 2]
        vx, vy, vz = p[c, 0] - p[a, 0], p[c, 1] - p[a, 1], p[c, 2] - p[a, 2]
        nx, ny, nz = uy * vz - uz * vy, uz * vx - ux * vz, ux * vy - uy * vx
        vol += p[a, 0] * nx + p[a, 1] * ny + p[a, 2] * nz
        for v in (a, b, c):
            nrm[v, 0] += nx
            nrm[v, 1] += ny
            nrm[v, 2] += nz
    if vol < 0:
        nrm = -nrm
    return nrm


def neighbors(tri: np.ndarray) -> np.ndarray:
    """nbr[t, j]: the triangle across the edge opposite corner j of triangle t (-1: none)."""
    tri = np.ascontiguousarray(tri, np.int64)
    if len(tri) and tri.min() >= 0:
        nbr, unique = _twin_edges(tri, int(tri.max()) + 1)
        if unique:
            return nbr
    return neighbors_sorted(tri)


@numba.njit(cache=True)
def _twin_edges(tri, n):
    """:func:`neighbors` through the directed edges leaving each vertex; ``unique`` False when
    a directed edge occurs twice (then which twin the sort finds is the sort's choice, and
    :func:`neighbors_sorted` decides)."""
    m = tri.shape[0]
    ptr = np.zeros(n + 1, np.int64)
    for t in range(m):
        for j in range(3):
            ptr[tri[t, j] + 1] += 1
    for v in range(n):
        ptr[v + 1] += ptr[v]
    fill = ptr[:-1].copy()
    head = np.empty(3 * m, np.int64)     # the directed edge a -> head, of triangle owner
    owner = np.empty(3 * m, np.int64)
    for t in range(m):
        for j in range(3):
            a = tri[t, (j + 1) % 3]
            b = tri[t, (j + 2) % 3]
            for e in range(ptr[a], fill[a]):
                if head[e] == b:
                    return np.empty((0, 3), np.int64), False
            head[fill[a]] = b
            owner[fill[a]] = t
            fill[a] += 1
    nbr = np.full((m, 3), -1, np.int64)
    for t in range(m):
        for j in range(3):
            a = tri[t, (j + 1) % 3]
            b = tri[t, (j + 2) % 3]
            for e in range(ptr[b], fill[b]):
                if head[e] == a:
                    nbr[t, j] = owner[e]
                    break
    return nbr, True


def neighbors_sorted(tri: np.ndarray) -> np.ndarray:
    """:func:`neighbors` by sorting the directed edges (any triangle list)."""
    m = len(tri)
    n = int(tri.max()) + 1
    a = np.concatenate([tri[:, 1], tri[:, 2], tri[:, 0]])
    b = np.concatenate([tri[:, 2], tri[:, 0], tri[:, 1]])
    owner = np.tile(np.arange(m), 3)
    corner = np.repeat(np.arange(3), m)
    key = a * n + b
    twin = b * n + a
    order = np.argsort(key)
    pos = np.searchsorted(key[order], twin)
    pos = np.minimum(pos, len(key) - 1)
    ok = key[order][pos] == twin
    nbr = np.full((m, 3), -1, np.int64)
    nbr[owner[ok], corner[ok]] = owner[order][pos[ok]]
    return nbr


def locate(sphere_points, queries, *, triangles=None, start=None):
    """Exact point location in the spherical Delaunay triangulation.

    Parameters
    ----------
    sphere_points : (n, 3) float64
        Unit vectors (the sites).
    queries : (q, 3) float64
        Unit vectors to locate.
    triangles : (m, 3) int64, optional
        Counter-clockwise triangulation of the sites (default: their convex hull).
    start : (q,) int64, optional
        A triangle near each query to start the walk from (default: one incident to the nearest
        site, found with a KD-tree).

    Returns
    -------
    triangles : (m, 3) int64
        The triangulation used.
    index : (q,) int64
        Triangle of each query.
    bary : (q, 3) float64
        Barycentric coordinates (≥ −1e-12 up to round-off, summing to 1).
    """
    pts = as_array(sphere_points, "sphere_points", shape=(None, 3), min_len=4)
    qs = as_array(queries, "queries", shape=(None, 3))
    tri = hull_triangles(pts) if triangles is None else as_array(
        triangles, "triangles", dtype=np.int64, shape=(None, 3))
    nbr = neighbors(tri)
    if start is None:
        start = _nearest_starts(pts, tri, qs)
    else:
        start = np.clip(as_array(start, "start", dtype=np.int64, shape=(len(qs),)), 0, len(tri) - 1)
    idx, bary = _walk(qs, pts, tri, nbr, start, 1e-12)
    _settle(qs, _Sites(pts, tri), idx, bary)
    return tri, idx, bary


def _nearest_starts(pts, tri, qs):
    """A triangle incident to the site nearest each query."""
    from scipy.spatial import cKDTree

    inc = np.full(len(pts), -1, np.int64)
    inc[tri.ravel()] = np.repeat(np.arange(len(tri)), 3)
    _, near = cKDTree(pts).query(qs)
    start = inc[near]
    start[start < 0] = 0
    return start


def locate_grid(sphere_points, grid, *, triangles=None):
    """:func:`locate` for the vertices of an icosahedral grid, coarse to fine.

    Each vertex born on an edge at level j + 1 starts its walk from the triangle that holds the
    edge's first end, so the walks are a few steps long and no KD-tree over the queries is needed.

    Parameters
    ----------
    sphere_points : (n, 3) float64
    grid : Icosphere
    triangles : (m, 3) int64, optional

    Returns
    -------
    triangles, index, bary
        As :func:`locate`.
    """
    pts = as_array(sphere_points, "sphere_points", shape=(None, 3), min_len=4)
    tri = hull_triangles(pts) if triangles is None else as_array(
        triangles, "triangles", dtype=np.int64, shape=(None, 3))
    nbr = neighbors(tri)
    q = np.ascontiguousarray(grid.vertices, dtype=np.float64)
    counts = [vertex_count(j) for j in range(grid.level + 1)]
    idx = np.empty(len(q), np.int64)
    bary = np.empty((len(q), 3))
    c0 = counts[0]
    sites = _Sites(pts, tri)
    idx[:c0], bary[:c0] = _walk(q[:c0], pts, tri, nbr, _nearest_starts(pts, tri, q[:c0]), 1e-12)
    _settle(q[:c0], sites, idx[:c0], bary[:c0])
    for lo, hi in zip(counts[:-1], counts[1:]):
        start = idx[grid.edge_parents[lo:hi, 0]]      # settled: every parent has a triangle
        idx[lo:hi], bary[lo:hi] = _walk(q[lo:hi], pts, tri, nbr, start, 1e-12)
        _settle(q[lo:hi], sites, idx[lo:hi], bary[lo:hi])
    return tri, idx, bary





def map_triangles(surfels: SurfelSet, sphere_points) -> np.ndarray:
    """The spherical triangulation :func:`resample` interpolates in.

    Parameters
    ----------
    surfels : SurfelSet
    sphere_points : (n, 3) float64
        The surfels' positions on the unit sphere.

    Returns
    -------
    (m, 3) int64
        Counter-clockwise triangles seen from outside: the surfels' faces (without those that
        repeat a corner; wound the other way round when the map mirrors them) when their signed
        spherical areas sum to 4π and the clockwise ones cover at most the share
        ``TOL.inverted_area`` of the sphere (the map embeds the mesh); otherwise the convex hull
        of ``sphere_points`` (:func:`surfidx.geometry.unitsphere.hull_triangles`). The own faces
        resample better: grid points land on the input's triangles.
    """
    pts = map_points(surfels, sphere_points)
    f = surfels.faces
    if f is not None and len(f):
        f = f[(f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 0] != f[:, 2])]
        area = triangle_areas(pts, f)
        if area.sum() < 0:      # faces wound against the normals the map followed
            f, area = f[:, [0, 2, 1]], -area
        if len(f) and -area[area < 0].sum() <= TOL.inverted_area * 4 * np.pi and abs(
                area.sum() / (4 * np.pi) - 1.0) <= TOL.sphere_cover:
            return np.ascontiguousarray(f, dtype=np.int64)
    return hull_triangles(pts)


def locate_surfels(surfels: SurfelSet, sphere_points, level: int):
    """Where :func:`resample` finds each grid vertex: its triangle and barycentric coordinates.

    Parameters
    ----------
    surfels : SurfelSet
    sphere_points : (n, 3) float64
    level : int

    Returns
    -------
    triangles : (m, 3) int64
        :func:`map_triangles` of the surfels.
    index : (10·4^level + 2,) int64
        Triangle of each grid vertex.
    bary : (10·4^level + 2, 3) float64
    own : bool
        Whether ``triangles`` are the surfels' own faces (without those repeating a corner).
    """
    pts = map_points(surfels, sphere_points)
    tri = map_triangles(surfels, pts)
    own = surfels.faces is not None and tri is not None and _own_faces(surfels.faces, tri)
    tri, idx, bary = locate_grid(pts, icosphere(level), triangles=tri)
    return tri, idx, bary, own


def _own_faces(faces, tri) -> bool:
    f = faces[(faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2])
              & (faces[:, 0] != faces[:, 2])]
    return f.shape == tri.shape and bool(np.array_equal(f, tri)
                                         or np.array_equal(f[:, [0, 2, 1]], tri))


def grid_patches(surfels: SurfelSet, sphere_points, level: int, *, face_patch=None,
                 location=None) -> np.ndarray:
    """The virtual patch each grid vertex samples (-1: the scan's own surface).

    A grid vertex lies in the triangle :func:`resample` interpolates it in
    (:func:`locate_surfels`); it is virtual when that triangle is: a face of the surfels'
    own triangulation carries ``face_patch`` (default: the largest patch of its corners, so a
    face with a virtual corner is virtual), a triangle of the hull the largest patch of its
    corners.

    Parameters
    ----------
    surfels : SurfelSet
        With :attr:`~surfidx.SurfelSet.patch` (None: nothing is virtual).
    sphere_points : (n, 3) float64
    level : int
    face_patch : (m,) int, optional
        Patch of each of ``surfels.faces`` (-1 real): marks virtual faces whose three corners
        are all scan vertices (a small hole's patch, an ear of a patch along its rim), which the
        corner labels cannot tell from the scan's faces.
    location : tuple, optional
        :func:`locate_surfels`'s result, when computed already.

    Returns
    -------
    (10·4^level + 2,) int32

    Raises
    ------
    InputError
        When ``face_patch`` does not have one entry per face or names no patch of the surfels.
    """
    n_grid = vertex_count(level)
    if surfels.patch is None:
        return np.full(n_grid, -1, np.int32)
    tri, idx, _, own = locate_surfels(surfels, sphere_points, level) if location is None \
        else location
    corner = surfels.patch[tri].max(axis=1).astype(np.int64)
    if face_patch is not None:
        fp = as_array(face_patch, "face_patch", dtype=np.int64,
                      shape=(0 if surfels.faces is None else len(surfels.faces),))
        count = len(surfels.patch_cut)
        if fp.size and (fp.min() < -1 or fp.max() >= count):
            raise InputError(f"face_patch must hold -1 or a patch index below {count}, got "
                             f"{int(fp.min())}..{int(fp.max())}")
        if own:
            f = surfels.faces
            keep = (f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 0] != f[:, 2])
            corner = np.maximum(corner, fp[keep])
    return corner[idx].astype(np.int32)


def resample(surfels: SurfelSet, sphere_points, level: int, *, color: bool | None = None,
             phong: float = PHONG_ALPHA, sharpness: float = PHONG_SHARPNESS,
             location=None) -> np.ndarray:
    """The surfel layers at the vertices of the level-``level`` icosahedral grid.

    Parameters
    ----------
    surfels : SurfelSet
    sphere_points : (n, 3) float64
        The surfels' positions on the unit sphere (:func:`surfidx.sphere.parameterize`).
    level : int
        Grid level, 0 … :data:`surfidx.geometry.icosphere.MAX_LEVEL`.
    color : bool, optional
        Resample the colours too (default: when the surfels have them).
    phong : float
        Phong-tessellation blend in [0, 1] (module notes); 0 interpolates positions linearly.
    sharpness : float
        Exponent ``s >= 1`` of the lift's corner weights (module notes); 1 is plain Phong.
    location : tuple, optional
        :func:`locate_surfels` of these surfels and level, when computed already.

    Returns
    -------
    (10·4^level + 2, 3 or 6) float64
        Columns :func:`layer_names`: x, y, z and, with colour, r, g, b in 0..255.

    Raises
    ------
    InputError
        Bad sphere points, colour asked of colourless surfels, ``phong`` outside [0, 1],
        ``sharpness`` below 1.
    """
    pts = map_points(surfels, sphere_points)
    color = surfels.has_color if color is None else bool(color)
    if color and not surfels.has_color:
        raise InputError("color=True, but the surfels have no colours")
    alpha = float(phong)
    if not 0.0 <= alpha <= 1.0:
        raise InputError(f"phong must lie in [0, 1], got {phong!r}")
    sharp = float(sharpness)
    if not sharp >= 1.0 or not np.isfinite(sharp):
        raise InputError(f"sharpness must be a finite number >= 1 (1: plain Phong), "
                         f"got {sharpness!r}")
    if location is None:
        tri, idx, bary = locate_grid(pts, icosphere(level), triangles=map_triangles(surfels, pts))
    else:
        tri, idx, bary = location[:3]
    corners = np.ascontiguousarray(np.take(tri, idx, axis=0))
    w = np.maximum(bary, 0.0) ** sharp                           # corner weights (s = 1: Phong)
    w /= w.sum(axis=1)[:, None]
    geo = _lift(np.ascontiguousarray(bary, np.float64), w, corners,
                np.ascontiguousarray(surfels.positions, np.float64),
                np.ascontiguousarray(surfels.normals, np.float64), alpha)
    if not color:
        return geo
    return np.hstack([geo, np.einsum("qk,qkl->ql", bary,
                                     _gather(surfels.colors, corners).astype(np.float64))])


@numba.njit(cache=True)
def _lift(bary, w, corners, pos, nrm, alpha):
    """The Phong-lifted positions of :func:`resample`, point by point: ``p = Σ b_k v_k``,
    ``off_k = (p - v_k) · n_k``, ``p - α Σ (w_k off_k) n_k``, with the floating-point operations
    of the ``numpy.einsum`` calls they replace, in their order (the sums over corners from 0 in
    corner order, the dot product as einsum pairs its terms), without their ``(q, 3, 3)``
    temporaries."""
    q = corners.shape[0]
    out = np.empty((q, 3), dtype=np.float64)
    p = np.empty(3)
    off = np.empty(3)
    for i in range(q):
        for l in range(3):
            acc = 0.0
            for k in range(3):
                acc = bary[i, k] * pos[corners[i, k], l] + acc
            p[l] = acc
        for k in range(3):
            c = corners[i, k]
            # einsum's contiguous 3-term dot product: lanes (x, y) plus the z term on lane x
            off[k] = (((p[0] - pos[c, 0]) * nrm[c, 0] + (p[2] - pos[c, 2]) * nrm[c, 2])
                      + (p[1] - pos[c, 1]) * nrm[c, 1])
        for l in range(3):
            acc = 0.0
            for k in range(3):
                acc = w[i, k] * off[k] * nrm[corners[i, k], l] + acc
            out[i, l] = p[l] - alpha * acc
    return out


def _gather(rows, corners):
    """``rows[corners]`` for ``rows : (n, d)`` and ``corners : (q, 3)``: ``(q, 3, d)``, the
    same values (numpy's two-dimensional fancy index is several times slower)."""
    return _gather_rows(np.ascontiguousarray(rows), np.ascontiguousarray(corners, np.int64))


@numba.njit(cache=True)
def _gather_rows(rows, corners):
    q, c = corners.shape
    d = rows.shape[1]
    out = np.empty((q, c, d), dtype=rows.dtype)
    for i in range(q):
        for j in range(c):
            r = corners[i, j]
            for k in range(d):
                out[i, j, k] = rows[r, k]
    return out


def _grid_level(values) -> tuple[np.ndarray, int]:
    vals = as_array(values, "values", shape=(None, None))
    if vals.shape[1] not in (3, 6):
        raise InputError(f"values must have 3 (x, y, z) or 6 (x, y, z, r, g, b) columns, got "
                         f"{vals.shape[1]}")
    level = level_of_count(len(vals))
    if level is None:
        raise InputError(f"values must have 10·4^L + 2 rows (one per grid vertex), got "
                         f"{len(vals)}")
    return vals, level


def _colors(vals):
    if vals.shape[1] == 6:
        return np.clip(np.round(vals[:, 3:6]), 0, 255).astype(np.uint8)
    return None


def grid_to_mesh(values, *, name=None) -> TriangleMesh:
    """Triangle mesh of grid values on the grid's faces.

    Parameters
    ----------
    values : (10·4^L + 2, 3 or 6) float64
        Output of :func:`resample`.
    name : str, optional

    Returns
    -------
    TriangleMesh
    """
    vals, level = _grid_level(values)
    grid = icosphere(level)
    return TriangleMesh(vals[:, :3], np.array(grid.faces), vertex_colors=_colors(vals), name=name)


def _unit_normals(p, nrm):
    """The area-weighted normals ``nrm`` of grid positions ``p`` normalised, a collapsed spot's
    (zero normal) the direction from the centroid (in place)."""
    ln = np.sqrt(np.einsum("ij,ij->i", nrm, nrm))
    bad = ln <= 0
    if bad.any():  # collapsed spots: fall back to the direction from the centroid
        d = p[bad] - p.mean(axis=0)
        dl = np.linalg.norm(d, axis=1)
        d[dl <= 0] = (0.0, 0.0, 1.0)
        nrm[bad] = d
        ln = np.linalg.norm(nrm, axis=1)
    nrm /= ln[:, None]
    return nrm


def _grid_points(values):
    """The positions and unit normals :func:`grid_to_surfels` gives grid values (no radii, no
    colours, unchecked: values of the codec's decoder)."""
    vals, level = _grid_level(values)
    p = np.ascontiguousarray(vals[:, :3])
    return p, _unit_normals(p, _grid_normals(p, np.asarray(icosphere(level).faces)))


def grid_to_surfels(values, *, name=None) -> SurfelSet:
    """Surfels reconstructed from grid values.

    Positions are the x, y, z layers; normals the area-weighted normals of the grid surface
    (oriented outward by the sign of the enclosed volume); radii the longest incident grid edge
    divided by √3 (the circumradius of an equilateral triangle of that edge), so the disks cover
    the grid surface; colours the rounded r, g, b layers.

    Parameters
    ----------
    values : (10·4^L + 2, 3 or 6) float64
    name : str, optional

    Returns
    -------
    SurfelSet
    """
    vals, level = _grid_level(values)
    grid = icosphere(level)
    p = np.ascontiguousarray(vals[:, :3])
    f = np.asarray(grid.faces)
    nrm, rad = _grid_normals_radii(p, f, grid.neighbor_indptr, grid.neighbor_indices)
    nrm = _unit_normals(p, nrm)
    floor = max(rad.max(), 1e-300) * 1e-6
    rad = np.maximum(rad, floor)
    return SurfelSet(p, nrm, rad, _colors(vals), faces=f, name=name)
