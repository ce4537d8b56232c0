"""Public names of :mod:`surfidx` (imported on first use, see ``__init__.py``)."""

from .errors import (SurfidxError, InputError, FileFormatError, TopologyError, BitstreamError,
                     DatabaseError)
from .tolerance import TOL, Tolerances
from .numerics import numerics_profile
from .geometry.surfels import SurfelSet
from .geometry.mesh import TriangleMesh
from .geometry.pointcloud import points_to_surfels
from .geometry.icosphere import Icosphere, choose_level
from .geometry.graph import SphereOfInfluenceGraph
from .geometry.geodesics import (GeodesicSolver, GeodesicPath, geodesic_distances, geodesic_path,
                                 farthest_point_landmarks)
from .geometry.metrics import evaluate, psnr_d1, psnr_d2, psnr_luma, hausdorff
from .io import read_surfels, read_mesh, read_model, write_ply, write_model, as_surfels
from .topology import RepairOptions, Model, join_surfels, repair_model
from .sphere import MapOptions, parameterize, SphericalMap
from .codec import Encoder, encode, decode
from .codec.klt import KLT
from .describe import describe_grid, DescriptorSet
from .codec.options import CodecOptions
from .describe.options import DescribeOptions
from .options import ProcessOptions
from .pipeline import process_model, describe_model, ProcessedModel
from .db import Database, SearchIndex

__version__: str
