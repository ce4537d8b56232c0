"""The per-model work unit shared by the CLI, bulk ingestion (process pool) and the distributed
executor: read → map to the sphere → encode → describe → thumbnail, as one picklable result
(:func:`process_model`); and the query's share of it, read → map → resample → describe
(:func:`describe_model`), whose descriptors are those an ingest stores."""

from __future__ import annotations

import hashlib
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .errors import SurfidxError

__all__ = ["ProcessedModel", "DescribedModel", "content_hash", "process_model", "describe_model",
           "describe_scan", "scan_surface", "export_texture", "describe_stream", "redescribe",
           "output_level", "combine_descriptors", "unit_of_work"]


@dataclass
class ProcessedModel:
    """Everything the database stores for one model (picklable, numpy + bytes only).

    Attributes
    ----------
    name : str
        Model name (file stem).
    source : str
        Path the model was read from (as given, resolved to absolute).
    content_hash : str
        SHA-256 hex of the model file's bytes and of its texture image's bytes, if any.
    n_surfels : int
        Surfels of the input (the rate denominator).
    has_color : bool
    bbox : (2, 3) float64
        Minimum and maximum corner of the input's bounding box.
    stream : bytes
        The compressed asset: a complete container file holding the embedded bitstream.
    format_version : int
        Bitstream container format version of ``stream``.
    rate : float
        Bits per input surfel of ``stream`` (whole file counted).
    quality : dict of str -> float or None
        ``psnr_d1``, ``psnr_d2``, ``psnr_y`` (None without colour) of ``stream`` decoded at full
        rate against the input.
    descriptors : dict of str -> (d,) float32
        Descriptor vectors by kind (``"shape"``, ``"texture"``, ``"spectrum"``).
    thumbnail : bytes
        PNG image of the decoded model.
    params : dict
        JSON-serialisable parameters that produced the record (grid level, map method, codec
        version, descriptor lmax and normalisation, ...).
    timings : dict of str -> float
        Seconds per stage.
    topology : dict or None
        What topology repair added (:meth:`surfidx.topology.Model.summary`: ``parts``,
        ``parts_dropped``, ``holes_filled``, ``handles_cut``, ``pinched_vertices``,
        ``virtual_surfels``, ``virtual_area_share``, ...), stored in ``model_topology``; None
        for a model stored as it was read.
    source_rel : str or None
        ``source`` relative to the folder an ingest was given (set by the ingest; None: the
        database stores the file's name).
    source_bytes : int or None
        Size of the file when it was hashed (set by the ingest).
    source_mtime : float or None
        Its modification time then, POSIX seconds (set by the ingest).

    Notes
    -----
    The geometry is in :attr:`stream`: :func:`surfidx.codec.decode` of it gives a
    :class:`~surfidx.SurfelSet` (or with ``mesh=True`` a :class:`~surfidx.TriangleMesh`), whose
    ``to_trimesh()`` gives a trimesh object.
    """

    name: str
    source: str
    content_hash: str
    n_surfels: int
    has_color: bool
    bbox: np.ndarray
    stream: bytes
    format_version: int
    rate: float
    quality: dict
    descriptors: dict
    thumbnail: bytes
    params: dict = field(default_factory=dict)
    timings: dict = field(default_factory=dict)
    topology: dict | None = None
    source_rel: str | None = None
    source_bytes: int | None = None
    source_mtime: float | None = None


def content_hash(path, *, texture=None) -> str:
    """SHA-256 hex digest of a model file (and of its texture image when one is given).

    Parameters
    ----------
    path : str or os.PathLike
    texture : str or os.PathLike, optional
    """
    h = hashlib.sha256()
    for p in (path, texture):
        if p is None:
            continue
        with open(Path(p), "rb") as fh:
            for chunk in iter(lambda: fh.read(1 << 20), b""):
                h.update(chunk)
    return h.hexdigest()


