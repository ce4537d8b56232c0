"""Compiled extension modules of other packages, loaded without their package's ``__init__``.

A query by example needs one compiled routine of a package whose ``__init__`` imports much more
than it: SHTOOLS' ``SHExpandDH`` (``pyshtools``' ``__init__`` loads matplotlib, xarray, astropy
and pandas). :func:`load_extension` loads one extension module from its package's folder on its
own, once per process: it enters ``sys.modules`` under its full name, where a later import of
the package (which imports it) finds it, so there is only ever one copy. Where the package has
another layout it returns None, and the caller imports the package.
"""

from __future__ import annotations

import importlib
import importlib.machinery
import importlib.util
import os
import sys
import threading

__all__ = ["load_extension"]

_LOCK = threading.Lock()   # one load of a module at a time (threads of one process)


def load_extension(package: str, name: str):
    """The compiled module ``package.name``, loaded without running ``package``'s
    ``__init__`` (the one already imported, when it is).

    Parameters
    ----------
    package : str
        Dotted name of the package whose folder holds the extension (found, not imported;
        its parents are imported).
    name : str
        The extension module's name in it, e.g. ``"_qhull"``.

    Returns
    -------
    module or None
        None when the folder holds no such extension file or the package is not installed.
    """
    full = f"{package}.{name}"
    with _LOCK:
        if full in sys.modules:
            return sys.modules[full]
        try:
            spec = importlib.util.find_spec(package)    # finds the package, does not run it
        except (ImportError, ValueError):
            return None
        if spec is None or not spec.submodule_search_locations:
            return None
        for folder in spec.submodule_search_locations:
            for suffix in importlib.machinery.EXTENSION_SUFFIXES:
                path = os.path.join(folder, name + suffix)
                if not os.path.isfile(path):
                    continue
                loader = importlib.machinery.ExtensionFileLoader(full, path)
                ext_spec = importlib.util.spec_from_file_location(full, path, loader=loader)
                module = importlib.util.module_from_spec(ext_spec)
                sys.modules[full] = module
                try:
                    loader.exec_module(module)
                except BaseException:
                    del sys.modules[full]
                    raise
                return module
    return None
