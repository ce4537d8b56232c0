"""Public names of :mod:`surfidx.io` (imported on first use, see ``__init__.py``)."""

from .registry import (SUPPORTED_SUFFIXES as SUPPORTED_SUFFIXES, MESH_SUFFIXES as MESH_SUFFIXES,
                       POINT_SUFFIXES as POINT_SUFFIXES, OUTPUT_FORMATS as OUTPUT_FORMATS,
                       up_axis as up_axis)
from .limits import (MAX_TEXTURE_PIXELS as MAX_TEXTURE_PIXELS, MAX_COORDINATE as MAX_COORDINATE,
                     MAX_TEXT_BYTES as MAX_TEXT_BYTES)
from .limits import MAX_LAZ_POINTS_PER_BYTE as MAX_LAZ_POINTS_PER_BYTE
from .reading import (read_surfels as read_surfels, read_mesh as read_mesh,
                      read_geometry as read_geometry, as_surfels as as_surfels,
                      model_hash as model_hash)
from .ply import write_ply as write_ply
from .writing import write_model as write_model, output_format as output_format
from .atomic import write_atomic as write_atomic
from .texture import (read_texture as read_texture, encode_image as encode_image,
                      check_image_options as check_image_options)
from .files import (find_texture as find_texture, pair_texture as pair_texture,
                    NotRegularFile as NotRegularFile)
from .originals import original_files as original_files
