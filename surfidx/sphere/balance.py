"""Distortion balancing of a spherical embedding of a mesh that keeps it an embedding.

Two energies of the piecewise-linear map from the 3D triangles to the chord triangles of the sphere
(scaled to the surface's area), with ``J`` a triangle's Jacobian, ``det = a_t / A_t`` the ratio of
its image area to its 3D area and ``D_t = ½ Σ_i cot α_i |q_j − q_k|² = A_t ‖J_t‖²`` (cotangents
of its 3D angles):

* symmetric Dirichlet ``Σ A (‖J‖² + ‖J⁻¹‖²) = Σ D (1 + (A / a)²)`` (Smith & Schaefer 2015;
  Rabinovich et al. 2017): 4 per unit area for an isometry;
* conformal-plus-area ``Σ A (‖J‖² / det + λ (det + 1 / det))`` (Garanzha et al. 2021): smallest
  for a similarity of unit area ratio; λ weighs area against angle preservation.

Both grow without bound as an image triangle degenerates. L-BFGS over the unnormalised positions
``y`` (``x = y / |y|``) with a backtracking line search that takes a step only when every
triangle stays counter-clockwise along the whole segment (:func:`segment_embedded`: a
triangle's orientation ``det[y_a, y_b, y_c]`` is a cubic in the step, positive on an interval
exactly when it is at the interval's ends and at the cubic's critical points inside it; the
exact form of Smith & Schaefer's step bound). A map that starts embedded therefore stays
embedded at every iterate: its triangles never pass through a degenerate position, so the map
keeps covering the sphere once.
"""

from __future__ import annotations

from ..jit import numba
import numpy as np

from .relax import Relaxation, _projected_area

__all__ = ["balance", "segment_embedded", "inverted"]


def _cotangents(p, f, *, max_cot: float = 4.0):
    """Cotangents of each triangle's corner angles and its 3D area.

    Near-degenerate triangles (a cotangent beyond ``max_cot``: an angle under 14° or over 166°)
    have an ill-conditioned Jacobian that stalls the optimisation; their shape (not their area)
    is blended halfway towards the equilateral triangle, twice if needed. Edge-length vectors of
    triangles form a convex cone, so the blend is always a valid triangle.
    """
    a, b, c = p[f[:, 0]], p[f[:, 1]], p[f[:, 2]]
    area = 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)
    floor = max(float(np.median(area)) * 1e-8, 1e-300)
    lens = np.column_stack([np.linalg.norm(c - b, axis=1), np.linalg.norm(a - c, axis=1),
                            np.linalg.norm(b - a, axis=1)])   # edge opposite corner k

    def cots(ln):
        s = 0.5 * ln.sum(axis=1)
        heron = np.sqrt(np.clip(s * (s - ln[:, 0]) * (s - ln[:, 1]) * (s - ln[:, 2]), 0, None))
        ar = np.maximum(heron, floor)
        sq = ln ** 2
        tot = sq.sum(axis=1)[:, None]
        return (tot - 2 * sq) / (4 * ar[:, None])

    cot = cots(lens)
    for _ in range(2):
        bad = np.abs(cot).max(axis=1) > max_cot
        if not bad.any():
            break
        eq = np.sqrt(4 * np.maximum(area[bad], floor) / np.sqrt(3.0))
        lens[bad] = 0.5 * lens[bad] + 0.5 * eq[:, None]
        cot = cots(lens)
    # a sliver's image must not shrink to nothing either: its target area is floored at 1 % of
    # the median (a degenerate 3D triangle otherwise pins the line search at a barrier)
    return cot, np.maximum(area, 0.01 * float(np.median(area)))


_BLOCK = 256          # triangles whose terms one vectorised pass computes


@numba.njit(inline="always", error_model="numpy")
def _term(a0, a1, a2, b0, b1, b2, e0, e1, e2, ct0, ct1, ct2, area3, eps,
          lam):  # pragma: no cover - compiled
    """One triangle's projected area, energy term, gradient factors ``k1``, ``k2``, cross
    product ``c``, centroid direction ``n`` and centroid sum length ``sl`` (the operations of
    :func:`surfidx.sphere.relax._projected_area` and of the energy, in their order)."""
    u0, u1, u2 = b0 - a0, b1 - a1, b2 - a2
    v0, v1, v2 = e0 - a0, e1 - a1, e2 - a2
    c0, c1, c2 = u1 * v2 - u2 * v1, u2 * v0 - u0 * v2, u0 * v1 - u1 * v0
    s0, s1, s2 = a0 + b0 + e0, a1 + b1 + e1, a2 + b2 + e2
    sl = np.sqrt(s0 * s0 + s1 * s1 + s2 * s2)
    n0, n1, n2 = s0 / sl, s1 / sl, s2 / sl
    ar = 0.5 * (c0 * n0 + c1 * n1 + c2 * n2)
    w0, w1, w2 = e0 - b0, e1 - b1, e2 - b2
    x0, x1, x2 = a0 - e0, a1 - e1, a2 - e2
    z0, z1, z2 = b0 - a0, b1 - a1, b2 - a2
    d = 0.5 * ct0 * (w0 * w0 + w1 * w1 + w2 * w2)
    d += 0.5 * ct1 * (x0 * x0 + x1 * x1 + x2 * x2)
    d += 0.5 * ct2 * (z0 * z0 + z1 * z1 + z2 * z2)
    if eps < 0.0:
        r2 = (area3 / ar) ** 2
        et = d * (1.0 + r2)
        k1 = 1.0 + r2
        k2 = -2.0 * d * r2 / ar
    else:
        det = ar / area3
        et = (d + lam * area3 * (det * det + 1.0)) / det
        k1 = 1.0 / det
        k2 = 2.0 * lam - et / det / area3
    return ar, et, k1, k2, c0, c1, c2, n0, n1, n2, sl


