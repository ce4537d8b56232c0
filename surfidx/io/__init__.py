"""Reading and writing surfel sets: surfel PLY, meshes (PLY faces or tristrips, OBJ with MTL
texture, OFF, STL, glTF/GLB with vertex colours or a base-colour texture) and point clouds (PLY,
PCD, XYZ, PTS); in-memory models (:func:`as_surfels`); PLY, OBJ and GLB output
(:func:`write_model`).

The readers keep the input's vertex order so surfels can be named by index. STL and glTF/GLB are
read through trimesh (their vertices, duplicated at seams and in STL's triangle soup, are merged
by exact position in order of first occurrence, so the surface is closed where it is); PCD
(ASCII and binary), XYZ and PTS by small bounded readers.
"""

from __future__ import annotations

import os
import re
import stat
import tempfile
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import FileFormatError, InputError, SurfidxError
from ..validate import as_array
from ..geometry.mesh import MAX_EDGE_RATIO, TriangleMesh
from ..geometry.pointcloud import points_to_surfels
from ..geometry.surfels import SurfelSet

__all__ = ["SUPPORTED_SUFFIXES", "MESH_SUFFIXES", "POINT_SUFFIXES", "OUTPUT_FORMATS",
           "MAX_TEXTURE_PIXELS", "MAX_COORDINATE", "MAX_TEXT_BYTES", "read_surfels", "read_mesh",
           "read_model", "Model", "join_surfels",
           "as_surfels", "model_hash", "write_ply", "write_model", "output_format",
           "write_atomic", "read_texture"]

#: Suffixes of the mesh formats read (PLY may also hold surfels or points).
MESH_SUFFIXES = (".ply", ".obj", ".off", ".stl", ".glb", ".gltf")
#: Suffixes of the point-cloud-only formats read.
POINT_SUFFIXES = (".pcd", ".xyz", ".pts")
#: Every suffix :func:`read_surfels` reads (and ``surfidx ingest`` looks for in folders).
SUPPORTED_SUFFIXES = MESH_SUFFIXES + POINT_SUFFIXES
#: Formats :func:`write_model` writes (``"sfz"``, the stored stream, is written by the callers
#: that hold one: ``surfidx get``/``decode``, :meth:`surfidx.Database.get`).
OUTPUT_FORMATS = ("ply", "obj", "glb")

MAX_TEXT_BYTES = 2 ** 31
"""Largest XYZ/PTS/ASCII-PCD point file read (2 GiB of text): numpy parses it whole."""

MAX_TEXTURE_PIXELS = 2 ** 27
"""Largest texture image read, in pixels (134,217,728: 16384 × 8192, 384 MiB as RGB); a larger
image is refused before it is decoded (a small PNG may declare 50,000 × 50,000 pixels)."""

MAX_COORDINATE = 1e30
"""Largest coordinate magnitude read: positions are stored as float32 (largest 3.4e38) and
their squares and cross products must stay finite."""

#: Image formats a texture may have (Pillow is never asked to run an external decoder).
_TEXTURE_FORMATS = ("PNG", "JPEG", "BMP", "TGA", "TIFF", "GIF", "WEBP", "PPM")


# ---------------------------------------------------------------------- public API
def read_surfels(path, *, texture=None, samples: int | None = None, seed: int = 0,
                 max_edge_ratio: float | None = MAX_EDGE_RATIO,
                 allow_outside_textures: bool = False) -> SurfelSet:
    """Read any supported file as surfels.

    Parameters
    ----------
    path : str or os.PathLike, or a model in memory
        A surfel PLY (x y z nx ny nz radius [red green blue]), a mesh (PLY with ``face`` or
        ``tristrips``, OBJ, OFF, STL, glTF/GLB) or a point cloud (PLY with positions and
        optional colours/normals, PCD, XYZ, PTS). A model in memory (a :class:`SurfelSet`,
        :class:`TriangleMesh`, ``(vertices, faces[, colours])``, an (n, 3) point array or a
        ``trimesh.Trimesh``/``PointCloud``) is converted by :func:`as_surfels`.
    texture : str or os.PathLike, optional
        Texture image for an OBJ whose UVs name no texture (overrides the MTL's ``map_Kd``).
    samples : int, optional
        For meshes: sample this many surfels uniformly over the surface instead of one per vertex.
    seed : int
        Seed of that sampling.
    max_edge_ratio : float or None
        For meshes converted one surfel per vertex: triangles with edges longer than this many
        times the median edge are first bisected, their new vertices becoming surfels too
        (:meth:`TriangleMesh.to_surfels`); ``None`` keeps exactly one surfel per vertex.
    allow_outside_textures : bool
        Use a texture that an OBJ's MTL names outside the model's folder (an absolute path, or
        one through ``..``); by default such a texture is skipped with a warning naming it, and
        the model is read without its colour.

    Returns
    -------
    SurfelSet
        The scan as it is: an open, pinched, genus > 0 or several-piece mesh gives the surfels
        of the mesh as read, nothing added and nothing dropped (what rendering, metrics and
        geodesics want). Storing, encoding and querying read through :func:`read_model`, which
        repairs such a mesh into closed genus-0 parts; its :attr:`Model.surfels` joins them.

    Raises
    ------
    FileFormatError
        Missing, unreadable, empty, truncated or corrupt file, an unknown format, or a texture
        image that is damaged or larger than :data:`MAX_TEXTURE_PIXELS`.
    InputError
        Valid file with unusable values (NaN coordinates or beyond :data:`MAX_COORDINATE`, too
        few points, points or faces that hold no surface).

    Warns
    -----
    UserWarning
        Degenerate faces dropped (how many), unused vertices dropped, a texture skipped.
    """
    if not isinstance(path, (str, os.PathLike)):
        return as_surfels(path, samples=samples, seed=seed, max_edge_ratio=max_edge_ratio)
    path = Path(path)
    try:
        model = _read_file(path, texture, samples, allow_outside_textures)
        if isinstance(model, TriangleMesh):
            with warnings.catch_warnings():
                warnings.simplefilter("default")
                return model.to_surfels(samples=samples, seed=seed,
                                        max_edge_ratio=max_edge_ratio)
        return model
    except SurfidxError as exc:
        if exc.path is None:
            raise type(exc)(exc.reason, path=path) from exc
        raise


def _read_file(path: Path, texture, samples, allow_outside_textures):
    """A file as a :class:`TriangleMesh` (a mesh) or a :class:`SurfelSet` (surfels, points)."""
    mesh = read_mesh(path, texture=texture, allow_outside_textures=allow_outside_textures,
                     _allow_points=True)
    if isinstance(mesh, _Points):
        if samples is not None:
            raise InputError("--samples needs a mesh; this file holds points only")
        return points_to_surfels(mesh.positions, normals=mesh.normals, colors=mesh.colors,
                                 name=path.stem)
    if isinstance(mesh, _PlyPoints) and mesh.faces is not None and samples is not None:
        mesh = TriangleMesh(np.stack([mesh.vertex[a] for a in "xyz"], axis=1), mesh.faces,
                            vertex_colors=_ply_colors(mesh.vertex), name=path.stem)
    if isinstance(mesh, TriangleMesh):
        return mesh
    if samples is not None:
        raise InputError("--samples needs a mesh; this file holds points only")
    return _points_from_ply_data(mesh, path)


