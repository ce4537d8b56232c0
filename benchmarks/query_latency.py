"""Query-by-example latency and recall of surfidx.db.search at 10k / 100k / 1M stored models: the
exact scan beside the approximate index (surfidx.db.ann), and the candidate libraries side by side.

Rows
----
Built from real descriptors: ``--real-npz`` folders of per-model grids cached by
``benchmarks/retrieval.py`` (``/tmp/surfidx_retrieval_cache/<key>/*.npz``, the retrieval
collection; their descriptors are computed with :func:`surfidx.describe.descriptors.describe_grid` and
cached in ``/tmp/surfidx_query_latency_desc``)
and/or ``--real-db`` databases of ingested models. Every stored kind is generated (``shape``,
``spectrum``, ``layers``, ``texture``), searched by :data:`surfidx.describe.distance.DEFAULT_KINDS`. They are
perturbed so that neighbourhoods look like real ones (:class:`Generator`): every row belongs to a
sub-class whose centre mixes two real models of one class (classes from ``labels.csv`` of the
retrieval collection; the mixing weight drawn towards the first) plus noise along the real models'
principal directions (15 % of their spread), and every row is its centre plus 5 % of that spread
(plus a 1 % isotropic floor). 70 % of the rows are coloured, their texture vectors built the same
way from the real coloured models (made up when there are none). Queries are fresh rows of the
same generator (new scans of stored sub-classes), half of them without colour.

Modes
-----
* default: fills a surfidx database per size by bulk SQL (then ``Database.descriptors_changed``)
  and measures, in one run, ``SearchIndex(db, exact=True)`` (the exact scan), the index build
  (:func:`surfidx.db.ann.build`, faiss IVF lists: CPU time, resident memory, size on disk), opening it
  (:func:`surfidx.db.ann.open_index`, memory-mapped) and top-10 queries through
  :meth:`surfidx.db.ann.AnnIndex.query` (candidates re-ranked on the row copies) for several
  candidate factors, and through ``SearchIndex(db)`` as it stands (``search`` column); p50/p99
  CPU time of a top-10 query and recall@10 against the exact scan, for shape-only and coloured
  queries.
* ``--filtered``: ``Database.query(where="surfels <= N")`` with filters passing 100, 50, 5 and
  0.1 % of the models (the surfel counts are a fixed permutation of 1..m): the path from the
  threshold on (the index skipping the models that fail, :meth:`surfidx.db.ann.AnnIndex.query`
  with ``allowed``) against the exact top-10 of the passing models, and the exact ranking read
  by id from SQLite (``exact=True``, the path before) on ``--before-queries`` of them; CPU time
  per query (median, p90) and the filter's SQL alone. The databases are kept in ``--tmp`` and
  reused. ``--markdown`` writes ``docs/benchmarks/query_latency_filtered.md``.
* ``--compare``: the same rows in memory, hnswlib, faiss-cpu and usearch HNSW indexes (one
  thread, connectivity 16) and surfidx.db.ann's faiss IVF index of the shape vector, each with the
  exact re-rank of ``factor * k`` candidates.

Times are ``time.process_time`` (CPU of this process, one thread), so that a shared machine's
load changes them little. Run: ``python benchmarks/query_latency.py --real-npz
/tmp/surfidx_retrieval_cache/* [--real-db real.db] [--sizes 10000 100000 1000000]
[--compare]``.
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import gc
import json
import os
import tempfile
import time
from pathlib import Path

from surfidx.numerics import use_portable_profile  # noqa: E402

use_portable_profile()   # before numpy loads: the bytes the surfidx command makes
import numpy as np

from surfidx.database import Database
from surfidx.db.catalog import utc_now
from surfidx.db.search import SearchIndex  # noqa: E402
from surfidx.describe.distance import (DEFAULT_KINDS, DEFAULT_SHAPE_WEIGHT,
                                       combine_distances, weighted_l2)

from _markdown import Report, add_markdown_option

#: What this script prints, kept for its documentation page (``--markdown``).
REPORT = Report('query_latency', 'Query latency and recall at scale', None,
                note=("Rows built from real descriptors, perturbed, at each size: the exact scan beside the approximate index (faiss IVF lists, re-ranked exactly): query CPU time p50/p99, recall@10 for shape-only and coloured queries, the index's build time, memory and size on disk."))

LABELS = Path(__file__).resolve().parents[2] / "shared" / "data" / "retrieval" / "labels.csv"
COLOUR = "texture"


def rss_mb() -> float:
    """Resident memory of this process, MB."""
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    return float("nan")  # pragma: no cover


def _labels() -> dict:
    if not LABELS.exists():
        return {}
    with open(LABELS) as f:
        return {Path(r["path"]).stem: r["class"] for r in csv.DictReader(f)}


def _described(npz: Path, cache: Path):
    """describe_grid vectors of one cached grid (themselves cached per descriptors.py)."""
    import hashlib

    import surfidx.describe.descriptors as sd

    key = hashlib.sha256(Path(sd.__file__).read_bytes()).hexdigest()[:12]
    out = cache / f"{npz.stem}-{key}.npz"
    if out.exists():
        with np.load(out, allow_pickle=False) as z:
            return str(z["name"]), {k: z[k] for k in z.files if k != "name"}
    with np.load(npz, allow_pickle=False) as z:
        meta = json.loads(str(z["meta"]))
        if "grid" not in z.files or meta.get("error"):
            return None
        grid = z["grid"]
    vec = {k: np.asarray(v, np.float64) for k, v in sd.describe_grid(grid, meta["level"]
                                                                      ).vectors.items()}
    name = Path(meta["path"]).stem
    cache.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(out.name + f".{os.getpid()}.tmp.npz")
    np.savez(tmp, name=np.array(name), **vec)
    os.replace(tmp, out)
    return name, vec


def real_descriptors(dbs=(), npz_dirs=(), cache=Path("/tmp/surfidx_query_latency_desc")) -> dict:
    """Real descriptors: ``names`` (n,), ``classes`` (n,), ``vectors`` list of dicts kind ->
    (d,) float64 without texture, ``textures`` (c, d) of the coloured models. Models whose
    kinds have other dimensions than the first one's (older descriptor versions) are left out
    of ``vectors``; their textures are kept when of the first texture's dimension."""
    labels = _labels()
    names, vectors, textures = [], [], []
    seen = set()
    for folder in npz_dirs:
        for f in sorted(Path(folder).glob("*.npz")):
            if "-copy" in f.name or f.name.endswith(".tmp.npz") or f.stem in seen:
                continue
            got = _described(f, cache)
            if got is None:
                continue
            seen.add(f.stem)
            names.append(got[0])
            vectors.append(got[1])
    for path in dbs:
        with Database(path, readonly=True) as db:
            for r in db.list_models():
                vec = {k: np.asarray(v, np.float64)
                       for k, v in db.get_descriptors(r["id"]).items()}
                names.append(r["name"])
                vectors.append(vec)
                if not r["has_color"]:
                    vec.pop(COLOUR, None)
    for v in vectors:
        if COLOUR in v:
            textures.append(v.pop(COLOUR))
    dims = {k: x.size for k, x in vectors[0].items()} if vectors else {}
    keep = [i for i, v in enumerate(vectors)
            if set(v) == set(dims) and all(v[k].size == dims[k] for k in dims)]
    textures = [t for t in textures if t.size == textures[0].size]
    names = [names[i] for i in keep]
    vectors = [vectors[i] for i in keep]
    classes = np.array([labels.get(n, n) for n in names])
    if textures:
        dims[COLOUR] = textures[0].size
    return {"names": names, "classes": classes, "vectors": vectors, "dims": dims,
            "textures": np.array(textures)}


