"""Writing models: the output format of a path (:func:`output_format`) and the model written in
it (:func:`write_model`, dispatching through :mod:`~surfidx.io.registry`)."""

from __future__ import annotations

from pathlib import Path

from ..errors import InputError
from ..geometry.surfels import SurfelSet
from .registry import OUTPUT_FORMATS, WRITERS


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


def write_model(model, path, *, format: str | None = None, text: bool = False,
                image_format: str = "png", image_quality: int | None = None) -> str:
    """Write a model as PLY (surfels without faces, or a mesh's vertices as surfels with its
    faces), OBJ or GLB.

    Parameters
    ----------
    model : SurfelSet or TriangleMesh
    path : str or os.PathLike
    format : {"ply", "obj", "glb"}, optional
        Default: from the suffix of ``path`` (:func:`output_format`).
    text : bool
        ASCII PLY (PLY only).
    image_format : {"png", "jpeg", "webp"}
        The image of a textured mesh (OBJ, GLB).
    image_quality : int, optional
        JPEG or WebP quality, 1 … 100 (default
        :data:`~surfidx.io.texture.DEFAULT_IMAGE_QUALITY`).

    Returns
    -------
    str
        The format written.

    Notes
    -----
    The writer is the format's (:data:`~surfidx.io.registry.WRITERS`). OBJ holds
    ``v x y z r g b`` (colours 0..1), ``vn`` lines (unit normals, a mesh's area-weighted vertex
    normals) and ``f v//vn`` lines when the model has faces; GLB (written by trimesh) a mesh with
    ``POSITION``, ``NORMAL`` and ``COLOR_0``, or a point cloud for surfels without faces. Both
    are read by trimesh, Blender and MeshLab. A mesh with a texture
    (:func:`surfidx.codec.decode` with ``texture=True``) is written with it: OBJ with ``vt``
    lines, a ``.mtl`` and the image beside it (:func:`~surfidx.io.obj.write_obj`), GLB with
    ``TEXCOORD_0`` and a ``baseColorTexture`` (:func:`~surfidx.io.gltf.write_glb`); PLY with
    the texture read at the vertices as vertex colours.
    """
    from ..geometry.mesh import TriangleMesh     # scipy.sparse: not for output_format alone
    from .texture import check_image_options

    image_format, image_quality = check_image_options(image_format, image_quality)
    fmt = output_format(path, format)
    if not isinstance(model, (TriangleMesh, SurfelSet)):
        raise InputError(f"write_model needs a SurfelSet or TriangleMesh, got "
                         f"{type(model).__name__}")
    if fmt in ("obj", "glb"):
        WRITERS[fmt](model, path, text=text, image_format=image_format,
                     image_quality=image_quality)
    else:
        WRITERS[fmt](model, path, text=text)
    return fmt
