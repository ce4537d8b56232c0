"""The approximate nearest-neighbour index beside a database: candidates for the exact distance.

Above :data:`DEFAULT_THRESHOLD` stored models, :class:`surfidx.search.SearchIndex` does not scan
every stored vector: it asks an HNSW graph (usearch, ``connectivity`` 16, vectors as float16) for
the ``factor * k`` models nearest by the shape vector (shape with the KLT spectrum appended), and
for a coloured query also the ``factor * k`` coloured models nearest by texture, then reads those
candidates' rows from SQLite (by id) and ranks them by the exact
:func:`surfidx.search.weighted_l2`. Every distance returned is the exact one, computed from the
rows stored at query time; the index decides only which models are looked at
(``benchmarks/query_latency.py`` measures recall@10 against the exact scan: >= 0.99 at 1M models
with :data:`DEFAULT_FACTOR`).

Files
-----
``DB.ann/`` beside the database file ``DB``: ``manifest.json`` and one ``TOKEN-KIND.usearch`` per
indexed kind. The manifest names the files, the library and settings, the descriptor dimensions
and conventions, the database state the index reflects (:meth:`Database.index_state`: the
descriptor generation counter that :class:`~surfidx.database.Database` increments with every
change of a model or its descriptors, the schema version, the largest model id and descriptor
rowid, the model count), and a content digest per indexed model. A new or updated index is
written to new files first and then the manifest is replaced (``os.replace``, atomic): a crash
leaves the old manifest naming the old files.

Consistency
-----------
:func:`open_index` compares the manifest's state with the database's. Equal: the files are
memory-mapped as they are (``view``: no loading, a query touches only the pages it visits).
Different (the database was changed by a process that did not update the index, or the index
update did not finish): the stored rows are read and compared by digest with the indexed ones;
changed and new models are added, removed ones removed (a full rebuild when more than a quarter
changed, or the conventions or dimensions changed), and the result is written back (only the
index files, never the database; in memory when the folder cannot be written). A writer that
changed models through :class:`~surfidx.database.Database` updates the index when it closes
(:func:`update`). The descriptor-version guard stays: descriptors of one kind made with two
conventions are refused as by :meth:`Database.descriptor_matrix`.
"""

from __future__ import annotations

import json
import os
import secrets
from pathlib import Path

import numpy as np

from ._errors import InputError

__all__ = ["AnnIndex", "open_index", "build", "update", "index_dir", "index_size",
           "DEFAULT_THRESHOLD", "DEFAULT_FACTOR", "DEFAULT_EXPANSION", "FORMAT"]

#: Model count from which :class:`surfidx.search.SearchIndex` uses the index (the exact scan
#: below it). Measured (``benchmarks/query_latency.py``): the scan costs ~0.13 ms per 1000
#: models on one core, an index query with its re-rank ~0.6-1 ms, opening the index a few ms.
DEFAULT_THRESHOLD = 20_000

#: Candidates per result: ``factor * k`` models are re-ranked by the exact distance.
DEFAULT_FACTOR = 8

#: HNSW search expansion (``ef``), raised to the candidate count when that is larger.
DEFAULT_EXPANSION = 128

#: Manifest format version.
FORMAT = 1

_CONNECTIVITY = 16
_EXPANSION_ADD = 128
_DTYPE = "f16"
#: Share of changed models above which a stale index is rebuilt rather than patched.
_REBUILD_SHARE = 0.25

_MULT = None


def index_dir(db_path) -> Path:
    """The index folder of a database file: ``DB.ann`` beside it."""
    p = Path(db_path)
    return p.with_name(p.name + ".ann")


def index_size(db_path) -> int:
    """Bytes of the index files the manifest names (0 without an index)."""
    d = index_dir(db_path)
    man = _read_manifest(d)
    if man is None:
        return 0
    return sum((d / f["file"]).stat().st_size for f in man["kinds"].values()
               if (d / f["file"]).exists())


