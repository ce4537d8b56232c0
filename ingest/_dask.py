"""The dask.distributed executor of bulk ingestion (``surfidx ingest --scheduler``).

:class:`DaskExecutor` has the interface of :class:`ingest.ProcessPool`: calling it,
``executor(fn, tasks)``, yields ``fn(task)`` for every task in completion order (and ``None`` as a
heartbeat while it waits), so :func:`ingest.run` keeps one loop for both (progress bar, batched
transactions, content-hash skipping, error records, summary) and the client stays the only writer
of the database. ``fn`` is the same per-model function the process pool runs
(:func:`ingest.process_task` bound to the processor and rate); it runs on the workers, which need
only the package and read access to the input paths.

Worker deaths: a task whose worker dies (a model that crashes its worker, a killed or lost worker)
errs with ``KilledWorker`` once the scheduler's ``allowed-failures`` are spent (0 on the
LocalCluster this module starts, so every death reaches the client); the client re-submits it
under a new key up to ``retries`` times, then yields it as a failed :class:`ingest.Outcome` and the
run goes on.

Parent death: the LocalCluster's worker processes end when this process dies, even by SIGKILL
(dask's worker processes watch the process that started them); ``tests/test_ingest_dask.py``
checks it, as :func:`ingest.exit_with_parent` does it for :class:`ingest.ProcessPool`.

``distributed`` is an optional dependency (``pip install 'surfidx[distributed]'``), imported when
an executor is opened.
"""

from __future__ import annotations

import time
import uuid

from surfidx.errors import InputError, SurfidxError
from surfidx.validate import check_positive_int

from ._tasks import Outcome, error_message

__all__ = ["DaskExecutor", "import_distributed"]

_INSTALL_HINT = "install it with: pip install 'surfidx[distributed]'"


def import_distributed():
    """The ``distributed`` module.

    Raises
    ------
    SurfidxError
        dask.distributed is not installed (the message says how to install it).
    """
    try:
        import distributed
    except ImportError as exc:
        raise SurfidxError(f"ingestion on a Dask cluster needs dask.distributed, which is not "
                           f"available ({exc}); {_INSTALL_HINT}") from exc
    return distributed


