"""Lifted butterfly spherical wavelets (Schröder & Sweldens 1995) on the icosahedral grid.

Coefficient layout
------------------
Coefficients live in the vertex order of :func:`surfidx.geometry.icosphere.icosphere`: entries
``0 .. 11`` hold the level-0 scaling coefficients, entry ``v`` born at level ``j + 1`` (index in
``counts[j] .. counts[j+1] - 1``) holds its detail coefficient. Arrays are ``(n,)`` or ``(n, k)``
(``k`` layers transformed independently).

One analysis step, level ``j + 1 → j`` (``m`` runs over the vertices born at level ``j + 1``)
-----------------------------------------------------------------------------------------------
Predict
    ``d_m = x_m − Σ_i w_i x_{S_m,i}`` with the 8-point butterfly stencil ``S = ico.butterfly`` and
    weights :data:`~surfidx.geometry.icosphere.BUTTERFLY_WEIGHTS`.
Update (``lifted=True`` only)
    ``s_a += σ_{m,a} d_m`` and ``s_b += σ_{m,b} d_m`` for the two edge parents ``a, b`` of ``m``,
    with ``σ_{m,a} = I_{j+1,m} / (2 I_{j,a})``.

Derivation of the update weights: the primal scaling functions are those of interpolating
subdivision with the butterfly rule, ``φ_{j,v} = φ_{j+1,v} + Σ_m w_{m,v} φ_{j+1,m}``, so their
integrals obey ``I_{j,v} = I_{j+1,v} + Σ_m w_{m,v} I_{j+1,m}`` (``w_{m,v}`` the stencil weight of
``v`` in ``S_m``). At the finest level ``L`` we take ``I_{L,v}`` = one third of the spherical area
of the triangles around ``v`` (the lumped-mass quadrature of the piecewise linear interpolant;
``Σ I_{L,v} = 4π``). After the update the primal wavelet is
``ψ_m = φ_{j+1,m} − σ_{m,a} φ_{j,a} − σ_{m,b} φ_{j,b}``, and with the σ above each parent cancels
half of ``∫ψ``: ``∫ψ_m = I_{j+1,m} − I_{j+1,m}/2 − I_{j+1,m}/2 = 0``. Hence the level-0 scaling
coefficients carry the whole integral: ``Σ_v I_{0,v} s_{0,v} = Σ_v I_{L,v} x_v`` (tested). The
integrals, hence the update weights, depend on the finest level ``L`` as well as on ``j``.

Normalisation (``normalized=True``)
-----------------------------------
Coefficient ``v`` is multiplied by ``level_norms(L)[level_of[v]]``, the root-mean-square
Euclidean norm (over the grid samples) of the synthesis of a unit coefficient of that level
(measured on a deterministic sample of up to :data:`NORM_SAMPLES` coefficients per level, and
stored as a constant table so that it is identical for encoder and decoder). A
quantisation error ``ε`` on any normalised coefficient then gives a grid error of Euclidean norm
``≈ |ε|`` whatever its level, so equal quantisation steps give equal distortion everywhere.

Local frames (``frames=True``)
------------------------------
The first three layers are then geometry (x, y, z in any rigid frame). After each analysis step
the 3-vector of details ``d_m`` of every vertex born at level ``j + 1`` is expressed in a local
frame of the level-``j`` approximation (the updated coarse values, which the synthesis has
before it needs the details): the normal ``n_m`` (the sum of the area-weighted vertex normals of
the edge parents ``a, b`` on the level-``j`` grid surface), the edge direction ``x_b − x_a`` made
orthogonal to it, and their cross product. The tangential components are multiplied by
``tangent_weight``. Point-to-plane distortion ignores displacements along the surface, and on a
spherical map most of the fine-level detail energy is tangential, so a weight below 1 spends the
bits on the normal components.
The frames are orthonormal (a degenerate normal or edge falls back to a fixed axis), so the
transform stays exactly invertible. :func:`forward`/:func:`inverse` take the frames from the exact
coarse values, so a decoder working from quantised ones computes slightly different frames, which
moves a detail by its length times the frames' angular error: on thin shapes at low rates that
can displace whole parts, which the closed-loop frames below avoid.

Closed-loop frames (:func:`forward_anchored`, what the codec uses) take the frames of level
``j + 1`` from the level-``j`` approximation synthesised from the *coded* coefficients quantised to
an anchor bit plane ``anchors[j]`` (:func:`choose_anchors`: a few planes below where that level's
largest details become significant). A decoder that has every plane down to ``anchors[j]``
reproduces them bit for bit (:func:`surfidx.codec.zerotree.anchor_values`), so encoder and decoder
disagree only at rates below the anchor, where the level's details are still mostly zero.

Inverse steps undo the forward steps in reverse order, so reconstruction is exact to rounding
(``TOL.reconstruction``).
"""

