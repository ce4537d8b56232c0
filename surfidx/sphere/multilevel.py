"""The coarse-to-fine map of a mesh, and its fallback to the single-level map.

A Tutte map squeezes a limb by ``exp(-2π length / girth)`` at any resolution, and balancing from
there must undo factors of 1e20 in area; a mesh of a few dozen vertices has no limbs to squeeze.
So the mesh is decimated (:mod:`surfidx.sphere.decimate`) by ``level_ratio`` per level down to a
coarsest size of ``coarse_ladder``, the coarsest mesh is mapped by the single-level route
(:mod:`surfidx.sphere.tutte`), and each finer level starts from a map that is right at large
scales (Praun & Hoppe 2003 in spirit): the removed vertices come back at the mean-value
combination of their ring's sphere positions, the triangles this folds are untangled and the map
is balanced at the level's resolution (:mod:`surfidx.sphere.balance`), then normalised.

A level left with more than ``inverted_kept`` of its triangles inverted fails the hierarchy; the
next coarsest size is tried, and only when every one fails is the whole mesh mapped by the
single-level route (the *fallback*). A fallback that squeezes the surface beyond the limit at
which :func:`surfidx.sphere.parameterize` refuses it gives way to the *embedded hierarchy*
(``embed``), whose levels all start embedded and so cannot fail.
"""

from __future__ import annotations

import numpy as np

from ..geometry.unitsphere import orientation
from ..geometry.surfels import SurfelSet
from .balance import balance as balance_map, untangle
from .decimate import decimate
from .options import MapOptions
from .surface import areas3, oriented_faces, vertex_areas
from .tutte import centre, tutte_map
from .quality import area_distortion

__all__ = ["mesh_map", "multilevel_map", "Untangled"]


class Untangled(Exception):
    """A level of the multilevel map kept inverted triangles (the caller tries another
    hierarchy, or falls back)."""


def mesh_map(surfels: SurfelSet, *, options: MapOptions, iterations: int, gamma: float,
             balance: bool, faces=None, progress=None):
    """The multilevel map for each coarsest size of ``options.coarse_ladder`` in turn, or the
    single-level map when every hierarchy fails; where that squeezes the surface beyond
    ``options.max_area_distortion`` (which :func:`surfidx.sphere.parameterize` refuses), the
    embedded hierarchy (``options.embedded_hierarchy``) instead.

    Returns the map, its figures and whether it fell back to the single-level map.
    ``iterations``, ``gamma`` and ``balance`` are :func:`surfidx.sphere.parameterize`'s;
    ``progress`` (a callback, :mod:`surfidx.progress`) gets ``("map", k, levels)`` as each level
    of a hierarchy is done, coarsest first."""
    route = dict(iterations=iterations, gamma=gamma, balance=balance)
    f = oriented_faces(surfels) if faces is None else faces
    large = len(surfels) > options.large_level
    steps = options.final_steps_large if large else options.final_steps
    ladder = options.coarse_ladder
    for tries, coarse in enumerate(ladder):
        try:
            x, info = multilevel_map(surfels, faces=f, steps=steps, coarse=coarse,
                                     options=options, progress=progress, **route)
        except Untangled:
            continue
        return x, dict(info, coarse=coarse, retries=tries), False
    x, info = tutte_map(surfels, faces=f, options=options, **route)
    if (options.embedded_hierarchy and balance
            and area_distortion(surfels, x) > options.max_area_distortion):
        try:
            xe, info = multilevel_map(surfels, faces=f, steps=steps, coarse=ladder[0],
                                      options=options, progress=progress, embed=True, **route)
        except Untangled:       # not expected: every level starts embedded
            pass
        else:
            return xe, dict(info, coarse=ladder[0], retries=len(ladder), embedded=1), False
    return x, dict(info, levels=1, base_vertices=len(surfels), retries=len(ladder)), True


def multilevel_map(surfels: SurfelSet, *, options: MapOptions, iterations: int, gamma: float,
                   balance: bool, coarse: int, steps: int, faces=None, progress=None,
                   embed: bool = False, _depth: int = 0):
    """Decimate by ``options.level_ratio``, map the coarser mesh (recursively, down to
    ``coarse`` vertices, which :func:`surfidx.sphere.tutte.tutte_map` maps), carry the map to
    every vertex, untangle what folded on the way and balance for at most ``steps`` steps
    (``options.level_steps`` on the coarser levels). ``progress``: as for :func:`mesh_map`
    (``_depth`` counts the finer levels above this one, so the coarsest knows the total).

    ``embed``: the *embedded hierarchy*. The decimation checks only the topology (no shape
    rule stalls it on a thin frame), the prolongation puts every vertex whose star the mean
    would fold into its ring's kernel (:meth:`Hierarchy.prolong`), so each level starts
    embedded, and the untangling lifts the triangles squeezed below its area goal before the
    balancing.

    Raises
    ------
    Untangled
        When a level keeps more than ``options.inverted_kept`` of its triangles inverted.
    """
    n = len(surfels)
    f = oriented_faces(surfels) if faces is None else faces   # decimation keeps the topology
    p = surfels.positions
    target = max(coarse, n // options.level_ratio)
    h = decimate(p, f, target, shape=not embed) if n > coarse else None
    if h is None or len(h.vertices) >= n:
        x, info = tutte_map(surfels, options=options, iterations=iterations, gamma=gamma,
                            balance=balance)
        if progress is not None:
            progress("map", 1, _depth + 1)
        return x, dict(info, levels=1, base_vertices=n)
    kept = h.vertices
    index = np.full(n, -1, dtype=np.int64)
    index[kept] = np.arange(len(kept))
    small = SurfelSet(p[kept], surfels.normals[kept], surfels.radii[kept], faces=index[h.faces])
    xc, info = multilevel_map(small, faces=small.faces, options=options, iterations=iterations,
                              gamma=gamma, balance=balance, coarse=coarse,
                              steps=options.level_steps, progress=progress, embed=embed,
                              _depth=_depth + 1)
    x = np.zeros((n, 3))
    x[kept] = xc
    x = h.prolong(x, p, unit=True, embed=embed)
    x, uinfo = untangle(x, p, f, rounds=options.untangle_rounds if balance else 0, lift=embed)
    # a few triangles left inverted (slivers of a randomly split mesh can pin the untangling)
    # cost a few folds; the single-level map instead squeezes every limb
    if uinfo["inverted"] > options.inverted_kept * len(f):
        raise Untangled(n)
    large = n > options.large_level
    x, binfo = balance_map(x, p, f, iterations=steps if balance else 0,
                           lam=options.energy_lambda, max_cot=np.inf,
                           tol=options.loose_tol if large else options.strict_tol,
                           patience=options.loose_patience if large else options.strict_patience)
    x = centre(x, vertex_areas(f, areas3(p, f), n), f, iterations=options.centre_iterations)
    neg = int(np.count_nonzero(orientation(x, f) <= 0))
    if progress is not None:
        progress("map", info["levels"] + 1, info["levels"] + 1 + _depth)
    return x, {"mesh_folds": neg, "levels": info["levels"] + 1,
               "base_vertices": info["base_vertices"],
               "untangle_rounds": uinfo["rounds"] + info.get("untangle_rounds", 0),
               "balance_steps": binfo["steps"], "balance_energy": float(binfo["energy"])}
