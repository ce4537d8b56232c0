"""Pinched (non-manifold) vertices and edges split: one vertex per fan.

A vertex whose faces form several fans (:func:`~.analyse.corner_fans`: faces joined through
edges of exactly two faces) gets one copy per further fan. An edge held by three or more faces
joins no fans, so splitting the vertices also separates the sheets meeting at it: afterwards
every edge has one or two faces and every vertex one fan. The first fan of a vertex (the one of
its lowest corner) keeps the vertex; copies are appended in the order (vertex, fan).
"""

from __future__ import annotations

import numpy as np

from .analysis import corner_fans, edge_table

__all__ = ["split_pinched"]


def split_pinched(faces: np.ndarray, n: int, *, table=None):
    """Split the pinched vertices and non-manifold edges of ``faces``.

    Parameters
    ----------
    faces : (m, 3) int64
        Faces with distinct corners.
    n : int
        Vertex count.
    table : tuple, optional
        :func:`~.analyse.edge_table` of ``faces``, when the caller has it.

    Returns
    -------
    faces : (m, 3) int64
        The same faces, corners of further fans renumbered to the copies.
    origin : (d,) int64
        The vertex each copy ``n + i`` duplicates.
    pinched : int
        Vertices that had more than one fan.
    nonmanifold_edges : int
        Edges that had three or more faces.
    """
    m = len(faces)
    table = edge_table(faces, n) if table is None else table
    nonman = int((table[2] > 2).sum())
    lab = corner_fans(faces, n, table=table)
    cv = faces.ravel()
    # distinct (vertex, fan) pairs, each fan ranked by its lowest corner within its vertex
    corner = np.arange(3 * m)
    first_of_fan = np.full(lab.max() + 1 if m else 0, 3 * m, np.int64)
    np.minimum.at(first_of_fan, lab, corner)
    key = cv * np.int64(3 * m + 1) + first_of_fan[lab]
    ukey, inv = np.unique(key, return_inverse=True)
    inv = inv.ravel()
    uv = ukey // np.int64(3 * m + 1)
    is_first = np.ones(len(ukey), bool)
    is_first[1:] = uv[1:] != uv[:-1]
    new_id = np.empty(len(ukey), np.int64)
    new_id[is_first] = uv[is_first]
    extra = np.flatnonzero(~is_first)
    new_id[extra] = n + np.arange(len(extra))
    out = new_id[inv].reshape(m, 3)
    origin = uv[extra].astype(np.int64)
    pinched = len(np.unique(origin))
    return out, origin, pinched, nonman
