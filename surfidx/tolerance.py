"""The one tolerance object of surfidx: every numeric threshold used for validation and tests."""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["Tolerances", "TOL"]


@dataclass(frozen=True)
class Tolerances:
    """Numeric tolerances, in one place.

    Attributes
    ----------
    unit_normal : float
        Largest allowed ``| |n| - 1 |`` of a normal given to :class:`~surfidx.SurfelSet`
        (normals are renormalised after the check).
    degenerate_area : float
        Triangles whose area is below this fraction of the mean triangle area count as degenerate.
    reconstruction : float
        Largest absolute error of a perfect-reconstruction transform (lifting, KLT).
    psnr_agreement : float
        dB within which two implementations of the same distortion measure must agree.
    geodesic_refine : float
        Geodesic path refinement stops a level when one sweep shortens the path by less than this
        fraction of its length.
    geodesic_shorten : float
        The shortening of a refined path on a mesh stops when no crossing point moves more than
        this fraction of the path length in a sweep.
    geodesic_steiner : int
        Steiner points per mesh edge for refined paths on a mesh: more points bring a path closer
        to the exact geodesic at a cost growing with their number.
    geodesic_corridor : float
        Half-width of the corridor of triangles searched for a refined path on a mesh, as a
        fraction of the mesh-edge path length (plus two of its longest edges): wide enough to
        hold the true path where the mesh-edge path strays from it.
    degenerate_angle : float
        Angles (radians) below this count as degenerate: cotangent weights are clipped at
        ``±1/degenerate_angle`` so sliver triangles of a squeezed map keep a finite Laplacian.
    sphere_cover : float
        Largest relative deviation from 4π of the summed spherical areas of a mesh's mapped faces
        (all counter-clockwise) for them to count as covering the sphere once.
    inverted_area : float
        Largest share of the sphere that the faces a map turns over may cover for resampling to
        interpolate in the mesh's faces rather than in the Delaunay triangles of the mapped
        surfels (a map given to the codec from elsewhere; the default map turns none over).
    """

    unit_normal: float = 1e-3
    degenerate_area: float = 1e-12
    reconstruction: float = 1e-10
    psnr_agreement: float = 0.5
    geodesic_refine: float = 1e-6
    geodesic_shorten: float = 1e-10
    geodesic_steiner: int = 5
    geodesic_corridor: float = 0.1
    degenerate_angle: float = 1e-4
    sphere_cover: float = 1e-6
    inverted_area: float = 0.01


TOL = Tolerances()
"""The tolerances every check of the library uses (one :class:`Tolerances`)."""
