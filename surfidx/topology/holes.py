"""Holes filled with fair patches (Liepa 2003): triangulate, refine, flip, fair.

1. **Triangulate** each boundary loop. Loops of at most ``options.dp_max_loop`` vertices: the
   O(n³) dynamic programme of Barequet & Sharir as weighted by Liepa, lexicographically smallest
   (largest dihedral angle between neighbouring triangles, including the rim faces; total area).
   Longer loops (a fragment's outline of thousands of vertices) are first split recursively
   by short chords across half the loop into pieces of at most that many (O(n log n)).
   Chords that are edges of the mesh already are never used (they would make an edge of three
   faces).
2. **Refine**: longest-edge bisection of the patch's interior edges (never a rim edge: the scan's
   faces stay as they are) until none is longer than ``options.refine_ratio`` times the loop's
   mean rim edge, the target lengthened when the patch would get more than
   ``options.patch_vertex_factor`` interior vertices per rim vertex (+ ``patch_vertex_floor``).
3. **Flip** interior patch edges to Delaunay (opposite angles summing to more than π), for
   ``options.flip_rounds`` rounds, never creating an edge the mesh has.
4. **Fair**: the new vertices solve the uniform bi-Laplacian system ``(L²) x = 0`` with every
   scan vertex fixed, so the patch continues the surrounding surface with matching tangents;
   steps 3 and 4 run twice. A patch that folds nonetheless (two neighbouring patch faces whose
   normals disagree: a flat disk's outline, which the continuation overshoots) or has
   degenerate faces takes the membrane solution ``L x = 0`` instead when that has fewer. The
   two lids of a handle cut take the membrane from the start, in both rounds (a flat lid
   across the tube, its edges flipped for that shape).
"""

from __future__ import annotations

from ..jit import numba
import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import spsolve

from ..tolerance import TOL

__all__ = ["fill_holes"]

_ANGLE_TIE = 1e-12  # dihedral angles closer than this (in 1 - cos) are compared by area
_SLIVER = 1e-6      # a triangle of area below this times its longest edge squared is degenerate
_VERTEX_AREA = 0.17  # patch area per new vertex, in units of the target edge squared (bisection
                     # leaves edges of T/2..T; chosen by measurement on a long scan outline)