def read_mesh(path, *, texture=None, allow_outside_textures: bool = False,
              _allow_points: bool = False):
    """Read a triangle mesh (PLY, OBJ, OFF, STL, glTF or GLB).

    Parameters
    ----------
    path : str or os.PathLike
    texture : str or os.PathLike, optional
        Texture image (OBJ only), overriding the MTL's.
    allow_outside_textures : bool
        Use an MTL texture outside the model's folder (see :func:`read_surfels`).

    Returns
    -------
    TriangleMesh

    Raises
    ------
    FileFormatError
        When the file cannot be read or holds no faces.
    """
    path = Path(path)
    _check_input_file(path)
    suffix = path.suffix.lower()
    if texture is not None and suffix != ".obj":
        raise InputError("--texture applies to OBJ files only", path=path)
    try:
        if suffix == ".ply":
            result = _read_ply(path)
        elif suffix == ".obj":
            result = _read_obj(path, texture, allow_outside_textures)
        elif suffix == ".off":
            result = _read_off(path)
        elif suffix in (".stl", ".glb", ".gltf"):
            result = _read_trimesh(path, allow_outside_textures)
        elif suffix == ".pcd":
            result = _read_pcd(path)
        elif suffix in (".xyz", ".pts"):
            result = _read_text_points(path)
        else:
            raise FileFormatError(
                f"unknown format {suffix or '(no suffix)'}; supported: "
                + ", ".join(SUPPORTED_SUFFIXES), path=path)
    except SurfidxError as exc:
        if exc.path is None:
            raise type(exc)(exc.reason, path=path) from exc
        raise
    if isinstance(result, TriangleMesh):
        result.name = path.stem if result.name is None else result.name
        return result
    if _allow_points:
        return result
    raise FileFormatError("the file holds points but no faces; it is not a mesh", path=path)


def write_ply(surfels: SurfelSet, path, *, extra: dict | None = None, text: bool = False) -> None:
    """Write a surfel PLY that plyfile, Open3D and MeshLab read.

    Parameters
    ----------
    surfels : SurfelSet
    path : str or os.PathLike
    extra : dict of str -> (n,) array, optional
        Additional per-surfel float64 properties (``{"sx": ..., "sy": ..., "sz": ...}``).
    text : bool
        ASCII instead of binary little-endian.

    Notes
    -----
    Positions, normals and radii are written as float32 (the raw format of the field: 96 bits of
    position per surfel); extra properties as float64; colours as uchar ``red green blue``.
    ``faces`` are written as a ``face`` element when present.
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
    if surfels.faces is not None and len(surfels.faces):
        fdata = np.empty(len(surfels.faces), dtype=[("vertex_indices", "i4", (3,))])
        fdata["vertex_indices"] = surfels.faces
        elements.append(PlyElement.describe(fdata, "face"))
    ply = PlyData(elements, text=text, comments=["written by surfidx"])
    write_atomic(path, lambda tmp: ply.write(str(tmp)))


def write_atomic(path, write, *, what: str = "") -> None:
    """Write a file whole or not at all: ``write(tmp)`` fills a temporary file in the target's
    folder, which then replaces ``path``; on an error the temporary file is removed.

    The temporary file is created exclusively under a fresh name (``.NAME.XXXXXXXX.part``), so
    nothing at a predictable name, a symlink in particular, is ever followed or overwritten;
    ``path`` itself is replaced, not written through (a symlink at ``path`` becomes the file).
    The file gets the permissions a newly created file has (``0o666`` less the umask).

    Raises
    ------
    FileFormatError
        Naming ``path`` (and ``what`` was being written) when the file cannot be written.
    """
    path = Path(path)
    tmp = None
    try:
        fd, name = tempfile.mkstemp(dir=path.parent, prefix="." + path.name + ".",
                                    suffix=".part")
        tmp = Path(name)
        try:
            os.fchmod(fd, 0o666 & ~_umask())
        finally:
            os.close(fd)
        write(tmp)
        os.replace(tmp, path)
        tmp = None
    except OSError as exc:
        raise FileFormatError(f"cannot write {what + ' ' if what else ''}({exc.strerror or exc})",
                              path=path) from exc
    finally:
        if tmp is not None:
            tmp.unlink(missing_ok=True)


def _umask() -> int:
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def read_texture(path, *, _source: str = "") -> np.ndarray:
    """Read a texture image as (h, w, 3) uint8.

    Only PNG, JPEG, BMP, TGA, TIFF, GIF, WebP and PPM images of at most
    :data:`MAX_TEXTURE_PIXELS` pixels are read; the size is checked before decoding.

    Raises
    ------
    FileFormatError
        Naming the image (and the file that refers to it) when it is missing, unreadable,
        damaged or too large.
    """
    from PIL import Image

    path = Path(path)
    where = f" ({_source})" if _source else ""
    if not path.is_file():
        raise FileFormatError(f"texture image not found{where}", path=path)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", Image.DecompressionBombWarning)
            im = Image.open(path, formats=_TEXTURE_FORMATS)
        with im:
            w, h = im.size
            if w * h > MAX_TEXTURE_PIXELS:
                raise FileFormatError(
                    f"texture image of {w} × {h} pixels exceeds the limit of "
                    f"{MAX_TEXTURE_PIXELS:,} pixels{where}; scale it down", path=path)
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", Image.DecompressionBombWarning)
                return np.asarray(im.convert("RGB"), dtype=np.uint8)
    except SurfidxError:
        raise
    except Image.DecompressionBombError as exc:
        size = re.search(r"\((\d+) pixels\)", str(exc))
        declared = f" (it declares {int(size.group(1)):,})" if size else ""
        raise FileFormatError(f"texture image exceeds the limit of {MAX_TEXTURE_PIXELS:,} "
                              f"pixels{declared}{where}; scale it down", path=path) from None
    except Exception as exc:  # Pillow raises many kinds on damaged images
        msg = str(exc).strip() or type(exc).__name__
        raise FileFormatError(f"cannot read the texture image ({msg}){where}", path=path) \
            from None


# ---------------------------------------------------------------------- file access
def _check_input_file(path: Path) -> None:
    """Refuse what is not a non-empty regular file, before opening it (a FIFO would block)."""
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


def _read_text(path: Path) -> str:
    """The file's text (undecodable bytes replaced); an OS error names the file."""
    try:
        with open(path, "rb") as fh:
            data = fh.read()
    except OSError as exc:
        raise FileFormatError(f"cannot read ({exc.strerror or exc})", path=path) from None
    return data.decode("utf-8", errors="replace")