@numba.njit(cache=True, error_model="numpy")
def _block_terms(p, ct, area3, eps, lam, nb, grad, ar_, et_, k1_, k2_, c_, n_,
                 sl_):  # pragma: no cover - compiled
    """The terms of ``nb`` triangles, their corners ``a, b, e`` in the rows of ``p`` (a's x,
    y, z, then b's, e's) and corner cotangents in those of ``ct``: projected area ``ar_`` and
    energy ``et_``; with ``grad``, the factors ``k1_``, ``k2_`` of its gradient, the cross
    product ``c_`` (3 rows), centroid direction ``n_`` (3 rows) and centroid sum length
    ``sl_`` too. Loops without branches over contiguous arrays, which the compiler vectorises:
    each triangle's operations are those of :func:`_term`, so every term has the same bits
    as one computed alone."""
    a0, a1, a2, b0, b1, b2, e0, e1, e2 = p[0], p[1], p[2], p[3], p[4], p[5], p[6], p[7], p[8]
    ct0, ct1, ct2 = ct[0], ct[1], ct[2]
    if grad:        # the geometry, then the energy: two loops vectorise where one did not
        for j in range(nb):
            u0, u1, u2 = b0[j] - a0[j], b1[j] - a1[j], b2[j] - a2[j]
            v0, v1, v2 = e0[j] - a0[j], e1[j] - a1[j], e2[j] - a2[j]
            c0, c1, c2 = u1 * v2 - u2 * v1, u2 * v0 - u0 * v2, u0 * v1 - u1 * v0
            s0, s1, s2 = a0[j] + b0[j] + e0[j], a1[j] + b1[j] + e1[j], a2[j] + b2[j] + e2[j]
            sl = np.sqrt(s0 * s0 + s1 * s1 + s2 * s2)
            n0, n1, n2 = s0 / sl, s1 / sl, s2 / sl
            ar_[j] = 0.5 * (c0 * n0 + c1 * n1 + c2 * n2)
            c_[0, j], c_[1, j], c_[2, j] = c0, c1, c2
            n_[0, j], n_[1, j], n_[2, j] = n0, n1, n2
            sl_[j] = sl
        if eps < 0.0:
            for j in range(nb):
                ar = ar_[j]
                w0, w1, w2 = e0[j] - b0[j], e1[j] - b1[j], e2[j] - b2[j]
                x0, x1, x2 = a0[j] - e0[j], a1[j] - e1[j], a2[j] - e2[j]
                z0, z1, z2 = b0[j] - a0[j], b1[j] - a1[j], b2[j] - a2[j]
                d = 0.5 * ct0[j] * (w0 * w0 + w1 * w1 + w2 * w2)
                d += 0.5 * ct1[j] * (x0 * x0 + x1 * x1 + x2 * x2)
                d += 0.5 * ct2[j] * (z0 * z0 + z1 * z1 + z2 * z2)
                r2 = (area3[j] / ar) ** 2
                et_[j] = d * (1.0 + r2)
                k1_[j] = 1.0 + r2
                k2_[j] = -2.0 * d * r2 / ar
        else:
            for j in range(nb):
                ar = ar_[j]
                w0, w1, w2 = e0[j] - b0[j], e1[j] - b1[j], e2[j] - b2[j]
                x0, x1, x2 = a0[j] - e0[j], a1[j] - e1[j], a2[j] - e2[j]
                z0, z1, z2 = b0[j] - a0[j], b1[j] - a1[j], b2[j] - a2[j]
                d = 0.5 * ct0[j] * (w0 * w0 + w1 * w1 + w2 * w2)
                d += 0.5 * ct1[j] * (x0 * x0 + x1 * x1 + x2 * x2)
                d += 0.5 * ct2[j] * (z0 * z0 + z1 * z1 + z2 * z2)
                det = ar / area3[j]
                et = (d + lam * area3[j] * (det * det + 1.0)) / det
                et_[j] = et
                k1_[j] = 1.0 / det
                k2_[j] = 2.0 * lam - et / det / area3[j]
    elif eps < 0.0:
        for j in range(nb):
            ar_[j], et_[j] = _term(a0[j], a1[j], a2[j], b0[j], b1[j], b2[j], e0[j], e1[j],
                                   e2[j], ct0[j], ct1[j], ct2[j], area3[j], -1.0, lam)[:2]
    else:
        for j in range(nb):
            ar_[j], et_[j] = _term(a0[j], a1[j], a2[j], b0[j], b1[j], b2[j], e0[j], e1[j],
                                   e2[j], ct0[j], ct1[j], ct2[j], area3[j], 0.0, lam)[:2]