def _png_bytes(image: np.ndarray) -> bytes:
    import io

    from PIL import Image

    buf = io.BytesIO()
    Image.fromarray(image).save(buf, format="PNG", optimize=True)
    return buf.getvalue()


def _identity(path, surfels, texture, name):
    """The name, source and content hash of a model (a file's, or one in memory)."""
    from .io import model_hash

    if not isinstance(path, (str, os.PathLike)):
        label = name or getattr(path, "name", None) or surfels.name or "model"
        return str(label), "<memory>", model_hash(surfels)
    return (str(name or Path(path).stem), str(Path(path).resolve()),
            content_hash(path, texture=texture))


def combine_descriptors(sets, weights):
    """One descriptor set for a model of several parts: the parts' vectors averaged.

    Each kind's vector is the mean of the parts' vectors weighted by ``weights`` (their surfel
    counts): a large part dominates as it dominates the surface, a part of 1 % moves the vectors
    by about 1 % of its difference. The parts' vectors are energies and distributions of
    normalised layers (scale, position and orientation removed per part), so their mean is a
    vector of the same kind, comparable with a one-part model's by the same distance; a kind
    that only some parts have (``texture``: colour) is averaged over those. One part: its own set,
    unchanged.

    Parameters
    ----------
    sets : sequence of surfidx.describe.descriptors.DescriptorSet
    weights : sequence of float
        Positive, one per set.

    Returns
    -------
    surfidx.describe.descriptors.DescriptorSet
        ``params`` of the first set plus ``parts`` (the count) when there are several.

    Raises
    ------
    InputError
        When ``sets`` is empty, the counts differ, a weight is not positive or the sets' params
        differ.
    """
    from .errors import InputError
    from .describe.descriptors import DescriptorSet

    sets, w = list(sets), np.asarray(weights, np.float64)
    if not sets or len(sets) != len(w):
        raise InputError(f"combine_descriptors needs one weight per descriptor set and at least "
                         f"one set, got {len(sets)} sets and {len(w)} weights")
    if not np.all(np.isfinite(w) & (w > 0)):
        raise InputError(f"descriptor weights must be positive, got {w.tolist()}")
    if len(sets) == 1:
        return sets[0]
    if any(s.params != sets[0].params for s in sets[1:]):
        raise InputError("the parts' descriptors were made with different conventions "
                         "(params); describe every part with the same lmax")
    vectors = {}
    for kind in dict.fromkeys(k for s in sets for k in s.vectors):
        have = [(s.vectors[kind], wi) for s, wi in zip(sets, w) if kind in s.vectors]
        ww = np.array([wi for _, wi in have])
        v = sum(np.asarray(x, np.float64) * wi for x, wi in have) / ww.sum()
        vectors[kind] = v.astype(np.float32)
    return DescriptorSet(vectors=vectors, params=dict(sets[0].params, parts=len(sets)))


def _read(timings, progress, path, texture, samples, allow_outside_textures, repair):
    """The model read (:func:`surfidx.io.read_geometry`) and repaired to closed genus-0 parts
    (:func:`surfidx.topology.repair_model`), together timed as the ``read`` stage; when
    anything was repaired, the CPU seconds of the reading and the repair together in
    ``timings["read_cpu"]``."""
    import time

    from .io import read_geometry
    from .topology import repair_model

    def read_and_repair():
        geometry = read_geometry(path, texture=texture, samples=samples,
                                 allow_outside_textures=allow_outside_textures)
        return repair_model(geometry, samples=samples, options=repair,
                            path=Path(path) if isinstance(path, (str, os.PathLike)) else None)

    cpu = time.process_time()
    model = _timed(timings, "read", progress, read_and_repair)
    if model.repaired:
        timings["read_cpu"] = time.process_time() - cpu
    return model


def _reference(model):
    """The surfels a decoded model is compared with: the scan's own (virtual ones left out)."""
    s = model.surfels
    if s.patch is None or not s.virtual.any():
        return s
    return s.subset(~s.virtual)


