"""The one Python API of a model database: :class:`Database` (``surfidx.Database``) is
:class:`surfidx.db.catalog.Catalog` with the calls the database commands make: :meth:`ingest`
(files, folders, models in memory), :meth:`query`, :meth:`get`, :meth:`get_sfz`,
:meth:`export` (besides the store's own ``remove``, ``rename``, ``tag``, ``untag``,
``list_models``).

>>> db = surfidx.Database.open("shapes.db")                             # doctest: +SKIP
>>> db.ingest(["scans/"])                  # as many workers as cores                                     # doctest: +SKIP
>>> db.query("bunny", k=5)                                               # doctest: +SKIP
>>> db.export("bunny", "bunny.glb", bits_per_surfel=2)                   # doctest: +SKIP

It sits above both the store (:mod:`surfidx.db`, which :mod:`ingest` writes through) and the
bulk runner (:mod:`ingest`, which :meth:`Database.ingest` drives), so imports run one way:
``surfidx.db`` ← ``ingest`` ← ``surfidx.database``.
"""

from __future__ import annotations

import functools
import os
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .errors import DatabaseError, InputError, SurfidxError
from .io.files import pair_texture
from .pipeline import unit_of_work
from .validate import accepts_keyword
from .db.catalog import LATEST_SQL, Catalog, is_storage_failure

__all__ = ["Database", "QueryExample"]

#: Most superseded versions a query skips by widening the index search (k + their count);
#: beyond, it ranks the latest versions by the exact distance read by id.
_WIDEN_MAX = 1000



@dataclass(frozen=True)
class QueryExample:
    """A query's example, described: what :meth:`Database.query` compares with the stored models.

    Attributes
    ----------
    id : int or None
        The stored model's id when the example is stored (by id, name or content hash).
    name : str
    has_color : bool
    descriptors : dict of str -> (d,) float32
        Descriptor vectors by kind, as an ingest stores them.
    thumbnail : bytes or None
        PNG of the example (a stored model's thumbnail, or one drawn of a file's surfels).
    virtual_share : float
        Share of the closed surface's area the topology repair added (0 for a model it left
        alone): what tells a partial scan (:func:`surfidx.describe.is_partial`).
    """

    id: int | None
    name: str
    has_color: bool
    descriptors: dict
    thumbnail: bytes | None = None
    virtual_share: float = 0.0


