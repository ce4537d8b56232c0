"""The files that make up a model as it was read, for ``ingest --keep-original``: the model
file, and the files it names that its readers use (an OBJ's material libraries and the images
they name, a glTF's buffers and images, a texture given or paired with it), laid out relative to
the deepest folder holding them all, so that written back together the model opens as before.
"""

from __future__ import annotations

import os
import warnings
from pathlib import Path

from .files import read_regular

__all__ = ["original_files", "MTL_IMAGE_STATEMENTS"]

#: MTL statements whose last word names an image file.
MTL_IMAGE_STATEMENTS = ("map_ka", "map_kd", "map_ks", "map_ke", "map_ns", "map_d", "map_bump",
                        "map_pr", "map_pm", "map_ps", "map_kn", "map_refl", "bump", "disp",
                        "decal", "refl", "norm")


def _mtl_images(text: str) -> list:
    """The image names of an MTL file's text (the last word of each image statement)."""
    out = []
    for line in text.splitlines():
        parts = line.split()
        if len(parts) > 1 and parts[0].lower() in MTL_IMAGE_STATEMENTS:
            out.append(parts[-1])
    return out


def _obj_references(path: Path, allow_outside: bool) -> tuple:
    """``(files, problems)``: an OBJ's material libraries and the images they name."""
    from .files import lines_of_regular
    from .obj import material_library, obj_statements

    st = obj_statements((ln.decode("utf-8", "replace") for ln in lines_of_regular(path)
                         if ln.startswith(b"mtllib ")), keys=("mtllib",))
    files, problems = [], []
    for lib in st["mtllib"]:
        mtl, why = material_library(path, lib, allow_outside=allow_outside)
        if mtl is None:
            problems.append(why)
            continue
        files.append(mtl)
        for name in _mtl_images(read_regular(mtl).decode("utf-8", "replace")):
            files.append(mtl.parent / name)
    return files, problems


def original_files(path, *, texture=None, allow_outside: bool = False) -> list:
    """The model file and the files it references, as ``ingest --keep-original`` keeps them.

    Parameters
    ----------
    path : str or os.PathLike
        The model file.
    texture : str or os.PathLike, optional
        The texture given with it, or paired with it (:func:`surfidx.io.find_texture`).
    allow_outside : bool
        Keep referenced files outside the model's folder (as the readers read them only with
        ``allow_outside_textures``).

    Returns
    -------
    list of (str, pathlib.Path, str)
        ``(relative path, file, role)``: the model file first (role ``"source"``), then each
        referenced file once (``"companion"``); relative paths are POSIX text from the deepest
        folder holding them all (the model's folder unless a file lies outside it).

    Warns
    -----
    UserWarning
        A referenced file not kept: missing, not a regular file, or outside the model's folder
        without ``allow_outside``, named with the reason.
    """
    path = Path(os.path.abspath(path))
    folder = path.parent
    wanted, problems = [], []
    suffix = path.suffix.lower()
    if suffix == ".obj":
        wanted, problems = _obj_references(path, allow_outside)
    elif suffix in (".gltf", ".glb"):
        from .gltf import referenced_uris

        wanted = [folder / uri for uri in referenced_uris(path)]
    if texture is not None:
        wanted.append(Path(texture))
    kept, seen = [(path, "source")], {path}
    for f in wanted:
        f = Path(os.path.normpath(os.path.abspath(f)))
        if f in seen:
            continue
        seen.add(f)
        if not allow_outside and not f.resolve().is_relative_to(folder.resolve()):
            problems.append(f"{f} lies outside the model's folder (keep it with "
                            "--allow-outside-textures)")
        elif not f.is_file():
            problems.append(f"{f} is not a file")
        else:
            kept.append((f, "companion"))
    for why in problems:
        warnings.warn(f"{path}: original kept without a file it names: {why}", UserWarning,
                      stacklevel=2)
    root = Path(os.path.commonpath([str(f.parent) for f, _ in kept]))
    return [(f.relative_to(root).as_posix(), f, role) for f, role in kept]
