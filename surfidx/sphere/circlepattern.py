"""Folded Delaunay triangles removed by choosing the triangulation first and realising it.

A map's fold count is decided by the spherical Delaunay triangulation of the mapped surfels (their
convex hull), and single-vertex moves (:mod:`surfidx.sphere.foldrepair`) stall where the map is
anisotropic: moving a vertex to mend one triangle changes which triangles are Delaunay around it.
This module works the other way round, in two steps.

1. **Flips** (:func:`flip_folds`): a combinatorial search on the current Delaunay triangulation.
   Each folded triangle (its 3D normal against its surfels' normals) has an edge flipped when the
   two new triangles hold fewer folded ones than the two old, or a sequence of up to
   :data:`_FLIP_DEPTH` flips is made, each on the folded triangle the previous one left, that
   loses nothing on the way and gains at the end (the fold is moved to where it can be removed).
   Any flip that does not duplicate an edge is allowed, also of a quadrilateral that is not
   convex on the sphere: the result is a triangulation of the sphere with fewer folded
   triangles, though no longer one of the points where they are.
2. **Realisation** (:func:`realise`): points on the sphere whose Delaunay triangulation is exactly
   that triangulation, close to the current map. By Rivin's theorem (1994; the variational
   principle of Bobenko & Springborn 2004), a triangulation of the sphere is realised as a
   Delaunay triangulation, uniquely up to Möbius transformations, with any intersection angles
   ``θ_e`` in ``(0, π)`` of the circumcircles meeting at its edges for which a *coherent angle
   system* exists: positive corner angles, π in each triangle and 2π around each vertex, the two
   opposite an edge summing to ``π - θ_e``. ``θ_e`` is positive exactly where the edge is
   locally Delaunay. After a stereographic projection from one vertex, the corner angles of the
   current map are projected onto such a system (:func:`coherent_angles`), with each edge at
   least :data:`_FLOOR` from cocircular and the flipped ones :data:`_NEW_ANGLE`. Newton's method
   then solves for the triangles' log circumradii (Kharevych, Springborn & Schröder 2006),
   searching each step for the minimum of the convex functional whose gradient it zeroes, so
   that it converges whenever the system is coherent. The triangles are laid out by least
   squares, fitted to the current map by a Möbius map (which keeps circles, so the realisation
   stays exact; a few flipped triangles change the radii everywhere, and a similarity fit would
   leave that change in) and projected back to the sphere.
   :func:`realise` returns the points only when Newton converged and their convex hull is
   that triangulation, triangle for triangle. :func:`lower_folds` takes the folds of the hull
   itself instead: a sliver of the pattern (angles of 1e-7) can be too thin for double
   precision on the sphere and come out flipped, which changes a fold count by one or two.

   Rivin's conditions are checked through the whole angle system, not the vertex sums
   alone: a flipped quadrilateral that is not convex can make three edges of a triangle sum
   past 2π, where no realisation exists.

Where every folded triangle needs a flip that adds a fold first, :func:`flip_folds` stops;
:func:`anneal_flips` searches by the Metropolis rule (such flips taken now and then), and the
first rung of :func:`lower_folds` realises its triangulation with the fewest folds, then one
halfway, before the flips alone. The mesh's own faces are no longer all embedded afterwards (a
few turned over, a small share of the sphere); resampling still interpolates in them
(:func:`surfidx.codec.resample.map_triangles`).

What a realisation costs is a regional change of scale. The flips in an anisotropic limb make
its triangulation nearer conformal, and a Delaunay realisation then changes the limb's conformal
shape: the surfels around the turned-over faces can lose much of their share of the sphere, and
the resampling with it. So :func:`lower_folds` keeps a realisation only when the caller's
``accept`` takes it (the map measures the resampling,
:class:`surfidx.sphere.repair.ResamplingCheck`).
"""

from __future__ import annotations

import contextlib
import gc
from itertools import compress

import numpy as np
import scipy.sparse as sp

from ..geometry.sparse import SPDSolver, spd_factor
from ..geometry.unitsphere import against_normals, corner_orientation, hull_triangles, mirrored, smallest_first
from .options import DEFAULT_OPTIONS, MapOptions

__all__ = ["flip_folds", "anneal_flips", "realise", "lower_folds"]

_FLOOR = 0.01          # intersection angle floor of the triangulation's edges (radians); near
# cocircular edges make Newton's functional nearly a step along them and its damped phase long
_NEW_ANGLE = 0.05      # ... of the flipped-in edges: Delaunay by this margin after realisation
MIN_CORNER = 1e-4     # smallest corner angle of the coherent angle system (radians)
_PROJECTION_STEPS = 300
NEWTON_STEPS = 300
_NEWTON_TOL = 1e-10    # largest triangle angle-sum error (radians) at convergence
_LINE_STEPS = 40       # bisections of a Newton step's line search
_STALLS = 2            # fresh Newton steps in a row whose line search accepts no point: stalled.
# A solve that converges meets at most one such step; one that does not meets them in a row,
# so two stop it long before NEWTON_STEPS (seen on the retrieval models).
_POLE_TRIES = 20       # candidate poles of the stereographic projection (by their star's area)
_MOEBIUS_STEPS = 5     # reweightings of the Möbius fit of a realisation to the current map
_LAYOUT_WEIGHT = 0.5   # rows of the layout weighted by circumradius ** -this (see layout)
_LAYOUT_REFINEMENTS = 2
_CHORD_RATE = 0.25     # a factorised Jacobian is reused while steps shrink the residual so
_FLIP_ROUNDS = 30
_FLIP_DEPTH = 6       # flips in a sequence that moves a fold before it is removed
MIN_SPACING_RATIO = 0.5
"""Without a caller's ``accept``, :func:`lower_folds` lets the realisations bring a point's
nearest neighbours on the sphere (the mean distance to :data:`_SPACING_NEIGHBOURS` of them)
closer by this factor at most, measured from the map before the first round: a flip far from
Delaunay moves its corners a lot, and the grid then samples the surfels there too sparsely.
A proxy only, and a poor one: the map measures the resampling instead."""
_SPACING_NEIGHBOURS = 6


