"""The codec's side of topology repair: the virtual region on the grid, and dropping it again.

Encoder side: the grid vertices that sample a virtual patch (:func:`surfidx.codec.resample.grid_patches`)
become the mask of :mod:`.mask`; its connected regions (through grid edges, ordered by their
smallest grid vertex) each get a code (:func:`surfidx.codec.container.region_code`: a hole of the
input, or a side of a handle cut) in the container's region table. :func:`mask_regions` makes
each patch one region: a patch the grid misses gets the real grid vertex nearest one of its
surfels with no patch beside it, two patches on neighbouring grid vertices are moved apart (the
larger gives up its vertices beside the smaller), a patch the grid splits is joined along
shortest grid paths that pass beside no other patch, and patches that still meet (each on its
last grid vertices beside the other: two holes closer together than the grid's spacing) are
parted by moving the smaller to one real grid vertex with no patch beside it, the one nearest
its image on the sphere within 3 hops. The mask's regions are its connected pieces, so two
patches on neighbouring grid vertices would be one hole to the decoder whatever it does.
Last, the encoder runs the decoder's clean-up (below) on the mask, and where two regions
would still drop as one hole (crowded within two grid hops) it moves the smaller patch of
each such group to a vertex with no other patch within 2 hops, so that each patch with a grid
vertex decodes as its own hole or cut side wherever the grid has room for it.

Decoder side (:func:`restore`): the grid faces over each region are dropped as one clean disk, and
the two boundary loops of each cut are zipped together again, so that the decoded mesh has the
input's boundary loops and genus:

1. a face is dropped with a region when at least two of its corners are in it;
2. repeated until nothing changes: each region keeps only its largest edge-connected piece of
   faces (a region left without a face takes the star of its smallest vertex, or one face of it
   where the star would touch another region); pieces of the kept surface cut off from its
   largest piece join the region around them, except a piece that shares a vertex with the
   largest piece at which two regions meet (a band between two holes two grid hops apart: the
   next rule joins it again); a vertex where the kept surface is pinched (more
   than two of its boundary edges) gives its whole star to the region holding it, or back to the
   kept surface where two regions meet there (so two holes closer together than the grid's
   spacing decode as two);
3. the kept surface's boundary loops are assigned to regions by the dropped faces beside them;
   the loops of the two sides of cut ``k`` (one loop each) are matched by arc length at the best
   cyclic offset and the strip between them triangulated (one triangle per loop edge, advancing
   along whichever loop's next vertex comes first). The second loop is walked against its own
   boundary direction: the only direction in which the strip's faces are wound consistently with
   both sides (the surface stays orientable).

At a coarser output level the regions are those of the coarse grid's prefix of the mask, labelled
from the regions of the stream's level; a region with no coarse vertex takes the coarse ancestor
of its smallest vertex (first edge parents), so every hole and cut side survives.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
import scipy.sparse as sp

from ..errors import BitstreamError, InputError
from ..geometry.icosphere import icosphere, vertex_count
from ..jit import njit

__all__ = ["grid_regions", "mask_regions", "regions_at", "restore", "restored_vertices",
           "closed_surfels", "RestoredMesh", "check_regions", "zip_loops"]

_MAX_ROUNDS = 64   # clean-up rounds of the dropped regions (each round only grows them)


@lru_cache(maxsize=2)
def _grid_graph(level: int):
    """The grid's vertex adjacency (read only: callers derive new matrices from it)."""
    g = icosphere(level)
    n = g.n_vertices
    ptr, nb = np.array(g.neighbor_indptr), np.array(g.neighbor_indices)
    return sp.csr_matrix((np.ones(len(nb), np.int8), nb, ptr), shape=(n, n))


def grid_regions(bits, level: int) -> tuple[int, np.ndarray]:
    """Connected regions of the set grid vertices, numbered by their smallest vertex.

    Parameters
    ----------
    bits : (10·4^level + 2,) bool
    level : int

    Returns
    -------
    count : int
    region : (n,) int64
        Region of each grid vertex, -1 where the bit is not set.
    """
    lab = np.where(np.asarray(bits, dtype=bool), 0, -1).astype(np.int64)
    g = icosphere(level)
    count, region = _label_regions(lab, np.asarray(g.neighbor_indptr),
                                   np.asarray(g.neighbor_indices))
    return int(count), region


