"""The ``.sfz`` container: magic, format version, header, checksums, embedded stream.

The layout is specified in ``data_schema/bitstream.md``. Every field is little-endian. A prefix of
the embedded stream is itself a valid stream, so :func:`truncate` serves a stored asset at a lower
rate by cutting the stream and rewriting its length and checksum.
"""

from __future__ import annotations

import struct
import zlib
from dataclasses import dataclass, field

import numpy as np

from ._errors import BitstreamError, InputError
from .icosphere import vertex_count

__all__ = ["MAGIC", "FORMAT_VERSION", "Header", "pack", "unpack", "truncate", "header_size",
           "storable", "min_file_bytes", "GRID_PER_BYTE", "MAX_WEIGHT", "MAX_MEAN", "MAX_PLANE"]

MAGIC = b"\x89SFZ"
FORMAT_VERSION = 3
"""Version 3 (this one): optional local-frame tangent weight and density-weight field after the
coder header (flag bits 2 and 3). Version 2 (still read): the same without them. Version 1 stored
the basis and one weight per layer as float32 (132 bytes more with colour)."""
READ_VERSIONS = (2, 3)

FLAG_COLOR = 1
FLAG_LIFTED = 2
FLAG_FRAMES = 4
FLAG_WEIGHTED = 8

# magic, version, flags, level, layers, n_surfels, map method, reserved, coder header length
_FIXED = struct.Struct("<4sBBBBIBBH")
_TAIL = struct.Struct("<III")  # stream length, header crc (of everything before it), stream crc
MAX_PLANE = 61
"""Highest bit plane of the format: a zerotree stream's top and final planes
(:mod:`surfidx.zerotree`) and every frame anchor the header stores lie in 0 … MAX_PLANE."""

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
        (:func:`surfidx.wavelets.forward`); None: plain per-layer wavelets.
    weight_field : bytes
        The density-weight field (:func:`surfidx.density.pack_field`); empty: unweighted.
    anchors : tuple of int
        With local frames: the bit plane of each level's frame anchor
        (:func:`surfidx.wavelets.forward_anchored`), one per grid level, non-increasing.
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
    extra: dict = field(default_factory=dict)

    @property
    def layers(self) -> int:
        return 6 if self.color else 3


def _n_weights(k: int) -> int:
    return 1 if k <= 3 else 2


def header_size(layers: int, coder_bytes: int, *, frames: bool = False, anchors: int = 0,
                field_bytes: int | None = None) -> int:
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
    """
    k = layers
    extra = (5 + anchors if frames else 0) + (0 if field_bytes is None else 2 + field_bytes)
    return _FIXED.size + 4 * k + 2 * k * k + 4 * _n_weights(k) + coder_bytes + extra + _TAIL.size


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
    if not (0 <= header.level <= 12):
        raise InputError(f"grid level must be 0..12, got {header.level}")
    if not (0 < header.n_surfels < 2 ** 32):
        raise InputError(f"n_surfels must be 1..2^32-1, got {header.n_surfels}")
    problem = _implausible(mean, weights, k)
    if problem:
        raise InputError(f"the KLT values cannot be stored: {problem}")
    flags = (FLAG_COLOR if header.color else 0) | (FLAG_LIFTED if header.lifted else 0)
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
    body = _FIXED.pack(MAGIC, FORMAT_VERSION, flags, header.level, k, header.n_surfels,
                       header.map_method, 0, len(header.coder))
    body += mean.tobytes() + basis.tobytes() + weights.tobytes() + bytes(header.coder) + extra
    body += struct.pack("<I", len(stream))
    if len(body) + 8 + len(stream) < min_file_bytes(header.level):
        raise InputError(f"a level-{header.level} container needs at least "
                         f"{min_file_bytes(header.level)} bytes, this one would have "
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
        Foreign file (bad magic), unknown version, truncated header or stream, checksum mismatch.
    """
    data = bytes(data)
    if len(data) < _FIXED.size:
        if len(data) >= 4 and data[:4] == MAGIC:
            raise BitstreamError(f"truncated header ({len(data)} bytes)", path=path)
        raise BitstreamError("not a surfidx .sfz file (too short)", path=path)
    magic, version, flags, level, k, n, method, _, clen = _FIXED.unpack_from(data, 0)
    if magic != MAGIC:
        raise BitstreamError("not a surfidx .sfz file (bad magic number)", path=path)
    if version not in READ_VERSIONS:
        raise BitstreamError(f"unsupported format version {version} (this surfidx reads "
                             f"versions {', '.join(map(str, READ_VERSIONS))}); upgrade surfidx",
                             path=path)
    if k not in (3, 6):
        raise BitstreamError(f"corrupt header (layer count {k}, expected 3 or 6)", path=path)
    if version < 3 and flags & (FLAG_FRAMES | FLAG_WEIGHTED):
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
    if flags & FLAG_WEIGHTED:
        if len(data) >= tail_off + 2:
            field_len = struct.unpack_from("<H", data, tail_off)[0]
        tail_off += 2 + field_len
    if len(data) < tail_off + _TAIL.size:
        raise BitstreamError(f"truncated header ({len(data)} of {tail_off + _TAIL.size} bytes)",
                             path=path)
    if len(data) < min_file_bytes(level):
        raise BitstreamError(f"corrupt header (grid level {level} in a file of {len(data)} "
                             f"bytes; that grid needs at least {min_file_bytes(level)})",
                             path=path)
    s_len, hcrc, scrc = _TAIL.unpack_from(data, tail_off)
    if zlib.crc32(data[:tail_off + 4]) != hcrc:
        raise BitstreamError("header checksum mismatch: the file is damaged", path=path)
    if flags & ~(FLAG_COLOR | FLAG_LIFTED | FLAG_FRAMES | FLAG_WEIGHTED):
        raise BitstreamError(f"corrupt header (unknown flags {flags:#04x})", path=path)
    if flags & FLAG_WEIGHTED and field_len == 0:
        raise BitstreamError("corrupt header (empty density-weight field)", path=path)
    if k not in (3, 6) or (k == 6) != bool(flags & FLAG_COLOR) or level > 12:
        raise BitstreamError("corrupt header (inconsistent layer count, flags or level)",
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
    header = Header(
        n_surfels=n, level=level, color=bool(flags & FLAG_COLOR), lifted=bool(flags & FLAG_LIFTED),
        mean=mean, basis=basis, weights=weights, coder=bytes(data[coder_end - clen:coder_end]),
        map_method=method, version=version, tangent_weight=tangent_weight, anchors=anchors,
        weight_field=bytes(data[tail_off - field_len:tail_off]) if field_len else b"")
    return header, stream


def truncate(data: bytes, max_bytes: int, *, path=None) -> bytes:
    """Cut a container's embedded stream so that the whole file is at most ``max_bytes``.

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
    header, stream = unpack(data, path=path)
    hsize = len(data) - len(stream)
    if max_bytes < max(hsize, min_file_bytes(header.level)):
        raise InputError(f"a budget of {max_bytes} bytes does not hold the {hsize}-byte header "
                         f"(or the {min_file_bytes(header.level)} bytes a level-{header.level} "
                         "container needs); ask for a higher rate")
    if max_bytes >= len(data):
        return bytes(data)
    return pack(header, stream[: max_bytes - hsize])