@contextlib.contextmanager
def _collector_paused():
    """Python's cyclic garbage collector paused for the block or the decorated function
    (restored as it was). The flip searches build a few hundred thousand tuples, lists and dict
    entries that live until the search ends and form no cycles: the collector would only walk
    them again and again as they grow."""
    was = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if was:
            gc.enable()


def _angle(x, a, b, c):
    """The angle at ``a`` between the chords to ``b`` and ``c``."""
    u, v = x[b] - x[a], x[c] - x[a]
    return float(np.arccos(np.clip(u @ v / np.sqrt((u @ u) * (v @ v)), -1.0, 1.0)))


def against(p, normals, t):
    """:func:`surfidx.geometry.unitsphere.against_normals` of the one triangle ``t``, on the rows of
    ``p`` and ``normals`` as lists: the same operations in the same order in Python floats
    (the searches judge tens of thousands of single flips, where numpy's cost per call is
    most of the work)."""
    k = t.index(min(t))
    i, j, m = t[k], t[k - 2], t[k - 1]          # from the smallest index, the order kept
    (x0, y0, z0), (x1, y1, z1), (x2, y2, z2) = p[i], p[j], p[m]
    ux, uy, uz = x1 - x0, y1 - y0, z1 - z0
    vx, vy, vz = x2 - x0, y2 - y0, z2 - z0
    (a0, a1, a2), (b0, b1, b2), (c0, c1, c2) = normals[i], normals[j], normals[m]
    return ((uy * vz - uz * vy) * (a0 + b0 + c0) + (uz * vx - ux * vz) * (a1 + b1 + c1)
            + (ux * vy - uy * vx) * (a2 + b2 + c2)) < 0


class _Flips:
    """A triangulation under edge flips: directed edge -> triangle, each triangle's fold, and the
    set of folded triangles."""

    def __init__(self, tri, p, normals, x, mirror, convex=False, max_violation=np.inf):
        self.tri = [tuple(t) for t in np.asarray(tri).tolist()]
        self.p, self.normals, self.x, self.mirror = p, normals, x, mirror
        self.convex = convex or max_violation < np.pi
        self.max_violation = max_violation
        self._flipped = {}
        self.edge = {}
        for i in range(len(self.tri)):
            self._register(i)
        self.bad = (against_normals(p, normals, tri) ^ mirror).tolist()
        self.folded = set(compress(range(len(self.bad)), self.bad))   # kept up to date by flips
        self._rows = p.tolist(), normals.tolist()       # for against, one triangle at a time

    @classmethod
    def of(cls, tri, p, normals, x, **options):
        """The state of ``tri`` in canonical order (the searches visit triangles by vertex
        index, not by input order, so a rotated map flips the same edges), mirrored when most
        of its triangles disagree with the normals."""
        tri = _canonical(tri)
        return cls(tri, p, normals, x, mirror=mirrored(against_normals(p, normals, tri)),
                   **options)

    def _register(self, i):
        a, b, c = self.tri[i]
        self.edge[(a, b)] = self.edge[(b, c)] = self.edge[(c, a)] = i

    def _unregister(self, i):
        a, b, c = self.tri[i]
        for e in ((a, b), (b, c), (c, a)):
            if self.edge.get(e) == i:
                del self.edge[e]

    def candidate(self, i, k):
        """The flip of triangle ``i``'s edge from corner ``k`` to the next, as ``(gain, i, j,
        new triangles, their folds)``; None when the new edge exists already, or when the
        quadrilateral is not convex on the sphere (with ``convex`` or a finite
        ``max_violation``), or when the new edge is further from Delaunay than that. Any other
        flip is combinatorially valid, and :func:`realise` moves the points to make it
        Delaunay."""
        t = self.tri[i]
        a, b, c = t[k], t[(k + 1) % 3], t[(k + 2) % 3]
        j = self.edge.get((b, a))
        if j is None:
            return None
        d = next(v for v in self.tri[j] if v != a and v != b)
        if c == d or (c, d) in self.edge or (d, c) in self.edge:
            return None
        new = ((a, d, c), (d, b, c))
        bad = self._flipped.get(new)
        if bad is None:
            bad = self._flipped[new] = self._judge(new)
        if bad is False:
            return None
        return int(self.bad[i]) + int(self.bad[j]) - sum(bad), i, j, new, bad

    def _judge(self, new):
        """The folds of the two triangles ``new`` of a flip (a list of two bools), or False
        where ``convex`` refuses the flip. They depend on the corners alone, and the searches
        meet the same flip again and again, so :meth:`candidate` remembers them."""
        (a, d, c), (_, b, _) = new
        if self.convex and not (
                (corner_orientation(self.x[np.array(new)]) > 0).all()
                and np.pi - _angle(self.x, a, d, c) - _angle(self.x, b, c, d)
                >= -self.max_violation):
            return False
        return [against(*self._rows, t) != self.mirror for t in new]

    def apply(self, cand):
        _, i, j, new, bad = cand
        old = (self.tri[i], self.tri[j], self.bad[i], self.bad[j])
        self._unregister(i)
        self._unregister(j)
        self.tri[i], self.tri[j] = new
        self.bad[i], self.bad[j] = bad
        self._register(i)
        self._register(j)
        self._refold(i, j)
        return i, j, old

    def undo(self, record):
        i, j, (ti, tj, bi, bj) = record
        self._unregister(i)
        self._unregister(j)
        self.tri[i], self.tri[j], self.bad[i], self.bad[j] = ti, tj, bi, bj
        self._register(i)
        self._register(j)
        self._refold(i, j)

    def _refold(self, *triangles):
        for q in triangles:
            if self.bad[q]:
                self.folded.add(q)
            else:
                self.folded.discard(q)

    def mend(self, i, depth: int = None, gained: int = 0) -> bool:
        """A sequence of at most ``depth`` flips, each on a folded triangle the previous one left
        and none losing a fold, whose gains sum positive (a fold moved by flips that keep the
        count until it meets a place, or another fold, where it can be removed)."""
        depth = _FLIP_DEPTH if depth is None else depth
        cands = [c for k in range(3) if (c := self.candidate(i, k)) is not None and c[0] >= 0]
        for cand in sorted(cands, key=lambda c: -c[0]):
            record = self.apply(cand)
            if gained + cand[0] > 0:
                return True
            if depth > 1 and any(self.bad[q] and self.mend(q, depth - 1, gained + cand[0])
                                 for q in record[:2]):
                return True
            self.undo(record)
        return False


