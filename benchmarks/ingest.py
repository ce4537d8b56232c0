"""Bulk ingestion throughput: the local process pool beside dask.distributed (issue 7).

For every executor (``pool``: :class:`ingest.ProcessPool`; ``local``: ``--scheduler local``, a
LocalCluster of worker processes; ``--scheduler tcp://HOST:PORT``: a running cluster, measured
with the workers it has) and worker count, the same model files are ingested with the real
processor (``surfidx.pipeline.process_model``) into a fresh database, and the script prints:

- models (files processed, stored or failed) per minute and stored input surfels per second
  (wall time of ``ingest.run``: hashing, the per-model work and the database writes),
- the mean per-model time measured inside the workers (``Outcome.seconds``),
- the overhead per model, ``(wall * workers - sum of per-model times) / models`` (all that is not
  model work: hashing, dispatch, transfers, idle workers at the end of the run), in seconds and
  as a share of the per-model time,
- for Dask, the dispatch overhead per model: median of ``received - submitted - per-model time``
  (submit, scheduling, argument and result transfer, the client's wait), the figure the issue
  targets (under 5% of the per-model time on models of 10k+ surfels).

Workers are warmed up first (imports and numba caches: one small model per worker) and the
LocalCluster start-up is timed apart. Mind that Dask's nanny starts workers with one BLAS/OpenMP
thread (``distributed.nanny.pre-spawn-environ``) while the process pool's workers inherit this
process's settings: on a busy machine that alone changes the per-model time. Usage::

    python benchmarks/ingest.py /work/shared/data/models/{armadillo,rocker-arm}.obj \\
        --workers 1,2 --executors pool,local --db-dir /tmp/ingest-bench [--json out.json]
"""

from __future__ import annotations

import argparse
import json
import shutil
import statistics
import sys
import tempfile
import time
from pathlib import Path

# This script is named like the package it measures: import the package, not the script.
sys.path = [p for p in sys.path if Path(p or ".").resolve() != Path(__file__).resolve().parent]
import ingest  # noqa: E402
from surfidx.io import find_texture  # noqa: E402
from surfidx.pipeline import process_model  # noqa: E402

sys.path.append(str(Path(__file__).resolve().parent))   # after the package: the page helper
from _markdown import Report, add_markdown_option  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
WARMUP = REPO / "examples" / "models" / "spot" / "spot_triangulated.obj"


def warm_up() -> None:
    """Process one small model (imports, numba caches) in this process."""
    process_model(str(WARMUP), texture=find_texture(WARMUP))


class Recording:
    """Wrap an executor, keeping every outcome it yields."""

    def __init__(self, executor):
        self.executor = executor
        self.outcomes = []

    def __call__(self, fn, tasks):
        for out in self.executor(fn, tasks):
            if out is not None:
                self.outcomes.append(out)
            yield out


def measure(paths, executor, n_workers, db_path, *, label):
    rec = Recording(executor)
    summary = ingest.run(paths, db=db_path, executor=rec, progress=False)
    done = [o for o in rec.outcomes if o.error is None]
    # Every processed file is model work, stored or failed (a failure costs its read and checks).
    per_model = [o.seconds for o in rec.outcomes]
    surfels = sum(o.model.n_surfels for o in done)
    wall = summary.seconds
    n = max(1, len(per_model))
    row = {
        "executor": label, "workers": n_workers, "models": summary.stored,
        "failed": summary.failed, "wall_s": wall,
        "models_per_min": 60.0 * len(per_model) / wall if wall else float("nan"),
        "surfels_per_s": surfels / wall if wall else float("nan"),
        "mean_surfels": surfels / max(1, len(done)),
        "per_model_s": statistics.fmean(per_model) if per_model else float("nan"),
    }
    row["overhead_s"] = (wall * n_workers - sum(per_model)) / n
    row["overhead_pct"] = 100.0 * row["overhead_s"] / row["per_model_s"]
    stats = getattr(executor, "stats", None)
    if stats:
        seconds = {o.task.path: o.seconds for o in rec.outcomes}
        recent = [(p, sub, recv) for p, sub, recv in stats[-len(per_model):] if p in seconds]
        row["dispatch_ms"] = 1e3 * statistics.median(recv - sub - seconds[p]
                                                     for p, sub, recv in recent)
        row["dispatch_pct"] = 100.0 * statistics.median((recv - sub - seconds[p]) / seconds[p]
                                                        for p, sub, recv in recent)
    for path, message in summary.errors:
        print(f"  failed {path}: {message}")
    return row


