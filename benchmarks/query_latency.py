"""Query-by-example latency and recall of surfidx.search at 10k / 100k / 1M stored models: the
exact scan beside the approximate index (surfidx.ann), and the candidate libraries side by side.

Rows
----
Built from the real descriptors of a database of ingested models (``--real-db``, e.g. a subset of
the retrieval collection ingested with ``surfidx ingest``), perturbed so that neighbourhoods look
like real ones (:func:`synthesize`): every row belongs to a sub-class whose centre mixes two real
models of one class (classes from ``labels.csv`` of the retrieval collection; the mixing weight
drawn towards the first) plus noise along the real models' principal directions (15 % of their
spread), and every row is its centre plus 5 % of that spread (plus a 1 % isotropic floor). 70 %
of the rows are coloured, their texture vectors built the same way from the real coloured models.
Queries are fresh rows of the same generator (new scans of stored sub-classes), half of them
without colour.

Modes
-----
* default: fills a surfidx database per size by bulk SQL (then ``Database.descriptors_changed``),
  and measures ``SearchIndex(db, exact=True)`` against ``SearchIndex(db)`` (the approximate
  index above :data:`surfidx.ann.DEFAULT_THRESHOLD` models: build or load, then top-10 with the
  exact re-rank on rows fetched from SQLite): build CPU time, resident memory, index size,
  p50/p99 CPU time of a top-10 query and recall@10 against the exact scan, for shape-only and
  coloured queries.
* ``--compare``: the same rows in memory, hnswlib, faiss-cpu and usearch HNSW indexes of the shape
  vector (one thread, connectivity 16), each with the exact re-rank of ``factor * k`` candidates.

Times are ``time.process_time`` (CPU of this process, one thread), so that a shared machine's
load changes them little. Run: ``python benchmarks/query_latency.py --real-db real.db
[--sizes 10000 100000 1000000] [--compare]``.
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import gc
import os
import tempfile
import time
from pathlib import Path

import numpy as np

from surfidx.database import Database, utc_now
from surfidx.search import DEFAULT_SHAPE_WEIGHT, SearchIndex, weighted_l2

LABELS = Path(__file__).resolve().parents[2] / "shared" / "data" / "retrieval" / "labels.csv"


def rss_mb() -> float:
    """Resident memory of this process, MB."""
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    return float("nan")  # pragma: no cover


def real_descriptors(path) -> dict:
    """Real descriptors of a database: ``shape`` (n, 201) shape + spectrum, ``classes`` (n,),
    ``texture`` (c, 78) of the coloured models."""
    with Database(path, readonly=True) as db:
        ids, shape = db.descriptor_matrix(("shape", "spectrum"))
        names = {r["id"]: r["name"] for r in db.list_models()}
        _, texture = db.descriptor_matrix("texture")
    labels = {}
    if LABELS.exists():
        with open(LABELS) as f:
            labels = {Path(r["path"]).stem: r["class"] for r in csv.DictReader(f)}
    classes = np.array([labels.get(names[int(i)], names[int(i)]) for i in ids])
    return {"shape": np.asarray(shape, np.float64), "classes": classes,
            "texture": np.asarray(texture, np.float64)}


class Generator:
    """Rows around real descriptors (see the module notes), deterministic for a seed."""

    def __init__(self, real: dict, m: int, seed: int = 0):
        rng = np.random.default_rng(seed)
        self.rng = rng
        s = real["shape"]
        self.basis, self.spread = self._pca(s)
        self.iso = 0.01 * float(s.std())
        n_sub = max(m // 20, len(s))
        base = rng.integers(len(s), size=n_sub)
        same = [np.flatnonzero(real["classes"] == c) for c in real["classes"]]
        other = np.array([rng.choice(same[b]) for b in base])
        lam = rng.beta(1.0, 3.0, n_sub)[:, None]
        self.centres = ((1 - lam) * s[base] + lam * s[other]
                        + self._noise(n_sub, 0.15, self.basis, self.spread))
        t = real["texture"]
        if len(t) == 0:                             # no coloured model: a made-up one
            t = np.abs(rng.standard_normal((2, 78)))
        self.tbasis, self.tspread = self._pca(t)
        tb = rng.integers(len(t), size=n_sub)
        tl = rng.beta(1.0, 3.0, n_sub)[:, None]
        self.tcentres = ((1 - tl) * t[tb] + tl * t[rng.integers(len(t), size=n_sub)]
                         + self._noise(n_sub, 0.3, self.tbasis, self.tspread)
                         + 0.05 * float(t.std()) * rng.standard_normal((n_sub, t.shape[1])))
        self.tiso = 0.01 * float(t.std())

    @staticmethod
    def _pca(x):
        x = x - x.mean(0)
        _, sv, vt = np.linalg.svd(x, full_matrices=False)
        spread = sv / np.sqrt(max(len(x) - 1, 1))
        if not spread.any():
            spread = np.ones_like(spread)
        return vt, spread

    def _noise(self, n, scale, basis, spread):
        z = self.rng.standard_normal((n, len(spread))) * (scale * spread)
        return z @ basis

    def rows(self, n: int, *, color_fraction: float = 0.7):
        """``shape`` (n, 201) float32, ``texture`` (n, 78) float32, ``color`` (n,) bool."""
        rng = self.rng
        sub = rng.integers(len(self.centres), size=n)
        shape = (self.centres[sub] + self._noise(n, 0.05, self.basis, self.spread)
                 + self.iso * rng.standard_normal((n, self.centres.shape[1])))
        texture = (self.tcentres[sub] + self._noise(n, 0.1, self.tbasis, self.tspread)
                   + self.tiso * rng.standard_normal((n, self.tcentres.shape[1])))
        color = rng.random(n) < color_fraction
        return shape.astype(np.float32), texture.astype(np.float32), color


def fill(db: Database, shape, texture, color) -> None:
    """Bulk-insert rows (shape = 198 shape + 3 spectrum values) as models 1..m."""
    m = len(shape)
    now = utc_now()
    conv = "{}"
    with db.transaction():
        db.conn.executemany(
            "INSERT INTO models (id, name, source, content_hash, n_surfels, has_color, bbox_min_x,"
            " bbox_min_y, bbox_min_z, bbox_max_x, bbox_max_y, bbox_max_z, ingested_at, params)"
            " VALUES (?, ?, ?, ?, 1000, ?, 0, 0, 0, 1, 1, 1, ?, '{}')",
            ((i + 1, f"m{i}", f"/synthetic/m{i}.ply", f"{i:064x}", int(color[i]), now)
             for i in range(m)))
        db.conn.executemany("INSERT INTO thumbnails (model_id, png) VALUES (?, ?)",
                            ((i + 1, b"") for i in range(m)))
        sh = shape[:, :198].astype("<f4")
        sp = shape[:, 198:].astype("<f4")
        tx = texture.astype("<f4")
        ins = ("INSERT INTO descriptors (model_id, kind, dimension, vector, convention) "
               "VALUES (?, ?, ?, ?, ?)")
        db.conn.executemany(ins, ((i + 1, "shape", 198, sh[i].tobytes(), conv) for i in range(m)))
        db.conn.executemany(ins, ((i + 1, "spectrum", 3, sp[i].tobytes(), conv)
                                  for i in range(m)))
        db.conn.executemany(ins, ((i + 1, "texture", tx.shape[1], tx[i].tobytes(), conv)
                                  for i in range(m) if color[i]))
        db.descriptors_changed()


def queries(gen: Generator, n: int):
    """Query descriptor dicts: the first half coloured, the second shape-only."""
    shape, texture, _ = gen.rows(n, color_fraction=1.0)
    out = []
    for i in range(n):
        q = {"shape": shape[i, :198], "spectrum": shape[i, 198:]}
        if i < n // 2:
            q["texture"] = texture[i]
        out.append(q)
    return out


def pct(times, p):
    return float(np.percentile(np.asarray(times) * 1e3, p))


# ---------------------------------------------------------------------- library comparison
def exact_topk(q, stored, present, k, w=DEFAULT_SHAPE_WEIGHT):
    d = weighted_l2(q, stored, present, shape_weight=w)
    part = np.argpartition(d, k - 1)[:k]
    return set(part[np.argsort(d[part], kind="stable")].tolist())


def rerank(q, stored, present, cand, k, w=DEFAULT_SHAPE_WEIGHT):
    cand = np.unique(cand[cand >= 0])
    sub = {kd: s[cand] for kd, s in stored.items()}
    pre = {kd: p[cand] for kd, p in present.items()}
    d = weighted_l2(q, sub, pre, shape_weight=w)
    return cand[np.argsort(d, kind="stable")[:k]]


class _Hnswlib:
    name = "hnswlib"

    def build(self, x, ef_add):
        import hnswlib
        self.ix = hnswlib.Index("l2", x.shape[1])
        self.ix.init_index(max_elements=len(x), ef_construction=ef_add, M=16, random_seed=0)
        self.ix.add_items(x, np.arange(len(x)), num_threads=1)

    def save(self, path):
        self.ix.save_index(str(path))

    def search(self, v, n, ef):
        self.ix.set_ef(max(ef, n))
        return self.ix.knn_query(v, k=n, num_threads=1)[0][0].astype(np.int64)


class _Faiss:
    name = "faiss"

    def build(self, x, ef_add):
        import faiss
        faiss.omp_set_num_threads(1)
        self.faiss = faiss
        self.ix = faiss.IndexHNSWFlat(x.shape[1], 16)
        self.ix.hnsw.efConstruction = ef_add
        self.ix.add(x)

    def save(self, path):
        self.faiss.write_index(self.ix, str(path))

    def search(self, v, n, ef):
        self.ix.hnsw.efSearch = max(ef, n)
        return self.ix.search(v[None], n)[1][0].astype(np.int64)


class _Usearch:
    def __init__(self, dtype):
        self.dtype = dtype
        self.name = f"usearch-{dtype}"

    def build(self, x, ef_add):
        from usearch.index import Index
        self.ix = Index(ndim=x.shape[1], metric="l2sq", dtype=self.dtype, connectivity=16,
                        expansion_add=ef_add)
        self.ix.add(np.arange(len(x)), x, threads=1)

    def save(self, path):
        self.ix.save(str(path))

    def search(self, v, n, ef):
        self.ix.expansion_search = max(ef, n)
        return np.asarray(self.ix.search(v, n, threads=1).keys, np.int64)


def compare(gen, m, qs, *, k, factors, ef, ef_add, libs):
    shape, texture, color = gen.rows(m)
    stored = {"shape": shape[:, :198], "spectrum": shape[:, 198:], "texture": texture}
    present = {"shape": np.ones(m, bool), "spectrum": np.ones(m, bool), "texture": color}
    truth = [exact_topk(q, stored, present, k) for q in qs]
    t_exact = []
    for q in qs[:20]:
        t0 = time.process_time()
        exact_topk(q, stored, present, k)
        t_exact.append(time.process_time() - t0)
    print(f"{m:>8} {'exact scan':>14} {'':>7} {'':>7} {'':>7} {'':>6} "
          f"{pct(t_exact, 50):>7.2f} {pct(t_exact, 99):>7.2f} {1.0:>7.3f} {1.0:>7.3f}",
          flush=True)
    for lib in libs:
        gc.collect()
        r0 = rss_mb()
        t0 = time.process_time()
        try:
            lib.build(shape, ef_add)
        except ImportError as exc:
            print(f"{m:>8} {lib.name:>14} not installed ({exc})")
            continue
        t_build = time.process_time() - t0
        mem = rss_mb() - r0
        with tempfile.TemporaryDirectory() as tmp:
            p = Path(tmp) / "ix"
            lib.save(p)
            size = p.stat().st_size / 2 ** 20
        for f in factors:
            n = f * k
            rec = {True: [], False: []}
            times = []
            for q, t in zip(qs, truth):
                t0 = time.process_time()
                cand = lib.search(q_vec(q), n, ef)
                if "texture" in q:
                    # the texture term: candidates of the shape index alone (see surfidx.ann)
                    pass
                got = rerank(q, stored, present, cand, k)
                times.append(time.process_time() - t0)
                rec["texture" in q].append(len(t & set(got.tolist())) / k)
            print(f"{m:>8} {lib.name:>14} {f:>7} {t_build:>7.1f} {mem:>7.0f} {size:>6.0f} "
                  f"{pct(times, 50):>7.2f} {pct(times, 99):>7.2f} {np.mean(rec[False]):>7.3f} "
                  f"{np.mean(rec[True]):>7.3f}", flush=True)
        del lib.ix


def q_vec(q):
    return np.concatenate([q["shape"], q["spectrum"]]).astype(np.float32)


# ---------------------------------------------------------------------- surfidx end to end
def end_to_end(gen, m, qs, *, k, tmp):
    from surfidx import ann

    path = Path(tmp) / f"bench{m}.db"
    shape, texture, color = gen.rows(m)
    with Database(path) as db:
        t0 = time.perf_counter()
        fill(db, shape, texture, color)
        t_fill = time.perf_counter() - t0
    del shape, texture, color
    gc.collect()
    out = {}
    with Database(path, readonly=True) as db:
        r0 = rss_mb()
        t0 = time.process_time()
        exact = SearchIndex(db, exact=True)
        t_load = time.process_time() - t0
        mem_exact = rss_mb() - r0
        truth, t_exact = [], []
        for q in qs:
            t0 = time.process_time()
            ids, _ = exact.query(q, k=k)
            t_exact.append(time.process_time() - t0)
            truth.append(set(ids.tolist()))
        del exact
        gc.collect()
        r0 = rss_mb()
        t0 = time.process_time()
        built = ann.build(db)                     # writes the index beside the database
        t_build = time.process_time() - t0
        mem_build = rss_mb() - r0
        del built
        gc.collect()
        size = ann.index_size(path) / 2 ** 20
        r0 = rss_mb()
        t0 = time.process_time()
        approx = SearchIndex(db, threshold=0)     # opens (memory-maps) the index
        t_open = time.process_time() - t0
        mem_open = rss_mb() - r0
        assert approx.approximate
        t_ann, rec = [], {True: [], False: []}
        for q, t in zip(qs, truth):
            t0 = time.process_time()
            ids, _ = approx.query(q, k=k)
            t_ann.append(time.process_time() - t0)
            rec["texture" in q].append(len(t & set(ids.tolist())) / k)
    out.update(fill=t_fill, load=t_load, mem_exact=mem_exact, build=t_build, mem_build=mem_build,
               size=size, open=t_open, mem_open=mem_open, exact50=pct(t_exact, 50),
               exact99=pct(t_exact, 99), ann50=pct(t_ann, 50), ann99=pct(t_ann, 99),
               rec_shape=float(np.mean(rec[False])), rec_color=float(np.mean(rec[True])))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--real-db", required=True, help="Database of real ingested models.")
    ap.add_argument("--sizes", type=int, nargs="+", default=[10_000, 100_000, 1_000_000])
    ap.add_argument("--queries", type=int, default=200)
    ap.add_argument("-k", type=int, default=10)
    ap.add_argument("--compare", action="store_true",
                    help="Compare hnswlib, faiss-cpu and usearch in memory instead.")
    ap.add_argument("--libs", nargs="+", default=["hnswlib", "faiss", "usearch-f32",
                                                  "usearch-f16"])
    ap.add_argument("--factors", type=int, nargs="+", default=[2, 4, 8])
    ap.add_argument("--ef", type=int, default=64, help="Search expansion (compare mode).")
    ap.add_argument("--ef-add", type=int, default=128, help="Build expansion (compare mode).")
    ap.add_argument("--tmp", default=None,
                    help="Folder for the databases, kept afterwards (default: a temp, removed).")
    args = ap.parse_args()
    real = real_descriptors(args.real_db)
    print(f"real descriptors: {len(real['shape'])} models ({len(set(real['classes']))} classes), "
          f"{len(real['texture'])} coloured; {args.queries} queries (half coloured), "
          f"k = {args.k}, w = {DEFAULT_SHAPE_WEIGHT}; load {os.getloadavg()[0]:.1f}")
    if args.compare:
        make = {"hnswlib": _Hnswlib, "faiss": _Faiss, "usearch-f32": lambda: _Usearch("f32"),
                "usearch-f16": lambda: _Usearch("f16"), "usearch-i8": lambda: _Usearch("i8")}
        print(f"HNSW M=16, ef_construction {args.ef_add}, ef_search max({args.ef}, candidates); "
              "CPU ms per query incl. exact re-rank in memory")
        print(f"{'models':>8} {'library':>14} {'factor':>7} {'build s':>7} {'mem MB':>7} "
              f"{'MB':>6} {'p50 ms':>7} {'p99 ms':>7} {'rec sh':>7} {'rec col':>7}")
        for m in args.sizes:
            gen = Generator(real, m)
            qs = queries(gen, args.queries)
            compare(gen, m, qs, k=args.k, factors=args.factors, ef=args.ef, ef_add=args.ef_add,
                    libs=[make[n]() for n in args.libs])
        return
    print(f"{'models':>8} {'fill s':>7} {'exact load s':>12} {'exact MB':>8} {'p50':>6} "
          f"{'p99':>6} | {'build s':>7} {'build MB':>8} {'disk MB':>7} {'open ms':>7} "
          f"{'open MB':>7} {'p50':>6} {'p99':>6} {'rec sh':>6} {'rec col':>7}")
    with (tempfile.TemporaryDirectory() if args.tmp is None
          else contextlib.nullcontext(args.tmp)) as tmp:
        for m in args.sizes:
            gen = Generator(real, m)
            qs = queries(gen, args.queries)
            r = end_to_end(gen, m, qs, k=args.k, tmp=tmp)
            print(f"{m:>8} {r['fill']:>7.1f} {r['load']:>12.2f} {r['mem_exact']:>8.0f} "
                  f"{r['exact50']:>6.2f} {r['exact99']:>6.2f} | {r['build']:>7.1f} "
                  f"{r['mem_build']:>8.0f} {r['size']:>7.0f} {r['open'] * 1e3:>7.1f} "
                  f"{r['mem_open']:>7.0f} {r['ann50']:>6.2f} {r['ann99']:>6.2f} "
                  f"{r['rec_shape']:>6.3f} {r['rec_color']:>7.3f}", flush=True)


if __name__ == "__main__":
    main()
