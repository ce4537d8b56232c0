"""Density weighting of the wavelet coefficients: spend bits where the input's surfels are.

The grid samples the sphere uniformly, but a spherical map squeezes some parts of the surface
(limbs, ears, thin parts) into little of the sphere, so there many input surfels share few grid
points. Point-to-plane distortion is averaged over the *input* surfels in one direction and over
the *decoded* (grid) points in the other; with ``d`` the input's relative surfel density on the
sphere (surfels per unit area over their mean) the first weighs a grid region's squared error by
``d``, the second by 1. Minimising ``mix · (first) + (1 − mix) · (second)`` weighs the error at a
grid point by

``w = mix · d + 1 − mix``  (:data:`DENSITY_MIX`)

and a coefficient multiplied by ``√w`` before the zerotree coder's uniform thresholds gets its
share of the bits (the decoder divides it back out). ``mix`` balances the two directions: with
a smaller one the first limits PSNR_D2, with a larger one the second; it was chosen by
measurement on a model with thin limbs at several rates.

The field
---------
``d`` is counted in the Voronoi cells of the vertices of a coarse icosphere (level
:func:`field_level`: at most 4, at most one field vertex per 16 surfels), ``log2 w`` rounded to an
integer (finer steps gain nothing measurable) and clipped to [:data:`Q_MIN`, :data:`Q_MAX`], and
interpolated to the grid in the log domain along the icosphere's edge bisections. It is stored in
the container (:func:`pack_field`): each vertex's value minus the floor of its edge parents' mean,
adaptively arithmetic coded (a few hundred bytes at most). A model the map samples
evenly gains less from weighting than the field costs, so :func:`weighting_gain` estimates the
gain and the encoder weights only above :data:`MIN_GAIN_DB`.
"""

from __future__ import annotations

import functools
import math

import numpy as np
from ..jit import njit

from ..errors import BitstreamError, InputError
from ..validate import as_array
from .entropy import dec_bit, dec_init, enc_bit, enc_flush, new_encoder, new_models
from ..geometry.icosphere import icosphere, vertex_count

__all__ = ["DENSITY_MIX", "Q_MIN", "Q_MAX", "MAX_FIELD_LEVEL", "SURFELS_PER_FIELD_VERTEX",
           "MIN_GAIN_DB", "relative_density", "field_level", "weight_field", "weighting_gain",
           "vertex_scales", "pack_field", "unpack_field"]

DENSITY_MIX = 0.8
"""Share of the input-surfel direction in the weight ``w = mix · d + 1 − mix``."""
Q_MIN, Q_MAX = -3, 12
"""Range of the stored ``round(log2 w)``."""
MAX_FIELD_LEVEL = 4
"""Finest icosphere level of the weight field (a coarser field blurs the density of thin parts
and loses PSNR_D2 on them)."""
SURFELS_PER_FIELD_VERTEX = 16
"""The field has at most one vertex per this many input surfels (so its bytes stay a small share
of the stream at any rate worth weighting)."""
MIN_GAIN_DB = 1.0
"""Weight only when :func:`weighting_gain` reaches this many dB."""

_CLASSES = 5          # context classes by field level (levels >= 4 share the last)
_PER_CLASS = 6        # zero flag, sign, 4 unary positions
N_CONTEXTS = _CLASSES * _PER_CLASS


@functools.lru_cache(maxsize=MAX_FIELD_LEVEL + 1)
def _cell_areas(level: int) -> np.ndarray:
    """Spherical areas of the Voronoi cells of a level's icosphere vertices (sum 4π)."""
    from scipy.spatial import SphericalVoronoi

    areas = SphericalVoronoi(icosphere(level).vertices).calculate_areas()
    areas.flags.writeable = False
    return areas


def relative_density(sphere_points, level: int) -> np.ndarray:
    """Relative surfel density on the sphere in the Voronoi cells of a coarse icosphere's vertices.

    Parameters
    ----------
    sphere_points : (n, 3) float64
        The input surfels' images on the unit sphere.
    level : int
        Icosphere level of the cells.

    Returns
    -------
    (10·4^level + 2,) float64
        Surfels per unit area of each cell over their mean ``n / 4π`` (mean 1 over the sphere).
    """
    from scipy.spatial import cKDTree      # encoding only: a decode does not load scipy.spatial

    u = as_array(sphere_points, "sphere_points", shape=(None, 3), min_len=1)
    ico = icosphere(level)
    _, cell = cKDTree(ico.vertices).query(u)
    count = np.bincount(cell, minlength=ico.n_vertices)
    return count / (_cell_areas(level) * len(u) / (4.0 * np.pi))


