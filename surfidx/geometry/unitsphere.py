"""Geometry on the unit sphere: Delaunay triangulation, orientation, folds, areas, Möbius maps.

The spherical map (:mod:`surfidx.sphere`), the resampling (:mod:`surfidx.codec.resample`) and the
icosahedral grid (:mod:`surfidx.geometry.icosphere`) share these. Points are unit vectors ``(n, 3)``;
triangles are index rows ``(m, 3)``, counter-clockwise seen from outside the sphere.

A triangle of mapped surfels is *folded* when its orientation in 3D (its normal against the sum
of its three surfel normals) disagrees with its orientation on the sphere; when most triangles
disagree the map is a mirror, not folded, and the minority counts.
"""

from __future__ import annotations

import hashlib
import threading

import numpy as np

from ..errors import InputError
from ..tolerance import TOL
from ..validate import as_array
from .surfels import SurfelSet

__all__ = ["hull_triangles", "unit_vectors", "map_points", "orientation", "corner_orientation",
           "against_normals", "mirrored", "folded_mask", "triangle_areas", "mobius",
           "smallest_first"]

# Rows per block of triangle_areas: its temporaries then stay in cache and are reused, where
# whole-array temporaries of a fine grid (5M triangles at level 9) cost more in fresh pages than
# in arithmetic. Each row's result does not depend on the blocking.
_BLOCK = 1 << 16


def unit_vectors(points, *, count: int | None = None, name: str = "sphere_points") -> np.ndarray:
    """Points checked to lie on the unit sphere, renormalised.

    Parameters
    ----------
    points : (n, 3) float64
        Unit vectors (up to ``TOL.unit_normal``), n ≥ 4.
    count : int, optional
        The number of points required.
    name : str
        The argument's name in messages.

    Returns
    -------
    (n, 3) float64

    Raises
    ------
    InputError
        Wrong shape, too few points, or points off the unit sphere.
    """
    pts = as_array(points, name, shape=(count, 3), min_len=4)
    nrm = np.linalg.norm(pts, axis=1)
    if np.any(np.abs(nrm - 1.0) > TOL.unit_normal):
        raise InputError(f"{name} must be unit vectors (points on the unit sphere)")
    return pts / nrm[:, None]


def map_points(surfels: SurfelSet, sphere_points) -> np.ndarray:
    """The checked sphere positions of ``surfels``: :func:`unit_vectors` with one row per surfel.

    Raises :class:`InputError` as :func:`unit_vectors` does, and when ``surfels`` is no
    :class:`~surfidx.SurfelSet`.
    """
    if not isinstance(surfels, SurfelSet):
        raise InputError(f"surfels must be a SurfelSet, got {type(surfels).__name__}")
    return unit_vectors(sphere_points, count=len(surfels))