@_collector_paused()
def flip_folds(tri, p, normals, x, *, rounds: int = _FLIP_ROUNDS, convex: bool = False,
               max_violation: float = np.inf):
    """Edge flips of a spherical triangulation that lower its count of folded triangles.

    Parameters
    ----------
    tri : (m, 3) int64
        Counter-clockwise triangulation of the sphere points ``x`` (e.g. their convex hull).
    p, normals : (n, 3) float64
        3D positions and surfel normals; a triangle is folded when its 3D normal points against
        the sum of its corners' normals (the minority orientation when most disagree: a mirror).
    x : (n, 3) float64
        Sphere points (for ``convex`` and ``max_violation`` only).
    rounds : int
        Passes over the folded triangles, until one changes nothing.
    convex : bool
        Flip only quadrilaterals convex on the sphere (the flipped triangulation is then still
        one of the points ``x``).
    max_violation : float
        When finite, flip only convex quadrilaterals whose new edge's intersection angle
        ``π - α - β`` (chord angles) is at least ``-max_violation``: the realisation then moves
        the points less.

    Returns
    -------
    tri : (m, 3) int64
        The flipped triangulation (rows in the canonical order: each starts at its smallest
        corner, rows sorted).
    folds : int
        Its folded triangles.
    """
    state = _Flips.of(tri, p, normals, x, convex=convex, max_violation=max_violation)
    for _ in range(rounds):
        todo = sorted(state.folded)
        changed = sum(state.mend(i) for i in todo if state.bad[i])
        if not changed:
            break
    return np.array(state.tri, dtype=np.int64), int(sum(state.bad))


@_collector_paused()
def anneal_flips(tri, p, normals, x, *, steps: int = DEFAULT_OPTIONS.anneal_steps,
                 temperature: float = DEFAULT_OPTIONS.anneal_temperature, seed: int = 0):
    """Random edge flips around the folded triangles, kept by the Metropolis rule: the
    triangulations with fewer folds than any before, met on the way.

    :func:`flip_folds` keeps only flip sequences that never add a fold, and stops where every
    folded triangle needs one that does. Here a flip of an edge of a folded
    triangle (or of a triangle next to one) is taken when it removes folds, with probability
    1/2 when it keeps the count, and ``exp(-k / temperature)`` when it adds ``k``.

    Parameters
    ----------
    tri : (m, 3) int64
        Counter-clockwise triangulation of the sphere points ``x``.
    p, normals : (n, 3) float64
        3D positions and surfel normals (folds as in :func:`flip_folds`).
    x : (n, 3) float64
        Sphere points.
    steps : int
        Flips proposed.
    temperature : float
        Positive; see above.
    seed : int
        Seed of the proposals: the same input gives the same triangulations.

    Returns
    -------
    list of ((m, 3) int64, int)
        Each new best triangulation (canonical rows, as :func:`flip_folds`) and its folds, in the
        order found (falling fold counts); empty when none beats ``tri``.
    """
    if not temperature > 0:
        raise ValueError(f"temperature must be positive, got {temperature!r}")
    rng = np.random.default_rng(seed)
    state = _Flips.of(tri, p, normals, x)
    folds = best = int(sum(state.bad))
    found = []
    bad = []
    for step in range(int(steps)):
        if step % 64 == 0 or not bad:
            bad = sorted(state.folded)      # the folded triangles in index order, without a scan
            if not bad:
                break
        i = bad[rng.integers(len(bad))]
        if rng.random() < 0.2:                          # the triangle across one of its edges
            a, b, c = state.tri[i]
            i = state.edge.get(((b, a), (c, b), (a, c))[rng.integers(3)])
            if i is None:
                continue
        cand = state.candidate(i, int(rng.integers(3)))
        if cand is None:
            continue
        gain = cand[0]
        if gain > 0 or (gain == 0 and rng.random() < 0.5) or (
                gain < 0 and rng.random() < np.exp(gain / temperature)):
            state.apply(cand)
            folds -= gain
            bad = [q for q in bad if state.bad[q]] + [q for q in cand[1:3] if state.bad[q]
                                                      and q not in bad]
            if folds < best:
                best = folds
                found.append((np.array(state.tri, dtype=np.int64), folds))
    return found


