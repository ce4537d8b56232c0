"""Point clouds (surfels without faces) mapped through a closed proxy mesh.

:func:`surfidx.sphere.proxy.proxy_mesh` reconstructs a closed genus-0 triangle mesh from the
oriented surfels; that mesh is mapped like any mesh (:func:`surfidx.sphere.multilevel.mesh_map`),
and each surfel takes the sphere position of its closest point on the proxy (barycentric
interpolation, renormalised). Marching-cubes slivers can stop every hierarchy from untangling, so
where the proxy's map falls back to the single-level route, a proxy with half of its vertices
collapsed (shortest edges first, its vertices still on the reconstructed surface) is mapped
instead, and should that fall back too, a proxy on a coarser grid (``MapOptions.proxy_coarser``).
The surfels' own Delaunay triangulation is repaired afterwards by the caller
(:mod:`surfidx.sphere.repair`): the proxy's faces are not the surfels'.
"""

from __future__ import annotations

import numpy as np

from ..errors import TopologyError
from ..geometry.mesh import TriangleMesh
from ..geometry.surfels import SurfelSet
from .decimate import decimate
from .multilevel import mesh_map
from .options import MapOptions
from .proxy import auto_resolution, proxy_mesh, transfer

__all__ = ["cloud_map", "PROXY_VARIANTS"]

PROXY_VARIANTS = ("reconstructed", "simplified", "coarser")
"""Which proxy the map of a point cloud went through, in the order they are tried."""


def _mapped(v, f, name, options, route):
    """The mesh map of the proxy ``(v, f)``: ``(x, figures, fell back)``; ``route`` holds
    :func:`cloud_map`'s ``iterations``, ``gamma`` and ``balance``."""
    proxy = TriangleMesh(v, f, name=name).to_surfels()   # every proxy vertex is used
    return mesh_map(proxy, options=options, **route)


def cloud_map(surfels: SurfelSet, *, options: MapOptions, iterations: int, gamma: float,
              balance: bool):
    """The map of a point cloud through its proxy mesh, before the repair.

    Returns the sphere points ``(n, 3)``, the figures of the proxy's map, whether it fell back,
    and the proxy's figures (``proxy_vertices``, ``proxy_faces``, ``proxy``: one of
    :data:`PROXY_VARIANTS`). ``iterations``, ``gamma`` and ``balance`` are
    :func:`surfidx.sphere.parameterize`'s."""
    route = dict(iterations=iterations, gamma=gamma, balance=balance)
    v, f = proxy_mesh(surfels)
    x, info, fallback = _mapped(v, f, surfels.name, options, route)
    variant = PROXY_VARIANTS[0]
    if fallback:
        h = decimate(v, f, len(v) // 2)
        index = np.full(len(v), -1, dtype=np.int64)
        index[h.vertices] = np.arange(len(h.vertices))
        v2, f2 = v[h.vertices], index[h.faces]
        x2, info2, fallback2 = _mapped(v2, f2, surfels.name, options, route)
        if not fallback2:
            v, f, x, info, fallback, variant = v2, f2, x2, info2, False, PROXY_VARIANTS[1]
        else:
            coarser = _coarser(surfels, options, route)
            if coarser is not None:
                (v, f, x, info), fallback, variant = coarser, False, PROXY_VARIANTS[2]
    pts = transfer(surfels.positions, v, f, x)
    pts /= np.linalg.norm(pts, axis=1)[:, None]
    return pts, info, fallback, {"proxy_vertices": len(v), "proxy_faces": len(f),
                                 "proxy": variant}


def _coarser(surfels: SurfelSet, options: MapOptions, route):
    """The proxy at ``options.proxy_coarser`` times the automatic grid resolution and its map
    ``(vertices, faces, map, figures)``; None when that proxy is not genus 0 or falls back too."""
    resolution = auto_resolution(surfels.positions, scale=options.proxy_coarser)
    try:
        v, f = proxy_mesh(surfels, resolution=resolution)
    except TopologyError:
        return None
    x, info, fallback = _mapped(v, f, surfels.name, options, route)
    return None if fallback else (v, f, x, info)
