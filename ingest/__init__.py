"""Bulk ingestion of model files into a surfidx database (``surfidx ingest``).

>>> import ingest                                                         # doctest: +SKIP
>>> summary = ingest.run(["scans/"], db="surfidx.db", workers=4, bits_per_surfel=8.0)
>>> print(summary)                                                        # doctest: +SKIP
run 1: stored 41, skipped 0, failed 1 in 312.4 s

See :mod:`ingest._run` for the data flow, the executor abstraction and the texture discovery, and
:mod:`ingest._dask` for the dask.distributed executor (``ingest.run(..., scheduler="local")`` or
``scheduler="tcp://HOST:PORT"``; needs ``pip install 'surfidx[distributed]'``).
"""

from ._dask import DaskExecutor
from ._run import (IngestSummary, NotRegularFile, Outcome, ProcessPool, Task, discover,
                   error_message, exit_with_parent, find_texture, hash_files, make_tasks,
                   process_task, resolve_processor, run, serial)

__all__ = ["run", "IngestSummary", "Task", "Outcome", "discover", "find_texture", "make_tasks",
           "process_task", "resolve_processor", "serial", "ProcessPool", "DaskExecutor",
           "error_message", "hash_files", "NotRegularFile", "exit_with_parent"]