def _check_coordinates(positions: np.ndarray, path: Path) -> np.ndarray:
    """Refuse absurdly large coordinates (beyond :data:`MAX_COORDINATE`; NaN and infinity are
    refused by the arrays' validation)."""
    with np.errstate(invalid="ignore"):
        bad = (np.abs(positions) > MAX_COORDINATE) & np.isfinite(positions)
    if bad.any():
        rows = bad.any(axis=1)
        row = int(np.flatnonzero(rows)[0])
        raise InputError(f"{int(rows.sum())} vertices have coordinates beyond "
                         f"±{MAX_COORDINATE:g} (first: vertex {row}, {positions[row].tolist()}); "
                         "rescale the model", path=path)
    return positions


# ---------------------------------------------------------------------- PLY
class _PlyPoints:
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


def _read_ply(path: Path):
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
    positions = _check_coordinates(
        np.stack([vertex[a] for a in "xyz"], axis=1).astype(np.float64), path)
    colors = _ply_colors(vertex)
    faces = None
    if "face" in names and len(ply["face"].data):
        faces = _faces_from_lists(ply["face"].data, path)
    elif "tristrips" in names and len(ply["tristrips"].data):
        faces = _faces_from_strips(ply["tristrips"].data, path)
    is_surfel = all(p in props for p in ("nx", "ny", "nz", "radius"))
    if faces is not None and not is_surfel:
        return TriangleMesh(positions, faces, vertex_colors=colors, name=path.stem)
    return _PlyPoints(vertex, faces)


def _ply_colors(vertex):
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
    return _triangulate_polygons(polys, path)


def _triangulate_polygons(polys, path):
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


def _faces_from_strips(data, path):
    """Triangles from -1 separated strips; odd triangles flip winding; degenerate ones dropped.

    Every window of three consecutive entries of one strip is a triangle, in strip order, odd
    when its first entry is an odd number of places into its strip."""
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


def _points_from_ply_data(points: _PlyPoints, path: Path) -> SurfelSet:
    v = points.vertex
    props = v.dtype.names
    pos = np.stack([v[a] for a in "xyz"], axis=1).astype(np.float64)
    colors = _ply_colors(v)
    normals = None
    if all(p in props for p in ("nx", "ny", "nz")):
        normals = np.stack([v[p] for p in ("nx", "ny", "nz")], axis=1).astype(np.float64)
    if "radius" in props and normals is not None:
        return SurfelSet(pos, normals, np.asarray(v["radius"], np.float64), colors,
                         faces=points.faces, name=path.stem)
    return points_to_surfels(pos, normals=normals, colors=colors, name=path.stem)


# ---------------------------------------------------------------------- OBJ
_OBJ_KEYS = ("v", "vt", "f", "mtllib")


def _obj_statements(lines, keys=_OBJ_KEYS) -> dict:
    """The statements of an OBJ file's lines that :func:`_read_obj` reads.

    Parameters
    ----------
    lines : iterable of str
    keys : sequence of str
        The statement keywords to collect (``"v"``, ``"vt"``, ``"f"``, ``"mtllib"``).

    Returns
    -------
    dict of str -> list of str
        Per keyword, the text after it of each of its lines, in file order (``f`` lines split
        into their corners, ``mtllib`` names stripped).
    """
    out = {k: [] for k in keys}
    v, vt, f, mtl = (out.get(k) for k in _OBJ_KEYS)
    for line in lines:
        if line.startswith("v "):
            if v is not None:
                v.append(line[2:])
        elif line.startswith("vt "):
            if vt is not None:
                vt.append(line[3:])
        elif line.startswith("f "):
            if f is not None:
                f.append(line[2:].split())
        elif line.startswith("mtllib "):
            if mtl is not None:
                mtl.append(line[7:].strip())
    return out


def _mtl_texture_name(text: str) -> str | None:
    """The image file named by the first ``map_Kd`` statement of an MTL file's text, or None."""
    for line in text.splitlines():
        parts = line.strip().split()
        if parts and parts[0] == "map_Kd" and len(parts) > 1:
            return parts[-1]
    return None


def _read_obj(path: Path, texture, allow_outside: bool = False) -> TriangleMesh:
    st = _obj_statements(_read_text(path).splitlines())
    v_lines, vt_lines, f_lines, mtllibs = (st[k] for k in _OBJ_KEYS)
    if not v_lines:
        raise FileFormatError("OBJ has no vertices ('v' lines)", path=path)
    verts, vcols = _parse_obj_vertices(v_lines, path)
    _check_coordinates(verts, path)
    nv = len(verts)
    if not f_lines:
        raise FileFormatError("OBJ has no faces ('f' lines)", path=path)
    uv = _parse_floats(vt_lines, 2, "texture coordinate", path) if vt_lines else None
    nvt = 0 if uv is None else len(uv)
    faces, uv_faces = _parse_obj_faces(f_lines, nv, nvt, path)
    tex = None
    if texture is not None:
        tex = read_texture(texture)
    elif mtllibs and uv is not None:
        tex = _texture_from_mtl(path, mtllibs, allow_outside)
    if tex is None or uv_faces is None:
        uv, uv_faces, tex = (None, None, None) if vcols is None or tex is None else (uv, uv_faces, tex)
    return TriangleMesh(verts, faces, vertex_colors=vcols, uv=uv, uv_faces=uv_faces, texture=tex,
                        name=path.stem)


def _parse_floats(lines, width, what, path):
    try:
        rows = [ln.split()[:width] for ln in lines]
        arr = np.array(rows, dtype=np.float64)
    except ValueError as exc:
        raise FileFormatError(f"malformed {what} line ({exc})", path=path) from exc
    if arr.ndim != 2 or arr.shape[1] != width:
        raise FileFormatError(f"a {what} line has fewer than {width} numbers", path=path)
    return arr


def _parse_obj_vertices(lines, path):
    try:
        rows = [ln.split() for ln in lines]
        widths = {len(r) for r in rows}
        if widths == {6} or widths == {7}:
            arr = np.array(rows, dtype=np.float64)
            pos, col = arr[:, :3], arr[:, 3:6]
            if np.nanmax(col) <= 1.0:
                col = col * 255.0
            if not np.all(np.isfinite(col)):
                raise FileFormatError("vertex colours contain NaN", path=path)
            return pos, np.clip(np.round(col), 0, 255).astype(np.uint8)
        arr = np.array([r[:3] for r in rows], dtype=np.float64)
    except SurfidxError:
        raise
    except ValueError as exc:
        raise FileFormatError(f"malformed vertex line ({exc})", path=path) from exc
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise FileFormatError("a vertex line has fewer than 3 coordinates", path=path)
    return arr, None