@njit(cache=True)
def _label_regions(lab, indptr, indices):
    """The connected pieces of the vertices of each label (``lab`` >= 0; -1: none) on an
    adjacency CSR (-1 entries: no neighbour), for :func:`grid_regions`, :func:`_components` and
    :func:`_split_patches`: a flood fill through neighbours of the same label from each
    unnumbered vertex in increasing order, so each piece is found from its smallest vertex and
    numbered in the order of those. Returns the count and each vertex's piece (-1: none)."""
    n = lab.shape[0]
    region = np.full(n, -1, np.int64)
    stack = np.empty(n, np.int64)
    count = 0
    for s in range(n):
        if lab[s] < 0 or region[s] >= 0:
            continue
        region[s] = count
        stack[0] = s
        top = 1
        while top > 0:
            top -= 1
            v = stack[top]
            for j in range(indptr[v], indptr[v + 1]):
                u = indices[j]
                if u >= 0 and lab[u] == lab[s] and region[u] < 0:
                    region[u] = count
                    stack[top] = u
                    top += 1
        count += 1
    return count, region


def mask_regions(patches, level: int, patch_cut, *, anchors=None, centres=None):
    """The mask bits and region table of the grid's patch labels.

    Each patch with a grid vertex (or an anchor) is one region of the mask, and one hole or
    cut side of :func:`restore`'s mesh, when the grid has room for it: patches that would meet
    on the grid or in the decoder's clean-up are parted (module docs); only where no free grid
    vertex lies within 3 hops of a patch's vertices do two patches stay one region or one hole.
    (A patch the grid splits and no fenced path joins stays several regions.)

    Parameters
    ----------
    patches : (n,) int
        Patch each grid vertex samples (-1 real; :func:`surfidx.codec.resample.grid_patches`).
    level : int
    patch_cut : (P,) int
        Cut of each patch (-1: a hole), as :attr:`surfidx.SurfelSet.patch_cut`.
    anchors : (P,) int, optional
        A grid vertex for each patch (-1: none), made virtual when the patch has no grid
        vertex (a patch smaller than the grid's spacing).
    centres : (P, 3) float64, optional
        Where each patch lies on the unit sphere (a row of NaN: unknown). A patch moved off
        another goes to the candidate vertex nearest its centre (default, and for an unknown
        centre: the candidate of smallest index).

    Returns
    -------
    bits : (n,) bool
    codes : tuple of int
        :func:`surfidx.codec.container.region_code` of each region (regions by smallest vertex).
    """
    from .container import region_code

    lab = np.array(patches, np.int64)
    cut = np.asarray(patch_cut, np.int64)
    P = len(cut)
    if anchors is not None:
        for p in range(P):
            a = int(anchors[p])
            if a >= 0 and not (lab == p).any():
                v = _place(lab, level, p, [a])
                if v >= 0:
                    lab[v] = p
                elif lab[a] < 0:    # no free vertex near: a itself
                    lab[a] = p
    _separate(lab, level, P)
    graph = None
    for p in _split_patches(lab, level):   # joined along shortest grid paths
        # through real vertices with no other patch beside them (weight 1 into each), so the
        # path keeps the patches apart; joining p changes no other patch's vertices
        fenced = _beside_others(lab, level, p)
        while True:
            on = lab == p
            count, region = grid_regions(on, level)
            if count <= 1:
                break
            from scipy.sparse.csgraph import dijkstra   # encoding only: not loaded to decode

            graph = _grid_graph(level) if graph is None else graph
            free = ((lab < 0) & ~fenced) | on
            # the grid's edges into free vertices, weight 1 (its own index arrays: the cached
            # graph's stay as they are)
            keep = free[graph.indices]
            kept = np.zeros(len(keep) + 1, graph.indptr.dtype)   # kept entries before each
            np.cumsum(keep, dtype=kept.dtype, out=kept[1:])
            indptr = kept[graph.indptr]
            w = sp.csr_matrix((np.ones(int(indptr[-1])), graph.indices[keep], indptr),
                              shape=graph.shape)
            src = np.flatnonzero(region == 0)
            dist, pred, _ = dijkstra(w, indices=src, min_only=True, return_predecessors=True)
            others = np.flatnonzero(region > 0)
            reach = others[np.isfinite(dist[others])]
            if not len(reach):
                break
            v = int(reach[np.argmin(dist[reach])])
            while v >= 0 and region[v] != 0:
                lab[v] = p
                v = int(pred[v])
    _part(lab, level, P, centres)
    _part_decoded(lab, level, P, centres)
    bits = lab >= 0
    count, region = grid_regions(bits, level)
    codes = []
    for r in range(count):
        ps = lab[region == r]
        p = int(np.bincount(ps).argmax())
        k = int(cut[p])
        if k < 0:
            codes.append(region_code(-1))
        else:   # side 0: the cut's patch of smaller index
            sides = np.flatnonzero(cut == k)
            s = int(p != sides[0])
            codes.append(region_code(k, s))
    return bits, tuple(codes)


