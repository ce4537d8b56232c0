"""Point clouds (surfels without faces) mapped through a closed proxy mesh.

:func:`surfidx.sphere.proxy.proxy_mesh` reconstructs a closed genus-0 triangle mesh from the
oriented surfels; that mesh is mapped like any mesh (:func:`surfidx.sphere.multilevel.mesh_map`,
an embedding), and each surfel takes the sphere position of its closest point on the proxy
(barycentric interpolation, renormalised).
"""

from __future__ import annotations

import numpy as np

from ..geometry.mesh import TriangleMesh
from ..geometry.surfels import SurfelSet
from .multilevel import mesh_map
from .options import MapOptions
from .proxy import proxy_mesh, transfer

__all__ = ["cloud_map"]


def cloud_map(surfels: SurfelSet, *, options: MapOptions, iterations: int, gamma: float,
              balance: bool):
    """The map of a point cloud through its proxy mesh.

    Returns the sphere points ``(n, 3)``, the figures of the proxy's map and the proxy's
    figures (``proxy_vertices``, ``proxy_faces``). ``iterations``, ``gamma`` and ``balance``
    are :func:`surfidx.sphere.parameterize`'s."""
    v, f = proxy_mesh(surfels)
    proxy = TriangleMesh(v, f, name=surfels.name).to_surfels()   # every proxy vertex is used
    x, info = mesh_map(proxy, options=options, iterations=iterations, gamma=gamma,
                       balance=balance)
    pts = transfer(surfels.positions, v, f, x)
    pts /= np.linalg.norm(pts, axis=1)[:, None]
    return pts, info, {"proxy_vertices": len(v), "proxy_faces": len(f)}
