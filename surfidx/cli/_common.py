"""Shared CLI helpers: error mapping, JSON output, input options."""

from __future__ import annotations

import functools
import json
import warnings

import click
import numpy as np

from .._errors import SurfidxError, TopologyError

__all__ = ["command_errors", "echo_json", "read_input", "input_options"]


def command_errors(func):
    """Map library errors to ``click.ClickException`` (one line, exit 1), and OS errors too.

    A :class:`~surfidx.TopologyError` (found after reading, so naming no file) is prefixed with
    the command's ``input`` argument, if any.

    Warnings are shown as one ``warning:`` line on stderr instead of Python's two-line format.
    """

    @functools.wraps(func)
    def wrapper(*args, **kwargs):
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            try:
                return func(*args, **kwargs)
            except SurfidxError as exc:
                # a topology problem is found after reading: name the input file it concerns
                src = kwargs.get("input")
                named = exc.path is not None or src is None or not isinstance(exc, TopologyError)
                raise click.ClickException(str(exc) if named else f"{src}: {exc}") from None
            except MemoryError:
                raise click.ClickException("out of memory; try a smaller input or level") from None
            except OSError as exc:
                where = f"{exc.filename}: " if exc.filename else ""
                raise click.ClickException(f"{where}{exc.strerror or exc}") from None
            finally:
                seen = set()
                for w in caught:
                    msg = str(w.message)
                    if msg not in seen and not issubclass(w.category, DeprecationWarning):
                        seen.add(msg)
                        click.echo(f"warning: {msg}", err=True)

    return wrapper


def _default(o):
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    raise TypeError(type(o).__name__)


def echo_json(obj) -> None:
    """Print ``obj`` as indented JSON (numpy scalars and arrays converted)."""
    click.echo(json.dumps(obj, indent=2, default=_default))


def input_options(func):
    """The ``--texture`` and ``--samples`` options every command that reads a model takes."""
    func = click.option("--samples", type=click.IntRange(min=4), default=None,
                        help="Sample N surfels uniformly over a mesh instead of one per vertex.")(func)
    func = click.option("--texture", type=click.Path(dir_okay=False), default=None,
                        help="Texture image for an OBJ whose UVs name none.")(func)
    return func


def read_input(path, texture=None, samples=None):
    """Read a model file as surfels (the library's :func:`surfidx.read_surfels`)."""
    from ..io import read_surfels

    return read_surfels(path, texture=texture, samples=samples)