def _timed(timings, stage, progress, fn, *args, **kwargs):
    """``fn(*args, **kwargs)``, its wall time in ``timings[stage]``, ``stage`` reported to
    ``progress`` as it starts and ends."""
    import time

    from .progress import report

    report(progress, stage, 0, 1)
    t0 = time.perf_counter()
    out = fn(*args, **kwargs)
    timings[stage] = time.perf_counter() - t0
    report(progress, stage, 1, 1)
    return out


def process_model(path, *, options=None, bits_per_surfel: float | None = None, texture=None,
                  samples: int | None = None, level: int | None = None,
                  method: str | None = None, thumbnail_size: int | None = None,
                  lmax: int | None = None, allow_outside_textures: bool = False,
                  name: str | None = None, progress=None) -> ProcessedModel:
    """Read, map, encode, evaluate, describe and draw one model.

    Parameters
    ----------
    path : str or os.PathLike, or a model in memory
        Any file :func:`surfidx.read_surfels` reads, or a model in memory
        (:func:`surfidx.io.as_surfels`: a ``SurfelSet``, ``(vertices, faces[, colours])``, a
        ``trimesh.Trimesh``...): its source is then ``"<memory>"`` and its content hash that of
        its surfels (:func:`surfidx.io.model_hash`). It is read by
        :func:`surfidx.io.read_geometry` and repaired by :func:`surfidx.topology.repair_model`:
        a closed genus-0 mesh as it is (the stream and descriptors of a plain read), any other
        mesh repaired into closed genus-0 parts whose virtual patches the stream codes as a mask
        (one part per piece, tiny pieces dropped with a warning); the descriptors describe the
        closed surface, all parts together (:func:`combine_descriptors`), the quality figures
        compare the decoded real surface with the scan's own surfels.
    options : surfidx.options.ProcessOptions, optional
        Every setting of the repair, map, codec and descriptors (default ``ProcessOptions()``);
        the keywords below, when given, override its fields.
    bits_per_surfel : float, optional
        Full rate of the stored asset (``options.codec.bits_per_surfel``; lower rates are served
        by truncation).
    texture : str or os.PathLike, optional
        Texture image for an OBJ that names none.
    samples : int, optional
        Sample this many surfels uniformly over a mesh instead of one per vertex
        (``options.samples``).
    level : int, optional
        Grid level (``options.codec.level``; default from the surfel count).
    method : {"tutte", "mds"}, optional
        Spherical map (``options.map.method``).
    thumbnail_size : int, optional
        Thumbnail width and height in pixels (``options.thumbnail_size``).
    lmax : int, optional
        Largest SH degree of the descriptors (``options.describe.lmax``).
    allow_outside_textures : bool
        Use a texture an OBJ's MTL names outside the model's folder
        (:func:`surfidx.read_surfels`).
    name : str, optional
        The model's name (default: the file stem, or the in-memory model's name, else
        ``"model"``).
    progress : callable, optional
        ``progress(stage, done, total)`` at each stage boundary (:mod:`surfidx.progress`):
        ``read``, the map's (``map`` per level, ``figures``), ``resample``,
        ``transform``, ``code``, ``decode``, ``evaluate``, ``describe``, ``thumbnail``, in this
        order. It changes nothing in the result.

    Returns
    -------
    ProcessedModel
        Its thumbnail shows the decoded model upright, its up axis (``options.up``, else the
        file format's: :func:`surfidx.io.up_axis`) up, in a three-quarter view, or along its
        smallest principal axis when it is flat (:func:`surfidx.render.thumbnail_basis`);
        ``topology`` says what the repair added (None for a model stored as read);
        ``n_surfels`` counts every coded surfel, virtual included (the rate's denominator);
        ``params`` are the options as used (``options.to_dict()``, ``up`` the axis the
        thumbnail used), what the codec reports of each part
        (:meth:`surfidx.codec.encoder.Prepared.report`: grid level, map method, folds,
        weights), the descriptors' conventions and ``provenance``
        (:func:`surfidx.numerics.provenance`).

    Raises
    ------
    SurfidxError
        Unreadable file, a surface that cannot be stored (no triangle, a non-orientable piece:
        :class:`~surfidx.TopologyError` naming the file), a surface that cannot be mapped, or a
        rate below the header's size.
    """
    import time

    from .codec import CODEC_VERSION, PartsEncoder, decode
    from .describe.descriptors import describe_grid
    from .geometry.mesh import MAX_EDGE_RATIO
    from .geometry.metrics import evaluate
    from .io import up_axis
    from .numerics import provenance
    from .options import ProcessOptions

    opts = ProcessOptions.resolve(options, bits_per_surfel=bits_per_surfel, samples=samples,
                                  level=level, method=method, thumbnail_size=thumbnail_size,
                                  lmax=lmax)
    samples, size = opts.samples, opts.thumbnail_size
    timings = {}
    model = _read(timings, progress, path, texture, samples, allow_outside_textures,
                  opts.repair)
    surfels = model.surfels
    # one part: exactly Encoder's stream (PartsEncoder of one part is that part's Encoder)
    pe = PartsEncoder(list(model.parts), options=opts.codec, map_options=opts.map,
                      progress=progress,
                      face_patches=[model.face_patch(i) for i in range(len(model.parts))],
                      texture=model.texture)
    encoders = list(pe.encoders)
    for e in encoders:
        for k, v in e.setup_seconds.items():
            timings[k] = timings.get(k, 0.0) + v
    t0 = time.perf_counter()
    stream = pe.encode(opts.codec.bits_per_surfel, progress=progress)
    timings["encode"] = time.perf_counter() - t0
    decoded = _timed(timings, "decode", progress, decode, stream)
    q = _timed(timings, "evaluate", progress, evaluate, _reference(model), decoded)
    quality = {k: q[k] for k in ("psnr_d1", "psnr_d2", "psnr_y")}
    desc = _timed(timings, "describe", progress, lambda: combine_descriptors(
        [describe_grid(e.grid, e.level, lmax=opts.describe.lmax) for e in encoders],
        [len(p) for p in model.parts]))
    up = opts.up or up_axis(path)
    thumb = _thumbnail(timings, progress, decoded, up, size)
    reports = [e.prepared.report() for e in encoders]
    from_mesh = surfels.faces is not None and len(surfels.faces) > 0 and samples is None
    params = {**opts.to_dict(), "up": up, **reports[0],
              "folded": int(sum(r["folded"] for r in reports)),
              "max_edge_ratio": MAX_EDGE_RATIO if from_mesh else None,
              "texture": None if texture is None else str(texture),
              "descriptors": desc.params, "provenance": provenance()}
    if len(encoders) > 1:
        params["part_levels"] = [int(r["grid_level"]) for r in reports]
    label, source, digest = _identity(path, surfels, texture, name)
    return ProcessedModel(
        name=str(label), source=source, content_hash=digest, n_surfels=len(surfels),
        has_color=surfels.has_color, bbox=surfels.bounds, stream=stream,
        format_version=CODEC_VERSION, rate=8.0 * len(stream) / len(surfels), quality=quality,
        descriptors=desc.vectors, thumbnail=thumb, params=params, timings=timings,
        topology=model.summary() if model.repaired else None)


