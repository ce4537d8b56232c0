"""The spherical map's entry point: :func:`parameterize` routes a surfel set through the stages
(see :mod:`surfidx.sphere`) and returns a :class:`SphericalMap` with its quality figures and the
records of the stages that ran."""

from __future__ import annotations

import time
from dataclasses import dataclass, replace
from types import MappingProxyType
from typing import Mapping

import numpy as np

from ..errors import InputError
from ..validate import check_positive_int
from ..geometry.icosphere import choose_level
from ..progress import report
from ..geometry.unitsphere import hull_triangles, map_points
from ..geometry.surfels import SurfelSet
from .balance import inverted
from .multilevel import mesh_map
from .surface import check_surfels, has_faces, oriented_faces
from .options import DEFAULT_OPTIONS, METHODS, MapOptions
from .quality import _area_distortion, _count_folds, _sparse_sampling, landmark_stress

__all__ = ["parameterize", "SphericalMap", "Stage"]


@dataclass(frozen=True)
class Stage:
    """The record of one stage of a map.

    Attributes
    ----------
    name : str
        One of :data:`STAGES`: ``"multilevel"`` (the coarse-to-fine map), ``"proxy"`` (a point
        cloud's proxy mesh), ``"mds"``.
    figures : mapping of str to int, float or str
        Its counts and figures (read-only), e.g. ``levels``, ``balance_steps``,
        ``mesh_folds``.
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
        Folded triangles of the triangulation the codec interpolates in
        (:func:`surfidx.codec.resample.map_triangles`): for surfels with faces, the faces that
        are not counter-clockwise on the sphere (0 for method ``"tutte"``: it embeds the
        mesh); for a point cloud, the triangles of the spherical Delaunay triangulation
        (convex hull) of ``points`` whose 3D normal points against their surfels' normals.
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
        :func:`surfidx.sphere.sparse_sampling` of the map: how densely an even grid on the sphere samples the
        sparsest-mapped surfels, relative to their count (1 for an even map); it sets the grid
        level with the surfel count (:func:`surfidx.geometry.icosphere.choose_level`).

    Notes
    -----
    A map is one point on the sphere per surfel, not a surface of its own, so it has no
    ``to_trimesh``: ``TriangleMesh(smap.points, surfels.faces).to_trimesh()`` shows the map of
    surfels that carry faces, ``trimesh.PointCloud(smap.points)`` that of any surfels.
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
    def grid_level(self) -> int:
        """The icosahedral grid level for these surfels: :func:`surfidx.geometry.icosphere.choose_level`
        of the surfel count and this map's :attr:`sparse_sampling` (the codec's and the CLI's
        default level)."""
        return choose_level(len(self.points), sparse_sampling=self.sparse_sampling)

    @property
    def fold_fraction(self) -> float:
        """Share of folded triangles (of :attr:`triangles`)."""
        return self.folded / max(self.triangles, 1)

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
                "sparse_sampling": self.sparse_sampling,
                "stages": [s.name for s in self.stages], **self.info}


def parameterize(surfels: SurfelSet, *, method: str | None = None, seed: int | None = None,
                 landmarks: int | None = None, iterations: int | None = None,
                 gamma: float | None = None, balance: bool | None = None, stress: bool = True,
                 options: MapOptions | None = None, progress=None) -> SphericalMap:
    """Map surfels to the unit sphere.

    Parameters
    ----------
    surfels : SurfelSet
        A closed genus-0 surface. Method ``"tutte"`` maps the mesh faces (``surfels.faces``); a
        point cloud (no faces) is mapped through a closed proxy mesh reconstructed from the
        oriented surfels (:func:`surfidx.sphere.proxy.proxy_mesh`).
    method, seed, landmarks, iterations, gamma, balance : optional
        Override the fields of the same names of ``options`` (:class:`MapOptions` holds their
        defaults and meaning).
    stress : bool
        Compute the landmark stress figure (geodesics from ``landmarks`` sources).
    options : MapOptions, optional
        Method, switches and tuning of the stages (default: ``MapOptions()``).
    progress : callable, optional
        ``progress(stage, done, total)`` (:mod:`surfidx.progress`) at the stage boundaries:
        ``"map"`` (for a mesh, once per level of the multilevel map as it is done, coarsest
        first), ``"figures"``. It changes nothing in the map.

    Returns
    -------
    SphericalMap

    Raises
    ------
    InputError
        Unknown method, bad options, too few surfels.
    TopologyError
        Several pieces, holes, pinched vertices, genus > 0, inconsistent winding (for a point
        cloud: a proxy surface that is not one closed genus-0 piece).
    """
    surfels = check_surfels(surfels)
    if method is not None and method not in METHODS:
        raise InputError(f"method must be one of {', '.join(METHODS)}, got {method!r}")
    if landmarks is not None:
        check_positive_int(landmarks, "landmarks", minimum=4)
    if iterations is not None:
        check_positive_int(iterations, "iterations", minimum=0)
    if gamma is not None and not (0 < float(gamma) <= 2):
        raise InputError(f"gamma must lie in (0, 2], got {gamma!r}")
    if options is None:
        options = DEFAULT_OPTIONS
    elif not isinstance(options, MapOptions):
        raise InputError(f"options must be a MapOptions, got {type(options).__name__}")
    given = dict(method=method, seed=seed, landmarks=landmarks, iterations=iterations,
                 gamma=None if gamma is None else float(gamma),
                 balance=None if balance is None else bool(balance))
    given = {k: v for k, v in given.items() if v is not None}
    if given:
        options = replace(options, **given)
    method, seed, landmarks = options.method, options.seed, options.landmarks
    iterations = options.iterations
    t0 = time.perf_counter()
    report(progress, "map", 0, 1)
    lm = dist = None
    route = dict(iterations=iterations, gamma=float(options.gamma),
                 balance=bool(options.balance))
    faces = None
    if method == "tutte" and has_faces(surfels):
        faces = oriented_faces(surfels)
        pts, figures = mesh_map(surfels, faces=faces, options=options, progress=progress,
                                **route)
        stages = [Stage.of("multilevel", figures)]
    elif method == "tutte":
        from .cloud import cloud_map        # scipy.ndimage and the proxy: point clouds only

        pts, figures, proxy = cloud_map(surfels, options=options, **route)
        stages = [Stage.of("proxy", proxy), Stage.of("multilevel", figures)]
    else:
        from .mds import mds_map

        if has_faces(surfels):
            oriented_faces(surfels)  # topology check before mapping
        pts, figures, lm, dist = mds_map(surfels, options=options, landmarks=landmarks,
                                         seed=seed, maxiter=max(10 * iterations, 10))
        stages = [Stage.of("mds", figures)]
    seconds = time.perf_counter() - t0
    report(progress, "figures", 0, 1)
    tri = hull_triangles(pts)
    on_sphere = map_points(surfels, pts)      # checked once for the figures
    if faces is not None:
        folded, total = inverted(on_sphere, faces), len(faces)
    else:
        folded, total = _count_folds(surfels, tri)
    ad = _area_distortion(surfels.positions, on_sphere, tri)
    sparse = _sparse_sampling(on_sphere, tri)
    st = float("nan")
    if stress:
        if lm is None:
            from .mds import geodesics

            lm, dist = geodesics(surfels, min(landmarks, len(surfels)), seed)
        st = landmark_stress(pts, lm, dist)
    report(progress, "figures", 1, 1)
    return SphericalMap(pts, method, folded, total, st, ad, seconds, tuple(stages), sparse)
