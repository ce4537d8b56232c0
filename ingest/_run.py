"""Bulk ingestion: files and folders → processed models → one surfidx database.

Data flow of :func:`run`:

1. :func:`ingest.discover` (:mod:`ingest._files`) lists the model files once (folders
   recursively, every suffix of ``surfidx.io.SUPPORTED_SUFFIXES``, sorted), and
   :func:`surfidx.io.find_texture` pairs a textured OBJ whose UVs name no texture with a PNG beside
   it.
2. :func:`ingest.make_tasks` (:mod:`ingest._tasks`) computes every file's content hash (file bytes, then texture bytes) is computed first; files already
   stored (or seen earlier in the same run) are skipped, so re-running an interrupted ingest
   resumes where it stopped. Only regular files are read (a FIFO, a device, a socket or a link
   to one is skipped unread and recorded with the reason), and never beyond the size the file
   had when it was opened.
3. The remaining :class:`ingest.Task` s go to an *executor*: a callable ``executor(fn, tasks)`` that
   yields ``fn(task)`` for every task, in completion order (and may yield ``None`` as a
   heartbeat while it waits). :class:`ProcessPool` runs them in
   worker processes (restarting the pool when a worker dies), :func:`serial` in-process,
   :class:`ingest.DaskExecutor` on a dask.distributed cluster (``scheduler=``). ``fn`` is
   :func:`ingest.process_task` bound to the processor and rate: one picklable per-model function for
   every executor.
4. Results are written by this process alone, in batched transactions (every ``batch`` models or
   ``flush_seconds``), each model inside its own savepoint: a model is stored whole or not at all,
   and a SIGINT or SIGKILL at any moment leaves a consistent database (WAL mode).
5. A failing file is recorded in ``ingest_errors`` with its message and the run goes on; the run
   ends with an :class:`IngestSummary`. A database that cannot be written (read-only, full
   disk, damaged, locked) stops the run with one :class:`surfidx.DatabaseError`; what was
   committed stays whole.

File names are text as the OS gives them (``os.fsdecode``); a name whose bytes are not UTF-8 is
processed like any other and stored and reported through :func:`surfidx.db.catalog.escape_name`
(undecodable bytes as ``\\xHH``). Worker processes end when the process that started them dies
(even by SIGKILL, as the OOM killer sends it): see :class:`ProcessPool`.

Progress: the bar moves within a model. A processor that takes ``progress=`` (as
:func:`surfidx.pipeline.process_model` does) reports its stages (:mod:`surfidx.progress`); in
this process they advance the bar directly, from :class:`ProcessPool` workers they come through
a ``multiprocessing`` manager's queue that this process drains as results and heartbeats arrive
(a worker that dies loses only its own events). On a Dask cluster the bar moves per model.
"""

from __future__ import annotations

import concurrent.futures as cf
import contextlib
import functools
import os
import signal
import sys
import threading
import time
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass, field

from surfidx.errors import InputError, SurfidxError
from surfidx.validate import check_positive_int

from ._files import discover
from surfidx.validate import accepts_keyword

from ._tasks import Outcome, error_message, make_tasks, process_task, resolve_processor

__all__ = ["run", "IngestSummary", "serial", "ProcessPool", "exit_with_parent",
           "default_workers"]


# ---------------------------------------------------------------------- executors
#: Seconds between a worker's checks that its parent is alive (the portable fallback).
_PARENT_POLL = 0.5

_PR_SET_PDEATHSIG = 1


def _watch_parent(parent: int, poll: float) -> None:
    while True:
        time.sleep(poll)
        if os.getppid() != parent:                 # reparented: the parent has died
            os._exit(1)


def exit_with_parent(*, poll: float = _PARENT_POLL) -> None:
    """Make this (worker) process end when its parent process dies, however it dies.

    On Linux the kernel sends SIGKILL at the parent's death (``prctl(PR_SET_PDEATHSIG)``, via
    ctypes); everywhere, a daemon thread checks ``os.getppid()`` every ``poll`` seconds and
    exits the process once it has been reparented (the fallback, and the guard against a parent
    that died before the call). Called in every :class:`ProcessPool` worker; the workers of a
    Dask LocalCluster end with their parent through dask's own watch of it.

    Parameters
    ----------
    poll : float
        Seconds between the thread's checks.
    """
    parent = os.getppid()
    if sys.platform.startswith("linux"):
        try:
            import ctypes

            libc = ctypes.CDLL(None, use_errno=True)
            libc.prctl(_PR_SET_PDEATHSIG, int(signal.SIGKILL), 0, 0, 0)
        except (OSError, AttributeError):  # pragma: no cover - no prctl: the thread remains
            pass
    threading.Thread(target=_watch_parent, args=(parent, float(poll)), daemon=True,
                     name="surfidx-parent-watch").start()


