"""Which module reads and writes which format: a suffix → reader table and a format → writer
table that :func:`~surfidx.io.reading.read_mesh`, :func:`~surfidx.io.reading.read_surfels` and
:func:`~surfidx.io.writing.write_model` dispatch through.

Adding a format is a module with a reader (``read(path) -> TriangleMesh | Points | PlyPoints``)
or a writer (``write(model, path, *, text)``) and a line here; a reader's line also says which
axis is up in the format's files (:mod:`surfidx.geometry.axes`).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

from ..geometry.axes import MESH_UP, SCANNER_UP
from .e57 import read_e57
from .gltf import read_gltf, write_glb
from .las import read_las
from .obj import read_obj, write_obj
from .off import read_off
from .pcd import read_pcd
from .ply import read_ply, write_ply_model
from .stl import read_stl
from .xyz import read_xyz

__all__ = ["Reader", "MESH_READERS", "POINT_READERS", "WRITERS", "MESH_SUFFIXES", "POINT_SUFFIXES",
           "SUPPORTED_SUFFIXES", "OUTPUT_FORMATS", "reader", "up_axis"]


@dataclass(frozen=True)
class Reader:
    """A format's reader.

    Attributes
    ----------
    read : callable
        ``read(path, [texture], [allow_outside])``: a :class:`TriangleMesh`, or points
        (:class:`~surfidx.io.points.Points`, :class:`~surfidx.io.ply.PlyPoints`).
    texture : bool
        Whether it takes ``texture`` (an image given for the model's UVs).
    outside : bool
        Whether it takes ``allow_outside`` (files named outside the model's folder).
    up : str
        The format's up axis (:data:`~surfidx.geometry.axes.UP_AXES`): +y for the mesh
        formats, +z for the scanners' point clouds.
    """

    read: Callable
    texture: bool = False
    outside: bool = False
    up: str = MESH_UP

    def __call__(self, path, *, texture=None, allow_outside: bool = False):
        kwargs = {}
        if self.texture:
            kwargs["texture"] = texture
        if self.outside:
            kwargs["allow_outside"] = allow_outside
        return self.read(path, **kwargs)


#: Readers of the mesh formats (PLY may also hold surfels or points), by suffix.
MESH_READERS = {
    ".ply": Reader(read_ply),
    ".obj": Reader(read_obj, texture=True, outside=True),
    ".off": Reader(read_off),
    ".stl": Reader(read_stl),
    ".glb": Reader(read_gltf, outside=True),
    ".gltf": Reader(read_gltf, outside=True),
}
#: Readers of the point-cloud-only formats, by suffix.
POINT_READERS = {
    ".pcd": Reader(read_pcd, up=SCANNER_UP),
    ".xyz": Reader(read_xyz, up=SCANNER_UP),
    ".pts": Reader(read_xyz, up=SCANNER_UP),
    ".las": Reader(read_las, up=SCANNER_UP),
    ".laz": Reader(read_las, up=SCANNER_UP),
    ".e57": Reader(read_e57, up=SCANNER_UP),
}
#: Writers by format name: ``write(model, path, *, text)`` for a SurfelSet or TriangleMesh.
WRITERS = {
    "ply": write_ply_model,
    "obj": write_obj,
    "glb": write_glb,
}

#: Suffixes of the mesh formats read (PLY may also hold surfels or points).
MESH_SUFFIXES = tuple(MESH_READERS)
#: Suffixes of the point-cloud-only formats read.
POINT_SUFFIXES = tuple(POINT_READERS)
#: Every suffix :func:`~surfidx.io.reading.read_surfels` reads (and ``surfidx ingest`` looks for
#: in folders).
SUPPORTED_SUFFIXES = MESH_SUFFIXES + POINT_SUFFIXES
#: Formats :func:`~surfidx.io.writing.write_model` writes (``"sfz"``, the stored stream, is
#: written by the callers that hold one: ``surfidx get``/``decode``,
#: :meth:`surfidx.Database.get`).
OUTPUT_FORMATS = tuple(WRITERS)


def reader(suffix: str) -> Reader | None:
    """The reader of a lower-case suffix (``".obj"``), None for an unknown one.

    Parameters
    ----------
    suffix : str

    Returns
    -------
    Reader or None
    """
    return MESH_READERS.get(suffix) or POINT_READERS.get(suffix)


def up_axis(path) -> str:
    """The up axis of a model file's format (its reader's :attr:`Reader.up`).

    Parameters
    ----------
    path : str or os.PathLike, or a model in memory

    Returns
    -------
    str
        One of :data:`~surfidx.geometry.axes.UP_AXES`: the reader's for a file of a known
        suffix; :data:`~surfidx.geometry.axes.MESH_UP` for a model in memory (trimesh and the
        mesh formats it reads keep +y up) or an unknown suffix (reading that file fails anyway).
    """
    if not isinstance(path, (str, os.PathLike)):
        return MESH_UP
    read = reader(Path(path).suffix.lower())
    return MESH_UP if read is None else read.up