# ----------------------------------------------------------------------------- realisation
def mesh_edges(tri, n):
    """Unique edges ``(E, 2)`` and the edge opposite each corner ``(m, 3)``."""
    e = np.concatenate([tri[:, [1, 2]], tri[:, [2, 0]], tri[:, [0, 1]]])
    key = np.minimum(e[:, 0], e[:, 1]) * n + np.maximum(e[:, 0], e[:, 1])
    uniq, inv = np.unique(key, return_inverse=True)
    return np.column_stack([uniq // n, uniq % n]), inv.reshape(3, len(tri)).T


def planar_angles(u, t):
    """The signed corner angles of planar triangles.

    Parameters
    ----------
    u : ndarray of float64, shape (n, 2)
        Planar points.
    t : ndarray of int, shape (m, 3)
        Triangles.

    Returns
    -------
    ndarray of float64, shape (m, 3)
        The angle at each corner (negative in an inverted triangle).
    """
    out = np.empty(t.shape)
    for k in range(3):
        a, b, c = u[t[:, k]], u[t[:, (k + 1) % 3]], u[t[:, (k + 2) % 3]]
        e1, e2 = b - a, c - a
        out[:, k] = np.arctan2(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0],
                               np.einsum("ij,ij->i", e1, e2))
    return out


def coherent_angles(alpha, t, n, ring, ring_sums, opposite, cap):
    """Corner angles near ``alpha`` that form a coherent angle system for the planar triangles
    ``t`` (Bobenko & Springborn 2004): each at least :data:`MIN_CORNER`, summing to π in every
    triangle and to 2π around every inner vertex (to ``ring_sums`` at the ``ring`` vertices on
    the boundary), and the two opposite an edge summing to at most ``cap`` of that edge (one,
    at the boundary). Such a system exists exactly when the circle pattern with the
    intersection angles ``π - cap`` does, so these are the angles Newton's method is given.

    Alternating projections: onto each edge's constraints, which involve its two corners only
    (a triangle the flips turned over has negative angles), then onto the linear sums (a
    least-norm correction). The triangle sums have disjoint corners, so the correction's
    normal equations are solved through their Schur complement on the vertex sums, a matrix
    with the mesh's vertex adjacency, factored once.

    Parameters
    ----------
    alpha : (m, 3) float64
        The current corner angles (any sign: a flip may turn triangles over).
    t : (m, 3) int64
    n : int
    ring : (r,) int64
    ring_sums : (r,) float64
    opposite : (m, 3) int64
        The edge opposite each corner, indices into ``cap``.
    cap : (E,) float64

    Returns
    -------
    (m, 3) float64 or None
        None when the projections do not settle (no such system near ``alpha``).
    """
    m = len(t)
    corner = np.arange(3 * m)
    vertex = t.ravel()
    row = np.full(n, -1)
    inner = np.flatnonzero(np.bincount(vertex, minlength=n) > 0)
    inner = inner[inner != ring[0]]         # the sums are dependent: one vertex row left out
    row[inner] = np.arange(len(inner))
    use = row[vertex] >= 0
    tsum = sp.csr_matrix((np.ones(3 * m), (corner // 3, corner)), shape=(m, 3 * m))
    vsum = sp.csr_matrix((np.ones(use.sum()), (row[vertex][use], corner[use])),
                         shape=(len(inner), 3 * m))
    sums = np.full(n, 2 * np.pi)
    sums[ring] = ring_sums
    vrhs = sums[inner]
    # [[3 I, B], [B^T, D]] = [tsum; vsum] [tsum; vsum]^T, eliminated to D - B^T B / 3
    cross = tsum @ vsum.T
    try:
        lu = spd_factor(vsum @ vsum.T - (cross.T @ cross) / 3.0)
    except RuntimeError:
        return None

    def project(a):         # the nearest point of the linear sums' affine subspace
        rt, rv = tsum @ a - np.pi, vsum @ a - vrhs
        z = lu.solve(rv - cross.T @ rt / 3.0)
        return a - tsum.T @ ((rt - cross @ z) / 3.0) - vsum.T @ z

    e = opposite.ravel()
    order = np.argsort(e, kind="stable")
    first = np.flatnonzero(np.r_[True, e[order][1:] != e[order][:-1]])
    pair = np.bincount(e, minlength=len(cap))[e[order][first]] == 2
    p, q = order[first[pair]], order[first[pair] + 1]     # the two corners opposite an edge
    single = order[first[~pair]]                          # the one opposite a boundary edge
    cap_p, cap_s = cap[e[p]], cap[e[single]]
    lo, hi_p, hi_s = MIN_CORNER * 1.01, cap_p - 1e-6, cap_s - 1e-6     # inside, by a margin
    a = alpha.ravel().copy()
    for _ in range(_PROJECTION_STEPS):
        if a.min() >= MIN_CORNER and (a[p] + a[q] <= cap_p).all() and (a[single] <= cap_s).all() \
                and np.abs(tsum @ a - np.pi).max() < 1e-9 and np.abs(vsum @ a - vrhs).max() < 1e-9:
            return a.reshape(m, 3)
        u, v = np.maximum(a[p], lo), np.maximum(a[q], lo)
        excess = np.maximum(u + v - hi_p, 0.0) / 2   # the nearest point of the triangle
        u, v = u - excess, v - excess                # u, v >= lo, u + v <= hi
        a[p] = np.where(u < lo, lo, np.where(v < lo, hi_p - lo, u))
        a[q] = np.where(v < lo, lo, np.where(u < lo, hi_p - lo, v))
        a[single] = np.clip(a[single], lo, hi_s)
        a = project(a)
    return None


def half_angle(x, sin_ts, cos_ts):
    """Angle opposite an edge in a triangle whose circumcircle has log radius ``ρ_j``, when the
    neighbour's has ``ρ_j + x`` and the circles meet at ``π - ts``: ``arg(1 + e^(x + i ts))``,
    from ``sin(ts)`` and ``cos(ts)`` (Newton's method evaluates the angles of one ``ts``
    thousands of times, so it computes them once)."""
    with np.errstate(over="ignore"):        # a far larger neighbour: e^-x = inf, the angle 0
        return np.arctan2(sin_ts, np.exp(-x) + cos_ts)


def _half_angle_slope(x, sin_ts, cos_ts):
    """Derivative of :func:`half_angle` in ``x``, from ``sin(ts)`` and ``cos(ts)``."""
    return sin_ts / (2.0 * (np.cosh(np.clip(x, -700, 700)) + cos_ts))


def log_radii(ts, inner_pairs, boundary_face, boundary_ts, m, rho):
    """Newton's method for the log circumradii ``rho`` (m,) of the triangles: each triangle's
    angles sum to π. The residual is minus the gradient of a convex functional (Bobenko &
    Springborn), so each step is searched along for that functional's minimum on the line (by
    its derivative, the residual times the step): Newton's method then converges wherever the
    functional has a minimum, which a coherent angle system guarantees. When the searches
    along the steps of :data:`_STALLS` fresh factorisations in a row find no point the
    bisections accept, the method has stalled (rounding leaves no descent; the steps that follow
    repeat it until :data:`NEWTON_STEPS`), so it stops there. Returns (rho, converged)."""
    i, j = inner_pairs[:, 0], inner_pairs[:, 1]
    const = np.bincount(boundary_face, boundary_ts, minlength=m) - np.pi
    trig = dict(sin_ts=np.sin(ts), cos_ts=np.cos(ts))

    def residual(r):            # the two angles opposite an edge sum to its ts
        half = half_angle(r[j] - r[i], **trig)
        return const + np.bincount(i, half, minlength=m) + np.bincount(j, ts - half, minlength=m)

    def jacobian(r):            # minus the residual's Jacobian: a weighted dual Laplacian
        w = _half_angle_slope(r[j] - r[i], **trig)
        lap = sp.csr_matrix((np.concatenate([-w, -w]), (np.concatenate([i, j]),
                                                        np.concatenate([j, i]))), shape=(m, m))
        return (lap + sp.diags(np.bincount(i, w, minlength=m)
                               + np.bincount(j, w, minlength=m))).tocsr()[1:, 1:]

    g = residual(rho)
    lu, stalls, solver = None, 0, SPDSolver()
    for _ in range(NEWTON_STEPS):
        if np.abs(g).max() < _NEWTON_TOL:
            return rho, True
        if lu is None:          # a fresh factorisation, reused while the steps converge fast
            try:
                lu = solver.factor(jacobian(rho))
            except RuntimeError:
                return rho, False
            fresh = True
        step = np.zeros(m)
        step[1:] = lu.solve(g[1:])          # the residual's Jacobian is minus this matrix
        slope = g @ step        # minus the derivative of the convex functional along the step
        if not (np.isfinite(slope) and slope > 0):
            if fresh:
                return rho, False
            lu = None
            continue
        h, g1 = 1.0, residual(rho + step)
        exhausted = False
        if g1 @ step < 0:       # past the functional's minimum on the line: bisect for it
            lo, hi = 0.0, 1.0
            for _ in range(_LINE_STEPS):
                h = 0.5 * (lo + hi)
                g1 = residual(rho + h * step)
                d = g1 @ step
                if abs(d) <= 0.1 * slope:
                    break
                lo, hi = (h, hi) if d > 0 else (lo, h)
            else:
                exhausted = True
        if fresh:
            stalls = stalls + 1 if exhausted else 0
            if stalls == _STALLS:
                return rho, False
        norm = np.linalg.norm(g)
        rho, g = rho + h * step, g1
        if not fresh and (h < 1.0 or np.linalg.norm(g) > _CHORD_RATE * norm):
            lu = None
        fresh = False
    return rho, bool(np.abs(g).max() < _NEWTON_TOL)


def layout(t, angles, rho, n, anchor):
    """Positions (n,) complex of the triangles ``t`` with the given corner angles, by least squares
    over ``p_c - p_a = w (p_b - p_a)`` at every corner; the first triangle's first two corners
    pinned.

    The equations are consistent (Newton's angles close up to rounding), so their weights choose
    only how rounding spreads, and the circumradii span many orders of magnitude (slivers of
    angle 1e-7 next to triangles 1e8 times larger). Each corner's row is scaled to unit norm
    (``|w|`` reaches 1e7 at a sliver) times the circumradius to the power
    ``-``:data:`_LAYOUT_WEIGHT`, and the solution is refined :data:`_LAYOUT_REFINEMENTS` times
    from its residual with the same factor: without both, the normal equations are too
    ill-conditioned for double precision and large realisations come out with wrong angles."""
    m = len(t)
    scale = np.exp(-_LAYOUT_WEIGHT * rho)
    rows, cols, vals = [], [], []
    for k in range(3):
        a, b, c = t[:, k], t[:, (k + 1) % 3], t[:, (k + 2) % 3]
        w = np.sin(angles[:, (k + 1) % 3]) / np.sin(angles[:, (k + 2) % 3]) \
            * np.exp(1j * angles[:, k])
        r = k * m + np.arange(m)
        s = scale / np.sqrt(1.0 + np.abs(w - 1.0) ** 2 + np.abs(w) ** 2)
        rows += [r, r, r]
        cols += [c, a, b]
        vals += [s, (w - 1.0) * s, -w * s]
    mat = sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                        shape=(3 * m, n))
    z = np.zeros(n, complex)
    a0, b0 = t[0, 0], t[0, 1]
    z[b0] = 2.0 * np.exp(rho[0]) * np.sin(angles[0, 2])
    free = np.ones(n, bool)
    free[[a0, b0]] = False
    free[anchor] = False
    sub = mat[:, free]
    try:
        lu = spd_factor(sub.conj().T @ sub)
    except RuntimeError:
        return None
    for _ in range(1 + _LAYOUT_REFINEMENTS):
        z[free] += lu.solve(sub.conj().T @ -(mat @ z))
    return z


def _poles(x, tri):
    """The points by how much of the sphere their triangles cover, largest first (an intrinsic
    order: candidate poles of :func:`_stereographic`)."""
    star = np.bincount(tri.ravel(), np.repeat(np.abs(np.einsum(
        "ij,ij->i", x[tri[:, 0]], np.cross(x[tri[:, 1]], x[tri[:, 2]]))), 3), minlength=len(x))
    return np.argsort(-star, kind="stable")


def _stereographic(x, tri, pole):
    """Plane coordinates ``(n, 2)`` of ``x`` by the stereographic projection from ``pole``,
    mirrored so that ``tri`` keeps its orientation; and the frame ``(rotation, pole, mirrored)``
    that :func:`_from_plane` undoes."""
    n = len(x)
    pole = int(pole)
    z = x[pole]                         # the rotation taking the pole to (0, 0, 1)
    axis = np.cross(z, [0.0, 0.0, 1.0])
    s, c = np.linalg.norm(axis), z[2]
    if s < 1e-12:
        rot = np.eye(3) if c > 0 else np.diag([1.0, -1.0, -1.0])
    else:
        k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]]) / s
        rot = np.eye(3) + s * k + (1 - c) * k @ k
    y = x @ rot.T
    keep = np.arange(n) != pole
    u = np.zeros((n, 2))
    u[keep] = y[keep, :2] / (1.0 - y[keep, 2])[:, None]
    t = tri[~np.any(tri == pole, axis=1)]
    e1, e2 = u[t[:, 1]] - u[t[:, 0]], u[t[:, 2]] - u[t[:, 0]]
    mirror = bool(np.sum(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]) < 0)
    if mirror:
        u[:, 1] *= -1.0
    return u, (rot, pole, mirror)