def hull_triangles(sphere_points) -> np.ndarray:
    """Spherical Delaunay triangulation of points on the unit sphere (their convex hull).

    The map's stages ask for the hull of one map several times, so the last two hulls of at
    least 2,000 points are remembered by the digest of the points' bytes (a copy is returned).

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

    pts = np.ascontiguousarray(as_array(sphere_points, "sphere_points", shape=(None, 3),
                                        min_len=4))
    key = None
    if len(pts) >= _HULL_MEMO_MIN:   # the map's stages ask again for the hull of the same map
        key = hashlib.blake2b(pts.tobytes(), digest_size=16).digest()
        with _hull_lock:
            known = _hull_memo.get(key)
        if known is not None:
            return known.copy()
    try:
        hull = ConvexHull(pts)
    except QhullError as exc:
        raise InputError(f"the sphere points span no volume ({str(exc).splitlines()[0]})") from exc
    tri = np.ascontiguousarray(hull.simplices, dtype=np.int64)
    a, b, c = pts[tri[:, 0]], pts[tri[:, 1]], pts[tri[:, 2]]
    flip = np.einsum("ij,ij->i", np.cross(b - a, c - a), a + b + c) < 0
    tri[flip] = tri[flip][:, [0, 2, 1]]
    if key is not None:
        with _hull_lock:
            while len(_hull_memo) >= _HULL_MEMO_SIZE:
                del _hull_memo[next(iter(_hull_memo))]
            _hull_memo[key] = tri.copy()
    return tri


_HULL_MEMO_MIN = 2000   # points from which a hull is remembered (a smaller one is cheap to redo)
_HULL_MEMO_SIZE = 2     # hulls remembered, by the digest of the points' bytes (a copy returned)
_hull_memo: dict = {}
_hull_lock = threading.Lock()


def orientation(x, f) -> np.ndarray:
    """Orientation of each triangle on the sphere, ``(b - a) × (c - a) · (a + b + c)``.

    Parameters
    ----------
    x : (n, 3) float64
        Points on the sphere.
    f : (m, 3) int64
        Triangles.

    Returns
    -------
    (m,) float64
        Positive for a counter-clockwise triangle seen from outside.
    """
    return corner_orientation(x[f])


def corner_orientation(corners) -> np.ndarray:
    """:func:`orientation` of triangles given by their corners.

    Parameters
    ----------
    corners : (m, 3, 3) float64

    Returns
    -------
    (m,) float64
    """
    a, b, c = corners[:, 0], corners[:, 1], corners[:, 2]
    return np.einsum("ij,ij->i", np.cross(b - a, c - a), a + b + c)


def against_normals(positions, normals, triangles) -> np.ndarray:
    """Triangles whose 3D normal points against the sum of their corners' normals.

    Each triangle is taken from its smallest vertex index on (the same cyclic order), so a
    triangle that is straight in 3D gets the same answer whichever corner it is listed from.

    Parameters
    ----------
    positions, normals : (n, 3) float64
    triangles : (m, 3) int64

    Returns
    -------
    (m,) bool
    """
    p, t = positions, smallest_first(triangles)
    n3 = np.cross(p[t[:, 1]] - p[t[:, 0]], p[t[:, 2]] - p[t[:, 0]])
    return np.einsum("ij,ij->i", n3, normals[t].sum(axis=1)) < 0


def smallest_first(triangles) -> np.ndarray:
    """Each triangle rotated to start at its smallest vertex index (its orientation kept): one
    listing of a triangle, whichever corner it was given from.

    Parameters
    ----------
    triangles : (m, 3) int

    Returns
    -------
    (m, 3) int, the same dtype
    """
    t = np.asarray(triangles)
    if not len(t):
        return t
    return np.take_along_axis(t, (t.argmin(axis=1)[:, None] + np.arange(3)) % 3, axis=1)


def mirrored(bad) -> bool:
    """Whether most triangles of the mask ``bad`` (:func:`against_normals`) disagree with the
    normals: a global mirror, not folds."""
    return bool(np.count_nonzero(bad) > len(bad) - np.count_nonzero(bad))


def folded_mask(positions, normals, triangles) -> np.ndarray:
    """Folded triangles: those against their normals, or for a mirror those that are not.

    Parameters
    ----------
    positions, normals : (n, 3) float64
    triangles : (m, 3) int64
        Counter-clockwise seen from outside the sphere.

    Returns
    -------
    (m,) bool
    """
    bad = against_normals(positions, normals, triangles)
    return bad ^ mirrored(bad)


def triangle_areas(sphere_points, triangles) -> np.ndarray:
    """Signed areas (spherical excess, Van Oosterom & Strackee 1983) of spherical triangles.

    Parameters
    ----------
    sphere_points : (n, 3) float64
    triangles : (m, 3) int64

    Returns
    -------
    (m,) float64
        Positive for counter-clockwise triangles; summing to 4π over a triangulation of the
        sphere.
    """
    pts, tri = sphere_points, triangles
    out = np.empty(len(tri))
    for s in range(0, len(tri), _BLOCK):    # blocks: the temporaries stay in cache
        t = tri[s:s + _BLOCK]
        a, b, c = pts[t[:, 0]], pts[t[:, 1]], pts[t[:, 2]]
        num = np.einsum("ij,ij->i", a, np.cross(b, c))
        den = 1.0 + np.einsum("ij,ij->i", a, b) + np.einsum("ij,ij->i", b, c) \
            + np.einsum("ij,ij->i", c, a)
        out[s:s + _BLOCK] = 2.0 * np.arctan2(num, den)
    return out


def mobius(x, a) -> np.ndarray:
    """The Möbius automorphism of the unit ball sending ``a`` to the origin, applied to ``x``.

    Orientation preserving, it maps the sphere onto itself (Ahlfors).

    Parameters
    ----------
    x : (n, 3) float64
        Unit vectors.
    a : (3,) float64
        A point inside the ball, ``|a| < 1``.

    Returns
    -------
    (n, 3) float64
    """
    aa = a @ a
    d = x - a
    y = (1.0 - aa) * d - (d ** 2).sum(axis=1)[:, None] * a
    y /= (1.0 - 2.0 * (x @ a) + aa)[:, None]
    return y / np.linalg.norm(y, axis=1)[:, None]