@numba.njit(cache=True, error_model="numpy")
def _block_gradient(a0, a1, a2, b0, b1, b2, e0, e1, e2, cta, ctb, ctc, radius, nb, k1_, k2_,
                    c_, n_, sl_, g_):  # pragma: no cover - compiled
    """Each triangle's gradient terms at its corners ``g_`` (9 rows: corner 0's x, y, z, then
    corner 1's, corner 2's) from :func:`_block_terms`' figures, vectorised as it is.
    ``d ar / d q_k = 1/2 u x (q_l - q_j) + 1/2 (c - (c.u) u) / |s|``, ``(q_l - q_j)`` the edge
    opposite corner k; ``dD / d q_k``: its two edges, weighted by the far cotangents."""
    for j in range(nb):
        w0, w1, w2 = e0[j] - b0[j], e1[j] - b1[j], e2[j] - b2[j]
        x0, x1, x2 = a0[j] - e0[j], a1[j] - e1[j], a2[j] - e2[j]
        z0, z1, z2 = b0[j] - a0[j], b1[j] - a1[j], b2[j] - a2[j]
        c0, c1, c2 = c_[0, j], c_[1, j], c_[2, j]
        n0, n1, n2 = n_[0, j], n_[1, j], n_[2, j]
        sl = sl_[j]
        ct0, ct1, ct2 = cta[j], ctb[j], ctc[j]
        cu = c0 * n0 + c1 * n1 + c2 * n2
        h0 = 0.5 * (c0 - cu * n0) / sl
        h1 = 0.5 * (c1 - cu * n1) / sl
        h2 = 0.5 * (c2 - cu * n2) / sl
        rk1, rk2 = radius * k1_[j], radius * k2_[j]
        g_[0, j] = rk1 * (ct1 * x0 - ct2 * z0) + rk2 * (0.5 * (n1 * w2 - n2 * w1) + h0)
        g_[1, j] = rk1 * (ct1 * x1 - ct2 * z1) + rk2 * (0.5 * (n2 * w0 - n0 * w2) + h1)
        g_[2, j] = rk1 * (ct1 * x2 - ct2 * z2) + rk2 * (0.5 * (n0 * w1 - n1 * w0) + h2)
        g_[3, j] = rk1 * (ct2 * z0 - ct0 * w0) + rk2 * (0.5 * (n1 * x2 - n2 * x1) + h0)
        g_[4, j] = rk1 * (ct2 * z1 - ct0 * w1) + rk2 * (0.5 * (n2 * x0 - n0 * x2) + h1)
        g_[5, j] = rk1 * (ct2 * z2 - ct0 * w2) + rk2 * (0.5 * (n0 * x1 - n1 * x0) + h2)
        g_[6, j] = rk1 * (ct0 * w0 - ct1 * x0) + rk2 * (0.5 * (n1 * z2 - n2 * z1) + h0)
        g_[7, j] = rk1 * (ct0 * w1 - ct1 * x1) + rk2 * (0.5 * (n2 * z0 - n0 * z2) + h1)
        g_[8, j] = rk1 * (ct0 * w2 - ct1 * x2) + rk2 * (0.5 * (n0 * z1 - n1 * z0) + h2)


