"""Fold-free distortion balancing of a spherical mesh embedding (symmetric Dirichlet energy).

A Tutte (harmonic) embedding is fold-free but squeezes limbs exponentially. Starting from it, we
minimise the symmetric Dirichlet energy of the piecewise-linear map from the 3D triangles to the
chord triangles of the sphere (scaled to the surface's area),

    E = Σ_t A_t (‖J_t‖²_F + ‖J_t⁻¹‖²_F) = Σ_t D_t (1 + (A_t / a_t)²),

where ``D_t = ½ Σ_i cot α_i |q_j − q_k|²`` is the Dirichlet energy of triangle t (cotangents of
its 3D angles), ``A_t`` its 3D area and ``a_t`` the area of its image. The energy is smallest (4 per
unit area) for an isometry, penalises squeezed triangles like stretched ones, and grows without
bound as an image triangle degenerates, so a line search that rejects inverted triangles keeps
every iterate fold-free (Smith & Schaefer 2015; Rabinovich et al. 2017 use the same energy for
locally injective planar maps). L-BFGS over the unnormalised positions ``y`` with ``x = y / |y|``.
"""

from __future__ import annotations

import time

import numba
import numpy as np

__all__ = ["balance"]


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


@numba.njit(cache=True)
def _energy_kernel(y, f, cot, area3, radius, grad):  # pragma: no cover - compiled
    n = y.shape[0]
    x = np.empty((n, 3))
    for i in range(n):
        r = np.sqrt(y[i, 0] ** 2 + y[i, 1] ** 2 + y[i, 2] ** 2)
        for c in range(3):
            x[i, c] = y[i, c] / r
    g = np.zeros((n, 3))
    e = 0.0
    q = np.empty((3, 3))
    for t in range(f.shape[0]):
        for k in range(3):
            for c in range(3):
                q[k, c] = radius * x[f[t, k], c]
        u0, u1, u2 = q[1, 0] - q[0, 0], q[1, 1] - q[0, 1], q[1, 2] - q[0, 2]
        v0, v1, v2 = q[2, 0] - q[0, 0], q[2, 1] - q[0, 1], q[2, 2] - q[0, 2]
        c0, c1, c2 = u1 * v2 - u2 * v1, u2 * v0 - u0 * v2, u0 * v1 - u1 * v0
        s0, s1, s2 = q[0, 0] + q[1, 0] + q[2, 0], q[0, 1] + q[1, 1] + q[2, 1], q[0, 2] + q[1, 2] + q[2, 2]
        # signed area projected on the tangent plane at the centroid direction u: it vanishes
        # when the corners fall on one great circle (where the plain area |c|/2 does not)
        sl = np.sqrt(s0 * s0 + s1 * s1 + s2 * s2)
        n0, n1, n2 = s0 / sl, s1 / sl, s2 / sl
        ar = 0.5 * (c0 * n0 + c1 * n1 + c2 * n2)
        if ar <= 0.0:
            return np.inf, g
        d = 0.0
        for k in range(3):          # edge opposite corner k: from corner k+1 to k+2
            j, l = (k + 1) % 3, (k + 2) % 3
            el2 = ((q[l, 0] - q[j, 0]) ** 2 + (q[l, 1] - q[j, 1]) ** 2
                   + (q[l, 2] - q[j, 2]) ** 2)
            d += 0.5 * cot[t, k] * el2
        r2 = (area3[t] / ar) ** 2
        e += d * (1.0 + r2)
        if grad:
            k1 = 1.0 + r2
            k2 = -2.0 * d * r2 / ar
            # d ar / d q_k = 1/2 u x (q_l - q_j) + 1/2 (c - (c.u) u) / |s|
            cu = c0 * n0 + c1 * n1 + c2 * n2
            h0 = 0.5 * (c0 - cu * n0) / sl
            h1 = 0.5 * (c1 - cu * n1) / sl
            h2 = 0.5 * (c2 - cu * n2) / sl
            for k in range(3):
                j, l = (k + 1) % 3, (k + 2) % 3
                # dD/dq_k: edges k-j (cot at l) and k-l (cot at j)
                for c in range(3):
                    g[f[t, k], c] += radius * k1 * (cot[t, l] * (q[k, c] - q[j, c])
                                                    + cot[t, j] * (q[k, c] - q[l, c]))
                # d ar / d q_k
                w0, w1, w2 = q[l, 0] - q[j, 0], q[l, 1] - q[j, 1], q[l, 2] - q[j, 2]
                g[f[t, k], 0] += radius * k2 * (0.5 * (n1 * w2 - n2 * w1) + h0)
                g[f[t, k], 1] += radius * k2 * (0.5 * (n2 * w0 - n0 * w2) + h1)
                g[f[t, k], 2] += radius * k2 * (0.5 * (n0 * w1 - n1 * w0) + h2)
    if grad:
        for i in range(n):
            r = np.sqrt(y[i, 0] ** 2 + y[i, 1] ** 2 + y[i, 2] ** 2)
            dot = g[i, 0] * x[i, 0] + g[i, 1] * x[i, 1] + g[i, 2] * x[i, 2]
            for c in range(3):
                g[i, c] = (g[i, c] - dot * x[i, c]) / r
    return e, g


