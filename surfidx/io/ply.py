"""PLY: meshes (``face`` lists, triangulated as fans, or ``tristrips``), surfels (``x y z nx ny
nz radius [red green blue]``) and point clouds, read through plyfile with the header's element
counts checked against the file's size first; surfel PLY written (:func:`write_ply`)."""

from __future__ import annotations

import os
import warnings
from pathlib import Path

import numpy as np

from ..errors import FileFormatError, InputError, SurfidxError
from ..geometry.mesh import TriangleMesh
from ..geometry.surfels import SurfelSet
from .atomic import write_atomic
from .limits import check_coordinates


class PlyPoints:
    """Vertex data of a PLY with no faces (surfels or a point cloud)."""

    def __init__(self, vertex, faces=None):
        self.vertex = vertex
        self.faces = faces


_PLY_SIZES = {"char": 1, "int8": 1, "uchar": 1, "uint8": 1, "short": 2, "int16": 2,
              "ushort": 2, "uint16": 2, "int": 4, "int32": 4, "uint": 4, "uint32": 4,
              "float": 4, "float32": 4, "double": 8, "float64": 8}


def _check_ply_counts(fh, path: Path) -> None:
    """Refuse a PLY header whose element counts the file is too short to hold.

    plyfile allocates every element's array before reading it, so a header announcing 10^12
    vertices in a few bytes would exhaust memory; each element needs at least its fixed-size
    properties (binary) or two characters per property (ASCII).
    """
    size = os.fstat(fh.fileno()).st_size
    head = fh.read(1 << 20)
    fh.seek(0)
    end = head.find(b"end_header")
    if not head.startswith(b"ply") or end < 0:
        return  # plyfile names the problem
    fmt, need, counts, per = None, 0, {}, None
    for raw in head[:end].decode("latin-1").splitlines():
        tok = raw.split()
        if len(tok) >= 2 and tok[0] == "format":
            fmt = tok[1]
        elif len(tok) >= 3 and tok[0] == "element":
            try:
                count = int(tok[2])
            except ValueError:
                return
            per = [tok[1], count, 0]
            counts[tok[1]] = per
        elif len(tok) >= 3 and tok[0] == "property" and per is not None:
            if fmt == "ascii":
                per[2] += 2
            else:
                per[2] += _PLY_SIZES.get(tok[2] if tok[1] == "list" else tok[1], 1)
    data = size - (end + len(b"end_header"))
    for name, count, nbytes in counts.values():
        need += max(count, 0) * max(nbytes, 1)
        if need > data:
            raise FileFormatError(
                f"not a readable PLY file (its header announces {count:,} '{name}' elements, "
                f"more than the {data:,} bytes after it hold); the file may be truncated or "
                "corrupt", path=path)


#: The face lists read as one array when every face is a triangle (plyfile reads other lists
#: row by row: seconds for a scan of a hundred thousand faces).
_TRIANGLE_LISTS = {"face": {"vertex_indices": 3, "vertex_index": 3}}


def _ply_data(path: Path):
    """plyfile's reading of ``path``: its faces as one ``(m, 3)`` array when they are all
    triangles (memory-mapped, checked row by row by plyfile), else as lists."""
    from plyfile import PlyData, PlyElementParseError

    try:
        return PlyData.read(str(path), known_list_len=_TRIANGLE_LISTS)
    except PlyElementParseError as exc:
        if exc.message != "unexpected list length":
            raise
    return PlyData.read(str(path))


def _data_start(path: Path) -> int:
    """Offset of the first byte after the header's ``end_header`` line."""
    with open(path, "rb") as fh:
        head = fh.read(1 << 20)
    end = head.find(b"end_header")
    nl = head.find(b"\n", end)
    return len(head) if nl < 0 else nl + 1