def _separate(lab, level: int, P: int) -> None:
    """Keep different patches off neighbouring grid vertices, in place: of two neighbours in
    different patches, the vertex of the patch with more grid vertices (of equal counts, the
    higher index) becomes real, unless it is its patch's last one. Regions are the connected
    pieces of the mask, so two touching patches would be coded as one hole; a real vertex
    between them keeps them two (the decoder's clean-up keeps such a vertex real)."""
    g = _grid_graph(level).tocoo()
    u, v = g.row, g.col
    meet = (lab[u] >= 0) & (lab[v] >= 0) & (lab[u] != lab[v])
    if not meet.any():
        return
    size = np.bincount(lab[lab >= 0], minlength=P)
    u, v = u[meet], v[meet]
    pu, pv = lab[u], lab[v]
    bigger_u = (size[pu] > size[pv]) | ((size[pu] == size[pv]) & (pu > pv))
    drop, other = np.where(bigger_u, u, v), np.where(bigger_u, v, u)
    gone = np.unique(drop)
    left = size - np.bincount(lab[gone], minlength=P)
    flip = left[lab[drop]] <= 0     # the bigger patch would vanish: the smaller gives way
    drop[flip] = other[flip]
    gone = np.unique(drop)
    left = size - np.bincount(lab[gone], minlength=P)
    lab[gone[left[lab[gone]] > 0]] = -1     # both would vanish: they stay, and meet


def _place(lab, level: int, p: int, seeds, centre=None, gap: int = 1) -> int:
    """The grid vertex for patch ``p`` (on no grid vertex): of the real vertices with no other
    patch within ``gap`` grid hops, one fewest grid hops from ``seeds`` (within 3 hops), of
    those the one nearest ``centre`` on the sphere (no centre, or NaN: the smallest index); -1
    when there is none. ``lab`` is only read."""
    g = _grid_graph(level)
    taken = lab >= 0
    near = _beside_others(lab, level, p, gap)
    ring = np.unique(np.asarray(seeds, np.int64))
    seen = set(ring.tolist())
    for _ in range(4):
        ok = ring[~taken[ring] & ~near[ring]]
        if len(ok):
            if centre is None or not np.isfinite(centre).all():
                return int(ok.min())
            d = icosphere(level).vertices[ok] @ np.asarray(centre, np.float64)
            return int(ok[np.lexsort((ok, -d))[0]])
        nxt = np.unique(g[ring].indices)
        ring = np.array([x for x in nxt.tolist() if x not in seen], np.int64)
        seen.update(ring.tolist())
        if not len(ring):
            break
    return -1


def _part_decoded(lab, level: int, P: int, centres=None) -> None:
    """Part the patches whose regions the decoder would drop as one hole, in place.

    The decoder's clean-up (:func:`restore`) runs on the mask: regions whose dropped faces
    share a boundary loop of the kept surface, or a region left with no loop of its own,
    would decode as fewer holes than the mask has regions (small regions crowded within two
    grid hops of each other). Of each such group of regions, the patch with the fewest grid
    vertices (of equal counts, the higher index) that has not moved yet goes to the vertex
    :func:`_place` finds from its vertices with no other patch within 2 grid hops, so that no
    face of the grid touches it and another patch. Then the decoder's clean-up runs again;
    each patch moves at most once, so this ends, with the decoded holes the regions or no
    patch left to move.
    """
    faces, nbr, _ = _grid_faces(level)
    moved = np.zeros(P, bool)
    while True:
        count, region = grid_regions(lab >= 0, level)
        if count < 2:
            return
        label = _clean(level, region, count)
        root = np.arange(count)         # regions sharing a loop: union-find

        def find(r):
            while root[r] != r:
                root[r] = root[root[r]]
                r = root[r]
            return r

        own = np.zeros(count, bool)
        for _, labs in _boundary_loops(faces, nbr, label):
            rs = np.unique(labs[labs >= 0])
            if len(rs) == 1:
                own[rs[0]] = True
            for r in rs[1:]:
                root[find(r)] = find(rs[0])
        group = np.array([find(r) for r in range(count)])
        bad = (np.bincount(group, minlength=count)[group] > 1) | ~own
        if not bad.any():
            return
        on = np.flatnonzero(lab >= 0)
        size = np.bincount(lab[on], minlength=P)
        patch_of = np.zeros(count, np.int64)    # each region's patch (its most frequent)
        for r in np.flatnonzero(bad):
            patch_of[r] = np.bincount(lab[region == r]).argmax()
        chosen = []
        for gid in np.unique(group[bad]):       # groups in order of their smallest region
            ps = np.unique(patch_of[bad & (group == gid)])
            ps = ps[~moved[ps]]
            if len(ps):
                chosen.append(int(ps[np.lexsort((-ps, size[ps]))[0]]))
        if not chosen:
            return
        for p in chosen:
            moved[p] = True
            _move(lab, level, p, None if centres is None else centres[p], gap=2)