@numba.njit(cache=True)
def _energy_kernel(y, f, cot, area3, radius, grad, eps, lam, bound, hint, q, u, rr,
                   fresh):  # pragma: no cover - compiled
    """Energy and gradient, infinite when a triangle is not counter-clockwise. ``eps < 0``: the
    symmetric Dirichlet energy; ``eps >= 0``: ``A (‖J‖² / det + lam (det + 1 / det))``
    (Garanzha et al. 2021). ``D = A ‖J‖²`` (sum of cotangent-weighted squared image edge
    lengths / 2).
    Corners ``a, b, c`` of a triangle; its edge vectors ``w = c - b``, ``x = a - c``,
    ``z = b - a`` lie opposite corners 0, 1, 2.

    The triangles go in blocks: their corners are gathered, their terms computed by the
    vectorised :func:`_block_terms` (and :func:`_block_gradient`), then summed (and the
    gradient terms added to the corners) one by one in triangle order.

    Without ``grad``, the sum stops at the first partial sum above ``bound`` and returns it:
    every term is positive, so the energy is above ``bound`` too. ``hint[0]``: the triangle
    that last was not counter-clockwise, tested first (a line search's shortened trials
    mostly fail at the same triangle), and set to the one found. ``q``, ``u`` ``(n, 3)`` and
    ``rr`` ``(n,)``: the image points ``radius y / |y|``, the unit vectors ``y / |y|`` and the
    lengths ``|y|``, computed into them when ``fresh``, else read (those of the last call)."""
    n = y.shape[0]
    m = f.shape[0]
    if fresh and not grad and 0 <= hint[0] < m:
        t = hint[0]
        qa = np.empty(9)
        for k in range(3):
            i = f[t, k]
            r = np.sqrt(y[i, 0] ** 2 + y[i, 1] ** 2 + y[i, 2] ** 2)
            for c in range(3):
                qa[3 * k + c] = radius * (y[i, c] / r)
        if _projected_area(qa[0], qa[1], qa[2], qa[3], qa[4], qa[5], qa[6], qa[7],
                           qa[8])[0] <= 0.0:
            return np.inf, np.zeros((0, 3))
    if fresh:
        for i in range(n):
            r = np.sqrt(y[i, 0] ** 2 + y[i, 1] ** 2 + y[i, 2] ** 2)
            rr[i] = r
            for c in range(3):
                uc = y[i, c] / r
                u[i, c] = uc
                q[i, c] = radius * uc
    g = np.zeros((n if grad else 0, 3))
    bs = _BLOCK
    corners = np.empty((9, bs))
    cots = np.empty((3, bs))
    ar_, et_, k1_, k2_, sl_ = (np.empty(bs), np.empty(bs), np.empty(bs), np.empty(bs),
                               np.empty(bs))
    c_, n_ = np.empty((3, bs)), np.empty((3, bs))
    g_ = np.empty((9, bs))
    e = 0.0
    for t0 in range(0, m, bs):
        nb = min(bs, m - t0)
        for j in range(nb):
            t = t0 + j
            for k in range(3):
                i = f[t, k]
                corners[3 * k, j] = q[i, 0]
                corners[3 * k + 1, j] = q[i, 1]
                corners[3 * k + 2, j] = q[i, 2]
                cots[k, j] = cot[t, k]
        _block_terms(corners, cots, area3[t0:t0 + nb], eps, lam, nb, grad, ar_, et_, k1_, k2_,
                     c_, n_, sl_)
        for j in range(nb):
            if ar_[j] <= 0.0:
                hint[0] = t0 + j
                return np.inf, g
            e += et_[j]
            if not grad and e > bound:
                return e, g
        if grad:
            _block_gradient(corners[0], corners[1], corners[2], corners[3], corners[4],
                            corners[5], corners[6], corners[7], corners[8], cots[0], cots[1],
                            cots[2], radius, nb, k1_, k2_, c_, n_, sl_, g_)
            for j in range(nb):
                t = t0 + j
                for k in range(3):
                    i = f[t, k]
                    g[i, 0] += g_[3 * k, j]
                    g[i, 1] += g_[3 * k + 1, j]
                    g[i, 2] += g_[3 * k + 2, j]
    if grad:        # the gradient with respect to y (x = y / |y|)
        for i in range(n):
            r = rr[i]
            x0, x1, x2 = u[i, 0], u[i, 1], u[i, 2]
            dot = g[i, 0] * x0 + g[i, 1] * x1 + g[i, 2] * x2
            g[i, 0] = (g[i, 0] - dot * x0) / r
            g[i, 1] = (g[i, 1] - dot * x1) / r
            g[i, 2] = (g[i, 2] - dot * x2) / r
    return e, g


@numba.njit(cache=True)
def _csr_apply(indptr, indices, data, x, out):  # pragma: no cover - compiled
    """``out = A x`` for the CSR matrix ``(indptr, indices, data)`` and ``x`` ``(n, k)``, each
    row's products added in the order of its entries (as scipy's ``csr_matvecs`` adds them),
    without scipy's per-call overhead."""
    for i in range(out.shape[0]):
        for c in range(out.shape[1]):
            out[i, c] = 0.0
        for jj in range(indptr[i], indptr[i + 1]):
            j = indices[jj]
            a = data[jj]
            for c in range(out.shape[1]):
                out[i, c] += a * x[j, c]


def _dot(a, b):
    """Dot product of two long vectors without BLAS (threaded BLAS dot products of this size
    are far slower on a loaded machine)."""
    return float(np.einsum("i,i->", a, b))


