"""A model's arrays as the mesh writers take them (:func:`model_arrays`)."""

from __future__ import annotations

from ..errors import InputError
from ..geometry.mesh import TriangleMesh
from ..geometry.surfels import SurfelSet


def model_arrays(model):
    """The arrays a writer needs: a mesh's as it is, a surfel set's with its normals.

    Parameters
    ----------
    model : SurfelSet or TriangleMesh

    Returns
    -------
    positions : (n, 3) float64
    normals : (n, 3) float64
        Unit vectors: a surfel set's own, a mesh's area-weighted vertex normals
        (:meth:`~surfidx.TriangleMesh.vertex_normals`, unit even where a coarse decoded grid
        has degenerate triangles).
    colors : (n, 3) uint8 or None
    faces : (m, 3) int64 or None

    Raises
    ------
    InputError
        Another type.
    """
    if isinstance(model, TriangleMesh):
        return model.vertices, model.vertex_normals(), model.vertex_colors, model.faces
    if isinstance(model, SurfelSet):
        return model.positions, model.normals, model.colors, model.faces
    raise InputError(f"write_model needs a SurfelSet or TriangleMesh, got "
                     f"{type(model).__name__}")
