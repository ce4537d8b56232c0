"""Spherical-harmonic expansion of Driscoll–Healy grids and its per-degree energies, by SHTOOLS'
compiled Fortran transform without the rest of pyshtools.

``import pyshtools`` loads matplotlib, xarray, astropy and pandas for its classes, more CPU than
a whole query by example; the descriptors need one routine of its compiled extension
(``SHExpandDH``) and a per-degree sum of squares. The extension module is loaded from
pyshtools' folder on its own, once per process (it enters ``sys.modules`` under its own name,
``pyshtools._SHTOOLS``, where a later ``import pyshtools`` finds it); when that fails (another package layout), pyshtools' own Fortran
backend is imported instead. Either way the routine is SHTOOLS' Fortran one, never the ducc0
backend pyshtools prefers when it is installed, so the descriptors' bytes do not depend on what
else is installed.

``SHExpandDH`` plans its longitude FFTs with FFTW in ``FFTW_MEASURE`` mode: FFTW times several
ways of computing a transform of that length and keeps the fastest, which made the first
transform of a process cost about 0.04 s and its result depend on the timings (another split
of the FFT rounds differently in the last bits, so the same model could get ``layers`` and
``shape`` vectors differing in their last bits under load). Before the first transform the
plan of the descriptors' grid (:data:`FFTW_WISDOM`, 100 longitudes) is handed to the FFTW
library SHTOOLS uses, as FFTW *wisdom*: FFTW then builds that plan without timing anything, the
same on every machine whose CPU has AVX. Other grid lengths are planned as FFTW chooses.
"""

from __future__ import annotations

import functools

import numpy as np

from ..errors import InputError

__all__ = ["expand_dh", "degree_spectrum", "FFTW_WISDOM"]

#: FFTW 3.3.5 wisdom for the real-to-complex FFT of 100 samples (the longitudes of the
#: Driscoll–Healy grid of degree 24 that the descriptors expand): the plan FFTW measures fastest
#: on an idle x86-64 machine (``fftw_export_wisdom_to_string`` after one transform), whose
#: results are the descriptors the store holds.
FFTW_WISDOM = """(fftw-3.3.5 fftw_wisdom #x458a31c8 #x92381c4c #x4f974889 #xcd46f97e
 (fftw_rdft2_nop_register 0 #x11bdd #x11bdd #x0 #x0b76a560 #x305657d8 #xb2a3b66d #x059ea246)
 (fftw_codelet_hc2cfdftv_20_avx 0 #x11bdd #x11bdd #x0 #x965c9b24 #xf9ae20e8 #xca421317 #xec7f0e52)
 (fftw_codelet_n1fv_5_avx 0 #x11bdd #x11bdd #x0 #x01bb24a1 #xc238ea53 #x5da887ba #xe86c2204)
 (fftw_codelet_r2cf_20 2 #x11bdd #x11bdd #x0 #x64d5a0ba #x9aaad0ed #x51ff6a92 #x2785f7ef)
)
"""


def _fftw_library():
    """The double-precision FFTW library loaded in this process (``ctypes.CDLL``), found among
    the process's mapped files (Linux), or None."""
    import ctypes
    import os

    try:
        with open("/proc/self/maps", encoding="utf-8", errors="replace") as f:
            paths = {line.split(None, 5)[-1].strip() for line in f if "libfftw3" in line}
    except OSError:
        return None
    for path in sorted(paths):
        name = os.path.basename(path)
        if name.startswith("libfftw3") and not name.startswith(("libfftw3f", "libfftw3l",
                                                                 "libfftw3q", "libfftw3_")):
            try:
                return ctypes.CDLL(path)
            except OSError:
                continue
    return None


def _use_wisdom() -> bool:
    """Hand :data:`FFTW_WISDOM` to the FFTW library SHTOOLS loaded; whether FFTW took it."""
    lib = _fftw_library()
    if lib is None or not hasattr(lib, "fftw_import_wisdom_from_string"):
        return False
    return bool(lib.fftw_import_wisdom_from_string(FFTW_WISDOM.encode("ascii")))


def _load_extension():
    """pyshtools' ``_SHTOOLS`` extension module, loaded without running pyshtools' ``__init__``
    and entered in ``sys.modules`` (the one already there, when pyshtools loaded it), or None
    when the package's folder holds no such extension."""
    import importlib.machinery
    import importlib.util
    import os
    import sys

    full = "pyshtools._SHTOOLS"
    if full in sys.modules:
        return sys.modules[full]
    spec = importlib.util.find_spec("pyshtools")   # finds the package, does not import it
    if spec is None or not spec.submodule_search_locations:
        return None
    for folder in spec.submodule_search_locations:
        for suffix in importlib.machinery.EXTENSION_SUFFIXES:
            path = os.path.join(folder, "_SHTOOLS" + suffix)
            if not os.path.isfile(path):
                continue
            loader = importlib.machinery.ExtensionFileLoader(full, path)
            module = importlib.util.module_from_spec(
                importlib.util.spec_from_file_location(full, path, loader=loader))
            sys.modules[full] = module
            try:
                loader.exec_module(module)
            except BaseException:
                del sys.modules[full]
                raise
            return module
    return None


@functools.lru_cache(maxsize=1)
def _shexpanddh():
    """SHTOOLS' Fortran ``SHExpandDH`` returning ``(exitstatus, cilm)``."""
    try:
        ext = _load_extension()
    except ImportError:
        ext = None
    if ext is not None and hasattr(ext, "SHExpandDH"):
        _use_wisdom()
        return ext.SHExpandDH
    from pyshtools.backends import shtools

    _use_wisdom()
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