def _part(lab, level: int, P: int, centres=None) -> None:
    """Part the patches that still share a region of the mask, in place.

    While a connected piece of the mask holds more than one patch, the patch of that piece
    with the fewest grid vertices (of equal counts, the higher index) that has not moved yet
    leaves its vertices for the one :func:`_place` finds from them (nearest its centre): a
    real vertex with no patch beside it, so the move joins nothing. A patch with no such
    vertex within 3 hops keeps its vertices. Each patch moves at most once, so this ends.
    """
    moved = np.zeros(P, bool)
    while True:
        count, region = grid_regions(lab >= 0, level)
        on = np.flatnonzero(lab >= 0)
        # the distinct (region, patch) pairs in lexicographic order: one integer key each
        key = np.unique(region[on] * np.int64(P) + lab[on])
        pairs = np.stack([key // P, key % P], axis=1)
        shared = np.flatnonzero(np.bincount(pairs[:, 0], minlength=count) > 1) \
            if len(pairs) else np.zeros(0, np.int64)
        size = np.bincount(lab[on], minlength=P)
        for r in shared:            # the pieces in order of their smallest vertex
            ps = pairs[pairs[:, 0] == r, 1]
            ps = ps[~moved[ps]]
            if len(ps):
                break
        else:
            return
        p = int(ps[np.lexsort((-ps, size[ps]))[0]])
        moved[p] = True
        _move(lab, level, p, None if centres is None else centres[p], gap=1)


def _move(lab, level: int, p: int, centre, gap: int) -> None:
    """Patch ``p`` leaves its grid vertices for the one :func:`_place` finds from them, in
    place; it keeps them when there is none."""
    old = np.flatnonzero(lab == p)
    lab[old] = -1
    v = _place(lab, level, p, old, centre, gap=gap)
    lab[old if v < 0 else [v]] = p


def _beside_others(lab, level: int, p: int, hops: int = 1) -> np.ndarray:
    """(n,) bool: grid vertices reached from a vertex of a patch other than ``p`` by 1 to
    ``hops`` grid edges (``hops = 1``: a neighbour in another patch)."""
    g = _grid_graph(level)
    other = (lab >= 0) & (lab != p)
    near = (g @ other.astype(np.int8)) > 0
    for _ in range(hops - 1):
        near = ((g @ (near | other).astype(np.int8)) > 0) | near
    return near


def _split_patches(lab, level: int) -> np.ndarray:
    """Patches whose grid vertices form more than one component (through edges of the grid
    whose two ends sample the same patch), in increasing order."""
    lab = np.ascontiguousarray(lab, dtype=np.int64)
    if not (lab >= 0).any():
        return np.zeros(0, np.int64)
    g = icosphere(level)
    _, piece = _label_regions(lab, np.asarray(g.neighbor_indptr), np.asarray(g.neighbor_indices))
    first = np.unique(piece[piece >= 0], return_index=True)[1]
    pieces = np.bincount(lab[piece >= 0][first], minlength=int(lab.max()) + 1)
    return np.flatnonzero(pieces > 1)


def check_regions(codes, count: int, *, path=None) -> None:
    """Refuse a region table that does not fit the decoded mask (:class:`BitstreamError`)."""
    from .container import region_cut

    if len(codes) != count:
        raise BitstreamError(f"bad region table: it lists {len(codes)} regions, the decoded "
                             f"virtual-region mask has {count}; the file is damaged", path=path)
    for c in codes:
        k, _ = region_cut(c)
        if k >= len(codes):
            raise BitstreamError(f"bad region table: region code {c} names cut {k} in a table "
                                 f"of {len(codes)} regions; the file is damaged", path=path)


def regions_at(region, codes, level: int, out_level: int):
    """The regions of the level-``out_level`` prefix of a level-``level`` mask.

    Parameters
    ----------
    region : (10·4^level + 2,) int64
        :func:`grid_regions` of the stream's mask.
    codes : sequence of int
        Code of each region.
    level, out_level : int

    Returns
    -------
    region : (10·4^out_level + 2,) int64
    codes : tuple of int
    """
    if out_level == level:
        return region, tuple(codes)
    n_out = vertex_count(out_level)
    fine = icosphere(level)
    parents = np.asarray(fine.edge_parents)
    lab = np.array(region[:n_out], np.int64)
    for r in range(len(codes)):
        if (lab == r).any():
            continue
        v = int(np.flatnonzero(region == r).min())
        while v >= n_out:
            v = int(parents[v, 0])
        if lab[v] < 0:
            lab[v] = r
    count, coarse = grid_regions(lab >= 0, out_level)
    out = []
    for c in range(count):
        out.append(codes[int(lab[coarse == c].min())])
    return coarse, tuple(out)


# --------------------------------------------------------------------------- decoder side
def _face_adjacency(faces, n):
    """Across each face edge (corner j's opposite edge): the neighbouring face (-1: none)."""
    m = len(faces)
    a = np.concatenate([faces[:, 1], faces[:, 2], faces[:, 0]]).astype(np.int64)
    b = np.concatenate([faces[:, 2], faces[:, 0], faces[:, 1]]).astype(np.int64)
    key, twin = a * n + b, b * n + a
    order = np.argsort(key)
    pos = np.minimum(np.searchsorted(key[order], twin), len(key) - 1)
    ok = key[order][pos] == twin
    nbr = np.full(3 * m, -1, np.int64)
    nbr[ok] = order[pos[ok]] % m
    return nbr.reshape(3, m).T


def _components(mask, nbr):
    """Edge-connected components of the faces in ``mask``: labels (-1 outside) and count,
    numbered in the order of each component's smallest face."""
    nbr = np.ascontiguousarray(nbr, dtype=np.int64)
    indptr = np.arange(0, nbr.size + 1, max(nbr.shape[1], 1), dtype=np.int64)
    on = np.where(np.asarray(mask, dtype=bool), 0, -1).astype(np.int64)
    count, lab = _label_regions(on, indptr, nbr.ravel())
    return lab, int(count)


def _largest(lab, count):
    sizes = np.bincount(lab[lab >= 0], minlength=count)
    return int(np.argmax(sizes))   # ties: the component of the smallest face (labels in order)


def _face_regions(faces, region):
    r = region[faces]
    out = np.full(len(faces), -1, np.int64)
    for i, j in ((0, 1), (0, 2), (1, 2)):
        same = (r[:, i] == r[:, j]) & (r[:, i] >= 0) & (out < 0)
        out[same] = r[same, i]
    many = ((r >= 0).sum(axis=1) >= 2) & (out < 0)     # corners in different regions
    out[many] = np.where(r[many] >= 0, r[many], np.iinfo(np.int64).max).min(axis=1)
    return out


@lru_cache(maxsize=2)
def _grid_faces(level: int):
    """The grid's faces, their adjacency (:attr:`Icosphere.face_neighbors`, as
    :func:`_face_adjacency` finds it) and each vertex's faces
    (a vertex-by-face CSR matrix); read only."""
    g = icosphere(level)
    faces = np.asarray(g.faces, np.int64)
    n = g.n_vertices
    rows = np.repeat(np.arange(len(faces)), 3)
    star = sp.csr_matrix((np.ones(3 * len(faces), bool), (faces.ravel(), rows)),
                         shape=(n, len(faces)))
    return faces, g.face_neighbors, star


def _clean(level, region, n_regions):
    """Per-face region (-1 kept) after the clean-up rounds of the module docs."""
    faces, nbr, star = _grid_faces(level)
    n = star.shape[0]
    label = _face_regions(faces, region)
    first_vertex = np.full(n_regions, n, np.int64)
    on = region >= 0
    np.minimum.at(first_vertex, region[on], np.flatnonzero(on))
    for _ in range(_MAX_ROUNDS):
        before = label.copy()
        for r in range(n_regions):
            mine = label == r
            if mine.any():
                lab, count = _components(mine, nbr)
                if count > 1:
                    big = _largest(lab, count)
                    label[mine & (lab != big)] = -1
            else:
                s = star[first_vertex[r]].indices
                s = s[label[s] < 0]
                # beside another region, the whole star would make one hole of the two: one
                # face of it that touches no other region (by a corner) is the hole then
                corner = faces[s]
                u = np.unique(corner)
                busy = np.asarray(star[u] @ (label >= 0).astype(np.int8)).ravel() > 0
                busy |= on[u] & (region[u] != r)
                clash = busy[np.searchsorted(u, corner)].any(axis=1)
                if clash.any() and not clash.all():
                    s = s[~clash][:1]
                label[s] = r
        kept = label < 0
        lab, count = _components(kept, nbr)
        if count > 1:
            big = _largest(lab, count)
            on_big = np.zeros(n, bool)
            on_big[faces[lab == big].ravel()] = True
            for c in range(count):
                if c == big:
                    continue
                isl = np.flatnonzero(lab == c)
                around = label[nbr[isl].ravel()]
                around = around[around >= 0]
                if len(around) and not _bridge(faces[isl], on_big, star, label):
                    label[isl] = np.bincount(around).argmax()
        # pinched vertices of the kept surface: more than two boundary edges
        kept = label < 0
        kf = np.flatnonzero(kept)
        edge_free = (nbr[kf] < 0) | ~kept[np.maximum(nbr[kf], 0)]
        # boundary edge opposite corner j: vertices (j+1, j+2); each end counts once
        bf, bj = np.nonzero(edge_free)
        bf = kf[bf]
        deg = np.bincount(faces[bf, (bj + 1) % 3], minlength=n) \
            + np.bincount(faces[bf, (bj + 2) % 3], minlength=n)
        for v in np.flatnonzero(deg > 2):
            s = star[v].indices
            held = label[s][label[s] >= 0]
            if len(np.unique(held)) > 1:
                label[s] = -1      # two regions meet: their faces at v stay, keeping them apart
            elif len(held):
                label[s] = held[0]
        if np.array_equal(before, label):
            break
    return label


def _bridge(corners, on_big, star, label) -> bool:
    """Whether a piece of the kept surface (its faces' ``corners``) cut off from the largest
    piece shares a vertex with it at which two regions meet: the pinch step then gives that
    vertex's star back to the kept surface, which joins the piece again and keeps the two
    regions apart (a band of faces between two holes two grid hops apart)."""
    shared = np.unique(corners)
    for v in shared[on_big[shared]]:
        held = label[star[v].indices]
        if len(np.unique(held[held >= 0])) > 1:
            return True
    return False


def _boundary_loops(faces, nbr, label):
    """Directed boundary loops of the kept faces (``label < 0``) of a grid without pinches:
    vertex lists following the faces' winding, and each loop's edges' dropped neighbours'
    labels."""
    n = int(faces.max()) + 1
    kf = np.flatnonzero(label < 0)
    across = nbr[kf]
    free = label[across] >= 0
    f_idx, corner = np.nonzero(free)
    u = faces[kf[f_idx], (corner + 1) % 3]
    v = faces[kf[f_idx], (corner + 2) % 3]
    lab = label[across[f_idx, corner]]
    nxt = np.full(n, -1, np.int64)
    nxt[u] = v
    elab = np.full(n, -1, np.int64)
    elab[u] = lab
    seen = np.zeros(n, bool)
    loops = []
    for start in u:
        if seen[start]:
            continue
        loop = []
        w = int(start)
        while w >= 0 and not seen[w]:
            seen[w] = True
            loop.append(w)
            w = int(nxt[w])
        loop = np.array(loop, np.int64)
        loops.append((loop, elab[loop]))
    return loops


def _edge_keys(faces, n):
    """Distinct undirected edge keys ``min·n + max`` of ``faces``."""
    e = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]).astype(np.int64)
    return np.unique(np.minimum(e[:, 0], e[:, 1]) * n + np.maximum(e[:, 0], e[:, 1]))


