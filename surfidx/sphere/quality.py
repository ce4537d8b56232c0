"""Quality figures of a spherical map: folds, area distortion, sparse sampling, stress."""

from __future__ import annotations

import numpy as np

from ..errors import InputError
from ..validate import as_array
from ..geometry.mesh import vertex_area_shares
from ..geometry.unitsphere import folded_mask, hull_triangles, map_points, triangle_areas
from ..geometry.surfels import SurfelSet
from .surface import areas3

__all__ = ["count_folds", "area_distortion", "sparse_sampling", "landmark_stress",
           "SPARSE_QUANTILE"]

SPARSE_QUANTILE = 0.05
"""The "sparsest-mapped surfels" of :func:`sparse_sampling`: this share of them."""

_TINY = 1e-300          # divisions by a share, a scale or a squared sum stay finite
_RATIO_CLIP = (1e-30, 1e30)   # area ratios are clipped to this range before the log


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
        The hull of ``sphere_points`` when already computed
        (:func:`surfidx.geometry.unitsphere.hull_triangles`), or other triangles to measure on.

    Returns
    -------
    folded : int
    total : int
    """
    _, tri = _points_and_triangles(surfels, sphere_points, triangles)
    return _count_folds(surfels, tri)


def _count_folds(surfels: SurfelSet, tri: np.ndarray) -> tuple[int, int]:
    """:func:`count_folds` on checked triangles."""
    return int(np.count_nonzero(folded_mask(surfels.positions, surfels.normals, tri))), len(tri)


def _points_and_triangles(surfels, sphere_points, triangles):
    """Checked sphere points and the triangles to measure on (default: their hull)."""
    pts = map_points(surfels, sphere_points)
    tri = hull_triangles(pts) if triangles is None else as_array(
        triangles, "triangles", dtype=np.int64, shape=(None, 3))
    return pts, tri


def area_distortion(surfels: SurfelSet, sphere_points, *, triangles=None) -> float:
    """Area-weighted RMS of ``log(spherical area share / 3D area share)``.

    Parameters
    ----------
    surfels, sphere_points, triangles
        As in :func:`count_folds` (triangles: those to measure on).

    Returns
    -------
    float
        0 for an area-preserving map; ``log(10)`` ≈ 2.3 means tenfold typical area errors.
    """
    pts, tri = _points_and_triangles(surfels, sphere_points, triangles)
    return _area_distortion(surfels.positions, pts, tri)


def _area_distortion(positions: np.ndarray, pts: np.ndarray, tri: np.ndarray) -> float:
    """:func:`area_distortion` of checked sphere points and triangles."""
    a3 = areas3(positions, tri)
    asph = np.abs(triangle_areas(pts, tri))
    w = a3 / a3.sum()
    ratio = (asph / asph.sum()) / np.maximum(w, _TINY)
    lr = np.log(np.clip(ratio, *_RATIO_CLIP))
    return float(np.sqrt(np.average(lr ** 2, weights=w)))


def sparse_sampling(surfels: SurfelSet, sphere_points, *, triangles=None,
                    quantile: float = SPARSE_QUANTILE) -> float:
    """How well an even grid on the sphere samples the surfels the map squeezes most.

    Each surfel owns a third of its triangles' spherical area ``a_i``; an even grid of ``N``
    points puts about ``N a_i / 4π`` of them near it. The figure is the ``quantile`` of
    ``n a_i / 4π`` over the ``n`` surfels: a grid of ``N`` points gives the sparsest-mapped
    ``quantile`` share of the surfels fewer than ``N / n`` times this many grid points each.
    1 for a map that spreads the surfels evenly; the grid level depends on it
    (:func:`surfidx.geometry.icosphere.choose_level`).

    Parameters
    ----------
    surfels, sphere_points, triangles
        As in :func:`count_folds` (triangles: those to measure on).
    quantile : float
        In (0, 1).

    Returns
    -------
    float
    """
    if not 0.0 < float(quantile) < 1.0:
        raise InputError(f"quantile must lie in (0, 1), got {quantile!r}")
    pts, tri = _points_and_triangles(surfels, sphere_points, triangles)
    return _sparse_sampling(pts, tri, float(quantile))


def _sparse_sampling(pts: np.ndarray, tri: np.ndarray, quantile: float = SPARSE_QUANTILE) -> float:
    """:func:`sparse_sampling` of checked sphere points and triangles."""
    a = np.abs(triangle_areas(pts, tri))
    share = vertex_area_shares(tri, a, len(pts))
    return float(np.quantile(len(pts) * share / (4.0 * np.pi), float(quantile)))


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
    r = (th[ok] * d[ok]).sum() / max((th[ok] ** 2).sum(), _TINY)
    return float(np.sqrt(((r * th[ok] - d[ok]) ** 2).sum() / max((d[ok] ** 2).sum(), _TINY)))