@dataclass
class DescribedModel:
    """What a query needs of a model that is not stored (:func:`describe_model`).

    Attributes
    ----------
    name, source, content_hash : str
        As :class:`ProcessedModel`'s (the hash finds the model when it is stored).
    n_surfels : int
    has_color : bool
    descriptors : surfidx.describe.descriptors.DescriptorSet
        The vectors and conventions an ingest of the model stores.
    grid_level : int
    thumbnail : bytes or None
        PNG of the input surfels (not of a decoded stream), when asked for.
    timings : dict of str -> float
        Wall seconds per stage (figures only).
    topology : dict or None
        What the topology repair added (:meth:`surfidx.topology.Model.summary`); None when the model
        was taken as it is.
    """

    name: str
    source: str
    content_hash: str
    n_surfels: int
    has_color: bool
    descriptors: object
    grid_level: int
    thumbnail: bytes | None = None
    timings: dict = field(default_factory=dict)
    topology: dict | None = None


def describe_model(path, *, options=None, texture=None, samples: int | None = None,
                   level: int | None = None, method: str | None = None,
                   lmax: int | None = None, allow_outside_textures: bool = False,
                   name: str | None = None, thumbnail_size: int | None = None,
                   partial_by_views: bool = False, for_query: bool = False,
                   progress=None) -> DescribedModel:
    """Read, map, resample and describe one model: what a query by example computes, nothing
    else (no coding, decoding, quality figures).

    It reads and repairs (:func:`surfidx.io.read_geometry`, :func:`surfidx.topology.repair_model`,
    as ingest does), maps and resamples as :func:`process_model` does (the map without the
    stress figure, the grid at the encoder's level: ``level``, else the map's ``grid_level``;
    colour when the surfels have it; each part on its own, combined by
    :func:`combine_descriptors`), so with the same arguments its descriptors are bit-equal to
    ``process_model(...).descriptors`` — but for a partial scan
    (:func:`surfidx.describe.is_partial`), whose ``views`` are those of its real surface from
    its camera (:func:`surfidx.describe.views.scan_views`), what a partial query compares.

    Parameters
    ----------
    path : str or os.PathLike, or a model in memory
        As for :func:`process_model`.
    options : surfidx.options.ProcessOptions, optional
        As for :func:`process_model` (its repair, map, codec level and describe settings are
        used; its ``thumbnail_size`` is not: a query draws no thumbnail unless asked).
    texture, samples, level, method, lmax, allow_outside_textures, name
        As for :func:`process_model`.
    thumbnail_size : int, optional
        Also draw a thumbnail of the input surfels this many pixels wide and high, in the view
        of a stored model's (upright, ``options.up`` or the format's up axis up).
    partial_by_views : bool
        Describe a scan found partial after its repair by its views alone, as
        :func:`describe_scan` does, without mapping it: what a partial query compares with a
        database that holds views (the map of a 10k-vertex view costs ten times its read).
    for_query : bool
        Map with a query's step counts (:meth:`surfidx.sphere.MapOptions.for_query`) and
        resample on a grid of level at most ``options.describe.query_level`` (unless ``level``
        is given): the descriptors find the stored models as well as an ingest's would, at
        about half the CPU, but are no longer bit-equal to ``process_model``'s.
    progress : callable, optional
        ``progress(stage, done, total)`` (:mod:`surfidx.progress`): ``read``, the map's
        (``map`` per level, ``figures``), ``resample``, ``describe`` and, with a
        thumbnail, ``thumbnail``.

    Returns
    -------
    DescribedModel

    Raises
    ------
    SurfidxError
        Unreadable file, a surface that cannot be mapped, a bad method.
    """
    import time

    from .describe.descriptors import describe_grid
    from .describe.partial import is_partial
    from .options import ProcessOptions
    from .codec.resample import resample
    from .sphere import parameterize

    opts = ProcessOptions.resolve(options, samples=samples, level=level, method=method,
                                  lmax=lmax)
    samples, level, lm = opts.samples, opts.codec.level, opts.describe.lmax
    map_options = opts.map.for_query() if for_query else opts.map
    timings = {}
    model = _read(timings, progress, path, texture, samples, allow_outside_textures,
                  opts.repair)
    partial = model.repaired and is_partial(model.summary()["virtual_area_share"])
    if partial and partial_by_views:
        return _described_by_views(model, timings, progress, path=path, texture=texture,
                                   name=name, options=opts, thumbnail_size=thumbnail_size)
    surfels = model.surfels
    sets, levels = [], []
    for part in model.parts:
        t0 = time.perf_counter()
        sphere_map = parameterize(part, stress=False, options=map_options, progress=progress)
        timings["map"] = timings.get("map", 0.0) + time.perf_counter() - t0
        grid_level = sphere_map.grid_level if level is None else level
        if for_query and level is None:
            grid_level = min(grid_level, opts.describe.query_level)
        grid = _timed(timings, "resample", progress, resample, part, sphere_map.points,
                      grid_level, color=part.has_color)
        d = _timed(timings, "describe", progress, describe_grid, grid, grid_level, lmax=lm)
        sets.append(d)
        levels.append(int(grid_level))
    desc = combine_descriptors(sets, [len(p) for p in model.parts])
    if partial:     # a single view: its own views, not the capped model's
        desc.vectors["views"] = _scan_view_vector(model)
    grid_level = levels[0]
    thumb = _input_thumbnail(timings, progress, surfels, path, opts, thumbnail_size)
    label, source, digest = _identity(path, surfels, texture, name)
    return DescribedModel(name=label, source=source, content_hash=digest,
                          n_surfels=len(surfels), has_color=surfels.has_color,
                          descriptors=desc, grid_level=int(grid_level), thumbnail=thumb,
                          timings=timings, topology=model.summary() if model.repaired else None)


