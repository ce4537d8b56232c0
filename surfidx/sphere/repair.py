"""Folded Delaunay triangles of a map lowered: local moves, a second pass, realised flips.

A map that embeds the mesh can still fold the spherical Delaunay triangulation of the mapped
surfels (where the map is anisotropic, see :mod:`surfidx.sphere.foldrepair`). Three stages lower
that count, each never raising it:

1. the fold repair (:func:`surfidx.sphere.foldrepair.repair_folds`): single-vertex moves that
   keep ``mesh`` embedded (a point cloud has none: its triangulation's unfolded triangles stand
   in for it);
2. with ``MapOptions.second_pass``, where folds remain: every move tried again, without the
   random search, the Delaunay triangles that are not folded kept embedded too (their
   neighbourhoods propose other moves);
3. with ``MapOptions.realise``, where folds still remain: edge flips of the triangulation,
   realised as the exact Delaunay triangulation of moved points
   (:func:`surfidx.sphere.circlepattern.lower_folds`), each round kept only when the
   resampling loses at most ``TOL.realise_loss`` dB (:class:`ResamplingCheck`).
"""

from __future__ import annotations

import numpy as np

from ..tolerance import TOL
from ..geometry.icosphere import choose_level
from ..geometry.metrics import Reference
from ..codec.resample import grid_to_surfels, locate_surfels, resample
from ..geometry.unitsphere import folded_mask, hull_triangles
from ..geometry.surfels import SurfelSet
from .circlepattern import lower_folds
from .foldrepair import repair_folds
from .options import MapOptions
from .quality import sparse_sampling

__all__ = ["repair", "ResamplingCheck"]


def repair(x, surfels: SurfelSet, *, options: MapOptions, mesh=None):
    """The three stages on the map ``x``; ``mesh`` (faces) is kept embedded.

    Returns the map, a list of ``(stage name, figures)``: ``"repair"`` (``folds_repaired``
    by both passes, ``repair_rounds``, ``second_pass`` the folds the second pass removed) and,
    when it ran, ``"realise"`` (``folds_realised``, ``realise_rounds``, ``realise_refused``,
    ``realise_annealed``), empty for a point cloud whose triangulation has no folded triangle
    or only folded ones; and, when the realisation's check located the grid in the returned
    map, ``(level, location)`` (:func:`surfidx.codec.resample.locate_surfels`), else None."""
    p, normals = surfels.positions, surfels.normals

    def unfolded(x):
        tri = hull_triangles(x)
        bad = folded_mask(p, normals, tri)
        return bad, tri[~bad] if mesh is None else np.concatenate([mesh, tri[~bad]])

    faces = mesh
    if mesh is None:
        bad, faces = unfolded(x)
        if not bad.any() or bad.all():
            return x, [], None
    x, first = repair_folds(x, p, normals, faces, options=options)
    figures = {"folds_repaired": first["folds_before"] - first["folds"],
               "repair_rounds": first["rounds"], "second_pass": 0}
    stages = [("repair", figures)]
    folds = first["folds"]
    if folds and options.second_pass:
        x, second = repair_folds(x, p, normals, unfolded(x)[1], options=options, search=False)
        figures["second_pass"] = second["folds_before"] - second["folds"]
        figures["folds_repaired"] += figures["second_pass"]
        folds = second["folds"]
    located = None
    if folds and options.realise:
        check = ResamplingCheck(surfels, x)
        x, real = lower_folds(x, p, normals, accept=check, options=options)
        stages.append(("realise", {"folds_realised": real["folds_before"] - real["folds"],
                                   "realise_rounds": real["rounds"],
                                   "realise_refused": real["refused"],
                                   "realise_annealed": real["annealed"]}))
        location = check.location_of(x)
        located = None if location is None else (check.level, location)
    return x, stages, located


class ResamplingCheck:
    """Whether a fold realisation of the map ``x`` keeps the resampling's quality: its
    infinite-rate PSNR_D2 (geometry resampled at the grid level chosen for ``x``, against the
    surfels) is at most ``TOL.realise_loss`` dB below that of ``x``.

    What a realisation costs shows only in the resampling: it changes the scale of whole limbs,
    and how far the points crowd is a poor predictor of that cost.

    It keeps where the grid lies in the last map it took (``x``, then each accepted
    realisation), which the final map's resampling can reuse (:meth:`location_of`)."""

    def __init__(self, surfels: SurfelSet, x):
        self.surfels = surfels
        self.reference = Reference(surfels)
        self.level = choose_level(len(surfels), sparse_sampling=sparse_sampling(surfels, x))
        grid, location = self._grid(x)
        self.floor = self.reference.psnr_d2(grid) - TOL.realise_loss
        self._taken = (x, location)

    def _grid(self, x) -> tuple[SurfelSet, tuple]:
        location = locate_surfels(self.surfels, x, self.level)
        grid = resample(self.surfels, x, self.level, color=False, location=location)
        return grid_to_surfels(grid), location

    def psnr(self, x) -> float:
        """Infinite-rate PSNR_D2 (dB) of the map ``x`` resampled at :attr:`level`."""
        return self.reference.psnr_d2(self._grid(x)[0])

    def location_of(self, x):
        """:func:`surfidx.codec.resample.locate_surfels` of the map ``x`` at :attr:`level` when ``x``
        is the last map this check took (the same array object), else None."""
        return self._taken[1] if self._taken[0] is x else None

    def __call__(self, y) -> bool:
        grid, location = self._grid(y)
        if not self.reference.psnr_d2_at_least(grid, self.floor):
            return False
        self._taken = (y, location)
        return True
