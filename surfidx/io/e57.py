"""E57 (ASTM E2807, terrestrial laser scans): the point clouds of every scan of a file, each
moved by its pose and merged (:func:`read_e57`), read through pye57 (libE57Format), the
optional ``scanners`` extra.

The file header is checked against the file's size, and each scan's point count against the
bits its record needs, before libE57 reads anything; points are read a chunk at a time.
"""

from __future__ import annotations

import struct
import warnings
from pathlib import Path

import numpy as np

from ..errors import FileFormatError
from . import limits
from .points import Points

__all__ = ["read_e57"]

#: Points read at a time (a few megabytes of buffers per field).
_CHUNK = 1 << 18
_HEADER = struct.Struct("<8sIIQQQQ")      # signature, version, lengths, XML section, page size
_PAGE = 1024
_CARTESIAN = ("cartesianX", "cartesianY", "cartesianZ")
_SPHERICAL = ("sphericalRange", "sphericalAzimuth", "sphericalElevation")
_RGB = ("colorRed", "colorGreen", "colorBlue")
_GREY = 128                                # colour of points whose scan or flag gives none


def _libe57(path: Path):
    """pye57's libE57 binding; a missing pye57 is a clean error naming the extra."""
    try:
        from pye57 import libe57
    except ImportError:
        raise FileFormatError("reading E57 needs pye57; install it with "
                              "pip install 'surfidx[scanners]'", path=path) from None
    return libe57


def _check_file_header(path: Path, size: int) -> None:
    """Refuse what is not an E57 file, or one whose header disagrees with its size (truncated),
    before libE57 opens it.

    Raises
    ------
    FileFormatError
        No ``ASTM-E57`` signature, a physical length other than the file's size, a page size
        other than 1024, an XML section outside the file.
    """
    with open(path, "rb") as fh:
        head = fh.read(_HEADER.size)
    if not head.startswith(b"ASTM-E57"):
        raise FileFormatError("not an E57 file (it does not start with the ASTM-E57 "
                              "signature)", path=path)
    if len(head) < _HEADER.size:
        raise FileFormatError(f"E57 header is truncated ({len(head)} of {_HEADER.size} bytes)",
                              path=path)
    _, major, _, length, xml_offset, xml_length, page = _HEADER.unpack(head)
    if major != 1:
        raise FileFormatError(f"E57 version {major} is not supported (1 is)", path=path)
    if length != size:
        raise FileFormatError(f"E57 header gives a length of {length:,} bytes and the file has "
                              f"{size:,}; it is truncated or damaged", path=path)
    if page != _PAGE:
        raise FileFormatError(f"E57 header gives a page size of {page:,} bytes; E57 pages have "
                              f"{_PAGE}; the file is damaged", path=path)
    if size % _PAGE:
        raise FileFormatError(f"E57 file of {size:,} bytes is not a whole number of "
                              f"{_PAGE}-byte pages; it is truncated or damaged", path=path)
    if not (_HEADER.size <= xml_offset < size and xml_length <= size):
        raise FileFormatError(f"E57 header puts its XML section ({xml_length:,} bytes at "
                              f"byte {xml_offset:,}) outside the file; it is damaged", path=path)


def _fields(node, libe57) -> dict:
    """Name -> typed node of the fields of a record prototype (a nested structure is kept
    as its untyped node: no standard field is one, and it adds nothing to the size bound)."""
    out = {}
    for i in range(node.childCount()):
        child = node.get(i)
        kind = child.type()
        if kind == libe57.E57_FLOAT:
            child = libe57.FloatNode(child)
        elif kind == libe57.E57_INTEGER:
            child = libe57.IntegerNode(child)
        elif kind == libe57.E57_SCALED_INTEGER:
            child = libe57.ScaledIntegerNode(child)
        out[child.elementName()] = child
    return out


def _record_bits(fields: dict, libe57) -> int:
    """Bits one record takes at least in libE57's bit-packed binary section: 32 or 64 per
    float, the width of the range of each integer, 1 when every field is constant."""
    bits = 0
    for node in fields.values():
        if isinstance(node, libe57.FloatNode):
            bits += 32 if node.precision() == libe57.E57_SINGLE else 64
        elif isinstance(node, (libe57.IntegerNode, libe57.ScaledIntegerNode)):
            bits += max(int(node.maximum()) - int(node.minimum()), 0).bit_length()
    return max(bits, 1)


