"""The ``surfidx`` click group, which every command module imports to register its commands.

It lives apart from ``cli/__init__.py`` so that the package imports the command modules and the
command modules import the group, with no import going back (no cycle).
"""

from __future__ import annotations

import click

from .. import __version__

__all__ = ["cli"]


@click.group(context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="surfidx")
def cli():
    """surfidx: a database for textured 3D scans (surfels, spherical wavelets, SQLite)."""
