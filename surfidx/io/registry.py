"""Which module reads and writes which format: a suffix → reader table and a format → writer
table that :func:`~surfidx.io.reading.read_mesh`, :func:`~surfidx.io.reading.read_surfels` and
:func:`~surfidx.io.writing.write_model` dispatch through.

Adding a format is a module with a reader (``read(path) -> TriangleMesh | Points | PlyPoints``)
or a writer (``write(model, path, *, text)``) and a line here; a reader's line also says which
axis is up in the format's files (:mod:`surfidx.geometry.axes`). The lines name the functions
(module of this package, function), which are imported when first called: reading an OFF file
loads neither the glTF, LAS nor E57 code.
"""

from __future__ import annotations

import importlib
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

from ..geometry.axes import MESH_UP, SCANNER_UP

__all__ = ["Reader", "MESH_READERS", "POINT_READERS", "WRITERS", "MESH_SUFFIXES", "POINT_SUFFIXES",
           "SUPPORTED_SUFFIXES", "OUTPUT_FORMATS", "reader", "up_axis"]


@dataclass(frozen=True)
class Reader:
    """A format's reader.

    Attributes
    ----------
    module, function : str
        The reader, ``function`` of the module ``module`` of this package (:attr:`read`).
    texture : bool
        Whether it takes ``texture`` (an image given for the model's UVs).
    outside : bool
        Whether it takes ``allow_outside`` (files named outside the model's folder).
    up : str
        The format's up axis (:data:`~surfidx.geometry.axes.UP_AXES`): +y for the mesh
        formats, +z for the scanners' point clouds.
    """

    module: str
    function: str
    texture: bool = False
    outside: bool = False
    up: str = MESH_UP

    @property
    def read(self) -> Callable:
        """``read(path, [texture], [allow_outside])``: a :class:`TriangleMesh`, or points
        (:class:`~surfidx.io.points.Points`, :class:`~surfidx.io.ply.PlyPoints`)."""
        return _load(self.module, self.function)

    def __call__(self, path, *, texture=None, allow_outside: bool = False):
        kwargs = {}
        if self.texture:
            kwargs["texture"] = texture
        if self.outside:
            kwargs["allow_outside"] = allow_outside
        return self.read(path, **kwargs)


def _load(module: str, function: str) -> Callable:
    """The function ``function`` of this package's module ``module`` (imported on first use)."""
    return getattr(importlib.import_module(f"{__package__}.{module}"), function)


class _Writer:
    """A format's writer ``write(model, path, *, text, ...)``, imported when first called."""

    def __init__(self, module: str, function: str):
        self.module, self.function = module, function

    def __call__(self, *args, **kwargs):
        return _load(self.module, self.function)(*args, **kwargs)


#: Readers of the mesh formats (PLY may also hold surfels or points), by suffix.
MESH_READERS = {
    ".ply": Reader("ply", "read_ply"),
    ".obj": Reader("obj", "read_obj", texture=True, outside=True),
    ".off": Reader("off", "read_off"),
    ".stl": Reader("stl", "read_stl"),
    ".glb": Reader("gltf", "read_gltf", outside=True),
    ".gltf": Reader("gltf", "read_gltf", outside=True),
}
#: Readers of the point-cloud-only formats, by suffix.
POINT_READERS = {
    ".pcd": Reader("pcd", "read_pcd", up=SCANNER_UP),
    ".xyz": Reader("xyz", "read_xyz", up=SCANNER_UP),
    ".pts": Reader("xyz", "read_xyz", up=SCANNER_UP),
    ".las": Reader("las", "read_las", up=SCANNER_UP),
    ".laz": Reader("las", "read_las", up=SCANNER_UP),
    ".e57": Reader("e57", "read_e57", up=SCANNER_UP),
}
#: Writers by format name: ``write(model, path, *, text)`` for a SurfelSet or TriangleMesh.
WRITERS = {
    "ply": _Writer("ply", "write_ply_model"),
    "obj": _Writer("obj", "write_obj"),
    "glb": _Writer("gltf", "write_glb"),
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