def scan_surface(model):
    """(vertices, faces) of what a read model really holds: every part's real faces (the
    repair's virtual patches left out), stacked.

    Raises
    ------
    InputError
        A part without faces (points or surfels): a view needs a surface.
    """
    from .errors import InputError

    verts, faces, offset = [], [], 0
    for k, part in enumerate(model.parts):
        if part.faces is None:
            raise InputError("a query by a single view needs a surface with faces (a mesh or "
                             "meshed surfels); this one has points only: query it as a "
                             "complete model (query --complete)")
        fp = model.face_patch(k)
        f = part.faces if fp is None else part.faces[np.asarray(fp) < 0]
        verts.append(np.asarray(part.positions, np.float64))
        faces.append(f + offset)
        offset += len(part)
    return np.vstack(verts), np.vstack(faces)


def describe_scan(path, *, options=None, texture=None, samples: int | None = None,
                  allow_outside_textures: bool = False, name: str | None = None,
                  thumbnail_size: int | None = None, progress=None) -> DescribedModel:
    """Read a single-view scan and describe what it holds as views: what a partial query
    compares with the stored models' ``views`` (:func:`surfidx.describe.views.partial_view_l2`).

    The scan is read and repaired as :func:`describe_model` reads it (so its virtual share is
    known), but not mapped: its real faces (:func:`scan_surface`) are seen from the camera
    direction (:func:`surfidx.describe.views.scan_direction`), from directions tilted around
    it and from the opposite one, and described as a stored model's views are
    (:func:`surfidx.describe.views.scan_views`).

    Parameters
    ----------
    path, options, texture, samples, allow_outside_textures, name, thumbnail_size, progress
        As for :func:`describe_model` (only the read and repair settings of ``options``
        count).

    Returns
    -------
    DescribedModel
        ``descriptors`` holds one kind, ``views`` (the
        :func:`surfidx.describe.views.scan_views` flattened); ``grid_level`` is 0 (nothing is
        resampled).

    Raises
    ------
    SurfidxError
        Unreadable file, a scan without faces or of zero area.
    """
    from .options import ProcessOptions

    opts = ProcessOptions.resolve(options, samples=samples)
    timings = {}
    model = _read(timings, progress, path, texture, opts.samples, allow_outside_textures,
                  opts.repair)
    return _described_by_views(model, timings, progress, path=path, texture=texture, name=name,
                               options=opts, thumbnail_size=thumbnail_size)


