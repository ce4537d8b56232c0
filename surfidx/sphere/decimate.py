"""Topology-preserving mesh decimation by rounds of independent half-edge collapses.

The coarse-to-fine spherical map (:mod:`surfidx.sphere`) maps a coarse version of the mesh
first, where area balancing converges in a fraction of a second, and then carries that map down to
every vertex. The coarse mesh must triangulate the same sphere, so every collapse keeps the mesh a
closed 2-manifold of genus 0:

* half-edge collapses (vertex ``r`` merged into its neighbour ``k``, which keeps its position), so
  the coarse vertices are a subset of the input's and every removed vertex knows the ring it was
  removed from;
* the link condition (``r`` and ``k`` share exactly the two neighbours opposite the edge; Dey et
  al. 1999), which is what keeps a closed triangulated surface a manifold of the same genus;
* no vertex of degree below 3 afterwards, no triangle turned over (its normal rotates less than
  60°) or turned into a sliver;
* collapses of one round are independent: the closed 1-rings of their edges are disjoint, so all
  of a round's checks hold at once and the round is applied with array operations.

Shortest edges go first, so the coarse mesh is roughly uniform and keeps thin limbs as long as
their edges are not the shortest. :func:`decimate` records the rounds; a removed vertex's ring is
the list of its neighbours when it was removed, all of them present in every coarser mesh.
"""

from __future__ import annotations

from dataclasses import dataclass

from ..jit import numba
import numpy as np

from ..geometry.unitsphere import corner_orientation

__all__ = ["Hierarchy", "decimate"]

_MAX_DEGREE = 12     # a kept vertex may not grow beyond this many neighbours
_COS_TURN = 0.5      # a collapse may rotate a triangle's normal by at most 60 degrees
_SLIVER = 0.05       # and leaves no triangle with area below this fraction of its longest edge²
_MAX_SCAN = 64       # vertices of higher degree (rare fan centres) are left alone
_KERNEL_HALVINGS = 60  # a point of a ring's kernel closer than 2^-60 to the kept vertex is below
                       # the floating-point resolution of the sphere's points
_PLACE_STEPS = 100     # pattern-search steps placing an inserted vertex in its ring's kernel


