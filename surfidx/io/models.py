"""Reading for storing: a file read (:func:`~surfidx.io.reading.read_geometry`) and repaired
to closed genus-0 parts (:func:`surfidx.topology.repair_model`) in one call, :func:`read_model`.

:class:`~surfidx.topology.Model` and :func:`~surfidx.topology.join_surfels` live in
:mod:`surfidx.topology.model`; they are named here too so ``surfidx.io`` keeps offering them.
"""

from __future__ import annotations

import os
from pathlib import Path

from ..geometry.mesh import MAX_EDGE_RATIO
from ..topology.model import Model, join_surfels
from .reading import read_geometry

__all__ = ["read_model", "Model", "join_surfels"]


def read_model(path, *, texture=None, samples: int | None = None, seed: int = 0,
               max_edge_ratio: float | None = MAX_EDGE_RATIO,
               allow_outside_textures: bool = False, options=None,
               name: str | None = None) -> Model:
    """Read any file (or model in memory) for storing: :func:`read_geometry`, then
    :func:`surfidx.topology.repair_model` (every mesh as it is, repaired to parts).

    A mesh that is one closed, manifold, genus-0 piece becomes exactly
    :func:`read_surfels`' surfels (one part, no patch labels), so its streams and descriptors
    are those of a plain read. Any other mesh is split into its pieces
    (:func:`surfidx.topology.split_parts`: pinched vertices split; pieces under
    ``max(options.min_part_vertices, options.min_part_share * V)`` vertices dropped, except the
    largest, with a ``UserWarning`` saying how many), and each piece brought to a closed genus-0
    surface (:func:`surfidx.topology.close_surface`: handles cut, holes and cut sides capped by
    fair virtual patches), then converted to surfels as :meth:`TriangleMesh.to_surfels` does,
    with :attr:`SurfelSet.patch` marking the virtual surfels (a vertex added by bisection is
    virtual when every face around it is virtual). Colours (vertex colours, or the texture
    averaged at the vertices) go with the scan's vertices; virtual vertices take the harmonic
    interpolation of their rim's. Point clouds and surfel files are one part as
    :func:`read_surfels` reads them (a point cloud's proxy surface is closed by construction).

    Parameters
    ----------
    path : str or os.PathLike, or a model in memory
        As for :func:`read_surfels` (a ``TriangleMesh``, ``(vertices, faces[, colours])`` or a
        trimesh object is repaired as a file's mesh is).
    texture, samples, seed, max_edge_ratio, allow_outside_textures
        As for :func:`read_surfels`.
    options : surfidx.topology.RepairOptions, optional
        Tuning of the repair (default ``RepairOptions()``).
    name : str, optional
        The model's name (default: the file stem or the model's own).

    Returns
    -------
    surfidx.topology.Model

    Raises
    ------
    FileFormatError
        As for :func:`read_surfels`.
    InputError
        As for :func:`read_surfels`.
    TopologyError
        A piece that cannot be closed to a sphere (non-orientable: a Möbius strip, a Klein
        bottle), or faces none of which is a triangle.

    Warns
    -----
    UserWarning
        Tiny pieces dropped (how many, how many vertices), degenerate faces dropped.
    """
    from ..topology import repair_model

    geometry = read_geometry(path, texture=texture, samples=samples,
                             allow_outside_textures=allow_outside_textures, name=name)
    return repair_model(geometry, samples=samples, seed=seed, max_edge_ratio=max_edge_ratio,
                        options=options, name=name,
                        path=Path(path) if isinstance(path, (str, os.PathLike)) else None)
