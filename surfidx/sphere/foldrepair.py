"""Local repair of folded Delaunay triangles of a fold-free spherical mesh embedding.

An area-balanced map of a limb is anisotropic (about ``2π · length / girth``): along the compressed
direction the mapped vertices lie in dense rows far apart, joined by long thin mesh triangles. The
spherical Delaunay triangulation of the mapped points then picks triangles between consecutive
points of a row. In 3D such a triple lies on a straight mesh line (its largest angle is 160–180°),
so where the row has a kink on the sphere the triple's orientation there disagrees with the one in
3D: a folded triangle, although no mesh triangle is inverted. Balancing does not remove these kinks:
a vertex moved across its row barely changes the energy of its long thin triangles.

The repair moves single vertices of folded triangles: across the great circle through the other
two corners, so that the triple takes the orientation it has in 3D (or stops being a Delaunay
triangle), first the corner with the largest 3D angle (the middle of a near-collinear triple),
then the other two, each with a small and a large margin past the circle; then each corner to, or
halfway to, the centroid of its mesh neighbours on the sphere. Each round gives every folded
triangle the next move it has not had. A move that would invert a mesh triangle on the sphere is
halved, up to three times, and then undone; the moves of a round are grouped into clusters (moved
vertices and two rings around them) and a cluster's moves are kept only when the cluster ends with
fewer folded triangles than it had. So the mesh stays fold-free and the count of folded Delaunay
triangles never grows.

What remains lies across sharp creases and thin sheets (the three surfel normals disagree) and in
the densest limb rows.

When the rounds leave at most ``search_folds`` folded triangles, a seeded random search follows
(:func:`random_search`): single moves of a corner or of a corner's mesh neighbour, in random directions
by up to a mesh-edge length, the first that lowers the count kept. It reaches folds across
creases that no move of the triangle's own corners mends. Its evaluations are one budget,
``search_work / n`` in all, shared by the folds, so the search costs about the same at any size.

Each round re-triangulates only the cavity of the moved vertices (:class:`Hull`); one global
convex hull is computed at the start and one at the end.
"""

from __future__ import annotations

from ..jit import numba
import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

from ..errors import InputError
from ..geometry.unitsphere import against_normals, folded_mask, hull_triangles, mirrored
from ..geometry.unitsphere import orientation
from .options import DEFAULT_OPTIONS, MapOptions

__all__ = ["repair_folds"]

#: Moves tried in turn on each folded triangle: (corner, margin). Corner 0 is the one with the
#: largest 3D angle, 1 and 2 the next ones around the triangle. A margin ≥ 0 moves the corner to
#: ``margin`` times its distance from the great circle through the other two, on the other side; a
#: margin < 0 moves it the share ``-margin`` of the way to the centroid of its mesh neighbours.
_MOVES = ((0, 0.2), (0, 1.0), (1, 0.2), (2, 0.2), (0, 0.05), (1, 1.0), (2, 1.0),
          (0, -1.0), (1, -1.0), (2, -1.0), (0, -0.5), (1, -0.5), (2, -0.5))
_CLUSTER_RINGS = 2   # rings of vertices around the moved ones that a cluster's folds are counted on
_FEW_MOVED = 8       # Hull.moved tests circumcircles directly against this many moved vertices
_HALVINGS = 3        # a move that inverts a mesh triangle is halved this often, then undone
_ON_CIRCLE = 1e-10   # a circumcircle holds a point nearer its centre than (1 - this) its radius
_SEARCH_MIN = 10     # the random search evaluates at least this many moves per fold
_SEARCH_STEP = (0.05, 1.0)   # ... each by this range of shares of a mesh-edge length


def _unit(v):
    return v / np.linalg.norm(v, axis=1)[:, None]


def _largest_angle_corner(p, t):
    """Index 0–2 of each triangle's corner with the largest 3D angle."""
    cos = np.empty((len(t), 3))
    for k in range(3):
        u = _unit(p[t[:, (k + 1) % 3]] - p[t[:, k]])
        v = _unit(p[t[:, (k + 2) % 3]] - p[t[:, k]])
        cos[:, k] = np.einsum("ij,ij->i", u, v)
    return np.nan_to_num(cos, nan=1.0).argmin(axis=1)