@dataclass
class Hierarchy:
    """A decimation: the coarse mesh and, round by round, which vertex went where.

    Attributes
    ----------
    faces : (m, 3) int64
        The coarse mesh's faces, in the input's vertex numbering.
    vertices : (k,) int64
        The input vertices the coarse mesh keeps.
    rounds : list of tuple
        One ``(removed, kept, ring_ptr, ring)`` per round, finest first: ``removed`` (r,) int64,
        the vertex ``kept[i]`` it was merged into, and the neighbours of ``removed[i]`` at its
        removal in ``ring[ring_ptr[i]:ring_ptr[i+1]]`` (counter-clockwise, ``kept[i]`` among
        them).
    kernel_insertions : int
        Removed vertices that :meth:`undo` put into their ring's kernel (the mean would have
        turned a triangle of their star over), counted over its calls.
    """

    faces: np.ndarray
    vertices: np.ndarray
    rounds: list
    kernel_insertions: int = 0

    def prolong(self, values, positions, *, unit: bool = False, embed: bool = False,
                settle=None):
        """Carry per-vertex values from the coarse mesh back to every vertex.

        Rounds are undone coarsest first; each removed vertex takes the mean of its ring's values
        with its 3D mean value coordinates (Floater 2003: positive, and exact for a map that is
        affine near the vertex), its ring being complete by then.

        With ``embed`` (points on the sphere), a removed vertex whose star that mean turns over
        goes instead into the kernel of its ring, near the vertex it was merged into: that vertex
        is a corner of the ring and its fan over the ring was embedded, so every point close
        enough to it inside the ring's angle there has an embedded star (the inverse of the
        collapse, as a vertex split of progressive meshes). The removed vertices of one round
        have disjoint stars, so an embedded coarse map stays embedded round by round.

        Parameters
        ----------
        values : (n, d) float64
            Values on all n input vertices; only the coarse ones (``self.vertices``) are read.
        positions : (n, 3) float64
            The input's 3D positions (for the weights).
        unit : bool
            Renormalise each new value to unit length (points on the sphere).
        embed : bool
            Keep an embedded spherical map embedded (needs ``unit`` and ``d == 3``).
        settle : callable, optional
            ``settle(values, r)`` after round ``r`` is undone (:meth:`undo`), returning the
            values to go on from.

        Returns
        -------
        (n, d) float64
        """
        out = np.array(values, dtype=np.float64)
        for r in reversed(range(len(self.rounds))):
            out = self.undo(r, out, positions, unit=unit, embed=embed, settle=settle)
        return out

    def undo(self, r, out, positions, *, unit: bool = False, embed: bool = False,
             settle=None):
        """:meth:`prolong` of round ``r`` alone: the values ``out`` ``(n, d)`` (every vertex
        of the coarser rounds set) with that round's removed vertices set, in place; with
        ``settle``, ``settle(out, r)`` is called after it (and its result kept)."""
        removed, kept, ptr, ring = self.rounds[r]
        counts = np.diff(ptr)
        owner = np.repeat(np.arange(len(removed)), counts)
        nxt = np.arange(len(ring)) + 1
        nxt[ptr[1:] - 1] = ptr[:-1]                  # the ring is cyclic
        e = positions[ring] - positions[removed][owner]
        length = np.linalg.norm(e, axis=1)
        # a zero-length edge (coincident input points) would give a weight that overflows the
        # ring's sum: lengths floored far below any real edge
        length = np.maximum(length, max(1e-9 * float(np.median(length)), 1e-300)
                            if len(length) else 1e-300)
        cos = np.einsum("ij,ij->i", e, e[nxt]) / (length * length[nxt])
        half = np.tan(0.5 * np.arccos(np.clip(cos, -1.0, 1.0)))   # angle at the vertex
        prv = np.empty_like(nxt)
        prv[nxt] = np.arange(len(ring))
        w = np.maximum((half + half[prv]) / length, 1e-300)
        acc = np.zeros((len(removed), out.shape[1]))
        np.add.at(acc, owner, w[:, None] * out[ring])
        if unit:
            acc /= np.maximum(np.linalg.norm(acc, axis=1), 1e-300)[:, None]
        else:
            acc /= np.bincount(owner, w, minlength=len(removed))[:, None]
        if embed:
            acc, moved = _into_kernels(acc, out, kept, ptr, ring, owner, nxt, positions,
                                       removed)
            self.kernel_insertions += moved
        out[removed] = acc
        if settle is not None:
            out = settle(out, r)
        return out

    def round_faces(self, faces) -> list:
        """The mesh after each round is undone: entry ``r`` holds the faces ``(m_r, 3)`` of
        the mesh whose vertices are those of rounds ``r`` and coarser (``faces`` the input's:
        entry 0)."""
        out = [np.ascontiguousarray(faces, dtype=np.int64)]
        remap = np.arange(int(faces.max()) + 1)
        for removed, kept, _, _ in self.rounds[:-1]:
            f = out[-1]
            remap[:] = np.arange(len(remap))
            remap[removed] = kept
            f = remap[f]
            out.append(np.ascontiguousarray(
                f[(f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 2] != f[:, 0])]))
        return out


def _star_folds(x, out, ring, owner, nxt):
    """Per removed vertex (at ``x``), whether a triangle of its star is not counter-clockwise."""
    o = corner_orientation(np.stack([x[owner], out[ring], out[ring[nxt]]], axis=1))
    return np.bincount(owner, o <= 0, minlength=len(x)) > 0


def _into_kernels(x, out, kept, ptr, ring, owner, nxt, positions, removed):
    """Move each removed vertex whose star folds to the vertex it was merged into, plus a step
    into the ring's kernel there (halved until the star is embedded, at most
    ``_KERNEL_HALVINGS`` times).

    Near the kept vertex ``k`` the kernel is the wedge left of both ring edges at ``k`` (the
    other edges see ``k`` on their inner side, its fan being embedded); the sum of the two edges'
    unit inner normals, ``k × next`` and ``prev × k``, points into that wedge, whether the ring's
    angle at ``k`` is convex or reflex. Each is then placed by :func:`_place`. Returns the
    positions and how many were moved."""
    bad = np.flatnonzero(_star_folds(x, out, ring, owner, nxt))
    moved = len(bad)
    if not moved:
        return x, 0
    x = x.copy()
    first = bad.copy()
    at = np.flatnonzero(ring == kept[owner])[bad]      # the kept vertex is once in each ring
    prv = np.empty_like(nxt)
    prv[nxt] = np.arange(len(nxt))
    k, a, b = out[kept[bad]], out[ring[nxt[at]]], out[ring[prv[at]]]
    n1, n2 = np.cross(k, a), np.cross(b, k)
    # a ring neighbour on the kept vertex (a zero normal) contributes no direction
    d = (n1 / np.maximum(np.linalg.norm(n1, axis=1), 1e-300)[:, None]
         + n2 / np.maximum(np.linalg.norm(n2, axis=1), 1e-300)[:, None])
    d *= (0.5 * np.minimum(np.linalg.norm(a - k, axis=1), np.linalg.norm(b - k, axis=1))
          / np.maximum(np.linalg.norm(d, axis=1), 1e-300))[:, None]
    for _ in range(_KERNEL_HALVINGS):
        y = k + d
        x[bad] = y / np.linalg.norm(y, axis=1)[:, None]
        still = _star_folds(x, out, ring, owner, nxt)[bad]
        if not still.any():
            break
        bad, k, d = bad[still], k[still], 0.5 * d[still]
    _place(x, first, out, ptr, ring, positions, removed, _PLACE_STEPS)
    return x, moved


