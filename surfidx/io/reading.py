"""Reading models as they are: any supported file, or a model in memory, as surfels
(:func:`read_surfels`, :func:`as_surfels`), as a mesh (:func:`read_mesh`) or as what the topology
repair takes (:func:`read_geometry`). Nothing is repaired here.

The readers keep the input's vertex order so surfels can be named by index; each format's
reader is the one :mod:`~surfidx.io.registry` names for its suffix.
"""

from __future__ import annotations

import os
import warnings
from pathlib import Path

import numpy as np

from ..errors import FileFormatError, InputError, SurfidxError
from ..geometry.mesh import MAX_EDGE_RATIO, TriangleMesh
from ..geometry.surfels import SurfelSet
from ..validate import as_array
from .files import pair_texture
from .limits import check_input_file
from .ply import PlyPoints, ply_colors, points_from_ply_data
from .points import Points
from .registry import SUPPORTED_SUFFIXES, reader
from .trimeshio import from_trimesh


def read_surfels(path, *, texture=None, samples: int | None = None, seed: int = 0,
                 max_edge_ratio: float | None = MAX_EDGE_RATIO,
                 allow_outside_textures: bool = False) -> SurfelSet:
    """Read any supported file as surfels.

    Parameters
    ----------
    path : str or os.PathLike, or a model in memory
        A surfel PLY (x y z nx ny nz radius [red green blue]), a mesh (PLY with ``face`` or
        ``tristrips``, OBJ, OFF, STL, glTF/GLB) or a point cloud (PLY with positions and
        optional colours/normals, PCD, XYZ, PTS, LAS/LAZ, E57). A model in memory (a :class:`SurfelSet`,
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
        geodesics want). Storing, encoding and querying repair such a mesh into closed genus-0
        parts (:func:`surfidx.topology.repair_model`, :func:`surfidx.topology.read_model`); the
        :attr:`~surfidx.topology.Model.surfels` of the result joins them.

    Raises
    ------
    FileFormatError
        Missing, unreadable, empty, truncated or corrupt file, an unknown format, or a texture
        image that is damaged or larger than :data:`~surfidx.io.limits.MAX_TEXTURE_PIXELS`.
    InputError
        Valid file with unusable values (NaN coordinates or beyond
        :data:`~surfidx.io.limits.MAX_COORDINATE`, too
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
    if isinstance(mesh, Points):
        from ..geometry.pointcloud import points_to_surfels    # numba, scipy.spatial: clouds only

        if samples is not None:
            raise InputError("--samples needs a mesh; this file holds points only")
        return points_to_surfels(mesh.positions, normals=mesh.normals, colors=mesh.colors,
                                 name=path.stem)
    if isinstance(mesh, PlyPoints) and mesh.faces is not None and samples is not None:
        mesh = TriangleMesh(np.stack([mesh.vertex[a] for a in "xyz"], axis=1), mesh.faces,
                            vertex_colors=ply_colors(mesh.vertex), name=path.stem)
    if isinstance(mesh, TriangleMesh):
        return mesh
    if samples is not None:
        raise InputError("--samples needs a mesh; this file holds points only")
    return points_from_ply_data(mesh, path)


def read_mesh(path, *, texture=None, allow_outside_textures: bool = False,
              _allow_points: bool = False):
    """Read a triangle mesh (PLY, OBJ, OFF, STL, glTF or GLB).

    The reader is the suffix's (:mod:`~surfidx.io.registry`); the mesh is as the file holds
    it, nothing repaired.

    Parameters
    ----------
    path : str or os.PathLike
    texture : str or os.PathLike, optional
        Texture image (OBJ only), overriding the MTL's. Without it, an OBJ with texture
        coordinates whose MTL names no image takes the image beside it
        (:func:`surfidx.io.find_texture`), as an ingest does, and a warning names it.
    allow_outside_textures : bool
        Use an MTL texture outside the model's folder (see :func:`read_surfels`).

    Returns
    -------
    TriangleMesh

    Raises
    ------
    FileFormatError
        When the file cannot be read or holds no faces.

    Warns
    -----
    UserWarning
        The texture image paired with an OBJ whose MTL names none.
    """
    path = Path(path)
    check_input_file(path)
    suffix = path.suffix.lower()
    read = reader(suffix)
    if texture is not None and (read is None or not read.texture):
        raise InputError("--texture applies to OBJ files only", path=path)
    if texture is None and read is not None and read.texture:
        texture = pair_texture(path)
    try:
        if read is None:
            raise FileFormatError(
                f"unknown format {suffix or '(no suffix)'}; supported: "
                + ", ".join(SUPPORTED_SUFFIXES), path=path)
        result = read(path, texture=texture, allow_outside=allow_outside_textures)
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


def read_geometry(path, *, texture=None, samples: int | None = None,
                  allow_outside_textures: bool = False, name: str | None = None):
    """Read a file (or take a model in memory) as it is, for :func:`surfidx.topology.repair_model`:
    a mesh as a :class:`TriangleMesh`, not yet converted to surfels (the repair closes it
    first), anything else as its surfels.

    Parameters
    ----------
    path : str or os.PathLike, or a model in memory
        As for :func:`read_surfels` (a ``TriangleMesh``, ``(vertices, faces[, colours])`` or a
        trimesh mesh gives a mesh).
    texture, allow_outside_textures
        As for :func:`read_surfels`.
    samples : int, optional
        Only checked here: a file of points refuses it (the mesh is sampled by the repair).
    name : str, optional
        Name of a model in memory (a file's mesh or surfels are named by its stem).

    Returns
    -------
    TriangleMesh or SurfelSet

    Raises
    ------
    FileFormatError
        As for :func:`read_surfels`.
    InputError
        As for :func:`read_surfels`.
    """
    if not isinstance(path, (str, os.PathLike)):
        mesh = _memory_mesh(path, name)
        if isinstance(mesh, TriangleMesh):
            return mesh
        return as_surfels(path, samples=samples, name=name)
    path = Path(path)
    try:
        return _read_file(path, texture, samples, allow_outside_textures)
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
        m = from_trimesh(model, name=name or getattr(model, "metadata", {}).get("name"))
        return m if isinstance(m, TriangleMesh) else None
    return None


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
        name = name or getattr(model, "metadata", {}).get("name")
        mesh = from_trimesh(model, name=name)
    elif isinstance(model, tuple):
        if len(model) not in (2, 3):
            raise InputError(f"a model tuple is (vertices, faces) or (vertices, faces, colours), "
                             f"got {len(model)} items")
        verts, faces = model[0], model[1]
        colors = model[2] if len(model) == 3 else None
        if faces is None:
            mesh = Points(as_array(verts, "vertices", shape=(None, 3)), None, colors)
        else:
            mesh = TriangleMesh(verts, faces, vertex_colors=colors, name=name)
    elif isinstance(model, np.ndarray):
        mesh = Points(as_array(model, "points", shape=(None, 3)))
    elif not isinstance(model, TriangleMesh):
        raise InputError(f"cannot read a model from a {type(model).__name__}; give a file, a "
                         "SurfelSet, a TriangleMesh, (vertices, faces[, colours]), an (n, 3) "
                         "point array or a trimesh object")
    if isinstance(mesh, Points):
        from ..geometry.pointcloud import points_to_surfels

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
