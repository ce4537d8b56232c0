"""Topology repair: any triangle mesh brought to closed genus-0 pieces, the additions recorded.

The spherical map (:func:`surfidx.sphere.parameterize`) needs one closed, manifold, genus-0
surface. Real scans are open (occlusion leaves holes), pinched, have handles or come in several
pieces. This package analyses a mesh and repairs it in steps, one module each:

1. :mod:`.pinch`: pinched (non-manifold) vertices and edges split, one vertex per fan;
2. :mod:`.pieces`: the pieces (connected components after splitting), tiny ones dropped;
3. orientation: faces of one piece wound consistently (flips recorded; a non-orientable piece is
   refused);
4. :mod:`.handles`: each handle cut along its shortest greedy homotopy generator (tree-cotree),
   until the genus is 0;
5. :mod:`.holes`: each boundary loop (holes and both sides of every cut) capped by a fair
   patch (Liepa 2003) of *virtual* vertices and faces;
6. :mod:`.patches`: the closed piece as a :class:`~surfidx.TriangleMesh` with its virtual faces
   labelled (:func:`closed_mesh`), whose surfels carry the patch labels the codec codes.

The scan itself is not changed: its vertices come first and keep their positions, its faces come
first, in their order, only renumbered where a vertex was duplicated (split or cut) and reversed
where the winding was inconsistent. Merging the vertices of equal
:attr:`ClosedSurface.vertex_origin` and dropping the virtual faces gives the input back (pinches
and handles included).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

from ..errors import InputError, TopologyError
from ..geometry.mesh import TriangleMesh
from ..validate import as_array
from .analysis import (boundary_loops, distinct_corners, edge_table, euler_characteristic,
                       face_components, orientation, used_count)
from .options import RepairOptions
from .pieces import drop_threshold, piece_faces
from .pinch import split_pinched
from .patches import closed_mesh, patch_cuts

if TYPE_CHECKING:                          # imported by the to_trimesh methods only
    import trimesh

__all__ = ["RepairOptions", "TopologyReport", "RepairReport", "CutCycle", "ClosedSurface", "Part",
           "Parts", "analyse", "close_surface", "split_parts", "closed_mesh", "patch_cuts"]


@dataclass(frozen=True)
class TopologyReport:
    """What a mesh is and what :func:`close_surface` / :func:`split_parts` would add.

    Attributes
    ----------
    vertices, faces, edges : int
        Used vertices, faces with distinct corners, their edges.
    degenerate_faces : int
        Faces repeating a corner (ignored).
    components : int
        Connected components through shared vertices, as the file has them.
    pinched_vertices : int
        Vertices whose faces form several fans.
    nonmanifold_edges : int
        Edges of three or more faces.
    parts : int
        Pieces once pinches are split (two spheres touching at a vertex: 2).
    part_vertices : tuple of int
        Vertices of each piece, largest first.
    parts_dropped : int
        Pieces :func:`split_parts` would drop as tiny (``options``' threshold).
    orientable : bool
        Every piece can be wound consistently.
    holes : int
        Boundary loops (after splitting pinches).
    hole_sizes : tuple of int
        Edges of each boundary loop, largest first.
    euler : int
        V - E + F of the used vertices.
    genus : tuple of int
        Genus of each piece (largest first), ``(2 - χ - b) / 2``; -1 for a non-orientable piece.
    closed : bool
        No boundary edge, non-manifold edge or pinched vertex.
    handles : int
        Handles to cut (sum of the kept pieces' genus).
    """

    vertices: int
    faces: int
    edges: int
    degenerate_faces: int
    components: int
    pinched_vertices: int
    nonmanifold_edges: int
    parts: int
    part_vertices: tuple
    parts_dropped: int
    orientable: bool
    holes: int
    hole_sizes: tuple
    euler: int
    genus: tuple
    closed: bool
    handles: int

    @property
    def is_sphere(self) -> bool:
        """One closed, orientable, genus-0 piece: the map takes it as it is."""
        return self.closed and self.parts == 1 and self.orientable and self.genus == (0,)

    @property
    def patches(self) -> int:
        """Virtual patches the repair would add: one per hole, two per handle."""
        return self.holes + 2 * self.handles

    def as_dict(self) -> dict:
        """The report as a plain dict (with ``is_sphere`` and ``patches``)."""
        d = dict(self.__dict__)
        d["is_sphere"], d["patches"] = self.is_sphere, self.patches
        return d


@dataclass(frozen=True)
class RepairReport:
    """What :func:`close_surface` added.

    Attributes
    ----------
    holes_filled : int
        Holes of the input capped (cut sides not counted).
    hole_sizes : tuple of int
        Rim vertices of each patch (input holes and the two sides of each cut), in the order
        of :attr:`ClosedSurface.patch` (loops ordered by their smallest vertex).
    handles_cut : int
    cut_lengths : tuple of float
        Length of each cut cycle, in model units.
    pinched_vertices : int
        Input vertices duplicated because their faces formed several fans.
    nonmanifold_edges : int
        Input edges of three or more faces.
    flipped_faces : int
        Input faces whose winding was reversed.
    degenerate_faces : int
        Input faces repeating a corner, dropped.
    duplicated_vertices : int
        Vertex copies added by splitting and cutting.
    virtual_vertices, virtual_faces : int
    virtual_area_share : float
        Share of the closed surface's area on virtual faces.
    genus_before : int
    """

    holes_filled: int
    hole_sizes: tuple
    handles_cut: int
    cut_lengths: tuple
    pinched_vertices: int
    nonmanifold_edges: int
    flipped_faces: int
    degenerate_faces: int
    duplicated_vertices: int
    virtual_vertices: int
    virtual_faces: int
    virtual_area_share: float
    genus_before: int

    def as_dict(self) -> dict:
        """The report as a plain dict."""
        return dict(self.__dict__)


@dataclass(frozen=True)
class CutCycle:
    """One handle cut: the cycle's vertices and their copies on the other side.

    Attributes
    ----------
    vertices : (k,) int64
        The cycle, in order (indices into :attr:`ClosedSurface.vertices`).
    copies : (k,) int64
        ``copies[i]`` is the copy of ``vertices[i]`` taken by the faces on the cut's other side;
        gluing ``copies[i]`` back onto ``vertices[i]`` (and dropping both caps) restores the
        handle.
    """

    vertices: np.ndarray
    copies: np.ndarray


@dataclass(frozen=True)
class ClosedSurface:
    """A closed, manifold, consistently wound genus-0 surface and how it was made.

    Attributes
    ----------
    vertices : (n, 3) float64
        The input vertices (all of them, unchanged, first), then copies of split and cut
        vertices (same positions), then the patches' virtual vertices.
    faces : (m, 3) int64
        The input faces with distinct corners, in input order (renumbered to copies, reversed
        where flipped), then the virtual faces.
    virtual_vertices : (n,) bool
    virtual_faces : (m,) bool
    vertex_origin : (n,) int64
        The input vertex each non-virtual vertex is or copies; -1 for virtual vertices.
    face_origin : (m,) int64
        The input face of each non-virtual face; -1 for virtual faces.
    flipped : (m,) bool
        Faces whose input winding was reversed.
    cuts : tuple of CutCycle
    patch : (m,) int64
        Patch (boundary loop) of each virtual face, -1 for the scan's faces.
    report : RepairReport
    """

    vertices: np.ndarray
    faces: np.ndarray
    virtual_vertices: np.ndarray
    virtual_faces: np.ndarray
    vertex_origin: np.ndarray
    face_origin: np.ndarray
    flipped: np.ndarray
    cuts: tuple
    patch: np.ndarray
    report: RepairReport

    def to_trimesh(self) -> "trimesh.Trimesh":
        """The closed surface as a ``trimesh.Trimesh``: :func:`closed_mesh` of it, converted by
        :meth:`surfidx.TriangleMesh.to_trimesh` (vertices and faces in this order, the virtual
        faces' patches in ``face_attributes["patch"]`` when the repair added any).

        Returns
        -------
        trimesh.Trimesh
        """
        return closed_mesh(self).to_trimesh()


@dataclass(frozen=True)
class Part:
    """One piece of a mesh.

    Attributes
    ----------
    vertices : (k, 3) float64
        The piece's used vertices, in input order.
    faces : (p, 3) int64
        Its faces (input order), indexing ``vertices``.
    vertex_index : (k,) int64
        Input index of each vertex (a vertex pinching two pieces is in both).
    face_index : (p,) int64
        Input index of each face.
    """

    vertices: np.ndarray
    faces: np.ndarray
    vertex_index: np.ndarray
    face_index: np.ndarray

    def to_trimesh(self) -> "trimesh.Trimesh":
        """The piece as a ``trimesh.Trimesh`` (:meth:`surfidx.TriangleMesh.to_trimesh`:
        vertices and faces in this order), with :attr:`vertex_index` in
        ``vertex_attributes["vertex_index"]`` ((k,) uint32, a type glTF can hold) and
        :attr:`face_index` in ``face_attributes["face_index"]`` ((p,) int64).

        Returns
        -------
        trimesh.Trimesh
        """
        out = TriangleMesh(self.vertices, self.faces).to_trimesh()
        out.vertex_attributes["vertex_index"] = np.array(self.vertex_index, np.uint32)
        out.face_attributes["face_index"] = np.array(self.face_index, np.int64)
        return out


@dataclass(frozen=True)
class Parts:
    """The pieces :func:`split_parts` keeps and what it dropped.

    Attributes
    ----------
    parts : list of Part
        Largest first.
    dropped : int
        Pieces dropped as tiny.
    dropped_vertices : int
        Their vertices.
    threshold : float
        Vertex count under which a piece was dropped.
    """

    parts: list = field(default_factory=list)
    dropped: int = 0
    dropped_vertices: int = 0
    threshold: float = 0.0


def _check(vertices, faces):
    v = as_array(vertices, "vertices", shape=(None, 3))
    f = as_array(faces, "faces", dtype=np.int64, shape=(None, 3))
    if not len(f):
        raise TopologyError("the mesh has no triangle at all; read the file as a point cloud "
                            "(surfidx.read_surfels) to map it through its proxy surface")
    if f.min() < 0 or f.max() >= len(v):
        raise InputError(f"faces index vertices outside 0..{len(v) - 1} (got "
                         f"{int(f.min())}..{int(f.max())}); fix the face list")
    keep = distinct_corners(f)
    if not keep.any():
        raise TopologyError(f"all {len(f)} faces repeat a corner: the mesh has no triangle at "
                            "all; read the file as a point cloud instead")
    return v, f, keep


def _check_options(options):
    if not isinstance(options, RepairOptions):
        raise InputError(f"options must be a RepairOptions, got {type(options).__name__}")
    return options


def _loop_sizes(table, n):
    """Edge counts of the boundary cycles (orientation-free: components of boundary edges) of
    the faces whose :func:`edge_table` is ``table``, over ``n`` vertices."""
    _, edges, count = table
    b = edges[count == 1]
    if not len(b):
        return np.zeros(0, np.int64), np.zeros(n, np.int64) - 1
    g = sp.coo_matrix((np.ones(len(b)), (b[:, 0], b[:, 1])), shape=(n, n))
    _, lab = connected_components(g, directed=False)
    _, comp = np.unique(lab[b[:, 0]], return_inverse=True)
    comp = comp.ravel()
    sizes = np.bincount(comp)
    vlab = np.full(n, -1, np.int64)
    vlab[b.ravel()] = np.repeat(comp, 2)
    return sizes, vlab


def analyse(vertices, faces, *, options: RepairOptions = RepairOptions()) -> TopologyReport:
    """Holes, pinches, genus and pieces of a triangle mesh, and what the repair would add.

    Parameters
    ----------
    vertices : (n, 3) float64
    faces : (m, 3) int64
    options : RepairOptions
        Its part-size threshold decides ``parts_dropped``.

    Returns
    -------
    TopologyReport

    Raises
    ------
    TopologyError
        When there is no triangle at all.
    InputError
        When the arrays are malformed or faces index missing vertices.
    """
    v, f, keep = _check(vertices, faces)
    options = _check_options(options)
    n = len(v)
    f = f[keep]
    comps, flab = face_components(f, n)
    table = edge_table(f, n)
    count = table[2]
    split, origin, pinched, nonman = split_pinched(f, n, table=table)
    nn = n + len(origin)
    if len(origin):
        parts, plab = face_components(split, nn)
        table = edge_table(split, nn)
    else:       # nothing split: the faces, their pieces and edges are those above
        parts, plab = comps, flab
    sizes, vlab = _loop_sizes(table, nn)
    flip = orientation(split, nn, table=table)
    orientable = flip is not None
    # per-part counts
    vpart = np.full(nn, -1, np.int64)
    vpart[split.ravel()] = np.repeat(plab, 3)
    pv = np.bincount(vpart[vpart >= 0], minlength=parts)
    edges = table[1]
    pe = np.bincount(vpart[edges[:, 0]], minlength=parts)
    pf = np.bincount(plab, minlength=parts)
    loop_part = np.zeros(len(sizes), np.int64)
    has = vlab >= 0
    loop_part[vlab[has]] = vpart[has]
    pb = np.bincount(loop_part, minlength=parts) if len(sizes) else np.zeros(parts, np.int64)
    chi = pv - pe + pf
    genus = (2 - chi - pb) // 2
    if not orientable:
        # a non-orientable piece (its faces meet their own flip) has genus -1
        bad = np.array([orientation(split[plab == p], nn) is None for p in range(parts)])
        genus = np.where(bad, -1, genus)
    order = np.lexsort((np.arange(parts), -pv))
    threshold = drop_threshold(int(pv.sum()), options)
    dropped = int(sum(1 for i, p in enumerate(order) if i > 0 and pv[p] < threshold))
    kept = [p for i, p in enumerate(order) if i == 0 or pv[p] >= threshold]
    used = used_count(f, n)
    return TopologyReport(
        vertices=used, faces=len(f), edges=len(count),
        degenerate_faces=int((~keep).sum()), components=comps, pinched_vertices=pinched,
        nonmanifold_edges=nonman, parts=parts, part_vertices=tuple(int(pv[p]) for p in order),
        parts_dropped=dropped, orientable=orientable,
        holes=len(sizes), hole_sizes=tuple(int(s) for s in np.sort(sizes)[::-1]),
        euler=used - len(count) + len(f), genus=tuple(int(genus[p]) for p in order),
        closed=bool(len(sizes) == 0 and nonman == 0 and pinched == 0 and (count == 2).all()),
        handles=int(sum(max(int(genus[p]), 0) for p in kept)))


def split_parts(vertices, faces, *, options: RepairOptions = RepairOptions()) -> Parts:
    """Split a mesh into its pieces and drop the tiny ones.

    Pieces are the components after pinched vertices and non-manifold edges are split, so each
    one can be closed by :func:`close_surface`. A piece with fewer vertices than
    ``max(options.min_part_vertices, options.min_part_share * V)`` is dropped, except the
    largest.

    Parameters
    ----------
    vertices : (n, 3) float64
    faces : (m, 3) int64
    options : RepairOptions

    Returns
    -------
    Parts

    Raises
    ------
    TopologyError
        When there is no triangle at all.
    InputError
        When the arrays are malformed or faces index missing vertices.

    Warns
    -----
    UserWarning
        Saying how many pieces (and vertices) were dropped, when any were.
    """
    v, f, keep = _check(vertices, faces)
    options = _check_options(options)
    rows = np.flatnonzero(keep)
    kept, dropped, sizes = piece_faces(f[rows], len(v), options)
    parts = []
    for r in kept:
        fi = rows[r]
        sub = f[fi]
        used = np.unique(sub)
        remap = np.full(len(v), -1, np.int64)
        remap[used] = np.arange(len(used))
        parts.append(Part(vertices=v[used], faces=remap[sub], vertex_index=used.astype(np.int64),
                          face_index=fi.astype(np.int64)))
    dropped_v = int(sizes[len(kept):].sum())
    threshold = drop_threshold(int(sizes.sum()), options)
    if dropped:
        warnings.warn(f"{len(dropped)} tiny pieces ({dropped_v} vertices, each under "
                      f"{threshold:.0f}) of {len(kept) + len(dropped)} were dropped",
                      UserWarning, stacklevel=2)
    return Parts(parts=parts, dropped=len(dropped), dropped_vertices=dropped_v,
                 threshold=threshold)


def close_surface(vertices, faces, *, options: RepairOptions = RepairOptions()) -> ClosedSurface:
    """Bring one piece to a closed, manifold, consistently wound genus-0 surface.

    Pinched vertices and non-manifold edges are split, the winding made consistent, every
    handle cut along a short non-separating cycle and every boundary loop capped by a fair
    virtual patch (see the package documentation). A closed genus-0 manifold comes back with
    its faces as they are and nothing virtual.

    Parameters
    ----------
    vertices : (n, 3) float64
    faces : (m, 3) int64
        One piece: connected once pinched vertices are split (:func:`split_parts` gives those).
    options : RepairOptions

    Returns
    -------
    ClosedSurface

    Raises
    ------
    TopologyError
        When there is no triangle at all, the piece falls apart into several pieces once its
        pinched vertices are split, or it is non-orientable (a Möbius strip, a Klein bottle).
    InputError
        When the arrays are malformed, faces index missing vertices or ``options`` is not a
        RepairOptions.
    """
    v, f_in, keep = _check(vertices, faces)
    options = _check_options(options)
    n0 = len(v)
    face_rows = np.flatnonzero(keep)
    f = f_in[keep]
    f, origin, pinched, nonman = split_pinched(f, n0)
    origin_all = np.concatenate([np.arange(n0, dtype=np.int64), origin])
    n = len(origin_all)
    parts, _ = face_components(f, n)
    if parts > 1:
        raise TopologyError(f"the surface falls apart into {parts} pieces once its pinched "
                            "vertices and non-manifold edges are split; close each piece on its "
                            "own (surfidx.topology.split_parts gives them)")
    flip = orientation(f, n)
    if flip is None:
        raise TopologyError("the surface is non-orientable (a Möbius strip or Klein bottle: no "
                            "consistent winding of its faces exists); it cannot be mapped to the "
                            "sphere; remove the twisted region or store it as a point cloud")
    f = np.where(flip[:, None], f[:, [0, 2, 1]], f)
    loops0 = boundary_loops(f, n)
    genus = (2 - euler_characteristic(f, n) - len(loops0)) // 2
    V = v[origin_all] if len(origin) else v.copy()
    cuts, cut_lengths = [], []
    for _ in range(max(genus, 0)):
        from .handles import cut_shortest_handle

        f, cycle, copies, _ = cut_shortest_handle(V, f, options)
        V = np.vstack([V, V[cycle]])
        origin_all = np.concatenate([origin_all, origin_all[cycle]])
        cuts.append(CutCycle(vertices=cycle, copies=copies))
        P = V[cycle]
        cut_lengths.append(float(np.linalg.norm(P - np.roll(P, -1, axis=0), axis=1).sum()))
    if cuts:   # a cut through a vertex of a hole's rim can pinch it: split again
        f, extra, _, _ = split_pinched(f, len(V))
        if len(extra):
            V = np.vstack([V, V[extra]])
            origin_all = np.concatenate([origin_all, origin_all[extra]])
    n_real = len(V)
    loops = boundary_loops(f, n_real)
    on_cut = np.zeros(n_real, bool)
    for cut in cuts:
        on_cut[cut.vertices] = True
        on_cut[cut.copies] = True
    lids = np.array([bool(on_cut[lp].all()) for lp in loops], bool)
    from .holes import fill_holes

    allv, patch, hole = fill_holes(V, f, loops, options, membrane=lids)
    nv, m_real = len(allv), len(f)
    faces_out = np.vstack([f, patch]).astype(np.int64)
    virtual_v = np.zeros(nv, bool)
    virtual_v[n_real:] = True
    virtual_f = np.zeros(len(faces_out), bool)
    virtual_f[m_real:] = True
    vertex_origin = np.concatenate([origin_all, np.full(nv - n_real, -1, np.int64)])
    face_origin = np.concatenate([face_rows, np.full(len(patch), -1, np.int64)])
    flipped = np.concatenate([flip, np.zeros(len(patch), bool)])
    patch_id = np.concatenate([np.full(m_real, -1, np.int64), hole])
    tri = allv[faces_out]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    total = float(area.sum())
    share = float(area[virtual_f].sum() / total) if total > 0 else 0.0
    report = RepairReport(
        holes_filled=len(loops0), hole_sizes=tuple(len(lp) for lp in loops),
        handles_cut=len(cuts), cut_lengths=tuple(cut_lengths), pinched_vertices=pinched,
        nonmanifold_edges=nonman, flipped_faces=int(flip.sum()),
        degenerate_faces=int((~keep).sum()), duplicated_vertices=n_real - n0,
        virtual_vertices=nv - n_real, virtual_faces=len(patch), virtual_area_share=share,
        genus_before=int(genus))
    return ClosedSurface(vertices=allv, faces=faces_out, virtual_vertices=virtual_v,
                         virtual_faces=virtual_f, vertex_origin=vertex_origin,
                         face_origin=face_origin, flipped=flipped, cuts=tuple(cuts),
                         patch=patch_id, report=report)