@numba.njit(cache=True)
def _dp_triangulate(P, rim_n, forbidden):
    """Liepa's weighted triangulation of the loop ``P``; triangles as loop indices (i, k, m).

    The tables are kept twice, as ``w[i, m]`` and transposed ``wT[k, m] = w[m, k]``, so the
    inner loop over ``m`` reads both operands along rows (contiguous memory, far faster).
    """
    n = len(P)
    INF = 1e300
    wa = np.full((n, n), INF)     # largest dihedral angle
    wr = np.full((n, n), INF)     # area
    waT = np.full((n, n), INF)
    wrT = np.full((n, n), INF)
    lam = np.full((n, n), -1, np.int64)
    nrm = np.zeros((n, n, 3))     # normal of the triangle chosen for (i, k)
    nrmT = np.zeros((n, n, 3))
    for i in range(n - 1):
        wa[i, i + 1] = 0.0
        wr[i, i + 1] = 0.0
        waT[i + 1, i] = 0.0
        wrT[i + 1, i] = 0.0
    for gap in range(2, n):
        for i in range(n - gap):
            k = i + gap
            if forbidden[i, k]:
                continue
            ba, br, bm = INF, INF, -1
            bx = by = bz = 0.0
            ux, uy, uz = P[k, 0] - P[i, 0], P[k, 1] - P[i, 1], P[k, 2] - P[i, 2]
            lik = ux * ux + uy * uy + uz * uz
            for m in range(i + 1, k):
                a1, a2 = wa[i, m], waT[k, m]
                if a1 >= INF or a2 >= INF:
                    continue
                ang = max(a1, a2)
                if ang > ba + _ANGLE_TIE:
                    continue
                # triangle (i, k, m): normal (P[k] - P[i]) x (P[m] - P[i]), all in scalars
                vx, vy, vz = P[m, 0] - P[i, 0], P[m, 1] - P[i, 1], P[m, 2] - P[i, 2]
                cx, cy, cz = uy * vz - uz * vy, uz * vx - ux * vz, ux * vy - uy * vx
                s2 = np.sqrt(cx * cx + cy * cy + cz * cz)
                area = 0.5 * s2
                wx, wy, wz = P[k, 0] - P[m, 0], P[k, 1] - P[m, 1], P[k, 2] - P[m, 2]
                e2 = max(lik, max(vx * vx + vy * vy + vz * vz, wx * wx + wy * wy + wz * wz))
                if s2 > 0:
                    cx, cy, cz = cx / s2, cy / s2, cz / s2
                if area <= _SLIVER * e2:
                    ang = max(ang, 3.0)            # collinear corners: only when unavoidable
                if m == i + 1:
                    d1 = cx * rim_n[i, 0] + cy * rim_n[i, 1] + cz * rim_n[i, 2]
                else:
                    d1 = cx * nrm[i, m, 0] + cy * nrm[i, m, 1] + cz * nrm[i, m, 2]
                if k == m + 1:
                    d2 = cx * rim_n[m, 0] + cy * rim_n[m, 1] + cz * rim_n[m, 2]
                else:
                    d2 = cx * nrmT[k, m, 0] + cy * nrmT[k, m, 1] + cz * nrmT[k, m, 2]
                ang = max(ang, max(1.0 - d1, 1.0 - d2))
                if gap == n - 1:
                    d3 = cx * rim_n[n - 1, 0] + cy * rim_n[n - 1, 1] + cz * rim_n[n - 1, 2]
                    ang = max(ang, 1.0 - d3)
                ar = wr[i, m] + wrT[k, m] + area
                if ang < ba - _ANGLE_TIE or (ang <= ba + _ANGLE_TIE and ar < br):
                    ba, br, bm = ang, ar, m
                    bx, by, bz = cx, cy, cz
            if bm >= 0:
                wa[i, k], wr[i, k], lam[i, k] = ba, br, bm
                waT[k, i], wrT[k, i] = ba, br
                nrm[i, k, 0], nrm[i, k, 1], nrm[i, k, 2] = bx, by, bz
                nrmT[k, i, 0], nrmT[k, i, 1], nrmT[k, i, 2] = bx, by, bz
    tris = np.empty((max(n - 2, 0), 3), np.int64)
    if lam[0, n - 1] < 0:
        return tris[:0]
    stack = np.empty((n, 2), np.int64)
    stack[0, 0], stack[0, 1] = 0, n - 1
    top, t = 1, 0
    while top > 0:
        top -= 1
        i, k = stack[top, 0], stack[top, 1]
        if k - i < 2:
            continue
        m = lam[i, k]
        tris[t, 0], tris[t, 1], tris[t, 2] = i, k, m
        t += 1
        stack[top, 0], stack[top, 1] = i, m
        stack[top + 1, 0], stack[top + 1, 1] = m, k
        top += 2
    return tris[:t]


@numba.njit(cache=True, _nrt=False)
def _cross(V, i, j, k, m):
    """``(V[i] - V[j]) × (V[k] - V[m])`` as three scalars, as ``np.cross`` computes it."""
    a0, a1, a2 = V[i, 0] - V[j, 0], V[i, 1] - V[j, 1], V[i, 2] - V[j, 2]
    b0, b1, b2 = V[k, 0] - V[m, 0], V[k, 1] - V[m, 1], V[k, 2] - V[m, 2]
    return a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0


