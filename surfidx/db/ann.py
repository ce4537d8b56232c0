"""The approximate nearest-neighbour index beside a database: candidates for the exact distance.

Above :data:`DEFAULT_THRESHOLD` stored models, :class:`surfidx.db.search.SearchIndex` does not scan
every stored vector. It asks inverted-file indexes (faiss ``IndexIVFScalarQuantizer``: the
vectors in :func:`list_count` k-means lists, stored as 8-bit codes; a query scans the
:data:`DEFAULT_PROBES` nearest lists) for candidates and ranks them by the exact distance.
Inverted files rather than HNSW graphs (hnswlib, usearch): they build several times faster for
the same recall, and a memory-mapped index opens at once (``benchmarks/query_latency.py
--compare`` prints the build time, size and recall of each):

* the ``"shape"`` index holds, per model with the first kind (``"shape"``), every kind of the
  search but ``"texture"`` side by side (for the default search, shape with the KLT spectrum
  appended; a kind a model lacks is zeros there);
* the ``"texture"`` graph holds the texture vectors of the coloured models.

A query takes the ``factor * k`` nearest models of the shape graph, for a coloured query also
the ``factor * k`` nearest of the texture graph, and ranks them by the exact distance (the
search's, e.g. :func:`surfidx.describe.distance.weighted_l2`) on float32 copies of their stored rows. The
index is generic over the descriptor kinds of the search: they are arguments, stored in the
manifest, and an index of other kinds is rebuilt.

Files
-----
``DB.ann/`` beside the database file ``DB``: ``manifest.json``; one ``TOKEN-GROUP.faiss`` per
index (as ``faiss.write_index`` writes it); per kind ``TOKEN-ids-KIND.npy`` (ids ascending,
int64) and ``TOKEN-rows-KIND.npy`` (the stored vectors, float32, exactly as in the database; for
``"texture"`` only the coloured models); ``TOKEN-digests.npz`` (a content digest per indexed
model). The manifest names the files, the library and settings, the kinds, dimensions and
conventions, and the database state the files reflect (:meth:`Database.index_state`: the
``descriptor_generation`` counter that :class:`~surfidx.db.catalog.Catalog` increments with every
change of a model or its descriptors, the schema version, the model count, the largest model id
and descriptor rowid). A new or updated index is written to new files first and then the
manifest is replaced (``os.replace``, atomic): a crash leaves the old manifest naming the old,
whole files.

Consistency
-----------
:func:`open_index` compares the manifest's state with the database's. Equal: the files are
memory-mapped as they are (no loading; a query touches only the pages it visits). Different (the
database was changed by a process that did not update the index, or the update did not finish):
the stored rows are read and compared by digest with the indexed ones; changed and new models are
added to the graphs, removed ones removed (a full rebuild when more than a quarter changed, or the
kinds, dimensions or conventions changed), the row copies rewritten, and the result is written
back (only the index files, never the database; in memory when the folder cannot be written).
Before each query, :meth:`AnnIndex.query` checks that the database is still in that state
(``PRAGMA data_version`` and the generation counter, microseconds; the whole state when either
moved) and catches up first when it is not, so the distances and the candidates are those of the
rows stored at query time. A writer that changed models through
:class:`~surfidx.db.catalog.Catalog` updates the index when it closes (:func:`update`).
Descriptors of one kind made with two conventions are refused as by
:meth:`Database.descriptor_matrix`.
"""

from __future__ import annotations

import functools
import json
import os
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..validate import as_array, check_positive_int

__all__ = ["AnnIndex", "open_index", "build", "update", "index_dir", "index_size",
           "list_count", "DEFAULT_THRESHOLD", "DEFAULT_FACTOR", "DEFAULT_PROBES", "BUILD_KINDS",
           "FILTER_SCAN_LIMIT", "FORMAT"]

#: Model count from which :class:`surfidx.db.search.SearchIndex` uses the index (the exact scan
#: below it): below it a scan is fast and exact by construction, and no writer pays for an
#: index (``benchmarks/query_latency.py`` prints both paths' latency).
DEFAULT_THRESHOLD = 20_000

#: Candidates per result: ``factor * k`` models per graph are ranked by the exact distance.
DEFAULT_FACTOR = 4

#: Lists a query scans in each index (``nprobe``; all of them when an index has fewer).
DEFAULT_PROBES = 32

#: Passing models up to which a filtered query (:meth:`AnnIndex.query` with ``allowed``) ranks
#: every one of them by the exact distance on the row copies instead of asking the index: an
#: exact result for about the cost of an index query (the scan's cost grows with the passing
#: models, the index's does not; ``benchmarks/query_latency.py --filtered`` prints the paths).
FILTER_SCAN_LIMIT = 1_000

