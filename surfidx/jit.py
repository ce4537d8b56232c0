"""numba for surfidx's kernels, their compiled cache kept per user, never in the package.

numba's default writes the cache files of ``@njit(cache=True)`` (``*.nbi``, ``*.nbc``) into the
package's own ``__pycache__``. pip's uninstall does not remove them, so replacing a regular
install by an editable one left ``site-packages/surfidx/`` holding only ``__pycache__``, a
namespace package that shadowed the editable install. The kernel modules import numba from here,
which adds one cache locator to numba's list: it serves the functions defined in surfidx's own
files only (every other function is cached as numba would cache it) and writes under
:func:`cache_dir`. Nothing is written to the environment; a ``NUMBA_CACHE_DIR`` the user set is
respected (numba's own locator then serves surfidx too).
"""

from __future__ import annotations

import os

import numba
from numba import njit
from numba.core import caching as _caching
from numba.core import config as _config

__all__ = ["numba", "njit", "cache_dir"]

_PACKAGE = os.path.dirname(os.path.abspath(__file__))


def cache_dir() -> str:
    """The per-user cache directory of surfidx's compiled kernels.

    ``$XDG_CACHE_HOME/surfidx/numba`` (default ``~/.cache/surfidx/numba``); on Windows under
    ``%LOCALAPPDATA%``.
    """
    base = os.environ.get("XDG_CACHE_HOME") or (
        os.environ.get("LOCALAPPDATA") if os.name == "nt" else None)
    if not base:
        base = os.path.join(os.path.expanduser("~"), ".cache")
    return os.path.join(base, "surfidx", "numba")


class _PackageCacheLocator(_caching.UserProvidedCacheLocator):
    """Caches the kernels of surfidx's own files under :func:`cache_dir`."""

    def __init__(self, py_func, py_file):
        self._py_file = py_file
        self._lineno = py_func.__code__.co_firstlineno
        self._cache_path = os.path.join(cache_dir(), self.get_suitable_cache_subpath(py_file))

    @classmethod
    def from_function(cls, py_func, py_file):
        if _config.CACHE_DIR or not os.path.abspath(py_file).startswith(_PACKAGE + os.sep):
            return None
        return super(_caching.UserProvidedCacheLocator, cls).from_function(py_func, py_file)


def _register() -> None:
    impl = getattr(_caching, "CacheImpl", None) or getattr(_caching, "_CacheImpl")
    if not any(c.__name__ == _PackageCacheLocator.__name__ for c in impl._locator_classes):
        impl._locator_classes.insert(0, _PackageCacheLocator)


_register()