class Generator:
    """Rows around real descriptors (see the module notes), deterministic for a seed.

    The kinds but texture are generated side by side (a model's missing kind as zeros), texture
    apart from the real coloured models.
    """

    def __init__(self, real: dict, m: int, seed: int = 0):
        rng = np.random.default_rng(seed)
        self.rng = rng
        self.geo_kinds = [k for k in real["dims"] if k != COLOUR]
        self.dims = real["dims"]
        s = np.array([np.concatenate([v.get(k, np.zeros(self.dims[k])) for k in self.geo_kinds])
                      for v in real["vectors"]])
        self.basis, self.spread = self._pca(s)
        self.iso = 0.01 * float(s.std())
        n_sub = max(m // 20, len(s))
        base = rng.integers(len(s), size=n_sub)
        same = [np.flatnonzero(real["classes"] == c) for c in real["classes"]]
        other = np.array([rng.choice(same[b]) for b in base])
        lam = rng.beta(1.0, 3.0, n_sub)[:, None]
        self.centres = ((1 - lam) * s[base] + lam * s[other]
                        + self._noise(n_sub, 0.15, self.basis, self.spread))
        t = real["textures"]
        if len(t) == 0:                             # no coloured model: made-up ones
            t = np.abs(rng.standard_normal((2, self.dims.get(COLOUR, 78))))
        self.tdim = t.shape[1]
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
        """``kinds`` dict kind -> (n, d_kind) float32 (texture for every row), ``color`` (n,)
        bool."""
        rng = self.rng
        sub = rng.integers(len(self.centres), size=n)
        geo = (self.centres[sub] + self._noise(n, 0.05, self.basis, self.spread)
               + self.iso * rng.standard_normal((n, self.centres.shape[1])))
        texture = (self.tcentres[sub] + self._noise(n, 0.1, self.tbasis, self.tspread)
                   + self.tiso * rng.standard_normal((n, self.tcentres.shape[1])))
        out, at = {}, 0
        for k in self.geo_kinds:
            out[k] = np.ascontiguousarray(geo[:, at:at + self.dims[k]], np.float32)
            at += self.dims[k]
        out[COLOUR] = texture.astype(np.float32)
        return out, rng.random(n) < color_fraction


def surfel_counts(m: int) -> np.ndarray:
    """The stored surfel count of models 1..m: a fixed permutation of 1..m, unrelated to the
    descriptors, so that the filter ``surfels <= p * m`` passes exactly that share."""
    return np.random.default_rng(11).permutation(m) + 1


def fill(db: Database, kinds: dict, color) -> None:
    """Bulk-insert rows (every kind of ``kinds``; texture where coloured) as models 1..m, with
    the surfel counts of :func:`surfel_counts`."""
    m = len(color)
    now = utc_now()
    conv = "{}"
    surfels = surfel_counts(m).tolist()
    with db.transaction():
        db.conn.executemany(
            "INSERT INTO models (id, name, source, content_hash, n_surfels, has_color, bbox_min_x,"
            " bbox_min_y, bbox_min_z, bbox_max_x, bbox_max_y, bbox_max_z, ingested_at, params)"
            " VALUES (?, ?, ?, ?, ?, ?, 0, 0, 0, 1, 1, 1, ?, '{}')",
            ((i + 1, f"m{i}", f"/synthetic/m{i}.ply", f"{i:064x}", surfels[i], int(color[i]),
              now) for i in range(m)))
        db.conn.executemany("INSERT INTO thumbnails (model_id, png) VALUES (?, ?)",
                            ((i + 1, b"") for i in range(m)))
        ins = ("INSERT INTO descriptors (model_id, kind, dimension, vector, convention) "
               "VALUES (?, ?, ?, ?, ?)")
        for kind, mat in kinds.items():
            mat = mat.astype("<f4")
            db.conn.executemany(ins, ((i + 1, kind, mat.shape[1], mat[i].tobytes(), conv)
                                      for i in range(m) if kind != COLOUR or color[i]))
        db.descriptors_changed()


def queries(gen: Generator, n: int):
    """Query descriptor dicts: the first half coloured, the second shape-only."""
    kinds, _ = gen.rows(n, color_fraction=1.0)
    out = []
    for i in range(n):
        q = {k: v[i] for k, v in kinds.items() if k != COLOUR}
        if i < n // 2:
            q[COLOUR] = kinds[COLOUR][i]
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


class _FaissIvf:
    """surfidx.db.ann's index (faiss IVF, 8-bit codes, its list count and seed) in memory,
    searched with ``surfidx.db.ann.DEFAULT_PROBES`` lists (``--ef`` is an HNSW setting)."""
    name = "faiss-ivf-sq8"

    def build(self, x, ef_add):
        from surfidx.db import ann
        self.ix = ann._new_graph(np.arange(len(x), dtype=np.int64), np.ascontiguousarray(x))

    def save(self, path):
        import faiss
        faiss.write_index(self.ix, str(path))

    def search(self, v, n, ef):
        from surfidx.db import ann
        self.ix.nprobe = ann.DEFAULT_PROBES
        return self.ix.search(np.ascontiguousarray(v, np.float32)[None], n)[1][0].astype(
            np.int64)


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
    kinds, color = gen.rows(m)
    stored = {kd: kinds[kd] for kd in DEFAULT_KINDS if kd in kinds}
    present = {kd: (color if kd == COLOUR else np.ones(m, bool)) for kd in stored}
    shape = np.hstack([stored[kd] for kd in DEFAULT_KINDS if kd in stored and kd != COLOUR])
    truth = [exact_topk(q, stored, present, k) for q in qs]
    t_exact = []
    for q in qs[:20]:
        t0 = time.process_time()
        exact_topk(q, stored, present, k)
        t_exact.append(time.process_time() - t0)
    REPORT.print(f"{m:>8} {'exact scan':>14} {'':>7} {'':>7} {'':>7} {'':>6} "
          f"{pct(t_exact, 50):>7.2f} {pct(t_exact, 99):>7.2f} {1.0:>7.3f} {1.0:>7.3f}",
          flush=True)
    for lib in libs:
        gc.collect()
        r0 = rss_mb()
        t0 = time.process_time()
        try:
            lib.build(shape, ef_add)
        except ImportError as exc:
            REPORT.print(f"{m:>8} {lib.name:>14} not installed ({exc})")
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
                cand = lib.search(q_vec(q), n, ef)       # the shape graph alone
                got = rerank(q, stored, present, cand, k)
                times.append(time.process_time() - t0)
                rec[COLOUR in q].append(len(t & set(got.tolist())) / k)
            REPORT.print(f"{m:>8} {lib.name:>14} {f:>7} {t_build:>7.1f} {mem:>7.0f} {size:>6.0f} "
                  f"{pct(times, 50):>7.2f} {pct(times, 99):>7.2f} {np.mean(rec[False]):>7.3f} "
                  f"{np.mean(rec[True]):>7.3f}", flush=True)
        del lib.ix


def q_vec(q):
    """The shape-graph vector of a query: the search's kinds but texture side by side."""
    return np.concatenate([q[kd] for kd in DEFAULT_KINDS if kd != COLOUR and kd in q]
                          ).astype(np.float32)


# ---------------------------------------------------------------------- surfidx end to end
def recall_and_times(fn, qs, truth):
    times, rec = [], {True: [], False: []}
    for q, t in zip(qs, truth):
        t0 = time.process_time()
        ids = fn(q)
        times.append(time.process_time() - t0)
        rec[COLOUR in q].append(len(t & set(ids.tolist())) / len(t))
    return {"p50": pct(times, 50), "p99": pct(times, 99), "rec_shape": float(np.mean(rec[False])),
            "rec_color": float(np.mean(rec[True]))}


def cli_times(path, ids, *, k):
    """``surfidx query id:N`` in fresh processes (interpreter start, imports, opening SQLite and
    the index, the search, the table): wall seconds and the child's CPU seconds (user + sys)
    per call. The first call is left out (it may page the index files in, and it writes the
    bytecode: the children keep it in a folder of their own, as an installed package has its
    bytecode, even where ``PYTHONDONTWRITEBYTECODE`` is set)."""
    import resource
    import subprocess
    import sys

    env = dict(os.environ, PYTHONPYCACHEPREFIX=str(Path(path).parent / "pycache"))
    env.pop("PYTHONDONTWRITEBYTECODE", None)
    wall, cpu = [], []
    for j, i in enumerate([ids[0], *ids]):
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        t0 = time.perf_counter()
        done = subprocess.run([sys.executable, "-m", "surfidx", "query", f"id:{int(i)}",
                               "--db", str(path), "-k", str(k)], stdout=subprocess.DEVNULL,
                              stderr=subprocess.PIPE, text=True, env=env)
        if done.returncode:
            REPORT.print(f"surfidx query id:{int(i)} failed: {done.stderr.strip()}", flush=True)
            return {"wall50": float("nan"), "cpu50": float("nan"), "cpu_max": float("nan")}
        t1 = time.perf_counter()
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
        if j:
            wall.append(t1 - t0)
            cpu.append(after.ru_utime - before.ru_utime + after.ru_stime - before.ru_stime)
    return {"wall50": float(np.median(wall)), "cpu50": float(np.median(cpu)),
            "cpu_max": float(np.max(cpu))}


def changes(gen, path, *, k, n_changed, n_queries):
    """Remove ``n_changed`` models and redescribe as many (new rows of other sub-classes), then
    compare queries through the index (which the writer's close brings up to date) with the
    exact scan: the removed models' old descriptors and the redescribed models' new ones as
    queries, shape-only and coloured."""
    from surfidx.db import ann

    rng = np.random.default_rng(7)
    with Database(path, readonly=True) as db:
        m = db.count()
    picked = rng.choice(np.arange(1, m + 1), 2 * n_changed, replace=False)
    gone, redo = picked[:n_changed], picked[n_changed:]
    new, _ = gen.rows(n_changed, color_fraction=1.0)
    with Database(path) as db:
        old_q = [{kd: v for kd, v in db.get_descriptors(int(i)).items() if kd in DEFAULT_KINDS}
                 for i in gone[:n_queries]]
        color = db.color_mask(redo)
        db.remove(*[int(i) for i in gone])
        for j, i in enumerate(redo):
            vec = {kd: new[kd][j] for kd in new if kd != COLOUR or color[j]}
            db.set_descriptors(int(i), vec, {})
        t0 = time.process_time()
        db.close()                                  # ann.update: the index catches up
        t_update = time.process_time() - t0
    redo_q = [{kd: new[kd][j] for kd in DEFAULT_KINDS if kd in new and (kd != COLOUR or color[j])}
              for j in range(min(n_queries, n_changed))]
    out = {"update": t_update, "same": 0, "queries": 0, "removed_found": 0, "max_dist_diff": 0.0,
           "self_first": 0}
    with Database(path, readonly=True) as db:
        approx = SearchIndex(db, threshold=0)
        assert approx.approximate
        exact = SearchIndex(db, exact=True)
        removed = set(gone.tolist())
        for j, q in enumerate(old_q + redo_q):
            for qq in (q, {kd: v for kd, v in q.items() if kd != COLOUR}):
                a_ids, a_d = approx.query(qq, k=k)
                e_ids, e_d = exact.query(qq, k=k)
                out["queries"] += 1
                out["same"] += int(np.array_equal(a_ids, e_ids))
                out["removed_found"] += len(removed & set(a_ids.tolist()))
                # every distance returned is the exact one of the rows stored now
                pos = np.searchsorted(exact.ids, a_ids)
                ex = weighted_l2({kd: np.asarray(v, np.float32) for kd, v in qq.items()},
                                 {kd: s[pos] for kd, s in exact.stored.items()},
                                 {kd: p[pos] for kd, p in exact.present.items()},
                                 shape_weight=DEFAULT_SHAPE_WEIGHT)
                out["max_dist_diff"] = max(out["max_dist_diff"],
                                           float(np.max(np.abs(ex - a_d), initial=0.0)))
                if j >= len(old_q):
                    out["self_first"] += int(a_ids.size > 0 and a_ids[0] == redo[j - len(old_q)])
        state_ok = ann.open_index(db, kinds=DEFAULT_KINDS).state == db.index_state()
    out["state_ok"] = state_ok
    out["n_redo_queries"] = 2 * len(redo_q)
    return out


def prepared(gen, m, tmp) -> Path:
    """``tmp/filtered{m}.db`` with ``m`` generated rows and its index, made when missing (or
    left by an unfinished run: no index manifest); kept for the next run."""
    from surfidx.db import ann

    path = Path(tmp) / f"filtered{m}.db"
    manifest = ann.index_dir(path) / "manifest.json"
    busy = Path(f"{path}.building")                 # another run is making it: wait for it
    while busy.exists() and not manifest.exists():
        time.sleep(10)
    if path.exists() and manifest.exists():
        return path
    busy.touch()
    for old in (path, Path(f"{path}-wal"), Path(f"{path}-shm")):
        old.unlink(missing_ok=True)
    kinds, color = gen.rows(m)
    with Database(path) as db:
        fill(db, kinds, color)
        db._index_dirty = False                     # built below, in its own process step
    del kinds, color
    gc.collect()
    with Database(path, readonly=True) as db:
        ann.build(db, kinds=DEFAULT_KINDS)
    busy.unlink()
    return path


#: Shares of the models a filter passes in the ``--filtered`` run (1.0: no filter).
FILTER_SHARES = (1.0, 0.5, 0.05, 0.001)


def _timed(db, examples, truth, *, k, where, exact):
    """CPU ms per ``Database.query`` (median, p90, mean, worst) and recall@k against
    ``truth``."""
    times, rec = [], []
    for ex, t in zip(examples, truth):
        t0 = time.process_time()
        got = db.query(ex, k=k, where=where, exact=exact)
        times.append(time.process_time() - t0)
        rec.append(len(t & {r["id"] for r in got}) / len(t))
    return {"p50": pct(times, 50), "p90": pct(times, 90), "mean": float(np.mean(times) * 1e3),
            "max": pct(times, 100), "recall": float(np.mean(rec)),
            "min_recall": float(np.min(rec)), "n": len(times)}


class _Truth:
    """The exact filtered top-k on the index's row copies (the rows as stored): the distance
    screened for every model by the expansion of the square, then the exact
    :func:`weighted_l2` on the ``max(4k, k + 64)`` best passing models (as the exact scan of
    :class:`SearchIndex` ranks), without reading the database's blobs again."""

    def __init__(self, index, m):
        self.ids, self.stored, self.present = index.rows(np.arange(1, m + 1, dtype=np.int64))
        self.norms = {kd: np.einsum("ij,ij->i", s, s, dtype=np.float64)
                      for kd, s in self.stored.items()}

    def screen(self, q):
        def sq(kd):
            v = np.asarray(q[kd], np.float32)
            return self.norms[kd] - 2.0 * (self.stored[kd] @ v) + float(v @ v)

        s = sq("shape")
        if "spectrum" in q:
            s = s + np.where(self.present["spectrum"], sq("spectrum"), 0.0)
        dt = np.sqrt(np.maximum(sq(COLOUR), 0.0)) if COLOUR in q else None
        return combine_distances(np.sqrt(np.maximum(s, 0.0)), dt, self.present.get(COLOUR),
                                 DEFAULT_SHAPE_WEIGHT)

    def top(self, q, d, mask, k):
        d = d if mask is None else np.where(mask, d, np.inf)
        nc = min(d.size, max(4 * k, k + 64))
        cand = np.argpartition(d, nc - 1)[:nc]
        cand = cand[np.isfinite(d[cand])]
        qq = {kd: np.asarray(v, np.float32) for kd, v in q.items()}
        ex = weighted_l2(qq, {kd: s[cand] for kd, s in self.stored.items()},
                         {kd: p[cand] for kd, p in self.present.items()},
                         shape_weight=DEFAULT_SHAPE_WEIGHT)
        return set(self.ids[cand[np.lexsort((self.ids[cand], ex))[:k]]].tolist())


def filtered(gen, m, qs, *, k, tmp, before_queries):
    """Filtered queries (``surfels <= share * m``) at ``m`` models: ``Database.query`` with
    ``where=`` on the index path beside the exact filtered ranking read by id from SQLite
    (``exact=True``, the path before the index took filters); recall@10 against the exact
    top-10 of the passing models (:class:`_Truth`); CPU ms per query (the filter's SQL
    included) and of the filter's SQL alone."""
    from surfidx.database import QueryExample
    from surfidx.db import ann

    path = prepared(gen, m, tmp)
    out = {}
    with Database(path, readonly=True) as db:
        truth_of = _Truth(ann.open_index(db, kinds=DEFAULT_KINDS), m)
        surfels = surfel_counts(m)[truth_of.ids - 1]
        screened = [truth_of.screen(q) for q in qs]
        examples = [QueryExample(id=None, name=f"q{j}", has_color=COLOUR in q, descriptors=q)
                    for j, q in enumerate(qs)]
        for share in FILTER_SHARES:
            limit = int(round(share * m))
            where = None if share >= 1.0 else f"surfels <= {limit}"
            mask = None if where is None else surfels <= limit
            truth = [truth_of.top(q, d, mask, k) for q, d in zip(qs, screened)]
            db.query(examples[0], k=k, where=where)       # opens the index (kept)
            after = _timed(db, examples, truth, k=k, where=where, exact=False)
            step = max(len(qs) // max(before_queries, 1), 1)
            before = (_timed(db, examples[::step][:before_queries],
                             truth[::step][:before_queries], k=k, where=where, exact=True)
                      if before_queries and where else None)
            sql = []
            for _ in range(5 if where else 0):
                t0 = time.process_time()
                db.select_ids(where=where)
                sql.append(time.process_time() - t0)
            out[share] = {"passing": m if mask is None else int(mask.sum()), "where": where,
                          "after": after, "before": before,
                          "sql": pct(sql, 50) if sql else float("nan")}
        del truth_of, screened
    return out


def end_to_end(gen, m, qs, *, k, tmp, factors, probes=(None,)):
    from surfidx.db import ann

    path = Path(tmp) / f"bench{m}.db"
    kinds, color = gen.rows(m)
    with Database(path) as db:
        t0 = time.perf_counter()
        fill(db, kinds, color)
        t_fill = time.perf_counter() - t0
        # the index is built below, timed: not by the writer's close (ann.update builds it
        # from the threshold on, which doubled the 1M run)
        db._index_dirty = False
    del kinds, color
    gc.collect()
    out = {"fill": t_fill, "db_mb": path.stat().st_size / 2 ** 20}
    with Database(path, readonly=True) as db:
        r0 = rss_mb()
        t0 = time.process_time()
        exact = SearchIndex(db, exact=True)
        out["load"] = time.process_time() - t0
        out["mem_exact"] = rss_mb() - r0
        truth, t_exact = [], []
        for q in qs:
            t0 = time.process_time()
            ids, _ = exact.query(q, k=k)
            t_exact.append(time.process_time() - t0)
            truth.append(set(ids.tolist()))
        out["exact50"], out["exact99"] = pct(t_exact, 50), pct(t_exact, 99)
        del exact
        db._cache.clear()                           # the exact scan's matrices
        gc.collect()
        r0 = rss_mb()
        t0 = time.process_time()
        built = ann.build(db, kinds=DEFAULT_KINDS)  # writes the index beside the database
        out["build"] = time.process_time() - t0
        out["mem_build"] = rss_mb() - r0
        del built
        db._cache.clear()
        gc.collect()
        out["size"] = ann.index_size(path) / 2 ** 20
        r0 = rss_mb()
        t0 = time.process_time()
        index = ann.open_index(db, kinds=DEFAULT_KINDS)       # memory-maps the files
        out["open"] = time.process_time() - t0
        out["runs"] = {}
        for e in probes:
            pr = ann.DEFAULT_PROBES if e is None else e
            for f in factors:
                out["runs"][f"f{f}/p{pr}"] = recall_and_times(
                    lambda q: index.query(q, distance=weighted_l2, k=k,
                                          shape_weight=DEFAULT_SHAPE_WEIGHT, factor=f,
                                          probes=pr)[0], qs, truth)
        out["mem_open"] = rss_mb() - r0
        approx = SearchIndex(db, threshold=0)
        assert approx.approximate
        out["search"] = recall_and_times(lambda q: approx.query(q, k=k)[0], qs, truth)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--real-npz", nargs="*", default=[],
                    help="Folders of grids cached by benchmarks/retrieval.py.")
    ap.add_argument("--real-db", nargs="*", default=[], help="Databases of real ingested models.")
    ap.add_argument("--sizes", type=int, nargs="+", default=[10_000, 100_000, 1_000_000])
    ap.add_argument("--queries", type=int, default=200)
    ap.add_argument("-k", type=int, default=10)
    ap.add_argument("--compare", action="store_true",
                    help="Compare hnswlib, faiss-cpu and usearch in memory instead.")
    ap.add_argument("--libs", nargs="+", default=["hnswlib", "faiss", "usearch-f32",
                                                  "usearch-f16", "faiss-ivf"])
    ap.add_argument("--factors", type=int, nargs="+", default=[2, 4, 8])
    ap.add_argument("--ef", type=int, default=64, help="Search expansion (compare mode).")
    ap.add_argument("--probes", type=int, nargs="+", default=None,
                    help="Lists probed in the AnnIndex.query rows (default: "
                         "surfidx.db.ann.DEFAULT_PROBES).")
    ap.add_argument("--cli", type=int, default=0,
                    help="Also time this many `surfidx query id:N` processes per size (from "
                         "the threshold on).")
    ap.add_argument("--changes", type=int, default=0,
                    help="Then remove and redescribe this many models of the largest size and "
                         "compare index queries with the exact scan.")
    ap.add_argument("--ef-add", type=int, default=128, help="Build expansion (compare mode).")
    ap.add_argument("--filtered", action="store_true",
                    help="Filtered queries instead: Database.query(where=) passing 100/50/5/0.1 "
                         "%% of the models, the index path beside the exact path read by id.")
    ap.add_argument("--before-queries", type=int, default=10,
                    help="Queries timed on the exact filtered path (--filtered; slow at 1M).")
    ap.add_argument("--tmp", default=None,
                    help="Folder for the databases, kept afterwards (default: a temp, removed).")
    add_markdown_option(ap, 'query_latency')
    args = ap.parse_args()
    REPORT.output = args.markdown
    if not args.real_npz and not args.real_db:
        ap.error("give --real-npz and/or --real-db")
    real = real_descriptors(args.real_db, args.real_npz)
    n_col = len(real["textures"])
    REPORT.print(f"real descriptors: {len(real['vectors'])} models ({len(set(real['classes']))} "
          f"classes), {n_col} coloured, kinds {real['dims']}; search kinds {DEFAULT_KINDS}; "
          f"{args.queries} queries (half coloured), k = {args.k}, w = {DEFAULT_SHAPE_WEIGHT}; "
          f"load {os.getloadavg()[0]:.1f}", flush=True)
    if args.filtered:
        from surfidx.db import ann

        REPORT.name, REPORT.title = "query_latency_filtered", "Filtered query latency and recall"
        REPORT.note = ("Database.query with a filter (--where) at 100,000 and 1,000,000 "
                       "models, rows built from real descriptors and perturbed as on the "
                       "query latency page: the path through the index beside the exact "
                       "ranking of the passing models read by id.")
        if args.markdown is not None and args.markdown.name == "query_latency.md":
            REPORT.output = args.markdown.with_name("query_latency_filtered.md")

        REPORT.print("CPU ms per Database.query(k=%d, where='surfels <= N'), the filter's SQL "
                     "included; recall@%d against the exact top-%d of the passing models "
                     "(mean, and the worst query); 'index' = the path from the threshold on "
                     "(the index skipping the other models, or all passing ranked exactly up "
                     "to %d), 'SQL' = the filter's share (Catalog.select_ids, p50), 'by id' = "
                     "the exact ranking of every passing model read from SQLite (exact=True, "
                     "the path before)" % (args.k, args.k, args.k, ann.FILTER_SCAN_LIMIT),
                     flush=True)
        REPORT.print(f"{'models':>8} {'passing':>8} {'index p50':>9} {'p90':>7} {'mean':>7} "
                     f"{'max':>7} {'recall':>7} {'min':>5} {'SQL':>6} | {'by id p50':>9} "
                     f"{'p90':>8} {'n':>3}")
        with (tempfile.TemporaryDirectory() if args.tmp is None
              else contextlib.nullcontext(args.tmp)) as tmp:
            for m in args.sizes:
                gen = Generator(real, m)
                qs = queries(gen, args.queries)
                for share, r in filtered(gen, m, qs, k=args.k, tmp=tmp,
                                         before_queries=args.before_queries).items():
                    a, b = r["after"], r["before"]
                    tail = (f"{b['p50']:>9.1f} {b['p90']:>8.1f} {b['n']:>3}" if b else
                            f"{'(unfiltered)':>22}")
                    REPORT.print(f"{m:>8} {share:>7.1%} {a['p50']:>9.2f} {a['p90']:>7.2f} "
                                 f"{a['mean']:>7.2f} {a['max']:>7.2f} {a['recall']:>7.3f} {a['min_recall']:>5.1f} "
                                 f"{r['sql']:>6.1f} | {tail}",
                                 flush=True)
        return
    if args.compare:
        make = {"hnswlib": _Hnswlib, "faiss": _Faiss, "faiss-ivf": _FaissIvf,
                "usearch-f32": lambda: _Usearch("f32"),
                "usearch-f16": lambda: _Usearch("f16"), "usearch-i8": lambda: _Usearch("i8")}
        REPORT.print(f"HNSW M=16, ef_construction {args.ef_add}, ef_search max({args.ef}, candidates); "
              "CPU ms per query incl. exact re-rank in memory")
        REPORT.print(f"{'models':>8} {'library':>14} {'factor':>7} {'build s':>7} {'mem MB':>7} "
              f"{'MB':>6} {'p50 ms':>7} {'p99 ms':>7} {'rec sh':>7} {'rec col':>7}")
        for m in args.sizes:
            gen = Generator(real, m)
            qs = queries(gen, args.queries)
            compare(gen, m, qs, k=args.k, factors=args.factors, ef=args.ef, ef_add=args.ef_add,
                    libs=[make[n]() for n in args.libs])
        return
    REPORT.print("CPU times (process_time); memory = resident-set growth; 'search' = SearchIndex as "
          "it stands (surfidx.db.ann defaults), 'fN/pP' = AnnIndex.query with N*k candidates "
          "per index (P lists probed) re-ranked on the row copies", flush=True)
    REPORT.print(f"{'models':>8} {'db MB':>6} {'exact p50':>9} {'p99':>6} {'MB':>5} | {'build s':>7} "
          f"{'MB':>5} {'disk MB':>7} {'open ms':>7} {'MB':>5} | {'path':>9} {'p50':>6} "
          f"{'p99':>6} {'rec sh':>6} {'rec col':>7}")
    with (tempfile.TemporaryDirectory() if args.tmp is None
          else contextlib.nullcontext(args.tmp)) as tmp:
        for m in args.sizes:
            gen = Generator(real, m)
            qs = queries(gen, args.queries)
            r = end_to_end(gen, m, qs, k=args.k, tmp=tmp, factors=args.factors,
                           probes=args.probes or (None,))
            head = (f"{m:>8} {r['db_mb']:>6.0f} {r['exact50']:>9.2f} {r['exact99']:>6.2f} "
                    f"{r['mem_exact']:>5.0f} | {r['build']:>7.1f} {r['mem_build']:>5.0f} "
                    f"{r['size']:>7.0f} {r['open'] * 1e3:>7.1f} {r['mem_open']:>5.0f} |")
            lines = list(r["runs"].items()) + [("search", r["search"])]
            for j, (name, x) in enumerate(lines):
                REPORT.print(f"{head if j == 0 else ' ' * len(head)} {name:>9} {x['p50']:>6.2f} "
                      f"{x['p99']:>6.2f} {x['rec_shape']:>6.3f} {x['rec_color']:>7.3f}",
                      flush=True)
            path = Path(tmp) / f"bench{m}.db"
            from surfidx.db import ann
            if args.cli and m >= ann.DEFAULT_THRESHOLD:
                ids = np.random.default_rng(3).choice(np.arange(1, m + 1), args.cli,
                                                      replace=False)
                c = cli_times(path, ids, k=args.k)
                REPORT.print(f"{m:>8} surfidx query id:N, {args.cli} processes: wall p50 "
                      f"{c['wall50']:.3f} s, CPU (user+sys) p50 {c['cpu50']:.3f} s, max "
                      f"{c['cpu_max']:.3f} s", flush=True)
        if args.changes:
            m = args.sizes[-1]
            gen = Generator(real, m, seed=1)
            c = changes(gen, Path(tmp) / f"bench{m}.db", k=args.k, n_changed=args.changes,
                        n_queries=min(args.changes, 50))
            REPORT.print(f"{m:>8} after removing {args.changes} and redescribing {args.changes} "
                  f"models: index update {c['update']:.1f} s CPU; {c['queries']} queries "
                  f"(removed models' old rows and redescribed models' new rows, each coloured "
                  f"and shape-only): {c['same']} equal to the exact scan, removed models "
                  f"returned {c['removed_found']}, largest distance difference "
                  f"{c['max_dist_diff']:.2g}, redescribed model first "
                  f"{c['self_first']}/{c['n_redo_queries']}, manifest current {c['state_ok']}",
                  flush=True)


if __name__ == "__main__":
    main()
    REPORT.finish()