def _element_bytes(element) -> int:
    """Bytes a binary PLY element's rows take, list lengths as read."""
    total = 0
    for prop in element.properties:
        val = np.dtype(prop.val_dtype).itemsize
        if hasattr(prop, "len_dtype"):
            column = element.data[prop.name]
            lengths = (np.full(len(column), column.shape[1]) if column.dtype != object
                       else np.fromiter((len(r) for r in column), np.int64, len(column)))
            total += len(column) * np.dtype(prop.len_dtype).itemsize + int(lengths.sum()) * val
        else:
            total += element.count * val
    return total


def _warn_trailing(ply, path: Path) -> None:
    """Warn when the file holds data past the elements its header counts (plyfile reads the
    counted rows and ignores the rest, so a header count that is too small would drop part of
    the model without a word)."""
    start = _data_start(path)
    size = os.path.getsize(path)
    if ply.text:
        rows = sum(e.count for e in ply.elements)
        with open(path, "rb") as fh:
            fh.seek(start)
            lines = sum(1 for line in fh if line.strip())
        if lines > rows:
            warnings.warn(f"{path}: {lines - rows:,} lines after the {rows:,} rows the PLY header "
                          "counts are ignored; if they belong to the model, correct the "
                          "header's element counts", UserWarning, stacklevel=3)
        return
    extra = size - start - sum(_element_bytes(e) for e in ply.elements)
    if extra > 0:
        warnings.warn(f"{path}: {extra:,} bytes after the elements the PLY header counts are "
                      "ignored; if they belong to the model, correct the header's element "
                      "counts", UserWarning, stacklevel=3)


def read_ply(path: Path):
    """Read a PLY file: a mesh (``face`` or ``tristrips``), surfels or a point cloud.

    Parameters
    ----------
    path : pathlib.Path

    Returns
    -------
    TriangleMesh or PlyPoints
        A mesh when the file has faces and its vertices are not surfels (``nx ny nz radius``);
        else the vertex data, with the faces when there are any.

    Raises
    ------
    FileFormatError
        An unreadable, truncated or corrupt file, a header announcing more than the file holds,
        no vertices or no ``x y z``.

    Warns
    -----
    UserWarning
        Data past the rows the header counts (ignored).
    """
    try:
        with open(path, "rb") as fh:
            _check_ply_counts(fh, path)
        ply = _ply_data(path)
    except SurfidxError:
        raise
    except OSError as exc:
        raise FileFormatError(f"cannot read ({exc.strerror or exc})", path=path) from None
    except Exception as exc:  # plyfile raises many kinds on damaged input
        msg = str(exc).strip() or type(exc).__name__
        raise FileFormatError(f"not a readable PLY file ({msg}); the file may be truncated or "
                              "corrupt", path=path) from exc
    _warn_trailing(ply, path)
    names = [e.name for e in ply.elements]
    if "vertex" not in names:
        raise FileFormatError("PLY has no 'vertex' element", path=path)
    vertex = ply["vertex"].data
    props = vertex.dtype.names or ()
    for p in ("x", "y", "z"):
        if p not in props:
            raise FileFormatError(f"PLY vertex element lacks property '{p}'", path=path)
    if len(vertex) == 0:
        raise FileFormatError("PLY has no vertices", path=path)
    positions = check_coordinates(
        np.stack([vertex[a] for a in "xyz"], axis=1).astype(np.float64), path)
    colors = ply_colors(vertex)
    faces = None
    if "face" in names and len(ply["face"].data):
        faces = _faces_from_lists(ply["face"].data, path)
    elif "tristrips" in names and len(ply["tristrips"].data):
        faces = faces_from_strips(ply["tristrips"].data, path)
    is_surfel = all(p in props for p in ("nx", "ny", "nz", "radius"))
    if faces is not None and not is_surfel:
        return TriangleMesh(positions, faces, vertex_colors=colors, name=path.stem)
    return PlyPoints(vertex, faces)


