"""Query-by-example latency of surfidx.search at 10k and 100k stored models (synthetic rows).

Fills a temporary surfidx database with random descriptors of the sizes surfidx.descriptors makes
(taken from ``describe_grid`` on a small grid at the given lmax: today "shape" 198 floats,
"spectrum" 3, "texture" 78 for the 70 % coloured models) by bulk SQL inserts, then times:

* load: ``SearchIndex(db)`` (reading the descriptor matrices from SQLite),
* top-10: one ``SearchIndex.query(..., k=10)`` (median and worst of 50 random queries).

Run: ``python benchmarks/query_latency.py [--lmax 24] [--sizes 10000 100000]``.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from surfidx.database import Database, utc_now
from surfidx.search import SearchIndex


def sizes(lmax: int) -> dict:
    """Vector length per descriptor kind, as surfidx.descriptors makes them."""
    from surfidx.descriptors import describe_grid
    from surfidx.icosphere import icosphere

    v = icosphere(3).vertices
    vals = np.c_[v * [1.0, 1.5, 2.0], 127 * (v + 1)]
    return {k: int(x.size) for k, x in describe_grid(vals, 3, lmax=lmax).vectors.items()}


def fill(db: Database, m: int, lmax: int, rng) -> None:
    d = sizes(lmax)
    dim, dtex = d["shape"], d["texture"]
    shape = rng.standard_normal((m, dim)).astype("<f4")
    spectrum = rng.random((m, 3)).astype("<f4")
    texture = rng.standard_normal((m, dtex)).astype("<f4")
    color = rng.random(m) < 0.7
    now = utc_now()
    with db.transaction():
        db.conn.executemany(
            "INSERT INTO models (id, name, source, content_hash, n_surfels, has_color, bbox_min_x,"
            " bbox_min_y, bbox_min_z, bbox_max_x, bbox_max_y, bbox_max_z, ingested_at, params)"
            " VALUES (?, ?, ?, ?, 1000, ?, 0, 0, 0, 1, 1, 1, ?, '{}')",
            ((i + 1, f"m{i}", f"/synthetic/m{i}.ply", f"{i:064x}", int(color[i]), now)
             for i in range(m)))
        db.conn.executemany(
            "INSERT INTO descriptors (model_id, kind, dimension, vector) VALUES (?, ?, ?, ?)",
            ((i + 1, "shape", dim, shape[i].tobytes()) for i in range(m)))
        db.conn.executemany(
            "INSERT INTO descriptors (model_id, kind, dimension, vector) VALUES (?, ?, ?, ?)",
            ((i + 1, "spectrum", 3, spectrum[i].tobytes()) for i in range(m)))
        db.conn.executemany(
            "INSERT INTO descriptors (model_id, kind, dimension, vector) VALUES (?, ?, ?, ?)",
            ((i + 1, "texture", dtex, texture[i].tobytes()) for i in range(m) if color[i]))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--lmax", type=int, default=24)
    ap.add_argument("--sizes", type=int, nargs="+", default=[10_000, 100_000])
    ap.add_argument("--queries", type=int, default=50)
    args = ap.parse_args()
    rng = np.random.default_rng(0)
    d = sizes(args.lmax)
    print(f"descriptors: shape {d['shape']} + spectrum 3 + texture {d['texture']} float32, "
          f"70 % coloured; {args.queries} queries, k = 10, default shape weight")
    print(f"{'models':>8} {'fill s':>8} {'load ms':>8} {'top-10 median ms':>17} "
          f"{'top-10 max ms':>14}")
    with tempfile.TemporaryDirectory() as tmp:
        for m in args.sizes:
            path = Path(tmp) / f"bench{m}.db"
            with Database(path) as db:
                t0 = time.perf_counter()
                fill(db, m, args.lmax, rng)
                t_fill = time.perf_counter() - t0
                t0 = time.perf_counter()
                index = SearchIndex(db)
                t_load = time.perf_counter() - t0
                index.query({"shape": index.stored["shape"][0]}, k=10)       # warm-up
                times = []
                for _ in range(args.queries):
                    i = int(rng.integers(m))
                    q = {"shape": index.stored["shape"][i],
                         "spectrum": index.stored["spectrum"][i]}
                    if index.present["texture"][i]:
                        q["texture"] = index.stored["texture"][i]
                    t0 = time.perf_counter()
                    ids, _ = index.query(q, k=10)
                    times.append(time.perf_counter() - t0)
                    assert ids[0] == index.ids[i]
            print(f"{m:>8} {t_fill:>8.2f} {t_load * 1e3:>8.1f} {np.median(times) * 1e3:>17.2f} "
                  f"{max(times) * 1e3:>14.2f}")


if __name__ == "__main__":
    main()