def _from_plane(z, frame, far=np.inf):
    """Unit vectors ``(n, 3)`` of the plane points ``z`` (n,) complex: :func:`_stereographic`
    undone. The pole goes to ``far`` (where a Möbius map took infinity); None when some point
    is not finite."""
    rot, pole, mirror = frame
    z = np.array(z, dtype=complex)
    z[pole] = 0.0
    if mirror:
        z, far = np.conj(z), np.conj(far)
    r2 = np.abs(z) ** 2
    out = np.column_stack([2 * z.real, 2 * z.imag, r2 - 1.0]) / (1.0 + r2)[:, None]
    f2 = abs(far) ** 2 if abs(far) < 1e8 else np.inf     # within 1e-8 of the pole: the pole
    out[pole] = [2 * far.real / (1 + f2), 2 * far.imag / (1 + f2), (f2 - 1) / (f2 + 1)] \
        if np.isfinite(f2) else [0.0, 0.0, 1.0]
    if not np.isfinite(out).all():
        return None
    out = out @ rot
    return out / np.linalg.norm(out, axis=1)[:, None]


def realise(x, tri, *, new_edges=None):
    """Points on the sphere near ``x`` whose Delaunay triangulation is ``tri``.

    Parameters
    ----------
    x : (n, 3) float64
        Unit vectors.
    tri : (m, 3) int64
        A triangulation of the sphere on them, counter-clockwise seen from outside (where ``x``
        does not embed it, e.g. after a flip of a quadrilateral that is not convex, the
        turned-over triangles' angles are projected like the others).
    new_edges : (k, 2) int64, optional
        Edges to make Delaunay by the margin :data:`_NEW_ANGLE` (default: those of ``tri`` that
        are not Delaunay in ``x``).

    Returns
    -------
    (n, 3) float64 or None
        The realisation (its convex hull is ``tri``), or None when ``tri`` is no triangulation
        of all the points (a duplicate point that the convex hull leaves out), the angles admit
        no realisation, Newton's method does not converge, or the hull of the points it gives
        differs from ``tri``.
    """
    out = _circle_pattern(x, tri, new_edges=new_edges)
    return out if out is not None and _same_triangles(hull_triangles(out), tri) else None


