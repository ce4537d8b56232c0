"""Vertex-by-vertex relaxation of the balancing energy that keeps a spherical embedding embedded.

The balancing energy ``Σ A (‖J‖² / det + λ (det + 1 / det))`` (:mod:`surfidx.sphere.balance`)
has a barrier at every degenerate triangle. A global L-BFGS step is as long as its stiffest
triangle allows: where a few triangles are squeezed (vertices inserted into thin kernels by the
prolongation, or limbs still short of area) the line search halves it to nothing and the rest of
the mesh waits. A sweep of nonlinear Gauss–Seidel moves one vertex at a time, its neighbours
held, against the gradient of its star's energy: the squeezed stars open up locally, in one
pass over the mesh, and the global steps that follow are long again.

Each move is along the great circle through the vertex in the direction of steepest descent,
its length halved until the star's energy falls by the Armijo fraction; the accepted length,
doubled, is the next sweep's first try for that vertex. The sweeps stop early when one of them
lowers the mesh's energy by less than a given fraction of it (a move lowers the whole energy by
what it lowers its star's, so the fall is summed move by move): a sweep that gains that little
is followed by ones that gain less. A triangle's orientation
``det[q, b, c]`` is linear in the unnormalised vertex ``q``, so a star counter-clockwise at both
ends of a move is counter-clockwise along it: an embedding stays an embedding at every move.
Vertices are visited in index order, so the result depends on the input alone.
"""

from __future__ import annotations

import numpy as np

from ..jit import numba
from .decimate import _vertex_faces

__all__ = ["Relaxation"]

_ARMIJO = 1e-4        # a move must lower the star's energy by this share of its first-order fall
_HALVINGS = 12        # halvings of a vertex's move before it stays put this sweep
_FIRST_MOVE = 0.25    # a vertex's first move is at most this share of its shortest star edge


@numba.njit(cache=True)
def _projected_area(a0, a1, a2, b0, b1, b2, e0, e1, e2):  # pragma: no cover - compiled
    """Signed area of the triangle ``(a, b, e)`` projected on the tangent plane at its centroid
    direction ``n`` (it vanishes when the corners fall on one great circle, where the plain
    area ``|c| / 2`` does not), with ``c = (b - a) × (e - a)``, ``n`` and the centroid sum's
    length ``sl``: ``(area, c0, c1, c2, n0, n1, n2, sl)``."""
    u0, u1, u2 = b0 - a0, b1 - a1, b2 - a2
    v0, v1, v2 = e0 - a0, e1 - a1, e2 - a2
    c0, c1, c2 = u1 * v2 - u2 * v1, u2 * v0 - u0 * v2, u0 * v1 - u1 * v0
    s0, s1, s2 = a0 + b0 + e0, a1 + b1 + e1, a2 + b2 + e2
    sl = np.sqrt(s0 * s0 + s1 * s1 + s2 * s2)
    n0, n1, n2 = s0 / sl, s1 / sl, s2 / sl
    return 0.5 * (c0 * n0 + c1 * n1 + c2 * n2), c0, c1, c2, n0, n1, n2, sl


