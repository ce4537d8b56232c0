"""A model brought to closed genus-0 parts for storing: :class:`Model`, :func:`repair_model`
and :func:`read_model`.

Reading a file (:mod:`surfidx.io`) gives the scan as it is; storing, encoding and querying need
closed genus-0 surfaces, so :func:`repair_model` splits a mesh into its pieces and closes each
(:func:`.repair.split_parts`, :func:`.repair.close_surface`), recording what was added.
:func:`read_model` is the two in one call (read, then repair); :func:`join_surfels` stacks the
parts back into one surfel set.
"""

from __future__ import annotations

import os
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ..errors import InputError, SurfidxError
from ..geometry.mesh import MAX_EDGE_RATIO, TriangleMesh
from ..geometry.surfels import SurfelSet

if TYPE_CHECKING:                          # imported by the to_trimesh methods only
    import trimesh

__all__ = ["Model", "join_surfels", "repair_model", "read_model"]


@dataclass(frozen=True)
class Model:
    """A model for storing (:func:`repair_model`, :func:`read_model`): its parts,
    each closed genus-0 surfels.

    Attributes
    ----------
    parts : tuple of SurfelSet
        One per kept piece, largest first. A part of a repaired mesh carries
        :attr:`SurfelSet.patch` / :attr:`SurfelSet.patch_cut` when the repair added faces.
    reports : tuple of (surfidx.topology.RepairReport or None)
        What the repair added to each part; ``None`` for a part taken as it is (a closed
        genus-0 mesh, a point cloud, surfels).
    topology : surfidx.topology.TopologyReport or None
        The input mesh's analysis (holes, pinches, genus, pieces); ``None`` for points or
        surfels.
    kind : {"mesh", "points", "surfels"}
        What the file held.
    parts_dropped : int
        Tiny pieces dropped (:func:`surfidx.topology.split_parts`' threshold).
    dropped_vertices : int
        Their vertices.
    areas : tuple of float
        Surface area of each part's closed mesh (0 for points and surfels).
    name : str or None
    face_patches : tuple of ((m,) int64 or None)
        Per part, the virtual patch of each of its surfels' faces (-1 real; the codec's
        ``face_patch``, which tells a patch face whose three corners are scan vertices from the
        scan's own); None for a part with nothing virtual.
    texture : TriangleMesh or None
        The mesh as read when it has texture coordinates and a texture: the codec samples
        its colour grid from it (:mod:`surfidx.codec.colorgrid`).
    """

    parts: tuple
    reports: tuple
    topology: object = None
    kind: str = "mesh"
    parts_dropped: int = 0
    dropped_vertices: int = 0
    areas: tuple = ()
    name: str | None = None
    face_patches: tuple = ()
    texture: object = None

    def face_patch(self, i: int):
        """Part ``i``'s face labels (:attr:`face_patches`), None when it has none."""
        return self.face_patches[i] if i < len(self.face_patches) else None

    @property
    def repaired(self) -> bool:
        """Whether anything was added or split (a report on any part) or a piece dropped."""
        return any(r is not None for r in self.reports) or self.parts_dropped > 0

    @property
    def surfels(self) -> SurfelSet:
        """The surfels of all parts (:func:`join_surfels`; the part itself when there is one)."""
        return join_surfels(self.parts, name=self.name)

    @property
    def n_surfels(self) -> int:
        """Surfels of all parts together."""
        return int(sum(len(p) for p in self.parts))

    def to_trimesh(self) -> "trimesh.PointCloud":
        """The surfels of all parts (:attr:`surfels`) as one ``trimesh.PointCloud``
        (:meth:`SurfelSet.to_trimesh`: normals, radii, faces and patch labels in its
        ``metadata``); each part converts on its own too.

        Returns
        -------
        trimesh.PointCloud
        """
        return self.surfels.to_trimesh()

    def summary(self) -> dict:
        """What the repair added, for records and ``surfidx info``/``show``.

        Returns
        -------
        dict
            ``parts``, ``parts_dropped``, ``dropped_vertices``, ``holes_filled``,
            ``handles_cut``, ``pinched_vertices``, ``nonmanifold_edges``, ``flipped_faces``,
            ``virtual_surfels``, ``virtual_area_share`` (virtual faces' area over the closed
            parts' area, all parts together), ``genus_before`` (per part) and ``repaired``.
        """
        reps = [r for r in self.reports if r is not None]
        total = float(sum(self.areas))
        virt = float(sum(r.virtual_area_share * a for r, a in zip(self.reports, self.areas)
                         if r is not None))
        return {"parts": len(self.parts), "parts_dropped": int(self.parts_dropped),
                "dropped_vertices": int(self.dropped_vertices),
                "holes_filled": int(sum(r.holes_filled for r in reps)),
                "handles_cut": int(sum(r.handles_cut for r in reps)),
                "pinched_vertices": int(sum(r.pinched_vertices for r in reps)),
                "nonmanifold_edges": int(sum(r.nonmanifold_edges for r in reps)),
                "flipped_faces": int(sum(r.flipped_faces for r in reps)),
                "virtual_surfels": int(sum(int(p.virtual.sum()) for p in self.parts)),
                "virtual_area_share": virt / total if total > 0 else 0.0,
                "genus_before": [None if r is None else int(r.genus_before)
                                 for r in self.reports],
                "repaired": self.repaired}