def _circle_pattern(x, tri, *, new_edges=None):
    """:func:`realise` before its check: the points of the circle pattern, or None when ``tri``
    is no triangulation of all the points, the angles admit no realisation or Newton's method
    does not converge. Their hull can differ from ``tri`` where a triangle is thinner than
    double precision resolves on the sphere (angles of 1e-7 at a size of 1e-9)."""
    x = np.asarray(x, dtype=np.float64)
    tri = np.asarray(tri, dtype=np.int64)
    n = len(x)
    if not _spans(tri, n):
        return None
    edges, opposite = mesh_edges(tri, n)
    ne = len(edges)
    for pole in _poles(x, tri)[:_POLE_TRIES]:
        # the pole's edges keep their intersection angles, the turning angles of the boundary
        # of the plane triangulation: a pole whose triangles the flips changed leaves some of
        # them non-convex, and a few triangles there would not be Delaunay
        u, frame = _stereographic(x, tri, pole)
        inner = ~np.any(tri == pole, axis=1)
        t = tri[inner]
        ang = planar_angles(u, t)
        spoke = np.any(edges == pole, axis=1)
        ring = np.where(edges[spoke, 0] == pole, edges[spoke, 1], edges[spoke, 0])
        vertex_sum = np.bincount(t.ravel(), ang.ravel(), minlength=n)
        if np.pi - vertex_sum[ring].max() >= _NEW_ANGLE:
            break
    else:
        return None
    keep = np.arange(n) != pole
    theta = np.pi - np.bincount(opposite[inner].ravel(), ang.ravel(), minlength=ne)
    floor = np.full(ne, _FLOOR)
    if new_edges is None:
        floor[theta < 0] = _NEW_ANGLE
    elif len(new_edges):
        ne_ = np.sort(np.asarray(new_edges, dtype=np.int64), axis=1)
        floor[np.isin(edges[:, 0] * n + edges[:, 1], ne_[:, 0] * n + ne_[:, 1])] = _NEW_ANGLE
    alpha = coherent_angles(ang, t, n, ring, vertex_sum[ring], opposite[inner], np.pi - floor)
    out = None if alpha is None else _pattern(
        alpha, u, t, ang, opposite[inner], ne, n, pole, keep, frame)
    return out