class Database(Catalog):
    """A surfidx model database with the one-call API (see the module notes); opened as
    :class:`surfidx.db.catalog.Catalog` is (``Database.open(path)``, ``readonly=``...)."""

    def ingest(self, models, *, workers: int | None = None, bits_per_surfel: float | None = None,
               options=None, name=None, tags=(), processor=None, progress: bool = False,
               allow_outside_textures: bool = False, replace=None, keep_original: bool = False,
               **run_options):
        """Process and store models: files, folders (recursively) or models in memory.

        Parameters
        ----------
        models : str, os.PathLike, model in memory, or a sequence of them
            Files and folders as for ``surfidx ingest`` (:func:`ingest.run`: resumable, skipping
            what is stored), and models in memory (a ``SurfelSet``, ``(vertices, faces[,
            colours])``, a ``trimesh.Trimesh``: :func:`surfidx.io.as_surfels`), processed here.
        workers : int, optional
            Worker processes for the files (default: as many as the machine's cores,
            :func:`ingest.run`).
        bits_per_surfel : float, optional
            Full rate of the stored streams (default ``options.codec.bits_per_surfel``).
        options : surfidx.options.ProcessOptions, optional
            Every setting of the processing (:func:`surfidx.pipeline.process_model`).
        name : str, optional
            Name of the model, when ``models`` is one file or one model (must be free).
        tags : str or sequence of str
            Tags given to every model stored.
        processor : callable, optional
            As for :func:`ingest.run` (default :func:`surfidx.pipeline.process_model`).
        progress : bool
            A progress bar on stderr.
        allow_outside_textures : bool
            As for :func:`surfidx.read_surfels`.
        replace : int or str, optional
            A stored model (name, ``NAME@N`` or id): store the one file or model given as its
            next version. Without it, a changed file read from the absolute path of a stored
            model becomes that model's next version (:meth:`add`).
        keep_original : bool
            Also store each new model's original files, deduplicated (files only; see
            :func:`ingest.run`).
        **run_options
            Further keywords of :func:`ingest.run` (``scheduler``, ``retries``, ``batch``...).

        Returns
        -------
        ingest.IngestSummary
            ``stored``, ``skipped``, ``failed``, ``ids``, ``errors`` (``(path, message)``).

        Raises
        ------
        InputError
            ``name`` with several models, a path that does not exist, a folder holding no
            supported file.
        DatabaseError
            The database cannot be written (the run stops).
        """
        import ingest as _ingest

        from .geometry.surfels import SurfelSet

        items = [models] if isinstance(models, (str, os.PathLike, tuple, np.ndarray,
                                                SurfelSet)) or not hasattr(models, "__iter__") \
            or type(models).__module__.startswith("trimesh") else list(models)
        paths = [m for m in items if isinstance(m, (str, os.PathLike))]
        memory = [m for m in items if not isinstance(m, (str, os.PathLike))]
        if name is not None and len(items) != 1:
            raise InputError(f"name= names one model; {len(items)} were given")
        if replace is not None and len(items) != 1:
            raise InputError(f"replace= stores one model as a new version; {len(items)} were "
                             "given")
        tags = [] if not tags else self._tags_of(tags)
        from .options import ProcessOptions

        if options is not None and not isinstance(options, ProcessOptions):
            raise InputError(f"options must be a ProcessOptions, got {type(options).__name__}")
        if bits_per_surfel is None:
            bits_per_surfel = (options or ProcessOptions()).codec.bits_per_surfel
        elif options is not None:
            options = options.updated(**{"codec.bits_per_surfel": float(bits_per_surfel)})
        summary = None
        if paths:
            summary = _ingest.run(paths, db=self, workers=workers,
                                  bits_per_surfel=bits_per_surfel, options=options,
                                  processor=processor, progress=progress, name=name, tags=tags,
                                  allow_outside_textures=allow_outside_textures,
                                  replace=replace, keep_original=keep_original, **run_options)
        if memory:
            if replace is not None:
                self.resolve(replace)
            proc = _ingest.resolve_processor(processor)
            run = summary or _ingest.IngestSummary(run_id=self.start_run(
                ["<memory>"], workers=1, bits_per_surfel=bits_per_surfel))
            for i, model in enumerate(memory):
                label = f"<memory model {i}>"
                try:
                    extra = {"name": name} if name is not None else {}
                    if options is not None and accepts_keyword(proc, "options"):
                        extra["options"] = options
                    processed = proc(model, bits_per_surfel=bits_per_surfel, **extra)
                    if self.has_hash(processed.content_hash):
                        run.skipped += 1
                        continue
                    with self.transaction():
                        mid = self.add(processed, exact_name=name is not None,
                                       replace=replace)
                        if tags:
                            self.tag(mid, tags)
                    run.ids.append(mid)
                    run.stored += 1
                except SurfidxError as exc:
                    if is_storage_failure(exc):
                        raise
                    run.failed += 1
                    run.errors.append((label, str(exc)))
                    self.record_error(run.run_id, label, str(exc))
            self.finish_run(run.run_id, stored=run.stored, skipped=run.skipped,
                            failed=run.failed)
            summary = run
        if summary is None:
            raise InputError("give at least one model file, folder or model to ingest")
        return summary

    def load(self, id_or_name):
        """Read a stored model back as a :class:`surfidx.pipeline.ProcessedModel`.

        ``timings`` are not stored and come back empty; ``quality`` holds the three PSNR keys;
        ``source`` is the absolute path (``source_abs``) where one is stored, ``source_rel``
        the stored relative one.
        """
        from .pipeline import ProcessedModel
        from .db.catalog import QUALITY_KEYS

        rec = self.get_model(id_or_name)
        a = rec["asset"]
        return ProcessedModel(
            name=rec["name"], source=rec["source_abs"] or rec["source"],
            content_hash=rec["content_hash"],
            n_surfels=rec["n_surfels"], has_color=rec["has_color"], bbox=rec["bbox"],
            stream=self.get_stream(rec["id"]), format_version=a["format_version"],
            rate=a["bits_per_surfel"], quality={k: a[k] for k in QUALITY_KEYS},
            descriptors=self.get_descriptors(rec["id"]), thumbnail=self.get_thumbnail(rec["id"]),
            params=rec["params"], timings={}, source_rel=rec["source"],
            source_bytes=rec["source_bytes"], source_mtime=_posix(rec["source_mtime"]))

    def example(self, model, *, processor=None, describer=None, texture=None,
                allow_outside_textures: bool = False, thumbnail: bool = True,
                progress=None, options=None, partial: bool | None = None) -> QueryExample:
        """Describe a query's example once, for :meth:`query` (and a contact sheet's thumbnail).

        ``model`` is what :meth:`query` takes: a stored model's id or name, a model file, or a
        model in memory.

        A file or a model in memory is described by ``processor`` when one is given (a whole
        ingest's work, :func:`surfidx.pipeline.process_model`'s signature), else by
        ``describer`` (default :func:`surfidx.pipeline.describe_model`: map, resample and
        describe only; its ``thumbnail`` is of the input, drawn only when ``thumbnail``).
        ``progress`` goes to the describer (:mod:`surfidx.progress`), ``options`` (a
        :class:`surfidx.options.ProcessOptions`) to a processor or describer that takes it.
        ``partial=True`` describes a file or model in memory as a single-view scan, by
        :func:`surfidx.pipeline.describe_scan` (its views only, no spherical map), unless a
        processor or describer is given; with ``partial=None`` a file the repair finds partial
        is described so too when any stored model has views (what it is then compared with),
        mapped otherwise."""
        ref = model
        if isinstance(model, str):
            text = model.strip()
            if re.fullmatch(r"(?:id:)?\d+", text) and not Path(model).is_file():
                ref = int(text.removeprefix("id:"))
            elif text.startswith("id:"):
                raise InputError(f"{model!r} is not a model id; write id:N with an integer N")
            elif Path(model).is_file():
                ref = Path(model)
            else:
                try:
                    ref = int(self.resolve(model))
                except DatabaseError as exc:
                    if not exc.reason.startswith("no model named"):
                        raise                       # an ambiguous name, a damaged file
                    raise InputError("no such model file, and no stored model has this name",
                                     path=model) from None
        if isinstance(ref, (int, np.integer)) and not isinstance(ref, bool):
            rec = self.get_model(int(ref))
            topo = rec.get("topology") or {}
            return QueryExample(id=rec["id"], name=rec["name"], has_color=rec["has_color"],
                                descriptors=self.get_descriptors(rec["id"]),
                                thumbnail=self.get_thumbnail(rec["id"]),
                                virtual_share=float(topo.get("virtual_area_share") or 0.0))
        from .codec.options import DEFAULT_BITS_PER_SURFEL
        from .options import DEFAULT_THUMBNAIL_SIZE

        extra = {"allow_outside_textures": True} if allow_outside_textures else {}
        if options is not None and accepts_keyword(
                processor if processor is not None else unit_of_work(describer, "describe_model"), "options"):
            extra["options"] = options
        if processor is not None:
            proc = functools.partial(processor, bits_per_surfel=DEFAULT_BITS_PER_SURFEL)
        elif partial and describer is None:
            from .pipeline import describe_scan

            extra.pop("options", None)
            proc = functools.partial(describe_scan, options=options,
                                     thumbnail_size=DEFAULT_THUMBNAIL_SIZE if thumbnail else None,
                                     **({"progress": progress} if progress is not None else {}))
        else:
            if describer is None:
                extra["for_query"] = True       # the query's map (MapOptions.for_query)
                if partial is None and self._has_views():
                    # a scan found partial is compared by its views: no map needed
                    extra["partial_by_views"] = True
            proc = functools.partial(unit_of_work(describer, "describe_model"),
                                     thumbnail_size=DEFAULT_THUMBNAIL_SIZE if thumbnail else None,
                                     **({"progress": progress} if progress is not None else {}))
        try:
            if isinstance(ref, os.PathLike):
                if not Path(ref).is_file():
                    raise InputError("no such model file", path=ref)
                tex = texture if texture is not None else pair_texture(ref)
                processed = proc(str(ref), texture=tex, **extra)
            else:
                processed = proc(ref, **extra)
        except SurfidxError as exc:
            if exc.path is None and isinstance(ref, os.PathLike):
                raise type(exc)(exc.reason, path=ref) from exc
            raise
        row = self.conn.execute("SELECT id FROM models WHERE content_hash = ?",
                                (str(processed.content_hash),)).fetchone()
        vectors = processed.descriptors
        vectors = getattr(vectors, "vectors", vectors)       # a DescriptorSet, or a dict
        topo = getattr(processed, "topology", None) or {}
        return QueryExample(id=None if row is None else int(row[0]), name=processed.name,
                            has_color=processed.has_color, descriptors=dict(vectors),
                            thumbnail=processed.thumbnail,
                            virtual_share=float(topo.get("virtual_area_share") or 0.0))

    def query(self, model, *, k: int = 10, shape_weight: float | None = None,
              include_self: bool = False, processor=None, describer=None, texture=None,
              allow_outside_textures: bool = False, exact: bool = False,
              progress=None, options=None, tag=None, where: str | None = None,
              partial: bool | None = None, all_versions: bool = False) -> list:
        """The stored models most similar to ``model`` (:class:`surfidx.db.search.SearchIndex`).

        Parameters
        ----------
        model : int, str, os.PathLike, model in memory or QueryExample
            A stored model's id (``12`` or ``"id:12"``) or name, a model file or a model in
            memory (mapped, resampled and described as an ingest would, by
            :func:`surfidx.pipeline.describe_model`; nothing is coded or stored), or an
            example :meth:`example` described already.
        k : int
            Number of results.
        shape_weight : float, optional
            Weight of shape against texture distance (default
            :data:`surfidx.describe.distance.DEFAULT_SHAPE_WEIGHT`).
        include_self : bool
            Keep the query model itself among the results when it is stored (by default it is
            left out).
        processor : callable, optional
            Describe a file or model in memory by this ingest processor's whole work instead
            (a ``ProcessedModel``, as for :meth:`ingest`).
        describer : callable, optional
            Instead of :func:`surfidx.pipeline.describe_model` (same signature).
        texture, allow_outside_textures
            For a file or a model in memory (as for :meth:`ingest`).
        progress : callable, optional
            ``progress(stage, done, total)`` while a file or model in memory is described
            (:mod:`surfidx.progress`).
        options : surfidx.options.ProcessOptions, optional
            How a file or model in memory is read, mapped and described (as an ingest with
            these options would).
        exact : bool
            Scan every stored model, never the approximate index (:mod:`surfidx.db.ann`, used from
            :data:`surfidx.db.ann.DEFAULT_THRESHOLD` models on).
        tag : str or sequence of str, optional
            Only models carrying every one of these tags.
        where : str, optional
            Only models passing this filter on their stored figures
            (:func:`surfidx.db.filters.where_sql`, e.g. ``"surfels > 10000 and colour = true"``).
            Below :data:`surfidx.db.ann.DEFAULT_THRESHOLD` models (or with ``exact``) a filtered
            query ranks every passing model by the exact distance; from it on, the approximate
            index skips the others inside it (:meth:`surfidx.db.ann.AnnIndex.query`, all
            passing models ranked exactly when few pass).
        partial : bool, optional
            Whether the example is a single-view scan of part of an object: its views (a file
            is then described by :func:`surfidx.pipeline.describe_scan`, without the spherical
            map) are compared with the stored models' by
            :func:`surfidx.describe.views.partial_view_l2`; an example without views (stored
            by an older surfidx) by :func:`surfidx.describe.partial_l2`. Default: detected from
            the share of its surface the repair added (:func:`surfidx.describe.is_partial`,
            :attr:`QueryExample.virtual_share`).

        all_versions : bool
            Compare with every stored version, not only each model's latest.

        Returns
        -------
        list of dict
            ``{"id", "name", "version", "source", "distance"}``, nearest first.

        Raises
        ------
        InputError
            Neither a file nor a stored model, or a bad ``k``.
        DatabaseError
            No such stored model.
        """
        from .db.search import SearchIndex
        from .describe.distance import DEFAULT_SHAPE_WEIGHT

        ex = model if isinstance(model, QueryExample) else self.example(
            model, processor=processor, describer=describer, texture=texture,
            allow_outside_textures=allow_outside_textures, thumbnail=False, progress=progress,
            options=options, partial=partial)
        descriptors = dict(ex.descriptors)
        if not ex.has_color:
            descriptors.pop("texture", None)
        k = int(k)
        if k < 1:
            raise InputError(f"k must be at least 1, got {k}")
        from .describe.partial import is_partial, partial_l2

        if partial is None:
            partial = is_partial(ex.virtual_share)
        drop = None if include_self else ex.id
        w = DEFAULT_SHAPE_WEIGHT if shape_weight is None else shape_weight
        # rows past version 1: at least every superseded one, counted on a partial index
        older = 0 if all_versions else int(self.conn.execute(
            "SELECT count(*) FROM models WHERE version > 1").fetchone()[0])
        allowed = None
        if tag is not None or where is not None or older > _WIDEN_MAX:
            allowed = self.select_ids(tag=tag, where=where, all_versions=all_versions)
            older = 0
        by_views = partial and "views" in descriptors and self._has_views()
        if partial and "shape" not in descriptors and not by_views:
            raise InputError("no stored model has views (descriptors made before version 8), "
                             "and a scan described by its views alone has nothing else to "
                             "compare; run `surfidx redescribe`, or query with --complete")
        if by_views:
            ids, dist = self._view_search(descriptors["views"], allowed,
                                          k=k + (drop is not None) + older, shape_weight=w)
        elif allowed is not None and (exact or not self._approximate()):
            ids, dist = self._filtered_search(descriptors, allowed,
                                              k=k + (drop is not None), shape_weight=w,
                                              distance=partial_l2 if partial else None)
        else:
            # every version is indexed: k + (older versions) nearest hold the k nearest latest
            ids, dist = self._search_index(SearchIndex, exact=exact).query(
                descriptors, k=k + (drop is not None) + older, shape_weight=w,
                distance=partial_l2 if partial else None, allowed=allowed)
        rows = []
        for i, d in zip(ids.tolist(), dist.tolist()):
            if i == drop or len(rows) == k:
                continue
            rec = self.conn.execute(f"SELECT name, version, source, {LATEST_SQL} FROM models m "
                                    "WHERE id = ?", (i,)).fetchone()
            if older and not rec[3]:
                continue
            rows.append({"id": int(i), "name": rec[0], "version": int(rec[1]), "source": rec[2],
                         "distance": float(d)})
        return rows

    def _has_views(self) -> bool:
        """Whether any stored model has ``views`` descriptors (what a partial query compares)."""
        return self.conn.execute(
            "SELECT 1 FROM descriptors WHERE kind = 'views' LIMIT 1").fetchone() is not None

    def _approximate(self) -> bool:
        """Whether :meth:`query` searches through the approximate index (the model count is at
        :data:`surfidx.db.ann.DEFAULT_THRESHOLD` or above), told without loading anything."""
        from .db.ann import DEFAULT_THRESHOLD

        kept = self.__dict__.get("_kept_search")
        return (kept is not None and kept.still_approximate()) or \
            self.count() >= DEFAULT_THRESHOLD

    def _view_search(self, views, allowed, *, k, shape_weight):
        """The ``k`` nearest stored models (of the ids ``allowed``; None: all) to a partial
        query's views by :func:`surfidx.describe.views.partial_view_l2`, the ranking expanded
        by the first match's complete-model distances (:func:`surfidx.describe.views.
        expand_by_first`), ties by id."""
        from .describe.views import expand_by_first, partial_view_l2

        if allowed is None:
            allowed = np.asarray([r[0] for r in self.conn.execute(
                "SELECT DISTINCT model_id FROM descriptors WHERE kind = 'views'")], np.int64)
        if allowed.size == 0:
            return np.zeros(0, np.int64), np.zeros(0)
        ids, stored, present = self.descriptor_rows(allowed, ("views",))
        if ids.size == 0:
            return np.zeros(0, np.int64), np.zeros(0)
        dist = partial_view_l2({"views": views}, stored, present)
        if np.isfinite(dist).any():
            first = ids[np.lexsort((ids, dist))[0]]
            dist = expand_by_first(dist, self._first_distances(ids, first,
                                                               shape_weight=shape_weight))
        order = np.lexsort((ids, dist))[:k]
        return ids[order], dist[order]

    def _first_distances(self, ids, first, *, shape_weight):
        """(n,) :func:`surfidx.describe.weighted_l2` of the stored model ``first`` to each
        stored model of ``ids`` by their complete-model descriptors (``inf``: none stored)."""
        from .describe.distance import DEFAULT_KINDS, weighted_l2

        out = np.full(len(ids), np.inf)
        have, stored, present = self.descriptor_rows(ids, DEFAULT_KINDS)
        at = np.searchsorted(have, first)
        if at == have.size or have[at] != first:
            return out
        query = {kind: s[at] for kind, s in stored.items() if present[kind][at]}
        d = weighted_l2(query, stored, present, shape_weight=shape_weight)
        out[np.searchsorted(ids, have)] = d
        return out

    def _search_index(self, make, *, exact: bool):
        """The search of :meth:`query`: an index on the approximate path is kept for the next
        query (opening its graphs takes time in proportion to the models; it follows changes of the
        database itself, :meth:`SearchIndex.still_approximate`); the exact scan is set up per
        query (its matrices are not followed)."""
        kept = self.__dict__.get("_kept_search")
        if not exact and kept is not None and kept.still_approximate():
            return kept
        index = make(self, exact=exact)
        if not exact:
            self.__dict__["_kept_search"] = index if index.approximate else None
        return index

    def _filtered_search(self, descriptors, allowed, *, k, shape_weight, distance=None):
        """The ``k`` nearest of the models ``allowed`` (ids) by the exact distance (``distance``,
        with :func:`surfidx.describe.distance.weighted_l2`'s signature; that one by default),
        read by id."""
        from .describe.distance import DEFAULT_KINDS, check_shape_weight, weighted_l2

        w = check_shape_weight(shape_weight)
        kinds = [kd for kd in DEFAULT_KINDS if kd in descriptors]
        if allowed.size == 0 or "shape" not in kinds:
            return np.zeros(0, np.int64), np.zeros(0)
        ids, stored, present = self.descriptor_rows(allowed, kinds)
        held = [kd for kd in kinds if stored[kd].shape[1] > 0]     # a kind no model holds: out
        dist = (distance or weighted_l2)({kd: descriptors[kd] for kd in held},
                           {kd: stored[kd] for kd in held}, {kd: present[kd] for kd in held},
                           shape_weight=w)
        order = np.lexsort((ids, dist))[:k]          # ties by id: the same order every run
        return ids[order], dist[order]

    def get_sfz(self, model, *, bits_per_surfel: float | None = None) -> bytes:
        """A stored model's stream as a ``.sfz`` file, truncated to ``bits_per_surfel`` (over
        the stored input surfel count; default: all of it).

        Raises
        ------
        InputError
            A rate whose budget does not hold the header.
        DatabaseError
            No such model.
        """
        from .codec import max_file_bytes
        from .codec.container import truncate

        mid = self.resolve(model)
        stream = self.get_stream(mid)
        if bits_per_surfel is None:
            return stream
        n = self.get_model(mid)["n_surfels"]
        return truncate(stream, max_file_bytes(bits_per_surfel, int(n)),
                        path=f"model {mid}")

    def get(self, model, *, bits_per_surfel: float | None = None, level: int | None = None,
            mesh: bool = False, max_surfels: int | None = None,
            max_vertices: int | None = None, texture: bool = False,
            texture_size: int | None = None, decoder=None):
        """Decode a stored model.

        Parameters
        ----------
        model : int or str
            Id or name.
        bits_per_surfel : float, optional
            Serve the stream truncated to this rate (default: all of it).
        level : int, optional
            Grid level of the output; default the stream's own, or a coarser one at the
            rates where the encoder measured that it is closer to the input
            (:func:`surfidx.pipeline.output_level`).
        mesh : bool
            A :class:`~surfidx.TriangleMesh` on the grid instead of surfels.
        max_surfels : int, optional
            As for :func:`surfidx.codec.decode`.
        max_vertices : int, optional
            At most this many vertices (surfels): the decoded mesh simplified
            (:func:`surfidx.codec.decode`).
        texture, texture_size
            A mesh's colour as a texture baked on the grid's atlas, and the image's side
            (:func:`surfidx.codec.decode`).
        decoder : callable, optional
            Instead of :func:`surfidx.codec.decode`.

        Returns
        -------
        SurfelSet or TriangleMesh
            Named after the model; ``to_trimesh()`` converts either (a ``trimesh.PointCloud``
            or a ``trimesh.Trimesh``).
        """
        mid = self.resolve(model)
        stream = self.get_stream(mid)
        name = self.get_model(mid)["name"]
        options = {} if level is None else {"level": level}
        if mesh:
            options["mesh"] = True
        if max_surfels is not None:
            options["max_surfels"] = max_surfels
        if max_vertices is not None:
            options["max_vertices"] = max_vertices
        if texture:
            options["texture"] = True
        if texture_size is not None:
            options["texture_size"] = texture_size
        if decoder is None:
            from .codec import decode as decoder

            options["path"] = f"model {mid}"
        out = decoder(stream, bits_per_surfel=bits_per_surfel, **options)
        out.name = name
        return out

    def export_many(self, models=None, folder=".", *, tag=None, format: str = "glb",
                    thumbnails: bool = False, **options) -> tuple:
        """Write several stored models into ``folder``, one file each named after the model
        (``NAME.FORMAT``; ``NAME.png`` for thumbnails): the batch form of :meth:`export`.

        A model that cannot be written is reported and the others are still written, as an
        ingest goes on past a file it cannot read.

        Parameters
        ----------
        models : sequence of int or str, optional
            Ids or names; with neither ``models`` nor ``tag``, every stored model.
        folder : str or os.PathLike
            Created when missing.
        tag : str or sequence of str, optional
            Also every model carrying all of these tags.
        format : {"glb", "obj", "ply", "sfz"}
            The files' format (for ``thumbnails``, PNG whatever this says).
        thumbnails : bool
            Write each model's stored thumbnail (PNG) instead of the model.
        **options
            Keywords of :meth:`export` (``bits_per_surfel``, ``level``, ``max_vertices``...).

        Returns
        -------
        written : list of dict
            :meth:`export`'s record of each file written (for thumbnails: ``id``, ``name``,
            ``output``, ``bytes``).
        failed : list of (str, str)
            ``(model, message)`` of each model that could not be written.

        Raises
        ------
        InputError
            An unknown format, or a selection that names no model.
        """
        from .io import write_atomic

        fmt = str(format).lower().lstrip(".")
        if fmt not in ("glb", "obj", "ply", "sfz"):
            raise InputError(f"format must be one of glb, obj, ply, sfz; got {format!r}")
        ids = [self.resolve(m) for m in (models or [])]
        if tag is not None:
            ids += [r["id"] for r in self.list_models(tag=tag)]
        if not models and tag is None:
            ids = [r["id"] for r in self.list_models()]
        ids = list(dict.fromkeys(ids))
        if not ids:
            raise InputError("the selection names no stored model (give ids, names, a tag, "
                             "or every model)")
        out_dir = Path(folder)
        out_dir.mkdir(parents=True, exist_ok=True)
        written, failed = [], []
        for mid in ids:
            name = self.get_model(mid)["name"]
            stem = _file_stem(name, mid)
            try:
                if thumbnails:
                    png = self.get_thumbnail(mid)
                    target = out_dir / f"{stem}.png"
                    write_atomic(target, lambda tmp: tmp.write_bytes(png))
                    written.append({"id": mid, "name": name, "output": str(target),
                                    "bytes": len(png)})
                else:
                    written.append(self.export(mid, out_dir / f"{stem}.{fmt}", format=fmt,
                                               **options))
            except SurfidxError as exc:
                if is_storage_failure(exc):
                    raise
                failed.append((name, str(exc)))
        return written, failed

    def export(self, model, path, *, format: str | None = None,
               bits_per_surfel: float | None = None, level: int | None = None,
               mesh: bool | None = None, max_surfels: int | None = None,
               max_vertices: int | None = None, text: bool = False,
               texture: bool | None = None, texture_size: int | None = None,
               image_format: str = "png", image_quality: int | None = None,
               decoder=None) -> dict:
        """Write a stored model to a file: PLY, OBJ, GLB (decoded) or SFZ (the stream).

        Parameters
        ----------
        model : int or str
        path : str or os.PathLike
        format : {"ply", "obj", "glb", "sfz"}, optional
            Default from the suffix of ``path``; another suffix is an error.
        bits_per_surfel, level, max_surfels, max_vertices, decoder
            As for :meth:`get` (``sfz``: the stream truncated to the rate).
        mesh : bool, optional
            Decode to the grid mesh (default for OBJ and GLB) or to surfels (default for PLY).
        text : bool
            ASCII PLY.
        texture : bool, optional
            Write a mesh's colour as a texture baked on the grid's atlas (OBJ: with a ``.mtl``
            and the image beside it; GLB: ``TEXCOORD_0`` and a ``baseColorTexture``), or as
            vertex colours (False). Default (None): a texture for an OBJ or GLB mesh without
            ``max_vertices`` (a model without colour gets neither), else vertex colours.
        texture_size : int, optional
            The image's side in texels (:func:`surfidx.codec.decode`).
        image_format : {"png", "jpeg", "webp"}
            The image's format.
        image_quality : int, optional
            JPEG or WebP quality, 1 … 100 (:func:`surfidx.io.texture.check_image_options`).

        Returns
        -------
        dict
            ``id``, ``name``, ``output``, ``format``, ``bytes`` (sfz) or ``surfels``
            (and ``faces`` for a mesh), ``level`` (the grid level decoded, before any
            simplification to ``max_vertices``), ``bits_per_surfel``, ``texture`` (the
            image's side, or None for vertex colours; decoded models only).
        """
        from .io import output_format, write_atomic, write_model
        from .io.texture import check_image_options

        fmt = output_format(path, format, allowed=("ply", "obj", "glb", "sfz"))
        image_format, image_quality = check_image_options(image_format, image_quality)
        mid = self.resolve(model)
        name = self.get_model(mid)["name"]
        out = {"id": mid, "name": name, "output": str(path), "format": fmt,
               "bits_per_surfel": bits_per_surfel}
        if fmt == "sfz":
            data = self.get_sfz(mid, bits_per_surfel=bits_per_surfel)
            write_atomic(path, lambda tmp: tmp.write_bytes(data))
            out["bytes"] = len(data)
            return out
        from .pipeline import export_texture, output_level

        as_mesh = fmt in ("obj", "glb") if mesh is None else bool(mesh)
        textured = export_texture(texture, fmt=fmt, mesh=as_mesh, max_vertices=max_vertices,
                                  texture_size=texture_size)
        decoded = self.get(mid, bits_per_surfel=bits_per_surfel, level=level, mesh=as_mesh,
                           max_surfels=max_surfels, max_vertices=max_vertices,
                           texture=textured, texture_size=texture_size, decoder=decoder)
        write_model(decoded, path, format=fmt, text=text, image_format=image_format,
                    image_quality=image_quality)
        n = len(decoded.vertices) if hasattr(decoded, "vertices") else len(decoded)
        image = getattr(decoded, "texture", None)
        if level is None:
            level = output_level(self.get_stream(mid), bits_per_surfel=bits_per_surfel)
        out.update({"surfels": int(n), "level": level,
                    "texture": None if image is None else int(image.shape[0])})
        if as_mesh and hasattr(decoded, "faces") and decoded.faces is not None:
            out["faces"] = int(len(decoded.faces))
        return out


    def export_original(self, model, folder, *, subfolder: bool = False) -> dict:
        """Write a model version's original files (``ingest --keep-original``) into ``folder``
        byte for byte, with the relative layout they were read in (the model file beside its
        material library and textures), each written atomically and checked against its SHA-256.

        Parameters
        ----------
        model : int or str
            Id, name (the latest version) or ``NAME@N``.
        folder : str or os.PathLike
            Created when missing; files in it with the same names are replaced.
        subfolder : bool
            Write into ``folder/NAME`` (the model's name made file-safe) instead.

        Returns
        -------
        dict
            ``id``, ``name``, ``version``, ``output`` (the folder), ``files`` (``path``,
            ``bytes``, ``role`` of each file written; the source file first).

        Raises
        ------
        InputError
            The version has no original (it was ingested without ``--keep-original``).
        DatabaseError
            A stored file does not match its SHA-256 (the database is damaged), or a stored
            path that would leave ``folder``.
        """
        import hashlib

        from .io import write_atomic

        mid = self.resolve(model)
        rec = self.conn.execute("SELECT name, version FROM models WHERE id = ?", (mid,)).fetchone()
        files = self.original_files(mid)
        if not files:
            raise InputError(f"model {rec[0]}@{rec[1]} (id {mid}) has no original: it was "
                             "ingested without --keep-original")
        out_dir = Path(folder) / _file_stem(rec[0], mid) if subfolder else Path(folder)
        out_dir.mkdir(parents=True, exist_ok=True)
        written = []
        for f in files:
            target = out_dir.joinpath(*Path(f["path"]).parts)
            if Path(f["path"]).is_absolute() or ".." in Path(f["path"]).parts:
                raise DatabaseError(f"original file path {f['path']!r} of model {mid} leaves "
                                    "the output folder; the database is damaged", path=self.path)
            target.parent.mkdir(parents=True, exist_ok=True)

            def write(tmp, sha=f["sha256"]):
                h = hashlib.sha256()
                with open(tmp, "wb") as fh:
                    for piece in self.original_pieces(sha):
                        h.update(piece)
                        fh.write(piece)
                if h.hexdigest() != sha:
                    raise DatabaseError(f"original file {f['path']!r} of model {mid} does not "
                                        "match its SHA-256; the database is damaged",
                                        path=self.path)

            write_atomic(target, write)
            written.append({"path": f["path"], "bytes": f["bytes"], "role": f["role"]})
        return {"id": mid, "name": rec[0], "version": int(rec[1]), "output": str(out_dir),
                "files": written}


def _posix(text):
    """POSIX seconds of the database's ISO 8601 UTC text (None stays None)."""
    if text is None:
        return None
    import datetime as dt

    t = dt.datetime.fromisoformat(str(text).removesuffix("Z"))
    return t.replace(tzinfo=dt.timezone.utc).timestamp()


def _file_stem(name: str, mid: int) -> str:
    """A model's name as a file name in any folder: path separators and control characters
    become ``_``, leading dots are dropped; an empty result becomes ``model-ID``."""
    stem = re.sub(r"[\\/\x00-\x1f\x7f]", "_", name).lstrip(".") or f"model-{mid}"
    return stem[:200]