def _number(node, libe57, what: str, path: Path) -> float:
    """The value of a numeric node (float, integer or scaled integer).

    Raises
    ------
    FileFormatError
        The node holds a string, a structure or a vector.
    """
    if not isinstance(node, (libe57.FloatNode, libe57.IntegerNode, libe57.ScaledIntegerNode)):
        raise FileFormatError(f"E57 {what} is not a number; the file is damaged", path=path)
    return float(node.value())


def _limits(scan, group: str, lo: str, hi: str, node, libe57, path: Path):
    """``(low, high)`` of a colour or intensity field: the scan's ``colorLimits`` /
    ``intensityLimits``, else the integer range of its prototype node, else None."""
    if scan.isDefined(f"{group}/{lo}") and scan.isDefined(f"{group}/{hi}"):
        return (_number(scan[group][lo], libe57, f"{group} {lo}", path),
                _number(scan[group][hi], libe57, f"{group} {hi}", path))
    if isinstance(node, (libe57.IntegerNode, libe57.ScaledIntegerNode)):
        return float(node.minimum()), float(node.maximum())
    return None


def _scaled(values: np.ndarray, lims, what: str, notes: list) -> np.ndarray | None:
    """Values scaled from their limits to 0..255, a column each.

    Parameters
    ----------
    values : (n, k) float64
    lims : list of k (low, high) or None
        A column's limits; None takes the column's own range.
    what : str
        Named in the note of values outside the limits (clipped, counted in ``notes``).

    Returns
    -------
    (n, k) uint8 or None
        None when a column's range is empty or not finite (the field carries nothing).
    """
    if values.size == 0:
        return None
    lo, hi = np.array([lim if lim is not None else (np.min(v), np.max(v))
                       for lim, v in zip(lims, values.T)], np.float64).T
    if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi)) and np.all(hi > lo)):
        return None
    with np.errstate(invalid="ignore"):
        out = (values - lo) * (255.0 / (hi - lo))
        bad = ~((out >= -0.5) & (out <= 255.5))
    if bad.any():
        rng = ", ".join(f"{a:g}..{b:g}" for a, b in zip(lo, hi))
        notes.append(f"{int(bad.any(axis=1).sum()):,} points with {what} outside its limits "
                     f"{rng} clipped")
        out = np.where(np.isfinite(out), out, 0.0)
    return np.clip(np.round(out), 0, 255).astype(np.uint8)


def _pose(scan, libe57, path: Path, index: int):
    """``(rotation (3, 3), translation (3,))`` of a scan's pose (either part may be missing:
    identity)."""
    rot, shift = np.eye(3), np.zeros(3)
    pose = scan["pose"]
    parts = [pose] + [pose[k] for k in ("rotation", "translation")
                      if isinstance(pose, libe57.StructureNode) and pose.isDefined(k)]
    if not all(isinstance(p, libe57.StructureNode) for p in parts):
        raise FileFormatError(f"E57 scan {index}'s pose is not a structure of rotation and "
                              "translation; the file is damaged", path=path)
    if pose.isDefined("rotation"):
        r = pose["rotation"]
        w, x, y, z = (_number(r[k], libe57, f"scan {index}'s pose rotation {k}", path)
                      for k in "wxyz")
        norm = np.sqrt(w * w + x * x + y * y + z * z)
        if not np.isfinite(norm) or norm == 0:
            raise FileFormatError(f"E57 scan {index}'s pose rotation ({w}, {x}, {y}, {z}) is "
                                  "not a rotation quaternion", path=path)
        w, x, y, z = w / norm, x / norm, y / norm, z / norm
        rot = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])
    if pose.isDefined("translation"):
        t = pose["translation"]
        shift = np.array([_number(t[k], libe57, f"scan {index}'s pose translation {k}", path)
                          for k in "xyz"])
    return rot, shift


