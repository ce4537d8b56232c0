"""The ``.sfz`` container: magic, format version, header, checksums, embedded stream.

The layout is specified in ``data_schema/bitstream.md``. Every field is little-endian. A prefix of
the embedded stream is itself a valid stream, so :func:`truncate` serves a stored asset at a lower
rate by cutting the stream and rewriting its length and checksum.
"""

from __future__ import annotations

import math
import struct
import zlib
from dataclasses import dataclass, field

import numpy as np

from ..errors import BitstreamError, InputError
from ..geometry.icosphere import MAX_LEVEL, vertex_count

__all__ = ["MAGIC", "FORMAT_VERSION", "Header", "pack", "unpack", "truncate", "header_size",
           "storable", "min_file_bytes", "max_file_bytes", "GRID_PER_BYTE", "MAX_WEIGHT", "MAX_MEAN", "MAX_PLANE",
           "pack_parts", "unpack_parts", "is_multipart", "split_budget", "parts_overhead",
           "MAX_PARTS", "MAX_REGIONS", "REGION_HOLE", "region_code", "region_cut",
           "part_surfels", "FLAG_LEVELS", "MAX_LEVEL_HINTS", "HINT_SECTION_BYTES", "HINT_GAPS",
           "hint_bytes", "hinted_level"]

MAGIC = b"\x89SFZ"
FORMAT_VERSION = 6
"""Version 6 (this one): version 5 plus an optional output-level section (flag bit 6;
:data:`HINT_SECTION_BYTES` bytes after the colour-grid section, and the fixed header's reserved
byte): the stream-prefix lengths below which a decoding without a level asked for is written on
a coarser grid (:func:`hinted_level`). A file without it is written as version 5, 4 or 3, byte
for byte as before. Version 5: version 4 plus an optional colour-grid section after the mask
(flag bit 5): the colour layers on their own finer grid and the schedule of geometry and colour bit
planes in the stream. A file without it is written as version 4 or 3, byte for byte as before.
Version 4: version 3 plus an optional virtual-region mask and region table after
the density-weight field (flag bit 4), and multi-part files (several part containers in one,
flag bit 7 of a short outer header). A file without either is written as version 3, byte for
byte (closed genus-0 single-part models keep their streams). Version 3: optional local-frame
tangent weight and density-weight field after the coder header (flag bits 2 and 3). Version 2
(still read): the same without them. Version 1 stored the basis and one weight per layer as
float32 (132 bytes more with colour)."""
READ_VERSIONS = (2, 3, 4, 5, 6)

FLAG_COLOR = 1
FLAG_LIFTED = 2
FLAG_FRAMES = 4
FLAG_WEIGHTED = 8
FLAG_MASK = 16
FLAG_COLOR_GRID = 32
FLAG_LEVELS = 64
FLAG_PARTS = 128

MAX_PARTS = 4096
"""Most parts a multi-part file may hold (each part is a complete container of at least 70
bytes)."""

MAX_LEVEL_HINTS = 4
"""Codes of an output-level section: the default output level of a prefix is at most this many
levels below the stream's."""

HINT_SECTION_BYTES = 2
"""Bytes of an output-level section besides the fixed header's reserved byte, which holds the
first code: the three gaps between successive codes, 5 bits each (0 … 30 code steps, 31: that
step and the later ones never apply). The section has a fixed size, so that a stream coded at a
rate and the same prefix of a stream coded at a higher rate have headers of one size, hence
streams of one length and bit-identical coefficients."""

HINT_GAPS = 31
"""The stored gap that stands for "this step and the later ones never apply": the gaps between
successive nonzero output-level codes are 0 … HINT_GAPS - 1."""

MAX_REGIONS = 0xFFFF
"""Most regions a virtual-region table may list."""

REGION_HOLE = 0
"""Region code of a hole of the input; side ``s`` (0 or 1) of handle cut ``k`` is
``1 + 2k + s`` (:func:`region_code`)."""

_PARTS_FIXED = struct.Struct("<4sBBH")   # magic, version, flags (FLAG_PARTS), part count


def region_code(cut: int, side: int = 0) -> int:
    """Region-table code of a hole (``cut = -1``) or of side ``side`` of handle cut ``cut``."""
    return REGION_HOLE if cut < 0 else 1 + 2 * int(cut) + int(side)


