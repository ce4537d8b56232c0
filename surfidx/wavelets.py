"""Lifted butterfly spherical wavelets (Schröder & Sweldens 1995) on the icosahedral grid.

Coefficient layout
------------------
Coefficients live in the vertex order of :func:`surfidx.icosphere.icosphere`: entries
``0 .. 11`` hold the level-0 scaling coefficients, entry ``v`` born at level ``j + 1`` (index in
``counts[j] .. counts[j+1] - 1``) holds its detail coefficient. Arrays are ``(n,)`` or ``(n, k)``
(``k`` layers transformed independently).

One analysis step, level ``j + 1 → j`` (``m`` runs over the vertices born at level ``j + 1``)
-----------------------------------------------------------------------------------------------
Predict
    ``d_m = x_m − Σ_i w_i x_{S_m,i}`` with the 8-point butterfly stencil ``S = ico.butterfly`` and
    weights :data:`~surfidx.icosphere.BUTTERFLY_WEIGHTS`.
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
(measured on a deterministic sample of up to :data:`NORM_SAMPLES` coefficients per level). A
quantisation error ``ε`` on any normalised coefficient then gives a grid error of Euclidean norm
``≈ |ε|`` whatever its level, so equal quantisation steps give equal distortion everywhere.

Inverse steps undo the forward steps in reverse order, so reconstruction is exact to rounding
(``TOL.reconstruction``).
"""

from __future__ import annotations

import functools

import numpy as np
import scipy.sparse as sp

from ._errors import InputError
from ._validate import as_array
from .icosphere import BUTTERFLY_WEIGHTS, _check_level, _vertex_areas, icosphere, vertex_count

__all__ = ["forward", "inverse", "level_norms", "scaling_integrals", "NORM_SAMPLES"]

NORM_SAMPLES = 16
"""Coefficients per level whose synthesis norms are averaged by :func:`level_norms`."""


class _Operators:
    """Per-level sparse predict/update matrices of the level-``L`` transform (cached)."""

    def __init__(self, level: int):
        ico = icosphere(level)
        counts = ico.counts
        self.level = level
        self.counts = counts
        self.predict = []   # predict[j]: (m_j, counts[j]) CSR, m_j = counts[j+1] - counts[j]
        self.update = []    # update[j]: (counts[j], m_j) CSR
        integrals = [None] * (level + 1)
        integrals[level] = np.asarray(_vertex_areas(level))
        for j in range(level - 1, -1, -1):
            lo, hi = counts[j], counts[j + 1]
            m = hi - lo
            st = ico.butterfly[lo:hi]
            rows = np.repeat(np.arange(m), 8)
            P = sp.csr_matrix((np.tile(BUTTERFLY_WEIGHTS, m), (rows, st.ravel())),
                              shape=(m, lo))
            self.predict.append(P)
            fine = integrals[j + 1]
            integrals[j] = fine[:lo] + P.T @ fine[lo:hi]
        self.predict.reverse()
        self.integrals = integrals
        for j in range(level):
            lo, hi = counts[j], counts[j + 1]
            m = hi - lo
            par = ico.edge_parents[lo:hi]
            i_m = integrals[j + 1][lo:hi]
            coarse = integrals[j]
            vals = np.stack([i_m / (2 * coarse[par[:, 0]]), i_m / (2 * coarse[par[:, 1]])], 1)
            U = sp.csr_matrix((vals.ravel(), (par.ravel(), np.repeat(np.arange(m), 2))),
                              shape=(lo, m))
            self.update.append(U)


@functools.lru_cache(maxsize=4)
def _operators(level: int) -> _Operators:
    return _Operators(level)


def _prepare(values, level, name):
    lev = _check_level(level)
    n = vertex_count(lev)
    arr = as_array(values, name)
    if arr.ndim not in (1, 2) or arr.shape[0] != n:
        raise InputError(f"{name} must have shape ({n},) or ({n}, k) for grid level {lev} "
                         f"(10·4^{lev} + 2 vertices), got {arr.shape}; resample to the level-{lev} "
                         "grid or pass the level the data was sampled at")
    return lev, arr


def _scales(level: int, lifted: bool) -> np.ndarray:
    return level_norms(level, lifted=lifted)[icosphere(level).level_of]


def _forward(x: np.ndarray, level: int, lifted: bool) -> None:
    ops = _operators(level)
    c = ops.counts
    for j in range(level - 1, -1, -1):
        lo, hi = c[j], c[j + 1]
        x[lo:hi] -= ops.predict[j] @ x[:lo]
        if lifted:
            x[:lo] += ops.update[j] @ x[lo:hi]


def _inverse(x: np.ndarray, level: int, lifted: bool) -> None:
    ops = _operators(level)
    c = ops.counts
    for j in range(level):
        lo, hi = c[j], c[j + 1]
        if lifted:
            x[:lo] -= ops.update[j] @ x[lo:hi]
        x[lo:hi] += ops.predict[j] @ x[:lo]


def forward(values, level: int, *, lifted: bool = True, normalized: bool = False) -> np.ndarray:
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

    Returns
    -------
    (n,) or (n, k) float64
        Coefficients in vertex order (see the module docstring); same shape as ``values``.

    Raises
    ------
    InputError
        On a wrong length for the level, a bad level, or NaN/infinite values.
    """
    lev, arr = _prepare(values, level, "values")
    x = arr.reshape(arr.shape[0], -1).copy()
    _forward(x, lev, bool(lifted))
    if normalized:
        x *= _scales(lev, bool(lifted))[:, None]
    return x.reshape(arr.shape)


def inverse(coeffs, level: int, *, lifted: bool = True, normalized: bool = False) -> np.ndarray:
    """Wavelet synthesis: the exact inverse of :func:`forward` with the same options.

    Parameters
    ----------
    coeffs : (n,) or (n, k) float64
        Coefficients in vertex order, ``n = 10·4^level + 2``.
    level : int
        Grid level ``L``.
    lifted, normalized : bool
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
    x = arr.reshape(arr.shape[0], -1).copy()
    if normalized:
        x /= _scales(lev, bool(lifted))[:, None]
    _inverse(x, lev, bool(lifted))
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
    lev = _check_level(level)
    j = _check_level(coarse_level, "coarse_level")
    if j > lev:
        raise InputError(f"coarse_level must be at most level={lev}, got {j}")
    return _operators(lev).integrals[j].copy()


@functools.lru_cache(maxsize=2 * 10)
def _level_norms(level: int, lifted: bool) -> np.ndarray:
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
    ``raw · level_norms(L)[level_of]``.

    Parameters
    ----------
    level : int
        Grid level ``L``.
    lifted : bool
        Of the lifted (default) or unlifted transform.

    Returns
    -------
    (L + 1,) float64
        Computed once per ``(L, lifted)`` and cached.
    """
    return _level_norms(_check_level(level), bool(lifted)).copy()
