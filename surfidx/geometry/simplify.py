"""A vertex budget met by quadric-error simplification (:func:`simplify_mesh`).

A decoded model is finest at its grid level; a user who needs fewer vertices gets that mesh
simplified by edge collapses that keep the quadric error small (fast-simplification, the
Fast-Quadric-Mesh-Simplification algorithm), rather than a coarser grid, which spends its
vertices evenly over the sphere instead of where the surface bends. Vertex colours are taken
from the nearest vertex of the mesh before simplification.
"""

from __future__ import annotations

import numpy as np

from ..errors import InputError
from .mesh import TriangleMesh

__all__ = ["simplify_mesh", "check_max_vertices", "MIN_VERTICES", "AGGRESSIVENESS"]

#: The smallest vertex budget: a tetrahedron, the smallest closed triangle mesh.
MIN_VERTICES = 4

#: fast-simplification's ``agg`` values tried in turn: the first keeps the shape best, the
#: later ones collapse faster and so reach a budget the first stops short of.
AGGRESSIVENESS = (3.0, 5.0, 7.0, 10.0)

_TRIES = 4  # per aggressiveness, each asking for fewer faces by what the last one overshot


def check_max_vertices(max_vertices) -> int:
    """``max_vertices`` as an int, checked before anything is decoded or simplified.

    Raises
    ------
    InputError
        Not an integer, or below :data:`MIN_VERTICES`.
    """
    if isinstance(max_vertices, bool) or not isinstance(max_vertices, (int, np.integer)):
        raise InputError(f"max_vertices must be an integer of at least {MIN_VERTICES}, got "
                         f"{max_vertices!r}")
    if max_vertices < MIN_VERTICES:
        raise InputError(f"max_vertices must be at least {MIN_VERTICES} (a tetrahedron), got "
                         f"{max_vertices}; ask for more vertices")
    return int(max_vertices)


def _compact(vertices: np.ndarray, faces: np.ndarray):
    """Drop the vertices no face uses (and the faces with a repeated corner)."""
    faces = faces[(faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2])
                  & (faces[:, 2] != faces[:, 0])]
    used = np.unique(faces)
    remap = np.full(len(vertices), -1, np.int64)
    remap[used] = np.arange(len(used))
    return vertices[used], remap[faces]


def _collapse(vertices, faces, max_vertices: int):
    """Simplified ``(vertices, faces)`` with at most ``max_vertices`` used vertices."""
    import fast_simplification

    n = len(vertices)
    for agg in AGGRESSIVENESS:
        # an edge collapse removes one vertex and two faces (one on a border): ask for the
        # faces of a mesh with max_vertices vertices, fewer while a try leaves too many
        target = len(faces) - 2 * (n - max_vertices)
        for _ in range(_TRIES):
            v, f = fast_simplification.simplify(vertices, faces.astype(np.int32),
                                                target_count=max(target, 4), agg=agg,
                                                preserve_border=True)
            v, f = _compact(np.asarray(v, np.float64), np.asarray(f, np.int64))
            if len(v) <= max_vertices:
                return v, f
            if target <= 4:
                break
            target -= 2 * (len(v) - max_vertices)
    raise InputError(f"the mesh of {n:,} vertices could not be simplified to "
                     f"{max_vertices:,} vertices (it stops at {len(v):,}, its open borders "
                     "kept); ask for more vertices")


def simplify_mesh(mesh: TriangleMesh, max_vertices: int) -> TriangleMesh:
    """A mesh of at most ``max_vertices`` vertices close to ``mesh``.

    Parameters
    ----------
    mesh : TriangleMesh
    max_vertices : int
        At least :data:`MIN_VERTICES`.

    Returns
    -------
    TriangleMesh
        ``mesh`` itself when it has no more vertices; else the mesh simplified by
        quadric-error edge collapses (open borders kept), every vertex used by a face,
        colours from the nearest vertex of ``mesh``, named as it.

    Raises
    ------
    InputError
        ``max_vertices`` not an integer of at least :data:`MIN_VERTICES`, or a mesh that
        cannot be collapsed that far (its borders and pieces need more vertices).
    """
    limit = check_max_vertices(max_vertices)
    if not isinstance(mesh, TriangleMesh):
        raise InputError(f"simplify_mesh needs a TriangleMesh, got {type(mesh).__name__}")
    if len(mesh.vertices) <= limit:
        return mesh
    v, f = _collapse(np.ascontiguousarray(mesh.vertices, np.float64), mesh.faces, limit)
    colors = None
    if mesh.vertex_colors is not None:
        from scipy.spatial import cKDTree

        colors = mesh.vertex_colors[cKDTree(mesh.vertices).query(v)[1]]
    return TriangleMesh(v, f, vertex_colors=colors, name=mesh.name)