def region_cut(code: int) -> tuple[int, int]:
    """``(cut, side)`` of a region code; ``(-1, 0)`` for a hole."""
    return (-1, 0) if code == REGION_HOLE else ((int(code) - 1) // 2, (int(code) - 1) % 2)

# magic, version, flags, level, layers, n_surfels, map method, reserved, coder header length
_FIXED = struct.Struct("<4sBBBBIBBH")
_TAIL = struct.Struct("<III")  # stream length, header crc (of everything before it), stream crc
MAX_PLANE = 61
"""Highest bit plane of the format: a zerotree stream's top and final planes
(:mod:`surfidx.codec.zerotree`) and every frame anchor the header stores lie in 0 … MAX_PLANE."""

GRID_PER_BYTE = 2048
"""Grid vertices a container's bytes may claim: a level-L stream (10·4^L + 2 vertices) must be a
file of at least :func:`min_file_bytes` bytes (level 9: 1,281; level 8: 321; level 7: 81), so
that decoding costs time and memory in proportion to the file. A tiny file claiming a fine grid
is a corrupt header; the encoder's lowest rate honours the bound."""

MAX_WEIGHT = 1e20
"""The unit weights (1 / bounding-box diagonal, colour weight / 255) lie in
[1 / MAX_WEIGHT, MAX_WEIGHT]."""

MAX_MEAN = 1e12
"""Largest magnitude of a KLT mean, in weighted units (for geometry: bounding-box diagonals of
the model's centre from the origin; float64 holds no shape beyond that)."""


def min_file_bytes(level: int) -> int:
    """Smallest container, in bytes, that may hold a level-``level`` stream (see
    :data:`GRID_PER_BYTE`)."""
    return -(-vertex_count(level) // GRID_PER_BYTE)


def max_file_bytes(bits_per_surfel: float, n_surfels: int) -> int:
    """Largest file size in bytes for a rate: ``ceil(bits_per_surfel · n_surfels / 8)``."""
    if not (isinstance(bits_per_surfel, (int, float, np.floating)) and bits_per_surfel > 0
            and math.isfinite(bits_per_surfel)):
        raise InputError(f"bits_per_surfel must be a positive number, got {bits_per_surfel!r}")
    return int(math.ceil(float(bits_per_surfel) * n_surfels / 8.0 - 1e-9))


@dataclass
class Header:
    """What a decoder needs besides the stream.

    Attributes
    ----------
    n_surfels : int
        Surfels of the encoder's input (the rate denominator; also the decoder's default count).
    level : int
        Icosahedral grid level.
    color : bool
        Whether layers 3..5 of the KLT input were colour.
    lifted : bool
        Whether the wavelets used the lifting (update) step.
    map_method : int
        Code of the spherical map that produced the grid (informational).
    mean : (k,) float32
        KLT mean.
    basis : (k, k) float32
        KLT basis (rows are the principal directions).
    weights : (k,) float32
        Per-layer unit weights applied before the KLT: one value for x, y, z and one for r, g, b.
    coder : bytes
        The zerotree coder's own small header (top bit plane, step, ...).
    tangent_weight : float or None
        Local-frame wavelets of the geometry layers with this weight on the tangential components
        (:func:`surfidx.codec.wavelets.forward`); None: plain per-layer wavelets.
    weight_field : bytes
        The density-weight field (:func:`surfidx.codec.density.pack_field`); empty: unweighted.
    anchors : tuple of int
        With local frames: the bit plane of each level's frame anchor
        (:func:`surfidx.codec.wavelets.forward_anchored`), one per grid level, non-increasing.
    mask : bytes
        The virtual-region mask (:func:`surfidx.codec.mask.encode_mask` of one bit per grid
        vertex); empty: the model has no virtual patch (and the file is version 3).
    regions : tuple of int
        With a mask: the code of each connected virtual region of the grid mask, regions in the
        order of their smallest grid vertex (:func:`region_code`: a hole, or a side of a cut).
    color_level : int or None
        With colour: the grid level of the colour layers when they have their own grid (format
        version 5, flag bit 5), at least ``level``; None: colour on the geometry's grid.
    color_top : int
        With ``color_level``: the colour layers' top bit plane (-1: all zero).
    schedule : tuple of int
        With ``color_level``: the group of each bit-plane pass in stream order (0 geometry,
        1 colour; :func:`surfidx.codec.zerotree.group_schedule`).
    level_hints : tuple of int
        Output-level codes (format version 6, flag bit 6): :data:`MAX_LEVEL_HINTS` codes in
        0 … 255, non-increasing; a prefix whose container (header and stream served) is
        smaller than :func:`hint_bytes` of the ``i``-th code decodes by default at least
        ``i + 1`` levels below ``level`` (:func:`hinted_level`; code 0 never applies, 255
        always). Empty: no section, the stream's level at any rate.
    """

    n_surfels: int
    level: int
    color: bool
    lifted: bool
    mean: np.ndarray
    basis: np.ndarray
    weights: np.ndarray
    coder: bytes = b""
    map_method: int = 0
    version: int = FORMAT_VERSION
    tangent_weight: float | None = None
    weight_field: bytes = b""
    anchors: tuple = ()
    mask: bytes = b""
    regions: tuple = ()
    color_level: int | None = None
    color_top: int = -1
    schedule: tuple = ()
    level_hints: tuple = ()
    extra: dict = field(default_factory=dict)

    @property
    def layers(self) -> int:
        return 6 if self.color else 3


def _n_weights(k: int) -> int:
    return 1 if k <= 3 else 2


def header_size(layers: int, coder_bytes: int, *, frames: bool = False, anchors: int = 0,
                field_bytes: int | None = None, mask_bytes: int | None = None,
                regions: int = 0, passes: int | None = None, hints: bool = False) -> int:
    """Bytes of a container's header.

    Parameters
    ----------
    layers : int
        KLT layers (3 or 6).
    coder_bytes : int
        Size of the coder's header.
    frames : bool
        Whether the header stores local-frame parameters: a tangent weight (4 bytes), an anchor
        count (1 byte) and ``anchors`` anchor planes (1 byte each).
    anchors : int
        Number of anchor planes (the grid level).
    field_bytes : int, optional
        Size of a stored density-weight field (plus its 2-byte length); None: no field.
    mask_bytes : int, optional
        Size of a stored virtual-region mask (plus its 4-byte length, the 2-byte region count
        and 2 bytes per region); None: no mask.
    regions : int
        Entries of the region table.
    passes : int, optional
        With a colour grid: the schedule's passes (3 bytes plus one bit per pass); None: no
        colour grid.
    hints : bool
        Whether the header has an output-level section (:data:`HINT_SECTION_BYTES`).
    """
    k = layers
    extra = (5 + anchors if frames else 0) + (0 if field_bytes is None else 2 + field_bytes)
    extra += 0 if mask_bytes is None else 6 + mask_bytes + 2 * regions
    extra += 0 if passes is None else _grid_section_size(passes)
    extra += HINT_SECTION_BYTES if hints else 0
    return _FIXED.size + 4 * k + 2 * k * k + 4 * _n_weights(k) + coder_bytes + extra + _TAIL.size


def hint_bytes(code: int, n_surfels: int) -> int:
    """The container size an output-level code stands for: the bytes of a rate of
    ``2^((code - 128) / 16)`` bits per input surfel, ``ceil(n_surfels · rate / 8)`` (code 128:
    1 bit/surfel; a code step is a factor of 2^(1/16), 4.4 %; codes 1 … 254 span 0.004 … 234
    bits/surfel). Code 0 stands for 0 bytes (never applies), 255 for 2^64 (always)."""
    code = int(code)
    if code <= 0:
        return 0
    if code >= 255:
        return 2 ** 64
    return int(math.ceil(int(n_surfels) * 2.0 ** ((code - 128) / 16.0) / 8.0 - 1e-9))


def hinted_level(header: Header, file_bytes: int) -> int:
    """The grid level a prefix decodes to by default: ``header.level`` less the number of
    :attr:`Header.level_hints` whose :func:`hint_bytes` exceed ``file_bytes``, the size of the
    container served (header and stream prefix: a function of the bytes served only, so a
    truncated file decodes as the same prefix served).

    Parameters
    ----------
    header : Header
    file_bytes : int

    Returns
    -------
    int
        In ``max(0, level - len(level_hints))`` … ``level``.
    """
    below = sum(1 for c in header.level_hints
                if int(file_bytes) < hint_bytes(c, header.n_surfels))
    return max(0, int(header.level) - below)


def _grid_section_size(passes: int) -> int:
    return 3 + (int(passes) + 7) // 8


def storable(mean, basis, weights):
    """The KLT arrays rounded exactly as :func:`pack` stores them.

    ``mean`` and ``weights`` become float32, ``basis`` float16 (an orthonormal basis loses
    nothing that matters: the analysis inverts the stored basis, so coding stays exact).

    Parameters
    ----------
    mean : (k,) float64
    basis : (k, k) float64
    weights : (k,) float64
        One value for x, y, z and one for r, g, b.

    Returns
    -------
    mean, basis, weights : float64 arrays holding the stored values

    Raises
    ------
    InputError
        When the weights are not one value per group.
    """
    k = len(mean)
    w = np.asarray(weights, np.float64).reshape(k)
    if np.any(w[:3] != w[0]) or np.any(w[3:] != w[3:4]):
        raise InputError("weights must be one value for x, y, z and one for r, g, b, got "
                         f"{w.tolist()}")
    with np.errstate(over="ignore"):  # overflow gives inf, refused by pack
        return (np.asarray(mean, np.float32).astype(np.float64),
                np.asarray(basis, np.float16).astype(np.float64),
                np.asarray(w, np.float32).astype(np.float64))


def pack(header: Header, stream: bytes) -> bytes:
    """Serialise a header and an embedded stream into a container file.

    Parameters
    ----------
    header : Header
    stream : bytes

    Returns
    -------
    bytes
    """
    k = header.layers
    mean, basis, weights = storable(np.reshape(header.mean, k), np.reshape(header.basis, (k, k)),
                                    np.reshape(header.weights, k))
    mean = mean.astype("<f4")
    basis = basis.astype("<f2")
    weights = weights[[0, 3][:_n_weights(k)]].astype("<f4")
    if not (np.all(np.isfinite(basis)) and np.all(np.isfinite(mean))
            and np.all(np.isfinite(weights))):
        raise InputError("the KLT mean, basis and weights must be finite in float32/float16")
    if not (0 <= header.level <= MAX_LEVEL):
        raise InputError(f"grid level must be 0..{MAX_LEVEL}, got {header.level}")
    if not (0 < header.n_surfels < 2 ** 32):
        raise InputError(f"n_surfels must be 1..2^32-1, got {header.n_surfels}")
    problem = _implausible(mean, weights, k)
    if problem:
        raise InputError(f"the KLT values cannot be stored: {problem}")
    flags = (FLAG_COLOR if header.color else 0) | (FLAG_LIFTED if header.lifted else 0)
    reserved = 0
    if len(header.coder) > 0xFFFF:
        raise InputError("coder header longer than 65535 bytes")
    extra = b""
    if header.tangent_weight is not None:
        tw = np.float32(header.tangent_weight)
        if not (0 < tw <= 1):
            raise InputError(f"tangent_weight must be in (0, 1], got {header.tangent_weight!r}")
        anchors = [int(a) for a in header.anchors]
        if len(anchors) > 255 or any(not 0 <= a <= MAX_PLANE for a in anchors):
            raise InputError(f"frame anchors must be at most 255 planes in 0..{MAX_PLANE}, got "
                             f"{anchors}")
        flags |= FLAG_FRAMES
        extra += tw.astype("<f4").tobytes() + bytes([len(anchors)]) + bytes(anchors)
    if header.weight_field:
        if len(header.weight_field) > 0xFFFF:
            raise InputError("density-weight field longer than 65535 bytes")
        flags |= FLAG_WEIGHTED
        extra += struct.pack("<H", len(header.weight_field)) + bytes(header.weight_field)
    version = 3
    if header.mask:
        regions = [int(r) for r in header.regions]
        if not regions or len(regions) > MAX_REGIONS or any(not 0 <= r <= 0xFFFF
                                                            for r in regions):
            raise InputError(f"a virtual-region mask needs a region table of 1..{MAX_REGIONS} "
                             f"codes in 0..65535, got {len(regions)} codes")
        if len(header.mask) >= 2 ** 32:
            raise InputError("virtual-region mask longer than 2^32 - 1 bytes")
        flags |= FLAG_MASK
        version = 4
        extra += (struct.pack("<I", len(header.mask)) + bytes(header.mask)
                  + struct.pack(f"<H{len(regions)}H", len(regions), *regions))
    smallest = min_file_bytes(header.level)
    if header.color_level is not None:
        order = [int(g) for g in header.schedule]
        if not (header.color and header.level <= header.color_level <= MAX_LEVEL):
            raise InputError(f"a colour grid needs colour and a level in {header.level}.."
                             f"{MAX_LEVEL}, got {header.color_level!r}")
        if len(order) > 255 or any(g not in (0, 1) for g in order) or not (
                -1 <= header.color_top <= MAX_PLANE):
            raise InputError(f"a colour grid's schedule is at most 255 passes of group 0 or 1 "
                             f"and its top plane in -1..{MAX_PLANE}, got {len(order)} passes, "
                             f"top {header.color_top}")
        flags |= FLAG_COLOR_GRID
        version = 5
        bits = np.packbits(np.asarray(order, np.uint8), bitorder="little").tobytes() \
            if order else b""
        extra += struct.pack("<BbB", header.color_level, header.color_top, len(order)) + bits
        smallest = min_file_bytes(header.color_level)
    if header.level_hints:
        hints = [int(c) for c in header.level_hints]
        if len(hints) != MAX_LEVEL_HINTS or any(not 0 <= c <= 255 for c in hints) or any(
                b > a or (b and a - b >= HINT_GAPS) for a, b in zip(hints, hints[1:])):
            raise InputError(f"output-level hints must be {MAX_LEVEL_HINTS} non-increasing "
                             f"codes in 0..255, each nonzero one less than {HINT_GAPS} below "
                             f"the one before, got {hints}")
        flags |= FLAG_LEVELS
        version = 6
        reserved = hints[0]
        gaps = [a - b if b else HINT_GAPS for a, b in zip(hints, hints[1:])]
        extra += struct.pack("<H", gaps[0] | gaps[1] << 5 | gaps[2] << 10)
    body = _FIXED.pack(MAGIC, version, flags, header.level, k, header.n_surfels,
                       header.map_method, reserved, len(header.coder))
    body += mean.tobytes() + basis.tobytes() + weights.tobytes() + bytes(header.coder) + extra
    body += struct.pack("<I", len(stream))
    if len(body) + 8 + len(stream) < smallest:
        raise InputError(f"a level-{header.level} container needs at least "
                         f"{smallest} bytes, this one would have "
                         f"{len(body) + 8 + len(stream)}; give the stream more bytes")
    return body + struct.pack("<II", zlib.crc32(body), zlib.crc32(stream)) + bytes(stream)


def _implausible(mean: np.ndarray, w: np.ndarray, k: int) -> str:
    """What is absurd about stored KLT values (see :data:`MAX_WEIGHT`, :data:`MAX_MEAN`), or ''.

    ``w`` holds the stored weights (one per group).
    """
    if not np.all((w >= 1.0 / MAX_WEIGHT) & (w <= MAX_WEIGHT)):
        return (f"unit weights {np.asarray(w, np.float64).tolist()} outside "
                f"[{1 / MAX_WEIGHT:g}, {MAX_WEIGHT:g}]")
    if not np.all(np.abs(mean) <= MAX_MEAN):
        return f"KLT mean {np.asarray(mean, np.float64).tolist()} beyond ±{MAX_MEAN:g}"
    return ""


def unpack(data: bytes, *, path=None) -> tuple[Header, bytes]:
    """Parse and verify a container.

    Parameters
    ----------
    data : bytes
    path : str, optional
        File name for error messages.

    Returns
    -------
    header : Header
    stream : bytes

    Raises
    ------
    BitstreamError
        Foreign file (bad magic), unknown version, truncated header or stream, checksum mismatch,
        an empty mask section; a multi-part file (read its parts with :func:`unpack_parts`).
    """
    data = bytes(data)
    if len(data) < _FIXED.size:
        if len(data) >= 4 and data[:4] == MAGIC:
            raise BitstreamError(f"truncated header ({len(data)} bytes)", path=path)
        raise BitstreamError("not a surfidx .sfz file (too short)", path=path)
    magic, version, flags, level, k, n, method, reserved, clen = _FIXED.unpack_from(data, 0)
    _check_magic_version(magic, version, path)
    if version >= 4 and flags & FLAG_PARTS:
        raise BitstreamError(f"a multi-part file ({struct.unpack_from('<H', data, 6)[0]} parts): "
                             "read it with surfidx.codec.container.unpack_parts or "
                             "surfidx.codec.decode", path=path)
    if k not in (3, 6):
        raise BitstreamError(f"corrupt header (layer count {k}, expected 3 or 6)", path=path)
    if level > MAX_LEVEL:
        raise BitstreamError(f"corrupt header (grid level {level}; format version {version} "
                             f"allows 0 … {MAX_LEVEL})", path=path)
    known = {2: FLAG_COLOR | FLAG_LIFTED, 3: FLAG_COLOR | FLAG_LIFTED | FLAG_FRAMES
             | FLAG_WEIGHTED, 4: FLAG_COLOR | FLAG_LIFTED | FLAG_FRAMES | FLAG_WEIGHTED
             | FLAG_MASK}.get(version, FLAG_COLOR | FLAG_LIFTED | FLAG_FRAMES | FLAG_WEIGHTED
                              | FLAG_MASK | FLAG_COLOR_GRID
                              | (FLAG_LEVELS if version >= 6 else 0))
    if version < 5 and flags & (FLAG_FRAMES | FLAG_WEIGHTED | FLAG_MASK | FLAG_COLOR_GRID) \
            & ~known:
        raise BitstreamError(f"corrupt header (flags {flags:#04x} unknown to version {version})",
                             path=path)
    nw = _n_weights(k)
    coder_end = _FIXED.size + 4 * k + 2 * k * k + 4 * nw + clen
    tail_off = coder_end
    n_anchors = 0
    if flags & FLAG_FRAMES:
        if len(data) >= coder_end + 5:
            n_anchors = data[coder_end + 4]
        tail_off += 5 + n_anchors
    field_len = 0
    field_off = tail_off + 2
    if flags & FLAG_WEIGHTED:
        if len(data) >= tail_off + 2:
            field_len = struct.unpack_from("<H", data, tail_off)[0]
        tail_off += 2 + field_len
    mask_off = mask_len = n_regions = 0
    if flags & FLAG_MASK:
        if len(data) >= tail_off + 4:
            mask_len = struct.unpack_from("<I", data, tail_off)[0]
        mask_off = tail_off + 4
        if len(data) >= mask_off + mask_len + 2:
            n_regions = struct.unpack_from("<H", data, mask_off + mask_len)[0]
        tail_off = mask_off + mask_len + 2 + 2 * n_regions
    grid_off = tail_off
    color_level, color_top, n_passes = None, -1, 0
    if flags & FLAG_COLOR_GRID:
        if len(data) >= grid_off + 3:
            color_level, color_top, n_passes = struct.unpack_from("<BbB", data, grid_off)
        tail_off = grid_off + _grid_section_size(n_passes)
    hints_off = tail_off
    hinted = bool(flags & FLAG_LEVELS) and version >= 6   # an unknown flag before version 6
    if hinted:
        tail_off = hints_off + HINT_SECTION_BYTES
    if len(data) < tail_off + _TAIL.size:
        raise BitstreamError(f"truncated header ({len(data)} of {tail_off + _TAIL.size} bytes)",
                             path=path)
    if len(data) < min_file_bytes(level):
        raise BitstreamError(f"corrupt header (grid level {level} in a file of {len(data)} "
                             f"bytes; that grid needs at least {min_file_bytes(level)})",
                             path=path)
    if color_level is not None and not (level <= color_level <= MAX_LEVEL
                                        and len(data) >= min_file_bytes(color_level)):
        raise BitstreamError(f"corrupt header (colour grid level {color_level} for grid level "
                             f"{level} in a file of {len(data)} bytes)", path=path)
    s_len, hcrc, scrc = _TAIL.unpack_from(data, tail_off)
    if zlib.crc32(data[:tail_off + 4]) != hcrc:
        raise BitstreamError("header checksum mismatch: the file is damaged", path=path)
    if flags & ~known:
        raise BitstreamError(f"corrupt header (unknown flags {flags:#04x})", path=path)
    if flags & FLAG_WEIGHTED and field_len == 0:
        raise BitstreamError("corrupt header (empty density-weight field)", path=path)
    if flags & FLAG_MASK and (mask_len == 0 or n_regions == 0):
        raise BitstreamError(f"corrupt header (virtual-region mask of {mask_len} bytes with "
                             f"{n_regions} regions; both must be > 0)", path=path)
    if flags & FLAG_COLOR_GRID and not (flags & FLAG_COLOR and -1 <= color_top <= MAX_PLANE):
        raise BitstreamError(f"corrupt header (colour grid without colour, or colour top plane "
                             f"{color_top})", path=path)
    if (k == 6) != bool(flags & FLAG_COLOR):
        raise BitstreamError("corrupt header (inconsistent layer count, flags or level)",
                             path=path)
    level_hints = ()
    if hinted:
        packed = struct.unpack_from("<H", data, hints_off)[0]
        codes = [reserved]
        for gap in (packed & 31, packed >> 5 & 31, packed >> 10 & 31):
            codes.append(0 if gap == HINT_GAPS or codes[-1] == 0 else codes[-1] - gap)
        level_hints = tuple(codes)
    if min(level_hints, default=0) < 0 or (hinted and packed >> 15):
        raise BitstreamError(f"corrupt header (output-level hints {list(level_hints)})",
                             path=path)
    stream = data[tail_off + _TAIL.size:]
    if len(stream) < s_len:
        raise BitstreamError(f"truncated stream ({len(stream)} of {s_len} bytes); to lower the "
                             "rate, truncate the complete file with surfidx instead of cutting "
                             "it", path=path)
    if len(stream) > s_len:
        raise BitstreamError(f"{len(stream) - s_len} unexpected bytes after the stream", path=path)
    if zlib.crc32(stream) != scrc:
        raise BitstreamError("stream checksum mismatch: the file is damaged", path=path)
    off = _FIXED.size
    mean = np.frombuffer(data, "<f4", k, off).astype(np.float32)
    basis = np.frombuffer(data, "<f2", k * k, off + 4 * k).astype(np.float32).reshape(k, k)
    w = np.frombuffer(data, "<f4", nw, off + 4 * k + 2 * k * k).astype(np.float32)
    if not (np.all(np.isfinite(mean)) and np.all(np.isfinite(basis)) and np.all(np.isfinite(w))):
        raise BitstreamError("corrupt header (non-finite KLT values)", path=path)
    if n == 0:
        raise BitstreamError("corrupt header (0 input surfels)", path=path)
    problem = _implausible(mean, w, k)
    if not problem and not np.all(np.abs(basis) <= 1):
        problem = "KLT basis entries beyond ±1 (the basis is orthonormal)"
    if problem:
        raise BitstreamError(f"corrupt header ({problem})", path=path)
    weights = np.repeat(w, 3)
    tangent_weight, anchors = None, ()
    if flags & FLAG_FRAMES:
        tangent_weight = float(np.frombuffer(data, "<f4", 1, coder_end)[0])
        if not (0 < tangent_weight <= 1):
            raise BitstreamError(f"corrupt header (tangent weight {tangent_weight!r})", path=path)
        anchors = tuple(int(a) for a in data[coder_end + 5:coder_end + 5 + n_anchors])
        if any(a > MAX_PLANE for a in anchors):
            raise BitstreamError(f"corrupt header (frame anchors {list(anchors)})", path=path)
    mask, regions = b"", ()
    if flags & FLAG_MASK:
        mask = bytes(data[mask_off:mask_off + mask_len])
        regions = struct.unpack_from(f"<{n_regions}H", data, mask_off + mask_len + 2)
    schedule = ()
    if flags & FLAG_COLOR_GRID:
        raw = np.frombuffer(data, np.uint8, (n_passes + 7) // 8, grid_off + 3)
        schedule = tuple(int(b) for b in np.unpackbits(raw, bitorder="little")[:n_passes])
    header = Header(
        color_level=color_level, color_top=color_top, schedule=schedule,
        level_hints=tuple(int(c) for c in level_hints), mask=mask,
        regions=tuple(int(r) for r in regions),
        n_surfels=n, level=level, color=bool(flags & FLAG_COLOR), lifted=bool(flags & FLAG_LIFTED),
        mean=mean, basis=basis, weights=weights, coder=bytes(data[coder_end - clen:coder_end]),
        map_method=method, version=version, tangent_weight=tangent_weight, anchors=anchors,
        weight_field=bytes(data[field_off:field_off + field_len]) if field_len else b"")
    return header, stream


def truncate(data: bytes, max_bytes: int, *, path=None) -> bytes:
    """Cut a container's embedded stream so that the whole file is at most ``max_bytes``.

    A multi-part file is cut part by part, the budget split as :func:`split_budget` says (the
    split the encoder used), so each part keeps a prefix of its stream.

    Parameters
    ----------
    data : bytes
        A complete container.
    max_bytes : int
        Byte budget of the result (header included).

    Returns
    -------
    bytes
        A valid container whose stream is a prefix of the original.

    Raises
    ------
    InputError
        When the budget does not even hold the header.
    """
    if is_multipart(data):
        parts = unpack_parts(data, path=path)
        total = sum(len(p) for p in parts) + parts_overhead(len(parts))
        if max_bytes >= total:
            return bytes(data)
        budgets = split_budget(max_bytes, [part_surfels(p, path=path) for p in parts])
        cut = []
        for i, (p, b) in enumerate(zip(parts, budgets)):
            try:
                cut.append(truncate(p, b, path=path))
            except InputError as exc:
                raise InputError(f"part {i} of {len(parts)}: {exc.reason}", path=path) from None
        return pack_parts(cut)
    header, stream = unpack(data, path=path)
    hsize = len(data) - len(stream)
    finest = header.level if header.color_level is None else header.color_level
    if max_bytes < max(hsize, min_file_bytes(finest)):
        raise InputError(f"a budget of {max_bytes} bytes does not hold the {hsize}-byte header "
                         f"(or the {min_file_bytes(finest)} bytes a level-{finest} "
                         "container needs); ask for a higher rate")
    if max_bytes >= len(data):
        return bytes(data)
    return pack(header, stream[: max_bytes - hsize])


def _check_magic_version(magic, version, path):
    if magic != MAGIC:
        raise BitstreamError("not a surfidx .sfz file (bad magic number)", path=path)
    if version not in READ_VERSIONS:
        raise BitstreamError(f"unsupported format version {version} (this surfidx reads "
                             f"versions {', '.join(map(str, READ_VERSIONS))}); upgrade surfidx",
                             path=path)


def is_multipart(data: bytes) -> bool:
    """Whether ``data`` starts like a multi-part container (version 4, flag bit 7)."""
    return len(data) >= 6 and bytes(data[:4]) == MAGIC and data[4] >= 4 and bool(
        data[5] & FLAG_PARTS)


def parts_overhead(parts: int) -> int:
    """Bytes of a multi-part file's outer header: 8 fixed, 4 per part length, a 4-byte CRC."""
    return _PARTS_FIXED.size + 4 * parts + 4


def split_budget(max_bytes: int, n_surfels) -> list:
    """Bytes of each part of a multi-part file of at most ``max_bytes`` bytes.

    The bytes left after the outer header (:func:`parts_overhead`) are split in proportion to
    the parts' input surfels: part ``i`` gets ``floor(rest · n_i / N)`` bytes, and the bytes
    this rounding leaves go one each to the first parts. Encoder and :func:`truncate` split
    alike, so a lower rate of a multi-part file is a prefix of each part's stream.

    Parameters
    ----------
    max_bytes : int
    n_surfels : sequence of int
        Input surfels of each part (all > 0).

    Returns
    -------
    list of int
    """
    n = [int(x) for x in n_surfels]
    total = sum(n)
    rest = max(int(max_bytes) - parts_overhead(len(n)), 0)
    out = [rest * x // total for x in n]
    for i in range(rest - sum(out)):
        out[i % len(n)] += 1
    return out


def pack_parts(parts) -> bytes:
    """Several complete part containers in one multi-part file (format version 4).

    Parameters
    ----------
    parts : sequence of bytes
        At least two complete single-part containers.

    Returns
    -------
    bytes
        Magic, version 4, flags ``FLAG_PARTS``, u16 part count ``P``, ``P`` u32 part lengths,
        the CRC-32 of those bytes, then the parts.

    Raises
    ------
    InputError
        Fewer than two or more than :data:`MAX_PARTS` parts.
    """
    parts = [bytes(p) for p in parts]
    if not 2 <= len(parts) <= MAX_PARTS:
        raise InputError(f"a multi-part file holds 2..{MAX_PARTS} parts, got {len(parts)}; "
                         "a single part is a plain container")
    head = _PARTS_FIXED.pack(MAGIC, 4, FLAG_PARTS, len(parts))
    head += struct.pack(f"<{len(parts)}I", *(len(p) for p in parts))
    return head + struct.pack("<I", zlib.crc32(head)) + b"".join(parts)


def unpack_parts(data: bytes, *, path=None) -> list:
    """The part containers of a file: the parts of a multi-part file, or ``[data]``.

    Only the outer header is checked here (the parts are checked when they are unpacked).

    Parameters
    ----------
    data : bytes
    path : str, optional

    Returns
    -------
    list of bytes

    Raises
    ------
    BitstreamError
        Naming ``path``: a part count outside 2 … :data:`MAX_PARTS` or more than the file can
        hold, a damaged outer header, part lengths that do not add up to the file.
    """
    data = bytes(data)
    if not is_multipart(data):
        return [data]
    if len(data) < _PARTS_FIXED.size:
        raise BitstreamError(f"truncated multi-part header ({len(data)} bytes)", path=path)
    magic, version, flags, count = _PARTS_FIXED.unpack_from(data, 0)
    _check_magic_version(magic, version, path)
    if flags != FLAG_PARTS:
        raise BitstreamError(f"corrupt multi-part header (flags {flags:#04x}, expected "
                             f"{FLAG_PARTS:#04x})", path=path)
    # every part is a container of at least the smallest header: bound the count by the file
    smallest = _FIXED.size + _TAIL.size
    if not 2 <= count <= MAX_PARTS or parts_overhead(count) + count * smallest > len(data):
        raise BitstreamError(f"corrupt multi-part header ({count} parts in a file of "
                             f"{len(data)} bytes; expected 2..{MAX_PARTS} parts of at least "
                             f"{smallest} bytes each)", path=path)
    end = parts_overhead(count)
    lengths = struct.unpack_from(f"<{count}I", data, _PARTS_FIXED.size)
    crc = struct.unpack_from("<I", data, end - 4)[0]
    if zlib.crc32(data[:end - 4]) != crc:
        raise BitstreamError("multi-part header checksum mismatch: the file is damaged",
                             path=path)
    if end + sum(lengths) != len(data):
        what = "truncated" if end + sum(lengths) > len(data) else "unexpected bytes after"
        raise BitstreamError(f"multi-part file {what} its parts ({len(data)} bytes, the parts "
                             f"claim {end + sum(lengths)}); to lower the rate, truncate the "
                             "complete file with surfidx", path=path)
    out, off = [], end
    for ln in lengths:
        out.append(data[off:off + ln])
        off += ln
    return out


def part_surfels(part: bytes, *, path=None) -> int:
    """Input surfels of one part container (its header's ``n_surfels``), checked."""
    return unpack(part, path=path)[0].n_surfels