def _read_scan(imf, scan, fields: dict, count: int, libe57, path: Path, index: int, notes: list):
    """One scan's valid points in the file's frame, their colour (or None) and how many were
    invalid."""
    spherical = not all(f in fields for f in _CARTESIAN)
    coords = _SPHERICAL if spherical else _CARTESIAN
    state = "sphericalInvalidState" if spherical else "cartesianInvalidState"
    rgb = all(f in fields for f in _RGB)
    wanted = list(coords) + [f for f in (state, "intensity", "isIntensityInvalid")
                             if f in fields]
    if rgb:
        wanted += list(_RGB) + (["isColorInvalid"] if "isColorInvalid" in fields else [])
    arrays = {f: np.empty(_CHUNK, np.float64) for f in wanted}
    buffers = libe57.VectorSourceDestBuffer()
    for f in wanted:
        buffers.append(libe57.SourceDestBuffer(imf, f, arrays[f], _CHUNK, True, True))
    parts = {f: [] for f in wanted}
    reader = scan["points"].reader(buffers)
    try:
        got = 0
        while got < count:
            n = reader.read()
            if n == 0:
                break
            got += n
            for f in wanted:
                parts[f].append(arrays[f][:n].copy())
    finally:
        reader.close()
    if got != count:
        raise FileFormatError(f"E57 scan {index} announces {count:,} points and holds {got:,}; "
                              "the file is damaged", path=path)
    data = {f: np.concatenate(p) if p else np.empty(0) for f, p in parts.items()}
    valid = data[state] == 0 if state in data else np.ones(count, bool)
    pts = np.stack([data[f][valid] for f in coords], axis=1)
    if spherical:
        r, az, el = pts.T
        pts = np.stack([r * np.cos(el) * np.cos(az), r * np.cos(el) * np.sin(az),
                        r * np.sin(el)], axis=1)
    if scan.isDefined("pose"):
        rot, shift = _pose(scan, libe57, path, index)
        # R p + t as three broadcast products: exact in the order written, whatever BLAS
        # numpy loads (and ten times faster than an (n, 3) @ (3, 3) product)
        pts = pts[:, :1] * rot[:, 0] + pts[:, 1:2] * rot[:, 1] + pts[:, 2:] * rot[:, 2] + shift
    colors, flag = None, None
    if rgb:
        lims = [_limits(scan, "colorLimits", f + "Minimum", f + "Maximum", fields[f], libe57,
                        path) for f in _RGB]
        colors = _scaled(np.stack([data[f][valid] for f in _RGB], axis=1), lims, "colour",
                         notes)
        flag = "isColorInvalid"
        if colors is None and valid.any():
            notes.append(f"scan {index}'s colour limits are empty or not finite; its colour "
                         "is not used")
    if colors is None and "intensity" in data:
        lim = _limits(scan, "intensityLimits", "intensityMinimum", "intensityMaximum",
                      fields["intensity"], libe57, path)
        grey = _scaled(data["intensity"][valid][:, None], [lim], "intensity", notes)
        if grey is not None:
            colors = np.repeat(grey, 3, axis=1)
            flag = "isIntensityInvalid"
        elif valid.any():
            notes.append(f"scan {index}'s intensity has an empty or non-finite range; it is "
                         "not used as grey")
    if colors is not None and flag in data:
        bad = data[flag][valid] != 0
        if bad.any():
            colors[bad] = _GREY
            notes.append(f"{int(bad.sum()):,} points flagged {flag} coloured grey")
    return pts, colors, int(count - valid.sum())


