"""Components: a mesh split into its pieces, tiny ones dropped.

Pieces are the connected components of the faces after pinched vertices and non-manifold edges
are split (:mod:`.pinch`), so two closed surfaces touching at one vertex or along one edge are
two pieces. A piece is dropped when it has fewer vertices than
``max(options.min_part_vertices, options.min_part_share * V)`` (``V``: vertices of all pieces,
counted after splitting), except the largest one, which is always kept.
"""

from __future__ import annotations

import numpy as np

from .analysis import face_components
from .pinch import split_pinched

__all__ = ["piece_faces", "drop_threshold"]


def drop_threshold(total: int, options) -> float:
    """Vertex count under which a piece is dropped."""
    return max(float(options.min_part_vertices), options.min_part_share * total)


def piece_faces(faces: np.ndarray, n: int, options):
    """Faces of each piece, largest first.

    Parameters
    ----------
    faces : (m, 3) int64
        Faces with distinct corners.
    n : int
    options : RepairOptions

    Returns
    -------
    kept : list of (k,) int64
        Row indices into ``faces`` of each kept piece, ordered by decreasing vertex count (ties:
        by first face).
    dropped : list of (k,) int64
        The same for the dropped pieces.
    sizes : (p,) int64
        Vertex counts of all pieces, in the order kept then dropped.
    """
    split, _, _, _ = split_pinched(faces, n)
    nn = int(split.max()) + 1 if len(split) else n
    count, lab = face_components(split, nn)
    # vertices per piece: each split vertex belongs to exactly one piece
    vert_piece = np.full(nn, -1, np.int64)
    vert_piece[split.ravel()] = np.repeat(lab, 3)
    sizes = np.bincount(vert_piece[vert_piece >= 0], minlength=count)
    order = np.lexsort((np.arange(count), -sizes))
    threshold = drop_threshold(int(sizes.sum()), options)
    groups = np.argsort(lab, kind="stable")
    bounds = np.searchsorted(lab[groups], np.arange(count + 1))
    rows = [groups[bounds[c]:bounds[c + 1]] for c in range(count)]
    kept = [rows[c] for i, c in enumerate(order) if i == 0 or sizes[c] >= threshold]
    dropped = [rows[c] for i, c in enumerate(order) if i > 0 and sizes[c] < threshold]
    keep_sizes = [sizes[c] for i, c in enumerate(order) if i == 0 or sizes[c] >= threshold]
    drop_sizes = [sizes[c] for i, c in enumerate(order) if i > 0 and sizes[c] < threshold]
    return kept, dropped, np.array(keep_sizes + drop_sizes, np.int64)
