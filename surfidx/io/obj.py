"""OBJ with MTL: meshes with vertex colours or a ``map_Kd`` texture read (:func:`read_obj`),
meshes and surfels written (:func:`write_obj`)."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np

from ..errors import FileFormatError, SurfidxError
from ..geometry.mesh import TriangleMesh
from .arrays import model_arrays
from .atomic import write_atomic
from .limits import check_coordinates, read_text
from .texture import read_texture


#: The statement keywords :func:`read_obj` reads.
OBJ_KEYS = ("v", "vt", "f", "mtllib")


def obj_statements(lines, keys=OBJ_KEYS) -> dict:
    """The statements of an OBJ file's lines that :func:`read_obj` reads, in one pass.

    ``surfidx ingest`` parses an OBJ's ``vt`` and ``mtllib`` lines with it too, so it decides
    whether a model needs a texture as the reader would.

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
    v, vt, f, mtl = (out.get(k) for k in OBJ_KEYS)
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


def mtl_texture_name(text: str) -> str | None:
    """The image file named by the first ``map_Kd`` statement of an MTL file's text.

    Options before the name (``map_Kd -s 1 1 1 t.png``) are skipped: the name is the last word.

    Parameters
    ----------
    text : str
        The MTL file's text.

    Returns
    -------
    str or None
        The name as written (relative to the MTL's folder), None when no ``map_Kd`` names one.
    """
    for line in text.splitlines():
        parts = line.strip().split()
        if parts and parts[0] == "map_Kd" and len(parts) > 1:
            return parts[-1]
    return None


def read_obj(path: Path, texture=None, allow_outside: bool = False) -> TriangleMesh:
    """Read an OBJ mesh: ``v`` (with optional ``r g b``), ``vt`` and ``f`` lines (polygons as
    fans), the texture of its MTL's ``map_Kd`` or the one given.

    Parameters
    ----------
    path : pathlib.Path
    texture : str or os.PathLike, optional
        Texture image, used instead of the MTL's.
    allow_outside : bool
        Use an MTL texture outside the OBJ's folder (else skipped with a warning).

    Returns
    -------
    TriangleMesh
        With UVs and texture when both are there; vertex colours otherwise.

    Raises
    ------
    FileFormatError
        No vertices or no faces, malformed lines, a face naming a missing vertex, a damaged
        texture.
    """
    st = obj_statements(read_text(path).splitlines())
    v_lines, vt_lines, f_lines, mtllibs = (st[k] for k in OBJ_KEYS)
    if not v_lines:
        raise FileFormatError("OBJ has no vertices ('v' lines)", path=path)
    verts, vcols = _parse_obj_vertices(v_lines, path)
    check_coordinates(verts, path)
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


def material_library(path: Path, lib: str, *, allow_outside: bool = False):
    """The MTL file an OBJ's ``mtllib`` statement names, if it may be read.

    Only a name ending in ``.mtl`` is a material library (``mtllib ../../etc/passwd`` is not
    read), and only one inside the OBJ's folder (after resolving ``..`` and symlinks) unless
    ``allow_outside``; it must be a regular file.

    Parameters
    ----------
    path : pathlib.Path
        The OBJ file.
    lib : str
        The name after ``mtllib``.
    allow_outside : bool

    Returns
    -------
    (pathlib.Path or None, str)
        The file, or None and why it is not read (for a warning naming the OBJ).
    """
    mtl = path.parent / lib
    if not lib.lower().endswith(".mtl"):
        return None, f"material library {lib} is not an .mtl file"
    if not allow_outside and not mtl.resolve().is_relative_to(path.parent.resolve()):
        return None, (f"material library {lib} lies outside the model's folder (allow it with "
                      "allow_outside_textures=True, --allow-outside-textures)")
    if not mtl.is_file():
        return None, f"material library {lib} not found"
    return mtl, ""


