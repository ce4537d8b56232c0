"""Shared CLI helpers: error mapping, JSON output, input options."""

from __future__ import annotations

import functools
import json
import re
import sqlite3
import warnings

import click
import numpy as np

from .._errors import SurfidxError, TopologyError

__all__ = ["command_errors", "echo_json", "read_input", "input_options", "plain"]

_NAMED = {"\n": "\\n", "\r": "\\r", "\t": "\\t"}
_UNSAFE = re.compile(r"[\x00-\x1f\x7f-\x9f\u2028\u2029\u202a-\u202e\u2066-\u2069\ud800-\udfff]")


def _escape(m) -> str:
    c = m.group()
    if c in _NAMED:
        return _NAMED[c]
    o = ord(c)
    if 0xDC80 <= o <= 0xDCFF:                       # an undecodable byte (os.fsdecode)
        return f"\\x{o - 0xDC00:02x}"
    return f"\\x{o:02x}" if o < 0x100 else f"\\u{o:04x}"


def plain(text) -> str:
    """``text`` safe for a terminal line: control characters (C0, DEL, C1: ANSI escape
    sequences, newlines, tabs), line and paragraph separators, bidirectional overrides and lone
    surrogates are written as backslash escapes (``\\n``, ``\\x1b``, ``\\u202e``); every other
    character is kept. Plain-text output goes through it; ``--json`` output does not (it is
    exact)."""
    text = str(text)
    return _UNSAFE.sub(_escape, text) if _UNSAFE.search(text) else text


def command_errors(func):
    """Map library errors to ``click.ClickException`` (one line, exit 1), and OS errors too.

    A :class:`~surfidx.TopologyError` (found after reading, so naming no file) is prefixed with
    the command's ``input`` argument, if any. The line goes through :func:`plain` (names with
    control characters stay on one line); an ``sqlite3`` error the library did not map is one
    line too.

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
                raise click.ClickException(plain(str(exc) if named else f"{src}: {exc}")) \
                    from None
            except sqlite3.Error as exc:
                raise click.ClickException(plain(f"SQLite error ({exc})")) from None
            except MemoryError:
                raise click.ClickException("out of memory; try a smaller input or level") from None
            except OSError as exc:
                where = f"{exc.filename}: " if exc.filename else ""
                raise click.ClickException(plain(f"{where}{exc.strerror or exc}")) from None
            finally:
                seen = set()
                for w in caught:
                    msg = str(w.message)
                    if msg not in seen and not issubclass(w.category, DeprecationWarning):
                        seen.add(msg)
                        click.echo(f"warning: {plain(msg)}", err=True)

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