def _worker_init(parent_pid: int) -> None:
    """Worker initializer: Ctrl-C is the parent's to handle (it stops the workers), and the
    worker ends when its parent dies (:func:`exit_with_parent`)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    if os.getppid() != parent_pid and not _alive(parent_pid):
        os._exit(1)                                 # the parent died while this one started
    exit_with_parent()


def _worker_context():
    """How worker processes start: forked from this process when it computes in the portable
    numerics profile already (the ``surfidx`` command), else spawned in it
    (:func:`surfidx.numerics.portable_context`), so that every worker makes the same bytes
    whoever started the ingestion."""
    import multiprocessing

    from surfidx.numerics import portable_context, portable_environment

    return multiprocessing.get_context() if not portable_environment() else portable_context()


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:  # pragma: no cover - exists, not ours
        return True
    return True


def default_workers() -> int:
    """The default worker count of an ingest: the cores this process may run on
    (``len(os.sched_getaffinity(0))`` where the OS has it, else ``os.cpu_count()``; at least 1)."""
    try:
        n = len(os.sched_getaffinity(0))
    except (AttributeError, OSError):       # pragma: no cover - macOS, Windows
        n = os.cpu_count() or 1
    return max(int(n), 1)


class _StageQueue:
    """The stage events of models processed in worker processes: a ``multiprocessing``
    manager's queue (its server process ends with this one, :func:`exit_with_parent`); workers
    put ``(path, stage, done, total)`` through :class:`_StageSender`, this process drains it.

    A worker killed at any moment leaves the queue usable (each put is one request to the
    server); a server that is gone makes puts and drains do nothing."""

    def __init__(self, mp_context=None):
        import multiprocessing
        from multiprocessing.managers import SyncManager

        self.manager = SyncManager(ctx=mp_context or multiprocessing.get_context())
        self.manager.start(_worker_init, (os.getpid(),))
        self.queue = self.manager.Queue()

    def sender(self):
        return _StageSender(self.queue)

    def drain(self, on_event) -> None:
        """Call ``on_event(path, stage, done, total)`` for every event queued now."""
        import queue as _queue

        while True:
            try:
                event = self.queue.get_nowait()
            except _queue.Empty:
                return
            except Exception:   # pragma: no cover - the server is gone: no more events
                return
            on_event(*event)

    def close(self) -> None:
        try:
            self.manager.shutdown()
        except Exception:  # pragma: no cover - already gone
            pass


class _StageSender:
    """Picklable ``sender(path, stage, done, total)`` of a worker: one put on the queue (a
    failed put is dropped: progress never fails a model)."""

    def __init__(self, queue):
        self.queue = queue

    def __call__(self, path, stage, done, total):
        try:
            self.queue.put((path, stage, int(done), int(total)))
        except Exception:  # pragma: no cover - the parent's manager is gone
            pass


def serial(fn, tasks):
    """The in-process executor: yield ``fn(task)`` for each task in order."""
    for task in tasks:
        yield fn(task)


class ProcessPool:
    """A process-pool executor (``concurrent.futures.ProcessPoolExecutor``) that survives crashes.

    Calling it, ``pool(fn, tasks)``, yields ``fn(task)`` for every task in completion order,
    keeping at most ``2 * workers`` tasks in flight, and ``None`` every ``heartbeat`` seconds
    without a completion (so the caller can write finished models by time). When a worker
    process dies (``BrokenProcessPool``), the tasks that were in flight are re-run one at a time in a fresh
    single-worker pool so that the culprit is identified: it yields an :class:`Outcome` with the
    error ``"worker process crashed (...)"``, the innocent ones their normal results; then the
    main pool is restarted and the run continues.

    Workers ignore SIGINT; on ``KeyboardInterrupt`` in the parent (or when the caller stops
    iterating) running workers are terminated. Workers also end when the parent process dies
    (SIGKILL, the OOM killer): :func:`exit_with_parent`.

    Parameters
    ----------
    workers : int
    heartbeat : float
        Seconds between ``None`` yields while waiting.
    mp_context : multiprocessing context, optional
        E.g. ``multiprocessing.get_context("spawn")``; default: the platform's (fork on Linux).
    """

    def __init__(self, workers: int, *, heartbeat: float = 1.0, mp_context=None):
        self.workers = check_positive_int(workers, "workers")
        self.heartbeat = float(heartbeat)
        self.mp_context = mp_context
        self._pool = None

    def _new_pool(self, n):
        return cf.ProcessPoolExecutor(max_workers=n, mp_context=self.mp_context or _worker_context(),
                                      initializer=_worker_init, initargs=(os.getpid(),))

    def shutdown(self, *, kill: bool = False):
        """Stop the workers, cancelling queued tasks (``kill``: terminate running ones too)."""
        if self._pool is not None:
            procs = list((getattr(self._pool, "_processes", None) or {}).values())
            self._pool.shutdown(wait=False, cancel_futures=True)
            if kill:
                for proc in procs:
                    proc.terminate()
            self._pool = None

    def __call__(self, fn, tasks):
        pending = list(tasks)[::-1]
        try:
            while pending:
                self._pool = self._new_pool(self.workers)
                in_flight = {}
                broken = []
                while pending or in_flight:
                    while pending and len(in_flight) < 2 * self.workers and not broken:
                        task = pending.pop()
                        try:
                            in_flight[self._pool.submit(fn, task)] = task
                        except BrokenProcessPool:
                            broken.append(task)
                    if not in_flight:
                        break
                    done, _ = cf.wait(in_flight, timeout=self.heartbeat,
                                      return_when=cf.FIRST_COMPLETED)
                    if not done:
                        yield None                  # heartbeat: lets the caller flush by time
                        continue
                    for fut in done:
                        task = in_flight.pop(fut)
                        try:
                            yield fut.result()
                        except BrokenProcessPool:
                            broken.append(task)
                    if broken:
                        # Every remaining future fails as well; collect them.
                        for fut, task in list(in_flight.items()):
                            try:
                                res = fut.result()
                            except BrokenProcessPool:
                                broken.append(task)
                            else:
                                yield res
                        in_flight.clear()
                        break
                self.shutdown()
                for task in broken:
                    yield self._isolated(fn, task)
        except (KeyboardInterrupt, GeneratorExit):
            self.shutdown(kill=True)
            raise
        finally:
            self.shutdown()

    def _isolated(self, fn, task):
        pool = self._new_pool(1)
        try:
            return pool.submit(fn, task).result()
        except BrokenProcessPool as exc:
            return Outcome(task, error=f"worker process crashed (BrokenProcessPool: {exc})")
        finally:
            pool.shutdown(wait=False, cancel_futures=True)


def _check_picklable(processor):
    import pickle

    try:
        pickle.dumps(processor)
    except Exception as exc:
        raise InputError(f"with workers > 1 the processor must be picklable (a module-level "
                         f"function), got {processor!r} ({exc})") from exc


# ---------------------------------------------------------------------- run
@dataclass
class IngestSummary:
    """The outcome of an ingest run.

    Attributes
    ----------
    run_id : int
    stored, skipped, failed : int
    ids : list of int
        Ids of the models stored by this run.
    errors : list of (str, str)
        ``(path, message)`` of every failed file.
    skips : list of (str, str)
        ``(path, reason)`` of every file skipped unread because it is not a regular file
        (counted in ``skipped``, recorded in ``ingest_errors`` as ``"skipped: <reason>"``).
    seconds : float
    status : str
        ``"finished"`` or ``"interrupted"``.
    """

    run_id: int
    stored: int = 0
    skipped: int = 0
    failed: int = 0
    ids: list = field(default_factory=list)
    errors: list = field(default_factory=list)
    skips: list = field(default_factory=list)
    seconds: float = 0.0
    status: str = "finished"

    def __str__(self):
        return (f"run {self.run_id}: stored {self.stored}, skipped {self.skipped}, "
                f"failed {self.failed} in {self.seconds:.1f} s")

def run(paths, *, db, workers: int | None = None, bits_per_surfel: float | None = None,
        options=None, processor=None, progress: bool = True, executor=None, batch: int = 8,
        flush_seconds: float = 2.0, scheduler=None, retries: int = 2, name: str | None = None,
        tags=(), allow_outside_textures: bool = False, replace=None,
        keep_original: bool = False) -> IngestSummary:
    """Ingest model files and folders into a database, skipping models already stored.

    Parameters
    ----------
    paths : sequence of str or os.PathLike
        Model files and folders (see :func:`discover`).
    db : surfidx.db.catalog.Catalog or str or os.PathLike
        An open database, or the path of one (created when missing).
    workers : int, optional
        Worker processes; ``1`` processes in this process. Default: as many as the machine's
        cores (:func:`default_workers`), or 1 when the processor cannot be sent to worker
        processes (not picklable). With ``scheduler="local"`` the LocalCluster's workers;
        ignored with a running cluster (its workers are used).
    bits_per_surfel : float, optional
        Coding rate passed to the processor (default ``options.codec.bits_per_surfel``).
    options : surfidx.options.ProcessOptions, optional
        Every setting of the processing; passed (with ``bits_per_surfel`` put in) to a
        processor that takes ``options=``, as :func:`surfidx.pipeline.process_model` does.
    processor : callable, optional
        ``processor(path, *, bits_per_surfel, texture) -> ProcessedModel``; default
        ``surfidx.pipeline.process_model``. With ``workers > 1`` it must be picklable (a
        module-level function).
    progress : bool
        Show a tqdm progress bar (rate, ETA) on stderr; it moves within a model when the
        processor takes ``progress=`` (see the module notes).
    executor : callable, optional
        ``executor(fn, tasks)`` yielding ``fn(task)`` per task as they complete (and optionally
        ``None`` as a heartbeat while waiting); default
        :func:`serial` for one worker, else :class:`ProcessPool` ``(workers)``.
    batch : int
        Models per write transaction.
    flush_seconds : float
        Longest time a finished model waits before it is written.
    scheduler : str or distributed.Client, optional
        Run the per-model work on a Dask cluster (:class:`ingest.DaskExecutor`): ``"local"``
        starts a LocalCluster of ``workers`` processes, ``"tcp://HOST:PORT"`` connects to a
        running scheduler. This process remains the only writer of the database.
    retries : int
        With ``scheduler``: times a model whose worker died is submitted again before it is
        recorded as failed.
    name : str, optional
        The stored model's name, when ``paths`` names one file (it must be free; by default a
        model is named after its file's stem, see :meth:`surfidx.Database.add`).
    tags : sequence of str
        Tags given to every model this run stores.
    allow_outside_textures : bool
        Passed to the processor (``surfidx.pipeline.process_model``): use textures an OBJ's MTL
        names outside the model's folder (and keep them with ``keep_original``).
    replace : int or str, optional
        A stored model (name, ``NAME@N`` or id): the one file ``paths`` names is stored as its
        next version. Without it a changed file read from the absolute path of a stored model
        becomes that model's next version (:meth:`surfidx.db.catalog.Catalog.add`).
    keep_original : bool
        Also store each new model's original files (:func:`surfidx.io.original_files`: the
        file, its material libraries, textures and buffers) as deduplicated blobs
        (:meth:`surfidx.db.catalog.Catalog.keep_original`); a file larger than
        :data:`surfidx.db.catalog.MAX_ORIGINAL_BYTES` fails its model.

    Returns
    -------
    IngestSummary

    Raises
    ------
    InputError
        A path does not exist, bad ``workers``/``bits_per_surfel``/``batch``/``retries``, a
        processor that cannot be sent to worker processes, both ``executor`` and
        ``scheduler``, ``replace`` with several files or with ``name``.
    SurfidxError
        ``scheduler`` without dask.distributed installed, or a scheduler that cannot be reached
        (before anything is written).
    DatabaseError
        The database cannot be opened or written (not a surfidx database, read-only, full disk,
        damaged, locked past the timeout), or ``replace`` names no stored model: the run
        stops; every model committed is whole. A
        file that fails SQLite's ``PRAGMA quick_check`` is refused before anything is written
        (:meth:`surfidx.db.catalog.Catalog.check_intact`).

    Notes
    -----
    ``KeyboardInterrupt`` writes the models finished so far, marks the run ``interrupted`` and
    propagates; a re-run resumes. After SIGKILL the run row stays ``running``; every model that was
    committed is whole.
    """
    from surfidx.db.catalog import Catalog

    defaulted = workers is None
    workers = default_workers() if defaulted else check_positive_int(workers, "workers")
    batch = check_positive_int(batch, "batch")
    from surfidx.options import ProcessOptions

    if options is not None and not isinstance(options, ProcessOptions):
        raise InputError(f"options must be a ProcessOptions, got {type(options).__name__}")
    if bits_per_surfel is not None:
        bits_per_surfel = float(bits_per_surfel)
        if not bits_per_surfel > 0:
            raise InputError(f"bits_per_surfel must be positive, got {bits_per_surfel}")
        if options is not None:
            options = options.updated(**{"codec.bits_per_surfel": bits_per_surfel})
    else:
        bits_per_surfel = (ProcessOptions() if options is None else options).codec.bits_per_surfel
    paths = [paths] if isinstance(paths, (str, os.PathLike)) else list(paths)
    files, roots = discover(paths, roots=True)
    if name is not None and len(files) != 1:
        raise InputError(f"a name names one model; the paths hold {len(files)} model files")
    if replace is not None and len(files) != 1:
        raise InputError(f"--replace stores one file as the next version of a model; the paths "
                         f"hold {len(files)} model files")
    if replace is not None and name is not None:
        raise InputError("give either a name (a new model) or replace (a new version of a "
                         "stored one), not both")
    processor = resolve_processor(processor)
    if scheduler is not None and executor is not None:
        raise InputError("give either executor or scheduler, not both")
    if scheduler is None and executor is None and workers > 1:
        if defaulted:
            try:
                _check_picklable(processor)
            except InputError:
                workers = 1                 # a closure or lambda runs in this process
        else:
            _check_picklable(processor)
    with contextlib.ExitStack() as stack:
        if scheduler is not None:
            from ._dask import DaskExecutor

            # Connect (or start the LocalCluster) before anything is written.
            executor = stack.enter_context(DaskExecutor(scheduler, workers=workers,
                                                        retries=retries))
        if not isinstance(db, Catalog):
            db = stack.enter_context(Catalog(db))
        if replace is not None:
            db.resolve(replace)         # a model to replace must exist before any work
        return _ingest(files, [str(p) for p in paths], db=db, workers=workers,
                       bits_per_surfel=bits_per_surfel, options=options, processor=processor,
                       progress=progress, executor=executor, batch=batch, flush_seconds=flush_seconds, name=name,
                       tags=[tags] if isinstance(tags, str) else list(tags),
                       allow_outside_textures=allow_outside_textures, roots=roots,
                       replace=replace, keep_original=keep_original)


def _keep_original(db, model_id, task, allow_outside) -> None:
    """Store the original files of the model a task made (the file, the files it names, the
    texture paired with it), checked against the task's content hash."""
    from surfidx.io.originals import original_files

    files = original_files(task.path, texture=task.texture, allow_outside=allow_outside)
    db.keep_original(model_id, files, content_hash=task.content_hash,
                     hashed=[p for p in (task.path, task.texture) if p is not None])


