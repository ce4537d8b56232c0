"""Public names of :mod:`surfidx.geometry` (imported on first use, see ``__init__.py``)."""

from .surfels import SurfelSet
from .mesh import TriangleMesh
from .pointcloud import points_to_surfels
from .graph import SphereOfInfluenceGraph, sphere_of_influence_graph
from .geodesics import (GeodesicSolver, GeodesicPath, geodesic_distances, geodesic_path,
                        farthest_point_landmarks)
from .icosphere import Icosphere, choose_level, vertex_count
from .metrics import evaluate, psnr_d1, psnr_d2, psnr_luma, hausdorff, Reference
