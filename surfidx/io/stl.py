"""STL (ASCII or binary), read through trimesh: its triangle soup's vertices merged by position."""

from __future__ import annotations

from pathlib import Path

from .trimeshio import read_trimesh


def read_stl(path: Path):
    """Read an STL mesh (:func:`~surfidx.io.trimeshio.read_trimesh`).

    Parameters
    ----------
    path : pathlib.Path

    Returns
    -------
    TriangleMesh
        Vertices merged by exact position, so the surface is closed where it is.
    """
    return read_trimesh(path)
