"""The ``surfidx`` command line: a thin layer over the library (as sqlite-utils does it).

The click group is :data:`surfidx.cli._group.cli`; each command lives in its own module below,
which imports the group and registers itself on it. Importing this package imports every command
module, so that ``cli`` holds them all. Library errors become one clear line and a non-zero exit
through :func:`surfidx.cli._common.command_errors`.
"""

from __future__ import annotations

from . import _codec, _convert, _db, _geodesic, _sphere, _view  # noqa: F401  (register commands)
from ._group import cli

__all__ = ["cli"]
