"""Spherical map of a closed genus-0 surfel set that does not fold.

The stages of the default method ``"tutte"``, one module each:

0. :mod:`._surface`: the mesh faces (``SurfelSet.faces``) are checked to triangulate a sphere
   (closed, one piece, manifold, genus 0, consistent winding) before any mapping, so a torus or
   two pieces fail with :class:`~surfidx.TopologyError`.
1. :mod:`._multilevel` with :mod:`._decimate`: rounds of independent half-edge collapses under
   the link condition shrink the mesh by ``level_ratio`` per level down to a few dozen vertices;
   every level triangulates the same sphere. A Tutte map squeezes a limb by
   ``exp(-2π length / girth)`` at any resolution; a mesh of a few dozen vertices has no limbs to
   squeeze.
2. :mod:`._tutte`: the coarsest mesh gets the single-level map: a Tutte embedding with positive
   mean-value weights (fold-free by Tutte's theorem), area reweighting, balancing.
3. Each finer level: the removed vertices come back at the mean-value combination of their
   ring's sphere positions; the triangles this folds are untangled (Garanzha et al. 2021;
   :func:`._balance.untangle`); then the map is balanced by L-BFGS on the energy
   ``Σ A (‖J‖²/det + λ (det + 1/det))`` of the map from each 3D triangle to its chord triangle,
   preconditioned by the 3D cotangent Laplacian, with a line search that rejects any inverted
   triangle (:func:`._balance.balance`). The energy is smallest for a similarity of unit area
   ratio and grows without bound as a triangle degenerates, so every accepted iterate is a
   fold-free embedding; it trades angle against area distortion, so limbs keep the share of the
   sphere the grid needs. A Möbius normalisation ends each level: the area-weighted centre of
   mass at the origin, which makes the map canonical up to a rotation.
   A level that cannot be untangled fails its hierarchy; other coarsest sizes are tried
   (``MapOptions.coarse_ladder``), and when every one fails the whole surface gets the
   single-level map (the *fallback*, refused when it squeezes parts of the surface to nothing).
4. :mod:`._repair`: the folded triangles of the spherical Delaunay triangulation of the mapped
   surfels (where the map is anisotropic) are lowered by single-vertex moves
   (:mod:`._foldrepair`), a second pass, and edge flips realised as the exact Delaunay
   triangulation of moved points by a circle pattern (:mod:`._circlepattern`), each realisation
   kept only when the resampling loses at most ``TOL.realise_loss``.

Point clouds (surfels without faces) are mapped through a closed proxy mesh (:mod:`.proxy`,
:mod:`._cloud`); each surfel takes the sphere position of its closest point on the proxy, and
stage 4 repairs the surfels' own Delaunay triangulation. The original method ``"mds"``
(:mod:`._mds`) is spherical MDS of landmark geodesics.

All stages use intrinsic quantities only (lengths, angles, areas, connectivity; ties broken by
index), and stop on counts of steps or rounds, never on the clock: the map depends on the input
and :class:`MapOptions` only, and a rotated input gives the same points up to a rotation.
Quality figures are in :mod:`.quality`; geometry on the unit sphere in :mod:`surfidx.spherical`.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from types import MappingProxyType
from typing import Mapping

import numpy as np

from .._errors import InputError, TopologyError
from .._validate import check_positive_int
from ..spherical import hull_triangles
from ..surfels import SurfelSet
from ._cloud import cloud_map
from ._mds import geodesics, mds_map
from ._multilevel import mesh_map
from ._repair import repair
from ._surface import check_surfels, has_faces, oriented_faces
from .options import DEFAULT_OPTIONS, MapOptions
from .quality import (SPARSE_QUANTILE, area_distortion, count_folds, landmark_stress,
                      sparse_sampling)

__all__ = ["parameterize", "SphericalMap", "Stage", "MapOptions", "METHODS", "STAGES",
           "count_folds", "area_distortion", "sparse_sampling", "landmark_stress",
           "hull_triangles", "SPARSE_QUANTILE"]

METHODS = ("tutte", "mds")
"""Names accepted by :func:`parameterize` (the first is the default)."""

STAGES = ("multilevel", "single_level", "proxy", "repair", "realise", "mds")
"""Names of the stage records of a :class:`SphericalMap`, in the order they run."""


@dataclass(frozen=True)
class Stage:
    """The record of one stage of a map.

    Attributes
    ----------
    name : str
        One of :data:`STAGES`: ``"multilevel"`` (the coarse-to-fine map), ``"single_level"``
        (the single-level map, a fallback for a mesh), ``"proxy"`` (a point cloud's proxy
        mesh), ``"repair"`` (fold repair and second pass), ``"realise"`` (realised flips),
        ``"mds"``.
    figures : mapping of str to int, float or str
        Its counts and figures (read-only), e.g. ``levels``, ``balance_steps``,
        ``folds_repaired``.
    """

    name: str
    figures: Mapping

    @classmethod
    def of(cls, name: str, figures: dict) -> "Stage":
        """The record of stage ``name`` with a read-only copy of ``figures``."""
        return cls(name, MappingProxyType(dict(figures)))


@dataclass(frozen=True)
class SphericalMap:
    """A map of surfels onto the unit sphere, its quality figures and the stages that ran.

    Attributes
    ----------
    points : (n, 3) float64
        Unit vectors, one per surfel, in surfel order.
    method : str
        ``"tutte"`` or ``"mds"``.
    folded : int
        Folded triangles of the spherical Delaunay triangulation (convex hull) of ``points``.
    triangles : int
        Triangles of that triangulation.
    landmark_stress : float
        Normalised stress ``sqrt(sum (r*theta - d)^2 / sum d^2)`` of landmark geodesic distances
        ``d`` against great-circle angles ``theta`` (best scale ``r``); NaN when not computed.
    area_distortion : float
        Area-weighted RMS of ``log(spherical area share / 3D area share)`` over hull triangles.
    seconds : float
        Wall time of the mapping (a figure only: no stage depends on time).
    stages : tuple of Stage
        The stages that ran, in order.
    sparse_sampling : float
        :func:`sparse_sampling` of the map: how densely an even grid on the sphere samples the
        sparsest-mapped surfels, relative to their count (1 for an even map); it sets the grid
        level with the surfel count (:func:`surfidx.icosphere.choose_level`).
    """

    points: np.ndarray
    method: str
    folded: int
    triangles: int
    landmark_stress: float
    area_distortion: float
    seconds: float
    stages: tuple = ()
    sparse_sampling: float = 1.0

    @property
    def fold_fraction(self) -> float:
        """Share of folded hull triangles."""
        return self.folded / max(self.triangles, 1)

    @property
    def fallback(self) -> bool:
        """Whether a mesh (or a point cloud's proxy) got the single-level map because no
        hierarchy could be untangled."""
        return self.stage("single_level") is not None

    def stage(self, name: str):
        """The :class:`Stage` record called ``name``, or None when that stage did not run."""
        return next((s for s in self.stages if s.name == name), None)

    @property
    def info(self) -> Mapping:
        """The figures of every stage in one read-only mapping (later stages win a shared key)."""
        out = {}
        for s in self.stages:
            out.update(s.figures)
        return MappingProxyType(out)

    def figures(self) -> dict:
        """The figures as a plain dict (for JSON and tables): the map's and its stages'."""
        return {"method": self.method, "surfels": len(self.points), "folded": self.folded,
                "triangles": self.triangles, "fold_fraction": self.fold_fraction,
                "landmark_stress": self.landmark_stress,
                "area_distortion": self.area_distortion, "seconds": self.seconds,
                "sparse_sampling": self.sparse_sampling, "fallback": self.fallback,
                "stages": [s.name for s in self.stages], **self.info}


def _route_stage(figures: dict, fallback: bool) -> Stage:
    return Stage.of("single_level" if fallback else "multilevel", figures)


def parameterize(surfels: SurfelSet, *, method: str = "tutte", seed: int = 0,
                 landmarks: int = 32, iterations: int = 40, gamma: float = 0.15,
                 balance: bool = True, stress: bool = True,
                 options: MapOptions | None = None) -> SphericalMap:
    """Map surfels to the unit sphere.

    Parameters
    ----------
    surfels : SurfelSet
        A closed genus-0 surface. Method ``"tutte"`` maps the mesh faces (``surfels.faces``); a
        point cloud (no faces) is mapped through a closed proxy mesh reconstructed from the
        oriented surfels (:func:`surfidx.sphere.proxy.proxy_mesh`).
    method : {"tutte", "mds"}
        ``"tutte"``: fold-free Tutte embedding with area balancing (default); ``"mds"``: the
        original spherical MDS of landmark geodesics.
    seed : int
        Seed of the landmark choice.
    landmarks : int
        Landmarks for the stress figure and for ``"mds"``.
    iterations : int
        Most area-reweighting iterations (``"tutte"``) or CG iterations / 10 (``"mds"``).
    gamma : float
        Exponent of the area reweighting, in (0, 2].
    balance : bool
        Untangle and balance the distortion at each level (False: the Tutte start, a level
        whose prolongation folds falls back to the single-level map; for tests and
        comparisons).
    stress : bool
        Compute the landmark stress figure (geodesics from ``landmarks`` sources).
    options : MapOptions, optional
        Switches and tuning of the stages (default: ``MapOptions()``).

    Returns
    -------
    SphericalMap

    Raises
    ------
    InputError
        Unknown method, bad options, too few surfels.
    TopologyError
        Several pieces, holes, pinched vertices, genus > 0, inconsistent winding (for a point
        cloud: a proxy surface that is not one closed genus-0 piece); a fallback map that
        squeezes parts of the surface to nothing (area distortion above
        ``options.max_area_distortion``).
    """
    surfels = check_surfels(surfels)
    if method not in METHODS:
        raise InputError(f"method must be one of {', '.join(METHODS)}, got {method!r}")
    check_positive_int(landmarks, "landmarks", minimum=4)
    check_positive_int(iterations, "iterations", minimum=0)
    if not (0 < float(gamma) <= 2):
        raise InputError(f"gamma must lie in (0, 2], got {gamma!r}")
    if options is None:
        options = DEFAULT_OPTIONS
    elif not isinstance(options, MapOptions):
        raise InputError(f"options must be a MapOptions, got {type(options).__name__}")
    t0 = time.perf_counter()
    lm = dist = None
    fallback = False
    route = dict(iterations=iterations, gamma=float(gamma), balance=bool(balance))
    if method == "tutte" and has_faces(surfels):
        f = oriented_faces(surfels)
        pts, figures, fallback = mesh_map(surfels, faces=f, options=options, **route)
        stages = [_route_stage(figures, fallback)]
        pts, repaired = repair(pts, surfels, options=options, mesh=f)
    elif method == "tutte":
        pts, figures, fallback, proxy = cloud_map(surfels, options=options, **route)
        stages = [Stage.of("proxy", proxy), _route_stage(figures, fallback)]
        pts, repaired = repair(pts, surfels, options=options)
    else:
        if has_faces(surfels):
            oriented_faces(surfels)  # topology check before mapping
        pts, figures, lm, dist = mds_map(surfels, options=options, landmarks=landmarks,
                                         seed=seed, maxiter=max(10 * iterations, 10))
        stages, repaired = [Stage.of("mds", figures)], []
    stages += [Stage.of(name, figs) for name, figs in repaired]
    seconds = time.perf_counter() - t0
    tri = hull_triangles(pts)
    folded, total = count_folds(surfels, pts, triangles=tri)
    ad = area_distortion(surfels, pts, triangles=tri)
    if fallback and ad > options.max_area_distortion:
        cloud = not has_faces(surfels)
        what = "its proxy surface" if cloud else "the mesh"
        raise TopologyError(
            f"the spherical map squeezes parts of the surface to nothing (area distortion "
            f"{ad:.1f}; maps that resample well stay below {options.max_area_distortion:g}): no "
            f"level of {what} could be untangled, so the grid would miss those parts; thin or "
            "touching parts are the usual cause" + (": mesh the scan, or sample it more densely"
                                                    if cloud else ""))
    sparse = sparse_sampling(surfels, pts, triangles=tri)
    st = float("nan")
    if stress:
        if lm is None:
            lm, dist = geodesics(surfels, min(landmarks, len(surfels)), seed)
        st = landmark_stress(pts, lm, dist)
    return SphericalMap(pts, method, folded, total, st, ad, seconds, tuple(stages), sparse)
