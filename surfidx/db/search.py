"""Query by example: rank the stored models by descriptor distance to a query.

Two paths, one answer:

* exact scan (below :data:`surfidx.db.ann.DEFAULT_THRESHOLD` stored models, or ``exact=True``): the
  stored vectors are read once into dense float32 matrices (built from
  :meth:`surfidx.db.catalog.Catalog.descriptor_matrix`) and every query is one vectorised scan
  followed by ``np.argpartition`` for the top ``k``;
* approximate index (from the threshold on): faiss inverted-file indexes beside the database
  (:mod:`surfidx.db.ann`) give ``factor * k`` candidates by the shape vector (and as many by
  texture for a coloured query), ranked by the exact distance below on the index's float32 copies
  of the stored rows, so every distance returned is the exact one.

A filter's passing models (``allowed`` ids) narrow either path: the scan leaves the others out,
the index skips them inside its lists (:meth:`surfidx.db.ann.AnnIndex.query`).

``benchmarks/query_latency.py`` prints both paths' latency and the index's recall@10 against the
scan at 10 000, 100 000 and 1 000 000 models.

Distances are :func:`surfidx.describe.distance.weighted_l2` (see there for the rule).
"""

from __future__ import annotations

import numpy as np

from ..describe.distance import (DEFAULT_KINDS, DEFAULT_SHAPE_WEIGHT, check_shape_weight,
                                combine_distances, squared_distances, weighted_l2)
from ..errors import InputError
from ..validate import as_array, check_positive_int

#: Candidates per result of the approximate path (as :data:`surfidx.db.ann.DEFAULT_FACTOR`; kept
#: here so that importing this module does not import the index library).
DEFAULT_FACTOR = 4

__all__ = ["SearchIndex", "search", "DEFAULT_FACTOR"]