def _usearch():
    from usearch.index import Index

    return Index


def _digest(*mats) -> np.ndarray:
    """A 64-bit digest per row of float32 matrices side by side (exact bytes, order-aware)."""
    global _MULT
    words = np.hstack([np.ascontiguousarray(m, np.float32).view(np.uint32) for m in mats])
    if _MULT is None or _MULT.size < words.shape[1]:
        rng = np.random.default_rng(0x5F5A)
        _MULT = rng.integers(1, 2 ** 63, size=512, dtype=np.uint64) | np.uint64(1)
    with np.errstate(over="ignore"):
        acc = np.zeros(words.shape[0], np.uint64)
        for j in range(words.shape[1]):          # column loop: 280 columns, vectorised rows
            acc = (acc ^ words[:, j].astype(np.uint64)) * _MULT[j]
    return acc


def _read_manifest(d: Path):
    try:
        with open(d / "manifest.json", encoding="utf-8") as f:
            man = json.load(f)
    except (OSError, ValueError):
        return None
    if not isinstance(man, dict) or man.get("format") != FORMAT or "kinds" not in man:
        return None
    return man


def _rows(db):
    """Everything the index is built from: ids, shape+spectrum, texture (coloured), digests."""
    ids, shape = db.descriptor_matrix("shape")
    m = ids.size
    sid, spec = db.descriptor_matrix("spectrum")
    full_spec = np.zeros((m, spec.shape[1] if spec.ndim == 2 else 0), np.float32)
    if m and sid.size:
        pos = np.searchsorted(ids, sid)
        ok = (pos < m) & (ids[np.minimum(pos, m - 1)] == sid)
        full_spec[pos[ok]] = spec[ok]
    vec = np.hstack([shape, full_spec]).astype(np.float32)
    tid, tex = db.descriptor_matrix("texture")
    color = db.color_mask(tid) if tid.size else np.zeros(0, bool)
    tid, tex = tid[color], tex[color]
    conventions = {kind: [r[0] for r in db.conn.execute(
        "SELECT DISTINCT convention FROM descriptors WHERE kind = ?", (kind,))]
        for kind in ("shape", "spectrum", "texture")}
    return {"ids": ids, "vec": vec, "tids": tid, "tex": np.ascontiguousarray(tex, np.float32),
            "digest": _digest(vec), "tdigest": _digest(tex) if tid.size else np.zeros(0, np.uint64),
            "dims": {"shape": int(shape.shape[1]) if m else 0,
                     "spectrum": int(full_spec.shape[1]),
                     "texture": int(tex.shape[1]) if tid.size else 0},
            "conventions": conventions}


def _new_index(ndim):
    return _usearch()(ndim=int(ndim), metric="l2sq", dtype=_DTYPE, connectivity=_CONNECTIVITY,
                      expansion_add=_EXPANSION_ADD)