def _parse_obj_faces(f_lines, nv, nvt, path):
    lens = np.fromiter((len(f) for f in f_lines), np.int64, len(f_lines))
    if lens.min() < 3:
        raise FileFormatError("a face has fewer than 3 vertices", path=path)
    tokens = [t for f in f_lines for t in f]
    parts = [t.split("/") for t in tokens]
    try:
        vi = np.array([int(p[0]) for p in parts], np.int64)
        has_vt = nvt > 0 and all(len(p) > 1 and p[1] for p in parts)
        ti = np.array([int(p[1]) for p in parts], np.int64) if has_vt else None
    except (ValueError, OverflowError) as exc:
        raise FileFormatError(f"malformed face line ({exc})", path=path) from exc

    def fix(idx, count, what):
        idx = np.where(idx < 0, idx + count, idx - 1)
        if idx.size and (idx.min() < 0 or idx.max() >= count):
            raise FileFormatError(f"a face refers to a {what} that does not exist "
                                  f"(file has {count})", path=path)
        return idx

    vi = fix(vi, nv, "vertex")
    ti = fix(ti, nvt, "texture coordinate") if ti is not None else None
    offsets = np.concatenate([[0], np.cumsum(lens)])
    if np.all(lens == 3):
        return vi.reshape(-1, 3), None if ti is None else ti.reshape(-1, 3)
    tris, ttris = [], []
    for k in np.unique(lens):
        rows = np.flatnonzero(lens == k)
        base = offsets[rows]
        for j in range(1, k - 1):
            sel = np.stack([base, base + j, base + j + 1], axis=1)
            tris.append(vi[sel])
            if ti is not None:
                ttris.append(ti[sel])
    return np.concatenate(tris), (np.concatenate(ttris) if ti is not None else None)


def _texture_from_mtl(path: Path, mtllibs, allow_outside: bool = False):
    """The first ``map_Kd`` image of the OBJ's material libraries, or None.

    A texture outside the OBJ's folder (after resolving ``..`` and symlinks) is used only with
    ``allow_outside``; otherwise it is skipped with a warning, and the model has no texture.
    """
    folder = path.parent.resolve()
    for lib in mtllibs:
        mtl = path.parent / lib
        if not mtl.is_file():
            warnings.warn(f"{path}: material library {lib} not found; no texture", UserWarning)
            continue
        name = _mtl_texture_name(_read_text(mtl))
        if name is None:
            continue
        image = mtl.parent / name
        if not allow_outside and not image.resolve().is_relative_to(folder):
            warnings.warn(
                f"{path}: texture {image} (map_Kd in {mtl.name}) lies outside the "
                "model's folder; skipped, the model is read without its texture (allow "
                "it with allow_outside_textures=True, --allow-outside-textures)",
                UserWarning)
            return None
        return read_texture(image, _source=f"map_Kd in {mtl}, used by {path}")
    return None


# ---------------------------------------------------------------------- OFF
_OFF_HEADER = re.compile(r"(ST)?(C)?(N)?(4)?(n)?OFF")


def _read_off(path: Path) -> TriangleMesh:
    """Read an ASCII OFF file as common tools write it.

    The keyword may carry the prefixes ``ST`` (texture coordinates), ``C`` (colours: RGB or
    RGBA, 0..1 or 0..255), ``N`` (normals) and ``4`` (homogeneous coordinates, divided by w);
    the counts ``V F E`` follow on the keyword's line or the next one; ``#`` starts a comment.
    Each vertex and each face is one line; a face line is ``k i_1 … i_k`` and may end with a
    face colour (ignored).
    """
    text = _read_text(path)
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
            faces = _triangulate_polygons([np.array(r[1:1 + int(r[0])], np.int64) for r in frows],
                                          path)
    except SurfidxError:
        raise
    except (ValueError, IndexError, OverflowError) as exc:
        raise FileFormatError(f"malformed OFF data ({exc})", path=path) from exc
    positions = arr[:, :3]
    if homogeneous:
        with np.errstate(divide="ignore", invalid="ignore"):
            positions = positions / arr[:, 3:4]
    _check_coordinates(positions, path)
    if faces.size and (faces.min() < 0 or faces.max() >= nv):
        raise FileFormatError("a face refers to a vertex that does not exist", path=path)
    if not len(faces):
        raise FileFormatError("OFF file has no faces", path=path)
    return TriangleMesh(positions, faces, vertex_colors=vcols, name=path.stem)


# ---------------------------------------------------------------------- point clouds
class _Points:
    """Points read from a point-cloud file: positions, optional normals and colours."""

    def __init__(self, positions, normals=None, colors=None):
        self.positions = positions
        self.normals = normals
        self.colors = colors
        self.faces = None


def _colors_of(c, what: str, path) -> np.ndarray:
    """(n, 3) colours 0..1 (all floats at most 1) or 0..255 as uint8."""
    c = np.asarray(c, np.float64)
    if not np.all(np.isfinite(c)):
        raise FileFormatError(f"{what} colours contain NaN or infinite values", path=path)
    if c.size and c.max() <= 1.0:
        c = c * 255.0
    return np.clip(np.round(c), 0, 255).astype(np.uint8)


def _check_text_size(path: Path) -> None:
    size = path.stat().st_size
    if size > MAX_TEXT_BYTES:
        raise FileFormatError(f"text point file of {size:,} bytes exceeds the limit of "
                              f"{MAX_TEXT_BYTES:,} bytes; convert it to binary PLY or PCD",
                              path=path)


def _loadtxt(lines, path: Path, what: str) -> np.ndarray:
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


def _read_text_points(path: Path) -> _Points:
    """XYZ (``x y z``, ``x y z r g b``, ``x y z nx ny nz``, ``x y z nx ny nz r g b``) or PTS
    (an optional first line with the point count, then ``x y z [intensity] [r g b]``)."""
    _check_text_size(path)
    lines = _read_text(path).splitlines()
    what = path.suffix.lower().lstrip(".").upper()
    count = None
    if what == "PTS" and lines and re.fullmatch(r"\s*\d+\s*", lines[0]):
        count = int(lines[0])
        lines = lines[1:]
    arr = _loadtxt(lines, path, what)
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
            colors = _colors_of(arr[:, k - 3:], what, path)
    else:
        if k not in (3, 6, 9):
            raise FileFormatError(f"XYZ lines hold {k} numbers; expected x y z, x y z r g b, "
                                  "x y z nx ny nz or x y z nx ny nz r g b", path=path)
        if k == 9:
            normals, colors = arr[:, 3:6], _colors_of(arr[:, 6:9], what, path)
        elif k == 6:
            extra = arr[:, 3:6]
            lengths = np.linalg.norm(extra, axis=1)
            if np.all(np.abs(lengths - 1.0) < 1e-3):
                normals = extra
            elif np.all((extra >= 0) & (extra <= 255)):
                colors = _colors_of(extra, what, path)
            else:
                raise FileFormatError("XYZ columns 4-6 are neither unit normals nor colours "
                                      "(0..1 or 0..255)", path=path)
    return _Points(_check_coordinates(pos, path), normals, colors)


_PCD_TYPES = {("F", 4): "<f4", ("F", 8): "<f8", ("I", 1): "i1", ("I", 2): "<i2",
              ("I", 4): "<i4", ("I", 8): "<i8", ("U", 1): "u1", ("U", 2): "<u2",
              ("U", 4): "<u4", ("U", 8): "<u8"}


