"""Reading and writing surfel sets: surfel PLY, meshes (PLY faces or tristrips, OBJ with MTL
texture, OFF) and plain point clouds.

The readers keep the input's vertex order so surfels can be named by index.
"""

from __future__ import annotations

import os
import re
import stat
import tempfile
import warnings
from pathlib import Path

import numpy as np

from ._errors import FileFormatError, InputError, SurfidxError
from .mesh import MAX_EDGE_RATIO, TriangleMesh
from .pointcloud import points_to_surfels
from .surfels import SurfelSet

__all__ = ["SUPPORTED_SUFFIXES", "MAX_TEXTURE_PIXELS", "MAX_COORDINATE", "read_surfels",
           "read_mesh", "write_ply", "write_atomic", "read_texture"]

SUPPORTED_SUFFIXES = (".ply", ".obj", ".off")

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
    path : str or os.PathLike
        A surfel PLY (x y z nx ny nz radius [red green blue]), a mesh (PLY with ``face`` or
        ``tristrips``, OBJ, OFF) or a point-cloud PLY (positions, optional colours/normals).
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
    path = Path(path)
    try:
        mesh = read_mesh(path, texture=texture, allow_outside_textures=allow_outside_textures,
                         _allow_points=True)
        if isinstance(mesh, _PlyPoints) and mesh.faces is not None and samples is not None:
            mesh = TriangleMesh(np.stack([mesh.vertex[a] for a in "xyz"], axis=1), mesh.faces,
                                vertex_colors=_ply_colors(mesh.vertex), name=path.stem)
        if isinstance(mesh, TriangleMesh):
            with warnings.catch_warnings():
                warnings.simplefilter("default")
                return mesh.to_surfels(samples=samples, seed=seed,
                                       max_edge_ratio=max_edge_ratio)
        if samples is not None:
            raise InputError("--samples needs a mesh; this file holds points only")
        return _points_from_ply_data(mesh, path)
    except SurfidxError as exc:
        if exc.path is None:
            raise type(exc)(exc.reason, path=path) from exc
        raise


def read_mesh(path, *, texture=None, allow_outside_textures: bool = False,
              _allow_points: bool = False):
    """Read a triangle mesh (PLY, OBJ or OFF).

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


def _read_ply(path: Path):
    from plyfile import PlyData

    try:
        with open(path, "rb") as fh:
            _check_ply_counts(fh, path)
        ply = PlyData.read(str(path))
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
    """Triangles from -1 separated strips; odd triangles flip winding; degenerate ones dropped."""
    col = _list_column(data)
    strips = np.concatenate([np.asarray(s, np.int64).ravel() for s in col])
    out = []
    # split at -1
    cuts = np.flatnonzero(strips < 0)
    start = 0
    for end in list(cuts) + [len(strips)]:
        s = strips[start:end]
        start = end + 1
        if len(s) < 3:
            continue
        a, b, c = s[:-2], s[1:-1], s[2:]
        t = np.stack([a, b, c], axis=1)
        odd = (np.arange(len(t)) % 2) == 1
        t[odd] = t[odd][:, [1, 0, 2]]
        out.append(t)
    if not out:
        raise FileFormatError("tristrips hold no triangle", path=path)
    t = np.concatenate(out)
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
def _read_obj(path: Path, texture, allow_outside: bool = False) -> TriangleMesh:
    text = _read_text(path)
    v_lines, vt_lines, f_lines, mtllibs = [], [], [], []
    for line in text.splitlines():
        if line.startswith("v "):
            v_lines.append(line[2:])
        elif line.startswith("vt "):
            vt_lines.append(line[3:])
        elif line.startswith("f "):
            f_lines.append(line[2:].split())
        elif line.startswith("mtllib "):
            mtllibs.append(line[7:].strip())
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
        for line in _read_text(mtl).splitlines():
            parts = line.strip().split()
            if parts and parts[0] == "map_Kd" and len(parts) > 1:
                image = mtl.parent / parts[-1]
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