class Energy:
    """The energy of a spherical map of triangles ``f`` of the surface ``p`` and its gradient:
    the symmetric Dirichlet energy, or the conformal-plus-area energy once :attr:`eps` is 0.

    Parameters
    ----------
    p : ndarray of float64, shape (n, 3)
        The surface's points.
    f : ndarray of int, shape (m, 3)
        Its triangles.
    max_cot : float
        Bound of the cotangent weights.
    """

    def __init__(self, p, f, *, max_cot: float = 4.0):
        self.f = np.ascontiguousarray(f, dtype=np.int64)
        self.cot, self.area3 = _cotangents(p, f, max_cot=max_cot)
        self.radius = float(np.sqrt(self.area3.sum() / (4 * np.pi)))
        self.n = len(p)
        self.eps = -1.0     # < 0: symmetric Dirichlet; 0: conformal-plus-area (weight lam)
        self.lam = 0.5
        self._hint = np.full(1, -1, dtype=np.int64)   # the last triangle found clockwise
        self._scratch = None    # the kernel's normalisation of the last point

    def dets(self, y):
        """Each triangle's ratio of image to 3D area (negative: inverted), ``(m,)``."""
        x = y / np.linalg.norm(y, axis=1)[:, None] * self.radius
        a, b, c = x[self.f[:, 0]], x[self.f[:, 1]], x[self.f[:, 2]]
        s = a + b + c
        ar = 0.5 * np.einsum("ij,ij->i", np.cross(b - a, c - a), s) / np.linalg.norm(s, axis=1)
        return ar / self.area3

    def min_det(self, y):
        """Smallest ratio of image to 3D area over the triangles (negative: inverted)."""
        return float(self.dets(y).min())

    def preconditioner(self, *, shift: float, solver=None):
        """Solve and product with ``P = L + shift·mean(diag L)·I``, L the cotangent Laplacian of the 3D
        mesh (the Hessian of the energy's Dirichlet part at an isometry: the accelerated
        quadratic proxy of Kovalsky et al. 2016). Updates spread over whole limbs instead of
        creeping one ring per step. It depends on the 3D mesh alone: a proxy weighted by the
        start map's area ratios reaches the stop in fewer steps, but where it stops then depends
        on the start, and copies of a model get less alike descriptors. ``solver``
        (:class:`surfidx.geometry.sparse.SPDSolver`) factors ``P``: one shared by the
        balancings of one mesh reuses its order, and its factors with ``keep``."""
        import scipy.sparse as sp

        from ..geometry.sparse import SPDSolver
        from ..geometry.mesh import cotangent_laplacian

        lap = cotangent_laplacian(self.f, self.cot, self.n)
        lap = lap + sp.diags(np.full(self.n, shift * float(np.abs(lap.diagonal()).mean())))
        lap = lap.tocsr()
        lu = (SPDSolver() if solver is None else solver).factor(lap)

        def solve(r):
            return lu.solve(r.reshape(-1, 3)).ravel(order="C")

        indptr, indices, data = lap.indptr, lap.indices, lap.data

        def apply(r):
            out = np.empty((self.n, 3))
            _csr_apply(indptr, indices, data, r.reshape(-1, 3), out)
            return out.ravel()

        return solve, apply

    def __call__(self, y, *, grad: bool = True, bound: float = np.inf, again: bool = False):
        """The energy at ``y`` ``(n, 3)`` and, with ``grad``, its gradient ``(n, 3)`` (None
        without). Infinite (and no gradient) when a triangle is not counter-clockwise. Without
        ``grad``, a value above ``bound`` is any number above it, not the energy: the sum
        stops once it passes ``bound``. ``again``: ``y`` is the point of the last call,
        unchanged (its normalisation is reused)."""
        if self._scratch is None:
            self._scratch = (np.empty((self.n, 3)), np.empty((self.n, 3)), np.empty(self.n))
            again = False
        q, u, rr = self._scratch
        e, g = _energy_kernel(np.ascontiguousarray(y), self.f, self.cot, self.area3,
                              self.radius, grad, self.eps, self.lam, float(bound), self._hint,
                              q, u, rr, not again)
        if not np.isfinite(e):
            return np.inf, None
        return e, (g if grad else None)


def balance(x, p, f, *, iterations: int = 500, sweeps: int = 0, rounds: int = 1,
            memory: int = 8, tol: float = 1e-7, precondition: bool = True,
            shift: float = 1e-3, lam: float | None = None, max_cot: float = 4.0,
            patience: int = 20, sweep_tol: float = 0.0, solver=None):
    """Lower the distortion (symmetric Dirichlet, or conformal-plus-area) of a fold-free
    spherical embedding.

    Parameters
    ----------
    x : (n, 3) float64
        Unit vectors, a fold-free embedding of the mesh (every face counter-clockwise seen from
        outside).
    p : (n, 3) float64
        The surface's 3D positions.
    f : (m, 3) int64
        Faces, counter-clockwise seen from outside.
    iterations : int
        Stop after this many L-BFGS steps in all (a count, never the clock: the result is the
        same on every machine at any load).
    sweeps : int
        With ``lam``: sweeps of vertex-by-vertex relaxation (:mod:`surfidx.sphere.relax`)
        before each of the ``rounds`` runs of L-BFGS and after the last; they open up the
        squeezed stars that cut the global steps short.
    sweep_tol : float
        Each batch of sweeps stops after a sweep that lowers the energy by less than this
        fraction of it (0: all ``sweeps``).
    rounds : int
        The L-BFGS steps are split into this many runs (the first takes the remainder), each
        from a fresh history after its sweeps.
    memory : int
        L-BFGS history length.
    tol, patience : float, int
        Stop when ``patience`` steps in a row lower the energy by less than the fraction ``tol``.
    precondition : bool
        Precondition L-BFGS with the 3D cotangent Laplacian (plus ``shift`` times its mean
        diagonal): the accelerated quadratic proxy of Kovalsky, Galun & Lipman (2016).
    lam : float, optional
        None: the symmetric Dirichlet energy. A number: the conformal-plus-area energy
        ``Σ A (‖J‖² / det + lam (det + 1 / det))`` (Garanzha et al. 2021 with ``eps = 0``),
        ``det`` the ratio of image to 3D area: ``lam`` weighs area against angle preservation.
        Both grow without bound as a triangle degenerates.
    max_cot : float
        3D triangles with a cotangent beyond this are treated as fatter (see ``_cotangents``);
        ``inf`` keeps every triangle's shape.
    solver : surfidx.geometry.sparse.SPDSolver, optional
        Factors the preconditioner (a new one by default); balancings of the same mesh that
        share one made with ``keep=True`` factor an equal preconditioner once.

    Returns
    -------
    x : (n, 3) float64
        The balanced embedding, still fold-free.
    info : dict
        ``energy_start``, ``energy`` (per unit area; 4 is an isometry), ``steps``, ``moves``
        (vertex moves of the sweeps), ``sweeps`` (sweeps run).
    """
    energy = Energy(p, f, max_cot=max_cot)
    if lam is not None:
        energy.eps, energy.lam = 0.0, float(lam)
    total = energy.area3.sum()
    y = np.array(x, dtype=np.float64)
    e0, _ = energy(y, grad=False)
    if not np.isfinite(e0):
        return x, {"energy_start": np.inf, "energy": np.inf, "steps": 0, "moves": 0,
                   "sweeps": 0}
    iterations, rounds = max(int(iterations), 0), max(int(rounds), 1)
    relax = Relaxation(energy.f, energy.cot, energy.area3, energy.radius, energy.lam,
                       energy.n) if sweeps > 0 and lam is not None else None
    solve = apply = _identity
    if precondition and iterations:
        solve, apply = energy.preconditioner(shift=shift, solver=solver)
    e, steps, moves = e0, 0, 0
    for r in range(rounds):
        if relax is not None:
            y, m = relax(y, sweeps, tol=sweep_tol)
            moves += m
        run = iterations // rounds + (iterations % rounds if r == 0 else 0)
        if run:
            y, e, s = _lbfgs(energy, y, solve, apply, run, memory, tol, patience)
            steps += s
    if relax is not None:
        y, m = relax(y / np.linalg.norm(y, axis=1)[:, None], sweeps, tol=sweep_tol)
        moves += m
    if relax is not None or not steps:
        e, _ = energy(y, grad=False)
    x = y / np.linalg.norm(y, axis=1)[:, None]
    return x, {"energy_start": e0 / total, "energy": e / total, "steps": steps, "moves": moves,
               "sweeps": relax.passes if relax is not None else 0}