def _loop_keys(loop, n):
    nxt = np.roll(loop, -1)
    return np.minimum(loop, nxt) * n + np.maximum(loop, nxt)


def _arc(P):
    seg = np.linalg.norm(np.roll(P, -1, axis=0) - P, axis=1)
    total = seg.sum()
    s = np.concatenate([[0.0], np.cumsum(seg)[:-1]])
    return (s / total if total > 0 else np.arange(len(P)) / len(P)), total


def zip_loops(positions, a, b, *, samples: int = 64):
    """Triangles joining loop ``a`` (in its boundary direction) to loop ``b`` (its boundary
    direction too; walked backwards), matched by arc length at the best cyclic offset.

    Parameters
    ----------
    positions : (n, 3) float64
    a, b : (m,) and (k,) int64
        Vertex loops as the faces' winding gives them (:func:`_boundary_loops`).
    samples : int
        Arc-length samples the offset is chosen on.

    Returns
    -------
    (m + k, 3) int64
    """
    b = b[::-1]
    sa, _ = _arc(positions[a])
    sb, _ = _arc(positions[b])
    u = (np.arange(samples) + 0.5) / samples
    A = np.stack([np.interp(u, sa, positions[a][:, d], period=1.0) for d in range(3)], axis=1)
    # B sampled from each possible start vertex j: parameter sb[j] + u
    t = (sb[None, :] + u[:, None]) % 1.0
    cost = np.zeros(len(b))
    for d in range(3):
        Bd = np.interp(t.ravel(), sb, positions[b][:, d], period=1.0).reshape(t.shape)
        cost += ((Bd - A[:, d][:, None]) ** 2).sum(axis=0)
    j0 = int(np.argmin(cost))
    b = np.roll(b, -j0)
    tb = (sb - sb[j0]) % 1.0
    tb = np.roll(tb, -j0)
    m, k = len(a), len(b)
    out = []
    i = j = 0
    while i < m or j < k:
        na = sa[i + 1] if i + 1 < m else 1.0
        nb = tb[j + 1] if j + 1 < k else 1.0
        if j == k or (i < m and na <= nb):
            out.append((a[(i + 1) % m], a[i], b[j % k]))
            i += 1
        else:
            out.append((b[j], b[(j + 1) % k], a[i % m]))
            j += 1
    return np.array(out, np.int64)