@numba.njit(cache=True)
def _star_energy(q, out, ring, lo, hi, cot):  # pragma: no cover - compiled
    """``Σ D / a`` over the star of a vertex at ``q`` (unit) with the ring ``ring[lo:hi]``:
    ``D`` the cotangent-weighted squared edge lengths (3D cotangents ``cot``), ``a`` the
    chord triangle's area towards the sphere; infinite when a triangle is not
    counter-clockwise. Scale-invariant, smallest for stars similar to the 3D one."""
    e = 0.0
    m = hi - lo
    for j in range(m):
        a = out[ring[lo + j]]
        b = out[ring[lo + (j + 1) % m]]
        det = (q[0] * (a[1] * b[2] - a[2] * b[1]) - q[1] * (a[0] * b[2] - a[2] * b[0])
               + q[2] * (a[0] * b[1] - a[1] * b[0]))
        if det <= 0.0:
            return np.inf
        d = 0.0
        for c in range(3):
            d += (cot[lo + j, 0] * (a[c] - b[c]) ** 2 + cot[lo + j, 1] * (b[c] - q[c]) ** 2
                  + cot[lo + j, 2] * (q[c] - a[c]) ** 2)
        e += d / det
    return e


@numba.njit(cache=True)
def _place_kernel(x, which, out, ptr, ring, cot, steps):  # pragma: no cover - compiled
    """Pattern search of each vertex ``which`` (at ``x``) over the sphere for the smallest
    :func:`_star_energy`, its ring held: a move is taken only when it lowers the energy, so the
    star stays embedded (its orientations are linear in the vertex, positive at both ends of
    a move and so along it). Steps start at half the distance to the nearest ring vertex, double after a
    move (up to half the mean distance to the ring) and halve after a miss."""
    for w in which:
        lo, hi = ptr[w], ptr[w + 1]
        q = x[w].copy()
        e = _star_energy(q, out, ring, lo, hi, cot)
        if not np.isfinite(e):
            continue
        top = 0.0
        step = np.inf
        for j in range(lo, hi):
            dist = np.sqrt(((out[ring[j]] - q) ** 2).sum())
            top += dist
            step = min(step, 0.5 * dist)
        top *= 0.5 / (hi - lo)          # half the mean distance to the ring
        for _ in range(steps):
            # a tangent basis at q
            t1 = np.empty(3)
            if abs(q[0]) < 0.9:
                t1[0], t1[1], t1[2] = 0.0, -q[2], q[1]
            else:
                t1[0], t1[1], t1[2] = -q[2], 0.0, q[0]
            t1 /= np.sqrt((t1 ** 2).sum())
            t2 = np.array([q[1] * t1[2] - q[2] * t1[1], q[2] * t1[0] - q[0] * t1[2],
                           q[0] * t1[1] - q[1] * t1[0]])
            moved = False
            for k in range(8):
                ang = k * np.pi / 4.0
                y = q + step * (np.cos(ang) * t1 + np.sin(ang) * t2)
                y /= np.sqrt((y ** 2).sum())
                e2 = _star_energy(y, out, ring, lo, hi, cot)
                if e2 < e:
                    q, e, moved = y, e2, True
                    break
            step = min(2.0 * step, top) if moved else 0.5 * step
        x[w] = q


