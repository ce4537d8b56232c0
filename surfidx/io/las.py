"""LAS and LAZ (ASPRS lidar point clouds, LAZ compressed with LASzip): point clouds read
(:func:`read_las`) through laspy and its lazrs backend, the optional ``scanners`` extra.

The header, the variable-length records and the extended ones are checked against the file's
size before laspy reads anything, because laspy allocates what a header announces: a point
count, or an extended record's length, too large for the file is refused unread.
"""

from __future__ import annotations

import contextlib
import logging
import struct
import warnings
from pathlib import Path

import numpy as np

from ..errors import FileFormatError
from . import limits
from .points import Points

__all__ = ["read_las"]

#: LAS point data formats whose records hold red, green and blue.
_COLOR_FORMATS = frozenset({2, 3, 5, 7, 8, 10})
#: Bytes of a point record of each LAS point data format (a record may add extra bytes).
_RECORD_SIZES = (20, 28, 26, 34, 57, 63, 30, 36, 38, 59, 67)

#: Points decoded at a time: laspy's arrays for one chunk stay a few tens of megabytes.
_CHUNK = 1 << 20

_HEADER_MIN = 227            # the LAS 1.0-1.2 public header block
_HEADER_14 = 375             # LAS 1.4's
_VLR_HEADER = 54
_EVLR_HEADER = 60


def _laspy(path: Path, compressed: bool):
    """laspy and the errors its reading raises (lazrs's too when the points are compressed);
    a missing package is a clean error naming the extra that installs it."""
    try:
        import laspy
    except ImportError:
        raise FileFormatError("reading LAS/LAZ needs laspy; install it with "
                              "pip install 'surfidx[scanners]'", path=path) from None
    errors = (laspy.LaspyException, ValueError, OSError, EOFError)
    if compressed:
        try:
            import lazrs
        except ImportError:
            raise FileFormatError("reading LAZ needs laspy's lazrs backend; install it with "
                                  "pip install 'surfidx[scanners]'", path=path) from None
        errors += (lazrs.LazrsError,)
    return laspy, errors


def _walk_records(fh, pos: int, n: int, head: int, length: str, end: int, what: str,
                  path: Path) -> int:
    """Follow ``n`` records from byte ``pos`` (each a ``head``-byte header whose length field,
    of struct format ``length``, sits at byte 20) and return where they end; a record that
    runs past ``end`` is refused, so a count of 4 billion stops at the first one out of
    bounds."""
    for i in range(n):
        if pos + head > end:
            raise FileFormatError(f"LAS header announces {n:,} {what}; record {i} runs past "
                                  f"byte {end:,}; the file is truncated or damaged", path=path)
        fh.seek(pos + 20)
        pos += head + struct.unpack(length, fh.read(struct.calcsize(length)))[0]
    if pos > end:
        raise FileFormatError(f"LAS header announces {n:,} {what}; the last runs past byte "
                              f"{end:,}; the file is truncated or damaged", path=path)
    return pos