def _described_by_views(model, timings, progress, *, path, texture, name, options,
                        thumbnail_size):
    """The :class:`DescribedModel` of a read scan by its views alone (:func:`describe_scan`)."""
    from .describe.descriptors import DescriptorSet, descriptor_params

    views = _timed(timings, "describe", progress, _scan_view_vector, model)
    desc = DescriptorSet({"views": views}, descriptor_params(lmax=options.describe.lmax))
    surfels = model.surfels
    thumb = _input_thumbnail(timings, progress, surfels, path, options, thumbnail_size)
    label, source, digest = _identity(path, surfels, texture, name)
    return DescribedModel(name=label, source=source, content_hash=digest,
                          n_surfels=len(surfels), has_color=surfels.has_color,
                          descriptors=desc, grid_level=0, thumbnail=thumb, timings=timings,
                          topology=model.summary() if model.repaired else None)


def _thumbnail(timings, progress, surfels, up, size):
    """PNG of ``surfels`` ``size`` pixels square in a stored model's view with the axis ``up``
    upwards, timed as ``thumbnail``."""
    from .render import THUMBNAIL, render

    return _timed(timings, "thumbnail", progress, lambda: _png_bytes(
        render(surfels, width=size, height=size, view=THUMBNAIL, up=up)))


def _input_thumbnail(timings, progress, surfels, path, options, size):
    """:func:`_thumbnail` of a query's input surfels, upright as an ingest of ``path`` would
    draw it (``options.up`` or the format's up axis); None without a size."""
    if size is None:
        return None
    from .io import up_axis

    return _thumbnail(timings, progress, surfels, options.up or up_axis(path), size)


