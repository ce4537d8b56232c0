"""The exact closest point of a triangle mesh to each of many points.

Candidates are the triangles with the nearest centroids (a KD-tree); a compiled point-triangle
projection (Ericson, *Real-Time Collision Detection*, 5.1.5) picks the closest, and a distance
bound certifies it or widens the search. Used to carry values from a mesh to points
(:func:`surfidx.sphere.proxy.transfer`) and to compare colours at the same surface points
(:func:`surfidx.geometry.metrics.psnr_luma_surface`).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from ..errors import InputError
from ..jit import njit
from ..validate import as_array, check_positive_int

__all__ = ["closest_points", "closest_on_triangle", "project_to_candidates"]


@njit(cache=True, _nrt=False)
def _closest_on_segment(p, a, b):  # pragma: no cover - compiled
    """Parameter t in [0, 1] of the point of segment ab closest to p, and its squared
    distance (t = 0 where a and b coincide)."""
    ex, ey, ez = b[0] - a[0], b[1] - a[1], b[2] - a[2]
    den = ex * ex + ey * ey + ez * ez
    t = 0.0
    if den > 0.0:
        t = ((p[0] - a[0]) * ex + (p[1] - a[1]) * ey + (p[2] - a[2]) * ez) / den
        t = min(max(t, 0.0), 1.0)
    dx, dy, dz = a[0] + t * ex - p[0], a[1] + t * ey - p[1], a[2] + t * ez - p[2]
    return t, dx * dx + dy * dy + dz * dz


@njit(cache=True, _nrt=False)
def _closest_on_edges(p, a, b, c):  # pragma: no cover - compiled
    """Barycentric coordinates of the point of a flat (zero-area) triangle abc closest to p:
    the best of its three edges."""
    t1, e1 = _closest_on_segment(p, a, b)
    t2, e2 = _closest_on_segment(p, a, c)
    t3, e3 = _closest_on_segment(p, b, c)
    if e1 <= e2 and e1 <= e3:
        return 1.0 - t1, t1, 0.0
    if e2 <= e3:
        return 1.0 - t2, 0.0, t2
    return 0.0, 1.0 - t3, t3


@njit(cache=True, _nrt=False)
def closest_on_triangle(p, a, b, c):  # pragma: no cover - compiled
    """Barycentric coordinates (u, v, w) of the point of triangle abc closest to p (Ericson,
    Real-Time Collision Detection, 5.1.5). A flat triangle (coincident or collinear corners, as
    a coarsely quantised mesh has) is searched along its three edges instead."""
    abx, aby, abz = b[0] - a[0], b[1] - a[1], b[2] - a[2]
    acx, acy, acz = c[0] - a[0], c[1] - a[1], c[2] - a[2]
    apx, apy, apz = p[0] - a[0], p[1] - a[1], p[2] - a[2]
    nx, ny, nz = aby * acz - abz * acy, abz * acx - abx * acz, abx * acy - aby * acx
    ab2 = abx * abx + aby * aby + abz * abz
    ac2 = acx * acx + acy * acy + acz * acz
    if nx * nx + ny * ny + nz * nz <= 1e-20 * ab2 * ac2:
        return _closest_on_edges(p, a, b, c)
    d1 = abx * apx + aby * apy + abz * apz
    d2 = acx * apx + acy * apy + acz * apz
    if d1 <= 0.0 and d2 <= 0.0:
        return 1.0, 0.0, 0.0
    bpx, bpy, bpz = p[0] - b[0], p[1] - b[1], p[2] - b[2]
    d3 = abx * bpx + aby * bpy + abz * bpz
    d4 = acx * bpx + acy * bpy + acz * bpz
    if d3 >= 0.0 and d4 <= d3:
        return 0.0, 1.0, 0.0
    vc = d1 * d4 - d3 * d2
    if vc <= 0.0 and d1 >= 0.0 and d3 <= 0.0:
        den = d1 - d3   # >= 0; zero only where a and b coincide
        t = d1 / den if den > 0.0 else 0.0
        return 1.0 - t, t, 0.0
    cpx, cpy, cpz = p[0] - c[0], p[1] - c[1], p[2] - c[2]
    d5 = abx * cpx + aby * cpy + abz * cpz
    d6 = acx * cpx + acy * cpy + acz * cpz
    if d6 >= 0.0 and d5 <= d6:
        return 0.0, 0.0, 1.0
    vb = d5 * d2 - d1 * d6
    if vb <= 0.0 and d2 >= 0.0 and d6 <= 0.0:
        den = d2 - d6   # >= 0; zero only where a and c coincide
        t = d2 / den if den > 0.0 else 0.0
        return 1.0 - t, 0.0, t
    va = d3 * d6 - d5 * d4
    if va <= 0.0 and (d4 - d3) >= 0.0 and (d5 - d6) >= 0.0:
        den = (d4 - d3) + (d5 - d6)   # >= 0; zero only where b and c coincide
        t = (d4 - d3) / den if den > 0.0 else 0.0
        return 0.0, 1.0 - t, t
    den = va + vb + vc
    if den <= 0.0:  # degenerate triangle: fall back to the nearest corner
        da = apx * apx + apy * apy + apz * apz
        db = bpx * bpx + bpy * bpy + bpz * bpz
        dc = cpx * cpx + cpy * cpy + cpz * cpz
        if da <= db and da <= dc:
            return 1.0, 0.0, 0.0
        if db <= dc:
            return 0.0, 1.0, 0.0
        return 0.0, 0.0, 1.0
    v = vb / den
    w = vc / den
    return 1.0 - v - w, v, w


@njit(cache=True)
def project_to_candidates(points, cand, vertices, faces):  # pragma: no cover - compiled
    """For each point, the closest of its candidate triangles (``cand`` rows, -1 padded):
    face index, barycentric coordinates, squared distance."""
    n, k = cand.shape
    best_f = np.full(n, -1, np.int64)
    best_b = np.zeros((n, 3))
    best_d = np.full(n, np.inf)
    # the point and corners copied into arrays made once (a row view per candidate would
    # cost a reference count each)
    p = np.empty(3)
    a = np.empty(3)
    b = np.empty(3)
    c = np.empty(3)
    for i in range(n):
        for x in range(3):
            p[x] = points[i, x]
        for j in range(k):
            t = cand[i, j]
            if t < 0:
                break
            for x in range(3):
                a[x] = vertices[faces[t, 0], x]
                b[x] = vertices[faces[t, 1], x]
                c[x] = vertices[faces[t, 2], x]
            u, v, w = closest_on_triangle(p, a, b, c)
            dx = u * a[0] + v * b[0] + w * c[0] - p[0]
            dy = u * a[1] + v * b[1] + w * c[1] - p[1]
            dz = u * a[2] + v * b[2] + w * c[2] - p[2]
            d = dx * dx + dy * dy + dz * dz
            if d < best_d[i]:
                best_d[i] = d
                best_f[i] = t
                best_b[i, 0] = u
                best_b[i, 1] = v
                best_b[i, 2] = w
    return best_f, best_b, best_d


def closest_points(points, vertices, faces, *, candidates: int = 16):
    """The exact closest point of a triangle mesh to each point.

    Candidates are the triangles with the ``candidates`` nearest centroids; a point whose best
    distance is not certified by them (a triangle further away could be closer: its centroid
    distance minus the largest centroid-to-corner distance is below the best) is searched again
    among all triangles within that bound.

    Parameters
    ----------
    points : (n, 3) float64
    vertices : (m, 3) float64
    faces : (k, 3) int64
    candidates : int
        Nearest-centroid triangles tried first.

    Returns
    -------
    face : (n,) int64
        The triangle holding the closest point.
    bary : (n, 3) float64
        Its barycentric coordinates in that triangle (non-negative, summing to 1).
    distance : (n,) float64

    Raises
    ------
    InputError
        Bad shapes, non-finite values, face indices out of range, no faces.
    """
    points = as_array(points, "points", shape=(None, 3))
    vertices = as_array(vertices, "vertices", shape=(None, 3))
    faces = as_array(faces, "faces", dtype=np.int64, shape=(None, 3))
    if not len(faces):
        raise InputError("faces is empty; closest points need a mesh with at least one triangle")
    if faces.min() < 0 or faces.max() >= len(vertices):
        raise InputError(f"faces index vertices outside 0..{len(vertices) - 1}")
    check_positive_int(candidates, "candidates")
    tri = vertices[faces]
    cen = tri.mean(axis=1)
    radius = np.linalg.norm(tri - cen[:, None, :], axis=2).max(axis=1)
    # triangles far larger than nearly all others are tried for every point (few, in chunks),
    # so that one long sliver does not widen every point's search to the whole mesh
    big = np.flatnonzero(radius > _BIG_RADIUS * float(np.quantile(radius, 0.99)))
    small = np.setdiff1d(np.arange(len(faces)), big)
    found = _closest_small(points, vertices, faces, small, cen[small],
                           float(radius[small].max()), candidates)
    if len(big):
        rows = max(1, _CHUNK // len(big))
        for s in range(0, len(points), rows):
            r = np.arange(s, min(s + rows, len(points)))
            _improve(points, r, np.broadcast_to(big, (len(r), len(big))), vertices, faces, found)
    return found


_BIG_RADIUS = 4.0
"""A triangle whose centroid-to-corner radius exceeds this multiple of the 99th percentile is
tried for every point instead of through the centroid tree."""

_CHUNK = 1 << 22
"""Point-candidate pairs projected at once where the search widens (bounds the memory)."""


def _closest_small(points, vertices, faces, small, cen, reach, candidates):
    """Closest of the triangles ``small`` (centroids ``cen``, radii at most ``reach``): the
    nearest-centroid candidates first; a point whose answer the distance bound does not certify
    tries twice as many, in chunks of at most ``_CHUNK`` pairs, until it does."""
    tree = cKDTree(cen)
    k = min(candidates, len(small))
    dk, cand = tree.query(points, k=k, workers=-1)
    if k == 1:
        dk, cand = dk[:, None], cand[:, None]
    face, bary, d2 = project_to_candidates(points, small[cand], vertices, faces)
    dist = np.sqrt(d2)
    # an untried triangle is at least (its centroid distance - reach) >= dk[:, -1] - reach away
    redo = np.flatnonzero(dist > dk[:, -1] - reach)
    while len(redo) and k < len(small):
        k = min(2 * k, len(small))
        last = np.empty(len(redo))
        rows = max(1, _CHUNK // k)
        for s in range(0, len(redo), rows):
            r = redo[s:s + rows]
            dr, cr = tree.query(points[r], k=k, workers=-1)
            _improve(points, r, small[cr], vertices, faces, (face, bary, dist))
            last[s:s + len(r)] = dr[:, -1]
        redo = redo[dist[redo] > last - reach]
    return face, bary, dist


def _improve(points, rows, cand, vertices, faces, found):
    """Try the candidate triangles ``cand`` (one row per index of ``rows``) for those points and
    keep, in ``found = (face, bary, dist)``, each one closer than the answer held."""
    face, bary, dist = found
    f2, b2, d22 = project_to_candidates(points[rows], np.ascontiguousarray(cand), vertices, faces)
    d = np.sqrt(d22)
    better = d < dist[rows]
    sel = rows[better]
    face[sel], bary[sel], dist[sel] = f2[better], b2[better], d[better]
