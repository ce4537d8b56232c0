"""Shape and texture descriptors from the spherical representation the codec uses.

The resampled layers on the icosahedral grid are decorrelated by a KLT (geometry and colour
separately), each KLT layer is sampled from the icosahedral grid onto a Driscoll–Healy grid and
expanded in spherical harmonics with pyshtools; the per-degree energies form the descriptor.

Invariance, by construction:

* rotation and reflection of the **sphere** (the map is canonical only up to a rotation): the
  energy of each degree ``l`` is invariant under any orthogonal transform of the sphere;
* rotation and reflection of the **object**: the KLT layers are the object's coordinates along its
  principal axes, which turn with the object (up to sign, which per-degree energies ignore);
* translation: the KLT mean is removed;
* scale: geometric layers are divided by the square root of the total geometric variance.

Descriptor vectors (float32), by kind:

``shape``  (3·(lmax+1),) — sqrt of per-degree energies of the three geometric KLT layers;
``texture`` (3·(lmax+1) + 3,) — the same for the colour KLT layers (colour units /255) followed by
           the mean colour /255; absent without colour;
``spectrum`` (3,) — the normalised geometric KLT eigenvalues (sum 1).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from ._errors import InputError
from ._validate import as_array
from .icosphere import icosphere
from .klt import KLT

__all__ = ["DescriptorSet", "describe_grid", "descriptor_distance", "DEFAULT_LMAX",
           "SH_NORMALIZATION", "DESCRIPTOR_VERSION"]

DEFAULT_LMAX = 24
SH_NORMALIZATION = "4pi"  # pyshtools norm=1: 4π-normalised real harmonics, no Condon-Shortley phase
DESCRIPTOR_VERSION = 1


@dataclass
class DescriptorSet:
    """The descriptor vectors of one model and the conventions that produced them.

    Attributes
    ----------
    vectors : dict of str -> (d,) float32
        By kind: ``shape``, ``spectrum`` and, with colour, ``texture``.
    params : dict
        The conventions that make two descriptors comparable: ``lmax``, ``normalization``,
        ``version`` (the grid level is not one: energies at a degree do not depend on it).
    """

    vectors: dict
    params: dict


def _dh_points(lmax: int) -> np.ndarray:
    """(n, 2n, 3) unit vectors of the Driscoll–Healy grid (sampling=2) of degree ``lmax``."""
    n = 2 * (lmax + 1)
    lat = np.radians(90.0 - 180.0 * np.arange(n) / n)
    lon = np.radians(360.0 * np.arange(2 * n) / (2 * n))
    clat, slat = np.cos(lat)[:, None], np.sin(lat)[:, None]
    return np.stack([clat * np.cos(lon), clat * np.sin(lon), np.broadcast_to(slat, (n, 2 * n))],
                    axis=-1)


@functools.lru_cache(maxsize=16)
def _ico_to_dh(level: int, lmax: int) -> sp.csr_matrix:
    """Sparse (n_dh, n_grid) barycentric interpolation from the icosahedral grid to the DH grid
    (exact point location in the icosphere's triangulation, built once per level and lmax)."""
    from .resample import locate

    ico = icosphere(level)
    q = _dh_points(lmax).reshape(-1, 3)
    tri, idx, bary = locate(ico.vertices, q, triangles=ico.faces)
    rows = np.repeat(np.arange(len(q)), 3)
    return sp.csr_matrix((bary.ravel(), (rows, tri[idx].ravel())), shape=(len(q), ico.n_vertices))


def _degree_energies(layers: np.ndarray, level: int, lmax: int) -> np.ndarray:
    """(k, lmax+1) per-degree energies (pyshtools, 4π norm) of grid layers (n_grid, k)."""
    import pyshtools as pysh

    n = 2 * (lmax + 1)
    dh = (_ico_to_dh(level, lmax) @ layers).reshape(n, 2 * n, -1)
    out = np.empty((layers.shape[1], lmax + 1))
    for j in range(layers.shape[1]):
        cilm = pysh.expand.SHExpandDH(np.ascontiguousarray(dh[:, :, j]), norm=1, sampling=2,
                                      csphase=1, lmax_calc=lmax)
        out[j] = pysh.spectralanalysis.spectrum(cilm, normalization="4pi", unit="per_l")
    return out


def describe_grid(values, level: int, *, lmax: int = DEFAULT_LMAX) -> DescriptorSet:
    """Descriptors of a model from its layers on the icosahedral grid.

    Parameters
    ----------
    values : (n_grid, 3) or (n_grid, 6) float64
        x, y, z (and r, g, b in 0..255) at the vertices of the level-``level`` icosphere.
    level : int
        Grid level.
    lmax : int
        Largest spherical-harmonic degree (keyword-only; stored in ``params``).

    Returns
    -------
    DescriptorSet

    Raises
    ------
    InputError
        On a wrong shape for the level, NaNs, a degenerate (zero-variance) geometry or a bad lmax.
    """
    ico = icosphere(level)
    values = as_array(values, "values", shape=(ico.n_vertices, None))
    if values.shape[1] not in (3, 6):
        raise InputError(f"values must have 3 or 6 columns (x y z [r g b]), got {values.shape[1]}")
    if not (isinstance(lmax, (int, np.integer)) and 2 <= lmax <= 128):
        raise InputError(f"lmax must be an integer in 2..128, got {lmax!r}")
    area = ico.vertex_areas()
    geo = KLT.fit(values[:, :3], sample_weights=area)
    total = float(np.sum(geo.eigenvalues))
    if not total > 0:
        raise InputError("the geometry has zero variance; cannot normalise its scale")
    g = geo.forward(values[:, :3]) / np.sqrt(total)
    vectors = {
        "shape": np.sqrt(np.maximum(_degree_energies(g, level, lmax), 0)).ravel(),
        "spectrum": np.asarray(geo.eigenvalues) / total,
    }
    if values.shape[1] == 6:
        col = values[:, 3:] / 255.0
        ck = KLT.fit(col, sample_weights=area)
        c = ck.forward(col)
        mean_col = (area @ col) / area.sum()
        vectors["texture"] = np.concatenate(
            [np.sqrt(np.maximum(_degree_energies(c, level, lmax), 0)).ravel(), mean_col])
    vectors = {k: np.asarray(v, np.float32) for k, v in vectors.items()}
    params = {"lmax": int(lmax), "normalization": SH_NORMALIZATION, "version": DESCRIPTOR_VERSION}
    return DescriptorSet(vectors, params)


def descriptor_distance(a: dict, b: dict, *, shape_weight: float = 0.7) -> float:
    """Distance between two models' descriptor dicts.

    ``d = w·‖Δshape‖ + (1 − w)·‖Δtexture‖`` with ``w = shape_weight``; when either model lacks
    colour the texture term is dropped and ``d = ‖Δshape‖``. The KLT spectrum is part of the shape
    term (appended to the shape vector).

    Parameters
    ----------
    a, b : dict of str -> (d,) float32
    shape_weight : float
        In [0, 1].

    Returns
    -------
    float
    """
    if not (0.0 <= shape_weight <= 1.0):
        raise InputError(f"shape_weight must lie in [0, 1], got {shape_weight!r}")
    for d in (a, b):
        if "shape" not in d:
            raise InputError("a descriptor set lacks its 'shape' vector")
    sa = np.concatenate([a["shape"], a.get("spectrum", [])]).astype(np.float64)
    sb = np.concatenate([b["shape"], b.get("spectrum", [])]).astype(np.float64)
    if sa.shape != sb.shape:
        raise InputError("descriptor dimensions differ (different lmax?); recompute them")
    ds = float(np.linalg.norm(sa - sb))
    if "texture" in a and "texture" in b:
        dt = float(np.linalg.norm(a["texture"].astype(np.float64) - b["texture"]))
        return shape_weight * ds + (1.0 - shape_weight) * dt
    return ds
