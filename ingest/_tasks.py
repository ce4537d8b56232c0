"""The tasks of an ingest: one per new model file, the per-model function and its outcome.

:func:`make_tasks` hashes each file with its texture and skips those stored already;
:func:`process_task` is the one picklable per-model function every executor runs; an
:class:`Outcome` carries its model or its error message back to the single writer.
"""

from __future__ import annotations

import functools
import os
import stat
import time
from dataclasses import dataclass
from pathlib import Path

from surfidx.errors import SurfidxError

from surfidx.io.files import NotRegularFile, find_texture, not_regular
from surfidx.validate import accepts_keyword

from ._files import hash_files

__all__ = ["Task", "Outcome", "error_message", "resolve_processor", "process_task", "make_tasks"]


# ---------------------------------------------------------------------- tasks and outcomes
@dataclass(frozen=True)
class Task:
    """One model file to process.

    Attributes
    ----------
    path : str
        Absolute path of the model file.
    texture : str or None
        Texture image found by :func:`find_texture`.
    content_hash : str
        SHA-256 hex of the file's bytes and then the texture's (``surfidx.pipeline.content_hash``).
    source_rel : str or None
        ``path`` relative to the folder the ingest was given that holds it (its name for a file
        given itself).
    size : int or None
        The file's size when it was hashed.
    mtime : float or None
        Its modification time then (POSIX seconds).
    """

    path: str
    texture: str | None
    content_hash: str
    source_rel: str | None = None
    size: int | None = None
    mtime: float | None = None


@dataclass
class Outcome:
    """What processing one task produced: a model, or an error message."""

    task: Task
    model: object = None
    error: str | None = None
    seconds: float = 0.0


def error_message(exc: BaseException) -> str:
    """The message recorded for a failure: a ``SurfidxError``'s own message, otherwise
    ``"TypeName: message"``."""
    if isinstance(exc, SurfidxError):
        return str(exc)
    text = str(exc)
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__


def resolve_processor(processor=None):
    """``processor``, or :func:`surfidx.pipeline.process_model` when None
    (:func:`surfidx.pipeline.unit_of_work`).

    Raises
    ------
    SurfidxError
        ``surfidx.pipeline.process_model`` is not available.
    """
    from surfidx.pipeline import unit_of_work

    return unit_of_work(processor, "process_model")


def process_task(task: Task, *, processor, bits_per_surfel: float, options=None,
                 allow_outside_textures: bool = False, stages=None) -> Outcome:
    """Run the processor on one task, catching its errors (the per-model function of every
    executor; picklable when ``processor`` is a module-level function).

    ``processor(path, bits_per_surfel=B, texture=T)`` must return a
    ``surfidx.pipeline.ProcessedModel``; its ``content_hash`` is set to the task's so that a re-run
    recognises the model. With ``allow_outside_textures`` the processor also gets
    ``allow_outside_textures=True``; with ``options`` (a ``surfidx.options.ProcessOptions``) a
    processor that names an ``options`` parameter also gets ``options=``. With ``stages``, a callable ``stages(path, stage, done,
    total)``, a processor that takes ``progress=`` (:func:`surfidx.validate.accepts_keyword`) gets one that
    reports its stage events with the task's path. ``KeyboardInterrupt`` and ``SystemExit``
    propagate.
    """
    t0 = time.perf_counter()
    extra = {"allow_outside_textures": True} if allow_outside_textures else {}
    if options is not None and accepts_keyword(processor, "options"):
        extra["options"] = options
    if stages is not None and accepts_keyword(processor, "progress"):
        extra["progress"] = functools.partial(stages, task.path)
    try:
        model = processor(task.path, bits_per_surfel=bits_per_surfel, texture=task.texture,
                          **extra)
        model.content_hash = task.content_hash
        model.source_rel, model.source_bytes, model.source_mtime = (task.source_rel, task.size,
                                                                    task.mtime)
        return Outcome(task, model=model, seconds=time.perf_counter() - t0)
    except Exception as exc:
        return Outcome(task, error=error_message(exc), seconds=time.perf_counter() - t0)


def make_tasks(files, *, known_hashes=frozenset(), on_error=None, on_skip=None,
               on_known=None, roots=None) -> list:
    """Hash the files (with their textures) and make a :class:`Task` for each new one.

    Parameters
    ----------
    files : sequence of pathlib.Path
    roots : dict of pathlib.Path -> pathlib.Path, optional
        The folder the ingest was given that holds each file (:func:`ingest.discover` with
        ``roots=True``); a file missing here is relative to its own folder.
    known_hashes : set of str
        Hashes already stored: those files are skipped.
    on_error : callable, optional
        ``on_error(path, message)`` for files that cannot be read.
    on_skip : callable, optional
        ``on_skip(path, reason)`` for files skipped: ``reason`` is None for files already stored
        or repeated in ``files``, the message (``"not a regular file: a named pipe (FIFO)"``)
        for files that are not regular files and are not read.
    on_known : callable, optional
        ``on_known(path, content_hash)`` for files whose model is stored already (one of
        ``known_hashes``), besides ``on_skip``.

    Returns
    -------
    list of Task
    """
    seen = set(known_hashes)
    tasks = []
    for f in files:
        try:
            st = os.stat(f)
            if not stat.S_ISREG(st.st_mode):
                raise not_regular(f, st.st_mode)
            tex = find_texture(f)
            h = hash_files(f, texture=tex)
        except NotRegularFile as exc:
            if on_skip is not None:
                on_skip(f, str(exc))
            continue
        except OSError as exc:
            if on_error is not None:
                on_error(f, f"cannot read ({exc.strerror or exc})")
            continue
        if h in seen:
            if on_skip is not None:
                on_skip(f, None)
            if on_known is not None and h in known_hashes:
                on_known(f, h)
            continue
        seen.add(h)
        root = (roots or {}).get(f, Path(f).parent)
        tasks.append(Task(str(f), None if tex is None else str(tex), h,
                          source_rel=Path(os.path.relpath(f, root)).as_posix(),
                          size=int(st.st_size), mtime=float(st.st_mtime)))
    return tasks
