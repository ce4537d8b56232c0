"""Plain point clouds to surfels: PCA normals, consistent outward orientation, spacing radii."""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from ..jit import njit
from scipy.sparse.csgraph import breadth_first_order, connected_components, minimum_spanning_tree
from scipy.spatial import cKDTree

from ..errors import InputError
from ..validate import as_array
from .mesh import spacing_radii
from .surfels import SurfelSet

__all__ = ["estimate_normals", "orient_normals", "points_to_surfels"]

#: Relative rounding of stored coordinates (16 float32 epsilons): a spread below this times the
#: largest coordinate is rounding noise, not a surface.
_ROUNDING = 16 * float(np.finfo(np.float32).eps)


def estimate_normals(points, *, k: int = 16) -> np.ndarray:
    """Unoriented normals by principal component analysis of the ``k`` nearest neighbours.

    Parameters
    ----------
    points : (n, 3) float64
    k : int
        Neighbourhood size (clipped to n).

    Returns
    -------
    (n, 3) float64
        Unit normals (the direction of least variance), sign arbitrary.
    """
    points = as_array(points, "points", shape=(None, 3), min_len=4)
    kk = min(k, len(points))
    _, idx = cKDTree(points).query(points, k=kk)
    nb = points[idx] - points[idx].mean(axis=1, keepdims=True)
    cov = np.einsum("nki,nkj->nij", nb, nb)
    _, vecs = np.linalg.eigh(cov)
    return np.ascontiguousarray(vecs[:, :, 0])


@njit(cache=True)
def _propagate_signs(order, pred, flip):  # pragma: no cover - compiled
    """Walk the tree in breadth-first ``order``: sign[v] = sign[parent] * flip[v] (node ids)."""
    sign = np.ones(flip.shape[0], np.float64)
    for i in range(order.shape[0]):
        v = order[i]
        p = pred[v]
        if p >= 0:
            sign[v] = sign[p] * flip[v]
    return sign


def orient_normals(points, normals, *, k: int = 12) -> np.ndarray:
    """Orient normals consistently and outward.

    Signs are propagated along the minimum spanning tree of the k-nearest-neighbour graph weighted
    by ``1 - |n_i . n_j|`` (Hoppe et al. 1992), per connected component; each component is then
    flipped so that its normals point away from its centroid on (area-)average.

    Parameters
    ----------
    points : (n, 3) float64
    normals : (n, 3) float64
    k : int

    Returns
    -------
    (n, 3) float64
    """
    points = as_array(points, "points", shape=(None, 3), min_len=4)
    normals = as_array(normals, "normals", shape=points.shape)
    n = len(points)
    kk = min(k + 1, n)
    dist, idx = cKDTree(points).query(points, k=kk)
    rows = np.repeat(np.arange(n), kk - 1)
    cols = idx[:, 1:].ravel()
    w = 1.0 - np.abs(np.einsum("ij,ij->i", normals[rows], normals[cols])) + 1e-9
    g = sp.coo_matrix((w, (rows, cols)), shape=(n, n)).tocsr()
    g = g.maximum(g.T)
    mst = minimum_spanning_tree(g)
    mst = mst + mst.T
    ncomp, labels = connected_components(mst, directed=False)
    out = normals.copy()
    for c in range(ncomp):
        members = np.flatnonzero(labels == c)
        order, pred = breadth_first_order(mst, members[0], directed=False)
        pred = pred.astype(np.int64)
        flip = np.ones(n)
        has = pred >= 0
        flip[has] = np.sign(np.einsum("ij,ij->i", normals[has], normals[pred[has]]))
        flip[flip == 0] = 1.0
        sign = _propagate_signs(order.astype(np.int64), pred, flip)
        out[order] *= sign[order][:, None]
        centre = points[order].mean(axis=0)
        if np.einsum("ij,ij->", points[order] - centre, out[order]) < 0:
            out[order] *= -1.0
    return out


def points_to_surfels(points, *, normals=None, colors=None, name=None) -> SurfelSet:
    """Surfels from a point cloud.

    Parameters
    ----------
    points : (n, 3) float64
    normals : (n, 3) float64, optional
        Given normals are kept (renormalised); otherwise estimated by PCA and oriented outward.
    colors : (n, 3) uint8, optional
    name : str, optional

    Returns
    -------
    SurfelSet
        Radii are the distance to the 6th nearest neighbour (:func:`surfidx.geometry.mesh.spacing_radii`).

    Raises
    ------
    InputError
        Fewer than 4 points, NaN/infinite coordinates, or points that hold no surface (all
        coincident or collinear).
    """
    points = as_array(points, "points", shape=(None, 3))
    if len(points) < 4:
        raise InputError(f"a point cloud needs at least 4 points to estimate normals, got {len(points)}")
    _check_spread(points)
    if normals is None:
        normals = orient_normals(points, estimate_normals(points))
    else:
        normals = as_array(normals, "normals", shape=points.shape)
        ln = np.linalg.norm(normals, axis=1)
        if np.any(ln == 0):
            normals = orient_normals(points, estimate_normals(points))
        else:
            normals = normals / ln[:, None]
    return SurfelSet(points, normals, spacing_radii(points), colors, name=name)


def _check_spread(points: np.ndarray) -> None:
    """Refuse points with no surface: all coincident, or all on one line.

    "On one line" means within rounding: the RMS distance from the points' principal line is at
    most :data:`_ROUNDING` times their largest coordinate magnitude (point files store float32).
    """
    n = len(points)
    centred = points - points.mean(axis=0)
    noise = _ROUNDING * float(np.abs(points).max())
    sv = np.linalg.svd(centred, compute_uv=False) / np.sqrt(n)  # RMS extents
    if not sv[0] > noise:
        raise InputError(f"all {n} points coincide; they hold no surface")
    if not sv[1] > noise:
        raise InputError(f"the {n} points are collinear; they hold no surface (a point cloud "
                         "needs points spread over a surface)")
