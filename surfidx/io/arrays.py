"""A model's arrays as the mesh writers take them (:func:`model_arrays`)."""

from __future__ import annotations

import numpy as np

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
        A textured mesh without vertex colours: its texture read at each vertex's texture
        coordinate (its first corner's).
    faces : (m, 3) int64 or None

    Raises
    ------
    InputError
        Another type.
    """
    if isinstance(model, TriangleMesh):
        colors = model.vertex_colors
        if colors is None and model.texture is not None and model.uv is not None \
                and model.uv_faces is not None and len(model.faces):
            from ..geometry.mesh import sample_texture

            used, first = np.unique(model.faces.ravel(), return_index=True)
            t = np.zeros(len(model.vertices), np.int64)
            t[used] = model.uv_faces.ravel()[first]
            colors = np.clip(np.round(sample_texture(model.texture, model.uv[t])), 0,
                             255).astype(np.uint8)
        return model.vertices, model.vertex_normals(), colors, model.faces
    if isinstance(model, SurfelSet):
        return model.positions, model.normals, model.colors, model.faces
    raise InputError(f"write_model needs a SurfelSet or TriangleMesh, got "
                     f"{type(model).__name__}")