def _read_pcd(path: Path) -> _Points:
    """A PCD file (Point Cloud Library), ``DATA ascii`` or ``binary``: fields ``x y z``,
    optionally ``normal_x normal_y normal_z`` and ``rgb``/``rgba`` (packed) or ``r g b``."""
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
        n = int(header["POINTS"][0]) if "POINTS" in header else \
            int(header["WIDTH"][0]) * int(header.get("HEIGHT", ["1"])[0])
    except (KeyError, ValueError, IndexError) as exc:
        raise FileFormatError(f"PCD header lacks or garbles a line ({exc})", path=path) from None
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
        with open(path, "rb") as fh:
            fh.seek(offset)
            rows = np.frombuffer(fh.read(n * dtype.itemsize), dtype=dtype, count=n)
    elif data_kind == "ascii":
        _check_text_size(path)
        text = _read_text(path)
        body = text.encode("latin-1", "replace")[offset:].decode("latin-1").splitlines()
        arr = _loadtxt(body, path, "PCD")
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
    keep = np.all(np.isfinite(pos), axis=1)             # PCL marks missing points with NaN
    pos = _check_coordinates(pos[keep], path)
    normals = None
    if all(f"normal_{a}" in fields for a in "xyz"):
        normals = np.stack([rows[f"normal_{a}"] for a in "xyz"], axis=1).astype(np.float64)[keep]
        if not np.all(np.isfinite(normals)):
            normals = None
    colors = None
    for name in ("rgb", "rgba"):
        if name in fields:
            packed = np.ascontiguousarray(rows[name]).view("<u4")[keep]
            colors = np.stack([(packed >> 16) & 255, (packed >> 8) & 255, packed & 255],
                              axis=1).astype(np.uint8)
    if colors is None and all(c in fields for c in "rgb"):
        colors = _colors_of(np.stack([rows[c] for c in "rgb"], axis=1)[keep], "PCD", path)
    return _Points(pos, normals, colors)


# ---------------------------------------------------------------------- STL, glTF, GLB
def _merge_positions(vertices: np.ndarray):
    """Vertices merged by exact position, in order of first occurrence: ``(unique, index)``
    with ``vertices == unique[index]``."""
    uniq, first, inverse = np.unique(vertices, axis=0, return_index=True, return_inverse=True)
    order = np.argsort(first, kind="stable")
    rank = np.empty(len(order), np.int64)
    rank[order] = np.arange(len(order))
    return vertices[first[order]], rank[np.asarray(inverse).ravel()]


def _image_array(image, path) -> np.ndarray | None:
    if image is None:
        return None
    w, h = image.size
    if w * h > MAX_TEXTURE_PIXELS:
        raise FileFormatError(f"texture image of {w} × {h} pixels exceeds the limit of "
                              f"{MAX_TEXTURE_PIXELS:,} pixels; scale it down", path=path)
    return np.asarray(image.convert("RGB"), dtype=np.uint8)


def _mesh_parts(tm, path):
    """``(vertices, faces, vertex colours or None, uv or None, texture or None)`` of one
    ``trimesh.Trimesh``: a base-colour texture (times its factor) with UVs, or vertex or face
    colours, or a uniform base colour."""
    verts = np.asarray(tm.vertices, np.float64)
    faces = np.asarray(tm.faces, np.int64)
    visual = tm.visual
    kind = getattr(visual, "kind", None)
    colors, uv, tex = None, None, None
    if kind == "texture":
        mat = getattr(visual, "material", None)
        image = getattr(mat, "baseColorTexture", None) or getattr(mat, "image", None)
        factor = getattr(mat, "baseColorFactor", None)
        tex = _image_array(image, path)
        if tex is not None and getattr(visual, "uv", None) is not None and \
                len(visual.uv) == len(verts):
            uv = np.asarray(visual.uv, np.float64)
            if factor is not None and image is getattr(mat, "baseColorTexture", None):
                f = np.asarray(factor, np.float64)[:3] / 255.0
                tex = np.clip(np.round(tex * f), 0, 255).astype(np.uint8)
        else:
            tex = None
            if factor is not None:
                colors = np.tile(np.asarray(factor, np.uint8)[:3], (len(verts), 1))
    elif kind in ("vertex", "face"):
        colors = np.asarray(visual.vertex_colors, np.uint8)[:, :3]
    return verts, faces, colors, uv, tex


def _from_trimesh(obj, path=None, name=None):
    """A ``trimesh.Trimesh``, ``PointCloud`` or ``Scene`` as a :class:`TriangleMesh` (vertices
    merged by position, see :func:`_merge_positions`) or as :class:`_Points`."""
    import trimesh

    if isinstance(obj, trimesh.Scene):
        geoms = obj.dump(concatenate=False) if len(obj.geometry) else []
    else:
        geoms = [obj]
    meshes = [g for g in geoms if isinstance(g, trimesh.Trimesh) and len(g.faces)]
    clouds = [g for g in geoms if isinstance(g, trimesh.PointCloud) and len(g.vertices)]
    if not meshes:
        if not clouds:
            raise FileFormatError("holds no triangles and no points", path=path)
        pos = np.vstack([np.asarray(c.vertices, np.float64) for c in clouds])
        cols = [getattr(c, "colors", None) for c in clouds]
        colors = None
        if all(c is not None and len(c) for c in cols):
            colors = np.vstack([np.asarray(c, np.uint8)[:, :3] for c in cols])
        return _Points(_check_coordinates(pos, path), None, colors)
    parts = [_mesh_parts(m, path) for m in meshes]
    if len(parts) == 1 and parts[0][4] is not None:
        verts, faces, colors, uv, tex = parts[0]
        merged, index = _merge_positions(verts)
        return TriangleMesh(_check_coordinates(merged, path), index[faces], uv=uv, uv_faces=faces,
                            texture=tex, name=name)
    # several parts: textures are sampled at the vertices (colours per vertex), then joined
    vs, fs, cs, base = [], [], [], 0
    for verts, faces, colors, uv, tex in parts:
        if tex is not None:
            from ..geometry.mesh import sample_texture

            colors = np.clip(np.round(sample_texture(tex, uv)), 0, 255).astype(np.uint8)
        vs.append(verts)
        fs.append(faces + base)
        cs.append(colors)
        base += len(verts)
    verts = np.vstack(vs)
    colors = np.vstack(cs) if all(c is not None for c in cs) else None
    merged, index = _merge_positions(verts)
    if colors is not None:
        first = np.full(len(merged), -1, np.int64)
        first[index[::-1]] = np.arange(len(index))[::-1]
        colors = colors[first]
    return TriangleMesh(_check_coordinates(merged, path), index[np.vstack(fs)],
                        vertex_colors=colors, name=name)


def _read_trimesh(path: Path, allow_outside: bool = False):
    """STL, glTF or GLB through trimesh. A ``.gltf`` refers to its buffers and images by
    name: only files in its own folder are read unless ``allow_outside``."""
    try:
        import trimesh
    except ImportError as exc:                              # pragma: no cover - a dependency
        raise FileFormatError(f"reading {path.suffix} needs trimesh ({exc})", path=path) \
            from None
    if path.suffix.lower() == ".gltf" and not allow_outside:
        _check_gltf_uris(path)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            loaded = trimesh.load(str(path), process=False, force=None)
    except MemoryError:
        raise
    except Exception as exc:  # trimesh raises many kinds on damaged input
        msg = str(exc).strip() or type(exc).__name__
        raise FileFormatError(f"not a readable {path.suffix.lstrip('.').upper()} file ({msg})",
                              path=path) from None
    return _from_trimesh(loaded, path, name=path.stem)


