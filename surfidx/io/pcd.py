"""PCD (Point Cloud Library), ``DATA ascii`` or ``binary``: point clouds read (:func:`read_pcd`)."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np

from ..errors import FileFormatError, InputError
from .limits import check_coordinates, check_text_size, read_text
from .points import Points, colors_of, loadtxt


_PCD_TYPES = {("F", 4): "<f4", ("F", 8): "<f8", ("I", 1): "i1", ("I", 2): "<i2",
              ("I", 4): "<i4", ("I", 8): "<i8", ("U", 1): "u1", ("U", 2): "<u2",
              ("U", 4): "<u4", ("U", 8): "<u8"}


def read_pcd(path: Path) -> Points:
    """A PCD file (Point Cloud Library), ``DATA ascii`` or ``binary``: fields ``x y z``,
    optionally ``normal_x normal_y normal_z`` and ``rgb``/``rgba`` (packed) or ``r g b``.
    Points with NaN coordinates (PCL's missing points) are refused, as XYZ and PTS refuse
    them: nothing is dropped without a word.

    Parameters
    ----------
    path : pathlib.Path

    Returns
    -------
    Points

    Raises
    ------
    FileFormatError
        No DATA line, a garbled or inconsistent header, no ``x y z``, an unsupported type or
        DATA kind, less or more data than the header announces, colours outside 0..255.
    InputError
        A point with NaN or infinite coordinates (naming the first).

    Warns
    -----
    UserWarning
        Normals with NaN or infinite values, dropped (they are estimated from the points).
    """
    try:
        with open(path, "rb") as fh:
            head = fh.read(1 << 16)
    except OSError as exc:
        raise FileFormatError(f"cannot read ({exc.strerror or exc})", path=path) from None
    header, offset, data_kind = {}, 0, None
    for raw in head.split(b"\n"):
        offset += len(raw) + 1
        line = raw.decode("latin-1").strip()
        if not line or line.startswith("#"):
            continue
        key, _, value = line.partition(" ")
        header[key.upper()] = value.split()
        if key.upper() == "DATA":
            data_kind = value.strip().lower()
            break
    if data_kind is None:
        raise FileFormatError("not a PCD file (no DATA line in its header)", path=path)
    try:
        fields = header["FIELDS"]
        sizes = [int(x) for x in header.get("SIZE", [])]
        types = [t.upper() for t in header.get("TYPE", [])]
        counts = [int(x) for x in header.get("COUNT", ["1"] * len(fields))]
        grid = int(header["WIDTH"][0]) * int(header.get("HEIGHT", ["1"])[0]) \
            if "WIDTH" in header else None
        n = int(header["POINTS"][0]) if "POINTS" in header else grid
        if n is None:
            raise KeyError("POINTS")
    except (KeyError, ValueError, IndexError) as exc:
        raise FileFormatError(f"PCD header lacks or garbles a line ({exc})", path=path) from None
    if grid is not None and grid != n:
        raise FileFormatError(f"PCD header announces {n:,} points (POINTS) and a grid of "
                              f"{grid:,} (WIDTH × HEIGHT); fix the header", path=path)
    if not (len(fields) == len(sizes) == len(types) == len(counts)) or n < 0:
        raise FileFormatError("PCD header's FIELDS, SIZE, TYPE and COUNT lines differ in length",
                              path=path)
    if not all(f in fields for f in "xyz"):
        raise FileFormatError("PCD file lacks the fields x y z", path=path)
    try:
        dtype = np.dtype([(f if f != "_" else f"_{i}", _PCD_TYPES[(t, s)], (c,) if c > 1 else ())
                          for i, (f, s, t, c) in enumerate(zip(fields, sizes, types, counts))])
    except (KeyError, ValueError, TypeError) as exc:
        raise FileFormatError(f"PCD field type or size not supported ({exc})", path=path) \
            from None
    size = path.stat().st_size
    if data_kind == "binary":
        if n * dtype.itemsize > size - offset:
            raise FileFormatError(f"PCD header announces {n:,} points, more than the "
                                  f"{size - offset:,} bytes after it hold; the file may be "
                                  "truncated", path=path)
        if size - offset >= (n + 1) * dtype.itemsize:
            raise FileFormatError(f"PCD header announces {n:,} points, the data holds "
                                  f"{(size - offset) // dtype.itemsize:,} of {dtype.itemsize} "
                                  "bytes; fix the header's POINTS, WIDTH and HEIGHT", path=path)
        with open(path, "rb") as fh:
            fh.seek(offset)
            rows = np.frombuffer(fh.read(n * dtype.itemsize), dtype=dtype, count=n)
    elif data_kind == "ascii":
        check_text_size(path)
        text = read_text(path)
        body = text.encode("latin-1", "replace")[offset:].decode("latin-1").splitlines()
        arr = loadtxt(body, path, "PCD")
        if arr.shape != (n, sum(counts)):
            raise FileFormatError(f"PCD header announces {n:,} points of {sum(counts)} numbers, "
                                  f"the data holds {arr.shape[0]:,} of {arr.shape[1]}", path=path)
        rows = np.empty(n, dtype)
        col = 0
        for name, c in zip(dtype.names, counts):
            vals = arr[:, col:col + c]
            if name in ("rgb", "rgba") and c == 1:   # packed colour written as a float or int
                v = vals[:, 0]
                bits = v.astype("<f4").view("<u4") if rows[name].dtype.kind == "f" else \
                    v.astype("<u4")
                rows[name] = bits.view(rows[name].dtype) if rows[name].dtype.kind == "f" else bits
            else:
                rows[name] = vals.reshape(rows[name].shape)
            col += c
    else:
        raise FileFormatError(f"PCD DATA {data_kind} is not supported; save it as ascii or "
                              "binary (e.g. pcl_convert_pcd_ascii_binary IN OUT 1)", path=path)
    pos = np.stack([rows[a] for a in "xyz"], axis=1).astype(np.float64)
    missing = ~np.all(np.isfinite(pos), axis=1)        # PCL marks missing points with NaN
    if missing.any():
        first = int(np.flatnonzero(missing)[0])
        raise InputError(f"PCD point {first} has NaN or infinite coordinates "
                         f"({int(missing.sum()):,} points so: PCL's missing points); remove "
                         "them (e.g. pcl::removeNaNFromPointCloud)", path=path)
    pos = check_coordinates(pos, path)
    normals = None
    if all(f"normal_{a}" in fields for a in "xyz"):
        normals = np.stack([rows[f"normal_{a}"] for a in "xyz"], axis=1).astype(np.float64)
        if not np.all(np.isfinite(normals)):
            bad = int((~np.all(np.isfinite(normals), axis=1)).sum())
            warnings.warn(f"{path}: {bad:,} PCD normals have NaN or infinite values; the normals "
                          "are dropped and estimated from the points", UserWarning, stacklevel=2)
            normals = None
    colors = None
    for name in ("rgb", "rgba"):
        if name in fields:
            packed = np.ascontiguousarray(rows[name]).view("<u4")
            colors = np.stack([(packed >> 16) & 255, (packed >> 8) & 255, packed & 255],
                              axis=1).astype(np.uint8)
    if colors is None and all(c in fields for c in "rgb"):
        colors = colors_of(np.stack([rows[c] for c in "rgb"], axis=1), "PCD", path)
    return Points(pos, normals, colors)
