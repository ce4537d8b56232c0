"""The single-level map: a Tutte embedding, area reweighting, balancing; Möbius normalisation.

a. One vertex is punctured (the one of largest area share, or one far from it when that start
   is as clean, :func:`punctures`) and the rest is mapped into the plane by a Tutte embedding
   with positive mean-value weights (Floater 2003), its 1-ring fixed on the unit circle (spaced
   by edge length). Tutte's theorem (Floater's extension to any positive weights) makes the
   planar map an embedding. It is lifted to the sphere by the inverse stereographic projection
   (the punctured vertex at the north pole) of the plane scaled by ``2^-k``, the smallest ``k``
   at which every chord triangle is counter-clockwise: a triangle whose circumcircle holds the
   origin's antipode in the plane would turn over, and as the scale shrinks the lift tends to
   an affine map near the south pole, under which none does.
b. Area reweighting (after Yoshizawa, Belyaev & Seidel 2004): the weights toward each vertex are
   multiplied by ``exp(-gamma * s)``, ``s`` the graph-smoothed log ratio of 3D to spherical area
   share around it, and the system is solved again. Every iterate is again a positive-weight
   Tutte embedding; a step is kept only when it lowers the area distortion and inverts no mesh
   triangle; otherwise ``gamma`` is halved.
c. Balancing (:mod:`surfidx.sphere.balance`), which keeps the embedding.

The Möbius normalisation (:func:`centre`) ends this map and every level of the multilevel one:
the automorphism of the sphere moving the area-weighted centre of mass of the vertices to the
origin (Gu et al. 2004; Praun & Hoppe 2003), in halved steps that never invert a mesh triangle.
It fixes the three non-rotational Möbius degrees of freedom: the map is canonical up to a
rotation.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import dijkstra

from ..errors import InputError
from ..geometry.unitsphere import mobius, orientation, triangle_areas
from ..geometry.surfels import SurfelSet
from .balance import balance as balance_map
from .options import MapOptions
from .surface import areas3, oriented_faces, vertex_areas

__all__ = ["tutte_map", "single_level_steps", "centre"]

_TINY = 1e-300           # denominators and logs stay finite
_HUGE = 1e300            # ... and log arguments below this
_WEIGHT_FLOOR = 1e-6     # mean-value weights are floored at this share of their row's mean
_FAR_HOPS = 0.5          # the far puncture is at least this share of the largest hop distance away
_TIE_DIGITS = 9          # area shares are compared rounded to this many digits (ties by index)
_STEP_CLIP = 10.0        # the log area ratio of a reweighting step is clipped to ±this
_CENTRE_TOL = 1e-10      # the normalisation stops once the centre of mass is this near the origin
_CENTRE_MIN_STEP = 1e-3  # ... or once its halved step is this short
_CENTRE_MAX_STEP = 0.5   # the longest Möbius step (|a|; the ball's radius is 1)
_LIFT_HALVINGS = 60      # the plane is scaled by 2^-k, k < this, before the lift to the sphere


def _mean_value_weights(p, f):
    n = len(p)
    rows, cols, vals = [], [], []
    for k in range(3):
        i, j, l = f[:, k], f[:, (k + 1) % 3], f[:, (k + 2) % 3]
        e1, e2 = p[j] - p[i], p[l] - p[i]
        n1, n2 = np.linalg.norm(e1, axis=1), np.linalg.norm(e2, axis=1)
        c = np.clip(np.einsum("ij,ij->i", e1, e2) / np.maximum(n1 * n2, _TINY), -1.0, 1.0)
        t = np.tan(0.5 * np.arccos(c))
        rows += [i, i]
        cols += [j, l]
        vals += [t / np.maximum(n1, _TINY), t / np.maximum(n2, _TINY)]
    v = np.concatenate(vals)
    v = np.where(np.isfinite(v) & (v > 0), v, 0.0)
    w = sp.csr_matrix((v, (np.concatenate(rows), np.concatenate(cols))), shape=(n, n))
    w.sum_duplicates()
    rs = np.asarray(w.sum(axis=1)).ravel()
    # strictly positive weights (Floater's condition): floor tiny ones relative to the row
    w.data = np.maximum(w.data, _WEIGHT_FLOOR * np.repeat(rs / np.maximum(np.diff(w.indptr), 1),
                                                          np.diff(w.indptr)))
    return w


def punctures(adj, vertex_area):
    """Candidate vertices to puncture: the one of largest area share, and the largest area share
    among the vertices at least half the largest hop distance away from it. Ties are broken by
    index, so the choice depends on intrinsic quantities only."""
    key = np.round(vertex_area / vertex_area.max(), _TIE_DIGITS)
    v = int(np.flatnonzero(key == key.max())[0])
    hops = dijkstra(adj, indices=v, unweighted=True)
    cand = np.flatnonzero(hops >= _FAR_HOPS * hops[np.isfinite(hops)].max())
    key = np.round(vertex_area[cand] / vertex_area[cand].max(), _TIE_DIGITS)
    return v, int(cand[np.flatnonzero(key == key.max())[0]])


def _ring(f, v):
    """The 1-ring of vertex ``v`` in counter-clockwise order."""
    fv = f[np.any(f == v, axis=1)]
    k = np.argmax(fv == v, axis=1)
    a = fv[np.arange(len(fv)), (k + 1) % 3]
    b = fv[np.arange(len(fv)), (k + 2) % 3]
    nxt = dict(zip(a.tolist(), b.tolist()))
    ring = [int(a[0])]
    for _ in range(len(a) - 1):
        ring.append(nxt[ring[-1]])
    return np.array(ring, dtype=np.int64)


class _TutteSystem:
    """Tutte's linear system of the mesh punctured at one vertex, its 1-ring fixed on the unit
    circle (spaced by edge length, each at least 1 % of their mean); the punctured vertex goes to infinity (the north pole)."""

    def __init__(self, p, f, vertex, ring):
        n = len(p)
        self.n, self.vertex, self.ring = n, vertex, ring
        self.inner = np.setdiff1d(np.arange(n), np.concatenate([[vertex], ring]))
        el = np.linalg.norm(p[ring] - p[np.roll(ring, -1)], axis=1)
        # coincident ring vertices (repeated scan points) would share a place on the circle
        el = np.maximum(el, 0.01 * el.mean()) if el.sum() > 0 else np.ones(len(ring))
        ang = np.concatenate([[0.0], np.cumsum(el)[:-1]]) / el.sum() * 2 * np.pi
        self.ub = np.column_stack([np.cos(ang), np.sin(ang)])
        self.mirror = None

    def solve(self, w):
        from scipy.sparse.linalg import splu

        rs = np.asarray(w.sum(axis=1)).ravel()
        lap = (sp.diags(rs) - w).tocsr()
        rows = lap[self.inner]
        a = rows[:, self.inner].tocsc()
        b = rows[:, self.ring]
        u = np.zeros((self.n, 2))
        u[self.ring] = self.ub
        # a diagonally dominant M-matrix: no pivoting needed
        lu = splu(a, permc_spec="COLAMD", diag_pivot_thresh=0.0)
        u[self.inner] = lu.solve(np.asarray(-(b @ self.ub)))
        return u

    def sphere(self, u, f):
        """Inverse stereographic projection of ``u`` scaled by the largest ``2^-k`` at which no
        chord triangle turns over, oriented so that the mesh keeps its orientation."""
        for k in range(_LIFT_HALVINGS):
            v = u * 0.5 ** k
            r2 = (v ** 2).sum(axis=1)
            x = np.column_stack([2 * v[:, 0], 2 * v[:, 1], r2 - 1.0]) / (1.0 + r2)[:, None]
            x[self.vertex] = [0.0, 0.0, 1.0]
            if self.mirror is None:
                self.mirror = bool(np.sum(orientation(x, f)) < 0)
            if self.mirror:
                x[:, 0] *= -1.0
            if not np.any(orientation(x, f) <= 0):
                break
        return x


def centre(x, weights, f, *, iterations: int):
    """Möbius normalisation: move the ``weights``-weighted centre of mass of ``x`` to the origin.

    Newton steps: near ``a = 0`` the automorphism sending ``a`` to the origin moves each point
    by ``-2 (I - x xᵀ) a``, so the centre of mass ``c`` moves by ``-2 (I - M) a`` with ``M =
    Σ w x xᵀ``, and ``a = (2 (I - M))⁻¹ c`` cancels it to first order. A step is halved while
    it would invert more mesh triangles on the sphere than were inverted before; at most
    ``iterations`` steps."""
    w = weights / weights.sum()
    inverted = np.count_nonzero(orientation(x, f) <= 0)   # none, unless untangling left some
    for _ in range(iterations):
        c = w @ x
        if np.linalg.norm(c) < _CENTRE_TOL:
            break
        a = np.linalg.solve(2.0 * (np.eye(3) - (x * w[:, None]).T @ x), c)
        if not np.linalg.norm(a) < _CENTRE_MAX_STEP:     # far from the origin: a bounded step
            a *= _CENTRE_MAX_STEP / np.linalg.norm(a)
        h = 1.0
        while h > _CENTRE_MIN_STEP:
            y = mobius(x, h * a)
            if np.count_nonzero(orientation(y, f) <= 0) <= inverted:
                break
            h *= 0.5
        else:
            break
        x = y
    return x


def single_level_steps(n: int, options: MapOptions) -> int:
    """Balancing steps of a single-level map of ``n`` vertices: ``single_level_work / n``,
    clipped to ``[single_level_min_steps, single_level_max_steps]``."""
    return int(min(options.single_level_max_steps,
                   max(options.single_level_min_steps, options.single_level_work // max(n, 1))))


def tutte_map(surfels: SurfelSet, *, options: MapOptions, iterations: int, gamma: float,
              balance: bool = True, faces=None):
    """Single-level map: Tutte embedding, at most ``iterations`` reweighting steps, then (with
    ``balance``) distortion balancing for :func:`single_level_steps` steps;
    ``faces``: those of :func:`oriented_faces`, when already computed. Returns the map and its
    figures (``mesh_folds``, ``mesh_area_distortion``, ``iterations``, ``punctured_vertex``,
    ``balance_steps`` and, balanced, ``balance_energy``)."""
    f = oriented_faces(surfels) if faces is None else faces
    p = surfels.positions
    n = len(p)
    a3 = areas3(p, f)
    if not a3.sum() > 0:
        raise InputError("the surface has zero area")
    share3 = a3 / a3.sum()
    va = vertex_areas(f, a3, n)
    w0 = _mean_value_weights(p, f)
    adj = (w0 > 0).astype(np.float64)
    adj = adj + adj.T + sp.identity(n, format="csr")
    system = None

    def spread(x):
        """Area-weighted RMS of the log ratio of 3D to sphere area share over the faces."""
        asph = np.abs(triangle_areas(x, f))
        lr = np.log(np.clip(share3 / np.maximum(asph / asph.sum(), _TINY), _TINY, _HUGE))
        return float(np.sqrt(np.average(lr ** 2, weights=share3)))

    def evaluate(lw):
        x = system.sphere(system.solve(w0 @ sp.diags(np.exp(lw))), f)
        x = centre(x, va, f, iterations=options.centre_iterations)
        return x, spread(x), int(np.count_nonzero(orientation(x, f) <= 0))

    # log column weights: the weights toward a vertex whose neighbourhood is squeezed on the
    # sphere (3D share > sphere share) are lowered, so its neighbours move away from it and its
    # region grows; every iterate is a Tutte embedding
    avg = sp.diags(1.0 / np.asarray(adj.sum(axis=1)).ravel()) @ adj
    lw = np.zeros(n)
    # puncturing at the largest share can let the balancing collapse the neighbourhood of the
    # fixed 1-ring: the far candidate is punctured
    vertex = punctures(adj, va)[-1]
    system = _TutteSystem(p, f, vertex, _ring(f, vertex))
    x, sd, neg = evaluate(lw)
    g = gamma
    accepted = 0
    for _ in range(iterations):
        asph = np.bincount(f.ravel(), np.repeat(np.abs(triangle_areas(x, f)), 3), minlength=n)
        step = np.clip(np.log(va / va.sum() / np.maximum(asph / asph.sum(), _TINY)),
                       -_STEP_CLIP, _STEP_CLIP)
        for _ in range(options.reweight_smoothing):
            step = avg @ step
        improved = False
        while g > options.reweight_min_gamma:
            lw2 = lw - g * step
            x2, sd2, neg2 = evaluate(lw2)
            if neg2 <= neg and sd2 < sd:
                lw, x, sd, neg = lw2, x2, sd2, neg2
                improved = True
                accepted += 1
                g = min(gamma, options.reweight_growth * g)
                break
            g *= 0.5
        if not improved:
            break
    x = x / np.linalg.norm(x, axis=1)[:, None]
    if not balance:
        neg = int(np.count_nonzero(orientation(x, f) <= 0))
        return x, {"mesh_folds": neg, "mesh_area_distortion": sd, "iterations": accepted,
                   "punctured_vertex": vertex, "balance_steps": 0}
    x_start, sd_start = x, sd
    x, binfo = balance_map(x, p, f, iterations=single_level_steps(n, options),
                           sweeps=options.relax_sweeps, rounds=options.level_rounds,
                           sweep_tol=options.sweep_tol, lam=options.energy_lambda,
                           max_cot=np.inf)
    x = centre(x, va, f, iterations=options.centre_iterations)
    sd = spread(x)
    if sd > sd_start:
        # from a deeply squeezed start the steps may grow the few tiniest triangles at the
        # expense of the bulk: keep the start, whose area spread is lower
        x, sd = x_start, sd_start
        binfo = dict(binfo, steps=0, energy=binfo["energy_start"])
    neg = int(np.count_nonzero(orientation(x, f) <= 0))
    return x, {"mesh_folds": neg, "mesh_area_distortion": sd, "iterations": accepted,
               "punctured_vertex": vertex, "balance_steps": binfo["steps"],
               "balance_energy": float(binfo["energy"])}
