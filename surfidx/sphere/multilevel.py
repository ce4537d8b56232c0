"""The coarse-to-fine map of a mesh, an embedding of it on the sphere at every level.

A Tutte map squeezes a limb by ``exp(-2π length / girth)`` at any resolution, and balancing from
there must undo factors of 1e20 in area; a mesh of a few dozen vertices has no limbs to squeeze.
So the mesh is decimated (:mod:`surfidx.sphere.decimate`) by ``level_ratio`` per level down to
``coarse_vertices``, the coarsest mesh is mapped by the single-level route
(:mod:`surfidx.sphere.tutte`, an embedding), and each finer level starts from a map that is right
at large scales (Praun & Hoppe 2003): the removed vertices come back at the mean-value
combination of their ring's sphere positions, or, where that would turn a triangle of their star
over, inside the kernel of their ring (:meth:`surfidx.sphere.decimate.Hierarchy.prolong`), so
every level starts embedded. The map is balanced at the level's resolution by steps that keep it
embedded (:mod:`surfidx.sphere.balance`) and normalised by Möbius steps that turn no triangle
over. No level can fold, so nothing is untangled or repaired and nothing falls back.
"""

from __future__ import annotations

import numpy as np

from ..geometry.surfels import SurfelSet
from .balance import Energy, balance as balance_map, inverted
from .decimate import decimate
from .options import MapOptions
from .surface import areas3, oriented_faces, vertex_areas
from .tutte import centre, single_level_steps, tutte_map

__all__ = ["mesh_map"]


def mesh_map(surfels: SurfelSet, *, options: MapOptions, iterations: int, gamma: float,
             balance: bool, faces=None, progress=None, _depth: int = 0):
    """Decimate by ``options.level_ratio``, map the coarser mesh (recursively, down to
    ``options.coarse_vertices`` vertices, which :func:`surfidx.sphere.tutte.tutte_map` maps),
    carry the map to every vertex keeping it embedded and balance it for at most
    ``options.final_steps`` steps at the finest level (``final_steps_large`` above
    ``large_level`` vertices; ``level_steps`` on the coarser levels, the single-level count
    :func:`surfidx.sphere.tutte.single_level_steps` on those prolonged round by round).

    ``iterations``, ``gamma`` and ``balance`` are :func:`surfidx.sphere.parameterize`'s;
    ``progress`` (a callback, :mod:`surfidx.progress`) gets ``("map", k, levels)`` as each level
    is done, coarsest first (``_depth`` counts the finer levels above this one).

    Returns the map ``(n, 3)`` and its figures: ``levels``, ``base_vertices``,
    ``balance_steps``, ``balance_energy`` (of the finest level), ``kernel_insertions`` and
    ``settled_levels`` (levels prolonged round by round) over all levels, and ``mesh_folds``,
    the mesh triangles the map leaves clockwise (0: every level is an embedding).
    """
    n = len(surfels)
    f = oriented_faces(surfels) if faces is None else faces   # decimation keeps the topology
    p = surfels.positions
    coarse = options.coarse_vertices
    h = None
    if n > coarse:
        target = max(coarse, n // options.level_ratio)
        h = decimate(p, f, target)
        if len(h.vertices) > max(target, (n + target) // 2):
            # the shape rules stall (a thin frame): collapses under the link condition alone
            h = decimate(p, f, target, shape=False)
    if h is None or len(h.vertices) >= n:
        x, info = tutte_map(surfels, faces=f, options=options, iterations=iterations,
                            gamma=gamma, balance=balance)
        if progress is not None:
            progress("map", 1, _depth + 1)
        return x, dict(info, levels=1, base_vertices=n)
    kept = h.vertices
    index = np.full(n, -1, dtype=np.int64)
    index[kept] = np.arange(len(kept))
    small = SurfelSet(p[kept], surfels.normals[kept], surfels.radii[kept], faces=index[h.faces])
    xc, info = mesh_map(small, faces=small.faces, options=options, iterations=iterations,
                        gamma=gamma, balance=balance, progress=progress, _depth=_depth + 1)
    x = np.zeros((n, 3))
    x[kept] = xc
    start = h.prolong(x, p, unit=True, embed=True)
    from ..geometry.sparse import SPDSolver

    settled = 0
    # the last round's mesh is this level's: its preconditioner is factored once
    solver = SPDSolver(keep=True)
    if balance and not _balanced_start(start, p, f, options):
        # the kernels of many rounds nested in thin wedges: balance after every round
        start = h.prolong(x, p, unit=True, embed=True,
                          settle=_settle(h.round_faces(f), p, options, solver))
        settled = 1
    x = start
    large = n > options.large_level
    # a settled level's start was squeezed: it takes the single-level map's step count
    steps = (single_level_steps(n, options) if settled else options.level_steps) if _depth else (
        options.final_steps_large if large else options.final_steps)
    sweeps, rounds = ((options.relax_sweeps, options.level_rounds) if _depth else
                      (options.final_sweeps, options.final_rounds))
    x, binfo = balance_map(x, p, f, iterations=steps if balance else 0,
                           sweeps=sweeps if balance else 0, rounds=rounds,
                           sweep_tol=options.sweep_tol, lam=options.energy_lambda,
                           max_cot=np.inf,
                           tol=options.loose_tol if large else options.strict_tol,
                           patience=options.loose_patience if large else options.strict_patience,
                           solver=solver)
    x = centre(x, vertex_areas(f, areas3(p, f), n), f, iterations=options.centre_iterations)
    if progress is not None:
        progress("map", info["levels"] + 1, info["levels"] + 1 + _depth)
    return x, {"mesh_folds": inverted(x, f), "levels": info["levels"] + 1,
               "base_vertices": info["base_vertices"], "balance_steps": binfo["steps"],
               "balance_energy": float(binfo["energy"]),
               "kernel_insertions": h.kernel_insertions + info.get("kernel_insertions", 0),
               "settled_levels": settled + info.get("settled_levels", 0)}


def _balanced_start(x, p, f, options: MapOptions) -> bool:
    """Whether the prolonged map ``x`` is an embedding whose balancing energy per unit area
    is at most ``options.settle_energy``."""
    if not np.isfinite(x).all():
        return False
    energy = Energy(p, f, max_cot=np.inf)
    energy.eps, energy.lam = 0.0, options.energy_lambda
    e, _ = energy(x, grad=False)
    return bool(e <= options.settle_energy * energy.area3.sum())


def _settle(round_faces, p, options: MapOptions, solver):
    """The ``settle`` of :meth:`surfidx.sphere.decimate.Hierarchy.prolong` that balances the
    mesh of each round (``round_faces``) for ``options.round_steps`` steps, with
    ``options.round_sweeps`` relaxation sweeps before and after them, its preconditioners
    factored by ``solver``."""
    def settle(x, r):
        f = round_faces[r]
        verts = np.unique(f)
        local = np.full(len(x), -1, dtype=np.int64)
        local[verts] = np.arange(len(verts))
        y, _ = balance_map(x[verts], p[verts], local[f], iterations=options.round_steps,
                           sweeps=options.round_sweeps, sweep_tol=options.sweep_tol,
                           lam=options.energy_lambda, max_cot=np.inf, solver=solver)
        x[verts] = y
        return x
    return settle
