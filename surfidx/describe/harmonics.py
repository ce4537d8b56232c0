"""Spherical-harmonic expansion of Driscoll–Healy grids and its per-degree energies, by SHTOOLS'
compiled Fortran transform without the rest of pyshtools.

``import pyshtools`` loads matplotlib, xarray, astropy and pandas for its classes, more CPU than
a whole query by example; the descriptors need one routine of its compiled extension
(``SHExpandDH``) and a per-degree sum of squares. The extension module is loaded from
pyshtools' folder on its own, once per process (:func:`surfidx.extmodules.load_extension`: it
enters ``sys.modules`` under its own name, ``pyshtools._SHTOOLS``, where a later
``import pyshtools`` finds it); when that fails (another package layout), pyshtools' own Fortran
backend is imported instead. Either way the routine is SHTOOLS' Fortran
one, never the ducc0 backend pyshtools prefers when it is installed, so the descriptors' bytes do
not depend on what else is installed.
"""

from __future__ import annotations

import functools

import numpy as np

from ..errors import InputError

__all__ = ["expand_dh", "degree_spectrum"]


@functools.lru_cache(maxsize=1)
def _shexpanddh():
    """SHTOOLS' Fortran ``SHExpandDH`` returning ``(exitstatus, cilm)``."""
    from ..extmodules import load_extension

    try:
        ext = load_extension("pyshtools", "_SHTOOLS")
    except ImportError:
        ext = None
    if ext is not None and hasattr(ext, "SHExpandDH"):
        return ext.SHExpandDH
    from pyshtools.backends import shtools

    return lambda *args, **kwargs: (0, shtools.SHExpandDH(*args, **kwargs))


def expand_dh(grid: np.ndarray, lmax: int) -> np.ndarray:
    """(2, lmax+1, lmax+1) real spherical-harmonic coefficients (4π-normalised, no
    Condon–Shortley phase) of a Driscoll–Healy grid.

    Parameters
    ----------
    grid : (n, 2n) float64
        Equally spaced samples (``sampling=2``): latitudes from 90° N in steps of 180°/n,
        longitudes from 0° E in steps of 180°/n.
    lmax : int
        Largest degree computed, at most ``n/2 - 1``.

    Returns
    -------
    (2, lmax+1, lmax+1) float64
        Cosine (``[0, l, m]``) and sine (``[1, l, m]``) coefficients, as pyshtools'
        ``SHExpandDH(grid, norm=1, sampling=2, csphase=1, lmax_calc=lmax)``.

    Raises
    ------
    InputError
        A grid that is not (n, 2n) with n even, or ``lmax`` outside 0..n/2-1.
    """
    grid = np.ascontiguousarray(grid, dtype=np.float64)
    n = grid.shape[0] if grid.ndim == 2 else 0
    if grid.ndim != 2 or n < 2 or n % 2 or grid.shape[1] != 2 * n:
        raise InputError(f"a Driscoll-Healy grid (sampling 2) is (n, 2n) with n even, got shape "
                         f"{grid.shape}")
    if not 0 <= lmax <= n // 2 - 1:
        raise InputError(f"lmax must be in 0..{n // 2 - 1} for a grid of {n} latitudes, got "
                         f"{lmax}")
    status, cilm = _shexpanddh()(grid, norm=1, sampling=2, csphase=1, lmax_calc=int(lmax))
    assert status == 0, f"SHTOOLS SHExpandDH exit status {status}"
    return cilm


def degree_spectrum(cilm: np.ndarray) -> np.ndarray:
    """(lmax+1,) power per degree of 4π-normalised real coefficients (2, lmax+1, lmax+1):
    ``Σ_m c[0, l, m]² + Σ_{m≥1} c[1, l, m]²``, the sums in pyshtools' ``spectrum`` order
    (``normalization="4pi", unit="per_l"``), so the values are the same to the bit."""
    lmax = cilm.shape[1] - 1
    out = np.empty(lmax + 1)
    for l in range(lmax + 1):
        out[l] = (cilm[0, l, 0:l + 1] ** 2).sum() + (cilm[1, l, 1:l + 1] ** 2).sum()
    return out