@numba.njit(cache=True, _nrt=False)
def _has_edge(F, twin, h0, d):
    """Whether the start vertex of half-edge ``h0`` has an edge to ``d`` (rotation about it)."""
    h = h0
    for _ in range(len(twin)):
        if F[(h // 3), (h % 3 + 1) % 3] == d:
            return True
        # rotate: twin of the previous half-edge of the face
        h = twin[3 * (h // 3) + (h % 3 + 2) % 3]
        if h == h0 or h < 0:
            return False
    return False


@numba.njit(cache=True)
def _flip_rounds(V, F, twin, flippable, rounds):
    """Delaunay flips, in place, of the edges between two ``flippable`` faces of the closed mesh
    ``F`` (half-edge twins ``twin``); returns the number of flips."""
    m = len(F)
    flips = 0
    for _ in range(rounds):
        changed = 0
        for r in range(m):
            if not flippable[r]:
                continue
            for j in range(3):
                h = 3 * r + j
                t = twin[h]
                g = t // 3
                if not flippable[g] or g == r:
                    continue
                jj = t % 3
                a, b, c = F[r, j], F[r, (j + 1) % 3], F[r, (j + 2) % 3]
                d = F[g, (jj + 2) % 3]
                if d == c:
                    continue
                # the angles at c and d (coordinates as scalars: the same operations, in
                # the same order, as the 3-vectors' expressions, without an array each)
                u10, u11, u12 = V[a, 0] - V[c, 0], V[a, 1] - V[c, 1], V[a, 2] - V[c, 2]
                v10, v11, v12 = V[b, 0] - V[c, 0], V[b, 1] - V[c, 1], V[b, 2] - V[c, 2]
                u20, u21, u22 = V[a, 0] - V[d, 0], V[a, 1] - V[d, 1], V[a, 2] - V[d, 2]
                v20, v21, v22 = V[b, 0] - V[d, 0], V[b, 1] - V[d, 1], V[b, 2] - V[d, 2]
                n1 = np.sqrt((0.0 + u10 ** 2 + u11 ** 2 + u12 ** 2)
                             * (0.0 + v10 ** 2 + v11 ** 2 + v12 ** 2))
                n2 = np.sqrt((0.0 + u20 ** 2 + u21 ** 2 + u22 ** 2)
                             * (0.0 + v20 ** 2 + v21 ** 2 + v22 ** 2))
                if n1 <= 0 or n2 <= 0:
                    continue
                d1 = 0.0 + u10 * v10 + u11 * v11 + u12 * v12
                d2 = 0.0 + u20 * v20 + u21 * v21 + u22 * v22
                ac = np.arccos(min(1.0, max(-1.0, d1 / n1)))
                ad = np.arccos(min(1.0, max(-1.0, d2 / n2)))
                if ac + ad <= np.pi + 1e-9:
                    continue
                # keep the orientation: the new faces must not turn over the old pair
                p0, p1, p2 = _cross(V, b, a, c, a)
                q0, q1, q2 = _cross(V, a, b, d, b)
                o0, o1, o2 = p0 + q0, p1 + q1, p2 + q2
                f0, f1, f2 = _cross(V, d, a, c, a)
                g0, g1, g2 = _cross(V, b, d, c, d)
                if (0.0 + f0 * o0 + f1 * o1 + f2 * o2 <= 0
                        or 0.0 + g0 * o0 + g1 * o1 + g2 * o2 <= 0):
                    continue
                # the new edge c-d must not exist already (rotate about c)
                if _has_edge(F, twin, 3 * r + (j + 2) % 3, d):
                    continue
                # outer twins before the flip
                t_bc = twin[3 * r + (j + 1) % 3]
                t_ca = twin[3 * r + (j + 2) % 3]
                t_ad = twin[3 * g + (jj + 1) % 3]
                t_db = twin[3 * g + (jj + 2) % 3]
                F[r, 0], F[r, 1], F[r, 2] = a, d, c      # a->d, d->c, c->a
                F[g, 0], F[g, 1], F[g, 2] = d, b, c      # d->b, b->c, c->d
                twin[3 * r + 0], twin[t_ad] = t_ad, 3 * r + 0
                twin[3 * r + 2], twin[t_ca] = t_ca, 3 * r + 2
                twin[3 * g + 0], twin[t_db] = t_db, 3 * g + 0
                twin[3 * g + 1], twin[t_bc] = t_bc, 3 * g + 1
                twin[3 * r + 1], twin[3 * g + 2] = 3 * g + 2, 3 * r + 1
                changed += 1
                break
        flips += changed
        if changed == 0:
            break
    return flips


def _twins(F, n):
    """(3m,) twin half-edge of every half-edge of a closed manifold mesh."""
    a = F.ravel()
    b = np.roll(F, -1, axis=1).ravel()
    key = a * np.int64(n) + b
    order = np.argsort(key)
    pos = np.searchsorted(key[order], b * np.int64(n) + a)
    return order[np.minimum(pos, len(order) - 1)].astype(np.int64)


def _rim_normals(V, F, loop, n):
    """Unit normal of the scan face on each rim edge ``loop[i] -> loop[i+1]``."""
    a = F.ravel()
    b = np.roll(F, -1, axis=1).ravel()
    key = a * np.int64(n) + b
    order = np.argsort(key)
    la, lb = loop, np.roll(loop, -1)
    pos = order[np.searchsorted(key[order], la * np.int64(n) + lb)]
    f = F[pos // 3]
    nr = np.cross(V[f[:, 1]] - V[f[:, 0]], V[f[:, 2]] - V[f[:, 0]])
    return nr / np.maximum(np.linalg.norm(nr, axis=1), 1e-300)[:, None]


def _forbidden(loop, n, edge_keys):
    """(k, k) bool: chords of ``loop`` that are edges of the mesh already (not its own edges)."""
    k = len(loop)
    lo, hi = np.minimum.outer(loop, loop), np.maximum.outer(loop, loop)
    keys = lo * np.int64(n) + hi
    pos = np.clip(np.searchsorted(edge_keys, keys), 0, len(edge_keys) - 1)
    forbidden = edge_keys[pos] == keys
    idx = np.arange(k)
    forbidden[idx[:-1], idx[1:]] = False
    forbidden[0, k - 1] = False
    return forbidden


def _dp(P, loop, rim_n, n, edge_keys):
    k = len(loop)
    tris = _dp_triangulate(P, rim_n, _forbidden(loop, n, edge_keys))
    if len(tris) != k - 2:   # every triangulation needs an existing chord: allow them
        tris = _dp_triangulate(P, rim_n, np.zeros((k, k), np.bool_))
    return tris


def _triangulate(V, F, loop, n, edge_keys, options):
    """Loop-local triangles ``(t, 3)`` wound as the patch (opposite to the rim's half-edges).

    A loop longer than ``options.dp_max_loop`` is first split, recursively, by the shortest
    chord between vertices half the (sub-)loop apart that is not an edge of the mesh, into
    pieces the dynamic programme takes: O(n log n) chord searches and O(n) programme cost for
    a fixed piece size, and balanced pieces (no fan of slivers). Chords take the loop's mean rim
    normal in the programme's dihedral angles.
    """
    k = len(loop)
    if k == 3:
        return np.array([[0, 2, 1]], np.int64)
    rim_n = _rim_normals(V, F, loop, n)
    if k <= options.dp_max_loop:
        return _dp(V[loop], loop, rim_n, n, edge_keys)
    mean_n = rim_n.sum(axis=0)
    mean_n /= max(np.linalg.norm(mean_n), 1e-300)
    out = []
    stack = [(np.arange(k), rim_n)]
    while stack:
        idx, nrm = stack.pop()
        m = len(idx)
        if m <= max(options.dp_max_loop, 3):
            if m == 3:
                out.append(idx[[0, 2, 1]][None, :])
            else:
                out.append(idx[_dp(V[loop[idx]], loop[idx], nrm, n, edge_keys)])
            continue
        half = m // 2
        i = np.arange(m)
        j = (i + half) % m
        a, b = loop[idx[i]], loop[idx[j]]
        length = np.linalg.norm(V[a] - V[b], axis=1)
        keys = np.minimum(a, b) * np.int64(n) + np.maximum(a, b)
        pos = np.clip(np.searchsorted(edge_keys, keys), 0, len(edge_keys) - 1)
        length = np.where(edge_keys[pos] == keys, np.inf, length)
        s = int(np.argmin(length))       # first of the shortest: deterministic
        t = (s + half) % m
        run1 = (s + np.arange((t - s) % m + 1)) % m       # s .. t
        run2 = (t + np.arange((s - t) % m + 1)) % m       # t .. s
        n1 = np.vstack([nrm[run1[:-1]], mean_n])          # its closing edge t -> s is the chord
        n2 = np.vstack([nrm[run2[:-1]], mean_n])
        stack.append((idx[run2], n2))
        stack.append((idx[run1], n1))
    return np.vstack(out)


def _refine(V, patch, hole_of, target, limit_rounds):
    """Longest-interior-edge bisection of the patch faces; returns new vertices and faces.

    A face whose interior edges are all within its target is final (splitting a neighbour never
    lengthens them), so each round works only on the faces still active.
    """
    verts = [V]
    nv = len(V)
    done, done_hole = [], []
    faces, hole = patch, hole_of
    allv = V
    for _ in range(limit_rounds):
        if not len(faces):
            break
        a, b = faces, np.roll(faces, -1, axis=1)
        base = np.int64(nv + 1)
        key = np.minimum(a, b) * base + np.maximum(a, b)
        ukeys, inv, cnt = np.unique(key, return_inverse=True, return_counts=True)
        inv = inv.reshape(key.shape)
        interior = cnt[inv] == 2
        length = np.linalg.norm(allv[b] - allv[a], axis=2)
        eff = np.where(interior, length, -1.0)
        kk = np.argmax(eff, axis=1)
        top = eff[np.arange(len(faces)), kk][:, None]
        tie = (eff == top).sum(axis=1) > 1
        if tie.any():
            kk[tie] = np.argmax(np.where(eff[tie] == top[tie], key[tie], -1), axis=1)
        fl = eff[np.arange(len(faces)), kk]
        over = fl > target[hole]
        final = ~over
        if final.any():
            done.append(faces[final])
            done_hole.append(hole[final])
        cand = np.flatnonzero(over)
        if not len(cand):
            faces, hole = faces[:0], hole[:0]
            break
        ck = key[cand, kk[cand]]
        keys, count = np.unique(ck, return_counts=True)
        keys = keys[count == 2]
        rows = cand[np.isin(ck, keys)]
        if not len(rows):
            break
        k = kk[rows]
        rank = np.searchsorted(keys, key[rows, k])
        fa, fb, fc = (faces[rows, (k + i) % 3] for i in range(3))
        first = np.unique(rank, return_index=True)[1]
        mid = nv + rank
        verts.append(0.5 * (allv[fa[first]] + allv[fb[first]]))
        allv = np.vstack([allv, verts[-1]])
        nv += len(keys)
        wait = np.ones(len(faces), bool)
        wait[rows] = False
        wait &= over
        faces = np.vstack([faces[wait], np.stack([fa, mid, fc], 1), np.stack([mid, fb, fc], 1)])
        hole = np.concatenate([hole[wait], hole[rows], hole[rows]])
    faces = np.vstack(done + [faces])
    hole = np.concatenate(done_hole + [hole])
    return allv, faces, hole


def _bad_faces(V, F, m_real, hole, count):
    """(count,) int64 per patch: its degenerate faces (area under ``TOL.degenerate_area`` times
    the mean face area, the faces :meth:`TriangleMesh.to_surfels` drops) times ``m + 1``, plus
    its pairs of neighbouring faces whose normals disagree (folds): fewer degenerate faces
    first, then fewer folds."""
    fn = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    area = 0.5 * np.linalg.norm(fn, axis=1)
    fn /= np.maximum(2 * area, 1e-300)[:, None]
    degenerate = area < TOL.degenerate_area * area.mean()
    twin = _twins(F, len(V))
    face = np.repeat(np.arange(len(F)), 3)
    other = twin // 3
    both = (face >= m_real) & (other >= m_real) & (face < other)
    fold = both & (np.einsum("ij,ij->i", fn[face], fn[other]) <= 0)
    folds = np.bincount(hole[face[fold] - m_real], minlength=count)
    pd = np.flatnonzero(degenerate[m_real:])
    # a degenerate face is fatal (dropped, it opens the surface again), a fold is not
    return np.bincount(hole[pd], minlength=count) * (len(F) + 1) + folds


def _fair(V, F, free, order=2):
    """Positions of the ``free`` vertices solving the uniform bi-Laplacian (``order`` 2) or
    Laplacian (1) with the rest fixed."""
    n = len(V)
    if not free.any():
        return V
    e = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
    A = sp.coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(n, n)).tocsr()
    A = ((A + A.T) > 0).astype(np.float64)
    L = (sp.diags(np.asarray(A.sum(axis=1)).ravel()) - A).tocsr()
    U = np.flatnonzero(free)
    K = np.flatnonzero(~free)
    M = (L[U, :] @ L).tocsc() if order == 2 else L[U, :].tocsc()
    rhs = -(M[:, K] @ V[K])
    x = spsolve(M[:, U].tocsc(), rhs)
    out = V.copy()
    out[U] = np.asarray(x).reshape(len(U), 3)
    return out


def fill_holes(V: np.ndarray, F: np.ndarray, loops: list, options, *, membrane=None):
    """Fair patches over the boundary loops of an oriented manifold mesh.

    Parameters
    ----------
    V : (n, 3) float64
    F : (m, 3) int64
        Consistently wound faces; every edge has one or two faces.
    loops : list of (k,) int64
        The boundary loops (:func:`~.analyse.boundary_loops`).
    options : RepairOptions
    membrane : (len(loops),) bool, optional
        Loops capped by the membrane (Laplacian) solution from the start: the two sides of a
        handle cut, where the surface ends in a tube whose bi-Laplacian continuation would fold
        the cap back along the tube's wall; the membrane spans the cut like a flat lid.

    Returns
    -------
    vertices : (n + v, 3) float64
        ``V`` followed by the patches' new (virtual) vertices.
    faces : (p, 3) int64
        The patch faces (virtual), indexing ``vertices``.
    hole : (p,) int64
        Loop index of each patch face.
    """
    n = len(V)
    if not loops:
        return V, np.zeros((0, 3), np.int64), np.zeros(0, np.int64)
    a = F.ravel()
    b = np.roll(F, -1, axis=1).ravel()
    edge_keys = np.unique(np.minimum(a, b) * np.int64(n) + np.maximum(a, b))
    patches, holes, targets = [], [], []
    for h, loop in enumerate(loops):
        loop = np.asarray(loop, np.int64)
        tri = _triangulate(V, F, loop, n, edge_keys, options)
        faces = loop[tri]
        patches.append(faces)
        holes.append(np.full(len(faces), h, np.int64))
        P = V[loop]
        sigma = float(np.mean(np.linalg.norm(P - np.roll(P, -1, axis=0), axis=1)))
        area = float(0.5 * np.linalg.norm(np.cross(V[faces[:, 1]] - V[faces[:, 0]],
                                                   V[faces[:, 2]] - V[faces[:, 0]]),
                                          axis=1).sum())
        t = options.refine_ratio * sigma
        budget = options.patch_vertex_factor * len(loop) + options.patch_vertex_floor
        if t > 0 and area / (_VERTEX_AREA * t * t) > budget:
            t = np.sqrt(area / (_VERTEX_AREA * max(budget, 1.0)))
        targets.append(t if t > 0 else np.inf)
    patch = np.vstack(patches)
    hole = np.concatenate(holes)
    target = np.asarray(targets)
    budget_total = sum(options.patch_vertex_factor * len(lp) + options.patch_vertex_floor
                       for lp in loops)
    # every round splits at least the longest edge over target; the bound only stops a
    # pathological case (each round at least halves the longest edges of the faces it splits)
    rounds = int(4 * np.log2(2 + budget_total)) + 16
    allv, patch, hole = _refine(V, patch, hole, target, rounds)
    nv = len(allv)
    every = np.ascontiguousarray(np.vstack([F, patch]), dtype=np.int64)
    free = np.zeros(nv, bool)
    free[n:] = True
    flippable = np.zeros(len(every), bool)
    flippable[len(F):] = True
    lid = np.zeros(nv, bool)
    if membrane is not None and np.any(membrane):
        lid[patch[np.asarray(membrane, bool)[hole]].ravel()] = True
        lid &= free
    # flips on the flat refinement, fairing, then flips and fairing once more on the faired
    # patch (Liepa alternates the two: the first fairing turns slivers of a flat fan into
    # folds that the second round of flips removes). The lids are faired as membranes in both
    # rounds, so that the second round flips their edges for the membrane's shape: flipped for
    # the bi-Laplacian's (folded back along the tube) and then relaxed as a membrane, a lid can
    # squeeze a cluster of its vertices to one point (faces of zero area, which to_surfels drops,
    # reopening the surface)
    for _ in range(2):
        if options.flip_rounds:
            _flip_rounds(allv, every, _twins(every, nv), flippable, options.flip_rounds)
        allv = _fair(allv, every, free & ~lid)
        allv = _fair(allv, every, lid, order=1)
    patch = every[len(F):]
    bad = _bad_faces(allv, every, len(F), hole, len(loops))
    if membrane is not None:
        bad[np.asarray(membrane, bool)] = 0
    if bad.any():
        # a bi-Laplacian patch can overshoot and fold where the rim has nothing to continue (a
        # flat disk's outline: the patch would continue the disk beyond its rim and come back);
        # such a patch takes the membrane (Laplacian) solution, a convex combination of the rim,
        # when that has fewer folded or degenerate faces (it collapses parts of a patch joined
        # to the rest by one or two vertices)
        redo = np.zeros(nv, bool)
        redo[patch[(bad > 0)[hole]].ravel()] = True
        redo &= free
        membrane = _fair(allv, every, redo, order=1)
        better = _bad_faces(membrane, every, len(F), hole, len(loops)) < bad
        take = np.zeros(nv, bool)
        take[patch[better[hole]].ravel()] = True
        take &= free
        allv = np.where(take[:, None], membrane, allv)
    return allv, patch, hole
