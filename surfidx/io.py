"""Reading and writing surfel sets: surfel PLY, meshes (PLY faces or tristrips, OBJ with MTL
texture, OFF) and plain point clouds.

The readers keep the input's vertex order so surfels can be named by index.
"""

from __future__ import annotations

import os
import warnings
from pathlib import Path

import numpy as np

from ._errors import FileFormatError, InputError, SurfidxError
from .mesh import MAX_EDGE_RATIO, TriangleMesh
from .pointcloud import points_to_surfels
from .surfels import SurfelSet

__all__ = ["SUPPORTED_SUFFIXES", "read_surfels", "read_mesh", "write_ply", "read_texture"]

SUPPORTED_SUFFIXES = (".ply", ".obj", ".off")


# ---------------------------------------------------------------------- public API
def read_surfels(path, *, texture=None, samples: int | None = None, seed: int = 0,
                 max_edge_ratio: float | None = MAX_EDGE_RATIO) -> SurfelSet:
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

    Returns
    -------
    SurfelSet

    Raises
    ------
    FileFormatError
        Missing, empty, truncated or corrupt file, or an unknown format.
    InputError
        Valid file with unusable values (NaN coordinates, too few points).
    """
    path = Path(path)
    try:
        mesh = read_mesh(path, texture=texture, _allow_points=True)
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


def read_mesh(path, *, texture=None, _allow_points: bool = False):
    """Read a triangle mesh (PLY, OBJ or OFF).

    Parameters
    ----------
    path : str or os.PathLike
    texture : str or os.PathLike, optional
        Texture image (OBJ only), overriding the MTL's.

    Returns
    -------
    TriangleMesh

    Raises
    ------
    FileFormatError
        When the file cannot be read or holds no faces.
    """
    path = Path(path)
    if not path.exists():
        raise FileFormatError("no such file", path=path)
    if path.is_dir():
        raise FileFormatError("is a directory, not a model file", path=path)
    if path.stat().st_size == 0:
        raise FileFormatError("the file is empty", path=path)
    suffix = path.suffix.lower()
    if texture is not None and suffix != ".obj":
        raise InputError("--texture applies to OBJ files only", path=path)
    try:
        if suffix == ".ply":
            result = _read_ply(path)
        elif suffix == ".obj":
            result = _read_obj(path, texture)
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
    """Write a file whole or not at all: ``write(tmp)`` fills ``path.part``, which then
    replaces ``path``; on an OS error the partial file is removed.

    Raises
    ------
    FileFormatError
        Naming ``path`` (and ``what`` was being written) when the file cannot be written.
    """
    path = Path(path)
    tmp = path.with_name(path.name + ".part")
    try:
        write(tmp)
        os.replace(tmp, path)
    except OSError as exc:
        tmp.unlink(missing_ok=True)
        raise FileFormatError(f"cannot write {what + ' ' if what else ''}({exc.strerror or exc})",
                              path=path) from exc


def read_texture(path) -> np.ndarray:
    """Read a texture image as (h, w, 3) uint8.

    Raises
    ------
    FileFormatError
        When the image is missing or unreadable.
    """
    from PIL import Image, UnidentifiedImageError

    path = Path(path)
    if not path.exists():
        raise FileFormatError("texture image not found", path=path)
    try:
        with Image.open(path) as im:
            return np.asarray(im.convert("RGB"), dtype=np.uint8)
    except (UnidentifiedImageError, OSError, ValueError) as exc:
        raise FileFormatError(f"cannot read the texture image ({exc})", path=path) from exc


# ---------------------------------------------------------------------- PLY
class _PlyPoints:
    """Vertex data of a PLY with no faces (surfels or a point cloud)."""

    def __init__(self, vertex, faces=None):
        self.vertex = vertex
        self.faces = faces


def _read_ply(path: Path):
    from plyfile import PlyData

    try:
        ply = PlyData.read(str(path))
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
    positions = np.stack([vertex[a] for a in "xyz"], axis=1).astype(np.float64)
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
def _read_obj(path: Path, texture) -> TriangleMesh:
    try:
        text = path.read_text(errors="replace")
    except OSError as exc:
        raise FileFormatError(f"cannot read ({exc.strerror})", path=path) from exc
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
        tex = _texture_from_mtl(path, mtllibs)
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
    except ValueError as exc:
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


def _texture_from_mtl(path: Path, mtllibs):
    for lib in mtllibs:
        mtl = path.parent / lib
        if not mtl.exists():
            warnings.warn(f"{path}: material library {lib} not found; no texture", UserWarning)
            continue
        for line in mtl.read_text(errors="replace").splitlines():
            parts = line.strip().split()
            if parts and parts[0] == "map_Kd" and len(parts) > 1:
                return read_texture(mtl.parent / parts[-1])
    return None


# ---------------------------------------------------------------------- OFF
def _read_off(path: Path) -> TriangleMesh:
    try:
        text = path.read_text(errors="replace")
    except OSError as exc:
        raise FileFormatError(f"cannot read ({exc.strerror})", path=path) from exc
    lines = [ln.split("#", 1)[0].strip() for ln in text.splitlines()]
    lines = [ln for ln in lines if ln]
    if not lines:
        raise FileFormatError("the file is empty", path=path)
    head = lines[0]
    if not head.endswith("OFF"):
        raise FileFormatError("not an OFF file (first line must be 'OFF')", path=path)
    colored = head.startswith("C")
    rest = lines[1:]
    counts = head[len("COFF" if colored else "OFF"):].split() or (rest.pop(0).split() if rest else [])
    try:
        nv, nf = int(counts[0]), int(counts[1])
    except (IndexError, ValueError) as exc:
        raise FileFormatError("OFF header lacks vertex and face counts", path=path) from exc
    if len(rest) < nv + nf:
        raise FileFormatError(f"OFF file is truncated: header announces {nv} vertices and {nf} "
                              f"faces, found {len(rest)} data lines", path=path)
    try:
        vrows = [r.split() for r in rest[:nv]]
        width = 7 if colored else 3
        arr = np.array([r[:width] for r in vrows], np.float64)
        frows = [r.split() for r in rest[nv:nv + nf]]
        k = np.array([int(r[0]) for r in frows], np.int64)
        if np.all(k == 3):
            faces = np.array([r[1:4] for r in frows], np.int64)
        else:
            faces = _triangulate_polygons([np.array(r[1:1 + int(r[0])], np.int64) for r in frows],
                                          path)
    except (ValueError, IndexError) as exc:
        raise FileFormatError(f"malformed OFF data ({exc})", path=path) from exc
    if arr.ndim != 2 or arr.shape[1] != width:
        raise FileFormatError("an OFF vertex line has too few numbers", path=path)
    vcols = None
    if colored:
        c = arr[:, 3:6]
        if c.max() <= 1.0:
            c = c * 255
        vcols = np.clip(np.round(c), 0, 255).astype(np.uint8)
    if faces.size and (faces.min() < 0 or faces.max() >= nv):
        raise FileFormatError("a face refers to a vertex that does not exist", path=path)
    if not len(faces):
        raise FileFormatError("OFF file has no faces", path=path)
    return TriangleMesh(arr[:, :3], faces, vertex_colors=vcols, name=path.stem)
