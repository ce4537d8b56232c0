"""What the point-cloud readers share: the points read (:class:`Points`), their colours and
the parsing of a table of numbers."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np

from ..errors import FileFormatError


class Points:
    """Points read from a point-cloud file: positions, optional normals and colours."""

    def __init__(self, positions, normals=None, colors=None):
        self.positions = positions
        self.normals = normals
        self.colors = colors
        self.faces = None


def colors_of(c, what: str, path, where=None) -> np.ndarray:
    """Colours given as 0..1 (when all values are at most 1) or 0..255, as uint8; a value
    outside 0..255 is refused, not clipped.

    Parameters
    ----------
    c : (n, 3) float64
    what : str
        The format, named in the error.
    path : pathlib.Path
    where : callable, optional
        ``where(row) -> str``, the place of a row in the file named in the error
        (``"line 7"``); ``"point {row}"`` by default.

    Returns
    -------
    (n, 3) uint8

    Raises
    ------
    FileFormatError
        NaN or infinite colours, or colours below 0 or above 255, naming the first.
    """
    c = np.asarray(c, np.float64)
    if not np.all(np.isfinite(c)):
        raise FileFormatError(f"{what} colours contain NaN or infinite values", path=path)
    bad = ((c < 0) | (c > 255)).any(axis=1)
    if bad.any():
        row = int(np.flatnonzero(bad)[0])
        place = where(row) if where is not None else f"point {row}"
        raise FileFormatError(f"{what} colour {' '.join(f'{x:g}' for x in c[row])} on {place} is "
                              f"outside 0..255 ({int(bad.sum()):,} points so); fix the colour "
                              "columns", path=path)
    if c.size and c.max() <= 1.0:
        c = c * 255.0
    return np.clip(np.round(c), 0, 255).astype(np.uint8)


def data_line(lines, row: int, first: int = 1) -> str:
    """The line of a text point file that holds table row ``row`` of :func:`loadtxt` (comment
    and blank lines skipped as it skips them), as ``"line N"``.

    Parameters
    ----------
    lines : sequence of str
        The lines given to :func:`loadtxt`.
    row : int
    first : int
        The number of ``lines[0]`` in the file.

    Returns
    -------
    str
    """
    seen = -1
    for k, line in enumerate(lines):
        text = line.split("#", 1)[0].split("//", 1)[0].strip()
        if text:
            seen += 1
            if seen == row:
                return f"line {k + first}"
    return f"point {row}"


def loadtxt(lines, path: Path, what: str) -> np.ndarray:
    """The numbers of text lines as a table (``#`` and ``//`` start comments).

    Parameters
    ----------
    lines : iterable of str
    path : pathlib.Path
        Named in the error.
    what : str
        The format, named in the error.

    Returns
    -------
    (n, k) float64

    Raises
    ------
    FileFormatError
        Lines of different lengths, non-numbers, or no points.
    """
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")               # an empty input warns
            arr = np.loadtxt(lines, dtype=np.float64, comments=("#", "//"), ndmin=2)
    except ValueError as exc:
        raise FileFormatError(f"malformed {what} data ({exc}); every line must hold the same "
                              "count of numbers", path=path) from None
    if arr.size == 0:
        raise FileFormatError(f"{what} file holds no points", path=path)
    return arr
