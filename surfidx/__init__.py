"""surfidx: a database for textured 3D scans represented as surfels.

Data flow: files -> :class:`SurfelSet` -> spheres-of-influence graph and geodesics -> spherical
parameterization -> icosahedral resampling -> KLT + lifted butterfly wavelets -> zerotree and
arithmetic coding -> container; descriptors from the same spherical representation; SQLite store.
"""

from ._numerics import use_portable_profile

use_portable_profile()   # before numpy loads: the same kernels, so the same bytes, on every machine

from ._jitcache import use_user_cache  # noqa: E402

use_user_cache()   # before any kernel is compiled: numba's cache stays out of the package

from ._errors import (BitstreamError, DatabaseError, FileFormatError, InputError,  # noqa: E402
                      SurfidxError, TopologyError)
from ._tolerance import TOL, Tolerances  # noqa: E402

__version__ = "0.1.0"

__all__ = [
    "SurfelSet", "TriangleMesh", "read_surfels", "read_mesh", "write_ply", "points_to_surfels",
    "SurfidxError", "InputError", "FileFormatError", "TopologyError", "BitstreamError",
    "DatabaseError", "TOL", "Tolerances", "__version__", "numerics_profile",
    "evaluate", "psnr_d1", "psnr_d2", "psnr_luma", "hausdorff",
    "Icosphere", "choose_level", "KLT",
    "GeodesicSolver", "GeodesicPath", "geodesic_distances", "geodesic_path",
    "farthest_point_landmarks", "SphereOfInfluenceGraph",
]

# Everything else is imported on first use: numba, scipy and sqlite-utils cost seconds to
# import, which a query of a stored model (`surfidx query id:N`) does not need. No export is
# named as a submodule: importing the submodule would replace the export by the module
# (the grid function is `surfidx.Icosphere(level)` or `surfidx.icosphere.icosphere(level)`).
_LAZY = {"numerics_profile": "_numerics",
         "GeodesicPath": "geodesics", "GeodesicSolver": "geodesics",
         "farthest_point_landmarks": "geodesics", "geodesic_distances": "geodesics",
         "geodesic_path": "geodesics", "SphereOfInfluenceGraph": "graph",
         "Icosphere": "icosphere", "choose_level": "icosphere",
         "read_mesh": "io", "read_surfels": "io", "write_ply": "io", "KLT": "klt",
         "TriangleMesh": "mesh", "evaluate": "metrics", "hausdorff": "metrics",
         "psnr_d1": "metrics", "psnr_d2": "metrics", "psnr_luma": "metrics",
         "points_to_surfels": "pointcloud", "SurfelSet": "surfels",
         "as_surfels": "io", "write_model": "io", "read_model": "io", "Model": "io",
         "join_surfels": "io",
         "Database": "store", "SearchIndex": "search"}
__all__ += [n for n in _LAZY if n not in __all__]


def __getattr__(name):
    if name in _LAZY:
        import importlib

        value = getattr(importlib.import_module(f".{_LAZY[name]}", __name__), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__():
    return sorted(set(globals()) | set(_LAZY))