def _scan_view_vector(model):
    """The views of what a read scan really holds (:func:`scan_surface`), flattened: the
    ``views`` descriptor of a partial query."""
    from .describe.views import scan_views

    return scan_views(*scan_surface(model)).ravel()


def output_level(stream: bytes, *, bits_per_surfel: float | None = None,
                 path=None) -> int | None:
    """The grid level a stream decodes to by default at a rate, as :func:`surfidx.codec.decode`
    chooses it (:func:`surfidx.codec.output_levels`; of a multi-part file, its deepest part's).

    Parameters
    ----------
    stream : bytes
        A container file.
    bits_per_surfel : float, optional
        The rate it is served at (default: all of it).
    path : str, optional
        Name for messages.

    Returns
    -------
    int or None
        None when ``stream`` is not a container (a stand-in decoder's data).
    """
    from .errors import BitstreamError
    from .codec import output_levels

    try:
        return max(output_levels(bytes(stream), bits_per_surfel=bits_per_surfel, path=path))
    except BitstreamError:
        return None


def export_texture(texture, *, fmt: str, mesh: bool, max_vertices=None,
                   texture_size=None) -> bool:
    """Whether a decoded model is written with its colour as a texture (``surfidx get``,
    ``decode``, :meth:`surfidx.Database.export`).

    Parameters
    ----------
    texture : bool or None
        Asked for (True), vertex colours asked for (False), or the default (None): a texture
        for an OBJ or GLB mesh without ``max_vertices``.
    fmt : str
        The output format.
    mesh : bool
        Whether the model is decoded to a mesh.
    max_vertices : int, optional
    texture_size : int, optional

    Returns
    -------
    bool

    Raises
    ------
    InputError
        A texture asked for a format or a model that cannot carry it, or ``texture_size``
        without a texture.
    """
    from .errors import InputError

    if texture is None:
        texture = fmt in ("obj", "glb") and mesh and max_vertices is None
    elif texture:
        if fmt not in ("obj", "glb") or not mesh:
            raise InputError(f"a texture is written with an OBJ or GLB mesh, not {fmt} "
                             f"{'mesh' if mesh else 'surfels'}; write .obj or .glb, or use "
                             "vertex colours")
        if max_vertices is not None:
            raise InputError("a texture does not combine with max_vertices (a simplified mesh "
                             "has no place on the grid's atlas); use vertex colours or drop "
                             "max_vertices")
    if not texture and texture_size is not None:
        raise InputError(f"texture_size={texture_size!r} was given but the model is written "
                         "with vertex colours; ask for the texture or drop texture_size")
    return bool(texture)