def join_surfels(parts, *, name=None) -> SurfelSet:
    """Several surfel sets as one: arrays stacked, faces and patch labels renumbered.

    Parameters
    ----------
    parts : sequence of SurfelSet
        Patches of part ``i`` follow those of parts ``0..i-1``; so do their cuts.
    name : str, optional
        Name of the result (default: the first part's).

    Returns
    -------
    SurfelSet
        ``parts[0]`` itself when there is one part (and ``name`` is None or its own). Colours
        are kept when every part has them; faces when every part has them.

    Raises
    ------
    InputError
        When ``parts`` is empty.
    """
    parts = list(parts)
    if not parts:
        raise InputError("join_surfels needs at least one surfel set")
    if len(parts) == 1 and (name is None or parts[0].name == name):
        return parts[0]
    colors = None
    if all(p.colors is not None for p in parts):
        colors = np.vstack([p.colors for p in parts])
    faces, patch, patch_cut = None, None, None
    if all(p.faces is not None for p in parts):
        offs = np.cumsum([0] + [len(p) for p in parts[:-1]])
        faces = np.vstack([p.faces + o for p, o in zip(parts, offs)])
    if any(p.patch is not None for p in parts):
        labels, cuts, pbase, cbase = [], [], 0, 0
        for p in parts:
            if p.patch is None:
                labels.append(np.full(len(p), -1, np.int64))
                continue
            lab = p.patch.astype(np.int64)
            labels.append(np.where(lab >= 0, lab + pbase, -1))
            pc = p.patch_cut.astype(np.int64)
            cuts.append(np.where(pc >= 0, pc + cbase, -1))
            pbase += len(pc)
            cbase += int(pc.max()) + 1 if (pc >= 0).any() else 0
        patch = np.concatenate(labels)
        patch_cut = np.concatenate(cuts) if cuts else np.zeros(0, np.int64)
    return SurfelSet(np.vstack([p.positions for p in parts]),
                     np.vstack([p.normals for p in parts]),
                     np.concatenate([p.radii for p in parts]), colors, faces=faces,
                     name=parts[0].name if name is None else name, patch=patch,
                     patch_cut=patch_cut)


def repair_model(model, *, samples: int | None = None, seed: int = 0,
                 max_edge_ratio: float | None = MAX_EDGE_RATIO, options=None,
                 name: str | None = None, path=None) -> Model:
    """A model as read, brought to closed genus-0 parts: every mesh as it is, repaired to parts.

    A mesh that is one closed, manifold, genus-0 piece becomes exactly the surfels of
    :meth:`TriangleMesh.to_surfels` (one part, no patch labels), so its streams and descriptors
    are those of a plain read. Any other mesh is split into its pieces (:func:`split_parts`:
    pinched vertices split; pieces under ``max(options.min_part_vertices,
    options.min_part_share * V)`` vertices dropped, except the largest, with a ``UserWarning``
    saying how many), and each piece brought to a closed genus-0 surface
    (:func:`close_surface`: handles cut, holes and cut sides capped by fair virtual patches),
    then converted to surfels as :meth:`TriangleMesh.to_surfels` does, with
    :attr:`SurfelSet.patch` marking the virtual surfels (a vertex added by bisection is virtual
    when every face around it is virtual). Colours (vertex colours, or the texture averaged at
    the vertices) go with the scan's vertices; virtual vertices take the harmonic interpolation
    of their rim's. Surfels (a point cloud's, whose proxy surface is closed by construction, or
    a surfel file's) are one part as they are.

    Parameters
    ----------
    model : TriangleMesh or SurfelSet
        What :func:`surfidx.io.read_geometry` read.
    samples : int, optional
        For meshes: sample this many surfels uniformly over each closed part instead of one per
        vertex (:meth:`TriangleMesh.to_surfels`).
    seed : int
        Seed of that sampling.
    max_edge_ratio : float or None
        As for :meth:`TriangleMesh.to_surfels`.
    options : RepairOptions, optional
        Tuning of the repair (default ``RepairOptions()``).
    name : str, optional
        The model's name (default: the mesh's or surfels' own).
    path : str or os.PathLike, optional
        The file the model was read from: an error that names no file is raised again naming
        it.

    Returns
    -------
    Model
        ``kind`` is ``"mesh"`` for a mesh, ``"surfels"`` for surfels with faces, else
        ``"points"``.

    Raises
    ------
    InputError
        A mesh with no faces.
    TopologyError
        A piece that cannot be closed to a sphere (non-orientable: a Möbius strip, a Klein
        bottle), or faces none of which is a triangle.

    Warns
    -----
    UserWarning
        Tiny pieces dropped (how many, how many vertices), degenerate faces dropped.
    """
    from .options import RepairOptions

    options = RepairOptions() if options is None else options
    try:
        if isinstance(model, TriangleMesh):
            return _mesh_model(model, samples, seed, max_edge_ratio, options,
                               name or model.name, path)
        if not isinstance(model, SurfelSet):
            raise InputError(f"repair_model needs a TriangleMesh or SurfelSet, got "
                             f"{type(model).__name__}")
        kind = "surfels" if model.faces is not None else "points"
        return Model(parts=(model,), reports=(None,), kind=kind, areas=(0.0,),
                     name=name or model.name)
    except SurfidxError as exc:
        if path is not None and exc.path is None:
            raise type(exc)(exc.reason, path=path) from exc
        raise