class DaskExecutor:
    """Run ingestion tasks on a dask.distributed cluster; results stream back with ``as_completed``.

    Calling it, ``executor(fn, tasks)``, opens the cluster connection if it is not open (and closes
    it again at the end), submits at most ``in_flight`` tasks at a time (by default as many as the
    cluster has worker threads, re-read while it runs, so workers may join or leave), and yields
    ``fn(task)`` for every task as it completes, or ``None`` every ``heartbeat`` seconds without a
    completion. As a context manager it keeps one connection (and LocalCluster) for several calls.

    Parameters
    ----------
    scheduler : str or distributed.Client
        ``"local"``: start a LocalCluster of ``workers`` worker processes (one thread each) on this
        machine; ``"tcp://HOST:PORT"`` (or any address ``distributed.Client`` takes): connect to
        a running scheduler; a ``Client``: use it (it is not closed).
    workers : int
        Worker processes of the LocalCluster; ignored for a running cluster.
    retries : int
        Times a task whose worker died (``KilledWorker``) is submitted again before it is yielded
        as failed. With a running scheduler, its own ``distributed.scheduler.allowed-failures``
        (default 3) re-runs come on top of each submission.
    in_flight : int, optional
        Tasks submitted at once; default: the cluster's worker threads (at least 1).
    heartbeat : float
        Seconds between ``None`` yields while waiting.
    connect_timeout : float
        Seconds to wait for a running scheduler.

    Attributes
    ----------
    stats : list of (str, float, float)
        ``(path, submitted, received)`` ``time.perf_counter`` stamps of every result received
        (to measure the scheduling overhead: ``received - submitted - outcome.seconds``).

    Raises
    ------
    InputError
        Bad ``workers``/``retries``/``in_flight``, or an empty scheduler address.
    SurfidxError
        dask.distributed is not installed, or the scheduler cannot be reached (on opening).
    """

    def __init__(self, scheduler, *, workers: int = 1, retries: int = 2, in_flight=None,
                 heartbeat: float = 1.0, connect_timeout: float = 10.0):
        if isinstance(scheduler, str):
            scheduler = scheduler.strip()
            if not scheduler:
                raise InputError("the scheduler address is empty; give tcp://HOST:PORT or 'local'")
        self.scheduler = scheduler
        self.workers = check_positive_int(workers, "workers")
        if isinstance(retries, bool) or not isinstance(retries, int) or retries < 0:
            raise InputError(f"retries must be a non-negative integer, got {retries!r}")
        self.retries = retries
        self.in_flight = None if in_flight is None else check_positive_int(in_flight, "in_flight")
        self.heartbeat = float(heartbeat)
        self.connect_timeout = float(connect_timeout)
        self.client = None
        self.cluster = None
        self._own_client = False
        self.stats = []

    # ------------------------------------------------------------------ connection
    @property
    def is_local(self) -> bool:
        """True when this executor starts its own LocalCluster."""
        return isinstance(self.scheduler, str) and self.scheduler.lower() == "local"

    def open(self):
        """Connect to the scheduler (starting the LocalCluster for ``"local"``); returns self."""
        if self.client is not None:
            return self
        distributed = import_distributed()
        if not isinstance(self.scheduler, str):
            self.client = self.scheduler
            return self
        import dask

        from surfidx.numerics import environment, portable_environment

        try:
            if self.is_local:
                # Every worker death reaches the client at once: the retries are counted there.
                # The workers start in the portable numerics profile (this process's own
                # environment is restored once they have started).
                env = portable_environment()
                with dask.config.set({"distributed.scheduler.allowed-failures": 0}), \
                        environment(env):
                    self.cluster = distributed.LocalCluster(
                        n_workers=self.workers, threads_per_worker=1, processes=True,
                        host="127.0.0.1", dashboard_address=None, env=env)
                self.client = distributed.Client(self.cluster, set_as_default=False)
            else:
                self.client = distributed.Client(self.scheduler, set_as_default=False,
                                                 timeout=self.connect_timeout)
        except (OSError, TimeoutError, ValueError, RuntimeError) as exc:
            self.close()
            where = "start a LocalCluster" if self.is_local else \
                f"reach the Dask scheduler at {self.scheduler}"
            hint = (" (a script that starts one needs an `if __name__ == '__main__':` guard: "
                    "its worker processes are spawned and import it)") if self.is_local else \
                " (start one with `dask scheduler` and workers with `dask worker ADDRESS`)"
            raise SurfidxError(f"cannot {where}: {exc}{hint}") from exc
        self._own_client = True
        return self

    def close(self):
        """Close the client and the LocalCluster this executor opened."""
        client, cluster = self.client, self.cluster
        self.client = self.cluster = None
        if client is not None and self._own_client:
            try:
                client.close()
            except Exception:  # pragma: no cover - closing a broken connection
                pass
        if cluster is not None:
            try:
                cluster.close()
            except Exception:  # pragma: no cover
                pass
        self._own_client = False

    def __enter__(self):
        return self.open()

    def __exit__(self, *exc):
        self.close()

    @property
    def n_workers(self) -> int:
        """Workers connected to the scheduler now (``workers`` before opening)."""
        if self.client is None:
            return self.workers
        return len(self.client.nthreads())

    def _window(self) -> int:
        if self.in_flight is not None:
            return self.in_flight
        return max(1, sum(self.client.nthreads().values()))

    # ------------------------------------------------------------------ running
    def __call__(self, fn, tasks):
        opened_here = self.client is None
        self.open()
        try:
            yield from self._run(fn, list(tasks))
        finally:
            if opened_here:
                self.close()

    def _run(self, fn, tasks):
        from concurrent.futures import CancelledError

        from distributed import KilledWorker, as_completed, wait

        client = self.client
        token = uuid.uuid4().hex[:8]
        pending = tasks[::-1]
        attempts = {}                                 # task -> submissions so far
        in_flight = {}                                # future -> (task, submitted)
        ac = as_completed(loop=client.loop, with_results=True, raise_errors=False)
        window = self._window()
        try:
            while pending or in_flight:
                while pending and len(in_flight) < window:
                    task = pending.pop()
                    n = attempts[task] = attempts.get(task, 0) + 1
                    key = f"surfidx-ingest-{token}-{task.content_hash[:16]}-{n}"
                    fut = client.submit(fn, task, key=key, pure=False)
                    in_flight[fut] = (task, time.perf_counter())
                    ac.add(fut)
                done = ac.next_batch(block=False)
                if not done:
                    try:        # distributed's own timeout: no clock is read here
                        with client.as_current():
                            wait(list(in_flight), timeout=self.heartbeat,
                                 return_when="FIRST_COMPLETED")
                    except TimeoutError:
                        window = self._window()     # workers may have joined or left
                        yield None                  # heartbeat: lets the caller flush by time
                        continue
                    done = ac.next_batch(block=True)
                    window = self._window()
                for fut, result in done:
                    task, submitted = in_flight.pop(fut)
                    received = time.perf_counter()
                    if fut.status == "finished":
                        self.stats.append((task.path, submitted, received))
                        yield result
                        continue
                    exc = result[1] if isinstance(result, tuple) else result
                    if isinstance(exc, KilledWorker):
                        if attempts[task] <= self.retries:
                            pending.append(task)    # submitted again under a new key
                            continue
                        yield Outcome(task, error=f"worker process crashed {attempts[task]} "
                                                  f"times (KilledWorker: {exc})")
                    elif isinstance(exc, CancelledError):
                        raise SurfidxError(f"the Dask cluster cancelled the task of {task.path} "
                                           f"(scheduler lost or restarted?); re-run the ingest "
                                           f"to resume")
                    else:
                        yield Outcome(task, error=f"task failed on the cluster "
                                                  f"({error_message(exc)})")
        except (KeyboardInterrupt, GeneratorExit):
            if in_flight:
                try:
                    client.cancel(list(in_flight), force=True)
                except Exception:  # pragma: no cover - connection already gone
                    pass
            raise
        finally:
            ac.clear()
            in_flight.clear()
