"""The ``surfidx`` click group, which every command module imports to register its commands.

It lives apart from ``cli/__init__.py`` so that the package imports the command modules and the
command modules import the group, with no import going back (no cycle).

The group imports a command's module when the command is asked for by name
(:meth:`LazyGroup.get_command`): ``surfidx query id:N`` imports ``cli/_db.py`` and not the
codec, sphere or render commands (and their imports). Listing the commands (``surfidx --help``)
imports them all. ``cli.commands`` holds the commands imported so far; use
``cli.get_command(ctx, name)`` or :meth:`LazyGroup.load_all` for any of them.

Its commands are :class:`Command`: with ``--json`` among the arguments, a usage error found
while click parses them (a bad value, a missing option) is printed on stdout as
``{"error": "..."}`` as the command's own failures are (:func:`surfidx.cli.common.command_errors`).
"""

from __future__ import annotations

import importlib
import json

import click

from .. import __version__

__all__ = ["cli", "LazyGroup", "Command"]


def _wants_json(args) -> bool:
    """Whether ``--json`` is among the command-line arguments ``args`` (before a ``--``)."""
    args = list(args)
    return "--json" in (args[:args.index("--")] if "--" in args else args)


def _json_usage_error(exc: click.UsageError):
    """Print ``exc`` as ``{"error": "..."}`` on stdout; the exit keeps its status (2)."""
    click.echo(json.dumps({"error": exc.format_message()}, indent=2))
    return click.exceptions.Exit(exc.exit_code)


class Command(click.Command):
    """A surfidx command: with ``--json``, a usage error is printed as ``{"error": ...}`` on
    stdout too (and the exit status stays click's 2)."""

    def make_context(self, info_name, args, parent=None, **extra):
        wants_json = _wants_json(args)
        try:
            return super().make_context(info_name, args, parent=parent, **extra)
        except click.UsageError as exc:
            if not wants_json:
                raise
            raise _json_usage_error(exc) from exc


class LazyGroup(click.Group):
    """A click group whose commands are imported on demand.

    Attributes
    ----------
    modules : dict of str -> str
        Command name -> the module that registers it (set by ``surfidx.cli``).
    loader : callable or None
        Imports every command module (set by ``surfidx.cli``); run for a name that
        :attr:`modules` does not know, so that a command missing there is still found.
    """

    command_class = Command

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.modules = {}
        self.loader = None

    def load_all(self) -> None:
        """Import every command module (all commands in :attr:`commands`)."""
        for module in sorted(set(self.modules.values())):
            importlib.import_module(module)
        if self.loader is not None:
            self.loader()

    def get_command(self, ctx, cmd_name):
        if cmd_name not in self.commands:
            module = self.modules.get(cmd_name)
            if module is not None:
                importlib.import_module(module)
            if cmd_name not in self.commands:
                self.load_all()
        return super().get_command(ctx, cmd_name)

    def list_commands(self, ctx):
        self.load_all()
        return super().list_commands(ctx)

    def resolve_command(self, ctx, args):
        try:
            return super().resolve_command(ctx, args)
        except click.UsageError as exc:         # no such command
            if not _wants_json(args):
                raise
            raise _json_usage_error(exc) from exc


@click.group(cls=LazyGroup, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="surfidx")
def cli():
    """surfidx: a database for textured 3D scans (surfels, spherical wavelets, SQLite)."""
