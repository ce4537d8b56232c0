"""Bulk ingestion of model files into a surfidx database (``surfidx ingest``).

>>> import ingest                                                         # doctest: +SKIP
>>> summary = ingest.run(["scans/"], db="surfidx.db", bits_per_surfel=8.0)  # workers: cores
>>> print(summary)                                                        # doctest: +SKIP
run 1: stored 41, skipped 0, failed 1 in 312.4 s

Modules: :mod:`ingest._files` (discovery, content hashes),
:mod:`ingest._tasks` (tasks, the per-model function, outcomes), :mod:`ingest._run` (the data
flow, executors, the single writer) and :mod:`ingest._dask` (the dask.distributed executor:
``ingest.run(..., scheduler="local")`` or ``scheduler="tcp://HOST:PORT"``; needs
``pip install 'surfidx[distributed]'``).
"""

from ._dask import DaskExecutor
from ._files import discover, hash_files
from ._run import IngestSummary, ProcessPool, default_workers, exit_with_parent, run, serial
from ._tasks import Outcome, Task, error_message, make_tasks, process_task, resolve_processor

__all__ = ["run", "IngestSummary", "Task", "Outcome", "discover", "make_tasks",
           "process_task", "resolve_processor", "serial", "ProcessPool", "DaskExecutor",
           "error_message", "hash_files", "exit_with_parent",
           "default_workers"]