class RestoredMesh:
    """The real surface of a decoded grid.

    Attributes
    ----------
    vertices : (v,) int64
        The grid vertices it keeps (indices into the grid).
    faces : (f, 3) int64
        Its faces, indexing ``vertices`` (kept grid faces, then the cuts' strips).
    zipped : int
        Cuts whose two loops were zipped together.
    unzipped : int
        Cuts that could not be (not one loop on each side); they stay two holes.
    grid_faces : (f,) int64
        The grid face (of the level's icosphere, corners in its order) each kept face is;
        -1 for a strip's faces.
    """

    def __init__(self, vertices, faces, zipped, unzipped, grid_faces):
        self.vertices, self.faces, self.zipped, self.unzipped = vertices, faces, zipped, unzipped
        self.grid_faces = grid_faces


def restore(positions, level: int, region, codes) -> RestoredMesh:
    """Drop the virtual regions of a decoded grid surface and zip the cuts (module docs).

    Parameters
    ----------
    positions : (10·4^level + 2, 3) float64
        Decoded grid positions.
    level : int
    region : (n,) int64
        Region of each grid vertex (-1 real): :func:`regions_at`.
    codes : sequence of int
        Region codes (:func:`surfidx.codec.container.region_code`).

    Returns
    -------
    RestoredMesh
    """
    from .container import region_cut

    faces, nbr, star = _grid_faces(level)
    n = star.shape[0]
    label = _clean(level, np.asarray(region, np.int64), len(codes))
    kept = faces[label < 0]
    strips = []
    zipped = unzipped = 0
    if len(kept):
        by_side = {}
        for lp, labs in _boundary_loops(faces, nbr, label):
            labs = labs[labs >= 0]
            if not len(labs):
                continue
            r = int(np.bincount(labs).argmax())
            k, s = region_cut(codes[r])
            if k >= 0:
                by_side.setdefault(k, {}).setdefault(s, []).append(lp)
        taken = np.zeros(n, bool)
        strip_keys = np.zeros(0, np.int64)
        for k in sorted(by_side):
            sides = by_side[k]
            ok = len(sides.get(0, ())) == 1 and len(sides.get(1, ())) == 1
            if ok:
                a, b = sides[0][0], sides[1][0]
                ok = not (taken[a].any() or taken[b].any() or np.intersect1d(a, b).size)
            if ok:
                strip = zip_loops(positions, a, b)
                # a strip edge the kept mesh (or an earlier strip) has already, e.g. across a
                # band one face wide between the loops, would be an edge of three faces: the
                # cut stays open instead. Only kept faces at the loops' vertices can hold one.
                near = np.unique(star[np.concatenate([a, b])].indices)
                near = near[label[near] < 0]
                inner = _edge_keys(strip, n)
                inner = np.setdiff1d(inner, np.concatenate([_loop_keys(a, n),
                                                            _loop_keys(b, n)]))
                have = np.concatenate([_edge_keys(faces[near], n), strip_keys])
                ok = not np.isin(inner, have).any()
            if ok:
                strips.append(strip)
                strip_keys = np.concatenate([strip_keys, inner])
                taken[a] = taken[b] = True
                zipped += 1
            else:
                unzipped += 1
        missing = {region_cut(c)[0] for c in codes if region_cut(c)[0] >= 0} - set(by_side)
        unzipped += len(missing)
    allf = np.vstack([kept] + strips) if strips else kept
    used = _used_vertices(allf, n)
    remap = np.full(n, -1, np.int64)
    remap[used] = np.arange(len(used))
    grid_faces = np.concatenate([np.flatnonzero(label < 0), np.full(len(allf) - len(kept), -1,
                                                                    np.int64)])
    return RestoredMesh(used, remap[allf], zipped, unzipped, grid_faces)


