"""The ``surfidx`` command line: a thin layer over the library (as sqlite-utils does it).

The click group is :data:`surfidx.cli.group.cli`; each command lives in its own module below,
which imports the group and registers itself on it. The group imports a command's module when
the command is asked for (:data:`COMMAND_MODULES`; ``surfidx query id:N`` imports only the
database commands), every module when the commands are listed (``surfidx --help``,
:func:`load_all`). Library errors become one clear line and a non-zero exit through
:func:`surfidx.cli.common.command_errors`.
"""

from __future__ import annotations

from .group import cli

__all__ = ["cli", "main", "load_all", "COMMAND_MODULES"]

#: Command name -> the module of this package that registers it.
COMMAND_MODULES = {
    **{name: "db" for name in ("ingest", "query", "get", "ls", "show", "errors", "redescribe",
                                "rm", "rename", "tag", "untag", "datasette-metadata",
                                "upgrade")},
    "encode": "codec", "decode": "codec",
    "convert": "convert", "info": "convert",
    "geodesic": "geodesic",
    "parameterize": "sphere", "resample": "sphere",
    "eval": "view", "render": "view",
}


def load_all() -> None:
    """Import every command module (registers all commands on :data:`cli`)."""
    from . import codec, convert, db, geodesic, sphere, view  # noqa: F401


cli.modules = {name: f"{__name__}.{module}" for name, module in COMMAND_MODULES.items()}
cli.loader = load_all


def main(args=None) -> None:
    """The ``surfidx`` command: the process computes in the portable numerics profile
    (:func:`surfidx.numerics.use_portable_profile`, before numpy loads), then runs :data:`cli`."""
    from ..numerics import use_portable_profile

    use_portable_profile()
    cli.main(args=args, prog_name="surfidx")
