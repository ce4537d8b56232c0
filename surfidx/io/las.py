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
                  path: Path) -> dict:
    """Follow ``n`` records from byte ``pos`` (each a ``head``-byte header: user id at byte 2,
    record id at 18, length of struct format ``length`` at 20); a record that runs past ``end``
    is refused, so a count of 4 billion stops at the first one out of bounds.

    Returns
    -------
    dict
        ``(user id, record id) -> (start, length)`` of each record's data.
    """
    found = {}
    for i in range(n):
        if pos + head > end:
            raise FileFormatError(f"LAS header announces {n:,} {what}; record {i} runs past "
                                  f"byte {end:,}; the file is truncated or damaged", path=path)
        fh.seek(pos)
        rec = fh.read(head)
        (size,) = struct.unpack_from(length, rec, 20)
        user, number = rec[2:18].rstrip(b"\0"), struct.unpack_from("<H", rec, 18)[0]
        found.setdefault((user, number), (pos + head, size))
        pos += head + size
    if pos > end:
        raise FileFormatError(f"LAS header announces {n:,} {what}; the last runs past byte "
                              f"{end:,}; the file is truncated or damaged", path=path)
    return found


#: Layers of each LASzip item type in the layered compression of point formats 6 to 10
#: (POINT14, RGB14, RGBNIR14, WAVEPACKET14; BYTE14 has one a byte).
_LAYERS = {10: 9, 11: 1, 12: 2, 13: 1}


def _check_laszip(fh, laszip, offset: int, end: int, size: int, count: int, record: int,
                  path: Path) -> None:
    """Check what lazrs allocates by before it reads: the chunk table's chunk count (an entry
    is reserved for each) and, in the layered compression of point formats 6 to 10, each
    chunk's layer sizes (a buffer of that size is made for each).

    The first 8 bytes of the point data give the table's position (or, when a writer could not
    go back, the file's last 8 bytes do); the table starts with its version and chunk count.
    A layered chunk is its first point raw, its point count, a 32-bit size per layer of each
    item, then the layers.

    Raises
    ------
    FileFormatError
        A LASzip record too short for its items, fixed chunks of 0 points, more chunks than
        compressed bytes, fixed chunks too few for the points announced, a chunk of no points,
        layers larger than the bytes left.
    """
    if laszip is None:
        return                              # laspy names the missing LASzip record
    start, length = laszip
    fh.seek(start)
    vlr = fh.read(length)
    n_items = struct.unpack_from("<H", vlr, 32)[0] if length >= 34 else 0
    if length < 34 + 6 * n_items:
        raise FileFormatError(f"LAZ file's LASzip record is {length} bytes, shorter than the "
                              f"{34 + 6 * n_items} it needs; the file is damaged", path=path)
    compressor = struct.unpack_from("<H", vlr, 0)[0]
    chunk = struct.unpack_from("<I", vlr, 12)[0]
    items = [struct.unpack_from("<HH", vlr, 34 + 6 * i) for i in range(n_items)]
    if chunk == 0:
        raise FileFormatError("LAZ file's LASzip record gives chunks of 0 points; the file is "
                              "damaged", path=path)
    if end - offset < 8:
        raise FileFormatError("LAZ point data is shorter than its 8-byte chunk table offset; "
                              "the file is truncated", path=path)
    fh.seek(offset)
    (table,) = struct.unpack("<q", fh.read(8))
    if table <= offset and size >= 8:
        fh.seek(size - 8)
        (table,) = struct.unpack("<q", fh.read(8))
    if offset < table <= size - 8:
        fh.seek(table)
        _, chunks = struct.unpack("<II", fh.read(8))
        if chunks > table - offset:
            raise FileFormatError(f"LAZ chunk table lists {chunks:,} chunks, more than the "
                                  f"{table - offset:,} compressed bytes before it hold; the "
                                  "file is damaged", path=path)
        if chunk != 0xFFFFFFFF and chunks * chunk < count:
            raise FileFormatError(f"LAZ chunk table lists {chunks:,} chunks of {chunk:,} "
                                  f"points, fewer than the {count:,} points the header "
                                  "announces; the file is truncated or damaged", path=path)
        end = table
    layers = [_LAYERS.get(kind, size_ if kind == 14 else -1) for kind, size_ in items]
    if compressor != 3 or -1 in layers:
        return                              # pointwise: fixed-size models, nothing to reserve
    n_layers = sum(layers)
    pos, left, k = offset + 8, count, 0     # at most one step per record + 4 bytes of data
    while left > 0:
        head = record + 4 + 4 * n_layers
        if pos + head > end:
            raise FileFormatError(f"LAZ chunk {k} runs past byte {end:,}, the end of the "
                                  "compressed points; the file is truncated or damaged",
                                  path=path)
        fh.seek(pos + record)
        points, *sizes = struct.unpack(f"<I{n_layers}I", fh.read(4 + 4 * n_layers))
        if points == 0:
            raise FileFormatError(f"LAZ chunk {k} holds no points; the file is damaged",
                                  path=path)
        if sum(sizes) > end - pos - head:
            raise FileFormatError(f"LAZ chunk {k}'s layers announce {sum(sizes):,} bytes, "
                                  f"more than the {end - pos - head:,} left; the file is "
                                  "truncated or damaged", path=path)
        pos += head + sum(sizes)
        left -= points
        k += 1


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
        the header can hold (a LAZ: more than
        :data:`~surfidx.io.limits.MAX_LAZ_POINTS_PER_BYTE` allow,
        or a chunk table or chunk whose counts do not fit, see :func:`_check_laszip`).
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
        vlrs = _walk_records(fh, header_size, n_vlrs, _VLR_HEADER, "<H", offset,
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
        if count > limits.MAX_LAZ_POINTS_PER_BYTE * data:
            raise FileFormatError(f"LAZ header announces {count:,} points, more than "
                                  f"{limits.MAX_LAZ_POINTS_PER_BYTE} a byte of its {data:,} "
                                  "compressed bytes; the header is damaged (or the points are "
                                  "all alike)", path=path)
        with open(path, "rb") as fh:
            _check_laszip(fh, vlrs.get((b"laszip encoded", 22204)), offset, data_end, size,
                          count, record, path)
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
    except BaseException as exc:                        # lazrs panics on some damaged data
        if type(exc).__name__ != "PanicException":
            raise
        raise FileFormatError(f"{what} points cannot be decompressed ({exc}); the file is "
                              "damaged", path=path) from None
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