def field_level(n_surfels: int, grid_level: int) -> int:
    """Level of the weight field for a model of ``n_surfels`` coded on a ``grid_level`` grid."""
    level = 0
    while (level < min(MAX_FIELD_LEVEL, grid_level)
           and vertex_count(level + 1) * SURFELS_PER_FIELD_VERTEX <= n_surfels):
        level += 1
    return level


def weight_field(sphere_points, level: int, *, mix: float = DENSITY_MIX) -> np.ndarray:
    """The quantised field ``clip(round(log2(mix · d + 1 − mix)))`` at a level's vertices.

    Parameters
    ----------
    sphere_points : (n, 3) float64
    level : int
    mix : float
        In [0, 1]; 0 gives a flat field.

    Returns
    -------
    (10·4^level + 2,) int64
    """
    if not (0.0 <= mix <= 1.0):
        raise InputError(f"mix must be in [0, 1], got {mix!r}")
    d = relative_density(sphere_points, level)
    return np.clip(np.rint(np.log2(mix * d + 1.0 - mix)), Q_MIN, Q_MAX).astype(np.int64)


def weighting_gain(field, level: int) -> float:
    """Estimated PSNR gain in dB of coding with the weights over coding without them.

    With optimal bit allocation at high rate the weighted squared error falls by the ratio of the
    arithmetic to the geometric mean (over the sphere's area) of the weights.

    Parameters
    ----------
    field : (10·4^level + 2,) int
        ``log2`` of the weights (:func:`weight_field`).
    level : int

    Returns
    -------
    float
    """
    q = np.asarray(field, np.float64)
    a = _cell_areas(level)
    a = a / a.sum()
    return float(10.0 * math.log10(float(a @ 2.0 ** q)) - 10.0 * math.log10(2.0) * float(a @ q))


def vertex_scales(field, field_lvl: int, grid_level: int) -> np.ndarray:
    """Per-grid-vertex coefficient scales ``√w``, the field interpolated in the log domain.

    Parameters
    ----------
    field : (10·4^field_lvl + 2,) int
    field_lvl, grid_level : int
        ``field_lvl <= grid_level``.

    Returns
    -------
    (10·4^grid_level + 2,) float64
    """
    if not (0 <= field_lvl <= grid_level):
        raise InputError(f"the field's level {field_lvl} must be 0 … the grid level {grid_level}")
    ico = icosphere(grid_level)
    out = np.empty(ico.n_vertices)
    out[:vertex_count(field_lvl)] = np.asarray(field, np.float64)
    ep = ico.edge_parents
    for j in range(field_lvl + 1, grid_level + 1):
        lo, hi = vertex_count(j - 1), vertex_count(j)
        out[lo:hi] = 0.5 * (out[ep[lo:hi, 0]] + out[ep[lo:hi, 1]])
    return 2.0 ** (0.5 * out)


# ------------------------------------------------------------------ storage
def _residuals(q: np.ndarray, level: int) -> tuple[np.ndarray, np.ndarray]:
    ico = icosphere(level)
    r = q.copy()
    ep = ico.edge_parents
    for j in range(1, level + 1):
        lo, hi = vertex_count(j - 1), vertex_count(j)
        r[lo:hi] = q[lo:hi] - np.floor_divide(q[ep[lo:hi, 0]] + q[ep[lo:hi, 1]], 2)
    return r, np.minimum(ico.level_of, _CLASSES - 1).astype(np.int64)