def _dot(a, b):
    """Dot product of two long vectors without BLAS (threaded BLAS dot products of this size
    were measured 300x slower on a loaded 2-core machine)."""
    return float(np.einsum("i,i->", a, b))


class _Energy:
    def __init__(self, p, f):
        self.f = np.ascontiguousarray(f, dtype=np.int64)
        self.cot, self.area3 = _cotangents(p, f)
        self.radius = float(np.sqrt(self.area3.sum() / (4 * np.pi)))
        self.n = len(p)

    def preconditioner(self, *, shift: float):
        """Solve and product with ``P = L + shift·mean(diag L)·I``, L the cotangent Laplacian of the 3D
        mesh (the Hessian of the energy's Dirichlet part at an isometry: the accelerated
        quadratic proxy of Kovalsky et al. 2016). Updates spread over whole limbs instead of
        creeping one ring per step."""
        import scipy.sparse as sp
        from scipy.sparse.linalg import splu

        f, cot = self.f, self.cot
        rows = np.concatenate([f[:, 1], f[:, 2], f[:, 0]])
        cols = np.concatenate([f[:, 2], f[:, 0], f[:, 1]])
        w = 0.5 * np.concatenate([cot[:, 0], cot[:, 1], cot[:, 2]])
        off = sp.coo_matrix((w, (rows, cols)), shape=(self.n, self.n)).tocsr()
        off = off + off.T
        diag = np.asarray(off.sum(axis=1)).ravel()
        lap = sp.diags(diag + shift * float(np.abs(diag).mean())) - off
        lap = lap.tocsc()
        lu = splu(lap, permc_spec="COLAMD")

        def solve(r):
            return lu.solve(np.asfortranarray(r.reshape(-1, 3))).ravel(order="C")

        def apply(r):
            return np.asarray(lap @ r.reshape(-1, 3)).ravel()

        return solve, apply

    def __call__(self, y, *, grad: bool = True):
        e, g = _energy_kernel(np.ascontiguousarray(y), self.f, self.cot, self.area3,
                              self.radius, grad)
        if not np.isfinite(e):
            return np.inf, None
        return e, (g if grad else None)