class Mesh:
    """Adjacency of the mesh, built once."""

    def __init__(self, f, n):
        e = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
        a = sp.csr_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(n, n))
        self.adj = ((a + a.T) > 0).astype(np.int8).tocsr()
        self.vf = sp.csr_matrix((np.ones(3 * len(f), np.int8),
                                 (f.ravel(), np.repeat(np.arange(len(f)), 3))),
                                shape=(n, len(f))).tocsr()
        self.f, self.n = f, n

    def grow(self, mask, rings):
        for _ in range(rings):
            mask = mask | (self.adj @ mask.astype(np.int8) > 0)
        return mask

    def undo_inverting(self, x, y, moved, *, halvings: int = _HALVINGS):
        """Shorten (in ``y``) each move of a vertex of a mesh triangle that ``y`` inverts: halve
        it up to ``halvings`` times, then put the vertex back; returns the vertices still moved."""
        step = np.zeros(len(x), np.int64)
        while moved.any():
            faces = np.unique(self.vf[np.flatnonzero(moved)].indices)
            inv = faces[orientation(y, self.f[faces]) <= 0]
            back = np.unique(self.f[inv].ravel())
            back = back[moved[back]]
            if not len(back):
                break
            step[back] += 1
            half = back[step[back] <= halvings]
            y[half] = _unit(x[half] + y[half])
            gone = back[step[back] > halvings]
            y[gone] = x[gone]
            moved[gone] = False
        return moved


class Hull:
    """The spherical Delaunay triangulation of the current map and its folded triangles, updated
    locally when a few vertices move.

    Moving vertices removes the triangles they are corners of and those whose circumcircle now
    holds one of them; the cavity is re-triangulated from the hull of its corners and the moved
    vertices, keeping the triangles whose circumcircle holds no point of the whole map. A result
    that is not a triangulation of the sphere (``2n - 4`` triangles; cocircular ties) is replaced
    by the global hull.
    """

    def __init__(self, x, p, normals):
        self.p, self.normals = p, normals
        self.n = len(x)
        tri = hull_triangles(x)
        bad = against_normals(p, normals, tri)
        self.mirror = mirrored(bad)
        self.tri, self.bad = tri, bad ^ self.mirror
        self._of = None          # (x, tri) the cached figures below belong to
        self._caps = self._tree = self._keys = self._centres = None

    def _folded(self, t):
        return against_normals(self.p, self.normals, t) ^ self.mirror

    def moved(self, x, y, moved):
        """(triangles, folded mask) of ``y``, which differs from ``x`` (this triangulation's map)
        at the vertices ``moved``."""
        gone, local = self._cavity(x, y, moved)
        if local is None:
            return self._global(y)
        return (np.concatenate([self.tri[~gone], local]),
                np.concatenate([self.bad[~gone], self._folded(local)]))

    def folds_if_moved(self, x, y, moved) -> int:
        """``moved(x, y, moved)[1].sum()``, the count alone: the new triangulation is not
        assembled (the random search asks this of thousands of moves and keeps one)."""
        gone, local = self._cavity(x, y, moved)
        if local is None:
            return int(self._global(y)[1].sum())
        return int(np.count_nonzero(self.bad) - np.count_nonzero(self.bad[gone])
                   + np.count_nonzero(self._folded(local)))

    def _cavity(self, x, y, moved):
        """The triangles ``gone`` (a mask over :attr:`tri`) when ``moved`` vertices of ``x``
        move to their places in ``y``, and the ``local`` triangles that replace them; ``local``
        is None where the result is no triangulation of the sphere (use the global hull)."""
        from scipy.spatial import cKDTree

        tri, n = self.tri, self.n
        mv = np.flatnonzero(moved)
        if self._of is None or self._of[0] is not x or self._of[1] is not tri:
            # circumcircles of the current map, reused while it stays current (and, built when
            # a few moved vertices first ask, KD-trees of its points and of the centres)
            self._of, self._caps, self._keys = (x, tri), _circumcaps(x, tri), None
            self._tree = self._centres = None
        centre, radius = self._caps
        few = len(mv) <= _FEW_MOVED

        def chords(c):
            """Chord distances ``(len(c), len(mv))`` from unit vectors ``c`` to the moved
            vertices (directly: they are few)."""
            return np.sqrt(np.maximum(2.0 - 2.0 * (c @ y[mv].T), 0.0))

        def to_moved(c, within):
            """Chord distance from each unit vector ``c`` to the nearest moved vertex; beyond
            ``within`` it may be inf instead (the tree's search stops there)."""
            if few:
                return chords(c).min(axis=1)
            return cKDTree(y[mv]).query(c, k=1, distance_upper_bound=within)[0]

        if few:
            # only circumcircles that can hold a moved vertex, at its old or new place, are
            # tested: their centres lie within the largest radius plus the longest move
            if self._centres is None:
                self._centres = cKDTree(centre), float(radius.max())
            ctree, rmax = self._centres
            reach = rmax + float(np.linalg.norm(y[mv] - x[mv], axis=1).max())
            near = ctree.query_ball_point(y[mv], reach * (1.0 + 1e-9) + 1e-12)
            cand = np.unique(np.concatenate([np.asarray(c, dtype=np.int64) for c in near]))
        else:
            cand = np.arange(len(tri))
        gone = np.zeros(len(tri), dtype=bool)
        inside = radius[cand] * (1.0 - _ON_CIRCLE)      # a circle holds what is nearer
        holds = to_moved(centre[cand], inside.max(initial=0.0)) < inside
        gone[cand] = moved[tri[cand]].any(axis=1) | holds
        cavity = np.union1d(np.unique(tri[gone]), mv)
        try:
            local = cavity[hull_triangles(y[cavity])]
        except InputError:          # too few or coplanar cavity points
            return gone, None
        centre, radius = _circumcaps(y, local)
        # nearest point of y other than the triangle's corners (they lie on the circle up to a
        # rounding that grows as the circle shrinks, past _ON_CIRCLE): of the unmoved ones (the
        # tree of x, skipping moved vertices) or of the moved ones at their new places
        def corners(idx):
            """Whether the point indices ``idx`` (a row per local triangle, or one row for all)
            are corners of that triangle."""
            return (idx[:, None, :] == local[:, :, None]).any(axis=1)

        if few:
            if self._tree is None:
                self._tree = cKDTree(x)
            dist, idx = self._tree.query(centre, k=len(mv) + 4)
            dist = np.where(moved[idx] | corners(idx), np.inf, dist)
            chord = np.where(corners(mv[None, :]), np.inf, chords(centre))
            nearest = np.minimum(dist.min(axis=1), chord.min(axis=1))
        else:
            dist, idx = cKDTree(y).query(centre, k=4)
            nearest = np.where(corners(idx), np.inf, dist).min(axis=1)
        local = local[nearest >= radius * (1.0 - _ON_CIRCLE)]
        if n ** 3 >= 2 ** 62:
            return gone, None
        w = np.array([n * n, n, 1])
        if self._keys is None:          # keys of the current triangles, and as a set
            keys = np.sort(tri, axis=1) @ w
            self._keys = keys, set(keys.tolist())
        keys, keyset = self._keys
        gone_keys = set(keys[gone].tolist())
        lk = (np.sort(local, axis=1) @ w).tolist()
        local = local[[not (k in keyset and k not in gone_keys) for k in lk]]
        if len(tri) - np.count_nonzero(gone) + len(local) != 2 * n - 4:
            return gone, None
        return gone, local

    def _global(self, y):
        t = hull_triangles(y)
        return t, self._folded(t)