def _mesh_model(mesh: TriangleMesh, samples, seed, max_edge_ratio, options, name, path):
    """:func:`repair_model` of one mesh: as it is when it is a sphere, else repaired to parts."""
    from .repair import analyse, close_surface, closed_mesh, split_parts

    if name is not None:
        mesh.name = name
    if not len(mesh.faces):
        raise InputError("the mesh has no faces; read it as a point cloud instead")
    topo = analyse(mesh.vertices, mesh.faces, options=options)
    textured = mesh if (mesh.texture is not None and mesh.uv is not None
                        and mesh.uv_faces is not None) else None

    def convert(m):
        with warnings.catch_warnings():
            warnings.simplefilter("default")
            return m.to_surfels(samples=samples, seed=seed, max_edge_ratio=max_edge_ratio,
                                return_face_patch=True)

    if topo.is_sphere:
        s, _ = convert(mesh)
        return Model(parts=(s,), reports=(None,), topology=topo, kind="mesh",
                     areas=(float(mesh.face_areas().sum()),), name=name, texture=textured)
    colors = mesh._vertex_colors()
    pieces = split_parts(mesh.vertices, mesh.faces, options=options)
    parts, reports, areas, fps = [], [], [], []
    for i, part in enumerate(pieces.parts):
        try:
            closed = close_surface(part.vertices, part.faces, options=options)
        except SurfidxError as exc:
            what = f"piece {i + 1} of {len(pieces.parts)} ({len(part.vertices)} vertices): " \
                if len(pieces.parts) > 1 else ""
            raise type(exc)(what + exc.reason, path=path) from exc
        cm = closed_mesh(closed, colors=None if colors is None else colors[part.vertex_index],
                         name=name)
        s, fp = convert(cm)
        parts.append(s)
        fps.append(fp)
        reports.append(closed.report)
        areas.append(float(cm.face_areas().sum()))
    return Model(parts=tuple(parts), reports=tuple(reports), topology=topo, kind="mesh",
                 parts_dropped=pieces.dropped, dropped_vertices=pieces.dropped_vertices,
                 areas=tuple(areas), name=name, face_patches=tuple(fps), texture=textured)


def read_model(path, *, texture=None, samples: int | None = None, seed: int = 0,
               max_edge_ratio: float | None = MAX_EDGE_RATIO,
               allow_outside_textures: bool = False, options=None,
               name: str | None = None) -> Model:
    """Read any file (or model in memory) for storing: :func:`surfidx.io.read_geometry`, then
    :func:`repair_model` (every mesh as it is, repaired to parts).

    A mesh that is one closed, manifold, genus-0 piece becomes exactly
    :func:`surfidx.io.read_surfels`' surfels (one part, no patch labels), so its streams and descriptors
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
    :func:`surfidx.io.read_surfels` reads them (a point cloud's proxy surface is closed by construction).

    Parameters
    ----------
    path : str or os.PathLike, or a model in memory
        As for :func:`surfidx.io.read_surfels` (a ``TriangleMesh``, ``(vertices, faces[, colours])`` or a
        trimesh object is repaired as a file's mesh is).
    texture, samples, seed, max_edge_ratio, allow_outside_textures
        As for :func:`surfidx.io.read_surfels`.
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
        As for :func:`surfidx.io.read_surfels`.
    InputError
        As for :func:`surfidx.io.read_surfels`.
    TopologyError
        A piece that cannot be closed to a sphere (non-orientable: a Möbius strip, a Klein
        bottle), or faces none of which is a triangle.

    Warns
    -----
    UserWarning
        Tiny pieces dropped (how many, how many vertices), degenerate faces dropped.
    """
    from ..io.reading import read_geometry          # the readers and their formats: on use

    geometry = read_geometry(path, texture=texture, samples=samples,
                             allow_outside_textures=allow_outside_textures, name=name)
    return repair_model(geometry, samples=samples, seed=seed, max_edge_ratio=max_edge_ratio,
                        options=options, name=name,
                        path=Path(path) if isinstance(path, (str, os.PathLike)) else None)