class _BarMoves:
    """The progress bar's position: finished models plus the finished share of each running
    one (:func:`surfidx.progress.stage_fraction` of its latest stage event)."""

    def __init__(self):
        self.bar = None
        self.finished = 0
        self.running = {}
        self.closed = set()             # late events of a finished model move nothing

    def _move(self):
        target = self.finished + sum(self.running.values())
        if self.bar is not None and target > self.bar.n:
            self.bar.update(target - self.bar.n)

    def event(self, path, stage, done, total):
        from surfidx.progress import stage_fraction

        f = stage_fraction(stage, done, total)
        if path not in self.closed and f > self.running.get(path, 0.0):
            self.running[path] = f
            self._move()

    def done(self, path):
        self.running.pop(path, None)
        self.closed.add(path)
        self.finished += 1
        self._move()


def _ingest(files, paths, *, db, workers, bits_per_surfel, options, processor, progress, executor,
            batch, flush_seconds, name, tags, allow_outside_textures, roots=None, replace=None,
            keep_original=False) -> IngestSummary:
    """The run of :func:`run` on its checked arguments: ``files`` found once by
    :func:`discover`, ``db`` open, ``executor`` None or ready."""
    from surfidx.db.catalog import escape_name, is_storage_failure, storable_text

    t_start = time.perf_counter()
    db.check_intact()               # a damaged file is not written into: nothing is recorded
    n_workers = getattr(executor, "n_workers", workers)      # a cluster's actual worker count
    summary = IngestSummary(run_id=db.start_run(paths, workers=n_workers,
                                                bits_per_surfel=bits_per_surfel))
    pending_errors = []

    def fail(path, message):               # summary: as stored; record_error escapes itself
        summary.failed += 1
        summary.errors.append((escape_name(path), storable_text(message)))
        pending_errors.append((str(path), message))

    def skip(path, reason=None):
        summary.skipped += 1
        if reason is not None:
            summary.skips.append((escape_name(path), reason))
            pending_errors.append((str(path), f"skipped: {reason}"))

    buffer = []
    last_flush = time.monotonic()

    def flush():
        nonlocal last_flush
        # What the summary says must be what was committed: restored if the transaction fails.
        before = (summary.stored, summary.skipped, summary.failed, len(summary.ids),
                  len(summary.errors), len(pending_errors))
        try:
            with db.transaction():
                for outcome in buffer:
                    if db.has_hash(outcome.task.content_hash):  # stored meanwhile by another run
                        summary.skipped += 1
                        continue
                    try:
                        with db.transaction():
                            if name is not None:
                                outcome.model.name = name
                            mid = db.add(outcome.model, exact_name=name is not None,
                                         replace=replace)
                            if tags:
                                db.tag(mid, tags)
                            if keep_original:
                                _keep_original(db, mid, outcome.task, allow_outside_textures)
                        summary.ids.append(mid)
                        summary.stored += 1
                    except (SurfidxError, ValueError, TypeError, AttributeError, OSError) as exc:
                        if is_storage_failure(exc):
                            raise                       # the database, not the model
                        fail(outcome.task.path, error_message(exc))
                for path, message in pending_errors:
                    db.record_error(summary.run_id, path, message)
                db.update_run(summary.run_id, stored=summary.stored, skipped=summary.skipped,
                              failed=summary.failed)
        except BaseException:
            summary.stored, summary.skipped, summary.failed = before[:3]
            del summary.ids[before[3]:], summary.errors[before[4]:], pending_errors[before[5]:]
            raise
        buffer.clear()
        pending_errors.clear()
        last_flush = time.monotonic()

    bar = None
    stage_queue = None
    moved = _BarMoves()
    status = "failed"
    stack = contextlib.ExitStack()
    try:
        known = []
        tasks = make_tasks(files, known_hashes=db.hashes(), on_error=fail, on_skip=skip,
                           on_known=lambda path, h: known.append(h), roots=roots)
        if tags and known:          # a re-run with tags tags the models it finds stored
            with db.transaction():
                db.tag(db.ids_of_hashes(known), tags)
        flush()
        if executor is None:
            executor = serial if workers == 1 else ProcessPool(workers)
        sender = None
        if progress and tasks:
            from tqdm import tqdm

            if accepts_keyword(processor, "progress"):
                if executor is serial:
                    sender = moved.event
                elif isinstance(executor, ProcessPool):
                    try:
                        stage_queue = stack.enter_context(
                            contextlib.closing(_StageQueue(executor.mp_context)))
                        sender = stage_queue.sender()
                    except Exception:  # pragma: no cover - no manager: the bar moves per model
                        stage_queue = None
            # with stage events the bar counts tenths of a model
            fmt = None if sender is None else ("{l_bar}{bar}| {n:.1f}/{total_fmt} "
                                               "[{elapsed}<{remaining}{postfix}]")
            bar = tqdm(total=len(tasks), unit="model", desc="ingest", dynamic_ncols=True,
                       bar_format=fmt)
        moved.bar = bar
        fn = functools.partial(process_task, processor=processor,
                               bits_per_surfel=bits_per_surfel, options=options,
                               allow_outside_textures=allow_outside_textures, stages=sender)
        results = executor(fn, tasks)
        try:
            for outcome in results:
                if stage_queue is not None:
                    stage_queue.drain(moved.event)
                if outcome is None:                         # executor heartbeat
                    if buffer and time.monotonic() - last_flush >= flush_seconds:
                        flush()
                    continue
                if outcome.error is not None:
                    fail(outcome.task.path, outcome.error)
                else:
                    buffer.append(outcome)
                if bar is not None:
                    moved.done(outcome.task.path)
                    bar.set_postfix(stored=summary.stored + len(buffer), failed=summary.failed,
                                    refresh=False)
                if len(buffer) >= batch or time.monotonic() - last_flush >= flush_seconds:
                    flush()
        finally:
            close = getattr(results, "close", None)
            if close is not None:
                close()
        flush()
        status = "finished"
    except KeyboardInterrupt:
        status = "interrupted"
        try:
            flush()
        except BaseException:  # pragma: no cover - second interrupt while writing
            pass
        raise
    finally:
        stack.close()
        if bar is not None:
            bar.close()
        summary.status = status
        summary.seconds = time.perf_counter() - t_start
        try:
            db.finish_run(summary.run_id, stored=summary.stored, skipped=summary.skipped,
                          failed=summary.failed, status=status)
        except BaseException:  # pragma: no cover - database gone while unwinding
            if status == "finished":
                raise
    return summary
