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
    geodesic_resolution : float
        Final segment length of a refined path on a mesh, as a fraction of the local surfel
        spacing (the mean graph link over the sphere scale).
    geodesic_sheet_rings : int
        A refined path on a mesh has jumped to another sheet when the nearest vertices of two
        consecutive points are more than this many mesh rings apart.
    """

    unit_normal: float = 1e-3
    degenerate_area: float = 1e-12
    reconstruction: float = 1e-10
    psnr_agreement: float = 0.5
    geodesic_refine: float = 1e-6
    geodesic_resolution: float = 0.25
    geodesic_sheet_rings: int = 10


TOL = Tolerances()
