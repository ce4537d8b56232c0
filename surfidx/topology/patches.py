"""A repaired piece as a labelled triangle mesh: the scan's faces real, the patches' virtual.

:func:`closed_mesh` turns a :class:`~surfidx.topology.ClosedSurface` into a
:class:`~surfidx.geometry.mesh.TriangleMesh` whose ``face_patch`` says which faces are virtual (and of
which patch) and whose ``patch_cut`` says which patches are the two lids of a handle cut, so that
:meth:`~surfidx.geometry.mesh.TriangleMesh.to_surfels` gives surfels carrying
:attr:`~surfidx.SurfelSet.patch` / :attr:`~surfidx.SurfelSet.patch_cut` for the codec's mask.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import spsolve

from ..geometry.mesh import TriangleMesh

__all__ = ["closed_mesh", "patch_cuts"]


def patch_cuts(closed) -> np.ndarray:
    """(P,) int64: per patch of ``closed``, the handle cut whose lid it is, or -1 for a hole.

    A patch is a lid of cut ``k`` when every rim vertex of it is (a copy of) an input vertex on
    the cut cycle (compared by :attr:`ClosedSurface.vertex_origin`, so copies made when a cut
    pinched a hole's rim count too). A cut must have exactly two lids; a cut for which this test
    does not find two (it cannot happen unless a cut runs along a hole's rim) has its patches
    labelled -1 (holes), so the labels always pair.
    """
    patch = np.asarray(closed.patch)
    count = int(patch.max()) + 1 if patch.size and patch.max() >= 0 else 0
    out = np.full(count, -1, np.int64)
    if not count or not closed.cuts:
        return out
    virt = np.asarray(closed.virtual_vertices)
    origin = np.asarray(closed.vertex_origin)
    faces = np.asarray(closed.faces)
    cut_sets = [np.unique(origin[np.concatenate([c.vertices, c.copies])]) for c in closed.cuts]
    for p in range(count):
        corners = np.unique(faces[patch == p])
        rim = origin[corners[~virt[corners]]]
        for k, cset in enumerate(cut_sets):
            if len(rim) and np.isin(rim, cset).all():
                out[p] = k
                break
    for k in range(len(closed.cuts)):
        if int((out == k).sum()) != 2:
            out[out == k] = -1
    return out


def _harmonic_fill(values, known, faces):
    """``values`` with the unknown rows replaced by the discrete harmonic interpolation (uniform
    weights over the edges of ``faces``) of the known ones."""
    n = len(values)
    unknown = ~known
    if not unknown.any():
        return values
    e = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    e = np.sort(e, axis=1)
    key = np.unique(e[:, 0] * np.int64(n) + e[:, 1])    # the distinct edges, (lo, hi) order
    e = np.stack([key // n, key % n], axis=1)
    w = sp.coo_matrix((np.ones(2 * len(e)), (np.r_[e[:, 0], e[:, 1]], np.r_[e[:, 1], e[:, 0]])),
                      shape=(n, n)).tocsr()
    deg = np.asarray(w.sum(axis=1)).ravel()
    lap = (sp.diags(deg) - w).tocsr()
    u, k = np.flatnonzero(unknown), np.flatnonzero(known)
    a = lap[u][:, u].tocsc()
    b = -(lap[u][:, k] @ values[k])
    out = values.copy()
    sol = spsolve(a, b)
    out[u] = sol.reshape(len(u), -1)
    return out


def closed_mesh(closed, *, colors=None, name=None) -> TriangleMesh:
    """The closed surface as a triangle mesh with its virtual faces labelled.

    Parameters
    ----------
    closed : ClosedSurface
        From :func:`surfidx.topology.close_surface`.
    colors : (k, 3) uint8, optional
        Colour of each input vertex of the piece (the ``vertices`` given to ``close_surface``):
        copies take their original's colour, virtual vertices the harmonic interpolation of the
        rim colours (smooth across the patch, equal to the scan at its rim).
    name : str, optional

    Returns
    -------
    TriangleMesh
        ``face_patch`` and ``patch_cut`` set when the repair added any face (else ``None``:
        the scan only had pinches split).
    """
    faces = np.asarray(closed.faces, np.int64)
    vcol = None
    if colors is not None:
        origin = np.asarray(closed.vertex_origin)
        real = origin >= 0
        vals = np.zeros((len(origin), 3))
        vals[real] = np.asarray(colors, np.float64)[origin[real]]
        vals = _harmonic_fill(vals, real, faces)
        vcol = np.clip(np.round(vals), 0, 255).astype(np.uint8)
    face_patch = patch_cut = None
    if np.asarray(closed.virtual_faces).any():
        face_patch = np.asarray(closed.patch, np.int64)
        patch_cut = patch_cuts(closed)
    return TriangleMesh(closed.vertices, faces, vertex_colors=vcol, name=name,
                        face_patch=face_patch, patch_cut=patch_cut)
