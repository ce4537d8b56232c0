"""XYZ and PTS text point clouds: read bounded (:func:`read_xyz`)."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from ..errors import FileFormatError
from .limits import check_coordinates, check_text_size, read_text
from .points import Points, colors_of, data_line, loadtxt


def read_xyz(path: Path) -> Points:
    """XYZ (``x y z``, ``x y z r g b``, ``x y z nx ny nz``, ``x y z nx ny nz r g b``) or PTS
    (an optional first line with the point count, then ``x y z [intensity] [r g b]``), told
    apart by the suffix; XYZ's 6 columns are normals when they are unit vectors, else colours.
    A PTS intensity without colour becomes grey, stretched from its own range to 0..255 (PTS
    writers disagree on its scale); beside colour it is not kept (a surfel has one colour).

    Parameters
    ----------
    path : pathlib.Path

    Returns
    -------
    Points

    Raises
    ------
    FileFormatError
        A file over :data:`~surfidx.io.limits.MAX_TEXT_BYTES`, malformed lines, a count that
        differs from the points, an unexpected number of columns, colours outside 0..255
        (naming the line).
    """
    check_text_size(path)
    lines = read_text(path).splitlines()
    what = path.suffix.lower().lstrip(".").upper()
    count = None
    first = 1
    if what == "PTS" and lines and re.fullmatch(r"\s*\d+\s*", lines[0]):
        count = int(lines[0])
        lines, first = lines[1:], 2
    arr = loadtxt(lines, path, what)

    def where(row):
        return data_line(lines, row, first)

    if count is not None and count != len(arr):
        raise FileFormatError(f"PTS file announces {count:,} points and holds {len(arr):,}; "
                              "it may be truncated", path=path)
    k = arr.shape[1]
    pos, normals, colors = arr[:, :3], None, None
    if what == "PTS":
        if k not in (3, 4, 6, 7):
            raise FileFormatError(f"PTS lines hold {k} numbers; expected x y z, x y z "
                                  "intensity, x y z r g b or x y z intensity r g b", path=path)
        if k >= 6:
            colors = colors_of(arr[:, k - 3:], what, path, where)
        elif k == 4:
            colors = _intensity_grey(arr[:, 3])
    else:
        if k not in (3, 6, 9):
            raise FileFormatError(f"XYZ lines hold {k} numbers; expected x y z, x y z r g b, "
                                  "x y z nx ny nz or x y z nx ny nz r g b", path=path)
        if k == 9:
            normals, colors = arr[:, 3:6], colors_of(arr[:, 6:9], what, path, where)
        elif k == 6:
            extra = arr[:, 3:6]
            lengths = np.linalg.norm(extra, axis=1)
            if np.all(np.abs(lengths - 1.0) < 1e-3):
                normals = extra
            elif np.all((extra >= 0) & (extra <= 255)):
                colors = colors_of(extra, what, path, where)
            else:
                raise FileFormatError("XYZ columns 4-6 are neither unit normals nor colours "
                                      "(0..1 or 0..255)", path=path)
    return Points(check_coordinates(pos, path), normals, colors)


def _intensity_grey(intensity: np.ndarray) -> np.ndarray | None:
    """``(n, 3) uint8`` grey from an intensity column stretched from its own range, or None
    when the column is constant (it carries nothing)."""
    lo, hi = float(intensity.min()), float(intensity.max())
    if not hi > lo:
        return None
    grey = np.rint((intensity - lo) * (255.0 / (hi - lo))).astype(np.uint8)
    return np.repeat(grey[:, None], 3, axis=1)
