"""The icosahedral grid on the unit sphere and the hierarchy tables of its subdivision.

Level ``L`` of the grid is the icosahedron subdivided ``L`` times by edge midpoints projected to the
unit sphere: ``10·4^L + 2`` vertices, ``30·4^L`` edges, ``20·4^L`` faces.

Vertex order (the convention every table and every coefficient array follows)
--------------------------------------------------------------------------------
* The vertices of level ``j`` are a prefix of those of level ``j + 1``:
  ``icosphere(j + 1).vertices[:counts[j]] == icosphere(j).vertices``.
* The vertices *born* at level ``j + 1`` (indices ``counts[j] .. counts[j+1] - 1``) are the
  normalised midpoints of the level-``j`` edges, in lexicographic order of the edge's endpoint
  indices ``(lo, hi)``, ``lo < hi``.
* Faces: face ``f = (a, b, c)`` of level ``j`` has the four children ``4f .. 4f + 3`` at level
  ``j + 1``: ``(a, ab, ca), (b, bc, ab), (c, ca, bc), (ab, bc, ca)`` (``ab`` = midpoint of
  ``(a, b)``), so face ``4f + 3`` is the inner triangle. All faces are counter-clockwise seen from
  outside (``((b - a) × (c - a)) · (a + b + c) > 0``).

Per-vertex tables (all ``int64``, indexed by vertex id, rows of level-0 vertices hold ``-1``)
--------------------------------------------------------------------------------------------
``level_of[v]``
    The level at which ``v`` is born (0 for the 12 icosahedron vertices).
``edge_parents[v] = (a, b)``
    The level-``j`` edge that vertex ``v`` born at level ``j + 1`` splits, ``a < b``.
``butterfly[v] = (a, b, c, d, e1, e2, e3, e4)``
    The 8-point butterfly stencil (Dyn, Levin & Gregory 1990; Schröder & Sweldens 1995) of ``v`` in
    the level-``j`` mesh, with weights :data:`BUTTERFLY_WEIGHTS`
    ``(1/2, 1/2, 1/8, 1/8, -1/16, -1/16, -1/16, -1/16)``: ``a, b`` the edge endpoints,
    ``c`` the vertex opposite the edge in the triangle where the edge runs ``a → b``
    counter-clockwise, ``d`` the vertex opposite in the other triangle, ``e1, e2`` the "wing"
    vertices across the edges ``(b, c)`` and ``(c, a)``, ``e3, e4`` those across ``(a, d)`` and
    ``(d, b)``. No special handling is needed at the 12 valence-5 vertices: a wing is the third
    vertex of a triangle adjacent to the butterfly, and on a closed triangulation with every valence
    ≥ 4 the 8 vertices are distinct (checked by the tests at every level). We keep the plain 8-point
    stencil there, as Schröder & Sweldens did, not Zorin's modified butterfly; its weights sum to 1,
    so constants are reproduced exactly everywhere.
``tree_parent[v]``
    The zerotree parent (``-1`` for the 12 roots). Rule: every level-``j`` edge (``j ≥ 1``) has one
    owner among the vertices born at level ``j``; the vertex born on that edge at level ``j + 1`` is
    its child. A half of a split level-``(j-1)`` edge ``(m, a)`` is owned by its midpoint ``m``;
    the three inner edges of each subdivided triangle ``(a, b, c)`` are owned cyclically, ``ab``
    owns ``(ab, bc)``, ``bc`` owns ``(bc, ca)``, ``ca`` owns ``(ca, ab)`` (the tail of the inner
    triangle's counter-clockwise half-edge). Every vertex born at ``j ≥ 1`` lies in two level-
    ``(j-1)`` triangles, so it owns two half-edges plus two inner edges: exactly **4 children**.
    The 30 level-1 vertices (edges of the icosahedron) go to the 12 roots by a balanced rule that
    gives every root 2 or 3 children: orient the edges along a deterministic Euler circuit of the
    icosahedron plus a virtual vertex joined to all 12 (see ``_balanced_root_owners``); an edge is
    owned by the endpoint the circuit leaves it from.
``children_indptr, children_indices``
    The inverse of ``tree_parent`` in CSR form: the children of ``v`` are
    ``children_indices[children_indptr[v]:children_indptr[v + 1]]``, ascending; vertices born at
    the grid level have none (their children would live at level ``L + 1``).

Neighbours of the level-``L`` mesh come as CSR (``neighbor_indptr``, ``neighbor_indices``,
ascending ids); :meth:`Icosphere.neighbors` gives those of a coarser level.
"""

