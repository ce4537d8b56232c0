"""Public names of :mod:`surfidx.geometry` (imported on first use, see ``__init__.py``)."""

from .surfels import SurfelSet as SurfelSet
from .mesh import TriangleMesh as TriangleMesh
from .simplify import (simplify_mesh as simplify_mesh,
                       check_max_vertices as check_max_vertices)
from .pointcloud import points_to_surfels as points_to_surfels
from .axes import (UP_AXES as UP_AXES, MESH_UP as MESH_UP, SCANNER_UP as SCANNER_UP,
                   check_up as check_up, up_rotation as up_rotation)
from .graph import (SphereOfInfluenceGraph as SphereOfInfluenceGraph,
                    sphere_of_influence_graph as sphere_of_influence_graph)
from .geodesics import (GeodesicSolver as GeodesicSolver, GeodesicPath as GeodesicPath,
                        geodesic_distances as geodesic_distances, geodesic_path as geodesic_path,
                        farthest_point_landmarks as farthest_point_landmarks)
from .icosphere import (Icosphere as Icosphere, choose_level as choose_level,
                        vertex_count as vertex_count)
from .metrics import (evaluate as evaluate, psnr_d1 as psnr_d1, psnr_d2 as psnr_d2,
                      psnr_luma as psnr_luma, psnr_luma_surface as psnr_luma_surface,
                      hausdorff as hausdorff, Reference as Reference)
from .atlas import (GridAtlas as GridAtlas, grid_atlas as grid_atlas,
                    grid_face_index as grid_face_index, locate_on_grid as locate_on_grid,
                    GridColor as GridColor, bake_texture as bake_texture,
                    atlas_uv_faces as atlas_uv_faces,
                    default_texture_size as default_texture_size,
                    check_texture_size as check_texture_size)