def _texture_from_mtl(path: Path, mtllibs, allow_outside: bool = False):
    """The first ``map_Kd`` image of the OBJ's material libraries, or None.

    A library or texture outside the OBJ's folder (after resolving ``..`` and symlinks) is
    used only with ``allow_outside``; otherwise it is skipped with a warning, and the model has
    no texture. A library that is not an ``.mtl`` file is skipped with a warning.
    """
    folder = path.parent.resolve()
    for lib in mtllibs:
        mtl, why = material_library(path, lib, allow_outside=allow_outside)
        if mtl is None:
            warnings.warn(f"{path}: {why}; skipped, no texture from it", UserWarning)
            continue
        name = mtl_texture_name(read_text(mtl))
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


def _textured_obj_text(model, mtl_name: str) -> str:
    positions, normals, _, faces = model_arrays(model)
    out = [f"# written by surfidx: {len(positions)} vertices, texture in {mtl_name}",
           f"mtllib {mtl_name}"]
    out += ["v %.9g %.9g %.9g" % tuple(r) for r in positions.tolist()]
    out += ["vt %.9g %.9g" % tuple(r) for r in model.uv.tolist()]
    out += ["vn %.6g %.6g %.6g" % tuple(r) for r in normals.tolist()]
    out.append("usemtl surfidx")
    corners = np.stack([faces + 1, model.uv_faces + 1], 2)       # (m, 3, 2)
    out += ["f {0}/{1}/{0} {2}/{3}/{2} {4}/{5}/{4}".format(*r)
            for r in corners.reshape(-1, 6).tolist()]
    return "\n".join(out) + "\n"


def texture_files(path, image_format: str = "png") -> tuple[Path, Path]:
    """The material library and the image written beside a textured OBJ: ``NAME.mtl`` and
    ``NAME.png`` (``.jpg``, ``.webp``) in its folder.

    Parameters
    ----------
    path : str or os.PathLike
        The OBJ.
    image_format : {"png", "jpeg", "webp"}

    Returns
    -------
    mtl, image : pathlib.Path
    """
    from .texture import IMAGE_FORMATS, check_image_options

    fmt = check_image_options(image_format)[0]
    path = Path(path)
    return path.with_suffix(".mtl"), path.with_suffix(IMAGE_FORMATS[fmt][0])


def write_obj(model, path, *, text: bool = False, image_format: str = "png",
              image_quality: int | None = None) -> None:
    """Write a model as OBJ. A mesh with a texture (``uv``, ``uv_faces``, ``texture``): ``v``,
    ``vt``, ``vn`` and ``f v/vt/vn`` lines (a vertex on a texture seam has one ``vt`` per
    chart), a material library ``NAME.mtl`` whose material's ``map_Kd`` is the image
    ``NAME.png`` (``.jpg``, ``.webp``) beside it (:func:`texture_files`); the image and the
    library are written before the OBJ, each whole or not at all. Otherwise ``v x y z r g b``
    (colours 0..1), ``vn`` lines (surfels' normals, a mesh's vertex normals) and ``f`` lines
    when it has faces (a mesh is written as it is, nothing dropped).

    Parameters
    ----------
    model : SurfelSet or TriangleMesh
    path : str or os.PathLike
    text : bool
        Ignored (OBJ is text).
    image_format : {"png", "jpeg", "webp"}
        The texture image's format (a textured mesh only).
    image_quality : int, optional
        JPEG or WebP quality, 1 … 100 (:func:`~surfidx.io.texture.check_image_options`).
    """
    from .texture import check_image_options, encode_image

    fmt, quality = check_image_options(image_format, image_quality)
    if getattr(model, "texture", None) is not None and model.uv is not None:
        mtl, image = texture_files(path, fmt)
        data = encode_image(model.texture, image_format=fmt, image_quality=quality)
        material = ("# written by surfidx\nnewmtl surfidx\nKa 0 0 0\nKd 1 1 1\nKs 0 0 0\n"
                    f"illum 1\nmap_Kd {image.name}\n")
        content = _textured_obj_text(model, mtl.name)
        write_atomic(image, lambda tmp: tmp.write_bytes(data), what="the texture image")
        write_atomic(mtl, lambda tmp: tmp.write_text(material, encoding="utf-8"),
                     what="the material library")
        write_atomic(path, lambda tmp: tmp.write_text(content, encoding="utf-8"))
        return
    content = _obj_text(*model_arrays(model))
    write_atomic(path, lambda tmp: tmp.write_text(content, encoding="ascii"))