class AnnIndex:
    """The HNSW indexes of one database state, queried for candidates.

    Built by :func:`open_index` or :func:`build`; not thread-safe for updates.

    Attributes
    ----------
    state : dict
        The :meth:`Database.index_state` this index reflects.
    dims : dict of str -> int
        Dimensions of ``shape``, ``spectrum``, ``texture`` of the indexed rows.
    count : int
        Models in the shape index.
    """

    def __init__(self, indexes, manifest, digests):
        self._ix = indexes                      # kind -> usearch.Index
        self.manifest = manifest
        self.state = manifest["state"]
        self.dims = manifest["dims"]
        self._digests = digests                 # kind -> (ids, digests), or None until needed

    @property
    def count(self) -> int:
        return int(len(self._ix["shape"])) if "shape" in self._ix else 0

    def candidates(self, kind: str, vector, n: int, *, expansion: int = DEFAULT_EXPANSION):
        """Ids of the ``n`` models nearest to ``vector`` in the ``kind`` index (``"shape"``:
        shape with the spectrum appended; ``"texture"``).

        Returns
        -------
        (<= n,) int64
        """
        ix = self._ix.get(kind)
        if ix is None or len(ix) == 0 or n < 1:
            return np.zeros(0, np.int64)
        v = np.ascontiguousarray(vector, np.float32)
        if v.size != ix.ndim:
            raise InputError(f"query vector of {kind!r} has {v.size} values but the index "
                             f"holds {ix.ndim}")
        ix.expansion_search = max(int(expansion), int(n))
        return np.asarray(ix.search(v, int(n), threads=1).keys, np.int64)

    # ---------------------------------------------------------------- writing
    def _save(self, d: Path) -> bool:
        """Write the index files and then the manifest (atomically); False when the folder
        cannot be written (the index stays in memory)."""
        token = secrets.token_hex(6)
        old = _read_manifest(d)
        written = []
        try:
            d.mkdir(exist_ok=True)
            kinds = {}
            for kind, ix in self._ix.items():
                name = f"{token}-{kind}.usearch"
                tmp = d / (name + ".tmp")
                ix.save(str(tmp))
                os.replace(tmp, d / name)
                written.append(d / name)
                kinds[kind] = {"file": name, "count": int(len(ix)), "ndim": int(ix.ndim)}
            ids, dg = self._digests["shape"]
            tids, tdg = self._digests["texture"]
            dname = f"{token}-digests.npz"
            with open(d / (dname + ".tmp"), "wb") as f:
                np.savez(f, ids=ids, digest=dg, tids=tids, tdigest=tdg)
            os.replace(d / (dname + ".tmp"), d / dname)
            written.append(d / dname)
            man = dict(self.manifest, kinds=kinds, digests=dname)
            tmp = d / f"manifest.{token}.tmp"
            with open(tmp, "w", encoding="utf-8") as f:
                json.dump(man, f, indent=1, sort_keys=True)
                f.flush()
                os.fsync(f.fileno())
            os.replace(tmp, d / "manifest.json")
            self.manifest = man
        except OSError:
            for p in written:
                with _quiet():
                    p.unlink()
            return False
        if old is not None:                      # the files the old manifest named
            for name in [f["file"] for f in old["kinds"].values()] + [old.get("digests")]:
                if name and name not in [f["file"] for f in self.manifest["kinds"].values()]:
                    with _quiet():
                        (d / name).unlink()
        return True


class _quiet:
    def __enter__(self):
        return self

    def __exit__(self, et, ev, tb):
        return et is not None and issubclass(et, OSError)


def _manifest_of(state, rows):
    import usearch

    return {"format": FORMAT, "library": f"usearch {usearch.__version__}", "dtype": _DTYPE,
            "connectivity": _CONNECTIVITY, "expansion_add": _EXPANSION_ADD, "state": state,
            "dims": rows["dims"], "conventions": rows["conventions"], "kinds": {}}


def _fresh(rows):
    """New indexes of all rows (one thread: the same rows give the same index files)."""
    ix = {}
    if rows["ids"].size:
        ix["shape"] = _new_index(rows["vec"].shape[1])
        ix["shape"].add(rows["ids"].astype(np.uint64), rows["vec"], threads=1)
    if rows["tids"].size:
        ix["texture"] = _new_index(rows["tex"].shape[1])
        ix["texture"].add(rows["tids"].astype(np.uint64), rows["tex"], threads=1)
    return ix


def build(db, *, write: bool = True) -> AnnIndex:
    """Build the index of a database from all its rows (and write it beside the file).

    Parameters
    ----------
    db : surfidx.database.Database
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
    """
    state = db.index_state()
    rows = _rows(db)
    index = AnnIndex(_fresh(rows), _manifest_of(state, rows),
                     {"shape": (rows["ids"], rows["digest"]),
                      "texture": (rows["tids"], rows["tdigest"])})
    if write:
        index._save(index_dir(db.path))
    return index