#: Candidates of a filtered query asked of the index, as a multiple of the unfiltered ones: the
#: passing models near a query lie further out than the nearest of all, where the 8-bit codes
#: order them less surely; twice the candidates bring a filtered query's recall to the
#: unfiltered one's at about the same cost (``benchmarks/query_latency.py --filtered``).
_FILTER_WIDEN = 2

#: Manifest format version (an index of another format is rebuilt).
FORMAT = 3

#: k-means lists per stored vector: about ``4 sqrt(n)``, with at least 39 training vectors a
#: list (faiss's floor), so that a probed list holds about ``sqrt(n) / 4`` models.
_LISTS_PER_SQRT = 4
_MIN_PER_LIST = 39
_SEED = 1234
#: Share of changed models above which a stale index is rebuilt rather than patched.
_REBUILD_SHARE = 0.25
#: The kind compared only between coloured models (its graph and rows hold only those).
_COLOUR_KIND = "texture"
#: Kinds of an index made without a search naming its kinds (:func:`update` after an ingest
#: into a database without an index); a search of other kinds rebuilds it for its own.
BUILD_KINDS = ("shape", "spectrum", "texture")
#: Columns :func:`row_digest` takes at most.
_DIGEST_WIDTH = 1024


@functools.lru_cache(maxsize=1)
def _multipliers() -> np.ndarray:
    """Per-column odd multipliers of :func:`row_digest` (fixed: digests are stored; made on first
    use, so that a query, which never digests, does not import ``numpy.random``)."""
    return np.random.default_rng(0x5F5A).integers(1, 2 ** 63, size=_DIGEST_WIDTH,
                                                  dtype=np.uint64) | np.uint64(1)


def index_dir(db_path) -> Path:
    """The index folder of a database file: ``DB.ann`` beside it."""
    p = Path(db_path)
    return p.with_name(p.name + ".ann")


def index_files(man) -> list:
    """The files of an index that a manifest names.

    Parameters
    ----------
    man : dict
        The index manifest.

    Returns
    -------
    list of str
        The graph files, the row files (ids and rows) of each kind and the digests file, relative
        to the index folder.
    """
    out = [g["file"] for g in man.get("graphs", {}).values()]
    for r in man.get("rows", {}).values():
        out += [r["ids"], r["rows"]]
    if man.get("digests"):
        out.append(man["digests"])
    return out


def index_size(db_path) -> int:
    """Bytes of the index files the manifest names (0 without an index)."""
    d = index_dir(db_path)
    man = _read_manifest(d)
    if man is None:
        return 0
    return sum((d / f).stat().st_size for f in index_files(man) if (d / f).exists())