def run_pool(paths, n, db_dir):
    warm_up()                     # forked workers inherit the loaded modules and compiled kernels
    return measure(paths, ingest.ProcessPool(n), n, db_dir / f"pool-{n}.db", label="pool")


def run_dask(paths, n, db_dir, scheduler):
    t0 = time.perf_counter()
    with ingest.DaskExecutor(scheduler, workers=max(1, n)) as ex:
        started = time.perf_counter() - t0
        ex.client.run(warm_up)        # every worker
        warm = time.perf_counter() - t0 - started
        workers = ex.n_workers
        label = "dask local" if scheduler == "local" else "dask " + str(scheduler)
        row = measure(paths, ex, workers, db_dir / f"dask-{n}.db", label=label)
    row["startup_s"], row["warmup_s"] = started, warm
    return row


COLUMNS = [("executor", "executor", "{}"), ("workers", "workers", "{}"), ("models", "stored", "{}"),
           ("failed", "failed", "{}"),
           ("mean_surfels", "surfels/model", "{:.0f}"), ("wall_s", "wall s", "{:.1f}"),
           ("models_per_min", "models/min", "{:.2f}"), ("surfels_per_s", "surfels/s", "{:.0f}"),
           ("per_model_s", "s/model (worker)", "{:.2f}"), ("overhead_s", "overhead s", "{:.2f}"),
           ("overhead_pct", "overhead %", "{:.1f}"), ("dispatch_ms", "dispatch ms", "{:.1f}"),
           ("dispatch_pct", "dispatch %", "{:.2f}"), ("startup_s", "cluster start s", "{:.1f}")]


def print_table(rows, report):
    cells = [[(fmt.format(r[k]) if r.get(k) is not None else "-") for k, _, fmt in COLUMNS]
             for r in rows]
    report.table([h for _, h, _ in COLUMNS], cells)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("paths", nargs="+", help="model files and folders")
    ap.add_argument("--workers", default="1,2", help="worker counts (default 1,2)")
    ap.add_argument("--executors", default="pool,local",
                    help="pool, local (LocalCluster), or both (default pool,local)")
    ap.add_argument("--scheduler", default=None,
                    help="also measure a running cluster at this address (tcp://HOST:PORT)")
    ap.add_argument("--db-dir", default=None, help="folder for the databases (default: a "
                                                   "temporary one, removed afterwards)")
    ap.add_argument("--json", default=None, help="also write the rows as JSON here")
    add_markdown_option(ap, "ingest")
    args = ap.parse_args(argv)
    counts = [int(x) for x in args.workers.split(",")]
    kinds = [k.strip() for k in args.executors.split(",") if k.strip()]
    db_dir = Path(args.db_dir or tempfile.mkdtemp(prefix="surfidx-ingest-bench-"))
    if db_dir.exists() and args.db_dir:
        for f in db_dir.glob("*.db*"):
            f.unlink()
    db_dir.mkdir(parents=True, exist_ok=True)
    files = ingest.discover(args.paths)
    print(f"{len(files)} model files; databases in {db_dir}")
    rows = []
    try:
        for kind in kinds:
            for n in counts:
                if kind == "pool":
                    row = run_pool(files, n, db_dir)
                elif kind == "local":
                    row = run_dask(files, n, db_dir, "local")
                else:
                    raise SystemExit(f"unknown executor {kind!r}: use pool, local")
                rows.append(row)
                print(f"  {row['executor']} x{n}: {row['models']} models in {row['wall_s']:.1f} s",
                      flush=True)
        if args.scheduler:
            rows.append(run_dask(files, 0, db_dir, args.scheduler))
    finally:
        if not args.db_dir:
            shutil.rmtree(db_dir, ignore_errors=True)
    print()
    report = Report("ingest", "Bulk ingestion throughput: process pool and Dask", args.markdown,
                    note=f"{len(files)} model files ingested with the real processor into a "
                         f"fresh database per executor and worker count: models per minute and "
                         f"stored surfels per second (wall time of `ingest.run`), the mean "
                         f"per-model time inside the workers, the overhead per model and, for "
                         f"Dask, the dispatch overhead per model.")
    print_table(rows, report)
    report.finish()
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=2))


if __name__ == "__main__":
    main()