def _place(x, which, out, ptr, ring, positions, removed, steps):
    """Move the vertices ``which`` (rows of ``x``, the removed vertices of a round) to the
    lowest :func:`_star_energy` their kernels offer (:func:`_place_kernel`), in place."""
    counts = np.diff(ptr)
    owner = np.repeat(np.arange(len(removed)), counts)
    nxt = np.arange(len(ring)) + 1
    nxt[ptr[1:] - 1] = ptr[:-1]
    a = positions[removed][owner]            # the star's 3D triangles (centre, ring j, j + 1)
    b, c = positions[ring], positions[ring[nxt]]
    cot = np.column_stack([_cot(b, c, a), _cot(c, a, b), _cot(a, b, c)])
    # cot[:, 0] weighs the edge (b, c) opposite the centre, [:, 1] (c, a), [:, 2] (a, b)
    _place_kernel(x, np.ascontiguousarray(which, dtype=np.int64), out, ptr, ring,
                  np.ascontiguousarray(cot), int(steps))


def _cot(u, v, w):
    """Cotangent of the angle at ``w`` of the triangles ``(u, v, w)``, clipped to ±1e3."""
    e1, e2 = u - w, v - w
    cross = np.linalg.norm(np.cross(e1, e2), axis=1)
    return np.clip(np.einsum("ij,ij->i", e1, e2) / np.maximum(cross, 1e-300), -1e3, 1e3)


@numba.njit(cache=True, _nrt=False)
def _neighbours(v, vf_ptr, vf_idx, faces, out):  # pragma: no cover - compiled
    """Neighbours of ``v`` (unordered, each once) into ``out``; returns their count."""
    m = 0
    for q in range(vf_ptr[v], vf_ptr[v + 1]):
        t = vf_idx[q]
        for c in range(3):
            w = faces[t, c]
            if w == v:
                continue
            seen = False
            for s in range(m):
                if out[s] == w:
                    seen = True
                    break
            if not seen:
                out[m] = w
                m += 1
    return m


@numba.njit(cache=True, _nrt=False)
def _cyclic_ring(v, vf_ptr, vf_idx, faces, out, at, a, b):  # pragma: no cover - compiled
    """Neighbours of ``v`` in counter-clockwise order (closed manifold: one cycle) into
    ``out[at:]``; returns their count. ``a``, ``b``: scratch of at least its degree."""
    m = vf_ptr[v + 1] - vf_ptr[v]
    for i in range(m):
        t = vf_idx[vf_ptr[v] + i]
        for c in range(3):
            if faces[t, c] == v:
                a[i] = faces[t, (c + 1) % 3]
                b[i] = faces[t, (c + 2) % 3]
    out[at] = a[0]
    for s in range(1, m):
        nxt = -1
        for i in range(m):
            if a[i] == out[at + s - 1]:
                nxt = b[i]
                break
        out[at + s] = nxt
    return m


@numba.njit(cache=True, _nrt=False)
def _collapse_ok(r, k, pos, vf_ptr, vf_idx, faces, cos_turn, sliver):  # pragma: no cover
    """Geometric checks of merging ``r`` into ``k``: no face around ``r`` turns over or thins."""
    for q in range(vf_ptr[r], vf_ptr[r + 1]):
        t = vf_idx[q]
        a, b, c = faces[t, 0], faces[t, 1], faces[t, 2]
        if a == k or b == k or c == k:
            continue
        # the face's normal before (a) and after (b) the merge
        a0, a1, a2 = _normal(pos, a, b, c)
        x0, x1, x2 = a, b, c
        if x0 == r:
            x0 = k
        elif x1 == r:
            x1 = k
        else:
            x2 = k
        u0 = pos[x1, 0] - pos[x0, 0]
        u1 = pos[x1, 1] - pos[x0, 1]
        u2 = pos[x1, 2] - pos[x0, 2]
        v0 = pos[x2, 0] - pos[x0, 0]
        v1 = pos[x2, 1] - pos[x0, 1]
        v2 = pos[x2, 2] - pos[x0, 2]
        b0, b1, b2 = u1 * v2 - u2 * v1, u2 * v0 - u0 * v2, u0 * v1 - u1 * v0   # _normal's
        w0 = pos[x2, 0] - pos[x1, 0]
        w1 = pos[x2, 1] - pos[x1, 1]
        w2 = pos[x2, 2] - pos[x1, 2]
        longest = max(u0 * u0 + u1 * u1 + u2 * u2, v0 * v0 + v1 * v1 + v2 * v2,
                      w0 * w0 + w1 * w1 + w2 * w2)
        area2 = np.sqrt(b0 ** 2 + b1 ** 2 + b2 ** 2)
        if area2 < 2.0 * sliver * longest:
            return False
        la = np.sqrt(a0 ** 2 + a1 ** 2 + a2 ** 2)
        lb = np.sqrt(b0 ** 2 + b1 ** 2 + b2 ** 2)
        if a0 * b0 + a1 * b1 + a2 * b2 < cos_turn * la * lb:
            return False
    return True