def balance(x, p, f, *, iterations: int = 500, time_budget: float = 10.0, memory: int = 8,
            tol: float = 1e-7, precondition: bool = True, shift: float = 1e-3):
    """Lower the symmetric Dirichlet distortion of a fold-free spherical embedding.

    Parameters
    ----------
    x : (n, 3) float64
        Unit vectors, a fold-free embedding of the mesh (every face counter-clockwise seen from
        outside).
    p : (n, 3) float64
        The surface's 3D positions.
    f : (m, 3) int64
        Faces, counter-clockwise seen from outside.
    iterations, time_budget : int, float
        Stop after this many L-BFGS steps or seconds.
    memory : int
        L-BFGS history length.
    tol : float
        Stop when 20 steps in a row lower the energy by less than this fraction.
    precondition : bool
        Precondition L-BFGS with the 3D cotangent Laplacian (plus ``shift`` times its mean
        diagonal): the accelerated quadratic proxy of Kovalsky, Galun & Lipman (2016).

    Returns
    -------
    x : (n, 3) float64
        The balanced embedding, still fold-free.
    info : dict
        ``energy_start``, ``energy`` (per unit area; 4 is an isometry), ``steps``.
    """
    energy = _Energy(p, f)
    total = energy.area3.sum()
    y = np.array(x, dtype=np.float64)
    e0, _ = energy(y, grad=False)
    if not np.isfinite(e0):
        return x, {"energy_start": np.inf, "energy": np.inf, "steps": 0}
    if precondition:
        solve, apply = energy.preconditioner(shift=shift)
    else:
        solve = apply = _identity
    deadline = time.perf_counter() + time_budget
    y, e, steps = _lbfgs(energy, y, solve, apply, iterations, deadline, memory, tol)
    x = y / np.linalg.norm(y, axis=1)[:, None]
    return x, {"energy_start": e0 / total, "energy": e / total, "steps": steps}


def _identity(r):
    return r


def _lbfgs(energy, y, solve, apply, iterations, deadline, memory, tol):
    """L-BFGS on the sphere, initial inverse Hessian ``γ P⁻¹`` (``solve`` applies ``P⁻¹``,
    ``apply`` applies ``P``; ``γ = sᵀPs / sᵀy`` needs no second solve), with a fold-rejecting
    backtracking line search."""
    e, g = energy(y)
    s_hist, y_hist = [], []
    steps = 0
    last = 1.0
    stalls = 0
    for _ in range(max(iterations, 0)):
        if time.perf_counter() > deadline:
            break
        # two-loop recursion
        d = -g.ravel()
        alphas = []
        for s_k, y_k in reversed(list(zip(s_hist, y_hist))):
            rho = 1.0 / _dot(y_k, s_k)
            a_k = rho * _dot(s_k, d)
            alphas.append((rho, a_k))
            d -= a_k * y_k
        d = solve(d)
        if s_hist:
            d *= _dot(s_hist[-1], apply(s_hist[-1])) / _dot(s_hist[-1], y_hist[-1])
        else:
            d *= 1e-3 / max(np.abs(d).max(), 1e-300)
        for (s_k, y_k), (rho, a_k) in zip(zip(s_hist, y_hist), reversed(alphas)):
            d += s_k * (a_k - rho * _dot(y_k, d))
        slope = _dot(g.ravel(), d)
        if slope >= 0:  # not a descent direction: restart from the gradient
            s_hist.clear()
            y_hist.clear()
            d = solve(-g.ravel())
            d *= 1e-3 / max(np.abs(d).max(), 1e-300)
            slope = _dot(g.ravel(), d)
        step = min(1.0, 4.0 * last)
        while step > 1e-12:
            y2 = y + step * d.reshape(-1, 3)
            e2, g2 = energy(y2)
            if e2 <= e + 1e-4 * step * slope:
                break
            step *= 0.5
        else:
            if not s_hist:          # even the scaled gradient step fails: converged
                break
            s_hist.clear()          # a stale curvature model: restart from the gradient
            y_hist.clear()
            last = 1.0
            continue
        last = step
        s = (y2 - y).ravel()
        yk = (g2 - g).ravel()
        rel = (e - e2) / e
        y = y2 / np.linalg.norm(y2, axis=1)[:, None]   # stay on the sphere (the energy is
        e, g = energy(y)                                # invariant along the radius)
        steps += 1
        if _dot(s, yk) > 1e-12 * _dot(s, s):
            s_hist.append(s)
            y_hist.append(yk)
            if len(s_hist) > memory:
                s_hist.pop(0)
                y_hist.pop(0)
        stalls = stalls + 1 if rel < tol else 0
        if stalls >= 20:
            break
    return y, e, steps