class SearchIndex:
    """The stored descriptors of a database, set up once and queried many times: dense matrices
    for the exact scan, or the approximate index (:mod:`surfidx.db.ann`) from ``threshold`` models.

    Parameters
    ----------
    db : surfidx.db.catalog.Catalog
        Stays in use by the approximate path (candidate rows are read from it per query).
    kinds : sequence of str
        Descriptor kinds to load; the first (``"shape"``) is required of every model that takes
        part, the others are optional per model.
    exact : bool
        Always scan every stored vector (never the approximate index).
    threshold : int, optional
        Stored models from which the approximate index is used (default
        :data:`surfidx.db.ann.DEFAULT_THRESHOLD`); only with the default ``kinds``.
    factor : int
        Candidates per result of the approximate path (``factor * k`` by shape, as many by
        texture for a coloured query), re-ranked by the exact distance.

    Attributes
    ----------
    approximate : bool
        Whether queries use the approximate index.
    ids : (m,) int64
        Ids of the models holding ``kinds[0]``, ascending (read on first use in the approximate
        path).
    stored : dict of str -> (m, d_k) float32
    present : dict of str -> (m,) bool

    Notes
    -----
    Opening the approximate index checks it against the database (:func:`surfidx.db.ann.open_index`):
    a missing or stale index is rebuilt or patched first, written beside the database when its
    folder can be written (the database itself is never written).
    """

    def __init__(self, db, *, kinds=DEFAULT_KINDS, exact: bool = False, threshold=None,
                 factor: int = DEFAULT_FACTOR):
        kinds = tuple(kinds)
        if not kinds:
            raise InputError("kinds must name at least one descriptor kind")
        self.kinds = kinds
        self.factor = check_positive_int(factor, "factor")
        self._db = db
        self._norms = {}
        self._ann = None
        self._loaded = False
        self.approximate = False
        self._limit = None
        if not exact:
            from . import ann

            limit = ann.DEFAULT_THRESHOLD if threshold is None else int(threshold)
            self._limit = max(limit, 1)
            state = db.index_state()                # the model count, and what the index needs
            if state["models"] >= self._limit:
                self._ann = ann.open_index(db, kinds=kinds, state=state)
                self.approximate = True
                return
        self._load()

    def __getattr__(self, name):
        if name in ("ids", "stored", "present") and not self.__dict__.get("_loaded", True):
            self._load()
            return self.__dict__[name]
        raise AttributeError(name)

    def _load(self):
        db, kinds = self._db, self.kinds
        self._loaded = True
        self.ids, first = db.descriptor_matrix(kinds[0])
        m = self.ids.size
        self.stored = {kinds[0]: first}
        self.present = {kinds[0]: np.ones(m, bool)}
        color = db.color_mask(self.ids) if m else np.zeros(0, bool)
        for kind in kinds[1:]:
            kid, mat = db.descriptor_matrix(kind)
            full = np.zeros((m, mat.shape[1]), np.float32)
            has = np.zeros(m, bool)
            if m and kid.size:
                pos = np.minimum(np.searchsorted(self.ids, kid), m - 1)
                ok = self.ids[pos] == kid
                full[pos[ok]] = mat[ok]
                has[pos[ok]] = True
            if kind == "texture":
                has &= color
            self.stored[kind] = full
            self.present[kind] = has

    def still_approximate(self) -> bool:
        """Whether this index, set up on the approximate path, still is the right one after
        the database changed: it catches up with the stored rows (:meth:`AnnIndex.refresh`)
        and the model count is still at the threshold or above. False on the exact path (its
        matrices are not followed: set up a new index after changes).

        Returns
        -------
        bool
        """
        if not self.approximate:
            return False
        self._ann.refresh()
        return int(self._ann.state["models"]) >= self._limit

    def __len__(self):
        if self.approximate and not self._loaded:
            return int(self._ann.state["models"])
        return int(self.ids.size)

    def query(self, descriptors, *, k: int = 10, shape_weight: float = DEFAULT_SHAPE_WEIGHT,
              distance=None, exclude=None, allowed=None) -> tuple:
        """The ``k`` stored models nearest to a query.

        Parameters
        ----------
        descriptors : dict of str -> (d_k,) array_like
            The query's descriptors (``kinds[0]`` required; leave out ``"texture"`` for a query
            without colour).
        k : int
            Number of results (fewer when fewer models are stored).
        shape_weight : float
            ``w`` in [0, 1] of :func:`weighted_l2`.
        distance : callable, optional
            ``distance(query, stored, present, *, shape_weight) -> (m,) float``; default
            :func:`weighted_l2`.
        exclude : sequence of int, optional
            Model ids to leave out (e.g. the query's own id).
        allowed : sequence of int, optional
            Only these model ids may be returned (a filter's passing models; on the
            approximate path see :meth:`surfidx.db.ann.AnnIndex.query`).

        Returns
        -------
        ids : (k,) int64
            Nearest first; ties broken by ascending id.
        distances : (k,) float64

        Raises
        ------
        InputError
            Missing or mis-sized query descriptor, ``k < 1``, ``shape_weight`` outside [0, 1],
            or a distance function returning the wrong shape.
        """
        k = check_positive_int(k, "k")
        w = check_shape_weight(shape_weight)
        if self.approximate:
            return self._ann.query(descriptors, distance=distance or weighted_l2, k=k,
                                   shape_weight=w, exclude=exclude, factor=self.factor,
                                   allowed=allowed)
        q = {}
        for kind, vec in descriptors.items():
            if kind not in self.stored:
                continue
            if kind != self.kinds[0] and not self.present[kind].any():
                continue                                  # stored by no model: ignored
            v = as_array(vec, f"query descriptor {kind!r}", dtype=np.float32, shape=(None,))
            want = self.stored[kind].shape[1]
            if len(self) and v.size != want:
                raise InputError(f"query descriptor {kind!r} has {v.size} values but the stored "
                                 f"ones have {want}; use the same descriptor settings (after "
                                 "an upgrade: `surfidx redescribe` updates the stored ones)")
            q[kind] = v
        first = self.kinds[0]
        if distance is None and first != "shape":
            raise InputError(f"the default distance compares 'shape' descriptors; with kinds "
                             f"{self.kinds} pass distance=")
        if first not in q:
            raise InputError(f"the query has no {first!r} descriptor")
        m = len(self)
        if m == 0:
            return np.zeros(0, np.int64), np.zeros(0, np.float64)
        if distance is None:
            # Fast screen by ||a - b||^2 = ||a||^2 - 2 a.b + ||b||^2 (one BLAS mat-vec per kind),
            # then the exact weighted_l2 on a generous candidate set, so rounding of the
            # expansion cannot change the result.
            d = self._screen(q, w)
        else:
            d = np.asarray(distance(q, self.stored, self.present, shape_weight=w),
                           dtype=np.float64)
            if d.shape != (m,):
                raise InputError(f"the distance function returned shape {d.shape}, "
                                 f"expected ({m},)")
        drop = None
        if exclude is not None:
            drop = np.isin(self.ids, np.asarray(list(exclude), np.int64))
        if allowed is not None:
            out = ~np.isin(self.ids, np.asarray(allowed, np.int64).ravel())
            drop = out if drop is None else drop | out
        if drop is not None:
            d = d.copy()
            d[drop] = np.inf
        kk = min(k, m)
        if distance is None:
            nc = min(m, max(4 * kk, kk + 64))
            cand = np.argpartition(d, nc - 1)[:nc] if nc < m else np.arange(m)
            exact = weighted_l2(q, {kd: s[cand] for kd, s in self.stored.items()},
                                {kd: p[cand] for kd, p in self.present.items()}, shape_weight=w)
            d = np.full(m, np.inf)
            if drop is not None:
                keep = ~drop[cand]
                cand, exact = cand[keep], exact[keep]
            d[cand] = exact
        else:
            cand = np.argpartition(d, kk - 1)[:kk] if kk < m else np.arange(m)
        order = cand[np.lexsort((self.ids[cand], d[cand]))][:kk]
        order = order[np.isfinite(d[order])]
        return self.ids[order].copy(), d[order]

    def _sqnorms(self, kind):
        if kind not in self._norms:
            s = self.stored[kind]
            self._norms[kind] = np.einsum("ij,ij->i", s, s, dtype=np.float64)
        return self._norms[kind]

    def _screen(self, q, w) -> np.ndarray:
        """Approximate :func:`weighted_l2` of every stored model (expansion of the square)."""
        def sq(kind):
            v = q[kind]
            mat = self.stored[kind]
            # einsum beats BLAS gemv for wide rows here; gemv wins for a few columns.
            dot = mat @ v if mat.shape[1] <= 8 else np.einsum("ij,j->i", mat, v)
            return self._sqnorms(kind) - 2.0 * dot + float(v @ v)

        s = sq("shape")
        if "spectrum" in q and "spectrum" in self.stored:
            s = s + np.where(self.present["spectrum"], sq("spectrum"), 0.0)
        dt = None
        if ("texture" in q and "texture" in self.stored and w < 1.0
                and self.present["texture"].any()):
            dt = np.sqrt(np.maximum(sq("texture"), 0.0))
        return combine_distances(np.sqrt(np.maximum(s, 0.0)), dt, self.present.get("texture"), w)


def search(db, descriptors, *, k: int = 10, shape_weight: float = DEFAULT_SHAPE_WEIGHT,
           distance=None, exclude=None, exact: bool = False) -> tuple:
    """One query by example against a database (builds, or reuses cached, matrices).

    Parameters
    ----------
    db : surfidx.db.catalog.Catalog
    descriptors : dict of str -> (d_k,) array_like
        The query's descriptors, e.g. ``ProcessedModel.descriptors`` (drop ``"texture"`` when the
        query has no colour) or :meth:`Database.get_descriptors`.
    k, shape_weight, distance, exclude
        As in :meth:`SearchIndex.query`.
    exact : bool
        As in :class:`SearchIndex`.

    Returns
    -------
    ids : (k,) int64
    distances : (k,) float64
    """
    return SearchIndex(db, exact=exact).query(descriptors, k=k, shape_weight=shape_weight,
                                              distance=distance, exclude=exclude)