def _identity(r):
    return r


@numba.njit(cache=True)
def _history_back(g, d, s, y, rho, order, alpha):  # pragma: no cover - compiled
    """The two-loop recursion's first loop from ``d = -g``, newest pair first:
    ``alpha_k = rho_k s_kᵀd``, ``d -= alpha_k y_k``, into ``d``. ``order``: the rows of ``s``,
    ``y`` oldest first. One pass per pair: the update by one pair and the next pair's dot
    product share it (each element is updated before its product is taken, as in two
    passes)."""
    m = len(order)
    a = 0.0
    k = order[m - 1] if m else 0
    for i in range(d.shape[0]):
        d[i] = -g[i]
        if m:
            a += s[k, i] * d[i]
    for j in range(m - 1, -1, -1):
        k = order[j]
        a *= rho[k]
        alpha[k] = a
        if j:
            kn = order[j - 1]
            b = 0.0
            for i in range(d.shape[0]):
                d[i] -= a * y[k, i]
                b += s[kn, i] * d[i]
            a = b
        else:
            for i in range(d.shape[0]):
                d[i] -= a * y[k, i]


@numba.njit(cache=True)
def _history_forth(d, scale, s, y, rho, order, alpha):  # pragma: no cover - compiled
    """``d *= scale``, then the second loop, oldest pair first:
    ``d += s_k (alpha_k - rho_k y_kᵀd)``, in place, one pass per pair as in
    :func:`_history_back`."""
    m = len(order)
    b = 0.0
    k = order[0] if m else 0
    for i in range(d.shape[0]):
        d[i] *= scale
        if m:
            b += y[k, i] * d[i]
    for j in range(m):
        k = order[j]
        b = alpha[k] - rho[k] * b
        if j < m - 1:
            kn = order[j + 1]
            c = 0.0
            for i in range(d.shape[0]):
                d[i] += b * s[k, i]
                c += y[kn, i] * d[i]
            b = c
        else:
            for i in range(d.shape[0]):
                d[i] += b * s[k, i]