def restored_vertices(level: int, region, n_regions: int) -> np.ndarray:
    """The grid vertices :func:`restore` keeps (its ``vertices``), without decoded positions:
    those of the faces kept, since each zipped strip joins two boundary loops of kept faces and
    adds no vertex. They depend on the regions only, so a caller that restores many decodings
    of one stream (:func:`surfidx.codec.encoder.level_hints`) finds them once.

    Parameters
    ----------
    level : int
    region : (10·4^level + 2,) int64
        Region of each grid vertex (-1 real): :func:`regions_at`.
    n_regions : int
        Number of regions (the region table's length).

    Returns
    -------
    (k,) int64
        Sorted grid vertex indices.
    """
    faces, _, star = _grid_faces(level)
    label = _clean(level, np.asarray(region, np.int64), int(n_regions))
    return _used_vertices(faces[label < 0], star.shape[0])


def _used_vertices(faces, n: int) -> np.ndarray:
    """The sorted distinct vertices of ``faces`` (over ``n`` vertices), as ``np.unique`` gives
    them, by marking instead of sorting."""
    mark = np.zeros(n, bool)
    mark[faces.ravel()] = True
    return np.flatnonzero(mark)


# --------------------------------------------------------------------------- closed surfaces
def closed_surfels(closed, *, colors=None, name=None):
    """The surfels of a :class:`surfidx.topology.ClosedSurface`, with its patches, for the codec.

    One surfel per used vertex, in order (:meth:`surfidx.TriangleMesh.to_surfels` without
    bisection): the
    virtual vertices carry the patch of a virtual face around them, and ``patch_cut`` names the
    cut each patch closes (:func:`surfidx.topology.patch_cuts`).

    Parameters
    ----------
    closed : ClosedSurface
    colors : (k, 3) uint8, optional
        Colours of the piece's input vertices (those given to ``close_surface``): copies take
        their original's, virtual vertices the nearest scan vertex's.
    name : str, optional

    Returns
    -------
    surfels : SurfelSet
    face_patch : (m,) int64
        Patch of each of ``surfels.faces`` (for :class:`surfidx.codec.Encoder`'s
        ``face_patch``), -1 for the scan's faces.

    """
    import warnings

    from ..geometry.mesh import TriangleMesh
    from ..geometry.surfels import SurfelSet
    from ..topology.patches import patch_cuts

    V, F = closed.vertices, closed.faces
    if colors is not None:
        from scipy.spatial import cKDTree

        origin = np.asarray(closed.vertex_origin)
        real = np.flatnonzero(origin >= 0)
        col = np.zeros((len(V), 3), np.uint8)
        col[real] = np.asarray(colors)[origin[real]]
        virt = np.flatnonzero(origin < 0)
        if len(virt):
            _, near = cKDTree(V[real]).query(V[virt])
            col[virt] = col[real[near]]
        colors = col
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        s = TriangleMesh(V, F, vertex_colors=colors, name=name).to_surfels(max_edge_ratio=None)
    used = np.unique(F)          # the surfels are the used vertices, in order
    n = len(V)
    fp = np.asarray(closed.patch, np.int64)
    vpatch = np.full(n, -1, np.int64)
    virt = np.flatnonzero(fp >= 0)
    for j in range(3):
        vpatch[F[virt, j]] = np.maximum(vpatch[F[virt, j]], fp[virt])
    vpatch[~closed.virtual_vertices] = -1
    P = int(fp.max()) + 1 if len(virt) else 0
    patch_cut = patch_cuts(closed)
    vpatch = vpatch[used]
    # the surfels' faces are the mesh's non-degenerate ones: match them by corners
    sf = s.faces
    remap = np.full(n, -1, np.int64)
    remap[used] = np.arange(len(used))
    F = remap[F]
    n = len(used)
    key_all = np.sort(F, axis=1) @ np.array([n * n, n, 1], np.int64)
    key_s = np.sort(sf, axis=1) @ np.array([n * n, n, 1], np.int64)
    order = np.argsort(key_all)
    pos = np.minimum(np.searchsorted(key_all[order], key_s), len(F) - 1)
    face_patch = np.where(key_all[order][pos] == key_s, fp[order][pos], -1)
    # a patch without virtual vertex (a tiny hole's) is known by face_patch only
    vp, pc = (None, None) if P == 0 else (vpatch, patch_cut)
    out = SurfelSet(s.positions, s.normals, s.radii, s.colors, faces=sf, name=name,
                    patch=vp, patch_cut=pc)
    return out, face_patch

