"""The surface to map: surfels checked, mesh faces checked to triangulate a sphere, 3D areas."""

from __future__ import annotations

import numpy as np

from ..errors import InputError, TopologyError
from ..geometry.mesh import TriangleMesh
from ..geometry.surfels import SurfelSet

__all__ = ["MIN_SURFELS", "check_surfels", "has_faces", "oriented_faces", "areas3",
           "vertex_areas"]

MIN_SURFELS = 8
"""Fewest surfels :func:`surfidx.sphere.parameterize` maps."""

_AREA_FLOOR = 1e-300   # a vertex's area weight stays positive (Möbius normalisation divides by it)


def check_surfels(surfels) -> SurfelSet:
    """``surfels``, checked to be a SurfelSet of at least :data:`MIN_SURFELS`."""
    if not isinstance(surfels, SurfelSet):
        raise InputError(f"surfels must be a SurfelSet, got {type(surfels).__name__}")
    if len(surfels) < MIN_SURFELS:
        raise InputError(f"too few surfels to map to the sphere: {len(surfels)} (need at least "
                         f"{MIN_SURFELS})")
    return surfels


def has_faces(surfels: SurfelSet) -> bool:
    """Whether the surfels carry mesh faces (otherwise: a point cloud)."""
    return surfels.faces is not None and len(surfels.faces) > 0


def oriented_faces(surfels: SurfelSet) -> np.ndarray:
    """Non-degenerate faces, checked to triangulate a sphere, wound to agree with the normals.

    The checks (one piece, every surfel on a triangle, closed, manifold, genus 0, consistent
    winding) come before any mapping, so that a torus or two pieces fail with a clear
    :class:`~surfidx.TopologyError`.
    """
    f = surfels.faces
    f = f[(f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 0] != f[:, 2])]
    n = len(surfels)
    topo = TriangleMesh(surfels.positions, f).topology()
    if topo.vertices < n:
        raise TopologyError(f"{n - topo.vertices} surfels belong to no triangle; the surface must "
                            "be one closed piece")
    if topo.components != 1:
        raise TopologyError(f"the surface has {topo.components} separate pieces; a spherical map "
                            "needs one connected surface (split it or keep the largest piece)")
    if not topo.closed:
        raise TopologyError(f"the surface is not closed ({topo.boundary_edges} boundary edges, "
                            f"{topo.nonmanifold_edges} non-manifold edges); fill its holes first")
    if topo.nonmanifold_vertices:
        raise TopologyError(f"the surface has {topo.nonmanifold_vertices} pinched (non-manifold) "
                            "vertices; repair them before mapping to the sphere")
    if topo.genus != 0:
        raise TopologyError(f"the surface has genus {topo.genus} (Euler characteristic "
                            f"{topo.euler}); only genus-0 (sphere-like) surfaces can be mapped "
                            "to the sphere without cuts")
    # consistent winding: every directed edge once
    he = np.sort(np.concatenate([f[:, 0] * n + f[:, 1], f[:, 1] * n + f[:, 2],
                                 f[:, 2] * n + f[:, 0]]))
    if (he[1:] == he[:-1]).any():
        raise TopologyError("the triangles are not consistently oriented (the surface is "
                            "non-orientable or has flipped faces); fix the face winding")
    p = surfels.positions
    fn = np.cross(p[f[:, 1]] - p[f[:, 0]], p[f[:, 2]] - p[f[:, 0]])
    if np.einsum("ij,ij->", fn, surfels.normals[f].sum(axis=1)) < 0:
        f = f[:, [0, 2, 1]]
    return np.ascontiguousarray(f)


def areas3(p, tri) -> np.ndarray:
    """3D areas ``(m,)`` of the triangles ``tri`` of the positions ``p``."""
    return 0.5 * np.linalg.norm(np.cross(p[tri[:, 1]] - p[tri[:, 0]], p[tri[:, 2]] - p[tri[:, 0]]),
                                axis=1)


def vertex_areas(f, a3, n) -> np.ndarray:
    """Each vertex's summed 3D area of its triangles ``a3`` (kept above zero), ``(n,)``: the
    weights of the Möbius normalisation."""
    return np.maximum(np.bincount(f.ravel(), np.repeat(a3, 3), minlength=n), _AREA_FLOOR)
