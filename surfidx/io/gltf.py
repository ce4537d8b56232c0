"""glTF and GLB: meshes with vertex colours or a base-colour texture read through trimesh (a
``.gltf`` only with buffers and images in its own folder, unless allowed); GLB written."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .arrays import model_arrays
from .atomic import write_atomic
from .trimeshio import read_trimesh


def read_gltf(path: Path, allow_outside: bool = False):
    """Read a glTF or GLB model (:func:`~surfidx.io.trimeshio.read_trimesh`).

    Parameters
    ----------
    path : pathlib.Path
    allow_outside : bool
        Read buffers and images a ``.gltf`` names outside its folder.

    Returns
    -------
    TriangleMesh or Points
    """
    return read_trimesh(path, allow_outside)


def _glb_bytes(positions, normals, colors, faces) -> bytes:
    import trimesh

    if colors is not None:
        colors = np.hstack([colors, np.full((len(colors), 1), 255, np.uint8)])
    if faces is not None and len(faces):
        tm = trimesh.Trimesh(positions, faces, vertex_colors=colors, process=False)
        tm.vertex_normals = normals    # ours, set last: the constructor's caching may drop them
        return tm.export(file_type="glb", include_normals=True)
    return trimesh.PointCloud(positions, colors=colors).export(file_type="glb")


def write_glb(model, path, *, text: bool = False) -> None:
    """Write a model as GLB (through trimesh): a mesh whose primitive holds ``POSITION``,
    ``NORMAL`` (unit, float32, per vertex: :func:`~surfidx.io.arrays.model_arrays`) and
    ``COLOR_0`` when it has colours, or a point cloud for surfels without faces.

    Parameters
    ----------
    model : SurfelSet or TriangleMesh
    path : str or os.PathLike
    text : bool
        Ignored (GLB is binary).
    """
    data = _glb_bytes(*model_arrays(model))
    write_atomic(path, lambda tmp: tmp.write_bytes(data))
