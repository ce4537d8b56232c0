"""The ``surfidx`` command line: a thin layer over the library (as sqlite-utils does it).

Each command lives in its own module below and registers itself on :data:`cli`; library errors
become one clear line and a non-zero exit through :func:`surfidx.cli._common.command`.
"""

from __future__ import annotations

import click

from .. import __version__


@click.group(context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="surfidx")
def cli():
    """surfidx: a database for textured 3D scans (surfels, spherical wavelets, SQLite)."""


# Command modules register themselves on ``cli`` when imported.
from . import _convert  # noqa: E402,F401
from . import _geodesic  # noqa: E402,F401
from . import _view  # noqa: E402,F401
from . import _db  # noqa: E402,F401
from . import _sphere  # noqa: E402,F401
from . import _codec  # noqa: E402,F401

__all__ = ["cli"]