def _check_gltf_uris(path: Path) -> None:
    import json

    try:
        doc = json.loads(_read_text(path))
    except ValueError as exc:
        raise FileFormatError(f"not a readable glTF file ({exc})", path=path) from None
    folder = path.parent.resolve()
    for key in ("buffers", "images"):
        for item in doc.get(key, []) if isinstance(doc, dict) else []:
            uri = item.get("uri") if isinstance(item, dict) else None
            if isinstance(uri, str) and not uri.startswith("data:"):
                target = (path.parent / uri).resolve()
                if not target.is_relative_to(folder):
                    raise FileFormatError(
                        f"refers to {uri} outside the model's folder; allow it with "
                        "allow_outside_textures=True (--allow-outside-textures)", path=path)


# ---------------------------------------------------------------------- models to store
@dataclass(frozen=True)
class Model:
    """A model read for storing (:func:`read_model`): its parts, each closed genus-0 surfels.

    Attributes
    ----------
    parts : tuple of SurfelSet
        One per kept piece, largest first. A part of a repaired mesh carries
        :attr:`SurfelSet.patch` / :attr:`SurfelSet.patch_cut` when the repair added faces.
    reports : tuple of (surfidx.topology.RepairReport or None)
        What the repair added to each part; ``None`` for a part taken as it is (a closed
        genus-0 mesh, a point cloud, surfels).
    topology : surfidx.topology.TopologyReport or None
        The input mesh's analysis (holes, pinches, genus, pieces); ``None`` for points or
        surfels.
    kind : {"mesh", "points", "surfels"}
        What the file held.
    parts_dropped : int
        Tiny pieces dropped (:func:`surfidx.topology.split_parts`' threshold).
    dropped_vertices : int
        Their vertices.
    areas : tuple of float
        Surface area of each part's closed mesh (0 for points and surfels).
    name : str or None
    face_patches : tuple of ((m,) int64 or None)
        Per part, the virtual patch of each of its surfels' faces (-1 real; the codec's
        ``face_patch``, which tells a patch face whose three corners are scan vertices from the
        scan's own); None for a part with nothing virtual.
    """

    parts: tuple
    reports: tuple
    topology: object = None
    kind: str = "mesh"
    parts_dropped: int = 0
    dropped_vertices: int = 0
    areas: tuple = ()
    name: str | None = None
    face_patches: tuple = ()

    def face_patch(self, i: int):
        """Part ``i``'s face labels (:attr:`face_patches`), None when it has none."""
        return self.face_patches[i] if i < len(self.face_patches) else None

    @property
    def repaired(self) -> bool:
        """Whether anything was added or split (a report on any part) or a piece dropped."""
        return any(r is not None for r in self.reports) or self.parts_dropped > 0

    @property
    def surfels(self) -> SurfelSet:
        """The surfels of all parts (:func:`join_surfels`; the part itself when there is one)."""
        return join_surfels(self.parts, name=self.name)

    @property
    def n_surfels(self) -> int:
        return int(sum(len(p) for p in self.parts))

    def summary(self) -> dict:
        """What the repair added, for records and ``surfidx info``/``show``.

        Returns
        -------
        dict
            ``parts``, ``parts_dropped``, ``dropped_vertices``, ``holes_filled``,
            ``handles_cut``, ``pinched_vertices``, ``nonmanifold_edges``, ``flipped_faces``,
            ``virtual_surfels``, ``virtual_area_share`` (virtual faces' area over the closed
            parts' area, all parts together), ``genus_before`` (per part) and ``repaired``.
        """
        reps = [r for r in self.reports if r is not None]
        total = float(sum(self.areas))
        virt = float(sum(r.virtual_area_share * a for r, a in zip(self.reports, self.areas)
                         if r is not None))
        return {"parts": len(self.parts), "parts_dropped": int(self.parts_dropped),
                "dropped_vertices": int(self.dropped_vertices),
                "holes_filled": int(sum(r.holes_filled for r in reps)),
                "handles_cut": int(sum(r.handles_cut for r in reps)),
                "pinched_vertices": int(sum(r.pinched_vertices for r in reps)),
                "nonmanifold_edges": int(sum(r.nonmanifold_edges for r in reps)),
                "flipped_faces": int(sum(r.flipped_faces for r in reps)),
                "virtual_surfels": int(sum(int(p.virtual.sum()) for p in self.parts)),
                "virtual_area_share": virt / total if total > 0 else 0.0,
                "genus_before": [None if r is None else int(r.genus_before)
                                 for r in self.reports],
                "repaired": self.repaired}


def join_surfels(parts, *, name=None) -> SurfelSet:
    """Several surfel sets as one: arrays stacked, faces and patch labels renumbered.

    Parameters
    ----------
    parts : sequence of SurfelSet
        Patches of part ``i`` follow those of parts ``0..i-1``; so do their cuts.
    name : str, optional
        Name of the result (default: the first part's).

    Returns
    -------
    SurfelSet
        ``parts[0]`` itself when there is one part (and ``name`` is None or its own). Colours
        are kept when every part has them; faces when every part has them.

    Raises
    ------
    InputError
        When ``parts`` is empty.
    """
    parts = list(parts)
    if not parts:
        raise InputError("join_surfels needs at least one surfel set")
    if len(parts) == 1 and (name is None or parts[0].name == name):
        return parts[0]
    colors = None
    if all(p.colors is not None for p in parts):
        colors = np.vstack([p.colors for p in parts])
    faces, patch, patch_cut = None, None, None
    if all(p.faces is not None for p in parts):
        offs = np.cumsum([0] + [len(p) for p in parts[:-1]])
        faces = np.vstack([p.faces + o for p, o in zip(parts, offs)])
    if any(p.patch is not None for p in parts):
        labels, cuts, pbase, cbase = [], [], 0, 0
        for p in parts:
            if p.patch is None:
                labels.append(np.full(len(p), -1, np.int64))
                continue
            lab = p.patch.astype(np.int64)
            labels.append(np.where(lab >= 0, lab + pbase, -1))
            pc = p.patch_cut.astype(np.int64)
            cuts.append(np.where(pc >= 0, pc + cbase, -1))
            pbase += len(pc)
            cbase += int(pc.max()) + 1 if (pc >= 0).any() else 0
        patch = np.concatenate(labels)
        patch_cut = np.concatenate(cuts) if cuts else np.zeros(0, np.int64)
    return SurfelSet(np.vstack([p.positions for p in parts]),
                     np.vstack([p.normals for p in parts]),
                     np.concatenate([p.radii for p in parts]), colors, faces=faces,
                     name=parts[0].name if name is None else name, patch=patch,
                     patch_cut=patch_cut)