def _check_header(path: Path, size: int) -> tuple[int, bool, int]:
    """Check the public header, the record chain and the point count against the file's size.

    Returns
    -------
    int
        The point count the header announces.
    bool
        Whether the points are LASzip-compressed.
    int
        Whole point records after the announced ones in an uncompressed file (its waveform
        packets and extended records excepted), which laspy does not read.

    Raises
    ------
    FileFormatError
        No ``LASF`` signature, an unknown version or point data format, records shorter than
        their format, records or offsets outside the file, or more points than the bytes after
        the header can hold (a LAZ: more than :data:`~surfidx.io.limits.MAX_LAZ_RATIO` allows).
    """
    with open(path, "rb") as fh:
        head = fh.read(_HEADER_14)
        if head[:4] != b"LASF":
            raise FileFormatError("not a LAS/LAZ file (it does not start with the LASF "
                                  "signature)", path=path)
        if len(head) < _HEADER_MIN:
            raise FileFormatError(f"LAS header is truncated ({len(head)} of {_HEADER_MIN} "
                                  "bytes)", path=path)
        major, minor = head[24], head[25]
        if major != 1 or minor > 4:
            raise FileFormatError(f"LAS version {major}.{minor} is not supported (1.0 to 1.4 "
                                  "are)", path=path)
        encoding = struct.unpack_from("<H", head, 6)[0]
        header_size, offset, n_vlrs, fmt, record = struct.unpack_from("<HIIBH", head, 94)
        count = struct.unpack_from("<I", head, 107)[0]
        n_evlrs = evlr_start = 0
        if minor >= 4:
            if len(head) < _HEADER_14:
                raise FileFormatError(f"LAS 1.4 header is truncated ({len(head)} of "
                                      f"{_HEADER_14} bytes)", path=path)
            evlr_start, n_evlrs, count14 = struct.unpack_from("<QIQ", head, 235)
            count = count14 or count
        if not (_HEADER_MIN <= header_size <= offset <= size):
            raise FileFormatError(f"LAS header size {header_size} and point data offset "
                                  f"{offset:,} do not fit a file of {size:,} bytes; it is "
                                  "truncated or damaged", path=path)
        _walk_records(fh, header_size, n_vlrs, _VLR_HEADER, "<H", offset,
                      "variable-length records", path)
        data_end = size
        if n_evlrs:
            if not offset <= evlr_start <= size:
                raise FileFormatError(f"LAS header puts its extended records at byte "
                                      f"{evlr_start:,}, outside the file of {size:,} bytes "
                                      "or before its points; it is truncated or damaged",
                                      path=path)
            _walk_records(fh, evlr_start, n_evlrs, _EVLR_HEADER, "<Q", size,
                          "extended records", path)
            data_end = evlr_start
    data = data_end - offset
    compressed, raw, fmt = bool(fmt & 0x80), fmt, fmt & 0x3F   # LASzip sets bits 7 (and 6)
    if fmt >= len(_RECORD_SIZES):
        raise FileFormatError(f"LAS point data format {raw} is not one of 0 to "
                              f"{len(_RECORD_SIZES) - 1} (plus 128 in a LAZ file); the header "
                              "is damaged", path=path)
    if record < _RECORD_SIZES[fmt]:
        raise FileFormatError(f"LAS point records of {record} bytes are shorter than point data "
                              f"format {fmt}'s {_RECORD_SIZES[fmt]}; the header is damaged",
                              path=path)
    if compressed:
        if count * record > limits.MAX_LAZ_RATIO * data:
            raise FileFormatError(f"LAZ header announces {count:,} points of {record} bytes, "
                                  f"more than {limits.MAX_LAZ_RATIO:,} times the {data:,} "
                                  "compressed bytes hold; the header is damaged", path=path)
        return count, compressed, 0
    if count * record > data:
        raise FileFormatError(f"LAS header announces {count:,} points of {record} bytes, more "
                              f"than the {data:,} bytes of point data hold; the file is "
                              "truncated or its header is damaged", path=path)
    waveform_inside = bool(encoding & 2)
    return count, compressed, 0 if waveform_inside else (data - count * record) // max(record, 1)


@contextlib.contextmanager
def _laspy_log():
    """Collect what laspy logs while it reads (a VLR it cannot parse, a short read) instead
    of letting it reach the process's log: the caller raises the error or warns naming the
    file."""
    said: list = []

    class _Collect(logging.Handler):
        def emit(self, record):
            said.append(record.getMessage())

    log = logging.getLogger("laspy")
    handler, propagate = _Collect(), log.propagate
    log.addHandler(handler)
    log.propagate = False
    try:
        yield said
    finally:
        log.removeHandler(handler)
        log.propagate = propagate


def _depth_scale(values: np.ndarray) -> float:
    """The full scale of 16-bit LAS values that may have been written at 8, 12 or 16 bits:
    255, 4095 or 65535, the smallest at or above their largest value."""
    top = int(values.max()) if values.size else 0
    return 255.0 if top <= 255 else 4095.0 if top <= 4095 else 65535.0