class History:
    """The last ``memory`` L-BFGS pairs ``(s, y)`` in ring buffers, oldest first, and one
    spare row that the next pair is written into (:meth:`spare`) before it is kept
    (:meth:`keep`) or dropped."""

    def __init__(self, memory: int, size: int):
        rows = max(memory, 0) + 1
        self.s = np.empty((rows, size))
        self.y = np.empty((rows, size))
        self.rho = np.empty(rows)
        self.sy = np.empty(rows)
        self.alpha = np.empty(rows)
        self.order = np.empty(0, dtype=np.int64)
        self.memory = memory
        self._spare = rows - 1

    def __len__(self):
        return len(self.order)

    def clear(self):
        self.order = np.empty(0, dtype=np.int64)

    def spare(self):
        """The rows ``(s, y)`` ``(size,)`` that the next pair is written into."""
        return self.s[self._spare], self.y[self._spare]

    def keep(self, sy: float):
        """Keep the pair in the spare rows, ``sy`` its ``sᵀy``; the oldest pair is dropped
        when ``memory`` pairs are kept."""
        if self.memory < 1:
            return
        k = self._spare
        if len(self.order) < self.memory:
            self.order = np.append(self.order, k)
            used = set(self.order.tolist())
            self._spare = next(r for r in range(len(self.rho)) if r not in used)
        else:
            self._spare = int(self.order[0])
            self.order = np.append(self.order[1:], k)
        self.sy[k] = sy
        self.rho[k] = 1.0 / sy

    def push(self, s, y):
        """Keep the pair ``(s, y)``."""
        s_row, y_row = self.spare()
        s_row[:], y_row[:] = s, y
        self.keep(_dot(y_row, s_row))

    def direction(self, g, solve, apply):
        """``-H g``: the two-loop recursion with initial inverse Hessian ``γ P⁻¹``."""
        d = np.empty_like(g)
        _history_back(g, d, self.s, self.y, self.rho, self.order, self.alpha)
        d = solve(d)
        if len(self.order):
            k = int(self.order[-1])
            scale = _dot(self.s[k], apply(self.s[k])) / self.sy[k]
        else:
            scale = 1e-3 / max(np.abs(d).max(), 1e-300)
        _history_forth(d, scale, self.s, self.y, self.rho, self.order, self.alpha)
        return d


@numba.njit(cache=True)
def _trial(y, d, step, out):  # pragma: no cover - compiled
    """``out = y + step d``."""
    for i in range(y.shape[0]):
        for c in range(3):
            out[i, c] = y[i, c] + step * d[i, c]


@numba.njit(cache=True)
def _advance(y, g, y2, g2, s, yk):  # pragma: no cover - compiled
    """An accepted step from ``(y, g)`` to ``(y2, g2)``: ``s = y2 - y`` and ``yk = g2 - g``
    (flat), then ``y = y2 / |y2|`` (row-wise) and ``g = g2 |y2|``, in place."""
    for i in range(y.shape[0]):
        for c in range(3):
            s[3 * i + c] = y2[i, c] - y[i, c]
            yk[3 * i + c] = g2[i, c] - g[i, c]
        r = np.sqrt(y2[i, 0] * y2[i, 0] + y2[i, 1] * y2[i, 1] + y2[i, 2] * y2[i, 2])
        for c in range(3):
            y[i, c] = y2[i, c] / r
            g[i, c] = g2[i, c] * r


def _lbfgs(energy, y, solve, apply, iterations, memory, tol, patience=20):
    """L-BFGS on the sphere, initial inverse Hessian ``γ P⁻¹`` (``solve`` applies ``P⁻¹``,
    ``apply`` applies ``P``; ``γ = sᵀPs / sᵀy`` needs no second solve), with a backtracking
    line search that takes only steps along which no triangle degenerates
    (:func:`segment_embedded`)."""
    y = np.array(y, dtype=np.float64, order="C")
    e, g = energy(y)
    hist = History(memory, g.size)
    y2 = np.empty_like(y)
    steps = 0
    last = 1.0
    stalls = 0
    for _ in range(max(iterations, 0)):
        d = hist.direction(g.ravel(), solve, apply)
        slope = _dot(g.ravel(), d)
        if slope >= 0:  # not a descent direction: restart from the gradient
            hist.clear()
            d = hist.direction(g.ravel(), solve, apply)
            slope = _dot(g.ravel(), d)
        step = min(1.0, 4.0 * last)
        dd = d.reshape(-1, 3)
        while step > 1e-12:         # the gradient only where a point is accepted
            _trial(y, dd, step, y2)
            bound = e + 1e-4 * step * slope
            e2, _ = energy(y2, grad=False, bound=bound)
            if e2 <= bound and segment_embedded(y, dd, energy.f, step):
                e2, g2 = energy(y2, again=True)
                break
            step *= 0.5
        else:
            if not len(hist):       # even the scaled gradient step fails: converged
                break
            hist.clear()            # a stale curvature model: restart from the gradient
            last = 1.0
            continue
        last = step
        s, yk = hist.spare()
        rel = (e - e2) / e
        # stay on the sphere: the energy is invariant along the radius, its gradient scales
        # by the radius
        _advance(y, g, y2, g2, s, yk)
        e = e2
        steps += 1
        sy = _dot(s, yk)
        if sy > 1e-12 * _dot(s, s):
            hist.keep(sy)
        stalls = stalls + 1 if rel < tol else 0
        if stalls >= patience:
            break
    return y, e, steps


def inverted(x, f) -> int:
    """How many triangles ``f`` of the spherical map ``x`` are not counter-clockwise."""
    return int(np.count_nonzero(_orientations(np.ascontiguousarray(x, dtype=np.float64),
                                              np.ascontiguousarray(f, dtype=np.int64)) <= 0))


@numba.njit(cache=True)
def _orientations(x, f):  # pragma: no cover - compiled
    out = np.empty(f.shape[0])
    for t in range(f.shape[0]):
        out[t] = _det(x[f[t, 0]], x[f[t, 1]], x[f[t, 2]])
    return out