def describe_stream(stream: bytes, *, lmax: int | None = None, path=None):
    """Descriptors of a stored asset: its embedded stream decoded in full, then described.

    Parameters
    ----------
    stream : bytes
        A container file (``assets.stream``).
    lmax : int, optional
        Spherical-harmonic degree of the ``layers``/``texture`` vectors (default: the library's).
    path : str, optional
        Name for messages.

    Returns
    -------
    surfidx.describe.descriptors.DescriptorSet

    Notes
    -----
    Ingest describes the grid before coding; this describes the decoded grid, so the vectors
    differ by the coding error (at the stored rate a few tenths of a percent of the distance
    between different models).
    """
    from .codec import decode_grid
    from .describe.descriptors import DEFAULT_LMAX, describe_grid

    values, header = decode_grid(bytes(stream), path=path)
    return describe_grid(values, header.level, lmax=DEFAULT_LMAX if lmax is None else lmax)


def redescribe(db, *, everything: bool = False, lmax: int | None = None, progress=None) -> dict:
    """Recompute stored descriptors from the stored assets, one model per transaction.

    After an upgrade that changes the descriptors (their ``version`` or settings), a database
    holds vectors this surfidx cannot compare with new ones; this brings them up to date without
    the source files. Killing it leaves every model either done or untouched; a re-run goes on.

    Parameters
    ----------
    db : surfidx.db.catalog.Catalog
    everything : bool
        Recompute every model, not only those whose conventions differ from this surfidx's.
    lmax : int, optional
        As for :func:`describe_stream`.
    progress : callable, optional
        ``progress(model_id)`` after each model.

    Returns
    -------
    dict
        ``redescribed``, ``current`` (left alone) and ``failed`` (``{id: message}``) counts.
    """
    import json

    from .errors import SurfidxError
    from .db.catalog import is_storage_failure
    from .describe.descriptors import DEFAULT_LMAX, descriptor_params

    want = descriptor_params(lmax=DEFAULT_LMAX if lmax is None else lmax)
    want = json.loads(json.dumps(want))
    ids = sorted(m["id"] for m in db.list_models())
    current = set()
    if not everything:
        # current: every stored kind made with this surfidx's conventions (a model with some
        # kinds current and others not is recomputed, as is one without descriptors)
        stale = set()
        for conv, mids in db.descriptor_conventions().items():
            (current if json.loads(conv) == want else stale).update(mids)
        current -= stale
    todo = [i for i in ids if i not in current]
    done, failed = 0, {}
    for model_id in todo:
        try:
            desc = describe_stream(db.get_stream(model_id), lmax=lmax, path=f"model {model_id}")
            db.set_descriptors(model_id, desc.vectors, desc.params)
            done += 1
        except SurfidxError as exc:
            if is_storage_failure(exc):
                raise                   # the database, not the model: one error, not one a model
            failed[model_id] = str(exc)
        if progress is not None:
            progress(model_id)
    return {"redescribed": done, "current": len(ids) - len(todo), "failed": failed}


def unit_of_work(func, name: str):
    """``func``, or this module's per-model function ``name`` (``"process_model"`` for an
    ingest, ``"describe_model"`` for a query by example) when ``func`` is None, looked up now:
    the one place the callers' default is chosen.

    Parameters
    ----------
    func : callable or None
    name : {"process_model", "describe_model"}

    Returns
    -------
    callable

    Raises
    ------
    SurfidxError
        This module has no function ``name``.
    """
    if func is not None:
        return func
    step = globals().get(name)
    if step is None:
        raise SurfidxError(f"the per-model function surfidx.pipeline.{name} is not available")
    return step
