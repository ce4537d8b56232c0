"""Shared CLI helpers: the options every command takes, error mapping, JSON output, the
options of the commands that read or write models.

Every command takes the same habits from :func:`common_options`: ``-q/--quiet`` (no progress
display, no informational notes on stderr; errors and warnings are still printed),
``-v/--verbose`` (per-stage times and details on stderr), ``--json`` (the result as JSON on
stdout, and a failure as ``{"error": "..."}`` there too, with a non-zero exit status) and, for a
command that uses the model database, ``--db PATH`` (``$SURFIDX_DB``, else
:data:`DEFAULT_DB`). The command gets a :class:`Console` that holds the first three and prints
accordingly.
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import json
import re
import sqlite3
import sys
import warnings

import click
import numpy as np

from ..errors import SurfidxError

__all__ = ["common_options", "Console", "uses_database", "DEFAULT_DB", "DB_ENVVAR",
           "command_errors", "echo_json", "plain", "stage_progress", "reading", "read_input",
           "input_options", "outside_textures_option", "allow_outside_textures",
           "options_file_option", "output_format_option", "rate_option", "ascii_option",
           "export_options", "EXPORT_HELP"]

#: The database file of the database commands when neither ``--db`` nor ``$SURFIDX_DB`` names one.
DEFAULT_DB = "surfidx.db"
#: The environment variable that names the database when ``--db`` is not given.
DB_ENVVAR = "SURFIDX_DB"

#: The arguments that name the file a command reads, for errors found after reading.
_INPUT_ARGS = ("input", "example", "reference")

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


_NOT_FOR_USERS = (DeprecationWarning, ResourceWarning)
"""Warning categories the CLI does not print (Python's default filters hide them too)."""


def command_errors(func):
    """Map library errors to ``click.ClickException`` (one line, exit 1), and OS errors too.

    An error that names no file (a :class:`~surfidx.TopologyError` or
    :class:`~surfidx.InputError` found after reading) is prefixed with the command's ``input``
    (or ``example``, ``reference``) argument, if any. The line goes through :func:`plain` (names
    with control characters stay on one line); an ``sqlite3`` error the library did not map is
    one line too. With ``--json`` (an ``as_json`` argument) the error is printed on stdout as
    ``{"error": "..."}`` (exact, not escaped) and the exit status is 1; so is a click error the
    command raises (a usage error keeps its status 2). A closed pipe (``surfidx ls | head``)
    ends the command quietly (click's handling of ``EPIPE``).

    Warnings are shown as one ``warning:`` line on stderr instead of Python's two-line format;
    :data:`_NOT_FOR_USERS` (deprecations, and resource warnings, which the garbage collector
    may raise during a command for objects that are not the command's) are not shown.
    """

    @functools.wraps(func)
    def wrapper(*args, **kwargs):
        as_json = bool(kwargs.get("as_json"))

        def fail(text, code=1):
            if as_json:
                echo_json({"error": text})
                raise click.exceptions.Exit(code)
            raise click.ClickException(plain(text))

        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            try:
                out = func(*args, **kwargs)
                sys.stdout.flush()                  # a closed pipe shows here, not at exit
                return out
            except SurfidxError as exc:
                # a problem found after reading names no file: name the input it concerns
                src = next((kwargs[a] for a in _INPUT_ARGS if kwargs.get(a) is not None), None)
                named = exc.path is not None or src is None
                fail(str(exc) if named else f"{src}: {exc}")
            except click.ClickException as exc:
                if not as_json:
                    raise
                fail(exc.format_message(), exc.exit_code)
            except sqlite3.Error as exc:
                fail(f"SQLite error ({exc})")
            except MemoryError:
                fail("out of memory; try a smaller input or level")
            except BrokenPipeError:
                raise                               # click's main ends quietly on EPIPE
            except OSError as exc:
                where = f"{exc.filename}: " if exc.filename else ""
                fail(f"{where}{exc.strerror or exc}")
            finally:
                seen = set()
                for w in caught:
                    msg = str(w.message)
                    if msg not in seen and not issubclass(w.category, _NOT_FOR_USERS):
                        seen.add(msg)
                        click.echo(f"warning: {plain(msg)}", err=True)

    return wrapper


@dataclasses.dataclass(frozen=True)
class Console:
    """What ``-q``, ``-v`` and ``--json`` asked of a command, and the ways it talks on stderr.

    Results go to stdout (as JSON with ``json``); notes, details and the progress display go
    to stderr, so that a ``--json`` result stays machine-readable.

    Attributes
    ----------
    quiet : bool
        No progress display and no notes (errors and warnings are still printed).
    verbose : bool
        Details and per-stage times too.
    json : bool
        Print the result (or the error) as JSON on stdout.
    """

    quiet: bool = False
    verbose: bool = False
    json: bool = False

    def note(self, text) -> None:
        """An informational line on stderr (through :func:`plain`), unless ``quiet``."""
        if not self.quiet:
            click.echo(plain(text), err=True)

    def detail(self, text) -> None:
        """A line on stderr (through :func:`plain`) with ``verbose`` only."""
        if self.verbose:
            click.echo(plain(text), err=True)

    def progress(self):
        """The command's stage display (:func:`stage_progress`): a context manager giving a
        progress callback, or None when nothing would be shown."""
        return stage_progress(quiet=self.quiet, verbose=self.verbose)

    @property
    def live(self) -> bool:
        """Whether a progress display (a bar) is shown: not ``quiet`` and stderr a terminal."""
        return not self.quiet and _stderr_is_terminal(click.get_text_stream("stderr"))


_DATABASE = "uses_database"
"""The attribute :func:`common_options` sets on the callback of a command that takes ``--db``."""


def uses_database(command) -> bool:
    """Whether the click ``command`` uses the model database (it was given ``--db`` by
    ``common_options(db=True)``)."""
    return bool(getattr(command.callback, _DATABASE, False))


def common_options(func=None, *, db: bool = False):
    """The options every command takes, with its errors mapped (:func:`command_errors`).

    Adds ``-q/--quiet``, ``-v/--verbose`` and ``--json`` and hands the command a
    :class:`Console` of them as ``console``; with ``db``, also ``--db PATH`` (default
    ``$SURFIDX_DB``, else :data:`DEFAULT_DB`), handed as ``db_path``, and the mark
    :func:`uses_database` reads. Use it as ``@common_options`` or ``@common_options(db=True)``
    right under the command's other options.

    Raises
    ------
    click.UsageError
        Both ``--quiet`` and ``--verbose``.
    """
    if func is None:
        return functools.partial(common_options, db=db)

    @functools.wraps(func)
    def wrapper(*args, quiet=False, verbose=False, as_json=False, **kwargs):
        if quiet and verbose:
            raise click.UsageError("--quiet and --verbose exclude each other")
        return func(*args, console=Console(quiet=quiet, verbose=verbose, json=as_json),
                    **kwargs)

    guarded = command_errors(wrapper)       # as_json reaches it: failures as JSON too
    setattr(guarded, _DATABASE, bool(db))
    guarded = click.option("--json", "as_json", is_flag=True,
                           help="Print the result as JSON on stdout (a failure as "
                                '{"error": "..."}).')(guarded)
    guarded = click.option("-v", "--verbose", is_flag=True,
                           help="Print details and each stage's wall and CPU time on "
                                "stderr.")(guarded)
    guarded = click.option("-q", "--quiet", is_flag=True,
                           help="No progress display and no notes on stderr (errors and "
                                "warnings still show); without it, progress shows when stderr "
                                "is a terminal.")(guarded)
    if db:
        guarded = click.option(
            "--db", "db_path", default=DEFAULT_DB, envvar=DB_ENVVAR, show_default=False,
            metavar="PATH", type=click.Path(dir_okay=False),
            help=f"Database file (default ${DB_ENVVAR}, else {DEFAULT_DB}).")(guarded)
    return guarded


def _default(o):
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    raise TypeError(type(o).__name__)


def echo_json(obj) -> None:
    """Print ``obj`` as indented JSON (numpy scalars and arrays converted)."""
    click.echo(json.dumps(obj, indent=2, default=_default))


_OUTSIDE = "surfidx.allow_outside_textures"


def outside_textures_option(func):
    """The ``--allow-outside-textures`` flag (part of :func:`input_options`): kept in the click
    context for :func:`read_input`, so the command does not take it as an argument."""
    @functools.wraps(func)
    def wrapper(*args, allow_outside_textures=False, **kwargs):
        ctx = click.get_current_context(silent=True)
        if ctx is not None:
            ctx.meta[_OUTSIDE] = bool(allow_outside_textures)
        return func(*args, **kwargs)

    return click.option(
        "--allow-outside-textures", is_flag=True,
        help="Use a texture (or glTF buffer) that the model names outside its folder (absolute "
             "path or '..'); by default it is skipped with a warning.")(wrapper)


def allow_outside_textures() -> bool:
    """Whether the running command was given ``--allow-outside-textures``."""
    ctx = click.get_current_context(silent=True)
    return bool(ctx is not None and ctx.meta.get(_OUTSIDE))


def input_options(func):
    """The ``--texture``, ``--samples`` and ``--allow-outside-textures`` options every command
    that reads a model takes (the last is read by :func:`read_input` from the context)."""
    func = outside_textures_option(func)
    func = click.option("--samples", type=click.IntRange(min=4), default=None,
                        help="Sample N surfels uniformly over a mesh instead of one per vertex.")(func)
    func = click.option("--texture", type=click.Path(dir_okay=False), default=None,
                        help="Texture image for an OBJ whose UVs name none.")(func)
    return func


def output_format_option(func=None, *, formats=("ply", "obj", "glb", "sfz")):
    """``--format``: the output format when the suffix does not say it, one of ``formats``."""
    if func is None:
        return functools.partial(output_format_option, formats=formats)
    suffixes = ", ".join(f".{f}" for f in formats)
    return click.option("--format", "fmt", type=click.Choice(list(formats), case_sensitive=False),
                        default=None,
                        help=f"Output format (default: from the output's suffix: {suffixes})."
                        )(func)


def rate_option(func=None, *, help: str, dest: str = "bits_per_surfel"):
    """``--bits-per-surfel B``: a coding or decoding rate (a positive number), as ``dest``."""
    if func is None:
        return functools.partial(rate_option, help=help, dest=dest)
    return click.option("--bits-per-surfel", dest, type=click.FloatRange(min=0, min_open=True),
                        default=None, metavar="B", help=help)(func)


def ascii_option(func):
    """``--ascii``: write a PLY as text instead of binary little-endian (handed as ``text``)."""
    return click.option("--ascii", "text", is_flag=True,
                        help="Write ASCII PLY instead of binary.")(func)


#: What ``decode`` and ``get`` write, by the output's suffix.
EXPORT_HELP = ("File to write, its format from the suffix (or --format): .ply (surfels, or a "
               "mesh with --mesh), .obj or .glb (the grid mesh with normals and its colour as a "
               "texture, or vertex colours with --vertex-colors; an OBJ's .mtl and image "
               "beside it), .sfz (the stream, truncated to --bits-per-surfel).")


def export_options(func=None, *, folder: bool = False):
    """The options of the commands that decode a stream to a file (``decode``, ``get``):
    ``-o/--output``, ``--format``, ``--bits-per-surfel`` (as ``bits_per_surfel``), ``--level``,
    ``--mesh/--surfels``, ``--max-surfels``, ``--max-vertices``, ``--ascii`` (as ``text``),
    ``--texture/--vertex-colors`` (as ``texture``, None unless given), ``--texture-size``,
    ``--image-format`` and ``--image-quality``. With ``folder``, ``-o`` may also name a folder
    (``get`` of several models)."""
    if func is None:
        return functools.partial(export_options, folder=folder)
    func = click.option("--image-quality", type=int, default=None, metavar="Q",
                        help="JPEG or WebP quality of the texture, 1 to 100 (default 90).")(func)
    func = click.option("--image-format", type=click.Choice(["png", "jpeg", "webp"],
                                                            case_sensitive=False),
                        default="png", show_default=True,
                        help="Format of the texture image (WebP in GLB through "
                             "EXT_texture_webp).")(func)
    func = click.option("--texture-size", type=int, default=None, metavar="N",
                        help="Side of the texture image in texels, 64 to 8192 (default: about "
                             "two texels per grid edge, 256 to 4096).")(func)
    func = click.option("--texture/--vertex-colors", "texture", default=None,
                        help="Write the colour of an OBJ or GLB mesh as a texture baked on the "
                             "grid's atlas, or as vertex colours (default: a texture, vertex "
                             "colours with --max-vertices).")(func)
    func = ascii_option(func)
    func = click.option("--max-vertices", type=int, default=None, metavar="N",
                        help="Write at most N vertices (surfels): the decoded mesh simplified "
                             "by quadric-error edge collapses, which keeps the shape better "
                             "than a lower --level (N >= 4).")(func)
    func = click.option("--max-surfels", type=click.IntRange(min=1), default=None,
                        help="Refuse to decode to more surfels than this (default 2,621,442, "
                             "the level-9 grid); --level gives fewer.")(func)
    func = click.option("--mesh/--surfels", "mesh", default=None,
                        help="Write the grid's triangle mesh, or surfels (default: mesh for OBJ "
                             "and GLB, surfels for PLY).")(func)
    func = click.option("--level", type=int, default=None,
                        help="Grid level of the output (default: the stream's own, or a coarser "
                             "one at the rates where the encoder measured that it is closer to "
                             "the input; lower: fewer surfels, but --max-vertices keeps the "
                             "shape better).")(func)
    func = rate_option(func, help="Decode (or keep, for .sfz) only the prefix of the stream "
                                  "that fits this rate (default: all of it).")
    func = output_format_option(func)
    return click.option("-o", "--output", required=True, type=click.Path(dir_okay=folder),
                        help=EXPORT_HELP + (" With several models: the folder to write them "
                                            "into, one file each named after the model."
                                            if folder else ""))(func)


def read_input(path, texture=None, samples=None, allow_outside=None):
    """Read a model file as surfels (the library's :func:`surfidx.read_surfels`), with the
    command's ``--allow-outside-textures`` unless ``allow_outside`` says otherwise."""
    from ..io import read_surfels

    allow = allow_outside_textures() if allow_outside is None else bool(allow_outside)
    return read_surfels(path, texture=texture, samples=samples, allow_outside_textures=allow)


def _stderr_is_terminal(stream) -> bool:
    """Whether ``stream`` is a terminal; the click context object's ``"terminal"`` key, when
    set, says so instead (``cli.main(args, obj={"terminal": True})``, for tests and embedding
    applications)."""
    ctx = click.get_current_context(silent=True)
    obj = ctx.find_root().obj if ctx is not None else None
    if isinstance(obj, dict) and "terminal" in obj:
        return bool(obj["terminal"])
    isatty = getattr(stream, "isatty", None)
    return bool(isatty is not None and isatty())


@contextlib.contextmanager
def stage_progress(*, quiet: bool, verbose: bool):
    """The progress callback of a command (a :class:`surfidx.progress.StageLog` on stderr), or
    None: the running stage on one line when stderr is a terminal and not ``quiet``; the
    per-stage times when the command ends, with ``verbose``.

    Raises
    ------
    click.UsageError
        Both ``quiet`` and ``verbose``.
    """
    from ..progress import StageLog

    if quiet and verbose:
        raise click.UsageError("--quiet and --verbose exclude each other")
    stream = click.get_text_stream("stderr")
    live = not quiet and _stderr_is_terminal(stream)
    if not (live or verbose):
        yield None
        return
    log = StageLog(stream, live=live, verbose=verbose)
    try:
        yield log
    finally:
        log.close()


def reading(progress, path, texture=None, samples=None):
    """:func:`read_input`, reported to ``progress`` as the ``read`` stage."""
    from ..progress import report

    report(progress, "read", 0, 1)
    surfels = read_input(path, texture, samples)
    report(progress, "read", 1, 1)
    return surfels


def options_file_option(func):
    """``--options FILE``: a ``.json`` or ``.toml`` :class:`surfidx.options.ProcessOptions` file,
    handed to the command as ``options`` (None without it; the command's own flags override
    its values)."""
    @functools.wraps(func)
    def wrapper(*args, options_file=None, **kwargs):
        options = None
        if options_file is not None:
            from ..options import ProcessOptions       # the whole tree: only when asked for

            options = ProcessOptions.load(options_file)
        return func(*args, options=options, **kwargs)

    return click.option(
        "--options", "options_file", type=click.Path(dir_okay=False), default=None,
        metavar="FILE",
        help="Processing options (.json or .toml: repair, map, codec, describe tables); "
             "flags given override them.")(wrapper)
