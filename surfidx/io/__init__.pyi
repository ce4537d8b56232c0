"""Public names of :mod:`surfidx.io` (imported on first use, see ``__init__.py``)."""

from .registry import SUPPORTED_SUFFIXES, MESH_SUFFIXES, POINT_SUFFIXES, OUTPUT_FORMATS
from .limits import MAX_TEXTURE_PIXELS, MAX_COORDINATE, MAX_TEXT_BYTES
from .reading import read_surfels, read_mesh, read_geometry, as_surfels, model_hash
from .models import read_model, Model, join_surfels
from .ply import write_ply
from .writing import write_model, output_format
from .atomic import write_atomic
from .texture import read_texture