from __future__ import annotations

import functools
from typing import TYPE_CHECKING

import numpy as np

from ..errors import InputError
from ..validate import check_positive_int

if TYPE_CHECKING:                     # trimesh is imported by :meth:`Icosphere.to_trimesh` only
    import trimesh

__all__ = ["Icosphere", "icosphere", "vertex_count", "level_of_count", "choose_level", "MAX_LEVEL",
           "SPARSE_MIN", "SPARSE_MAX_LEVEL", "BUTTERFLY_WEIGHTS"]

MAX_LEVEL = 9
"""Finest grid level supported (2,621,442 vertices)."""
SPARSE_MIN = 0.5
"""Grid points (at least) per surfel for a map's sparsest-mapped surfels (see choose_level)."""
SPARSE_MAX_LEVEL = 8
"""Finest level the sampling condition of :func:`choose_level` raises a grid to (the surfel
count alone still reaches :data:`MAX_LEVEL`)."""

BUTTERFLY_WEIGHTS = np.array([0.5, 0.5, 0.125, 0.125, -0.0625, -0.0625, -0.0625, -0.0625])
"""(8,) float64: weights of the columns of :attr:`Icosphere.butterfly`."""
BUTTERFLY_WEIGHTS.flags.writeable = False


def vertex_count(level: int) -> int:
    """Number of vertices ``10·4^level + 2`` of the level-``level`` grid."""
    return 10 * 4 ** int(level) + 2


def level_of_count(n: int) -> int | None:
    """The grid level whose grid has ``n`` vertices (:func:`vertex_count`), or None when no
    level has."""
    level = 0
    while vertex_count(level) < n:
        level += 1
    return level if vertex_count(level) == n else None


def check_level(level, name: str = "level") -> int:
    """A grid level checked: an integer in ``[0, MAX_LEVEL]``.

    Parameters
    ----------
    level : int
        The level to check.
    name : str
        The argument's name in the error message.

    Returns
    -------
    int
        ``level`` as a Python int.

    Raises
    ------
    InputError
        When ``level`` is not an integer, negative or above :data:`MAX_LEVEL`.
    """
    lev = check_positive_int(level, name, minimum=0)
    if lev > MAX_LEVEL:
        raise InputError(f"{name} must be at most {MAX_LEVEL} (grid of {vertex_count(MAX_LEVEL)} "
                         f"vertices), got {lev}")
    return lev


def _icosahedron():
    t = (1 + 5 ** 0.5) / 2
    v = np.array([[-1, t, 0], [1, t, 0], [-1, -t, 0], [1, -t, 0], [0, -1, t], [0, 1, t],
                  [0, -1, -t], [0, 1, -t], [t, 0, -1], [t, 0, 1], [-t, 0, -1], [-t, 0, 1]],
                 dtype=np.float64)
    f = np.array([[0, 11, 5], [0, 5, 1], [0, 1, 7], [0, 7, 10], [0, 10, 11], [1, 5, 9],
                  [5, 11, 4], [11, 10, 2], [10, 7, 6], [7, 1, 8], [3, 9, 4], [3, 4, 2], [3, 2, 6],
                  [3, 6, 8], [3, 8, 9], [4, 9, 5], [2, 4, 11], [6, 2, 10], [8, 6, 7], [9, 8, 1]],
                 dtype=np.int64)
    v /= np.linalg.norm(v, axis=1)[:, None]
    return v, f


