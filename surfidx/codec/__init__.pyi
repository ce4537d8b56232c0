"""Public names of :mod:`surfidx.codec` (imported on first use, see ``__init__.py``)."""

from .encoder import (Encoder as Encoder, encode as encode, decode as decode,
                      decode_grid as decode_grid, read_sfz as read_sfz,
                      COLOR_WEIGHT as COLOR_WEIGHT, TANGENT_WEIGHT as TANGENT_WEIGHT,
                      CODEC_VERSION as CODEC_VERSION, MAP_METHODS as MAP_METHODS,
                      MAX_SURFELS as MAX_SURFELS,
                      MAX_EXTENT as MAX_EXTENT, MAX_COLOR_WEIGHT as MAX_COLOR_WEIGHT,
                      MAX_COEFFICIENT as MAX_COEFFICIENT, check_header as check_header,
                      PartsEncoder as PartsEncoder, encode_parts as encode_parts,
                      decode_parts as decode_parts, stream_summary as stream_summary,
                      read_level as read_level, output_levels as output_levels,
                      level_hints as level_hints)
from .container import max_file_bytes as max_file_bytes
from .options import CodecOptions as CodecOptions
from .options import COLOR_IMPORTANCE as COLOR_IMPORTANCE
from .colorgrid import TextureSource as TextureSource
from .encoder import Prepared as Prepared, prepare as prepare, code as code
from .encoder import with_level_hints as with_level_hints