def ply_colors(vertex):
    """The vertex colours of PLY vertex data (``red green blue``, ``r g b`` or ``diffuse_*``;
    floats of at most 1 scaled to 0..255), or None.

    Parameters
    ----------
    vertex : (n,) structured array

    Returns
    -------
    (n, 3) uint8 or None
    """
    props = vertex.dtype.names
    for names in (("red", "green", "blue"), ("r", "g", "b"), ("diffuse_red", "diffuse_green",
                                                            "diffuse_blue")):
        if all(n in props for n in names):
            c = np.stack([vertex[n] for n in names], axis=1)
            if np.issubdtype(c.dtype, np.floating) and c.size and np.nanmax(c) <= 1.0:
                c = c * 255.0
            if np.issubdtype(c.dtype, np.floating) and not np.all(np.isfinite(c)):
                raise InputError("vertex colours contain NaN or infinite values")
            return np.clip(np.round(c), 0, 255).astype(np.uint8)
    return None


def _list_column(data):
    for name in ("vertex_indices", "vertex_index"):
        if name in data.dtype.names:
            return data[name]
    return data[data.dtype.names[0]]


def _faces_from_lists(data, path):
    col = _list_column(data)
    if col.dtype != object:  # fixed-size lists already an (m, k) array
        polys = [np.asarray(col)]
    else:
        lens = np.fromiter((len(x) for x in col), np.int64, len(col))
        if np.all(lens == 3):
            return np.stack(col).astype(np.int64)
        polys = [np.asarray(x) for x in col]
    return triangulate_polygons(polys, path)


def triangulate_polygons(polys, path):
    """Polygons as triangle fans around their first corner.

    Parameters
    ----------
    polys : sequence of (k,) int or (m, k) int
        One polygon, or ``m`` polygons of ``k`` corners each.
    path : pathlib.Path
        Named in the error.

    Returns
    -------
    (t, 3) int64

    Raises
    ------
    FileFormatError
        A polygon of fewer than 3 corners.
    """
    tris = []
    for p in polys:
        p = np.asarray(p, np.int64)
        if p.ndim == 2:
            for j in range(1, p.shape[1] - 1):
                tris.append(p[:, [0, j, j + 1]])
            continue
        if len(p) < 3:
            raise FileFormatError(f"face with {len(p)} vertices", path=path)
        for j in range(1, len(p) - 1):
            tris.append(p[[0, j, j + 1]][None])
    return np.concatenate(tris).astype(np.int64)


def faces_from_strips(data, path):
    """The triangles of a PLY ``tristrips`` element: -1 separated strips, odd triangles with
    their winding flipped, degenerate ones dropped.

    Every window of three consecutive entries of one strip is a triangle, in strip order, odd
    when its first entry is an odd number of places into its strip (flipping it keeps the
    strip's orientation); a strip goes on across the element's rows until a -1.

    Parameters
    ----------
    data : (r,) structured array
        The element's rows; its list column (``vertex_indices``, ``vertex_index`` or the first)
        holds the strips.
    path : str or pathlib.Path
        Named in the error.

    Returns
    -------
    (m, 3) int64

    Raises
    ------
    FileFormatError
        When the strips hold no triangle.
    """
    col = _list_column(data)
    strips = np.concatenate([np.asarray(s, np.int64).ravel() for s in col])
    i = np.arange(max(len(strips) - 2, 0))
    i = i[(strips[i] >= 0) & (strips[i + 1] >= 0) & (strips[i + 2] >= 0)]
    if not len(i):
        raise FileFormatError("tristrips hold no triangle", path=path)
    start = np.zeros(len(strips), np.int64)          # where the strip of each entry starts
    after = np.flatnonzero(strips < 0) + 1
    after = after[after < len(strips)]
    start[after] = after
    start = np.maximum.accumulate(start)
    t = np.stack([strips[i], strips[i + 1], strips[i + 2]], axis=1)
    odd = (i - start[i]) % 2 == 1
    t[odd] = t[odd][:, [1, 0, 2]]
    keep = (t[:, 0] != t[:, 1]) & (t[:, 1] != t[:, 2]) & (t[:, 0] != t[:, 2])
    return t[keep]