@numba.njit(cache=True, _nrt=False)
def _normal(pos, x0, x1, x2):  # pragma: no cover - compiled
    """``(p1 - p0) × (p2 - p0)`` of the triangle ``x0, x1, x2``, as three scalars."""
    u0 = pos[x1, 0] - pos[x0, 0]
    u1 = pos[x1, 1] - pos[x0, 1]
    u2 = pos[x1, 2] - pos[x0, 2]
    v0 = pos[x2, 0] - pos[x0, 0]
    v1 = pos[x2, 1] - pos[x0, 1]
    v2 = pos[x2, 2] - pos[x0, 2]
    return u1 * v2 - u2 * v1, u2 * v0 - u0 * v2, u0 * v1 - u1 * v0


@numba.njit(cache=True, _nrt=False)
def _lock(w, locked, near, vf_ptr, vf_idx, faces):  # pragma: no cover - compiled
    """Lock ``w`` and mark its neighbours ``near`` a locked vertex (so an edge whose 1-ring
    holds a locked vertex is refused without listing its neighbours)."""
    if locked[w]:
        return
    locked[w] = True
    for q in range(vf_ptr[w], vf_ptr[w + 1]):
        t = vf_idx[q]
        near[faces[t, 0]] = True
        near[faces[t, 1]] = True
        near[faces[t, 2]] = True


@numba.njit(cache=True)
def _select(edges, pos, vf_ptr, vf_idx, faces, deg, budget, max_degree, cos_turn,
            sliver):  # pragma: no cover - compiled
    """Greedy independent set of valid half-edge collapses, in the given edge order.

    Returns ``removed``, ``kept`` and the rings of the removed vertices (CSR)."""
    n = pos.shape[0]
    locked = np.zeros(n, np.bool_)
    near = np.zeros(n, np.bool_)     # a neighbour is locked
    mark = np.zeros(n, np.int64)
    removed = np.empty(budget, np.int64)
    kept = np.empty(budget, np.int64)
    ring_ptr = np.zeros(budget + 1, np.int64)
    ring = np.empty(budget * (max_degree + 2), np.int64)
    nu = np.empty(_MAX_SCAN, np.int64)
    nv = np.empty(_MAX_SCAN, np.int64)
    nu_r = np.empty(_MAX_SCAN, np.int64)     # _cyclic_ring's scratch
    nv_r = np.empty(_MAX_SCAN, np.int64)
    count = 0
    stamp = 0
    for e in range(edges.shape[0]):
        if count >= budget:
            break
        u, v = edges[e, 0], edges[e, 1]
        if locked[u] or locked[v] or near[u] or near[v]:
            continue
        if deg[u] > _MAX_SCAN or deg[v] > _MAX_SCAN:
            continue
        mu = _neighbours(u, vf_ptr, vf_idx, faces, nu)
        mv = _neighbours(v, vf_ptr, vf_idx, faces, nv)
        stamp += 1
        for s in range(mu):
            mark[nu[s]] = stamp
        common = 0
        low = 1 << 30
        for s in range(mv):
            if mark[nv[s]] == stamp:
                common += 1
                low = min(low, deg[nv[s]])
        if common != 2 or low <= 3 or mu + mv - 4 > max_degree:
            continue
        # remove the endpoint of lower degree first (keeps degrees even), else the other
        order0, order1 = (v, u) if deg[v] <= deg[u] else (u, v)
        done = False
        for attempt in range(2):
            r, k = (order0, order1) if attempt == 0 else (order1, order0)
            if deg[r] < 3:
                continue
            if _collapse_ok(r, k, pos, vf_ptr, vf_idx, faces, cos_turn, sliver):
                removed[count] = r
                kept[count] = k
                start = ring_ptr[count]
                nr = _cyclic_ring(r, vf_ptr, vf_idx, faces, ring, start, nu_r, nv_r)
                ring_ptr[count + 1] = start + nr
                count += 1
                done = True
                break
        if done:
            _lock(u, locked, near, vf_ptr, vf_idx, faces)
            _lock(v, locked, near, vf_ptr, vf_idx, faces)
            for s in range(mu):
                _lock(nu[s], locked, near, vf_ptr, vf_idx, faces)
            for s in range(mv):
                _lock(nv[s], locked, near, vf_ptr, vf_idx, faces)
    return removed[:count], kept[:count], ring_ptr[:count + 1], ring[:ring_ptr[count]]