def read_model(path, *, texture=None, samples: int | None = None, seed: int = 0,
               max_edge_ratio: float | None = MAX_EDGE_RATIO,
               allow_outside_textures: bool = False, options=None,
               name: str | None = None) -> Model:
    """Read any file (or model in memory) for storing: every mesh as it is, repaired to parts.

    A mesh that is one closed, manifold, genus-0 piece becomes exactly
    :func:`read_surfels`' surfels (one part, no patch labels), so its streams and descriptors
    are those of a plain read. Any other mesh is split into its pieces
    (:func:`surfidx.topology.split_parts`: pinched vertices split; pieces under
    ``max(options.min_part_vertices, options.min_part_share * V)`` vertices dropped, except the
    largest, with a ``UserWarning`` saying how many), and each piece brought to a closed genus-0
    surface (:func:`surfidx.topology.close_surface`: handles cut, holes and cut sides capped by
    fair virtual patches), then converted to surfels as :meth:`TriangleMesh.to_surfels` does,
    with :attr:`SurfelSet.patch` marking the virtual surfels (a vertex added by bisection is
    virtual when every face around it is virtual). Colours (vertex colours, or the texture
    averaged at the vertices) go with the scan's vertices; virtual vertices take the harmonic
    interpolation of their rim's. Point clouds and surfel files are one part as
    :func:`read_surfels` reads them (a point cloud's proxy surface is closed by construction).

    Parameters
    ----------
    path : str or os.PathLike, or a model in memory
        As for :func:`read_surfels` (a ``TriangleMesh``, ``(vertices, faces[, colours])`` or a
        trimesh object is repaired as a file's mesh is).
    texture, samples, seed, max_edge_ratio, allow_outside_textures
        As for :func:`read_surfels`.
    options : surfidx.topology.RepairOptions, optional
        Tuning of the repair (default ``RepairOptions()``).
    name : str, optional
        The model's name (default: the file stem or the model's own).

    Returns
    -------
    Model

    Raises
    ------
    FileFormatError
        As for :func:`read_surfels`.
    InputError
        As for :func:`read_surfels`.
    TopologyError
        A piece that cannot be closed to a sphere (non-orientable: a Möbius strip, a Klein
        bottle), or faces none of which is a triangle.

    Warns
    -----
    UserWarning
        Tiny pieces dropped (how many, how many vertices), degenerate faces dropped.
    """
    from ..topology import RepairOptions

    options = RepairOptions() if options is None else options
    if not isinstance(path, (str, os.PathLike)):
        mesh = _memory_mesh(path, name)
        if not isinstance(mesh, TriangleMesh):
            s = as_surfels(path, samples=samples, seed=seed, max_edge_ratio=max_edge_ratio,
                           name=name)
            kind = "points" if s.faces is None else "surfels"
            return Model(parts=(s,), reports=(None,), kind=kind, areas=(0.0,),
                         name=s.name if name is None else name)
        return _mesh_model(mesh, samples, seed, max_edge_ratio, options,
                           name or mesh.name, None)
    path = Path(path)
    try:
        model = _read_file(path, texture, samples, allow_outside_textures)
        if isinstance(model, TriangleMesh):
            return _mesh_model(model, samples, seed, max_edge_ratio, options,
                               name or model.name, path)
        kind = "surfels" if model.faces is not None or model.name is None else "points"
        return Model(parts=(model,), reports=(None,), kind=kind, areas=(0.0,),
                     name=name or model.name)
    except SurfidxError as exc:
        if exc.path is None:
            raise type(exc)(exc.reason, path=path) from exc
        raise


def _memory_mesh(model, name):
    """The :class:`TriangleMesh` of an in-memory mesh model, else ``None``."""
    if isinstance(model, TriangleMesh):
        return model
    if isinstance(model, tuple) and len(model) in (2, 3) and model[1] is not None:
        return TriangleMesh(model[0], model[1], vertex_colors=model[2] if len(model) == 3
                            else None, name=name)
    if type(model).__module__.startswith("trimesh"):
        m = _from_trimesh(model, name=name or getattr(model, "metadata", {}).get("name"))
        return m if isinstance(m, TriangleMesh) else None
    return None


def _mesh_model(mesh: TriangleMesh, samples, seed, max_edge_ratio, options, name, path):
    """:func:`read_model` of one mesh: as it is when it is a sphere, else repaired to parts."""
    from ..topology import analyse, close_surface, closed_mesh, split_parts

    if name is not None:
        mesh.name = name
    if not len(mesh.faces):
        raise InputError("the mesh has no faces; read it as a point cloud instead")
    topo = analyse(mesh.vertices, mesh.faces, options=options)

    def convert(m):
        with warnings.catch_warnings():
            warnings.simplefilter("default")
            return m.to_surfels(samples=samples, seed=seed, max_edge_ratio=max_edge_ratio,
                                return_face_patch=True)

    if topo.is_sphere:
        s, _ = convert(mesh)
        return Model(parts=(s,), reports=(None,), topology=topo, kind="mesh",
                     areas=(float(mesh.face_areas().sum()),), name=name)
    colors = mesh._vertex_colors()
    pieces = split_parts(mesh.vertices, mesh.faces, options=options)
    parts, reports, areas, fps = [], [], [], []
    for i, part in enumerate(pieces.parts):
        try:
            closed = close_surface(part.vertices, part.faces, options=options)
        except SurfidxError as exc:
            what = f"piece {i + 1} of {len(pieces.parts)} ({len(part.vertices)} vertices): " \
                if len(pieces.parts) > 1 else ""
            raise type(exc)(what + exc.reason, path=path) from exc
        cm = closed_mesh(closed, colors=None if colors is None else colors[part.vertex_index],
                         name=name)
        s, fp = convert(cm)
        parts.append(s)
        fps.append(fp)
        reports.append(closed.report)
        areas.append(float(cm.face_areas().sum()))
    return Model(parts=tuple(parts), reports=tuple(reports), topology=topo, kind="mesh",
                 parts_dropped=pieces.dropped, dropped_vertices=pieces.dropped_vertices,
                 areas=tuple(areas), name=name, face_patches=tuple(fps))