def points_from_ply_data(points: PlyPoints, path: Path) -> SurfelSet:
    """The surfels of a PLY's vertex data: its own when it has ``nx ny nz radius``, else a point
    cloud's (:func:`surfidx.geometry.pointcloud.points_to_surfels`).

    Parameters
    ----------
    points : PlyPoints
    path : pathlib.Path
        Its stem names the surfels.

    Returns
    -------
    SurfelSet
    """
    v = points.vertex
    props = v.dtype.names
    pos = np.stack([v[a] for a in "xyz"], axis=1).astype(np.float64)
    colors = ply_colors(v)
    normals = None
    if all(p in props for p in ("nx", "ny", "nz")):
        normals = np.stack([v[p] for p in ("nx", "ny", "nz")], axis=1).astype(np.float64)
    if "radius" in props and normals is not None:
        return SurfelSet(pos, normals, np.asarray(v["radius"], np.float64), colors,
                         faces=points.faces, name=path.stem)
    from ..geometry.pointcloud import points_to_surfels    # numba, scipy.spatial: clouds only

    return points_to_surfels(pos, normals=normals, colors=colors, name=path.stem)


def write_ply(surfels: SurfelSet, path, *, extra: dict | None = None, text: bool = False,
              faces: bool = True) -> None:
    """Write a surfel PLY that plyfile, Open3D and MeshLab read.

    Parameters
    ----------
    surfels : SurfelSet
    path : str or os.PathLike
    extra : dict of str -> (n,) array, optional
        Additional per-surfel float64 properties (``{"sx": ..., "sy": ..., "sz": ...}``).
    text : bool
        ASCII instead of binary little-endian.
    faces : bool
        Write the surfels' ``faces``, when they have some, as a ``face`` element.

    Notes
    -----
    Positions, normals and radii are written as float32 (the raw format of the field: 96 bits of
    position per surfel); extra properties as float64; colours as uchar ``red green blue``.
    """
    from plyfile import PlyData, PlyElement

    n = len(surfels)
    fields = [("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("nx", "<f4"), ("ny", "<f4"),
              ("nz", "<f4"), ("radius", "<f4")]
    if surfels.has_color:
        fields += [("red", "u1"), ("green", "u1"), ("blue", "u1")]
    extra = extra or {}
    for key, val in extra.items():
        if np.shape(val) != (n,):
            raise InputError(f"extra property {key!r} must have shape ({n},)")
        fields.append((key, "<f8"))
    data = np.empty(n, dtype=fields)
    for i, a in enumerate("xyz"):
        data[a] = surfels.positions[:, i]
        data["n" + a] = surfels.normals[:, i]
    data["radius"] = surfels.radii
    if surfels.has_color:
        for i, c in enumerate(("red", "green", "blue")):
            data[c] = surfels.colors[:, i]
    for key, val in extra.items():
        data[key] = val
    elements = [PlyElement.describe(data, "vertex")]
    if faces and surfels.faces is not None and len(surfels.faces):
        fdata = np.empty(len(surfels.faces), dtype=[("vertex_indices", "i4", (3,))])
        fdata["vertex_indices"] = surfels.faces
        elements.append(PlyElement.describe(fdata, "face"))
    ply = PlyData(elements, text=text, comments=["written by surfidx"])
    write_atomic(path, lambda tmp: ply.write(str(tmp)))


def write_ply_model(model, path, *, text: bool = False) -> None:
    """Write a :class:`SurfelSet` as a surfel PLY (:func:`write_ply`): its surfels only, no
    ``face`` element (a model decoded to surfels keeps its grid's faces, but a surfel file is
    points); or a :class:`TriangleMesh`'s vertices as surfels (one per vertex, none added) with
    its faces.

    Parameters
    ----------
    model : SurfelSet or TriangleMesh
    path : str or os.PathLike
    text : bool
        ASCII instead of binary little-endian.
    """
    if isinstance(model, TriangleMesh):
        write_ply(model.to_surfels(max_edge_ratio=None), path, text=text)
        return
    write_ply(model, path, text=text, faces=False)
