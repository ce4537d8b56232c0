"""Bounds on what is read: the largest coordinate, text file and texture, and the checks of a
file before and while it is parsed (a non-empty regular file, coordinates in range).

The limits are read through this module (``limits.MAX_TEXT_BYTES``) by the format modules, so
one assignment here changes them everywhere.
"""

from __future__ import annotations

import stat
from pathlib import Path

import numpy as np

from ..errors import FileFormatError, InputError

MAX_TEXT_BYTES = 2 ** 31
"""Largest XYZ/PTS/ASCII-PCD point file read (2 GiB of text): numpy parses it whole."""

MAX_TEXTURE_PIXELS = 2 ** 27
"""Largest texture image read, in pixels (134,217,728: 16384 × 8192, 384 MiB as RGB); a larger
image is refused before it is decoded (a small PNG may declare 50,000 × 50,000 pixels)."""

MAX_COORDINATE = 1e30
"""Largest coordinate magnitude read: positions are stored as float32 (largest 3.4e38) and
their squares and cross products must stay finite."""

MAX_LAZ_POINTS_PER_BYTE = 256
"""Most points a LAZ file may announce per byte of its compressed point data: above what LASzip
reaches on identical points in every point format and far above real scans
(``benchmarks/scanformats.py`` prints both), so a header announcing more points is refused
before decompression allocates them."""


def check_input_file(path: Path) -> None:
    """Refuse what is not a non-empty regular file, before opening it (a FIFO would block).

    Parameters
    ----------
    path : pathlib.Path

    Raises
    ------
    FileFormatError
        A missing or unreadable path, a directory, a device or FIFO, an empty file.
    """
    try:
        st = path.stat()
    except FileNotFoundError:
        raise FileFormatError("no such file", path=path) from None
    except OSError as exc:
        raise FileFormatError(f"cannot read ({exc.strerror or exc})", path=path) from None
    if stat.S_ISDIR(st.st_mode):
        raise FileFormatError("is a directory, not a model file", path=path)
    if not stat.S_ISREG(st.st_mode):
        raise FileFormatError("is not a regular file", path=path)
    if st.st_size == 0:
        raise FileFormatError("the file is empty", path=path)


def read_text(path: Path) -> str:
    """The file's text, decoded as UTF-8 with undecodable bytes replaced.

    Parameters
    ----------
    path : pathlib.Path

    Returns
    -------
    str

    Raises
    ------
    FileFormatError
        Naming the file when the OS refuses to read it.
    """
    try:
        with open(path, "rb") as fh:
            data = fh.read()
    except OSError as exc:
        raise FileFormatError(f"cannot read ({exc.strerror or exc})", path=path) from None
    return data.decode("utf-8", errors="replace")


def check_coordinates(positions: np.ndarray, path: Path) -> np.ndarray:
    """Refuse absurdly large coordinates (beyond :data:`MAX_COORDINATE`; NaN and infinity are
    refused by the arrays' validation).

    Parameters
    ----------
    positions : (n, 3) float64
    path : pathlib.Path
        Named in the error.

    Returns
    -------
    (n, 3) float64
        ``positions`` itself.

    Raises
    ------
    InputError
        Saying how many vertices are out of range and which is the first.
    """
    with np.errstate(invalid="ignore"):
        bad = (np.abs(positions) > MAX_COORDINATE) & np.isfinite(positions)
    if bad.any():
        rows = bad.any(axis=1)
        row = int(np.flatnonzero(rows)[0])
        raise InputError(f"{int(rows.sum())} vertices have coordinates beyond "
                         f"±{MAX_COORDINATE:g} (first: vertex {row}, {positions[row].tolist()}); "
                         "rescale the model", path=path)
    return positions


def check_text_size(path: Path) -> None:
    """Refuse a text point file larger than :data:`MAX_TEXT_BYTES` (numpy parses it whole).

    Raises
    ------
    FileFormatError
        Naming the size and the limit.
    """
    size = path.stat().st_size
    if size > MAX_TEXT_BYTES:
        raise FileFormatError(f"text point file of {size:,} bytes exceeds the limit of "
                              f"{MAX_TEXT_BYTES:,} bytes; convert it to binary PLY or PCD",
                              path=path)