# ---------------------------------------------------------------------- models in memory
def as_surfels(model, *, samples: int | None = None, seed: int = 0,
               max_edge_ratio: float | None = MAX_EDGE_RATIO, name: str | None = None,
               **read_options) -> SurfelSet:
    """Any model, in memory or in a file, as surfels.

    Parameters
    ----------
    model : SurfelSet, TriangleMesh, tuple, (n, 3) float64, trimesh object, str or os.PathLike
        A :class:`SurfelSet` (returned as it is); a :class:`TriangleMesh`; ``(vertices,
        faces)`` or ``(vertices, faces, colours)`` with (n, 3) float64 vertices, (m, 3) int64
        faces (``None`` for a point cloud) and (n, 3) uint8 colours; an (n, 3) array of points;
        a ``trimesh.Trimesh``, ``PointCloud`` or ``Scene``; or a file (:func:`read_surfels`,
        which ``read_options`` go to).
    samples, seed, max_edge_ratio
        As for :func:`read_surfels` (meshes only).
    name : str, optional
        Name of the result (default: the model's own, else None).

    Returns
    -------
    SurfelSet

    Raises
    ------
    InputError
        A model of another type, or arrays that are not a valid mesh or point cloud.
    """
    if isinstance(model, (str, os.PathLike)):
        return read_surfels(model, samples=samples, seed=seed, max_edge_ratio=max_edge_ratio,
                            **read_options)
    if read_options.get("texture") is not None:
        raise InputError("texture applies to OBJ files only, not to a model in memory")
    if isinstance(model, SurfelSet):
        if samples is not None:
            raise InputError("samples needs a mesh; a SurfelSet is used as it is")
        if name is not None and model.name != name:
            model = SurfelSet(model.positions, model.normals, model.radii, model.colors,
                              faces=model.faces, name=name)
        return model
    mesh = model
    if type(model).__module__.startswith("trimesh"):
        mesh = _from_trimesh(model, name=name or getattr(model, "metadata", {}).get("name"))
    elif isinstance(model, tuple):
        if len(model) not in (2, 3):
            raise InputError(f"a model tuple is (vertices, faces) or (vertices, faces, colours), "
                             f"got {len(model)} items")
        verts, faces = model[0], model[1]
        colors = model[2] if len(model) == 3 else None
        if faces is None:
            mesh = _Points(as_array(verts, "vertices", shape=(None, 3)), None, colors)
        else:
            mesh = TriangleMesh(verts, faces, vertex_colors=colors, name=name)
    elif isinstance(model, np.ndarray):
        mesh = _Points(as_array(model, "points", shape=(None, 3)))
    elif not isinstance(model, TriangleMesh):
        raise InputError(f"cannot read a model from a {type(model).__name__}; give a file, a "
                         "SurfelSet, a TriangleMesh, (vertices, faces[, colours]), an (n, 3) "
                         "point array or a trimesh object")
    if isinstance(mesh, _Points):
        if samples is not None:
            raise InputError("samples needs a mesh; this model holds points only")
        return points_to_surfels(mesh.positions, normals=mesh.normals, colors=mesh.colors,
                                 name=name)
    if name is not None:
        mesh.name = name
    with warnings.catch_warnings():
        warnings.simplefilter("default")
        return mesh.to_surfels(samples=samples, seed=seed, max_edge_ratio=max_edge_ratio)


def model_hash(surfels: SurfelSet) -> str:
    """SHA-256 hex of a surfel set's arrays (positions, normals, radii, colours, faces): the
    content hash of a model given in memory.

    Parameters
    ----------
    surfels : SurfelSet

    Returns
    -------
    str
    """
    import hashlib

    h = hashlib.sha256(b"surfidx surfels v1")
    for arr in (surfels.positions, surfels.normals, surfels.radii, surfels.colors, surfels.faces):
        h.update(b"-" if arr is None else np.ascontiguousarray(arr).tobytes())
    return h.hexdigest()


# ---------------------------------------------------------------------- writing models
def output_format(path, format: str | None = None, *, allowed=OUTPUT_FORMATS) -> str:
    """The output format of ``path``: ``format`` when given, else its suffix.

    Parameters
    ----------
    path : str or os.PathLike
    format : str, optional
        One of ``allowed``.
    allowed : sequence of str

    Returns
    -------
    str

    Raises
    ------
    InputError
        An unknown ``format``, or a suffix that names none of ``allowed`` (never a silent PLY).
    """
    if format is not None:
        fmt = str(format).lower().lstrip(".")
        if fmt not in allowed:
            raise InputError(f"unknown output format {format!r}; use one of "
                             + ", ".join(allowed), path=path)
        return fmt
    fmt = Path(path).suffix.lower().lstrip(".")
    if fmt not in allowed:
        raise InputError(f"cannot tell the output format from the suffix "
                         f"{Path(path).suffix or '(none)'}; name the file ."
                         + ", .".join(allowed) + " or give --format", path=path)
    return fmt


def write_model(model, path, *, format: str | None = None, text: bool = False) -> str:
    """Write a model as PLY (surfels, or a mesh's vertices as surfels with its faces), OBJ or GLB.

    Parameters
    ----------
    model : SurfelSet or TriangleMesh
    path : str or os.PathLike
    format : {"ply", "obj", "glb"}, optional
        Default: from the suffix of ``path`` (:func:`output_format`).
    text : bool
        ASCII PLY (PLY only).

    Returns
    -------
    str
        The format written.

    Notes
    -----
    OBJ holds ``v x y z r g b`` (colours 0..1) and ``vn`` lines, and ``f`` lines when the model
    has faces; GLB (written by trimesh) a mesh with vertex colours and normals, or a point cloud
    for surfels without faces. Both are read by trimesh, Blender and MeshLab.
    """
    fmt = output_format(path, format)
    if isinstance(model, TriangleMesh):
        if fmt == "ply":
            model = model.to_surfels(max_edge_ratio=None)
            parts = None
        else:       # written as it is: a coarse decoded grid may hold degenerate triangles
            parts = (model.vertices, None, model.vertex_colors, model.faces)
    elif isinstance(model, SurfelSet):
        parts = (model.positions, model.normals, model.colors, model.faces)
    else:
        raise InputError(f"write_model needs a SurfelSet or TriangleMesh, got "
                         f"{type(model).__name__}")
    if fmt == "ply":
        write_ply(model, path, text=text)
    elif fmt == "obj":
        write_atomic(path, lambda tmp: tmp.write_text(_obj_text(*parts), encoding="ascii"))
    else:
        data = _glb_bytes(*parts)
        write_atomic(path, lambda tmp: tmp.write_bytes(data))
    return fmt


def _obj_text(positions, normals, colors, faces) -> str:
    cols = colors.astype(np.float64) / 255.0 if colors is not None else None
    v = np.hstack([positions, cols]) if cols is not None else positions
    vfmt = " ".join(["%.9g"] * 3 + (["%.6g"] * 3 if cols is not None else []))
    out = [f"# written by surfidx: {len(positions)} vertices"]
    out += ["v " + vfmt % tuple(r) for r in v.tolist()]
    if normals is not None:
        out += ["vn %.6g %.6g %.6g" % tuple(r) for r in normals.tolist()]
    if faces is not None and len(faces):
        f = faces + 1
        pattern = "f {0}//{0} {1}//{1} {2}//{2}" if normals is not None else "f {0} {1} {2}"
        out += [pattern.format(a, b, c) for a, b, c in f.tolist()]
    return "\n".join(out) + "\n"


def _glb_bytes(positions, normals, colors, faces) -> bytes:
    import trimesh

    if colors is not None:
        colors = np.hstack([colors, np.full((len(colors), 1), 255, np.uint8)])
    if faces is not None and len(faces):
        tm = trimesh.Trimesh(positions, faces, vertex_normals=normals, vertex_colors=colors,
                             process=False)
    else:
        tm = trimesh.PointCloud(positions, colors=colors)
    return tm.export(file_type="glb")
