"""Public names of :mod:`surfidx` (imported on first use, see ``__init__.py``)."""

from .errors import (SurfidxError as SurfidxError, InputError as InputError,
                     FileFormatError as FileFormatError, TopologyError as TopologyError,
                     BitstreamError as BitstreamError, DatabaseError as DatabaseError)
from .tolerance import TOL as TOL, Tolerances as Tolerances
from .numerics import numerics_profile as numerics_profile
from .geometry.surfels import SurfelSet as SurfelSet
from .geometry.mesh import TriangleMesh as TriangleMesh
from .geometry.pointcloud import points_to_surfels as points_to_surfels
from .geometry.icosphere import Icosphere as Icosphere, choose_level as choose_level
from .geometry.graph import SphereOfInfluenceGraph as SphereOfInfluenceGraph
from .geometry.geodesics import (GeodesicSolver as GeodesicSolver, GeodesicPath as GeodesicPath,
                                 geodesic_distances as geodesic_distances,
                                 geodesic_path as geodesic_path,
                                 farthest_point_landmarks as farthest_point_landmarks)
from .geometry.metrics import (evaluate as evaluate, psnr_d1 as psnr_d1, psnr_d2 as psnr_d2,
                               psnr_luma as psnr_luma, psnr_luma_surface as psnr_luma_surface,
                               hausdorff as hausdorff)
from .io import (read_surfels as read_surfels, read_mesh as read_mesh,
                 write_ply as write_ply, write_model as write_model, as_surfels as as_surfels)
from .topology import (RepairOptions as RepairOptions, Model as Model, join_surfels as join_surfels,
                       repair_model as repair_model, read_model as read_model)
from .sphere import (MapOptions as MapOptions, parameterize as parameterize,
                     SphericalMap as SphericalMap)
from .codec import Encoder as Encoder, encode as encode, decode as decode
from .codec.klt import KLT as KLT
from .describe import describe_grid as describe_grid, DescriptorSet as DescriptorSet
from .codec.options import CodecOptions as CodecOptions
from .describe.options import DescribeOptions as DescribeOptions
from .options import ProcessOptions as ProcessOptions
from .pipeline import (process_model as process_model, describe_model as describe_model,
                       ProcessedModel as ProcessedModel)
from .database import Database as Database, QueryExample as QueryExample
from .db import SearchIndex as SearchIndex

__version__: str