def _filled(shape, head, *cols) -> np.ndarray:
    """A new int64 array of ``shape``: ``head``'s rows (if any) on top, then the rows whose
    entries are ``cols`` in row-major order (``len(cols)`` a multiple of the row length). It is
    ``np.concatenate([head, np.stack(cols, 1).reshape(-1, shape[1])])`` without the stacked
    copies, which on a fine grid cost more in fresh pages than in copying."""
    out = np.empty(shape, dtype=np.int64)
    start = 0 if head is None else len(head)
    if head is not None:
        out[:start] = head
    body = out[start:].reshape(-1, len(cols))
    for k, col in enumerate(cols):
        body[:, k] = col
    return out


def _readonly(*arrays):
    for a in arrays:
        a.flags.writeable = False


class _HalfEdges:
    """Half-edge structure of a closed triangle mesh (the level's faces).

    Half-edge ``3f + p`` runs from ``faces[f, p]`` to ``faces[f, (p+1) % 3]``; ``opp`` is the third
    vertex of its face, ``twin`` the reversed half-edge, ``edge`` the index of its undirected edge
    in lexicographic ``(lo, hi)`` order.
    """

    def __init__(self, faces: np.ndarray, n_vertices: int, twin: np.ndarray):
        tail = faces.ravel()
        head = faces[:, [1, 2, 0]].ravel()
        self.tail, self.head = tail, head
        self.opp = faces[:, [2, 0, 1]].ravel()
        self.twin = twin
        # the half-edge of each edge that runs lo -> hi, edges in lexicographic (lo, hi) order
        forward = np.flatnonzero(tail < head)
        key = tail[forward] * np.int64(n_vertices) + head[forward]
        order = np.argsort(key)                  # keys are distinct: any sort gives this order
        self.forward = forward[order]
        self.edges = np.stack([tail[self.forward], head[self.forward]], axis=1)
        edge = np.empty(len(tail), dtype=np.int64)
        edge[self.forward] = np.arange(len(self.forward), dtype=np.int64)
        edge[self.twin[self.forward]] = edge[self.forward]
        self.edge = edge

    @staticmethod
    def nxt(h):
        return h - h % 3 + (h + 1) % 3

    @staticmethod
    def prv(h):
        return h - h % 3 + (h + 2) % 3


def twins_by_sorting(tail: np.ndarray, head: np.ndarray, n_vertices: int) -> np.ndarray:
    """The reversed half-edge of each half-edge of a closed 2-manifold, by sorting edge keys."""
    key = np.minimum(tail, head) * np.int64(n_vertices) + np.maximum(tail, head)
    order = np.argsort(key, kind="stable")
    sk = key[order]
    if len(sk) % 2 or not np.all(sk[0::2] == sk[1::2]) or np.any(sk[2::2] == sk[1:-1:2]):
        raise AssertionError("icosphere mesh is not a closed 2-manifold")  # pragma: no cover
    twin = np.empty(len(key), dtype=np.int64)
    twin[order[0::2]] = order[1::2]
    twin[order[1::2]] = order[0::2]
    return twin


def _subdivided_twins(coarse_twin: np.ndarray) -> np.ndarray:
    """The twins of the half-edges of a 4-to-1 subdivision (:meth:`Icosphere._subdivide`'s
    face order), from the coarse mesh's twins, without a sort.

    Coarse half-edge ``H = 3f + p`` (``x -> y``) is split into ``x -> mid``, position 0 of child
    ``4f + p``, and ``mid -> y``, position 2 of child ``4f + (p+1) % 3``; each half twins the
    other half of ``twin(H)``. Position 1 of children 0, 1, 2 twins positions 2, 0, 1 of the
    inner child ``4f + 3``."""
    n_half = len(coarse_twin)
    h = np.arange(n_half, dtype=np.int64)
    f, p = h // 3, h % 3

    def first(f, p):
        return 3 * (4 * f + p)

    def second(f, p):
        return 3 * (4 * f + (p + 1) % 3) + 2

    t = coarse_twin
    tf, tp = t // 3, t % 3
    twin = np.empty(4 * n_half, dtype=np.int64)
    twin[first(f, p)] = second(tf, tp)
    twin[second(f, p)] = first(tf, tp)
    inner = 3 * (4 * f + p) + 1
    inner_twin = 3 * (4 * f + 3) + (p + 2) % 3
    twin[inner] = inner_twin
    twin[inner_twin] = inner
    return twin


