"""Triangle meshes: topology checks and conversion to surfels.

Surfels are placed at the used vertices, in the mesh's vertex order, or sampled uniformly over the
surface. Normals are area-weighted face normals oriented outward, radii the smallest that let the
disks cover every incident triangle, colours come from vertex colours or from the texture.

A surfel stands for the surface around its vertex, so a triangle far larger than its neighbours
(a decimated mesh's flat base, a long sliver across a planar region) is not represented by its
corners' disks: they are tilted by the neighbouring faces and would have to be many times wider
than the local spacing. Before the per-vertex conversion such triangles are bisected along their
longest edge (Rivara 1984; conforming, angles stay bounded) until no edge exceeds
:data:`MAX_EDGE_RATIO` times the median edge length, and the new vertices become surfels too,
after the mesh's own. A few such triangles can hold most of the point-to-plane error of the
vertex surfels against the surface; bisecting them adds a few surfels on meshes that have them
and none on uniform meshes.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from ..errors import InputError
from ..tolerance import TOL
from ..validate import as_array
from .surfels import SurfelSet, _rgba

if TYPE_CHECKING:   # trimesh: by :meth:`TriangleMesh.to_trimesh` only; scipy: where a graph is
    import scipy.sparse as sp          # built, not for the mesh a decoding returns
    import trimesh

__all__ = ["TriangleMesh", "Topology", "MAX_EDGE_RATIO", "sample_texture", "spacing_radii",
           "cotangent_laplacian", "vertex_area_shares"]

#: Per-vertex conversion bisects edges longer than this many times the median edge length: a
#: lower ratio adds surfels for little more accuracy, a higher one leaves the large triangles that
#: hold the error.
MAX_EDGE_RATIO = 4.0

#: Bisection gives up when it would more than multiply the vertex count by this (plus 1000): the
#: mesh then mixes triangles of wildly different sizes, which bisection cannot even out.
_MAX_BISECTION_GROWTH = 5


@dataclass(frozen=True)
class Topology:
    """Topological summary of a triangle mesh.

    Attributes
    ----------
    vertices, faces, edges : int
        Counts over used vertices and non-degenerate faces.
    components : int
        Connected components (by shared vertices).
    boundary_edges : int
        Edges with one incident face.
    nonmanifold_edges : int
        Edges with more than two incident faces.
    nonmanifold_vertices : int
        Vertices whose incident faces form more than one fan (pinched vertices).
    euler : int
        V - E + F.
    closed : bool
        Every edge has exactly two faces.
    genus : int or None
        (2 - euler) / 2 for a closed, connected, manifold mesh; None otherwise.
    """

    vertices: int
    faces: int
    edges: int
    components: int
    boundary_edges: int
    nonmanifold_edges: int
    nonmanifold_vertices: int
    euler: int
    closed: bool
    genus: int | None

    def as_dict(self) -> dict:
        return dict(self.__dict__)


class TriangleMesh:
    """A triangle mesh with optional vertex colours or a UV texture.

    Parameters
    ----------
    vertices : (n, 3) float64
    faces : (m, 3) int64
        Indices into ``vertices``; winding gives the face orientation.
    vertex_colors : (n, 3) uint8, optional
    uv : (k, 2) float64, optional
        Texture coordinates; ``uv_faces`` indexes them per face corner.
    uv_faces : (m, 3) int64, optional
    texture : (h, w, 3) uint8, optional
        Texture image, row 0 at the top (v = 1).
    name : str, optional
    face_patch : (m,) int64, optional
        Virtual patch of each face (-1: a face of the scan, ``p >= 0``: a face topology repair
        added to cap boundary loop ``p``, :func:`surfidx.topology.close_surface`). Kept by
        :meth:`bisected` (both halves of a face keep its label) and turned into the surfels'
        :attr:`SurfelSet.patch` by :meth:`to_surfels`: a surfel is virtual, of patch ``p``, when
        every face around it is of patch ``p`` (so an edge midpoint inside a patch, a chord
        across it included, is virtual; one on the rim is real). ``None``: all faces are real.
    patch_cut : (P,) int64, optional
        Per patch, the handle cut it closes or -1 for a hole (:attr:`SurfelSet.patch_cut`);
        only with ``face_patch``.

    Attributes
    ----------
    vertices : (n, 3) float64
    faces : (m, 3) int64
    vertex_colors : (n, 3) uint8 or None
        RGB per vertex.
    uv : (k, 2) float64 or None
        Texture coordinates, v upwards (OBJ's and trimesh's convention).
    uv_faces : (m, 3) int64 or None
        Indices into :attr:`uv` per face corner.
    texture : (h, w, 3) uint8 or None
        Texture image, row 0 at the top.
    name : str or None
    face_patch : (m,) int64 or None
        Virtual patch of each face (-1: a face of the scan), or None when all are real.
    patch_cut : (P,) int64 or None
        Handle cut of each patch (-1: a hole), or None without :attr:`face_patch`.

    See Also
    --------
    surfidx.io.read_mesh : a file as a mesh.
    surfidx.io.read_geometry : a ``trimesh.Trimesh`` in memory as a mesh.
    """

    def __init__(self, vertices, faces, *, vertex_colors=None, uv=None, uv_faces=None,
                 texture=None, name=None, face_patch=None, patch_cut=None):
        self.vertices = as_array(vertices, "vertices", shape=(None, 3))
        self.faces = as_array(faces, "faces", dtype=np.int64, shape=(None, 3))
        n = len(self.vertices)
        if self.faces.size and (self.faces.min() < 0 or self.faces.max() >= n):
            raise InputError(f"faces index vertices outside 0..{n - 1}")
        self.vertex_colors = None
        if vertex_colors is not None:
            self.vertex_colors = np.ascontiguousarray(vertex_colors, dtype=np.uint8)
        self.uv = None if uv is None else as_array(uv, "uv", shape=(None, 2))
        self.uv_faces = None if uv_faces is None else as_array(
            uv_faces, "uv_faces", dtype=np.int64, shape=self.faces.shape)
        if self.uv is not None and self.uv_faces is not None and self.uv_faces.size and (
                self.uv_faces.min() < 0 or self.uv_faces.max() >= len(self.uv)):
            raise InputError("texture-coordinate indices out of range")
        self.texture = texture
        self.name = name
        self.face_patch = self.patch_cut = None
        if face_patch is not None:
            self.face_patch = as_array(face_patch, "face_patch", dtype=np.int64,
                                       shape=(len(self.faces),))
            if self.face_patch.size and self.face_patch.min() < -1:
                raise InputError(f"face_patch labels must be -1 (a face of the scan) or a patch "
                                 f"index >= 0, got {int(self.face_patch.min())}")
            count = int(self.face_patch.max()) + 1 if self.face_patch.size else 0
            self.patch_cut = np.full(count, -1, np.int64) if patch_cut is None else as_array(
                patch_cut, "patch_cut", dtype=np.int64, shape=(None,))
        elif patch_cut is not None:
            raise InputError("patch_cut was given without face_patch; pass the per-face patch "
                             "labels")

    # ------------------------------------------------------------------ geometry
    def face_normals(self, *, unit: bool = True) -> np.ndarray:
        """(m, 3) float64 face normals (cross product; its length is twice the area)."""
        v = self.vertices[self.faces]
        nrm = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
        if unit:
            nrm = nrm / np.maximum(np.linalg.norm(nrm, axis=1), 1e-300)[:, None]
        return nrm

    def face_areas(self) -> np.ndarray:
        """(m,) float64 triangle areas."""
        return 0.5 * np.linalg.norm(self.face_normals(unit=False), axis=1)

    def vertex_normals(self) -> np.ndarray:
        """Unit vertex normals: the area-weighted sum of the incident faces' normals, pointing
        outward on a closed mesh (whatever its winding), as the surfels of :meth:`to_surfels`.

        A vertex whose incident normals cancel takes one incident face's normal, and a vertex
        no face uses ``(0, 0, 1)``, so every row is a unit vector (what glTF's ``NORMAL`` and
        OBJ's ``vn`` need, degenerate triangles of a coarse decoded grid included).

        Returns
        -------
        (n, 3) float64
        """
        if not len(self.faces):
            out = np.zeros((len(self.vertices), 3))
            out[:, 2] = 1.0
            return out
        return self._vertex_normals()

    def signed_volume(self) -> float:
        """Signed enclosed volume (positive when faces wind counter-clockwise seen from outside)."""
        v = self.vertices[self.faces]
        return float(np.einsum("ij,ij->i", v[:, 0], np.cross(v[:, 1], v[:, 2])).sum() / 6.0)

    def used_vertices(self) -> np.ndarray:
        """(k,) int64 sorted indices of vertices referenced by a face."""
        used = np.zeros(len(self.vertices), bool)
        used[self.faces.ravel()] = True
        return np.flatnonzero(used)

    # ------------------------------------------------------------------ interoperability
    def to_trimesh(self) -> "trimesh.Trimesh":
        """The mesh as a ``trimesh.Trimesh`` (built with ``process=False``; trimesh is imported
        on this call).

        Without a texture the trimesh has this mesh's vertices and faces as they are, in their
        order. A texture is a material on per-vertex texture coordinates, so the mesh is split
        at its UV seams: one trimesh vertex per texture coordinate where each texture coordinate
        belongs to one vertex (a mesh read from glTF, GLB or a trimesh object, whose original
        vertices this restores), else one per distinct (vertex, texture coordinate) pair of the
        faces, in order of first use.

        Returns
        -------
        trimesh.Trimesh
            ``vertices`` : (n', 3) float64
                :attr:`vertices` (``n' = n`` without a texture).
            ``faces`` : (m, 3) int64
                :attr:`faces`, renumbered to the split vertices with a texture.
            ``vertex_normals`` : (n', 3) float64
                The area-weighted normals :meth:`to_surfels` gives its surfels (outward on a
                closed mesh).
            ``visual``
                With a texture: ``TextureVisuals`` with ``uv`` (n', 2) float64 and a
                ``PBRMaterial`` whose ``baseColorTexture`` is :attr:`texture` (a PIL image);
                with vertex colours: (n', 4) uint8 RGBA, alpha 255; else trimesh's default.
            ``vertex_attributes`` : dict
                ``"color"``: (n', 4) uint8 RGBA, the vertex colours of a mesh that has both
                vertex colours and a texture.
            ``face_attributes`` : dict
                ``"patch"``: (m,) int64, :attr:`face_patch` where the mesh has it.
            ``metadata`` : dict
                ``"name"``; ``"patch_cut"`` (P,) int64 with :attr:`face_patch`.

        Notes
        -----
        :func:`surfidx.io.read_geometry` (and :func:`~surfidx.io.as_surfels`) read the trimesh
        back, merging vertices of equal position: a mesh whose vertices are distinct comes back
        with the same vertices, faces, colours, texture coordinates and texture.
        """
        import trimesh

        vertex_colors = _rgba(self.vertex_colors)
        normals = self._vertex_normals()
        meta = {"name": self.name}
        face_attrs, vertex_attrs = {}, {}
        if self.face_patch is not None:
            face_attrs["patch"] = self.face_patch.copy()
            meta["patch_cut"] = self.patch_cut.copy()
        if self.texture is None or self.uv is None or self.uv_faces is None:
            return trimesh.Trimesh(self.vertices.copy(), self.faces.copy(),
                                   vertex_normals=normals, vertex_colors=vertex_colors,
                                   face_attributes=face_attrs, metadata=meta, process=False)
        from PIL import Image

        index, faces, uv = self._uv_vertices()
        if vertex_colors is not None:
            vertex_attrs["color"] = vertex_colors[index]
        material = trimesh.visual.material.PBRMaterial(
            baseColorTexture=Image.fromarray(np.ascontiguousarray(self.texture, np.uint8)))
        return trimesh.Trimesh(self.vertices[index], faces, vertex_normals=normals[index],
                               visual=trimesh.visual.TextureVisuals(uv=uv, material=material),
                               face_attributes=face_attrs, vertex_attributes=vertex_attrs,
                               metadata=meta, process=False)

    def _uv_vertices(self):
        """The mesh split at its UV seams: ``(index, faces, uv)``, the vertex of each split
        vertex, the faces over the split vertices and their texture coordinates (see
        :meth:`to_trimesh`)."""
        corner_v, corner_t = self.faces.ravel(), self.uv_faces.ravel()
        owner = np.full(len(self.uv), -1, np.int64)
        owner[corner_t] = corner_v
        if np.all(owner >= 0) and np.array_equal(owner[corner_t], corner_v):
            return owner, self.uv_faces.copy(), self.uv.copy()
        key = corner_v * np.int64(len(self.uv)) + corner_t
        _, first, inverse = np.unique(key, return_index=True, return_inverse=True)
        order = np.argsort(first, kind="stable")
        rank = np.empty(len(order), np.int64)
        rank[order] = np.arange(len(order))
        pairs = key[first[order]]
        faces = rank[np.asarray(inverse).ravel()].reshape(-1, 3)
        return pairs // len(self.uv), faces, self.uv[pairs % len(self.uv)]

    # ------------------------------------------------------------------ topology
    def topology(self) -> Topology:
        """Counts, closedness and genus of the mesh (degenerate index triples are ignored)."""
        f = self.faces
        f = f[(f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 0] != f[:, 2])]
        used = np.unique(f)
        nv, nf = len(used), len(f)
        n = len(self.vertices)
        keys, ecount, base = _undirected_edges(f, n)
        ekeys = np.column_stack([keys // base, keys % base])
        ne = len(ekeys)
        if nf:
            import scipy.sparse as sp
            from scipy.sparse.csgraph import connected_components

            adj = sp.coo_matrix((np.ones(len(ekeys)), (ekeys[:, 0], ekeys[:, 1])), shape=(n, n))
            ncomp, lab = connected_components(adj, directed=False)
            ncomp = len(np.unique(lab[used]))
        else:
            ncomp = 0
        boundary = int((ecount == 1).sum())
        nonman_e = int((ecount > 2).sum())
        nonman_v = self._pinched_vertices(f, n)
        euler = nv - ne + nf
        closed = nf > 0 and boundary == 0 and nonman_e == 0
        genus = None
        if closed and ncomp == 1 and nonman_v == 0 and (2 - euler) % 2 == 0:
            genus = (2 - euler) // 2
        return Topology(nv, nf, ne, ncomp, boundary, nonman_e, nonman_v, euler, closed, genus)

    @staticmethod
    def _pinched_vertices(f: np.ndarray, n: int) -> int:
        """Vertices whose incident faces form more than one edge-connected fan."""
        if not len(f):
            return 0
        m = len(f)
        # corners: (face, vertex); two corners of one vertex are fan-adjacent when their faces
        # share the edge from that vertex to a common other vertex.
        corner_v = f.ravel()
        corner_f = np.repeat(np.arange(m), 3)
        nxt = np.roll(f, -1, axis=1).ravel()
        prv = np.roll(f, 1, axis=1).ravel()
        # half-edge keys (v, other) for both edges of a corner
        keys = np.concatenate([corner_v * n + nxt, corner_v * n + prv])
        cid = np.concatenate([np.arange(3 * m), np.arange(3 * m)])
        order = np.argsort(keys, kind="stable")
        ks, cs = keys[order], cid[order]
        same = ks[1:] == ks[:-1]
        a, b = cs[:-1][same], cs[1:][same]
        import scipy.sparse as sp
        from scipy.sparse.csgraph import connected_components

        g = sp.coo_matrix((np.ones(len(a)), (a, b)), shape=(3 * m, 3 * m))
        _, lab = connected_components(g, directed=False)
        fans = np.unique(corner_v * np.int64(3 * m) + lab)       # distinct (vertex, fan) pairs
        per_v = np.bincount(fans // (3 * m), minlength=n)
        del corner_f
        return int((per_v > 1).sum())

    # ------------------------------------------------------------------ conversion
    def to_surfels(self, *, samples: int | None = None, seed: int = 0,
                   max_edge_ratio: float | None = MAX_EDGE_RATIO,
                   return_face_patch: bool = False):
        """Convert to surfels.

        Parameters
        ----------
        samples : int, optional
            Sample this many surfels uniformly over the surface (colours and normals interpolated)
            instead of placing one surfel per used vertex.
        seed : int
            Random seed of the uniform sampling.
        max_edge_ratio : float or None
            Per-vertex conversion first bisects triangles whose edges exceed this many times the
            median edge length (see :meth:`bisected`); ``None`` keeps the mesh as it is.
        return_face_patch : bool
            Also return the virtual patch of each of the surfels' faces.

        Returns
        -------
        SurfelSet
            Per-vertex surfels keep the mesh's vertex order with unused vertices dropped (a
            ``UserWarning`` says how many), followed by the vertices that bisection added;
            ``faces`` then index the surfels. With :attr:`face_patch`, ``patch`` labels the
            virtual surfels (:meth:`vertex_patch`; sampled surfels take their face's label).
        face_patch : (m,) int64 or None
            With ``return_face_patch``: :attr:`face_patch` of the surfels' ``faces`` (None
            without labels or for sampled surfels, which have no faces).

        Raises
        ------
        InputError
            When the mesh has no faces or zero total area, or ``max_edge_ratio`` is not positive.

        Warns
        -----
        UserWarning
            Saying how many degenerate faces (:meth:`nondegenerate_faces`: a repeated corner, zero
            area, collinear corners) were dropped before anything else.
        """
        if not len(self.faces):
            raise InputError("the mesh has no faces; read it as a point cloud instead")
        areas = self.face_areas()
        if not areas.sum() > 0:
            raise InputError("the mesh has zero surface area (every face is degenerate: "
                             "repeated, coincident or collinear corners); it holds no surface")
        if not np.isfinite(areas.sum()):
            raise InputError("the mesh's coordinates are too large for its areas to be finite; "
                             "rescale the model")
        keep = self.nondegenerate_faces(areas)
        if not keep.all():
            mesh = self._with_faces(keep)
            warnings.warn(f"{int((~keep).sum())} degenerate faces (a repeated corner, zero area "
                          "or collinear corners) of "
                          f"{len(keep)} were dropped", UserWarning, stacklevel=2)
            return mesh.to_surfels(samples=samples, seed=seed, max_edge_ratio=max_edge_ratio,
                                   return_face_patch=return_face_patch)
        if samples is None and max_edge_ratio is not None:
            if not (np.isfinite(max_edge_ratio) and max_edge_ratio > 0):
                raise InputError(f"max_edge_ratio must be a positive number or None, got "
                                 f"{max_edge_ratio!r}")
            max_edge = max_edge_ratio * self.median_edge_length()
            mesh = self.bisected(max_edge) if max_edge > 0 else self  # most edges degenerate
            if mesh is not self:
                return mesh.to_surfels(max_edge_ratio=None, return_face_patch=return_face_patch)
        vnormals = self._vertex_normals()
        if samples is not None:
            out = self._sample(int(samples), seed, areas, vnormals)
            return (out, None) if return_face_patch else out
        used = self.used_vertices()
        if len(used) < len(self.vertices):
            warnings.warn(f"{len(self.vertices) - len(used)} vertices referenced by no face were "
                          "dropped; surfel indices follow the remaining vertices' order",
                          UserWarning, stacklevel=2)
        remap = np.full(len(self.vertices), -1, np.int64)
        remap[used] = np.arange(len(used))
        radii = self._cover_radii()[used]
        nrm = vnormals[used]
        colors = self._vertex_colors()
        colors = None if colors is None else colors[used]
        patch = self.vertex_patch()
        out = SurfelSet(self.vertices[used], nrm, radii, colors, faces=remap[self.faces],
                        name=self.name, patch=None if patch is None else patch[used],
                        patch_cut=self.patch_cut)
        return (out, self.face_patch) if return_face_patch else out

    def nondegenerate_faces(self, areas: np.ndarray | None = None) -> np.ndarray:
        """(m,) bool: faces with three distinct corners and an area of at least
        ``TOL.degenerate_area`` times the mean face area (not collinear or coincident corners).

        Parameters
        ----------
        areas : (m,) float64, optional
            The face areas, when already computed.
        """
        f = self.faces
        areas = self.face_areas() if areas is None else areas
        distinct = (f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 0] != f[:, 2])
        return distinct & (areas >= TOL.degenerate_area * areas.mean())

    def _with_faces(self, keep: np.ndarray) -> TriangleMesh:
        """The mesh with only the faces ``keep`` selects (vertices unchanged)."""
        uv_faces = None if self.uv_faces is None else self.uv_faces[keep]
        return TriangleMesh(self.vertices, self.faces[keep], vertex_colors=self.vertex_colors,
                            uv=self.uv, uv_faces=uv_faces, texture=self.texture, name=self.name,
                            face_patch=None if self.face_patch is None else self.face_patch[keep],
                            patch_cut=self.patch_cut)

    def median_edge_length(self) -> float:
        """Median length of the faces' edges (an edge shared by two faces counts twice)."""
        v = self.vertices[self.faces]
        return float(np.median(np.linalg.norm(v - np.roll(v, -1, axis=1), axis=2)))

    def bisected(self, max_edge: float) -> TriangleMesh:
        """The mesh with every edge longer than ``max_edge`` split by longest-edge bisection.

        Each round splits, at its midpoint, every edge that is the longest edge (ties broken by
        vertex indices) of each face holding it, and each of those faces into two along it; a
        face whose longest edge waits for a neighbour's split keeps it for a later round. Every
        round therefore keeps the mesh conforming (no vertex in the middle of an edge), splits at
        least the mesh's longest edge, and keeps face winding. New vertices are appended after
        the existing ones, with vertex colours and texture coordinates interpolated.

        Parameters
        ----------
        max_edge : float
            Longest edge allowed, in model units; must be positive.

        Returns
        -------
        TriangleMesh
            ``self`` when no edge is longer, else a new mesh.

        Raises
        ------
        InputError
            When ``max_edge`` is not positive, a face repeats a corner, or the refinement would
            multiply the vertex count by more than 5 (a few triangles vastly larger than the
            rest).
        """
        if not (np.isfinite(max_edge) and max_edge > 0):
            raise InputError(f"max_edge must be a positive length, got {max_edge!r}")
        verts, faces = self.vertices, self.faces
        colors = None if self.vertex_colors is None else self.vertex_colors.astype(np.float64)
        uv, uv_faces = self.uv, self.uv_faces
        if uv is None or uv_faces is None:
            uv = uv_faces = None
        fpatch = self.face_patch
        limit = _MAX_BISECTION_GROWTH * len(verts) + 1000
        # every round adds at least one vertex (faces with a repeated corner, whose longest edge
        # is held twice by one face, could stall it: they are refused), so ``limit`` rounds bound
        # the loop
        if np.any((faces[:, 0] == faces[:, 1]) | (faces[:, 1] == faces[:, 2])
                  | (faces[:, 0] == faces[:, 2])):
            raise InputError("bisection needs faces with three distinct corners; drop the "
                             "degenerate faces first (to_surfels does)")
        while (split := _bisection_round(verts, faces, max_edge)) is not None:
            if not len(split[0]):  # no edge can be split (cannot happen with distinct corners)
                break
            if len(verts) > limit:
                raise InputError(
                    f"bisecting edges longer than {max_edge:.3g} would add over "
                    f"{limit - len(self.vertices)} vertices: a few triangles are vastly larger "
                    "than the rest; convert with max_edge_ratio=None or sample the surface "
                    "(--samples)")
            rows, k, edge_rank = split
            a, b, c = (faces[rows, (k + i) % 3] for i in range(3))
            first = np.unique(edge_rank, return_index=True)[1]  # one face per split edge
            mid = len(verts) + edge_rank
            verts = np.vstack([verts, 0.5 * (verts[a[first]] + verts[b[first]])])
            if colors is not None:
                colors = np.vstack([colors, 0.5 * (colors[a[first]] + colors[b[first]])])
            keep = np.ones(len(faces), bool)
            keep[rows] = False
            faces = np.vstack([faces[keep], np.stack([a, mid, c], 1), np.stack([mid, b, c], 1)])
            if fpatch is not None:      # both halves keep the face's patch
                fpatch = np.concatenate([fpatch[keep], fpatch[rows], fpatch[rows]])
            if uv is not None:
                ua, ub, uc = (uv_faces[rows, (k + i) % 3] for i in range(3))
                # one new texture coordinate per split face, so seams stay seams
                um = len(uv) + np.arange(len(rows))
                uv = np.vstack([uv, 0.5 * (uv[ua] + uv[ub])])
                uv_faces = np.vstack([uv_faces[keep], np.stack([ua, um, uc], 1),
                                      np.stack([um, ub, uc], 1)])
        if len(verts) == len(self.vertices):
            return self
        if colors is not None:
            colors = np.clip(np.round(colors), 0, 255).astype(np.uint8)
        return TriangleMesh(verts, faces, vertex_colors=colors, uv=uv, uv_faces=uv_faces,
                            texture=self.texture, name=self.name, face_patch=fpatch,
                            patch_cut=self.patch_cut)

    def vertex_patch(self) -> np.ndarray | None:
        """(n,) int64 virtual patch of each vertex from :attr:`face_patch`, or None.

        ``p`` when every face around the vertex is of patch ``p``; -1 otherwise (a vertex of a
        scan's face, or on the seam of two patches, or of no face).
        """
        if self.face_patch is None:
            return None
        n = len(self.vertices)
        lo = np.full(n, np.iinfo(np.int64).max, np.int64)
        hi = np.full(n, -2, np.int64)
        for k in range(3):
            np.minimum.at(lo, self.faces[:, k], self.face_patch)
            np.maximum.at(hi, self.faces[:, k], self.face_patch)
        return np.where((lo == hi) & (lo >= 0), lo, -1)

    def _orientation_sign(self) -> float:
        """-1 when the mesh is closed and its winding encloses negative volume (inward), else +1.

        An open mesh keeps the orientation its winding gives.
        """
        _, count, _ = _undirected_edges(self.faces, len(self.vertices))
        if np.any(count != 2):
            return 1.0
        return -1.0 if self.signed_volume() < 0 else 1.0

    def _vertex_normals(self) -> np.ndarray:
        fn = self.face_normals(unit=False) * self._orientation_sign()  # length = 2 * area
        n = len(self.vertices)
        acc = np.zeros((n, 3))
        for k in range(3):
            for d in range(3):
                acc[:, d] += np.bincount(self.faces[:, k], weights=fn[:, d], minlength=n)
        length = np.linalg.norm(acc, axis=1)
        bad = length <= np.finfo(float).tiny
        if bad.any():  # vertex whose incident normals cancel: take any incident face normal
            fu = fn / np.maximum(np.linalg.norm(fn, axis=1), np.finfo(float).tiny)[:, None]
            for k in range(3):
                acc[self.faces[:, k]] += np.where(bad[self.faces[:, k]][:, None], fu, 0.0)
            length = np.linalg.norm(acc, axis=1)
            still = length <= np.finfo(float).tiny
            acc[still] = (0.0, 0.0, 1.0)
            length[still] = 1.0
        return acc / length[:, None]

    def _cover_radii(self) -> np.ndarray:
        """(n,) radius per vertex: the largest coverage radius of its incident triangles.

        The coverage radius of a triangle is the largest distance from a point of the triangle to
        its nearest corner: the circumradius for a non-obtuse triangle, otherwise the distance from
        an end of the longest edge to where the perpendicular bisector of an adjacent edge meets
        it. Disks of these radii cover every triangle, so neighbouring disks overlap without holes.
        """
        v = self.vertices[self.faces]
        e = np.stack([v[:, 2] - v[:, 1], v[:, 0] - v[:, 2], v[:, 1] - v[:, 0]], axis=1)
        L = np.linalg.norm(e, axis=2)  # L[:, k] is the edge opposite corner k
        # cosine of the angle at each corner
        cos = np.empty_like(L)
        for k in range(3):
            a, b = e[:, (k + 2) % 3], -e[:, (k + 1) % 3]
            cos[:, k] = np.einsum("ij,ij->i", a, b) / np.maximum(L[:, (k + 2) % 3] * L[:, (k + 1) % 3],
                                                                 np.finfo(float).tiny)
        cos = np.clip(cos, -1.0, 1.0)
        sin = np.sqrt(1.0 - cos ** 2)
        obtuse = cos.min(axis=1) < 0
        circum = L[:, 0] / np.maximum(2.0 * sin[:, 0], np.finfo(float).tiny)
        c = circum.copy()
        if obtuse.any():
            k = np.argmin(cos[obtuse], axis=1)  # obtuse corner
            rows = np.flatnonzero(obtuse)
            i1, i2 = (k + 1) % 3, (k + 2) % 3
            # edge from corner i1 to the obtuse corner k is the edge opposite i2, and vice versa
            r1 = L[rows, i2] / np.maximum(2.0 * cos[rows, i1], np.finfo(float).tiny)
            r2 = L[rows, i1] / np.maximum(2.0 * cos[rows, i2], np.finfo(float).tiny)
            c[rows] = np.maximum(r1, r2)
        c = np.minimum(c, L.max(axis=1))  # a sliver's bound never exceeds its longest edge
        out = np.zeros(len(self.vertices))
        for k in range(3):
            np.maximum.at(out, self.faces[:, k], c)
        pos = out > 0
        if not pos.all():
            out[~pos] = out[pos].min() if pos.any() else 1.0
        return out

    def colors_at(self, face, bary) -> np.ndarray:
        """The mesh's colour at points given on its faces, unrounded.

        Vertex colours are interpolated barycentrically; a texture is read bilinearly at the
        interpolated texture coordinates (vertex colours win when the mesh has both, as in
        :meth:`to_surfels`).

        Parameters
        ----------
        face : (n,) int64
            The face holding each point.
        bary : (n, 3) float64
            Its barycentric coordinates in that face.

        Returns
        -------
        (n, 3) float64
            RGB in 0..255.

        Raises
        ------
        InputError
            When the mesh has no colour (neither vertex colours nor a texture with coordinates),
            or a face index is out of range.
        """
        face = as_array(face, "face", dtype=np.int64, shape=(None,))
        bary = as_array(bary, "bary", shape=(len(face), 3))
        if len(face) and (face.min() < 0 or face.max() >= len(self.faces)):
            raise InputError(f"face indices must lie in 0..{len(self.faces) - 1}, got "
                             f"{int(face.min())}..{int(face.max())}")
        if self.vertex_colors is not None:
            corners = self.vertex_colors[self.faces[face]].astype(np.float64)
            return np.einsum("nc,ncd->nd", bary, corners)
        if self.texture is None or self.uv is None or self.uv_faces is None:
            raise InputError("the mesh has no colour (no vertex colours, and no texture with "
                             "texture coordinates); read it with its texture")
        uv = np.einsum("nc,ncd->nd", bary, self.uv[self.uv_faces[face]])
        return sample_texture(self.texture, uv)

    def _vertex_colors(self) -> np.ndarray | None:
        if self.vertex_colors is not None:
            return self.vertex_colors
        if self.texture is None or self.uv is None or self.uv_faces is None:
            return None
        # Average the texture over the part of each incident triangle nearest the vertex,
        # area-weighted, so colours are filtered rather than point-sampled.
        bary = np.array([[1.0, 0, 0], [2 / 3, 1 / 6, 1 / 6], [2 / 3, 1 / 3, 0], [2 / 3, 0, 1 / 3]])
        areas = self.face_areas()
        uvt = self.uv[self.uv_faces]  # (m, 3, 2)
        n = len(self.vertices)
        acc = np.zeros((n, 3))
        wsum = np.zeros(n)
        for k in range(3):
            perm = [k, (k + 1) % 3, (k + 2) % 3]
            tri = uvt[:, perm]
            for b in bary:
                uv = b[0] * tri[:, 0] + b[1] * tri[:, 1] + b[2] * tri[:, 2]
                col = sample_texture(self.texture, uv)
                for d in range(3):
                    acc[:, d] += np.bincount(self.faces[:, k], weights=areas * col[:, d],
                                             minlength=n)
                wsum += np.bincount(self.faces[:, k], weights=areas, minlength=n)
        acc /= np.maximum(wsum, np.finfo(float).tiny)[:, None]
        return np.clip(np.round(acc), 0, 255).astype(np.uint8)

    def _sample(self, count: int, seed: int, areas: np.ndarray, vnormals: np.ndarray) -> SurfelSet:
        if count < 4:
            raise InputError(f"samples must be at least 4, got {count}")
        rng = np.random.default_rng(seed)
        cdf = np.cumsum(areas)
        tri = np.searchsorted(cdf, rng.random(count) * cdf[-1], side="right")
        tri = np.minimum(tri, len(areas) - 1)
        r1, r2 = np.sqrt(rng.random(count)), rng.random(count)
        b = np.stack([1 - r1, r1 * (1 - r2), r1 * r2], axis=1)
        f = self.faces[tri]
        pos = np.einsum("ij,ijk->ik", b, self.vertices[f])
        nrm = np.einsum("ij,ijk->ik", b, vnormals[f])
        ln = np.linalg.norm(nrm, axis=1)
        fn = self.face_normals()[tri] * self._orientation_sign()
        bad = ln < 1e-6
        nrm[bad] = fn[bad]
        nrm /= np.linalg.norm(nrm, axis=1)[:, None]
        colors = None
        if self.vertex_colors is not None:
            colors = np.einsum("ij,ijk->ik", b, self.vertex_colors[f].astype(float))
            colors = np.clip(np.round(colors), 0, 255).astype(np.uint8)
        elif self.texture is not None and self.uv is not None and self.uv_faces is not None:
            uv = np.einsum("ij,ijk->ik", b, self.uv[self.uv_faces[tri]])
            colors = np.clip(np.round(sample_texture(self.texture, uv)), 0, 255).astype(np.uint8)
        radii = spacing_radii(pos)
        patch = None if self.face_patch is None else self.face_patch[tri]
        return SurfelSet(pos, nrm, radii, colors, name=self.name, patch=patch,
                         patch_cut=self.patch_cut)


def _undirected_edges(faces: np.ndarray, n: int):
    """Each undirected edge of ``faces`` (over ``n`` vertices) once, as the key
    ``lo * base + hi`` in increasing order, the number of faces holding it, and ``base`` (one
    integer per edge: a 1-D unique is far faster than ``unique(axis=0)``)."""
    e = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1)
    base = np.int64(max(n, 1))
    keys, count = np.unique(e[:, 0] * base + e[:, 1], return_counts=True)
    return keys, count, base


def _bisection_round(verts: np.ndarray, faces: np.ndarray, max_edge: float):
    """Edges one round of longest-edge bisection splits, or ``None`` when none is too long.

    Returns ``(rows, k, edge_rank)``: the faces split, the corner where each one's split edge
    starts (edge ``k`` runs from corner ``k`` to ``k + 1``), and the rank of that edge among the
    split edges (its new vertex is ``len(verts) + rank``).
    """
    a, b = faces, np.roll(faces, -1, axis=1)
    length = np.linalg.norm(verts[b] - verts[a], axis=2)
    key = np.minimum(a, b) * np.int64(len(verts)) + np.maximum(a, b)
    # longest edge per face, ties broken by the larger key so both faces of an edge agree
    k = _longest(length, key)
    fl = length[np.arange(len(faces)), k]
    cand = np.flatnonzero(fl > max_edge)
    if not len(cand):
        return None
    ck = key[cand, k[cand]]
    all_keys, all_count = np.unique(key, return_counts=True)
    keys, count = np.unique(ck, return_counts=True)
    # split an edge only when it is the longest edge of every face holding it
    keys = keys[count == all_count[np.searchsorted(all_keys, keys)]]
    rows = cand[np.isin(ck, keys)]
    k = k[rows]
    return rows, k, np.searchsorted(keys, key[rows, k])


def _longest(length: np.ndarray, key: np.ndarray) -> np.ndarray:
    """(m,) index of each row's longest edge; among equal lengths the one with the larger key."""
    k = np.argmax(length, axis=1)
    top = length[np.arange(len(length)), k][:, None]
    tie = (length == top).sum(axis=1) > 1
    if tie.any():
        k[tie] = np.argmax(np.where(length[tie] == top[tie], key[tie], -1), axis=1)
    return k


def spacing_radii(points: np.ndarray, *, k: int = 6, name: str = "points") -> np.ndarray:
    """Radii from neighbour spacing: the distance to the ``k``-th nearest neighbour.

    For a uniform random sampling a disk of this radius holds ``k`` other samples on average, so a
    point of the surface is left uncovered with probability about ``exp(-k)`` (0.25% at k = 6).

    Parameters
    ----------
    points : (n, 3) float64
    k : int
    name : str
        What the points are, for error messages (e.g. ``"surfels"``).

    Returns
    -------
    (n,) float64
    """
    from scipy.spatial import cKDTree

    points = as_array(points, name, shape=(None, 3), min_len=2)
    kk = min(k, len(points) - 1)
    d, _ = cKDTree(points).query(points, k=kk + 1)
    r = d[:, kk]
    pos = r > 0
    if not pos.any():
        raise InputError(f"all {name} coincide; cannot derive radii from their spacing")
    r[~pos] = r[pos].min()
    return r


def sample_texture(texture: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Bilinear texture look-up.

    Parameters
    ----------
    texture : (h, w, 3) uint8
        Row 0 is the top of the image (v = 1), as in OBJ/MTL conventions.
    uv : (k, 2) float64
        Texture coordinates; wrapped into [0, 1).

    Returns
    -------
    (k, 3) float64
        Colours in 0..255.
    """
    h, w = texture.shape[:2]
    u = np.mod(uv[:, 0], 1.0) * w - 0.5
    v = (1.0 - np.mod(uv[:, 1], 1.0)) * h - 0.5
    x0 = np.floor(u).astype(np.int64)
    y0 = np.floor(v).astype(np.int64)
    fx, fy = (u - x0)[:, None], (v - y0)[:, None]
    x0c, x1c = np.clip(x0, 0, w - 1), np.clip(x0 + 1, 0, w - 1)
    y0c, y1c = np.clip(y0, 0, h - 1), np.clip(y0 + 1, 0, h - 1)
    def t(y, x):  # gather the texels first: never a float64 copy of the whole image
        return texture[y, x, :3].astype(np.float64)

    top = t(y0c, x0c) * (1 - fx) + t(y0c, x1c) * fx
    bot = t(y1c, x0c) * (1 - fx) + t(y1c, x1c) * fx
    return top * (1 - fy) + bot * fy


def vertex_area_shares(faces: np.ndarray, areas: np.ndarray, n: int) -> np.ndarray:
    """Each vertex's share of the area: a third of each incident triangle's (barycentric cells).

    Parameters
    ----------
    faces : (m, 3) int64
    areas : (m,) float64
        Triangle areas (3D or spherical).
    n : int
        Vertex count.

    Returns
    -------
    (n,) float64
        Summing to ``areas.sum()``; 0 for a vertex in no triangle.
    """
    return np.bincount(faces.ravel(), weights=np.repeat(areas / 3.0, 3), minlength=n)


def cotangent_laplacian(faces: np.ndarray, cot: np.ndarray, n: int) -> sp.csr_matrix:
    """The cotangent Laplacian (stiffness matrix) of a triangle mesh.

    Parameters
    ----------
    faces : (m, 3) int64
    cot : (m, 3) float64
        Cotangent of each triangle's angle at each corner.
    n : int
        Vertex count.

    Returns
    -------
    (n, n) scipy.sparse.csr_matrix
        ``L_ij = -½ Σ cot`` of the angles opposite edge ``ij``, ``L_ii = -Σ_j L_ij``: symmetric,
        rows summing to 0.
    """
    import scipy.sparse as sp

    rows = np.concatenate([faces[:, 1], faces[:, 2], faces[:, 0]])
    cols = np.concatenate([faces[:, 2], faces[:, 0], faces[:, 1]])
    w = 0.5 * np.concatenate([cot[:, 0], cot[:, 1], cot[:, 2]])
    off = sp.coo_matrix((w, (rows, cols)), shape=(n, n)).tocsr()
    off = off + off.T
    return (sp.diags(np.asarray(off.sum(axis=1)).ravel()) - off).tocsr()