from __future__ import annotations

import functools

import numpy as np
import scipy.sparse as sp
from ..jit import njit

from ..errors import InputError
from ..validate import as_array
from ..geometry.icosphere import BUTTERFLY_WEIGHTS, check_level, level_vertex_areas, icosphere, vertex_count

__all__ = ["forward", "inverse", "level_norms", "scaling_integrals", "NORM_SAMPLES",
           "forward_anchored", "inverse_anchored", "choose_anchors", "ANCHOR_OFFSET"]

NORM_SAMPLES = 16
"""Coefficients per level whose synthesis norms are averaged by :func:`level_norms`."""


class _Operators:
    """Per-level sparse predict/update matrices of the level-``L`` transform (cached)."""

    def __init__(self, level: int):
        ico = icosphere(level)
        counts = ico.counts
        self.level = level
        self.counts = counts
        # predict[j]: (m_j, counts[j]) CSR, m_j = counts[j+1] - counts[j]; the same matrix at
        # every level above j (:func:`_predict`)
        self.predict = [_predict(j) for j in range(level)]
        self.update = []    # update[j]: (counts[j], m_j) CSR
        integrals = [None] * (level + 1)
        integrals[level] = np.asarray(level_vertex_areas(level))
        for j in range(level - 1, -1, -1):
            lo, hi = counts[j], counts[j + 1]
            fine = integrals[j + 1]
            integrals[j] = fine[:lo] + self.predict[j].T @ fine[lo:hi]
        self.integrals = integrals
        for j in range(level):
            lo, hi = counts[j], counts[j + 1]
            m = hi - lo
            par = ico.edge_parents[lo:hi]
            i_m = integrals[j + 1][lo:hi]
            coarse = integrals[j]
            vals = np.stack([i_m / (2 * coarse[par[:, 0]]), i_m / (2 * coarse[par[:, 1]])], 1)
            # the CSR of entries (par[i, 0], i) and (par[i, 1], i), as scipy's COO conversion
            # orders them (rows ascending, columns ascending in a row; an edge's two ends differ)
            rows = par.ravel()
            order = np.argsort(rows, kind="stable")
            indptr = np.zeros(lo + 1, dtype=np.int64)
            np.cumsum(np.bincount(rows, minlength=lo), out=indptr[1:])
            self.update.append(_csr(vals.ravel()[order], order // 2, indptr, (lo, m)))


def _csr(data, indices, indptr, shape):
    """A CSR matrix from arrays already in canonical order (sorted, distinct columns in each
    row), as scipy's COO conversion gives them (and with its index type)."""
    return sp.csr_matrix((data, indices, indptr), shape=shape)


@functools.lru_cache(maxsize=10)
def _predict(j: int):
    """The (m_j, counts[j]) CSR butterfly prediction of the vertices born at level ``j + 1``
    from the level-``j`` ones (:data:`BUTTERFLY_WEIGHTS` on the stencil
    ``icosphere(j + 1).butterfly``); weights of a column that appears twice in a stencil
    summed, as scipy's COO conversion sums them."""
    ico = icosphere(j + 1)
    lo, hi = int(ico.counts[j]), int(ico.counts[j + 1])
    m = hi - lo
    st = ico.butterfly[lo:hi]
    order = np.argsort(st, axis=1, kind="stable")
    cols = np.take_along_axis(st, order, 1)
    weights = np.asarray(BUTTERFLY_WEIGHTS, np.float64)[order]
    if np.any(cols[:, 1:] == cols[:, :-1]):
        rows = np.repeat(np.arange(m), 8)
        return sp.csr_matrix((np.tile(BUTTERFLY_WEIGHTS, m), (rows, st.ravel())),
                             shape=(m, lo))
    return _csr(weights.ravel(), cols.ravel(), np.arange(0, 8 * m + 1, 8), (m, lo))


@functools.lru_cache(maxsize=4)
def _operators(level: int) -> _Operators:
    return _Operators(level)


def _prepare(values, level, name):
    lev = check_level(level)
    n = vertex_count(lev)
    arr = as_array(values, name)
    if arr.ndim not in (1, 2) or arr.shape[0] != n:
        raise InputError(f"{name} must have shape ({n},) or ({n}, k) for grid level {lev} "
                         f"(10·4^{lev} + 2 vertices), got {arr.shape}; resample to the level-{lev} "
                         "grid or pass the level the data was sampled at")
    return lev, arr


def _scales(level: int, lifted: bool) -> np.ndarray:
    return level_norms(level, lifted=lifted)[icosphere(level).level_of]


@njit(cache=True)
def _vertex_normals(p, faces, n_vertices):
    """(n_vertices, 3) area-weighted vertex normals of the triangles ``faces`` over ``p``."""
    vn = np.zeros((n_vertices, 3))
    for t in range(faces.shape[0]):
        a, b, c = faces[t, 0], faces[t, 1], faces[t, 2]
        ux, uy, uz = p[b, 0] - p[a, 0], p[b, 1] - p[a, 1], p[b, 2] - p[a, 2]
        vx, vy, vz = p[c, 0] - p[a, 0], p[c, 1] - p[a, 1], p[c, 2] - p[a, 2]
        nx, ny, nz = uy * vz - uz * vy, uz * vx - ux * vz, ux * vy - uy * vx
        for v in (a, b, c):
            vn[v, 0] += nx
            vn[v, 1] += ny
            vn[v, 2] += nz
    return vn


@njit(cache=True)
def _rotate(x, g, lo, hi, parents, vn, weight, forward):
    """Express (forward) or restore the detail vectors ``x[lo:hi, :3]`` in their local frames.

    The frames come from the coarse geometry ``g[:lo, :3]`` (with vertex normals ``vn``).

    Frame of vertex ``m``: normal ``n`` = the sum of its edge parents' vertex normals, tangent
    ``t`` = the parents' edge made orthogonal to ``n``, binormal ``n × t``. A normal (or tangent)
    shorter than 1e-12 of the longest falls back to the x axis (or the axis least aligned with
    ``n``), so every frame is orthonormal. Tangential components are multiplied (forward) or
    divided by ``weight``.
    """
    top = 0.0
    for v in range(vn.shape[0]):
        top = max(top, np.sqrt(vn[v, 0] ** 2 + vn[v, 1] ** 2 + vn[v, 2] ** 2))
    for m in range(lo, hi):
        a, b = parents[m, 0], parents[m, 1]
        nx, ny, nz = vn[a, 0] + vn[b, 0], vn[a, 1] + vn[b, 1], vn[a, 2] + vn[b, 2]
        ln = np.sqrt(nx * nx + ny * ny + nz * nz)
        if ln > 1e-12 * top and ln > 0.0:
            nx, ny, nz = nx / ln, ny / ln, nz / ln
        else:
            nx, ny, nz = 1.0, 0.0, 0.0
        ex, ey, ez = g[b, 0] - g[a, 0], g[b, 1] - g[a, 1], g[b, 2] - g[a, 2]
        el = np.sqrt(ex * ex + ey * ey + ez * ez)
        dot = ex * nx + ey * ny + ez * nz
        tx, ty, tz = ex - dot * nx, ey - dot * ny, ez - dot * nz
        lt = np.sqrt(tx * tx + ty * ty + tz * tz)
        if not (lt > 1e-6 * el and lt > 0.0):
            ax, ay, az = abs(nx), abs(ny), abs(nz)
            if ax <= ay and ax <= az:
                ex, ey, ez = 1.0, 0.0, 0.0
            elif ay <= az:
                ex, ey, ez = 0.0, 1.0, 0.0
            else:
                ex, ey, ez = 0.0, 0.0, 1.0
            dot = ex * nx + ey * ny + ez * nz
            tx, ty, tz = ex - dot * nx, ey - dot * ny, ez - dot * nz
            lt = np.sqrt(tx * tx + ty * ty + tz * tz)
        tx, ty, tz = tx / lt, ty / lt, tz / lt
        bx, by, bz = ny * tz - nz * ty, nz * tx - nx * tz, nx * ty - ny * tx
        dx, dy, dz = x[m, 0], x[m, 1], x[m, 2]
        if forward:
            x[m, 0] = dx * nx + dy * ny + dz * nz
            x[m, 1] = (dx * tx + dy * ty + dz * tz) * weight
            x[m, 2] = (dx * bx + dy * by + dz * bz) * weight
        else:
            dt, db = dy / weight, dz / weight
            x[m, 0] = dx * nx + dt * tx + db * bx
            x[m, 1] = dx * ny + dt * ty + db * by
            x[m, 2] = dx * nz + dt * tz + db * bz


def _frames_step(x: np.ndarray, level: int, j: int, weight: float, forward: bool,
                 geometry: np.ndarray | None = None) -> None:
    """Local-frame step of the vertices born at level ``j + 1``, frames from the level-``j``
    geometry ``geometry`` (default ``x[:counts[j]]``)."""
    ico = icosphere(level)
    lo, hi = int(ico.counts[j]), int(ico.counts[j + 1])
    g = np.ascontiguousarray(x[:lo, :3] if geometry is None else geometry[:lo, :3])
    vn = _vertex_normals(g, icosphere(j).faces, lo)
    _rotate(x, g, lo, hi, ico.edge_parents, vn, float(weight), forward)


def _forward(x: np.ndarray, level: int, lifted: bool, tangent_weight: float | None = None) -> None:
    ops = _operators(level)
    c = ops.counts
    for j in range(level - 1, -1, -1):
        lo, hi = c[j], c[j + 1]
        x[lo:hi] -= ops.predict[j] @ x[:lo]
        if lifted:
            x[:lo] += ops.update[j] @ x[lo:hi]
        if tangent_weight is not None:
            _frames_step(x, level, j, tangent_weight, True)


def _inverse(x: np.ndarray, level: int, lifted: bool, tangent_weight: float | None = None) -> None:
    ops = _operators(level)
    c = ops.counts
    for j in range(level):
        lo, hi = c[j], c[j + 1]
        if tangent_weight is not None:
            _frames_step(x, level, j, tangent_weight, False)
        if lifted:
            x[:lo] -= ops.update[j] @ x[lo:hi]
        x[lo:hi] += ops.predict[j] @ x[:lo]


def _check_frames(frames, tangent_weight, arr) -> float | None:
    if not frames:
        if tangent_weight != 1.0:
            raise InputError("tangent_weight applies only with frames=True (the detail vectors "
                             "of the first three layers in local frames)")
        return None
    if arr.ndim != 2 or arr.shape[1] < 3:
        raise InputError(f"frames=True needs at least three layers (x, y, z first), got an array "
                         f"of shape {arr.shape}")
    w = float(tangent_weight)
    if not (0.0 < w <= 1.0):
        raise InputError(f"tangent_weight must be in (0, 1], got {tangent_weight!r}")
    return w


def forward(values, level: int, *, lifted: bool = True, normalized: bool = False,
            frames: bool = False, tangent_weight: float = 1.0) -> np.ndarray:
    """Wavelet analysis of grid values.

    Parameters
    ----------
    values : (n,) or (n, k) float64
        Samples at the ``n = 10·4^level + 2`` grid vertices, in icosphere order.
    level : int
        Grid level ``L`` (0 … 9).
    lifted : bool
        Apply the update step (wavelets with vanishing integral); ``False`` gives the
        interpolating (unlifted) butterfly wavelets.
    normalized : bool
        Scale each coefficient by :func:`level_norms` of its level (equal quantisation step, equal
        distortion at every level).
    frames : bool
        Express the detail vectors of layers 0–2 (geometry) in local frames of the coarser
        approximation: normal, tangent, binormal (see the module docstring).
    tangent_weight : float
        Factor in (0, 1] on the two tangential components (``frames=True`` only).

    Returns
    -------
    (n,) or (n, k) float64
        Coefficients in vertex order (see the module docstring); same shape as ``values``.

    Raises
    ------
    InputError
        On a wrong length for the level, a bad level, NaN/infinite values, frames on fewer than
        three layers, or a tangent weight outside (0, 1] or without frames.
    """
    lev, arr = _prepare(values, level, "values")
    tw = _check_frames(frames, tangent_weight, arr)
    x = arr.reshape(arr.shape[0], -1).copy()
    _forward(x, lev, bool(lifted), tw)
    if normalized:
        x *= _scales(lev, bool(lifted))[:, None]
    return x.reshape(arr.shape)


def inverse(coeffs, level: int, *, lifted: bool = True, normalized: bool = False,
            frames: bool = False, tangent_weight: float = 1.0) -> np.ndarray:
    """Wavelet synthesis: the exact inverse of :func:`forward` with the same options.

    Parameters
    ----------
    coeffs : (n,) or (n, k) float64
        Coefficients in vertex order, ``n = 10·4^level + 2``.
    level : int
        Grid level ``L``.
    lifted, normalized, frames : bool
        As given to :func:`forward`.
    tangent_weight : float
        As given to :func:`forward`.

    Returns
    -------
    (n,) or (n, k) float64
        Grid values.

    Raises
    ------
    InputError
        On a wrong length for the level, a bad level, or NaN/infinite values.
    """
    lev, arr = _prepare(coeffs, level, "coeffs")
    tw = _check_frames(frames, tangent_weight, arr)
    x = arr.reshape(arr.shape[0], -1).copy()
    if normalized:
        x /= _scales(lev, bool(lifted))[:, None]
    _inverse(x, lev, bool(lifted), tw)
    return x.reshape(arr.shape)


def scaling_integrals(level: int, coarse_level: int = 0) -> np.ndarray:
    """Integrals ``I_{j,v}`` of the primal scaling functions of level ``j = coarse_level``.

    Parameters
    ----------
    level : int
        Finest (grid) level ``L``.
    coarse_level : int
        ``j`` in 0 … ``L``.

    Returns
    -------
    (10·4^j + 2,) float64
        Sums to 4π; ``Σ_v I_{0,v} s_{0,v}`` of the lifted coefficients equals the
        quadrature ``Σ_v I_{L,v} x_v`` of the grid function.
    """
    lev = check_level(level)
    j = check_level(coarse_level, "coarse_level")
    if j > lev:
        raise InputError(f"coarse_level must be at most level={lev}, got {j}")
    return _operators(lev).integrals[j].copy()


# level_norms(L) for L = 0 … 9, measured by measure_level_norms (9 significant digits).
# A constant table, so encoder and decoder use bit-identical scales on every platform;
# tests/test_wavelets.py checks it against a fresh measurement.
_NORM_TABLE = {
    True: (
        (1.0,),
        (1.5385667, 0.906357798,),
        (2.9331646, 1.37675998, 0.915275119,),
        (5.81399929, 2.66119893, 1.40680945, 0.917526566,),
        (11.605129, 5.3063524, 2.72502509, 1.41419047, 0.918231854,),
        (23.199302, 10.6095474, 5.43600504, 2.7406278, 1.41645767, 0.918188984,),
        (46.3931915, 21.2182078, 10.8698546, 5.46767703, 2.74541445, 1.41633485, 0.918040747,),
        (92.7836854, 42.436065, 21.7393208, 10.9334352, 5.47734736, 2.74514381, 1.41586706,
         0.918051759,),
        (185.566023, 84.8719669, 43.4785396, 21.8666004, 10.9528183, 5.47679325, 2.74412891,
         1.41589466, 0.918027763,),
        (371.131373, 169.743854, 86.9570401, 43.7331578, 21.9053867, 10.9517037, 5.47473327,
         2.74418357, 1.41581925, 0.917929209,),
    ),
    False: (
        (1.0,),
        (1.5385667, 1.0,),
        (2.9331646, 1.625, 1.0,),
        (5.81399929, 3.1769702, 1.625, 1.0,),
        (11.605129, 6.34273662, 3.17513975, 1.625, 1.0,),
        (23.199302, 12.6839106, 6.33881576, 3.17468318, 1.625, 1.0,),
        (46.3931915, 25.3676132, 12.6760393, 6.33783818, 3.17460597, 1.625, 1.0,),
        (92.7836854, 50.7351994, 25.3518678, 12.6740768, 6.33767247, 3.17460567, 1.625, 1.0,),
        (185.566023, 101.470395, 50.7037085, 25.3479421, 12.6737441, 6.33767172, 3.17460567,
         1.625, 1.0,),
        (371.131373, 202.94079, 101.407413, 50.6958569, 25.3472766, 12.6737426, 6.33767172,
         3.17460567, 1.625, 1.0,),
    ),
}


@functools.lru_cache(maxsize=4)
def measure_level_norms(level: int, lifted: bool) -> np.ndarray:
    """Measure the scale table (what :data:`_NORM_TABLE` holds; slow at the finest levels, so the
    codec reads the table)."""
    ico = icosphere(level)
    counts = ico.counts
    n = int(counts[-1])
    out = np.empty(level + 1)
    batch = max(1, min(NORM_SAMPLES, 2 ** 23 // n))
    for j in range(level + 1):
        lo = 0 if j == 0 else int(counts[j - 1])
        hi = int(counts[j])
        s = min(NORM_SAMPLES, hi - lo)
        idx = lo + (np.arange(s) * (hi - lo)) // s
        sq = []
        for start in range(0, s, batch):
            part = idx[start:start + batch]
            x = np.zeros((n, len(part)))
            x[part, np.arange(len(part))] = 1.0
            _inverse(x, level, lifted)
            sq.append(np.einsum("ij,ij->j", x, x))
        out[j] = np.sqrt(np.mean(np.concatenate(sq)))
    out.flags.writeable = False
    return out


def level_norms(level: int, *, lifted: bool = True) -> np.ndarray:
    """Per-level synthesis norms, the scale table of ``normalized=True``.

    ``level_norms(L)[j]`` is the root-mean-square, over a deterministic sample of up to
    :data:`NORM_SAMPLES` coefficients of level ``j``, of the Euclidean norm (over the level-``L``
    grid samples) of :func:`inverse` of a unit coefficient. Entry 0 is the level-0 scaling
    coefficients, entry ``j ≥ 1`` the details born at level ``j``. Normalised coefficients are
    ``raw · level_norms(L)[level_of]``. The values are a constant table in this module (9
    significant digits of that measurement), part of the coefficient convention.

    Parameters
    ----------
    level : int
        Grid level ``L``.
    lifted : bool
        Of the lifted (default) or unlifted transform.

    Returns
    -------
    (L + 1,) float64
    """
    return np.array(_NORM_TABLE[bool(lifted)][check_level(level)], dtype=np.float64)


# ---------------------------------------------------------------- closed-loop local frames
ANCHOR_OFFSET = 3
"""Planes below the level's top plane (see :func:`choose_anchors`). A larger offset takes the
frames from a finer approximation, which encoder and decoder share only at higher rates; chosen by
measurement on the genus-0 retrieval models, where it leaves the fewest models below no frames
at low rates (``benchmarks/codec_collection.py`` prints how many lose against no frames)."""


def _synthesise_to(y: np.ndarray, level: int, upto: int, geometries, weight: float) -> None:
    """Synthesis steps ``0 … upto-1`` in place on ``y`` (rows ``:counts[upto]``), details of level
    ``j + 1`` restored from the frames of ``geometries[j]``."""
    ops = _operators(level)
    c = ops.counts
    for j in range(upto):
        lo, hi = c[j], c[j + 1]
        _frames_step(y, level, j, weight, False, geometries[j])
        y[:lo] -= ops.update[j] @ y[lo:hi]
        y[lo:hi] += ops.predict[j] @ y[:lo]


def choose_anchors(coded: np.ndarray, level: int, step: float, *,
                   offset: int = ANCHOR_OFFSET) -> np.ndarray:
    """Anchor bit plane of each level's frames, non-increasing from coarse to fine.

    ``anchors[j]`` (frames of the details born at level ``j + 1``) is the bit plane of the 99th
    percentile of those details' coded vector lengths, less ``offset``: a decoder has those planes
    by the time the level's details start to be significant in numbers.

    Parameters
    ----------
    coded : (n, k) float64
        Coded (scaled) coefficients; the vector lengths of layers 0–2 are used.
    level : int
    step : float
        The zerotree coder's quantisation step.
    offset : int

    Returns
    -------
    (level,) int64
    """
    c = icosphere(level).counts
    norm = np.sqrt(np.einsum("ij,ij->i", coded[:, :3], coded[:, :3]))
    planes = np.zeros(level, np.int64)
    for j in range(level):
        top = float(np.percentile(norm[c[j]:c[j + 1]], 99)) / step
        planes[j] = max(int(np.floor(np.log2(top))) - offset, 0) if top >= 1 else 0
    return np.minimum.accumulate(planes)


def forward_anchored(coeffs, level: int, *, tangent_weight: float, scales, step: float,
                     anchors) -> np.ndarray:
    """Closed-loop local frames on lifted wavelet coefficients; returns coded coefficients.

    The coefficients of :func:`forward` (lifted, not normalised) with, as ``frames=True`` would
    give, the geometry details in local frames, except that the frames of the details born at
    level ``j + 1`` come from the level-``j`` approximation synthesised from the *coded*
    coefficients of levels ``<= j`` quantised to bit plane ``anchors[j]``
    (:func:`surfidx.codec.zerotree.quantize_to_plane`). A decoder that has decoded every plane down to
    ``anchors[j]`` computes bit-identical frames (:func:`inverse_anchored`), so its frames and the
    encoder's differ only below that rate.

    Parameters
    ----------
    coeffs : (n, k) float64
        ``forward(values, level)`` of the grid layers, geometry first (k >= 3).
    level : int
    tangent_weight : float
        In (0, 1].
    scales : (n,) float64
        Positive factor from a raw coefficient to the coded one (level norms times any weights).
    step : float
        The zerotree coder's quantisation step.
    anchors : (level,) int
        :func:`choose_anchors`, non-increasing.

    Returns
    -------
    (n, k) float64
        Coded coefficients (raw coefficients times ``scales``).
    """
    lev, arr = _prepare(coeffs, level, "coeffs")
    tw = _check_frames(True, tangent_weight, arr)
    s = np.asarray(scales, np.float64)[:, None]
    raw = arr.reshape(arr.shape[0], -1)
    coded = raw * s
    c = icosphere(lev).counts
    from .zerotree import quantize_to_plane

    geometries = []
    rotated = raw[:, :3].copy()   # rows lo:hi are rotated in place at level j
    for j in range(lev):
        lo, hi = c[j], c[j + 1]
        y = quantize_to_plane(coded[:lo, :3], int(anchors[j]), step) / s[:lo]
        _synthesise_to(y, lev, j, geometries, tw)
        geometries.append(y)
        _frames_step(rotated, lev, j, tw, True, y)
        coded[lo:hi, :3] = rotated[lo:hi] * s[lo:hi]
    return coded


def inverse_anchored(coded, level: int, *, tangent_weight: float, scales, anchors,
                     anchor_values) -> np.ndarray:
    """Synthesis undoing :func:`forward_anchored`.

    Parameters
    ----------
    coded : (n, k) float64
        Decoded coded coefficients.
    level : int
    tangent_weight : float
    scales : (n,) float64
    anchors : (level,) int
    anchor_values : callable
        ``anchor_values(plane, rows)`` gives the first ``rows`` coded coefficients (at least
        layers 0–2) quantised to ``plane`` exactly as the encoder's
        (:func:`surfidx.codec.zerotree.anchor_values`), or None when the decoder has not got that plane;
        then the level's frames come from the decoder's own approximation.

    Returns
    -------
    (n, k) float64
    """
    lev, arr = _prepare(coded, level, "coeffs")
    tw = _check_frames(True, tangent_weight, arr)
    s = np.asarray(scales, np.float64)[:, None]
    c = icosphere(lev).counts
    geometries: list = []
    for j in range(lev):
        q = anchor_values(int(anchors[j]), int(c[j]))
        if q is None:
            break
        y = q[:, :3] / s[:c[j]]
        _synthesise_to(y, lev, j, geometries, tw)
        geometries.append(y)
    x = arr.reshape(arr.shape[0], -1) / s
    ops = _operators(lev)
    for j in range(lev):
        lo, hi = c[j], c[j + 1]
        _frames_step(x, lev, j, tw, False, geometries[j] if j < len(geometries) else None)
        x[:lo] -= ops.update[j] @ x[lo:hi]
        x[lo:hi] += ops.predict[j] @ x[:lo]
    return x