@numba.njit(cache=True)
def _star(x, v, q0, q1, q2, ptr, idx, f, cot, area3, lam, radius, grad, g):  # pragma: no cover
    """Energy of the star of vertex ``v`` placed at the unit vector ``q``, its neighbours at
    ``x``; with ``grad``, its gradient with respect to ``q`` (unnormalised, as in
    :func:`surfidx.sphere.balance._energy_kernel`) added to ``g``. Infinite when a triangle of the
    star is not counter-clockwise."""
    e = 0.0
    a0, a1, a2 = radius * q0, radius * q1, radius * q2
    for j in range(ptr[v], ptr[v + 1]):
        t = idx[j]
        k = 0 if f[t, 0] == v else (1 if f[t, 1] == v else 2)
        kb, kc = (k + 1) % 3, (k + 2) % 3
        ib, ic = f[t, kb], f[t, kc]
        b0, b1, b2 = radius * x[ib, 0], radius * x[ib, 1], radius * x[ib, 2]
        e0, e1, e2 = radius * x[ic, 0], radius * x[ic, 1], radius * x[ic, 2]
        ar, c0, c1, c2, n0, n1, n2, sl = _projected_area(a0, a1, a2, b0, b1, b2, e0, e1, e2)
        if ar <= 0.0:
            return np.inf
        u0, u1, u2 = b0 - a0, b1 - a1, b2 - a2
        w0, w1, w2 = e0 - b0, e1 - b1, e2 - b2
        x0, x1, x2 = a0 - e0, a1 - e1, a2 - e2
        ct0, ct1, ct2 = cot[t, k], cot[t, kb], cot[t, kc]
        d = 0.5 * (ct0 * (w0 * w0 + w1 * w1 + w2 * w2) + ct1 * (x0 * x0 + x1 * x1 + x2 * x2)
                   + ct2 * (u0 * u0 + u1 * u1 + u2 * u2))
        det = ar / area3[t]
        et = (d + lam * area3[t] * (det * det + 1.0)) / det
        e += et
        if grad:
            rk1 = radius / det
            rk2 = radius * (2.0 * lam - et / det / area3[t])
            cu = c0 * n0 + c1 * n1 + c2 * n2
            g[0] += rk1 * (ct1 * x0 - ct2 * u0) + rk2 * (
                0.5 * (n1 * w2 - n2 * w1) + 0.5 * (c0 - cu * n0) / sl)
            g[1] += rk1 * (ct1 * x1 - ct2 * u1) + rk2 * (
                0.5 * (n2 * w0 - n0 * w2) + 0.5 * (c1 - cu * n1) / sl)
            g[2] += rk1 * (ct1 * x2 - ct2 * u2) + rk2 * (
                0.5 * (n0 * w1 - n1 * w0) + 0.5 * (c2 - cu * n2) / sl)
    return e


@numba.njit(cache=True)
def _shortest_edge(x, v, ptr, idx, f):  # pragma: no cover - compiled
    """Length of the shortest chord from vertex ``v`` to a neighbour."""
    best = np.inf
    for j in range(ptr[v], ptr[v + 1]):
        t = idx[j]
        for c in range(3):
            w = f[t, c]
            if w != v:
                d = np.sqrt((x[w, 0] - x[v, 0]) ** 2 + (x[w, 1] - x[v, 1]) ** 2
                            + (x[w, 2] - x[v, 2]) ** 2)
                best = min(best, d)
    return best


@numba.njit(cache=True)
def _total(x, f, cot, area3, lam, radius):  # pragma: no cover - compiled
    """The mesh's energy at the unit vectors ``x`` (infinite when a triangle is not
    counter-clockwise): the sum over triangles of :func:`_star`'s terms."""
    e = 0.0
    for t in range(f.shape[0]):
        i0, i1, i2 = f[t, 0], f[t, 1], f[t, 2]
        a0, a1, a2 = radius * x[i0, 0], radius * x[i0, 1], radius * x[i0, 2]
        b0, b1, b2 = radius * x[i1, 0], radius * x[i1, 1], radius * x[i1, 2]
        e0, e1, e2 = radius * x[i2, 0], radius * x[i2, 1], radius * x[i2, 2]
        ar = _projected_area(a0, a1, a2, b0, b1, b2, e0, e1, e2)[0]
        if ar <= 0.0:
            return np.inf
        d = 0.5 * (cot[t, 0] * ((e0 - b0) ** 2 + (e1 - b1) ** 2 + (e2 - b2) ** 2)
                   + cot[t, 1] * ((a0 - e0) ** 2 + (a1 - e1) ** 2 + (a2 - e2) ** 2)
                   + cot[t, 2] * ((b0 - a0) ** 2 + (b1 - a1) ** 2 + (b2 - a2) ** 2))
        det = ar / area3[t]
        e += (d + lam * area3[t] * (det * det + 1.0)) / det
    return e