@njit(cache=True)
def encode_residuals(r, cls, buf, st, models):
    """Code density residuals, each in the contexts of its class: zero flag, sign, then its
    magnitude in unary (the coder allows values beyond ``[Q_MIN, Q_MAX]``).

    Parameters
    ----------
    r : ndarray of int64, shape (n,)
        The residuals.
    cls : ndarray of int64, shape (n,)
        The context class of each.
    buf : ndarray of uint8
        The output buffer.
    st : ndarray
        An encoder state (:func:`~surfidx.codec.entropy.new_encoder`).
    models : ndarray
        Models of :data:`N_CONTEXTS` contexts (:func:`~surfidx.codec.entropy.new_models`).

    Returns
    -------
    int
        The bytes written to ``buf``.
    """
    for i in range(r.shape[0]):
        base = cls[i] * _PER_CLASS
        v = r[i]
        enc_bit(st, buf, models, base, 1 if v != 0 else 0)
        if v == 0:
            continue
        enc_bit(st, buf, models, base + 1, 1 if v < 0 else 0)
        m = abs(v) - 1
        for k in range(m):
            enc_bit(st, buf, models, base + 2 + min(k, 3), 1)
        if m < Q_MAX - Q_MIN:
            enc_bit(st, buf, models, base + 2 + min(m, 3), 0)
    return enc_flush(st, buf)


@njit(cache=True)
def _decode_residuals(data, cls, out, models):
    st = np.zeros(4, dtype=np.int64)
    if not dec_init(st, data):
        return False
    for i in range(out.shape[0]):
        base = cls[i] * _PER_CLASS
        if dec_bit(st, data, models, base) == 0:
            out[i] = 0
            continue
        neg = dec_bit(st, data, models, base + 1)
        m = 0
        while m < Q_MAX - Q_MIN and dec_bit(st, data, models, base + 2 + min(m, 3)) == 1:
            m += 1
        out[i] = -(m + 1) if neg else m + 1
    return True


def pack_field(field, level: int) -> bytes:
    """Serialise a weight field: one byte of level, then its arithmetic-coded residuals.

    Parameters
    ----------
    field : (10·4^level + 2,) int
        Values in [:data:`Q_MIN`, :data:`Q_MAX`].
    level : int
        0 … :data:`MAX_FIELD_LEVEL`.

    Returns
    -------
    bytes
    """
    if not (isinstance(level, (int, np.integer)) and 0 <= level <= MAX_FIELD_LEVEL):
        raise InputError(f"the weight field's level must be 0 … {MAX_FIELD_LEVEL}, got {level!r}")
    q = as_array(field, "field", dtype=np.int64, shape=(vertex_count(level),))
    if q.min() < Q_MIN or q.max() > Q_MAX:
        raise InputError(f"weight field values must lie in [{Q_MIN}, {Q_MAX}], got "
                         f"[{q.min()}, {q.max()}]")
    r, cls = _residuals(q, int(level))
    buf = np.zeros(16 * len(r) + 16, np.uint8)
    size = encode_residuals(r, cls, buf, new_encoder(), new_models(N_CONTEXTS))
    return bytes([int(level)]) + bytes(buf[:size])


def unpack_field(data: bytes, *, path=None) -> tuple[np.ndarray, int]:
    """Read a field written by :func:`pack_field`.

    Returns
    -------
    field : (10·4^level + 2,) int64
    level : int

    Raises
    ------
    BitstreamError
        An empty record, a level out of range or values that leave the stored range.
    """
    if len(data) < 1 or data[0] > MAX_FIELD_LEVEL:
        raise BitstreamError("corrupt density-weight field (bad level)", path=path)
    level = int(data[0])
    n = vertex_count(level)
    r = np.zeros(n, np.int64)
    cls = np.minimum(icosphere(level).level_of, _CLASSES - 1).astype(np.int64)
    if not _decode_residuals(np.frombuffer(bytes(data[1:]), np.uint8), cls, r,
                             new_models(N_CONTEXTS)):
        raise BitstreamError("corrupt density-weight field (impossible code)", path=path)
    q = r.copy()
    ep = icosphere(level).edge_parents
    for j in range(1, level + 1):
        lo, hi = vertex_count(j - 1), vertex_count(j)
        q[lo:hi] = r[lo:hi] + np.floor_divide(q[ep[lo:hi, 0]] + q[ep[lo:hi, 1]], 2)
    if q.min() < Q_MIN or q.max() > Q_MAX:
        raise BitstreamError("corrupt density-weight field (values out of range)", path=path)
    return q, level