def read_e57(path: Path) -> Points:
    """The points of every scan of an E57 file, each moved into the file's frame by its pose
    (rotation quaternion and translation) and merged in scan order.

    Points marked invalid (``cartesianInvalidState`` or ``sphericalInvalidState`` other than 0)
    are skipped with a warning saying how many. Spherical scans are converted to Cartesian
    coordinates. Colour is ``colorRed/Green/Blue`` scaled from the scan's ``colorLimits`` (else
    the fields' integer ranges) to 0..255; a scan without colour gets its ``intensity``, scaled
    from ``intensityLimits`` (else its range), as grey, and intensity is not kept beside colour
    (a surfel has one colour). Points whose colour is flagged invalid, and the points of a scan
    with neither when other scans have colour, are mid grey, with a warning. The file's 2D
    images are not read (a warning says so).

    Parameters
    ----------
    path : pathlib.Path

    Returns
    -------
    Points
        Positions (n, 3) float64, colours (n, 3) uint8 or None, no normals.

    Raises
    ------
    FileFormatError
        Not an E57 file, a header that disagrees with the file's size (truncated), a scan whose
        point count its record size makes larger than the file, a damaged file (libE57's
        checksums), a scan without point records or coordinates, a pose that is no rotation, a
        limit or pose that is not a number, no scans or no valid points, pye57 missing.
    InputError
        Coordinates beyond :data:`~surfidx.io.limits.MAX_COORDINATE`; NaN coordinates of valid
        points are refused as for every point cloud.

    Warns
    -----
    UserWarning
        Invalid points skipped, colours clipped to their limits or given grey, colour or
        intensity with an empty range not used, images not read.
    """
    size = path.stat().st_size
    _check_file_header(path, size)
    libe57 = _libe57(path)
    notes, pos, cols, uncoloured, invalid = [], [], [], [], 0
    try:
        imf = libe57.ImageFile(str(path), "r")
    except libe57.E57Exception as exc:
        raise FileFormatError(f"E57 file cannot be read ({str(exc).splitlines()[0]}); it is "
                              "truncated or damaged", path=path) from None
    try:
        root = imf.root()
        scans = root["data3D"] if root.isDefined("data3D") else None
        if not isinstance(scans, libe57.VectorNode) or scans.childCount() == 0:
            raise FileFormatError("E57 file holds no 3D scans", path=path)
        prepared, need = [], 0
        for i in range(scans.childCount()):
            scan = scans[i]
            if not isinstance(scan, libe57.StructureNode) or not scan.isDefined("points") or \
                    not isinstance(scan["points"], libe57.CompressedVectorNode):
                raise FileFormatError(f"E57 scan {i} has no point records; the file is damaged",
                                      path=path)
            fields = _fields(libe57.StructureNode(scan["points"].prototype()), libe57)
            count = scan["points"].childCount()
            if not (all(f in fields for f in _CARTESIAN) or all(f in fields for f in _SPHERICAL)):
                raise FileFormatError(f"E57 scan {i} has neither cartesianX/Y/Z nor "
                                      "sphericalRange/Azimuth/Elevation fields", path=path)
            need += count * _record_bits(fields, libe57)
            if need > 8 * size:
                raise FileFormatError(f"E57 scan {i} announces {count:,} points of "
                                      f"{_record_bits(fields, libe57)} bits, more than the file "
                                      f"of {size:,} bytes holds; it is damaged", path=path)
            prepared.append((scan, fields, count))
        for i, (scan, fields, count) in enumerate(prepared):
            if count == 0:                  # libE57 refuses to read an empty scan
                continue
            pts, colors, bad = _read_scan(imf, scan, fields, count, libe57, path, i, notes)
            invalid += bad
            pos.append(pts)
            cols.append(colors)
            if colors is None and len(pts):
                uncoloured.append(i)
        images = root["images2D"].childCount() if root.isDefined("images2D") and \
            isinstance(root["images2D"], libe57.VectorNode) else 0
    except libe57.E57Exception as exc:
        raise FileFormatError(f"E57 file cannot be read ({str(exc).splitlines()[0]}); it is "
                              "truncated or damaged", path=path) from None
    finally:
        imf.close()
    positions = np.concatenate(pos) if pos else np.empty((0, 3))
    total = len(positions) + invalid
    if invalid:
        warnings.warn(f"{path}: skipped {invalid:,} of {total:,} points marked invalid "
                      "(cartesianInvalidState/sphericalInvalidState)", UserWarning, stacklevel=2)
    if len(positions) == 0:
        raise FileFormatError(f"E57 file holds no valid points ({total:,} points, all marked "
                              "invalid)" if total else "E57 file's scans hold no points",
                              path=path)
    colors = None
    if len(uncoloured) < len(cols):
        if uncoloured:
            notes.append(f"scans {', '.join(map(str, uncoloured))} have neither colour nor "
                         "intensity; their points are grey")
        colors = np.concatenate([c if c is not None else np.full((len(p), 3), _GREY, np.uint8)
                                 for c, p in zip(cols, pos)])
    if images:
        notes.append(f"its {images} 2D image{'s' if images > 1 else ''} not read")
    for note in notes:
        warnings.warn(f"{path}: {note}", UserWarning, stacklevel=2)
    return Points(limits.check_coordinates(positions, path), None, colors)