def _circumcaps(x, t):
    """Centre (a unit vector) and chord radius of each triangle's circumcircle on the sphere."""
    a, b, c = x[t[:, 0]], x[t[:, 1]], x[t[:, 2]]
    centre = _unit(np.cross(b - a, c - a))
    return centre, np.linalg.norm(a - centre, axis=1)


def _proposals(x, p, t, kinds, mesh):
    """Moved vertex and its new position for each folded triangle ``t`` with move ``kinds``
    (indices into :data:`_MOVES`), one per vertex."""
    corner = np.array([m[0] for m in _MOVES])[kinds]
    margin = np.array([m[1] for m in _MOVES])[kinds]
    k = (_largest_angle_corner(p, t) + corner) % 3
    rows = np.arange(len(t))
    v, a, c = t[rows, k], t[rows, (k + 1) % 3], t[rows, (k + 2) % 3]
    with np.errstate(invalid="ignore", divide="ignore"):   # undefined moves are dropped below
        return _moves(x, v, a, c, margin, mesh)


def _moves(x, v, a, c, margin, mesh):
    """:func:`_proposals`' targets for corners ``v`` of triangles ``(v, a, c)``."""
    v, first = np.unique(v, return_index=True)
    a, c, margin = a[first], c[first], margin[first]
    g = _unit(np.cross(x[a], x[c]))                 # normal of the great circle through a and c
    d = np.einsum("ij,ij->i", x[v], g)
    out = _unit(x[v] - (1.0 + margin)[:, None] * d[:, None] * g)
    mid = margin < 0             # to (a share -margin of the way to) its mesh neighbours' centroid
    if mid.any():
        w = -margin[mid][:, None]
        out[mid] = _unit((1.0 - w) * x[v[mid]] + w * _unit(mesh.adj[v[mid]] @ x))
    # no move where it is undefined: two corners on one point (no great circle through them), or
    # a vertex without mesh neighbours (a point cloud's triangulation less its folded triangles)
    ok = np.isfinite(out).all(axis=1)
    return v[ok], out[ok]