def _load(d: Path, man, *, view: bool):
    Index = _usearch()
    ix = {}
    for kind, f in man["kinds"].items():
        p = d / f["file"]
        got = Index.restore(str(p), view=view)
        if got is None or len(got) != f["count"] or got.ndim != f["ndim"]:
            raise OSError(f"index file {p} does not match its manifest")
        ix[kind] = got
    return ix


def _load_digests(d: Path, man):
    with np.load(d / man["digests"]) as z:
        return {"shape": (z["ids"], z["digest"]), "texture": (z["tids"], z["tdigest"])}


def open_index(db, *, write: bool = True) -> AnnIndex:
    """The index of a database, current with its rows: memory-mapped from :func:`index_dir`,
    patched or rebuilt when it is stale or missing (see the module notes).

    Parameters
    ----------
    db : surfidx.database.Database
        Read-only is fine: only the index folder is written.
    write : bool
        Write a patched or rebuilt index back (when the folder can be written).

    Returns
    -------
    AnnIndex
    """
    d = index_dir(db.path)
    state = db.index_state()
    for _ in range(2):                          # a writer may replace the files meanwhile
        man = _read_manifest(d)
        if man is None:
            return build(db, write=write)
        try:
            if man["state"] == state:
                return AnnIndex(_load(d, man, view=True), man, None)
            return _catch_up(db, d, man, state, write=write)
        except (OSError, ValueError, KeyError, RuntimeError):
            continue
    return build(db, write=write)


def _catch_up(db, d, man, state, *, write):
    """Patch a stale index to the rows stored now (or rebuild it)."""
    rows = _rows(db)
    if (rows["dims"] != man["dims"] or rows["conventions"] != man["conventions"]):
        return build(db, write=write)
    old = _load_digests(d, man)
    plan = {}
    for kind, ids, dg in (("shape", rows["ids"], rows["digest"]),
                          ("texture", rows["tids"], rows["tdigest"])):
        oid, odg = old[kind]
        now = dict(zip(ids.tolist(), dg.tolist()))
        was = dict(zip(oid.tolist(), odg.tolist()))
        gone = [i for i in was if i not in now]
        changed = [i for i, h in now.items() if was.get(i) != h]
        plan[kind] = (gone, changed)
    total = max(rows["ids"].size, 1)
    if sum(len(g) + len(c) for g, c in plan.values()) > _REBUILD_SHARE * total:
        return build(db, write=write)
    ix = _load(d, man, view=False)
    for kind, src_ids, src in (("shape", rows["ids"], rows["vec"]),
                               ("texture", rows["tids"], rows["tex"])):
        gone, changed = plan[kind]
        if not gone and not changed:
            continue
        if kind not in ix:
            ix[kind] = _new_index(src.shape[1])
        target = ix[kind]
        drop = [i for i in gone + changed if i in target]
        if drop:
            target.remove(np.asarray(drop, np.uint64))
        if changed:
            pos = np.searchsorted(src_ids, np.asarray(changed, np.int64))
            target.add(np.asarray(changed, np.uint64), src[pos], threads=1)
    index = AnnIndex(ix, dict(man, state=state),
                     {"shape": (rows["ids"], rows["digest"]),
                      "texture": (rows["tids"], rows["tdigest"])})
    if write:
        index._save(d)
    return index


def update(db, *, write: bool = True):
    """Bring the index beside ``db`` up to date after this process changed models (what
    :meth:`Database.close` runs); builds it when missing and the database holds at least
    :data:`DEFAULT_THRESHOLD` models, does nothing otherwise.

    Returns
    -------
    AnnIndex or None
    """
    d = index_dir(db.path)
    if _read_manifest(d) is None:
        if db.count() < DEFAULT_THRESHOLD:
            return None
        return build(db, write=write)
    return open_index(db, write=write)