def _balanced_root_owners(edges: np.ndarray) -> np.ndarray:
    """Owner of each icosahedron edge, balanced: every root owns 2 or 3 edges.

    The 12 vertices all have odd valence 5; joined to a virtual 13th vertex they have valence 6 and
    the graph has an Euler circuit. Hierholzer's algorithm, started at vertex 0 and always taking
    the smallest unused neighbour, gives a circuit; each icosahedron edge is owned by the vertex the
    circuit leaves it from. Every vertex leaves 3 circuit edges, at most one of them virtual.
    """
    virtual = 12
    links = [(int(a), int(b)) for a, b in edges.tolist()] + [(v, virtual) for v in range(12)]
    adj: dict[int, list[tuple[int, int]]] = {v: [] for v in range(13)}
    for i, (a, b) in enumerate(links):
        adj[a].append((b, i))
        adj[b].append((a, i))
    for v in adj:
        adj[v].sort(reverse=True)  # pop() takes the smallest neighbour
    used = [False] * len(links)
    stack = [(0, -1)]  # (vertex, link used to arrive)
    circuit: list[tuple[int, int]] = []
    while stack:  # 42 links, once per process
        v, _ = stack[-1]
        while adj[v] and used[adj[v][-1][1]]:
            adj[v].pop()
        if adj[v]:
            w, i = adj[v].pop()
            used[i] = True
            stack.append((w, i))
        else:
            circuit.append(stack.pop())
    circuit.reverse()  # (vertex, arriving link) in travel order
    owner = np.empty(len(edges), dtype=np.int64)
    for (v, _), (_, i) in zip(circuit[:-1], circuit[1:]):
        if i < len(edges):
            owner[i] = v
    return owner