def repair_folds(x, p, normals, f, *, options: MapOptions = DEFAULT_OPTIONS, search: bool = True):
    """Lower the count of folded Delaunay triangles of a spherical mesh embedding by local moves.

    Parameters
    ----------
    x : (n, 3) float64
        Unit vectors; every face of ``f`` counter-clockwise on the sphere.
    p, normals : (n, 3) float64
        3D positions and surfel normals.
    f : (m, 3) int64
        Faces, counter-clockwise seen from outside, agreeing with the normals.
    options : MapOptions
        ``repair_rounds``: most rounds. Each round tries a move on every folded triangle at
        once, the next of :data:`_MOVES` that this triangle has not had; the repair ends when
        every folded triangle has had them all. ``search_folds``, ``search_trials``,
        ``search_work``: the random search (:func:`random_search`).
    search : bool
        Follow the rounds with the random search when they leave at most
        ``options.search_folds`` folds.

    Returns
    -------
    x : (n, 3) float64
        The repaired embedding; no face more inverted than before.
    info : dict
        ``folds_before``, ``folds`` (folded hull triangles), ``rounds`` (rounds that kept a move),
        ``moved`` (moves kept, summed over the rounds) and, when the random search ran,
        ``searched`` (the folds it removed).
    """
    mesh = Mesh(f, len(x))
    x0 = x = np.array(x, dtype=np.float64)
    state = Hull(x, p, normals)
    info = {"folds_before": int(state.bad.sum()), "rounds": 0, "moved": 0, "folds": 0}
    if not info["folds_before"]:
        return x, info
    tried = {}                 # folded triangle (sorted corners) -> moves tried on it so far
    for _ in range(options.repair_rounds):
        t = state.tri[state.bad]
        keys = [tuple(k) for k in np.sort(t, axis=1).tolist()]
        kinds = np.array([tried.get(k, 0) for k in keys], dtype=np.int64)
        todo = kinds < len(_MOVES)
        if not todo.any():
            break
        for k in keys:
            tried[k] = tried.get(k, 0) + 1
        v, target = _proposals(x, p, t[todo], kinds[todo], mesh)
        y = x.copy()
        y[v] = target
        moved = np.zeros(len(x), bool)
        moved[v] = True
        moved = mesh.undo_inverting(x, y, moved)
        if not moved.any():
            continue
        tri2, bad2 = state.moved(x, y, moved)
        kept = _improving(mesh, state.tri, state.bad, tri2, bad2, moved)
        if not kept.any():
            continue
        if not np.array_equal(kept, moved):
            y[moved & ~kept] = x[moved & ~kept]
            tri2, bad2 = state.moved(x, y, kept)
        x, state.tri, state.bad = y, tri2, bad2
        info["rounds"] += 1
        info["moved"] += int(kept.sum())
    if search and 0 < int(state.bad.sum()) <= options.search_folds:
        x, found = random_search(x, state, mesh, trials=options.search_trials,
                           work=options.search_work)
        info["searched"] = found
    folds = int(folded_mask(p, normals, hull_triangles(x)).sum())   # the global hull, once
    if folds > info["folds_before"]:    # cannot happen unless the local updates went wrong
        x, folds = x0, info["folds_before"]
    info["folds"] = folds
    return x, info


