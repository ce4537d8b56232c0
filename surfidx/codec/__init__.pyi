"""Public names of :mod:`surfidx.codec` (imported on first use, see ``__init__.py``)."""

from .encoder import (Encoder, encode, decode, decode_grid, read_sfz, COLOR_WEIGHT, TANGENT_WEIGHT,
                      CODEC_VERSION, MAP_METHODS, max_file_bytes, MAX_SURFELS, MAX_EXTENT,
                      MAX_COLOR_WEIGHT, MAX_COEFFICIENT, check_header, PartsEncoder, encode_parts,
                      decode_parts, stream_summary)
from .options import CodecOptions
from .encoder import Prepared, prepare, code