def _to_uint8(values: np.ndarray, scale: float) -> np.ndarray:
    """Values of full scale ``scale`` as 0..255."""
    return np.round(values.astype(np.float64) * (255.0 / scale)).astype(np.uint8)


def read_las(path: Path) -> Points:
    """A LAS or LAZ point cloud (versions 1.0 to 1.4, every point data format).

    Positions are the records' integers with the header's scale and offset applied. Colour is
    the records' red, green and blue (point formats 2, 3, 5, 7, 8, 10): the standard's 16-bit
    values are divided by 256, and values that are all at most 255 (writers that store 8-bit
    colour) are kept as they are. Intensity becomes grey colour when there is no colour (a
    format without RGB, or RGB all zero), scaled from the 8-, 12- or 16-bit range its largest
    value falls in; with colour, intensity is not kept (a surfel has one colour). All points are
    read, withheld and noise classes included; waveform packets are not read. Point records
    beyond the header's count in a LAS file are not read, with a warning; in a LAZ file they
    cannot be told from the compressed stream (LASzip records no count of its own).

    Parameters
    ----------
    path : pathlib.Path

    Returns
    -------
    Points
        Positions (n, 3) float64, colours (n, 3) uint8 or None, no normals.

    Warns
    -----
    UserWarning
        Point records after the announced count, what laspy logs while reading.

    Raises
    ------
    FileFormatError
        Not a LAS/LAZ file, a header whose records or point count do not fit the file's size, a
        file truncated or damaged inside its points, a header count that differs from the points
        read, no points, laspy or its LAZ backend missing.
    InputError
        Coordinates beyond :data:`~surfidx.io.limits.MAX_COORDINATE`; NaN coordinates (a NaN
        scale or offset) are refused as for every point cloud.
    """
    size = path.stat().st_size
    count, compressed, extra = _check_header(path, size)
    laspy, errors = _laspy(path, compressed)
    pos, rgb, intensity = [], [], []
    what = "LAZ" if compressed else "LAS"
    try:
        with _laspy_log() as said, \
                laspy.open(path, laz_backend=laspy.LazBackend.Lazrs) as reader:
            has_rgb = reader.header.point_format.id in _COLOR_FORMATS
            for pts in reader.chunk_iterator(_CHUNK):
                pos.append(np.stack([np.asarray(pts.x, np.float64), np.asarray(pts.y, np.float64),
                                     np.asarray(pts.z, np.float64)], axis=1))
                intensity.append(np.asarray(pts.intensity, np.uint16))
                if has_rgb:
                    rgb.append(np.stack([np.asarray(pts.red), np.asarray(pts.green),
                                         np.asarray(pts.blue)], axis=1).astype(np.uint16))
    except errors as exc:
        raise FileFormatError(f"{what} file cannot be read ({exc}); it is truncated or damaged",
                              path=path) from None
    positions = np.concatenate(pos) if pos else np.empty((0, 3))
    if len(positions) != count:                         # a file that shrank while read
        raise FileFormatError(f"{what} header announces {count:,} points and the file holds "
                              f"{len(positions):,}; it is truncated or damaged", path=path)
    for message in said:
        warnings.warn(f"{path}: laspy: {message}", UserWarning, stacklevel=3)
    if extra:
        warnings.warn(f"{path}: {extra:,} point records follow the {count:,} the LAS header "
                      "announces; they are not read", UserWarning, stacklevel=3)
    if count == 0:
        raise FileFormatError(f"{what} file holds no points", path=path)
    colors = None
    if rgb:
        rgb = np.concatenate(rgb)
        if rgb.any():
            colors = (rgb >> 8 if rgb.max() > 255 else rgb).astype(np.uint8)
    if colors is None:
        intensity = np.concatenate(intensity)
        if intensity.any():
            grey = _to_uint8(intensity, _depth_scale(intensity))
            colors = np.repeat(grey[:, None], 3, axis=1)
    return Points(limits.check_coordinates(positions, path), None, colors)