class Icosphere:
    """The level-``level`` icosahedral grid with its hierarchy tables (see the module docstring).

    Build it through :func:`icosphere`, which caches one instance per level; arrays are read-only.

    Parameters
    ----------
    level : int
        Subdivision level, 0 … :data:`MAX_LEVEL`.

    Attributes
    ----------
    level : int
        The grid level ``L``.
    vertices : (n, 3) float64
        Unit vectors, ``n = 10·4^L + 2``, coarse levels first.
    faces : (20·4^L, 3) int64
        Counter-clockwise triangles of level ``L``.
    counts : (L + 1,) int64
        ``counts[j] = 10·4^j + 2``: vertices of level ``j`` are ``vertices[:counts[j]]``.
    level_of : (n,) int64
        Birth level of each vertex.
    edge_parents : (n, 2) int64
        Endpoints ``a < b`` of the coarser edge each vertex splits (``-1`` at level 0).
    butterfly : (n, 8) int64
        Butterfly stencil ``(a, b, c, d, e1, e2, e3, e4)`` of each vertex in the level below it,
        weights :data:`BUTTERFLY_WEIGHTS` (``-1`` at level 0).
    tree_parent : (n,) int64
        Zerotree parent (``-1`` for the 12 roots).
    children_indptr : (n + 1,) int64
    children_indices : (n - 12,) int64
        Zerotree children of each vertex, CSR.
    """

    def __init__(self, level: int, *, _coarser: "Icosphere | None" = None):
        level = check_level(level)
        self.level = level
        if level == 0:
            v, f = _icosahedron()
            n = len(v)
            self.vertices, self.faces = v, f
            self.counts = np.array([n], dtype=np.int64)
            self.level_of = np.zeros(n, dtype=np.int64)
            self.edge_parents = np.full((n, 2), -1, dtype=np.int64)
            self.butterfly = np.full((n, 8), -1, dtype=np.int64)
            self.tree_parent = np.full(n, -1, dtype=np.int64)
        else:
            c = _coarser if _coarser is not None else icosphere(level - 1)
            self._subdivide(c)
        self._build_children()
        _readonly(self.vertices, self.faces, self.counts, self.level_of, self.edge_parents,
                  self.butterfly, self.tree_parent, self.children_indptr, self.children_indices)

    # ------------------------------------------------------------------ construction
    def _subdivide(self, c: "Icosphere") -> None:
        j = c.level  # the coarse level; new vertices are born at level j + 1
        n_old = len(c.vertices)
        he = c._half_edges
        edges = he.edges
        n_new = len(edges)
        a, b = edges[:, 0], edges[:, 1]
        mid = c.vertices[a] + c.vertices[b]
        mid /= np.linalg.norm(mid, axis=1)[:, None]
        self.vertices = np.concatenate([c.vertices, mid])
        # faces: children 4f .. 4f+3
        m = n_old + he.edge.reshape(-1, 3)  # midpoints of (a,b), (b,c), (c,a) per face
        fa, fb, fc = c.faces[:, 0], c.faces[:, 1], c.faces[:, 2]
        ab, bc, ca = m[:, 0], m[:, 1], m[:, 2]
        self.faces = _filled((4 * len(c.faces), 3), None, fa, ab, ca, fb, bc, ab, fc, ca, bc,
                             ab, bc, ca)
        self.counts = np.append(c.counts, len(self.vertices)).astype(np.int64)
        self.level_of = np.concatenate([c.level_of, np.full(n_new, j + 1, dtype=np.int64)])
        self.edge_parents = np.concatenate([c.edge_parents, edges])
        # butterfly stencil
        h1 = he.forward                      # a -> b
        h2 = he.twin[h1]                     # b -> a
        cc, dd = he.opp[h1], he.opp[h2]
        e1 = he.opp[he.twin[he.nxt(h1)]]     # across (b, c)
        e2 = he.opp[he.twin[he.prv(h1)]]     # across (c, a)
        e3 = he.opp[he.twin[he.nxt(h2)]]     # across (a, d)
        e4 = he.opp[he.twin[he.prv(h2)]]     # across (d, b)
        self.butterfly = _filled((n_old + n_new, 8), c.butterfly, a, b, cc, dd, e1, e2, e3, e4)
        # zerotree owners of the level-j edges
        if j == 0:
            owner = _balanced_root_owners(edges)
        else:
            new_a = c.level_of[a] == j
            new_b = c.level_of[b] == j
            owner = np.where(new_a, a, b)
            inner = new_a & new_b
            # the half-edges of inner faces (4f + 3): owner is their tail
            h_inner = (np.arange(len(c.faces), dtype=np.int64)[3::4, None] * 3
                       + np.arange(3)).ravel()
            owner_by_edge = np.full(n_new, -1, dtype=np.int64)
            owner_by_edge[he.edge[h_inner]] = he.tail[h_inner]
            owner = np.where(inner, owner_by_edge, owner)
            if np.any(owner < 0):  # pragma: no cover - construction invariant
                raise AssertionError("zerotree owner missing")
        self.tree_parent = np.concatenate([c.tree_parent, owner])

    def _build_children(self) -> None:
        n = len(self.vertices)
        parent = self.tree_parent
        kids = np.flatnonzero(parent >= 0).astype(np.int64)
        order = np.argsort(parent[kids], kind="stable")
        self.children_indices = kids[order]
        self.children_indptr = np.zeros(n + 1, dtype=np.int64)
        np.cumsum(np.bincount(parent[kids], minlength=n), out=self.children_indptr[1:])

    @functools.cached_property
    def _twins(self) -> np.ndarray:
        """(3·m,) int64: the reversed half-edge of each half-edge ``3f + p`` (see
        :class:`_HalfEdges`), from the coarser level's without a sort."""
        if self.level == 0:
            return twins_by_sorting(self.faces.ravel(), self.faces[:, [1, 2, 0]].ravel(),
                                    len(self.vertices))
        return _subdivided_twins(icosphere(self.level - 1)._twins)

    @functools.cached_property
    def _half_edges(self) -> _HalfEdges:
        return _HalfEdges(self.faces, len(self.vertices), self._twins)

    @functools.cached_property
    def face_neighbors(self) -> np.ndarray:
        """(20·4^L, 3) int64: the face across the edge opposite each corner of each face
        (``face_neighbors[f, j]`` shares the edge ``faces[f, j+1], faces[f, j+2]``, corners
        modulo 3), read only."""
        out = np.ascontiguousarray(self._twins.reshape(-1, 3)[:, [1, 2, 0]]) // 3
        _readonly(out)
        return out

    # ------------------------------------------------------------------ queries
    @property
    def n_vertices(self) -> int:
        """Number of grid vertices ``10·4^L + 2``."""
        return len(self.vertices)

    @property
    def edges(self) -> np.ndarray:
        """(30·4^L, 2) int64: the level-``L`` edges ``(lo, hi)`` in lexicographic order.

        Edge ``i`` is split by vertex ``counts[L] + i`` of level ``L + 1``.
        """
        e = self._half_edges.edges
        e.flags.writeable = False
        return e

    @functools.cached_property
    def _neighbors(self):
        # a closed 2-manifold: each ordered pair of neighbours is one directed edge of a face
        n = len(self.vertices)
        src = self.faces.ravel()
        dst = self.faces[:, [1, 2, 0]].ravel()
        indices = np.sort(src * np.int64(n) + dst) % n     # by source, then neighbour
        indptr = np.zeros(n + 1, dtype=np.int64)
        np.cumsum(np.bincount(src, minlength=n), out=indptr[1:])
        _readonly(indptr, indices)
        return indptr, indices

    @property
    def neighbor_indptr(self) -> np.ndarray:
        """(n + 1,) int64: CSR row pointers of the level-``L`` vertex adjacency."""
        return self._neighbors[0]

    @property
    def neighbor_indices(self) -> np.ndarray:
        """(2·30·4^L,) int64: CSR neighbour ids of the level-``L`` mesh, ascending per vertex."""
        return self._neighbors[1]

    def neighbors(self, level: int | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Vertex adjacency of the mesh of level ``level`` (default: the grid level) as CSR.

        Parameters
        ----------
        level : int, optional
            0 … ``self.level``.

        Returns
        -------
        indptr : (counts[level] + 1,) int64
        indices : (60·4^level,) int64
            Neighbours of ``v`` are ``indices[indptr[v]:indptr[v + 1]]`` (ascending).
        """
        lev = self.level if level is None else check_level(level)
        if lev > self.level:
            raise InputError(f"level must be at most the grid level {self.level}, got {lev}")
        return icosphere(lev)._neighbors

    def children(self, v: int) -> np.ndarray:
        """Zerotree children of vertex ``v``: (0 or 2..4,) int64, ascending."""
        return self.children_indices[self.children_indptr[v]:self.children_indptr[v + 1]]

    def vertex_areas(self) -> np.ndarray:
        """(n,) float64: a third of the spherical areas of the triangles at each vertex (sum 4π)."""
        return level_vertex_areas(self.level).copy()

    def to_trimesh(self) -> "trimesh.Trimesh":
        """The grid as a ``trimesh.Trimesh`` of the unit sphere (``process=False``: vertices
        and faces in grid order), each vertex's birth level in ``vertex_attributes["level"]``
        ((n,) uint8, a type glTF can hold).

        The grid's values on it, a decoded surface, come from :func:`surfidx.codec.decode`
        (``mesh=True``) as a :class:`~surfidx.TriangleMesh` with its own ``to_trimesh``.

        Returns
        -------
        trimesh.Trimesh
        """
        import trimesh

        return trimesh.Trimesh(np.array(self.vertices), np.array(self.faces),
                               vertex_attributes={"level": self.level_of.astype(np.uint8)},
                               metadata={"name": f"icosphere level {self.level}"}, process=False)

    def __repr__(self) -> str:
        return f"Icosphere(level={self.level}, vertices={self.n_vertices}, faces={len(self.faces)})"


@functools.lru_cache(maxsize=MAX_LEVEL + 1)
def icosphere(level: int) -> Icosphere:
    """The cached level-``level`` :class:`Icosphere` (built once per process, from the coarser one).

    Parameters
    ----------
    level : int
        0 … :data:`MAX_LEVEL`.

    Returns
    -------
    Icosphere

    Raises
    ------
    InputError
        If ``level`` is not an integer in 0 … :data:`MAX_LEVEL`.
    """
    lev = check_level(level)
    return Icosphere(lev, _coarser=icosphere(lev - 1) if lev else None)


@functools.lru_cache(maxsize=MAX_LEVEL + 1)
def level_vertex_areas(level: int) -> np.ndarray:
    """The spherical area of each vertex of the level-``level`` grid (a third of each incident
    triangle's), cached and read-only.

    Parameters
    ----------
    level : int
        A checked grid level (see :func:`check_level`).

    Returns
    -------
    ndarray of float64, shape (vertex_count(level),)
        The vertex areas; they sum to 4π.
    """
    from .mesh import vertex_area_shares     # scipy: not needed to count vertices
    from .unitsphere import triangle_areas

    ico = icosphere(level)
    area = np.abs(triangle_areas(ico.vertices, ico.faces))
    out = vertex_area_shares(ico.faces, area, len(ico.vertices))
    out.flags.writeable = False
    return out


def choose_level(n_surfels: int, *, oversampling: float = 4.0, sparse_sampling: float = 1.0,
                 max_level: int = MAX_LEVEL) -> int:
    """The grid level for a model of ``n_surfels`` surfels.

    Rule: the smallest ``L`` with ``N = 10·4^L + 2 ≥ oversampling · n_surfels`` and
    ``N · sparse_sampling ≥ SPARSE_MIN · n_surfels``, capped at ``max_level``; the second
    condition raises the level by one at most, and to :data:`SPARSE_MAX_LEVEL` at most.

    Why: the grid samples the smooth (Phong-lifted) surface between the surfels, so it needs
    several samples per surfel (the default ``oversampling=4`` gives 4–16); and it must still
    sample the parts the spherical map squeezes, so the second condition gives the 5 % of surfels
    the map squeezes most (``sparse_sampling`` from :func:`surfidx.sphere.sparse_sampling`, a
    map's ``SphericalMap.sparse_sampling``) at least ``SPARSE_MIN`` grid points each. That
    condition raises the level by one at most, on maps that squeeze parts of the surface hard;
    each level costs four times the grid, and the coder pays little for a finer grid at a given
    rate. It raises no grid beyond :data:`SPARSE_MAX_LEVEL`: level 9 (2.6 million points)
    makes every stage that works on the grid four times as long as level 8, whose grid already
    has 4 to 16 points per surfel of a model the count puts there, so one model's ingest
    would take several times the others' (``benchmarks/profile.py``).
    ``benchmarks/parameterization.py`` prints the sparse sampling and the chosen level of the
    benchmark models.

    Parameters
    ----------
    n_surfels : int
        Surfel count, ≥ 1.
    oversampling : float
        Minimum grid vertices per surfel, > 0.
    sparse_sampling : float
        The map's sampling of its sparsest-mapped surfels relative to an even map, in [0, 1]
        (default 1: no map known, only the count decides).
    max_level : int
        Cap, 0 … :data:`MAX_LEVEL`.

    Returns
    -------
    int

    Raises
    ------
    InputError
        On a non-positive count or oversampling, or a cap outside 0 … :data:`MAX_LEVEL`.
    """
    n = check_positive_int(n_surfels, "n_surfels")
    cap = check_level(max_level, "max_level")
    try:
        ov = float(oversampling)
    except (TypeError, ValueError):
        raise InputError(f"oversampling must be a positive number, got {oversampling!r}") from None
    if not (ov > 0 and np.isfinite(ov)):
        raise InputError(f"oversampling must be a positive finite number, got {oversampling!r}")
    sparse = float(sparse_sampling)
    if not (0.0 <= sparse <= 1.0 + 1e-9):   # 0: a map that squeezes some surfels to nothing
        raise InputError(f"sparse_sampling must lie in [0, 1], got {sparse_sampling!r}")
    count = next((lev for lev in range(cap + 1) if vertex_count(lev) >= ov * n), cap)
    # the sampling condition raises the level by one at most (each level costs 4x), and not
    # beyond SPARSE_MAX_LEVEL
    if count < min(cap, SPARSE_MAX_LEVEL) and vertex_count(count) * sparse < SPARSE_MIN * n:
        return count + 1
    return count