@numba.njit(cache=True)
def _sweeps(x, ptr, idx, f, cot, area3, lam, radius, sweeps, reach, total, tol):  # pragma: no cover
    """At most ``sweeps`` passes over the vertices in index order, each vertex moved once per
    pass (in place); ``reach[v]``, the length of ``v``'s next first try (0: not yet known), is
    updated. ``total`` is the mesh's energy at ``x``: the passes stop after one that lowers it
    by less than the fraction ``tol`` (``tol <= 0``: never). Returns the number of moves and of
    passes."""
    g = np.zeros(3)
    moves = 0
    passes = 0
    for _ in range(sweeps):
        fall = 0.0
        passes += 1
        for v in range(x.shape[0]):
            q0, q1, q2 = x[v, 0], x[v, 1], x[v, 2]
            g[0] = g[1] = g[2] = 0.0
            e = _star(x, v, q0, q1, q2, ptr, idx, f, cot, area3, lam, radius, True, g)
            if not np.isfinite(e):
                continue
            dot = g[0] * q0 + g[1] * q1 + g[2] * q2
            g0, g1, g2 = g[0] - dot * q0, g[1] - dot * q1, g[2] - dot * q2
            gn = np.sqrt(g0 * g0 + g1 * g1 + g2 * g2)
            if gn == 0.0:
                continue
            length = reach[v]
            if length == 0.0:
                length = _FIRST_MOVE * _shortest_edge(x, v, ptr, idx, f)
            for _ in range(_HALVINGS):
                h = length / gn
                y0, y1, y2 = q0 - h * g0, q1 - h * g1, q2 - h * g2
                r = np.sqrt(y0 * y0 + y1 * y1 + y2 * y2)
                y0, y1, y2 = y0 / r, y1 / r, y2 / r
                e2 = _star(x, v, y0, y1, y2, ptr, idx, f, cot, area3, lam, radius, False, g)
                if e2 <= e - _ARMIJO * h * gn * gn:
                    x[v, 0], x[v, 1], x[v, 2] = y0, y1, y2
                    moves += 1
                    fall += e - e2
                    length *= 2.0
                    break
                length *= 0.5
            reach[v] = length
        if fall < tol * total:
            break
        total -= fall
    return moves, passes


class Relaxation:
    """Sweeps of vertex-by-vertex relaxation of one mesh's balancing energy.

    Parameters
    ----------
    f : (m, 3) int64
        The mesh's triangles, counter-clockwise seen from outside.
    cot : (m, 3) float64
        Cotangents of the 3D triangles' corner angles.
    area3 : (m,) float64
        Their 3D areas.
    radius : float
        Radius of the sphere with the surface's area (the energy compares areas at that scale).
    lam : float
        Area weight ``λ`` of the energy.
    n : int
        Vertex count.

    Notes
    -----
    The object keeps each vertex's last accepted move length, so sweeps split over several
    calls go on where the last call stopped, and counts the sweeps run in :attr:`passes`.
    """

    def __init__(self, f, cot, area3, radius: float, lam: float, n: int):
        self.f = np.ascontiguousarray(f, dtype=np.int64)
        self.cot = np.ascontiguousarray(cot, dtype=np.float64)
        self.area3 = np.ascontiguousarray(area3, dtype=np.float64)
        self.radius, self.lam = float(radius), float(lam)
        self.ptr, self.idx = _vertex_faces(self.f, n)
        self.reach = np.zeros(n)
        self.passes = 0

    def __call__(self, x, sweeps: int, *, tol: float = 0.0):
        """Relax the embedding ``x`` ``(n, 3)`` (unit vectors) for at most ``sweeps`` sweeps,
        stopping after the first that lowers the mesh's energy by less than the fraction
        ``tol`` of it (``tol <= 0``: all ``sweeps``).

        Returns
        -------
        x : (n, 3) float64
            A relaxed copy, an embedding whenever ``x`` is one.
        moves : int
            Vertex moves taken.
        """
        y = np.array(x, dtype=np.float64, order="C")
        total = _total(y, self.f, self.cot, self.area3, self.lam, self.radius) if tol > 0 \
            else 0.0
        if not np.isfinite(total):      # not an embedding: no fraction of it to compare with
            total, tol = 0.0, 0.0
        moves, passes = _sweeps(y, self.ptr, self.idx, self.f, self.cot, self.area3, self.lam,
                                self.radius, int(sweeps), self.reach, float(total), float(tol))
        self.passes += int(passes)
        return y, int(moves)
