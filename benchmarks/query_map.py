"""How a query by example is mapped: the query's map against the ingest's, by retrieval.

A query's descriptors are only compared with stored ones, so its spherical map may stop sooner
than an ingest's (:meth:`surfidx.sphere.MapOptions.for_query`: fewer balancing steps at the finest
level, which take most of a map's time) and its grid may be coarser
(:attr:`surfidx.describe.DescribeOptions.query_level`). For every labelled model of ``../shared/data/retrieval``
this script describes the model file as ``surfidx query FILE`` does
(:func:`surfidx.pipeline.describe_model` with ``for_query=True``) and ranks the other models by
their stored descriptors (those of the ingest's map: the grids ``benchmarks/retrieval.py``
caches, described by :func:`surfidx.describe.describe_grid`), leave-one-out: nearest neighbour,
mean average precision (all models, genus 0), the query's own stored model first (its descriptors
of the ingest's map nearer than any other model's), and the CPU seconds of the description
(read, map, resample, describe). ``--variants`` adds rows for other map settings (JSON: a name to
a dict of :class:`surfidx.sphere.MapOptions` fields over the ingest's map); ``--with-ingest-map``
adds the ingest's own map as a row (each query then equals its stored model).

Run ``python benchmarks/query_map.py [--with-ingest-map] [--variants JSON] [--limit N]
[--markdown]`` (the retrieval cache of ``benchmarks/retrieval.py`` is used and filled;
about 2 s of CPU per model and row).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
import warnings
from dataclasses import replace
from pathlib import Path

import retrieval as R       # first: it sets the numerics profile before numpy loads
from _markdown import Report, add_markdown_option

import numpy as np


def stored_descriptors(paths, cache_dir):
    """The descriptors an ingest stores for each model: its cached grid (computed and cached by
    :func:`retrieval.compute` when missing) described."""
    from surfidx.describe.descriptors import describe_grid

    rv = R.repair_version()
    out = []
    for p in paths:
        h = R.file_hash(p)
        name = f"{h}-repaired-{rv}.npz" if R.needs_repair(p) else f"{h}.npz"
        rec = R.compute({"path": str(p), "variant": None, "method": "tutte",
                         "cache_file": str(cache_dir / name)})
        if rec["error"]:
            raise SystemExit(f"{p}: {rec['error']}")
        out.append(describe_grid(rec["grid"], rec["level"]).vectors)
    return out


def query_descriptors(paths, options, *, for_query):
    """Each model file described as a query (:func:`surfidx.pipeline.describe_model`), and the
    CPU seconds of each description."""
    from surfidx.options import ProcessOptions
    from surfidx.pipeline import describe_model

    descs, cpu = [], []
    for p in paths:
        t0 = time.process_time()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            d = describe_model(p, options=options, for_query=for_query)
        cpu.append(time.process_time() - t0)
        descs.append(dict(d.descriptors.vectors))
        print(f"  {p.name}: {cpu[-1]:.2f} s", file=sys.stderr, flush=True)
    return descs, np.array(cpu)


def scores(queries, stored, classes, g0):
    """NN, mAP, genus-0 mAP (genus-0 queries among genus-0 models) and own-first share of
    ``queries`` ranked against ``stored`` (leave-one-out: each query's own model left out of the
    class ranking)."""
    from surfidx.describe.descriptors import descriptor_distance

    n = len(stored)
    d = np.array([[descriptor_distance(queries[i], stored[j]) for j in range(n)]
                  for i in range(n)])
    own_first = np.mean([d[i, i] < np.delete(d[i], i).min() for i in range(n)])

    def ap_nn(idx):
        aps, nn = [], []
        for i in idx:
            others = np.array([j for j in idx if j != i])
            order = others[np.argsort(d[i, others], kind="stable")]
            rel = classes[order] == classes[i]
            nn.append(rel[0])
            k = np.flatnonzero(rel)
            aps.append(np.mean(np.cumsum(rel)[k] / (k + 1)) if k.size else 0.0)
        return float(np.mean(nn)), float(np.mean(aps))

    nn, m = ap_nn(np.arange(n))
    _, m0 = ap_nn(np.flatnonzero(g0))
    return nn, m, m0, float(own_first)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=R.DATA)
    ap.add_argument("--cache", type=Path, default=R.CACHE)
    ap.add_argument("--cache-key", default=None, metavar="KEY",
                    help="the retrieval cache's folder (default: the code's version)")
    ap.add_argument("--limit", type=int, default=None, help="first N models only")
    ap.add_argument("--with-ingest-map", action="store_true",
                    help="also describe every model with the ingest's own map")
    ap.add_argument("--variants", default=None, metavar="JSON",
                    help='other query maps: {"name": {"final_steps": 50, ...}, ...}')
    add_markdown_option(ap, "query_map")
    args = ap.parse_args(argv)

    from surfidx.describe import DescribeOptions
    from surfidx.options import ProcessOptions
    from surfidx.sphere import MapOptions

    labels = R.read_table(args.data / "labels.csv")[:args.limit]
    meta = {r["path"]: r for r in R.read_table(args.data / "meta.csv")}
    paths = [args.data / r["path"] for r in labels]
    classes = np.array([r["class"] for r in labels])
    g0 = np.array([meta.get(r["path"], {}).get("genus") == "0" for r in labels])
    key = args.cache_key or R.code_version("tutte")
    stored = stored_descriptors(paths, args.cache / key)
    base = MapOptions()
    level = DescribeOptions().query_level
    rows = [("library query", base.for_query(), True,
             f"final steps {base.query_final_steps} ({base.query_final_steps_large} large), "
             f"grid level <= {level}")]
    if args.with_ingest_map:
        rows.insert(0, ("ingest map", base, False,
                        f"final steps {base.final_steps} ({base.final_steps_large} large)"))
    for name, fields in json.loads(args.variants or "{}").items():
        rows.append((name, replace(base, **fields), False,
                     ", ".join(f"{k} {v}" for k, v in fields.items())))
    report = Report("query_map", "The query's map", args.markdown, note=(
        f"{len(paths)} labelled models of `../shared/data/retrieval`, each described as a query "
        "by file and ranked against the others' stored descriptors (the ingest's map), "
        "leave-one-out; own first: the query's own stored descriptors nearer than any other "
        "model's. CPU: `describe_model` (read, repair, map, resample, describe) per model, one "
        "process, warm."))
    table = []
    for name, mopts, for_query, what in rows:
        print(f"{name}:", file=sys.stderr, flush=True)
        opts = ProcessOptions(map=mopts if not for_query else base)
        q, cpu = query_descriptors(paths, opts, for_query=for_query)
        nn, m, m0, own = scores(q, stored, classes, g0)
        table.append([name, what, f"{nn:.3f}", f"{m:.3f}", f"{m0:.3f}", f"{100 * own:.1f}",
                      f"{cpu.mean():.2f}", f"{np.median(cpu):.2f}", f"{cpu.max():.2f}"])
    report.table(["query map", "settings", "NN", "mAP", "genus-0 mAP", "own first %",
                  "CPU mean s", "median s", "max s"], table)
    report.finish()
    return 0


if __name__ == "__main__":
    sys.exit(main())
