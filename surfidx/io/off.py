"""OFF (ASCII, with the ``ST``, ``C``, ``N`` and ``4`` prefixes): meshes read."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from ..errors import FileFormatError, SurfidxError
from ..geometry.mesh import TriangleMesh
from .limits import check_coordinates, read_text
from .ply import triangulate_polygons


_OFF_HEADER = re.compile(r"(ST)?(C)?(N)?(4)?(n)?OFF")


def read_off(path: Path) -> TriangleMesh:
    """Read an ASCII OFF file as common tools write it.

    The keyword may carry the prefixes ``ST`` (texture coordinates), ``C`` (colours: RGB or
    RGBA, 0..1 or 0..255), ``N`` (normals) and ``4`` (homogeneous coordinates, divided by w);
    the counts ``V F E`` follow on the keyword's line or the next one; ``#`` starts a comment.
    Each vertex and each face is one line; a face line is ``k i_1 … i_k`` and may end with a
    face colour (ignored).

    Parameters
    ----------
    path : pathlib.Path

    Returns
    -------
    TriangleMesh

    Raises
    ------
    FileFormatError
        Not an OFF header, nOFF or binary OFF, too few lines for the counts, malformed lines, a
        face of fewer than 3 corners or naming a missing vertex, no faces.
    """
    text = read_text(path)
    lines = [ln.split("#", 1)[0].strip() for ln in text.splitlines()]
    lines = [ln for ln in lines if ln]
    if not lines:
        raise FileFormatError("the file is empty (only comments)", path=path)
    head = lines[0].split()
    m = _OFF_HEADER.fullmatch(head[0])
    if m is None:
        raise FileFormatError("not an OFF file (first line must be 'OFF', 'COFF', 'NOFF', ...)",
                              path=path)
    if m.group(5):
        raise FileFormatError("nOFF (vertices of another dimension than 3) is not supported",
                              path=path)
    rest = lines[1:]
    counts = head[1:]
    if counts and counts[0].upper() == "BINARY":
        raise FileFormatError("binary OFF is not supported; write it as ASCII", path=path)
    if not counts:
        counts = rest.pop(0).split() if rest else []
    try:
        nv, nf = int(counts[0]), int(counts[1])
    except (IndexError, ValueError) as exc:
        raise FileFormatError("OFF header lacks vertex and face counts", path=path) from exc
    if nv < 0 or nf < 0:
        raise FileFormatError(f"OFF header has negative counts ({nv} vertices, {nf} faces)",
                              path=path)
    if len(rest) < nv + nf:
        raise FileFormatError(f"OFF file is truncated: header announces {nv} vertices and {nf} "
                              f"faces, found {len(rest)} data lines", path=path)
    st, colored, normals, homogeneous = (bool(m.group(g)) for g in (1, 2, 3, 4))
    ncoord = 4 if homogeneous else 3
    lead = ncoord + (3 if normals else 0)       # numbers before the colour
    trail = 2 if st else 0                      # texture coordinates after it
    try:
        vrows = [r.split() for r in rest[:nv]]
        widths = np.fromiter((len(r) for r in vrows), np.int64, nv)
        low = lead + trail + (3 if colored else 0)
        if nv and widths.min() < low:
            bad = int(np.flatnonzero(widths < low)[0])
            raise FileFormatError(f"OFF vertex line {bad + 1} has {widths[bad]} numbers, "
                                  f"{head[0]} needs at least {low}", path=path)
        arr = np.array([r[:lead] for r in vrows], np.float64).reshape(nv, lead)
        vcols = None
        if colored:
            ncol = 4 if nv and widths.min() >= lead + trail + 4 else 3
            c = np.array([r[lead:lead + ncol] for r in vrows], np.float64).reshape(nv, ncol)
            c = c[:, :3]
            if not np.all(np.isfinite(c)):
                raise FileFormatError("OFF vertex colours contain NaN or infinite values",
                                      path=path)
            if c.size and c.max() <= 1.0:
                c = c * 255
            vcols = np.clip(np.round(c), 0, 255).astype(np.uint8)
        frows = [r.split() for r in rest[nv:nv + nf]]
        k = np.array([int(r[0]) for r in frows], np.int64)
        have = np.fromiter((len(r) - 1 for r in frows), np.int64, nf)
        short = k > have
        if short.any():
            bad = int(np.flatnonzero(short)[0])
            raise FileFormatError(f"OFF face {bad} declares {k[bad]:,} corners but its line "
                                  f"holds {have[bad]} numbers", path=path)
        if nf and k.min() < 3:
            bad = int(np.flatnonzero(k < 3)[0])
            raise FileFormatError(f"OFF face {bad} has {k[bad]} corners; a face needs at least 3",
                                  path=path)
        if np.all(k == 3):
            faces = np.array([r[1:4] for r in frows], np.int64).reshape(nf, 3)
        else:
            faces = triangulate_polygons([np.array(r[1:1 + int(r[0])], np.int64) for r in frows],
                                          path)
    except SurfidxError:
        raise
    except (ValueError, IndexError, OverflowError) as exc:
        raise FileFormatError(f"malformed OFF data ({exc})", path=path) from exc
    positions = arr[:, :3]
    if homogeneous:
        with np.errstate(divide="ignore", invalid="ignore"):
            positions = positions / arr[:, 3:4]
    check_coordinates(positions, path)
    if faces.size and (faces.min() < 0 or faces.max() >= nv):
        raise FileFormatError("a face refers to a vertex that does not exist", path=path)
    if not len(faces):
        raise FileFormatError("OFF file has no faces", path=path)
    return TriangleMesh(positions, faces, vertex_colors=vcols, name=path.stem)
