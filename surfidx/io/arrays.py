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
    normals : (n, 3) float64 or None
        None for a mesh (a coarse decoded grid may hold degenerate triangles: it is written as
        it is, normals left to the reader).
    colors : (n, 3) uint8 or None
    faces : (m, 3) int64 or None

    Raises
    ------
    InputError
        Another type.
    """
    if isinstance(model, TriangleMesh):
        return model.vertices, None, model.vertex_colors, model.faces
    if isinstance(model, SurfelSet):
        return model.positions, model.normals, model.colors, model.faces
    raise InputError(f"write_model needs a SurfelSet or TriangleMesh, got "
                     f"{type(model).__name__}")