def list_count(n: int) -> int:
    """k-means lists of an index of ``n`` vectors: ``round(4 sqrt(n))``, at most ``n // 39``,
    at least 1."""
    n = max(int(n), 0)
    return max(1, min(int(round(_LISTS_PER_SQRT * n ** 0.5)), n // _MIN_PER_LIST))


def _faiss():
    import faiss

    return faiss


class _one_thread:
    """faiss on one OpenMP thread inside the block (the same rows give the same k-means lists,
    and a query's CPU time is its own); the process's setting is restored after it."""

    def __enter__(self):
        faiss = _faiss()
        self._before = faiss.omp_get_max_threads()
        faiss.omp_set_num_threads(1)
        return self

    def __exit__(self, *exc):
        _faiss().omp_set_num_threads(self._before)
        return False


def row_digest(*mats) -> np.ndarray:
    """A 64-bit digest per row of float32 matrices side by side (exact bytes, order-aware)."""
    words = np.hstack([np.ascontiguousarray(m, np.float32).view(np.uint32) for m in mats])
    if words.shape[1] > _DIGEST_WIDTH:
        raise InputError(f"rows of {words.shape[1]} values are too wide for the index digest "
                         f"(at most {_DIGEST_WIDTH})")
    mult = _multipliers()
    with np.errstate(over="ignore"):
        acc = np.zeros(words.shape[0], np.uint64)
        for j in range(words.shape[1]):          # column loop, vectorised over rows
            acc = (acc ^ words[:, j].astype(np.uint64)) * mult[j]
    return acc


def _read_manifest(d: Path):
    try:
        with open(d / "manifest.json", encoding="utf-8") as f:
            man = json.load(f)
    except (OSError, ValueError):
        return None
    if not isinstance(man, dict) or man.get("format") != FORMAT or "graphs" not in man:
        return None
    return man


def _check_kinds(kinds) -> tuple:
    kinds = (kinds,) if isinstance(kinds, str) else tuple(kinds)
    if not kinds or not all(isinstance(k, str) and k for k in kinds) \
            or len(set(kinds)) != len(kinds):
        raise InputError(f"kinds must name distinct descriptor kinds, got {kinds!r}")
    if kinds[0] == _COLOUR_KIND:
        raise InputError(f"the first kind is required of every model and cannot be "
                         f"{_COLOUR_KIND!r}; got {kinds!r}")
    return kinds


def _same_kinds(a, b) -> bool:
    """Kinds of the same search: the same first kind and the same set."""
    return list(a)[:1] == list(b)[:1] and set(a) == set(b)


def _groups(kinds) -> dict:
    """Graph name -> the kinds side by side in its vectors."""
    out = {"shape": [k for k in kinds if k != _COLOUR_KIND]}
    if _COLOUR_KIND in kinds:
        out[_COLOUR_KIND] = [_COLOUR_KIND]
    return out


def _rows(db, kinds):
    """Everything the index is built from: per kind the ids and rows that take part, the graph
    vectors and their digests, dimensions and conventions."""
    ids, first = db.descriptor_matrix(kinds[0])
    per = {kinds[0]: (np.asarray(ids, np.int64), np.ascontiguousarray(first, np.float32))}
    for kind in kinds[1:]:
        kid, mat = db.descriptor_matrix(kind)
        keep = np.isin(kid, ids)
        if kind == _COLOUR_KIND and kid.size:
            keep &= db.color_mask(kid)
        per[kind] = (np.asarray(kid[keep], np.int64), np.ascontiguousarray(mat[keep], np.float32))
    dims = {k: int(per[k][1].shape[1]) if per[k][0].size else 0 for k in kinds}
    graphs = {}
    for name, members in _groups(kinds).items():
        gid = per[members[0]][0]
        cols, flags = [], []
        for kind in members:
            kid, mat = per[kind]
            full = np.zeros((gid.size, dims[kind]), np.float32)
            has = np.zeros(gid.size, np.float32)
            if kid.size:
                pos = np.searchsorted(gid, kid)
                full[pos] = mat
                has[pos] = 1.0
            cols.append(full)
            flags.append(has[:, None])
        vec = np.ascontiguousarray(np.hstack(cols), np.float32)
        graphs[name] = (gid, vec, row_digest(vec, *flags) if gid.size else np.zeros(0, np.uint64))
    conventions = {kind: sorted(r[0] for r in db.conn.execute(
        "SELECT DISTINCT convention FROM descriptors WHERE kind = ?", (kind,)))
        for kind in kinds}
    return {"per": per, "graphs": graphs, "dims": dims, "conventions": conventions}


def _new_graph(ids, vectors):
    """An inverted-file index of ``vectors`` (n, d) float32 under model ``ids`` (n,) int64:
    :func:`list_count` lists trained by k-means on them (faiss's fixed seed, one thread: the
    same rows give the same file), the vectors added as 8-bit codes."""
    faiss = _faiss()
    n, d = vectors.shape
    ix = faiss.IndexIVFScalarQuantizer(faiss.IndexFlatL2(int(d)), int(d), list_count(n),
                                       faiss.ScalarQuantizer.QT_8bit, faiss.METRIC_L2)
    ix.cp.seed = _SEED
    ix.verbose = False
    with _one_thread():
        ix.train(vectors)
        ix.add_with_ids(vectors, np.asarray(ids, np.int64))
    return ix


def open_graph(path, graph: dict, *, view: bool):
    """An index file, memory-mapped read-only for searches (``view``; a query touches only the
    lists it probes) or loaded to be changed (:func:`_catch_up`).

    Raises
    ------
    OSError
        The file is not of the size the manifest names (truncated, or another file), or does
        not hold the index the manifest names.
    RuntimeError
        faiss cannot read the file (damaged).
    """
    faiss = _faiss()
    if Path(path).stat().st_size != graph.get("bytes"):
        raise OSError(f"index file {path} is not of its manifest's size")
    # in-place mapping of the codes (IO_FLAG_MMAP_IFC): a search reads the mapped lists as it
    # reads loaded ones (faiss's IO_FLAG_MMAP, lists read from disk per search, is far slower)
    flags = faiss.IO_FLAG_MMAP_IFC | faiss.IO_FLAG_READ_ONLY if view else 0
    ix = faiss.read_index(str(path), flags)
    if ix.ntotal != graph["count"] or ix.d != graph["ndim"] or not hasattr(ix, "nprobe"):
        raise OSError(f"index file {path} does not match its manifest")
    return ix


def _marks(db) -> tuple:
    """What moves when any connection changes the database: ``PRAGMA data_version`` (commits of
    other connections) and the generation counter (this connection's changes)."""
    return tuple(db.conn.execute(
        "SELECT (SELECT data_version FROM pragma_data_version), "
        "(SELECT value FROM meta WHERE key = 'descriptor_generation')").fetchone())


class AnnIndex:
    """The inverted-file indexes and row copies of one database state, queried for exact
    top-k results.

    Made by :func:`open_index` or :func:`build`; not thread-safe.

    Attributes
    ----------
    kinds : tuple of str
        The descriptor kinds of the search (the first required of every model).
    state : dict
        The :meth:`Database.index_state` the files reflect.
    dims : dict of str -> int
        Dimension of every kind (0 when no model holds it).
    count : int
        Models in the shape graph.
    manifest : dict
    """

    def __init__(self, db, graphs, rows, manifest, digests, *, write: bool):
        self._db = db
        self._write = write
        self._set(graphs, rows, manifest, digests)

    def _set(self, graphs, rows, manifest, digests):
        self._ix = dict(graphs)                 # graph name -> faiss index (opened ones)
        self._lazy = {}                         # graph name -> file, memory-mapped on first use
        if isinstance(graphs, _Files):
            self._ix, self._lazy = {}, dict(graphs)
        self._rows = rows                       # kind -> (ids (n,) int64, rows (n, d) float32)
        self.manifest = manifest
        self.kinds = tuple(manifest["kinds"])
        self.state = manifest["state"]
        self.dims = manifest["dims"]
        self._digests = digests                 # graph -> (ids, digests), or None until needed
        self._marks = _marks(self._db)

    @property
    def count(self) -> int:
        g = self.manifest.get("graphs", {})
        if "shape" in self._lazy and "shape" in g:
            return int(g["shape"]["count"])
        return int(self._ix["shape"].ntotal) if "shape" in self._ix else 0

    def _graph(self, name):
        """The index ``name`` (memory-mapped on first use, see :func:`open_graph`), or None;
        a damaged file is rebuilt."""
        if name in self._ix or name not in self._lazy:
            return self._ix.get(name)
        path = self._lazy[name]
        f = self.manifest["graphs"][name]
        try:
            got = open_graph(path, f, view=True)
        except (OSError, ValueError, RuntimeError):
            new = build(self._db, kinds=self.kinds, write=self._write)
            self.__dict__.update(new.__dict__)
            return self._ix.get(name)
        self._lazy.pop(name)
        self._ix[name] = got
        return got

    # ---------------------------------------------------------------- consistency
    def refresh(self) -> bool:
        """Catch up with the database when it changed since this index was opened.

        Returns
        -------
        bool
            Whether the index was changed.
        """
        marks = _marks(self._db)
        if marks == self._marks:
            return False
        state = self._db.index_state()
        if state == self.state:
            self._marks = marks
            return False
        new = open_index(self._db, kinds=self.kinds, write=self._write)
        self.__dict__.update(new.__dict__)
        return True

    # ---------------------------------------------------------------- queries
    def candidates(self, graph: str, vector, n: int, *, probes: int = DEFAULT_PROBES,
                   allowed=None):
        """Ids of the ``n`` models nearest to ``vector`` in one index (``"shape"``: the kinds
        of :attr:`kinds` but texture side by side; ``"texture"``), by the 8-bit codes of the
        ``probes`` nearest lists.

        With ``allowed``, only those models are candidates: the index skips the others while it
        scans its lists (a faiss ``IDSelectorBitmap``), and it scans ``probes`` lists scaled by
        the index's models over the allowed ones (so that about as many allowed models are
        compared as an unfiltered query compares), doubled until ``n`` are found or every list
        is scanned.

        Parameters
        ----------
        graph : str
        vector : (d,) array_like
        n : int
        probes : int
        allowed : (a,) int64, optional
            Ascending model ids.

        Returns
        -------
        (<= n,) int64
            Nearest first.
        """
        ix = self._graph(graph)
        if ix is None or ix.ntotal == 0 or n < 1:
            return np.zeros(0, np.int64)
        v = np.ascontiguousarray(vector, np.float32).reshape(1, -1)
        if v.size != ix.d:
            raise InputError(f"query vector of {graph!r} has {v.size} values but the index "
                             f"holds {ix.d}")
        nlist = int(ix.nlist)
        nprobe = max(1, min(int(probes), nlist))
        if allowed is None:
            ix.nprobe = nprobe
            with _one_thread():
                _, found = ix.search(v, int(min(n, ix.ntotal)))
            found = np.asarray(found[0], np.int64)
            return found[found >= 0]
        faiss = _faiss()
        allowed = np.asarray(allowed, np.int64)
        if allowed.size == 0 or allowed[0] < 0:
            return np.zeros(0, np.int64)
        member = np.zeros(int(allowed[-1]) + 1, bool)
        member[allowed] = True
        bits = np.packbits(member, bitorder="little")     # bit i: id i may be returned
        selector = faiss.IDSelectorBitmap(int(bits.size), faiss.swig_ptr(bits))
        n = int(min(n, ix.ntotal, allowed.size))
        nprobe = min(nlist, max(nprobe, -(-nprobe * int(ix.ntotal) // int(allowed.size))))
        while True:
            params = faiss.SearchParametersIVF(sel=selector, nprobe=nprobe)
            with _one_thread():
                _, found = ix.search(v, n, params=params)
            found = np.asarray(found[0], np.int64)
            found = found[found >= 0]
            if found.size >= n or nprobe >= nlist:
                return found
            nprobe = min(nlist, 2 * nprobe)

    def rows(self, ids) -> tuple:
        """The stored descriptors of some models from the row copies (as
        :meth:`Database.descriptor_rows` reads them from SQLite).

        Parameters
        ----------
        ids : (n,) int64

        Returns
        -------
        ids : (m,) int64
            The models of ``ids`` holding the first kind, ascending.
        stored : dict of str -> (m, d_k) float32
            Rows of absent kinds are zeros.
        present : dict of str -> (m,) bool
            For ``"texture"``: the model has colour and a texture descriptor.
        """
        return self._take(np.unique(as_array(ids, "ids", dtype=np.int64, shape=(None,))))

    def _take(self, ids):
        """:meth:`rows` of ascending unique ``ids``."""
        fid, fmat = self._rows[self.kinds[0]]
        pos, has = _positions(fid, ids)
        out = ids[has]
        pos = pos[has]
        stored = {self.kinds[0]: np.asarray(fmat[pos])}
        present = {self.kinds[0]: np.ones(out.size, bool)}
        for kind in self.kinds[1:]:
            kid, mat = self._rows[kind]
            kpos, khas = _positions(kid, out)
            full = np.asarray(mat[kpos]) if kid.size else np.zeros((out.size, self.dims[kind]),
                                                                      np.float32)
            if not khas.all():
                full[~khas] = 0.0
            stored[kind], present[kind] = full, khas
        return out, stored, present

    def query(self, descriptors, *, distance, k: int = 10, shape_weight: float,
              exclude=None, factor: int = DEFAULT_FACTOR,
              probes: int = DEFAULT_PROBES, allowed=None,
              scan_limit: int = FILTER_SCAN_LIMIT) -> tuple:
        """The ``k`` models nearest to a query by ``distance``, among the candidates of the
        graphs, with the database as stored now (:meth:`refresh` first).

        Parameters
        ----------
        descriptors : dict of str -> (d_k,) array_like
            The query's descriptors (the first kind required; kinds no model holds are ignored;
            leave out ``"texture"`` for a query without colour).
        distance : callable
            ``distance(query, stored, present, *, shape_weight) -> (m,) float``, e.g.
            :func:`surfidx.describe.distance.weighted_l2`.
        k : int
        shape_weight : float
            ``w`` in [0, 1]; at 1 the texture graph is not asked.
        exclude : sequence of int, optional
            Model ids to leave out.
        factor : int
            Candidates per result and graph.
        probes : int
            Lists scanned per index (at least 1).
        allowed : sequence of int, optional
            Only these model ids may be returned (a filter's passing models). Up to
            ``scan_limit`` of them are all ranked by the exact distance (the exact answer);
            more are asked of the index with the others skipped inside it
            (:meth:`candidates`), twice as many candidates as without a filter.
        scan_limit : int
            See ``allowed``.

        Returns
        -------
        ids : (<= k,) int64
            Nearest first; ties broken by ascending id.
        distances : (<= k,) float64

        Raises
        ------
        InputError
            Missing or mis-sized query descriptor, ``k`` or ``factor`` below 1, or a distance
            function returning the wrong shape.
        """
        k = check_positive_int(k, "k")
        factor = check_positive_int(factor, "factor")
        probes = check_positive_int(probes, "probes")
        self.refresh()
        first = self.kinds[0]
        q = {}
        for kind, vec in descriptors.items():
            if kind not in self.kinds or (kind != first and not self.dims.get(kind)):
                continue                                  # not searched, or stored by no model
            v = as_array(vec, f"query descriptor {kind!r}", dtype=np.float32, shape=(None,))
            if self.count and v.size != self.dims[kind]:
                raise InputError(f"query descriptor {kind!r} has {v.size} values but the stored "
                                 f"ones have {self.dims[kind]}; use the same descriptor "
                                 "settings (after an upgrade: `surfidx redescribe` updates the "
                                 "stored ones)")
            q[kind] = v
        if first not in q:
            raise InputError(f"the query has no {first!r} descriptor")
        excl = np.zeros(0, np.int64) if exclude is None else np.unique(
            as_array(list(exclude), "exclude", dtype=np.int64, shape=(None,)))
        if allowed is not None:
            allowed = as_array(allowed if isinstance(allowed, np.ndarray) else list(allowed),
                               "allowed", dtype=np.int64, shape=(None,))
            if allowed.size > 1 and not bool(np.all(allowed[1:] > allowed[:-1])):
                allowed = np.unique(allowed)            # ascending and unique, as selected
            if excl.size:
                allowed = allowed[~np.isin(allowed, excl)]
                excl = np.zeros(0, np.int64)
        n = factor * (k + excl.size) * (1 if allowed is None else _FILTER_WIDEN)
        if allowed is not None and allowed.size <= int(scan_limit):
            cand = allowed                                  # all of them, exactly
        else:
            cand = []
            for graph, members in _groups(self.kinds).items():
                if graph == _COLOUR_KIND and (_COLOUR_KIND not in q
                                              or float(shape_weight) >= 1.0):
                    continue
                vec = np.concatenate([q.get(kd, np.zeros(self.dims[kd], np.float32))
                                      for kd in members])
                cand.append(self.candidates(graph, vec, n, probes=probes, allowed=allowed))
            cand = np.unique(np.concatenate(cand))
        if excl.size:
            cand = cand[~np.isin(cand, excl)]
        ids, stored, present = self._take(cand)
        if ids.size == 0:
            return np.zeros(0, np.int64), np.zeros(0, np.float64)
        d = np.asarray(distance(q, stored, present, shape_weight=shape_weight), np.float64)
        if d.shape != ids.shape:
            raise InputError(f"the distance function returned shape {d.shape}, expected "
                             f"({ids.size},)")
        order = np.lexsort((ids, d))[:k]
        order = order[np.isfinite(d[order])]
        return ids[order].copy(), d[order]

    # ---------------------------------------------------------------- writing
    def _save(self, d: Path) -> bool:
        """Write the index files and then the manifest (atomically); False when the folder
        cannot be written (the index stays in memory)."""
        token = os.urandom(6).hex()
        old = _read_manifest(d)
        written = []

        def put(name, write):
            tmp = d / (name + ".tmp")
            write(tmp)
            os.replace(tmp, d / name)
            written.append(d / name)

        def npy(arr):
            def write(p):
                with open(p, "wb") as f:
                    np.save(f, np.ascontiguousarray(arr))
            return write

        try:
            d.mkdir(exist_ok=True)
            graphs = {}
            for name, ix in self._ix.items():
                fname = f"{token}-{name}.faiss"
                put(fname, lambda p, ix=ix: _faiss().write_index(ix, str(p)))
                graphs[name] = {"file": fname, "count": int(ix.ntotal), "ndim": int(ix.d),
                                "lists": int(ix.nlist), "bytes": (d / fname).stat().st_size,
                                "kinds": _groups(self.kinds)[name]}
            rows = {}
            for kind, (kid, mat) in self._rows.items():
                rows[kind] = {"ids": f"{token}-ids-{kind}.npy", "rows": f"{token}-rows-{kind}.npy",
                              "count": int(kid.size), "dim": int(mat.shape[1])}
                put(rows[kind]["ids"], npy(np.asarray(kid, np.int64)))
                put(rows[kind]["rows"], npy(np.asarray(mat, np.float32)))
            dname = f"{token}-digests.npz"
            dg = self._digests

            def write_digests(p):
                with open(p, "wb") as f:
                    np.savez(f, **{f"{g}_ids": v[0] for g, v in dg.items()},
                             **{f"{g}_digest": v[1] for g, v in dg.items()})
            put(dname, write_digests)
            man = dict(self.manifest, graphs=graphs, rows=rows, digests=dname)
            _write_manifest(d, man, token)
            self.manifest = man
        except OSError:
            for p in written:
                with _quiet():
                    p.unlink()
            return False
        if old is not None:                      # the files the old manifest named
            keep = set(index_files(self.manifest))
            for name in index_files(old):
                if name not in keep:
                    with _quiet():
                        (d / name).unlink()
        return True


def _write_manifest(d: Path, man: dict, token: str) -> None:
    """Replace the manifest of folder ``d`` by ``man`` (written and synced first, then
    ``os.replace``: a reader sees the old manifest or the new one, whole)."""
    tmp = d / f"manifest.{token}.tmp"
    try:
        with open(tmp, "w", encoding="utf-8") as f:
            json.dump(man, f, indent=1, sort_keys=True)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, d / "manifest.json")
    except OSError:
        with _quiet():
            tmp.unlink()
        raise


def _positions(sorted_ids, ids) -> tuple:
    """Positions of ``ids`` in the ascending array ``sorted_ids`` (clipped) and which of them
    are there."""
    if sorted_ids.size == 0:
        return np.zeros(ids.size, np.intp), np.zeros(ids.size, bool)
    pos = np.minimum(np.searchsorted(sorted_ids, ids), sorted_ids.size - 1)
    return pos, np.asarray(sorted_ids[pos] == ids)


class _quiet:
    def __enter__(self):
        return self

    def __exit__(self, et, ev, tb):
        return et is not None and issubclass(et, OSError)


def _manifest_of(state, kinds, rows):
    return {"format": FORMAT, "library": f"faiss {_faiss().__version__}",
            "index": "IVF,SQ8 (IndexIVFScalarQuantizer, QT_8bit, L2)", "seed": _SEED,
            "state": state, "kinds": list(kinds), "dims": rows["dims"],
            "conventions": rows["conventions"], "graphs": {}}


def _fresh(rows):
    """New indexes of all rows (the same rows give the same index files)."""
    return {name: _new_graph(gid, vec) for name, (gid, vec, _) in rows["graphs"].items()
            if gid.size}


def build(db, *, kinds=None, write: bool = True) -> AnnIndex:
    """Build the index of a database from all its rows (and write it beside the file).

    Parameters
    ----------
    db : surfidx.db.catalog.Catalog
    kinds : sequence of str, optional
        The descriptor kinds of the search (e.g. :data:`surfidx.describe.distance.DEFAULT_KINDS`; default
        :data:`BUILD_KINDS`); the first is required of every model that takes part.
    write : bool
        Write it to :func:`index_dir` (when the folder can be written).

    Returns
    -------
    AnnIndex

    Raises
    ------
    DatabaseError
        Descriptors of one kind with different dimensions or conventions (as
        :meth:`Database.descriptor_matrix`).
    InputError
        ``kinds`` empty, repeated, or starting with ``"texture"``.
    """
    kinds = _check_kinds(BUILD_KINDS if kinds is None else kinds)
    state = db.index_state()
    rows = _rows(db, kinds)
    index = AnnIndex(db, _fresh(rows), rows["per"], _manifest_of(state, kinds, rows),
                     {g: (v[0], v[2]) for g, v in rows["graphs"].items()}, write=write)
    if write:
        index._save(index_dir(db.path))
    return index


class _Files(dict):
    """Graph name -> file of graphs not opened yet (see :meth:`AnnIndex._graph`)."""


def load_index(d: Path, man, *, view: bool):
    """The graphs and rows of the index in folder ``d`` that manifest ``man`` describes.

    Parameters
    ----------
    d : Path
        The index folder.
    man : dict
        Its manifest.
    view : bool
        Map the files read-only for searches (the graphs are opened on first use) rather than
        load them to be changed.

    Returns
    -------
    graphs : dict
        Graph name -> index (``view``: its file, opened by :func:`open_graph` on first use).
    rows : dict
        Kind -> ``(ids, rows)``: ``ndarray of int64, shape (count,)`` and
        ``ndarray of float32, shape (count, dim)``.

    Raises
    ------
    OSError
        When a file is missing or does not match the manifest.
    """
    ix = {}
    for name, f in man["graphs"].items():
        if view:
            if not (d / f["file"]).is_file():
                raise OSError(f"index file {d / f['file']} is missing")
            ix[name] = d / f["file"]
            continue
        ix[name] = open_graph(d / f["file"], f, view=False)
    rows = {}
    for kind, r in man["rows"].items():
        # plain ndarrays over the mapped pages: indexing an np.memmap goes through its Python
        # __getitem__, a dozen calls per query
        kid = np.asarray(np.load(d / r["ids"], mmap_mode="r" if view else None,
                                 allow_pickle=False))
        mat = np.asarray(np.load(d / r["rows"], mmap_mode="r" if view else None,
                                 allow_pickle=False))
        if kid.shape != (r["count"],) or mat.shape != (r["count"], r["dim"]) \
                or kid.dtype != np.int64 or mat.dtype != np.float32:
            raise OSError(f"row files of {kind!r} in {d} do not match their manifest")
        rows[kind] = (kid, mat)
    return (_Files(ix) if view else ix), rows


def _load_digests(d: Path, man):
    with np.load(d / man["digests"]) as z:
        return {g: (z[f"{g}_ids"], z[f"{g}_digest"]) for g in man["graphs"]}


def open_index(db, *, kinds=None, write: bool = True, state: dict | None = None) -> AnnIndex:
    """The index of a database, current with its rows: memory-mapped from :func:`index_dir`,
    patched or rebuilt when it is stale, missing or of other kinds (see the module notes).

    Parameters
    ----------
    db : surfidx.db.catalog.Catalog
        Read-only is fine: only the index folder is written.
    kinds : sequence of str, optional
        The descriptor kinds of the search (default: those of the index on disk, else
        :data:`BUILD_KINDS`).
    write : bool
        Write a patched or rebuilt index back (when the folder can be written).
    state : dict, optional
        ``db.index_state()`` as the caller just read it (it counts the models: read once).

    Returns
    -------
    AnnIndex
    """
    d = index_dir(db.path)
    state = db.index_state() if state is None else state
    for _ in range(2):                          # a writer may replace the files meanwhile
        man = _read_manifest(d)
        if kinds is None:
            kinds = tuple(man["kinds"]) if man is not None else BUILD_KINDS
        kinds = _check_kinds(kinds)
        if man is None or not _same_kinds(man["kinds"], kinds):
            return build(db, kinds=kinds, write=write)
        try:
            if man["state"] == state:
                graphs, rows = load_index(d, man, view=True)
                return AnnIndex(db, graphs, rows, man, None, write=write)
            return _catch_up(db, d, man, state, write=write)
        except (OSError, ValueError, KeyError, RuntimeError):
            continue
    return build(db, kinds=kinds, write=write)


def index_changes(old_ids, old_digests, ids, digests) -> tuple:
    """Models indexed but stored no more (``gone``) and stored but not indexed as they are now
    (``changed``: new or with other rows), from ascending ids and their digests.

    Returns
    -------
    gone : list of int
    changed : list of int
    """
    gone = old_ids[~np.isin(old_ids, ids)]
    pos, has = _positions(old_ids, ids)
    if old_ids.size:
        has &= old_digests[pos] == digests
    return gone.tolist(), ids[~has].tolist()


def _catch_up(db, d, man, state, *, write):
    """Patch a stale index to the rows stored now (or rebuild it)."""
    kinds = tuple(man["kinds"])
    rows = _rows(db, kinds)
    if rows["dims"] != man["dims"] or rows["conventions"] != man["conventions"]:
        return build(db, kinds=kinds, write=write)
    old = _load_digests(d, man)
    plan = {}
    for graph, (ids, _, dg) in rows["graphs"].items():
        oid, odg = old.get(graph, (np.zeros(0, np.int64), np.zeros(0, np.uint64)))
        plan[graph] = index_changes(np.asarray(oid, np.int64), np.asarray(odg, np.uint64), ids, dg)
    total = max(rows["graphs"]["shape"][0].size, 1)
    if sum(len(g) + len(c) for g, c in plan.values()) > _REBUILD_SHARE * total:
        return build(db, kinds=kinds, write=write)
    if not any(len(g) or len(c) for g, c in plan.values()):
        # every row as indexed (e.g. a schema upgrade or a change undone): the same files
        # under a manifest of the state now
        man = dict(man, state=state)
        if write:
            with _quiet():
                _write_manifest(d, man, os.urandom(6).hex())
        graphs, per = load_index(d, man, view=True)
        return AnnIndex(db, graphs, per, man, None, write=write)
    if any(graph not in man["graphs"] and (gone or changed)
           for graph, (gone, changed) in plan.items()):
        return build(db, kinds=kinds, write=write)   # a first coloured model: lists to train
    ix, _ = load_index(d, man, view=False)
    for graph, (src_ids, src, _) in rows["graphs"].items():
        gone, changed = plan[graph]
        if not gone and not changed:
            continue
        target = ix[graph]
        with _one_thread():
            target.remove_ids(np.asarray(gone + changed, np.int64))   # absent ids: no-op
            if changed:
                pos = np.searchsorted(src_ids, np.asarray(changed, np.int64))
                target.add_with_ids(src[pos], np.asarray(changed, np.int64))
    index = AnnIndex(db, ix, rows["per"], dict(man, state=state),
                     {g: (v[0], v[2]) for g, v in rows["graphs"].items()}, write=write)
    if write:
        index._save(d)
    return index


def update(db, *, kinds=None, write: bool = True):
    """Bring the index beside ``db`` up to date after this process changed models (what
    :meth:`Database.close` runs); builds it when missing and the database holds at least
    :data:`DEFAULT_THRESHOLD` models, does nothing otherwise.

    Parameters
    ----------
    db : surfidx.db.catalog.Catalog
    kinds : sequence of str, optional
        As in :func:`open_index`.
    write : bool

    Returns
    -------
    AnnIndex or None
    """
    d = index_dir(db.path)
    if _read_manifest(d) is None and db.count() < DEFAULT_THRESHOLD:
        return None
    return open_index(db, kinds=kinds, write=write)