@numba.njit(cache=True)
def _det(a, b, c):  # pragma: no cover - compiled
    return (a[0] * (b[1] * c[2] - b[2] * c[1]) - a[1] * (b[0] * c[2] - b[2] * c[0])
            + a[2] * (b[0] * c[1] - b[1] * c[0]))


@numba.njit(inline="always")
def _det9(a0, a1, a2, b0, b1, b2, c0, c1, c2):  # pragma: no cover - compiled
    """:func:`_det` of three vectors given by their coordinates."""
    return (a0 * (b1 * c2 - b2 * c1) - a1 * (b0 * c2 - b2 * c0)
            + a2 * (b0 * c1 - b1 * c0))


@numba.njit(cache=True, error_model="numpy")
def _block_turns(p, step, nb, out):  # pragma: no cover - compiled
    """Whether each of ``nb`` triangles turns over along the segment, ``out[j]``: its
    corners ``a, b, c`` and their directions ``da, db, dc`` in the 18 rows of ``p`` (x, y,
    z of a, b, c, then of da, db, dc). The tests of :func:`_segment_embedded`'s loop, each
    with the same operations, without branches (the compiler vectorises the loop)."""
    for j in range(nb):
        a0, a1, a2, b0, b1, b2 = p[0, j], p[1, j], p[2, j], p[3, j], p[4, j], p[5, j]
        e0, e1, e2, u0, u1, u2 = p[6, j], p[7, j], p[8, j], p[9, j], p[10, j], p[11, j]
        v0, v1, v2, w0, w1, w2 = p[12, j], p[13, j], p[14, j], p[15, j], p[16, j], p[17, j]
        # a = (a0, a1, a2), b, c = e; da = u, db = v, dc = w
        c0 = _det9(a0, a1, a2, b0, b1, b2, e0, e1, e2)
        c1 = (_det9(u0, u1, u2, b0, b1, b2, e0, e1, e2)
              + _det9(a0, a1, a2, v0, v1, v2, e0, e1, e2)
              + _det9(a0, a1, a2, b0, b1, b2, w0, w1, w2))
        c2 = (_det9(a0, a1, a2, v0, v1, v2, w0, w1, w2)
              + _det9(u0, u1, u2, b0, b1, b2, w0, w1, w2)
              + _det9(u0, u1, u2, v0, v1, v2, e0, e1, e2))
        c3 = _det9(u0, u1, u2, v0, v1, v2, w0, w1, w2)
        bad = (c0 <= 0.0) | (c0 + step * (c1 + step * (c2 + step * c3)) <= 0.0)
        qa, qb, qc = 3.0 * c3, 2.0 * c2, c1
        lin = qa == 0.0
        disc = qb * qb - 4.0 * qa * qc
        r = np.sqrt(disc)
        s1 = ((-qc / qb) if qb != 0.0 else -1.0) if lin else (-qb - r) / (2.0 * qa)
        s2 = -1.0 if lin else (-qb + r) / (2.0 * qa)
        real = lin | (disc >= 0.0)
        bad |= real & (0.0 < s1) & (s1 < step) & (c0 + s1 * (c1 + s1 * (c2 + s1 * c3)) <= 0.0)
        bad |= real & (0.0 < s2) & (s2 < step) & (c0 + s2 * (c1 + s2 * (c2 + s2 * c3)) <= 0.0)
        out[j] = bad


@numba.njit(cache=True)
def _segment_embedded(y, d, f, step):  # pragma: no cover - compiled
    """Whether no triangle turns over along the segment. A triangle's orientation
    ``det[a + s da, b + s db, c + s dc] = c0 + c1 s + c2 s² + c3 s³`` (multilinear) must be
    positive at ``s = 0``, at ``s = step`` and at the critical points inside (the roots of
    ``c1 + 2 c2 s + 3 c3 s²``); the triangles go in blocks through :func:`_block_turns`."""
    m = f.shape[0]
    bs = _BLOCK
    p = np.empty((18, bs))
    out = np.empty(bs, dtype=np.bool_)
    for t0 in range(0, m, bs):
        nb = min(bs, m - t0)
        for j in range(nb):
            t = t0 + j
            for k in range(3):
                i = f[t, k]
                for c in range(3):
                    p[3 * k + c, j] = y[i, c]
                    p[9 + 3 * k + c, j] = d[i, c]
        _block_turns(p, step, nb, out)
        for j in range(nb):
            if out[j]:
                return False
    return True


def segment_embedded(y, d, f, step: float) -> bool:
    """Whether every triangle ``f`` stays counter-clockwise (``det[y_a, y_b, y_c] > 0``) at
    every point ``y + s d``, ``0 <= s <= step``, of the segment.

    Parameters
    ----------
    y : (n, 3) float64
        Points (not necessarily unit: a triangle's orientation on the sphere is that of its
        three vectors).
    d : (n, 3) float64
        The step's direction.
    f : (m, 3) int64
    step : float

    Returns
    -------
    bool
    """
    return bool(_segment_embedded(np.ascontiguousarray(y, dtype=np.float64),
                                  np.ascontiguousarray(d, dtype=np.float64),
                                  np.ascontiguousarray(f, dtype=np.int64), float(step)))