def _spans(tri, n):
    """Whether ``tri`` is a triangulation of the sphere on all ``n`` points: ``2n - 4``
    triangles, each point a corner of three at least. A hull that leaves out a point (a
    duplicate, or one that a sliver too thin for double precision put on a face) is not, and
    no flip of it is: its flips cannot be realised."""
    return len(tri) == 2 * n - 4 and np.bincount(np.ravel(tri), minlength=n).min() >= 3


def _same_triangles(a, b):
    return len(a) == len(b) and np.array_equal(_sorted_rows(a), _sorted_rows(b))


def _pattern(alpha, u, t, ang, opp_inner, ne, n, pole, keep, frame):
    """The circle pattern of the coherent angles ``alpha`` of the plane triangles ``t``, laid
    out, fitted to the current plane points ``u`` and back on the sphere; None when Newton's
    method does not converge or the layout fails."""
    ts = np.bincount(opp_inner.ravel(), alpha.ravel(), minlength=ne)  # α + β at each edge
    # the circles of the inner triangles; edge -> its inner triangles
    mi = len(t)
    flat_e, flat_f = opp_inner.ravel(), np.repeat(np.arange(mi), 3)
    order = np.argsort(flat_e, kind="stable")
    flat_e, flat_f = flat_e[order], flat_f[order]
    first = np.r_[True, flat_e[1:] != flat_e[:-1]]
    count = np.bincount(flat_e, minlength=ne)
    two = count[flat_e[first]] == 2
    pairs = np.column_stack([flat_f[first][two], flat_f[np.flatnonzero(first)[two] + 1]])
    pair_edges = flat_e[first][two]
    bnd = count[flat_e[first]] == 1
    bnd_face, bnd_edge = flat_f[first][bnd], flat_e[first][bnd]
    a, b = u[t[:, 1]] - u[t[:, 0]], ang[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        rho = np.log(np.linalg.norm(a, axis=1) / (2.0 * np.abs(np.sin(b))))
    rho = np.where(np.isfinite(rho), rho, 0.0)
    rho, ok = log_radii(ts[pair_edges], pairs, bnd_face, ts[bnd_edge], mi, rho - rho[0])
    if not ok:
        return None
    # each inner triangle's corner angles: the half angle of the edge opposite the corner
    pair_of = np.full(ne, -1)
    pair_of[pair_edges] = np.arange(len(pair_edges))
    own = np.arange(mi)
    angles = np.empty((mi, 3))
    for k in range(3):
        e = opp_inner[:, k]
        q = np.maximum(pair_of[e], 0)
        nb = np.where(pairs[q, 0] == own, pairs[q, 1], pairs[q, 0])
        half = half_angle(rho[nb] - rho, np.sin(ts[e]), np.cos(ts[e]))
        angles[:, k] = np.where(pair_of[e] >= 0, half, ts[e])
    if not (angles > 0).all():
        return None
    zc = layout(t, angles, rho, n, pole)
    if zc is None:
        return None
    # the Möbius map closest to the current map, weighted like area on the sphere: it keeps
    # the pattern's circles, so the realisation stays exact
    zu = u[keep, 0] + 1j * u[keep, 1]
    moved, far = moebius_fit(zc[keep], zu, zc)
    return _from_plane(moved, frame, far)


def moebius_fit(z, target, z_all):
    """``m(z_all)`` and ``m(∞)`` for the Möbius map ``m(z) = (a z + b) / (c z + 1)`` that brings
    ``z`` nearest ``target`` in the sphere's metric: least squares on ``a z + b - c z target =
    target``, whose residuals are the wanted ones times ``c z + 1``, reweighted by that factor
    (:data:`_MOEBIUS_STEPS` times). A Möbius map rather than a similarity ``a z + b``: it keeps
    the far field in place, so the points move less and the resampling loses less."""
    w = 1.0 / (1.0 + np.abs(target) ** 2)        # the square root of the area element
    mat = np.column_stack([z, np.ones_like(z), -z * target])
    den = np.ones(len(z))
    for _ in range(_MOEBIUS_STEPS):
        wt = w / den
        a, b, c = np.linalg.lstsq(mat * wt[:, None], target * wt, rcond=None)[0]
        den = np.maximum(np.abs(c * z + 1.0), 1e-12)
    with np.errstate(divide="ignore", invalid="ignore"):
        out = (a * z_all + b) / (c * z_all + 1.0)
        far = a / c if abs(c) > 0 else np.inf
    return out, far


def _canonical(t):
    """Triangles rotated to start at their smallest corner (orientation kept), rows sorted."""
    t = smallest_first(np.asarray(t, dtype=np.int64))
    return t[np.lexsort(t.T[::-1])]


def point_spacing(x):
    """Each point's mean chord distance to its :data:`_SPACING_NEIGHBOURS` nearest, ``(n,)``."""
    from scipy.spatial import cKDTree

    k = min(_SPACING_NEIGHBOURS + 1, len(x))
    return cKDTree(x).query(x, k=k)[0][:, 1:].mean(axis=1)


def _sorted_rows(t):
    s = np.sort(t, axis=1)
    return s[np.lexsort(s.T[::-1])]


def lower_folds(x, p, normals, *, accept=None, options: MapOptions = DEFAULT_OPTIONS):
    """Rounds of :func:`flip_folds` (or :func:`anneal_flips`) on the Delaunay triangulation of
    ``x`` and :func:`realise`, each kept only when it lowers the count of folded Delaunay
    triangles and ``accept`` takes it. The rounds end where that triangulation leaves a point
    out (a realisation can put a point on a face of its hull): no flip of it can be realised.

    Parameters
    ----------
    x : (n, 3) float64
        Unit vectors, the map.
    p, normals : (n, 3) float64
        3D positions and surfel normals.
    accept : callable, optional
        ``accept(y) -> bool`` for a realisation ``y`` (an ``(n, 3)`` map): whether it may
        replace the map (:func:`surfidx.sphere.parameterize` passes a bound on the loss of
        resampling quality). Default: the geometric bound :data:`MIN_SPACING_RATIO` on the
        crowding of every point's neighbours, measured from ``x``.
    options : MapOptions
        ``realise_rounds``: most flip-and-realise rounds. ``flip_ladder``: the flips tried in
        turn. ``anneal_steps``, ``anneal_temperature``: the annealed search
        (:func:`anneal_flips`) from the flips of a rung of any flips, before they are realised
        alone (0 steps: none); two of its triangulations at most are realised per round
        (:func:`_annealed`). Once ``accept`` refuses an annealed triangulation, the later
        rounds do not anneal: the map has changed since by milder flips only, and their
        annealed triangulations would be refused as well, each after a circle pattern and a
        check.

    Returns
    -------
    x : (n, 3) float64
    info : dict
        ``folds_before``, ``folds``, ``rounds`` (kept), ``refused`` (realisations that
        ``accept`` refused), ``annealed`` (rounds that kept an annealed triangulation),
        ``annealing`` (annealed searches run).
    """
    tri = hull_triangles(x)
    bad = against_normals(p, normals, tri)
    mirror = mirrored(bad)
    folds = int((bad ^ mirror).sum())
    info = {"folds_before": folds, "folds": folds, "rounds": 0, "refused": 0, "annealed": 0,
            "annealing": 0}
    if accept is None:
        spacing = point_spacing(x)    # the rounds together may crowd a point this much at most

        def accept(y):
            return bool(np.min(point_spacing(y) / spacing) >= MIN_SPACING_RATIO)

    anneal = options.anneal_steps > 0
    for _ in range(options.realise_rounds):
        if not folds or not _spans(tri, len(x)):
            break
        y = None
        # flips with no realisation, or whose realisation is refused: milder ones
        for convex, limit in options.flip_ladder:
            flipped, left = flip_folds(tri, p, normals, x, convex=convex, max_violation=limit)
            tries = [(flipped, left, False)]
            if anneal and not convex and limit == np.inf:
                info["annealing"] += 1
                tries = [(t, k, True) for t, k in _annealed(
                    flipped, left, p, normals, x, options.anneal_steps,
                    options.anneal_temperature)] + tries
            for cand, cleft, annealed in tries:
                y = _circle_pattern(x, cand) if cleft < folds else None
                if y is not None:
                    # the folds of the hull itself: it is ``cand`` but for triangles too thin
                    # for double precision, which can come out flipped
                    hull = hull_triangles(y)
                    got = int((against_normals(p, normals, hull) ^ mirror).sum())
                    if got < folds:
                        if accept(y):
                            break
                        info["refused"] += 1
                        # the rounds after keep the map of milder flips, whose annealed
                        # triangulations change the limbs' scale as much: no more annealing
                        anneal = anneal and not annealed
                y = None
            if y is not None:
                break
        if y is None:
            break
        x, tri, folds = y, hull, got
        info["folds"], info["rounds"] = folds, info["rounds"] + 1
        info["annealed"] += int(annealed)
    return x, info


def _annealed(flipped, left, p, normals, x, steps, temperature):
    """The triangulations of :func:`anneal_flips` from ``flipped`` (``left`` folds) that
    :func:`lower_folds` tries to realise, in turn: the one with the fewest folds, then the first
    found with at most halfway between that and ``left``. More flips turn more mesh faces over
    in the realisation, which then fails or is refused more often, hence the second, milder
    one. Empty when ``flipped`` has no fold left."""
    found = anneal_flips(flipped, p, normals, x, steps=steps,
                         temperature=temperature) if left else []
    if not found:
        return []
    best = found[-1]
    half = next(f for f in found if f[1] <= (best[1] + left) // 2)
    return [best] if half is best else [best, half]