def random_search(x, state, mesh, *, trials: int, work: float):
    """Random single-vertex moves around the few folds the move rounds left: for each folded
    triangle, up to ``trials`` moves of a corner or of a corner's mesh neighbour, in a random
    direction by a random share (:data:`_SEARCH_STEP`) of its mean mesh-edge length on the
    sphere; those that invert no mesh triangle are evaluated, and the first that lowers the fold
    count is kept. The evaluations, ``work / n`` in all (so about the same cost at any size), are
    shared evenly by the folds still to try, at least :data:`_SEARCH_MIN` each. Seeded: the same
    map gives the same result. Returns the map and the number of folds removed."""
    rng = np.random.default_rng(0)
    removed = 0
    budget = int(work / len(x))
    y, moved = x.copy(), np.zeros(len(x), bool)   # a trial's map and moved vertex, reused
    adj, vf = mesh.adj, mesh.vf
    folded = state.tri[state.bad]
    for i, t in enumerate(folded):
        if not state._folded(t[None])[0]:
            continue                                    # already gone with an earlier move
        cand = np.unique(np.concatenate([t, mesh.adj[t].indices]))
        left = max(_SEARCH_MIN, budget // (len(folded) - i))
        budget -= left
        folds = int(np.count_nonzero(state.bad))      # changes only when a move is kept
        for _ in range(trials):
            if not left:
                break
            v = int(rng.choice(cand))
            if adj.indptr[v] == adj.indptr[v + 1]:
                continue                     # no mesh neighbour: no step length to draw from
            d = rng.standard_normal(3)
            new = trial_move(x, v, d, rng.uniform(*_SEARCH_STEP), adj.indptr, adj.indices,
                              vf.indptr, vf.indices, mesh.f)
            if new is None:
                continue                     # inverts a mesh triangle: rejected unevaluated
            left -= 1
            y[v], moved[v] = new, True       # the trial in place; undone below unless kept
            if state.folds_if_moved(x, y, moved) < folds:
                tri2, bad2 = state.moved(x, y, moved)
                removed += folds - int(np.count_nonzero(bad2))
                x, state.tri, state.bad = y.copy(), tri2, bad2
                moved[v] = False
                break
            y[v], moved[v] = x[v], False
        budget += left                                  # what this fold left goes to the rest
    return x, removed


def trial_move(x, v, d, share, adj_ptr, adj_idx, vf_ptr, vf_idx, f):
    """:func:`random_search`'s move of vertex ``v``: along the random direction ``d`` (projected on the
    tangent plane) by ``share`` of its mean mesh-edge length on the sphere; the new unit vector,
    or None when it would invert one of ``v``'s mesh triangles."""
    new = np.empty(3)
    return new if _trial_kernel(x, v, d, share, adj_ptr, adj_idx, vf_ptr, vf_idx, f, new) else None


@numba.njit(cache=True)
def _trial_kernel(x, v, d, share, adj_ptr, adj_idx, vf_ptr, vf_idx, f, new):  # pragma: no cover
    h = 0.0
    for k in range(adj_ptr[v], adj_ptr[v + 1]):
        u = adj_idx[k]
        h += np.sqrt((x[u, 0] - x[v, 0]) ** 2 + (x[u, 1] - x[v, 1]) ** 2 + (x[u, 2] - x[v, 2]) ** 2)
    h /= adj_ptr[v + 1] - adj_ptr[v]
    dot = d[0] * x[v, 0] + d[1] * x[v, 1] + d[2] * x[v, 2]
    t = np.empty(3)
    for c in range(3):
        t[c] = d[c] - dot * x[v, c]
    step = h * share / np.sqrt(t[0] ** 2 + t[1] ** 2 + t[2] ** 2)
    for c in range(3):
        new[c] = x[v, c] + t[c] * step
    r = np.sqrt(new[0] ** 2 + new[1] ** 2 + new[2] ** 2)
    for c in range(3):
        new[c] /= r
    q = np.empty((3, 3))
    for k in range(vf_ptr[v], vf_ptr[v + 1]):
        t_ = vf_idx[k]
        for j in range(3):
            w = f[t_, j]
            for c in range(3):
                q[j, c] = new[c] if w == v else x[w, c]
        u0, u1, u2 = q[1, 0] - q[0, 0], q[1, 1] - q[0, 1], q[1, 2] - q[0, 2]
        v0, v1, v2 = q[2, 0] - q[0, 0], q[2, 1] - q[0, 1], q[2, 2] - q[0, 2]
        o = ((u1 * v2 - u2 * v1) * (q[0, 0] + q[1, 0] + q[2, 0])
             + (u2 * v0 - u0 * v2) * (q[0, 1] + q[1, 1] + q[2, 1])
             + (u0 * v1 - u1 * v0) * (q[0, 2] + q[1, 2] + q[2, 2]))
        if o <= 0.0:
            return False
    return True


def _improving(mesh, tri, bad, tri2, bad2, moved):
    """The moved vertices whose cluster (moved vertices joined by :data:`_CLUSTER_RINGS` rings)
    has fewer folded triangles in ``tri2`` than in ``tri``."""
    region = mesh.grow(moved, _CLUSTER_RINGS)
    ri = np.flatnonzero(region)
    count, lab = connected_components(mesh.adj[ri][:, ri], directed=False)
    label = np.full(mesh.n, -1)
    label[ri] = lab

    def folds_per_cluster(t, b):
        lt = label[t[b]]
        first = np.where(lt[:, 0] >= 0, lt[:, 0], np.where(lt[:, 1] >= 0, lt[:, 1], lt[:, 2]))
        return np.bincount(first[first >= 0], minlength=count)

    better = folds_per_cluster(tri2, bad2) < folds_per_cluster(tri, bad)
    return moved & (label >= 0) & better[np.maximum(label, 0)]
