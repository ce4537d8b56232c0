"""Where numba keeps the compiled kernels of ``@numba.njit(cache=True)``: a per-user cache
directory, never the installed package.

numba's default writes its cache files (``*.nbi``, ``*.nbc``) into the package's own
``__pycache__``. pip's uninstall does not remove them, so replacing a regular install by an
editable one left ``site-packages/surfidx/`` holding only ``__pycache__``, a namespace package
that shadowed the editable install (``surfidx`` could no longer be imported). A user's own
``NUMBA_CACHE_DIR`` is respected.
"""

from __future__ import annotations

import os
import sys

__all__ = ["cache_dir", "use_user_cache"]


def cache_dir() -> str:
    """The per-user cache directory for surfidx's compiled kernels.

    ``$XDG_CACHE_HOME/surfidx/numba`` (default ``~/.cache/surfidx/numba``); on Windows under
    ``%LOCALAPPDATA%``.
    """
    base = os.environ.get("XDG_CACHE_HOME") or (
        os.environ.get("LOCALAPPDATA") if os.name == "nt" else None)
    if not base:
        base = os.path.join(os.path.expanduser("~"), ".cache")
    return os.path.join(base, "surfidx", "numba")


def use_user_cache() -> None:
    """Point numba's cache at :func:`cache_dir` unless ``NUMBA_CACHE_DIR`` is set already.

    Must run before the first kernel is decorated; numba re-reads its configuration from the
    environment when it was imported earlier.
    """
    if os.environ.get("NUMBA_CACHE_DIR"):
        return
    os.environ["NUMBA_CACHE_DIR"] = cache_dir()
    numba = sys.modules.get("numba")
    if numba is not None:
        numba.core.config.reload_config()
