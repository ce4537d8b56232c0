"""surfidx: a database for textured 3D scans represented as surfels.

The pipeline, one subpackage a stage (``ARCHITECTURE.md`` draws it)::

    io -> topology -> sphere -> codec -> describe -> db
    (read)  (repair)   (map)   (resample, KLT, wavelets, zerotree, container)

:mod:`surfidx.geometry` holds what every stage shares (surfels, meshes, the icosahedral grid,
the spheres-of-influence graph, geodesics, distortion metrics); :mod:`surfidx.pipeline` is the
per-model unit of work, :mod:`surfidx.options` its one options tree.

Importing surfidx changes nothing in the host process (no environment variable, no thread limit,
no output). The public names are imported on first use (PEP 562, ``lazy_loader``), so ``import surfidx``
and a query of a stored model do not pay for numba, scipy and trimesh; ``__init__.pyi`` beside
this file lists them for IDEs, type checkers and ``help(surfidx)``.
"""

from __future__ import annotations

import lazy_loader as _lazy

from .errors import (BitstreamError, DatabaseError, FileFormatError, InputError, SurfidxError,
                     TopologyError)
from .tolerance import TOL, Tolerances

__version__ = "0.1.0"

__getattr__, __dir__, __all__ = _lazy.attach_stub(__name__, __file__)
__all__ = ["__version__", *__all__]