def _vertex_faces(faces: np.ndarray, n: int):
    """The faces around each vertex (CSR ``ptr``, ``idx``), each vertex's in increasing order."""
    flat = faces.ravel()
    ptr = np.zeros(n + 1, np.int64)
    np.cumsum(np.bincount(flat, minlength=n), out=ptr[1:])
    return ptr, _bucket_faces(flat, ptr)


@numba.njit(cache=True)
def _bucket_faces(flat, ptr):  # pragma: no cover - compiled
    """Counting sort of the corners by vertex: the face of each, in corner order (as a stable
    argsort of ``flat``, divided by 3, but in linear time)."""
    fill = ptr[:-1].copy()
    idx = np.empty(len(flat), np.int64)
    for c in range(len(flat)):
        v = flat[c]
        idx[fill[v]] = c // 3
        fill[v] += 1
    return idx


def shortest_first(p: np.ndarray, e: np.ndarray) -> np.ndarray:
    """The order of the edges ``e`` by squared length rounded to 9 decimals relative to the mean,
    ties in edge order: the order (hence the coarse mesh) does not change with a rotation or
    scaling of the input.

    The rounded lengths are sorted as integers ``rint(1e9 · length / mean)`` with the edge index
    in the low bits, one plain sort of distinct keys (a stable argsort of the floats gives the
    same order, slower); where they would not fit 63 bits, by that argsort."""
    d = p[e[:, 0]] - p[e[:, 1]]
    length = np.einsum("ij,ij->i", d, d)
    relative = length / length.mean()
    scaled = np.rint(relative * 1e9)            # np.round(relative, 9) before its division
    bits = max(int(len(e) - 1).bit_length(), 1)
    if scaled.max() >= 2.0 ** (62 - bits):
        return np.argsort(np.round(relative, 9), kind="stable")
    key = np.left_shift(scaled.astype(np.int64), bits) | np.arange(len(e), dtype=np.int64)
    return np.sort(key) & np.int64((1 << bits) - 1)


def decimate(positions: np.ndarray, faces: np.ndarray, target: int, *,
             shape: bool = True) -> Hierarchy:
    """Decimate a closed manifold triangle mesh to about ``target`` vertices, keeping its topology.

    Parameters
    ----------
    positions : (n, 3) float64
    faces : (m, 3) int64
        Closed, manifold, consistently wound; every vertex used.
    target : int
        Vertices to keep (at least 4). Fewer collapses are made when no more pass the checks.
    shape : bool
        Refuse collapses that turn a triangle's normal by more than 60° or leave a sliver
        (False: only the link condition and the degrees are checked, for a hierarchy whose
        prolongation keeps the map embedded whatever the coarse mesh's shape).

    Returns
    -------
    Hierarchy
    """
    p = np.ascontiguousarray(positions, dtype=np.float64)
    f = np.ascontiguousarray(faces, dtype=np.int64)
    n = len(p)
    alive = n
    rounds = []
    target = max(int(target), 4)
    turn_sliver = (_COS_TURN, _SLIVER) if shape else (-2.0, 0.0)
    while alive > target:
        deg = np.bincount(f.ravel(), minlength=n)    # closed manifold: faces = neighbours
        e = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
        e = e[e[:, 0] < e[:, 1]]                     # each undirected edge once
        e = np.ascontiguousarray(e[shortest_first(p, e)])
        ptr, idx = _vertex_faces(f, n)
        removed, kept, ring_ptr, ring = _select(e, p, ptr, idx, f, deg, alive - target,
                                                _MAX_DEGREE, *turn_sliver)
        if not len(removed):
            break
        remap = np.arange(n)
        remap[removed] = kept
        f = remap[f]
        f = f[(f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 2] != f[:, 0])]
        rounds.append((removed, kept, ring_ptr, ring))
        alive -= len(removed)
    vertices = np.unique(f)
    return Hierarchy(np.ascontiguousarray(f), vertices, rounds)
