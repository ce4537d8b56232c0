"""surfidx: a database for textured 3D scans represented as surfels.

Data flow: files -> :class:`SurfelSet` -> spheres-of-influence graph and geodesics -> spherical
parameterization -> icosahedral resampling -> KLT + lifted butterfly wavelets -> zerotree and
arithmetic coding -> container; descriptors from the same spherical representation; SQLite store.
"""

from ._jitcache import use_user_cache

use_user_cache()   # before any kernel is compiled: numba's cache stays out of the package

from ._errors import (BitstreamError, DatabaseError, FileFormatError, InputError,  # noqa: E402
                      SurfidxError, TopologyError)
from ._tolerance import TOL, Tolerances
from .geodesics import (GeodesicPath, GeodesicSolver, farthest_point_landmarks,
                        geodesic_distances, geodesic_path)
from .graph import SphereOfInfluenceGraph
from .icosphere import Icosphere, choose_level, icosphere
from .io import read_mesh, read_surfels, write_ply
from .klt import KLT
from .mesh import TriangleMesh
from .metrics import evaluate, hausdorff, psnr_d1, psnr_d2, psnr_luma
from .pointcloud import points_to_surfels
from .surfels import SurfelSet

__version__ = "0.1.0"

__all__ = [
    "SurfelSet", "TriangleMesh", "read_surfels", "read_mesh", "write_ply", "points_to_surfels",
    "SurfidxError", "InputError", "FileFormatError", "TopologyError", "BitstreamError",
    "DatabaseError", "TOL", "Tolerances", "__version__",
    "evaluate", "psnr_d1", "psnr_d2", "psnr_luma", "hausdorff",
    "Icosphere", "icosphere", "choose_level", "KLT",
    "GeodesicSolver", "GeodesicPath", "geodesic_distances", "geodesic_path",
    "farthest_point_landmarks", "SphereOfInfluenceGraph",
]

# The SQLite store is imported on first use (sqlite-utils costs ~0.5 s to import).
_LAZY = {"Database": "database", "SearchIndex": "search"}
__all__ += list(_LAZY)


def __getattr__(name):
    if name in _LAZY:
        import importlib

        return getattr(importlib.import_module(f".{_LAZY[name]}", __name__), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
