"""The ``surfidx`` command line: a thin layer over the library (as sqlite-utils does it).

The click group is :data:`surfidx.cli._group.cli`; each command lives in its own module below,
which imports the group and registers itself on it. The group imports a command's module when
the command is asked for (:data:`COMMAND_MODULES`; ``surfidx query id:N`` imports only the
database commands), every module when the commands are listed (``surfidx --help``,
:func:`load_all`). Library errors become one clear line and a non-zero exit through
:func:`surfidx.cli._common.command_errors`.
"""

from __future__ import annotations

from ._group import cli

__all__ = ["cli", "load_all", "COMMAND_MODULES"]

#: Command name -> the module of this package that registers it.
COMMAND_MODULES = {
    **{name: "_db" for name in ("ingest", "query", "get", "ls", "show", "errors", "redescribe",
                                "rm", "rename", "tag", "untag", "datasette-metadata")},
    "encode": "_codec", "decode": "_codec",
    "convert": "_convert", "info": "_convert",
    "geodesic": "_geodesic",
    "parameterize": "_sphere", "resample": "_sphere",
    "eval": "_view", "render": "_view",
}


def load_all() -> None:
    """Import every command module (registers all commands on :data:`cli`)."""
    from . import _codec, _convert, _db, _geodesic, _sphere, _view  # noqa: F401


cli.modules = {name: f"{__name__}.{module}" for name, module in COMMAND_MODULES.items()}
cli.loader = load_all
