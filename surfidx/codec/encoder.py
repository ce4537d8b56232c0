"""The spherical wavelet codec: map → icosahedral resampling → KLT → lifted butterfly wavelets →
zerotree + arithmetic coding → ``.sfz`` container, and back.

One embedded stream holds all layers; any prefix decodes to a coarser model, so a stored asset is
served at a lower rate by truncation (:func:`decode` with ``bits_per_surfel``). Rates are bits per
*input* surfel with the whole file counted: a file encoded at ``B`` bits/surfel is at most
``ceil(B · n / 8)`` bytes.

Units. Before the KLT, geometry is divided by the input's bounding-box diagonal (the PSNR peak) and
colour by 255 and multiplied by :data:`COLOR_WEIGHT`. Colour has its own, finer grid, sampled
from the texture when the model has one, and geometry and colour are two groups of the zerotree
coder whose bit-plane passes the header orders (:mod:`surfidx.codec.colorgrid`): by gain of
``PSNR_D2 + color_importance · PSNR_YUV`` per bit, or, with ``allocation="fixed"``, plane by
plane as the colour weight scales them.

Two weightings fit the coder's uniform thresholds to point-to-plane distortion over the input:

* **local frames** (:func:`surfidx.codec.wavelets.forward` with ``frames=True``): the geometry details
  are coded as normal and tangential components, the tangential ones multiplied by
  :data:`TANGENT_WEIGHT`: a tangential error moves a point along the surface, which costs
  point-to-plane distortion far less than a normal one. The frames are closed-loop
  (:func:`surfidx.codec.wavelets.forward_anchored`): computed from the coarse surface quantised to a
  per-level anchor bit plane stored in the header, which a decoder that has that plane
  reproduces exactly;
* **density weights** (:mod:`surfidx.codec.density`): coefficients where the map squeezes many input
  surfels into little of the sphere count more; the field is stored in the header, and used only
  when its estimated gain is worth its bytes.

Topology. Surfels with virtual patches (:attr:`surfidx.SurfelSet.patch`, added by
:func:`surfidx.topology.close_surface` to close holes and handle cuts) are coded as the closed
surface plus a mask of the grid vertices that sample a virtual patch and a table saying, per
connected virtual region, whether it closes a hole or one side of a cut (format version 4; both
in the header, counted against the rate and never truncated). :func:`decode` drops the virtual
region again and zips each cut's two boundary loops together
(:mod:`surfidx.codec.restore`), so the decoded mesh has the input's holes and genus. A model
of several pieces is one file of several part streams (:class:`PartsEncoder`); a rate is split
across the parts in proportion to their input surfels (:func:`surfidx.codec.container.split_budget`).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from dataclasses import fields as dataclass_fields
from pathlib import Path

import numpy as np

from . import container, density, wavelets, zerotree
from .container import max_file_bytes
from ..errors import BitstreamError, InputError
from ..validate import check_positive_int
from ..geometry.icosphere import MAX_LEVEL, icosphere, vertex_count
from .klt import KLT
from .colorgrid import sample_colors
from .resample import grid_patches, locate_surfels, resample
from ..sphere.options import MAP_VERSION, METHODS as MAP_METHODS
from ..geometry.surfels import SurfelSet

__all__ = ["Encoder", "Prepared", "prepare", "quantise", "code", "code_bytes", "codec_options",
           "encode", "decode", "decode_grid", "read_sfz", "COLOR_WEIGHT",
           "TANGENT_WEIGHT", "CODEC_VERSION", "MAP_METHODS", "MAX_SURFELS",
           "MAX_EXTENT", "MAX_COLOR_WEIGHT", "MAX_COEFFICIENT", "check_header", "PartsEncoder",
           "encode_parts", "decode_parts", "stream_summary", "read_level", "READ_BELOW",
           "READ_LEVEL_MIN", "pass_bits", "level_hints", "with_level_hints", "output_levels",
           "HINT_PREFIXES",
           "HINT_ROUNDS", "HINT_SLACK", "HINT_TOLERANCE", "HINT_SAMPLES", "HINT_MARGIN"]

CODEC_VERSION = container.FORMAT_VERSION
"""Version of the container format the encoder writes (``data_schema/bitstream.md``)."""
from .options import COLOR_WEIGHT, MAX_COLOR_WEIGHT, TANGENT_WEIGHT  # noqa: E402

_PLANES = 30  # bit planes below the largest coefficient: finer than float32 positions

MAX_SURFELS = vertex_count(MAX_LEVEL)
"""Default of :func:`decode`'s ``max_surfels``: the level-9 grid (2,621,442 surfels), the finest
the encoder uses. A stream that would decode to more is refused before decoding; decode it at a
coarser ``level``, or raise the limit."""

MAX_EXTENT = 1e6
"""Decoded values lie within this many weighted units of the KLT mean (for geometry:
bounding-box diagonals of the model's centre; for colour: ``color_weight`` · value / 255, at most
:data:`MAX_COLOR_WEIGHT`); anything else, or a non-finite value, is a damaged stream."""

READ_BELOW = 2
"""Grid levels below the output level that a decoding at a coarser level reads (see
:func:`read_level`)."""

READ_LEVEL_MIN = 6
"""Finest grid level a decoding at a coarser level always reads (when the stream has it), so
that the smallest outputs still see the stream's fine details (see :func:`read_level`)."""


def read_level(out_level: int, stream_level: int) -> int:
    """The grid level a decoding at ``out_level`` reads of a level-``stream_level`` stream:
    ``max(out_level + READ_BELOW, READ_LEVEL_MIN)``, at most the stream's.

    The zerotree stream interleaves every level's decisions, so a coarse coefficient's last
    bits come after the finest details' first; reading it all costs time and memory in
    proportion to the stream's grid (a level-9 grid is 2,621,442 vertices), whatever level is
    asked. A coarser decoding therefore reads the coefficients down to this level only: the
    first decision about a finer one ends it, as the end of the stream would, and the surface
    is synthesised on this level's grid, whose prefix is the output. When the stream's grid is
    no finer, this is the whole decoding.

    Parameters
    ----------
    out_level, stream_level : int

    Returns
    -------
    int
    """
    return min(stream_level, max(out_level + READ_BELOW, READ_LEVEL_MIN))


HINT_PREFIXES = 11
"""Stream prefixes :func:`level_hints` measures first: the whole stream and each 2^(1/2) times
shorter one (down to 2^-5 of it: 8 bits/surfel down to 0.25)."""

HINT_TOLERANCE = 0.15
"""dB: two neighbouring prefixes whose levels differ are refined only when one of them would
lose more than this at the other's level (between them, either costs about as little)."""

HINT_SLACK = 0.05
"""dB a prefix may lose against its best level measured at no cost in :func:`level_hints`'
choice: a coarser level must win by more than this to be kept."""

HINT_MARGIN = 1.0
"""dB by which a coarser level must lose against a finer one on a prefix for :func:`level_hints`
to measure it no more on longer prefixes (where it loses more: the finer levels' details come
with the longer prefix), and to measure no longer prefix once every coarser level has."""

HINT_ROUNDS = 3
"""Rounds in which :func:`level_hints` measures the geometric mean of each two neighbouring
prefixes whose levels differ: after three, neighbours are 2^(1/16) apart, one code step of
:func:`surfidx.codec.container.hint_bytes`."""


HINT_SAMPLES = 4096
"""Points per direction on which :func:`level_hints` scores PSNR_D2
(:meth:`surfidx.geometry.metrics.Reference.psnr_d2_sampled`): the same seeded sample of the
input for every decoding, and as many of each decoding's points."""


MAX_COEFFICIENT = 1e12
"""Largest coefficient a stream's coder header may announce (step · 2^(top plane + 1)); the
encoder's are below 1e8 (level norms up to 371 at level 9, density weights up to 64)."""


_UNSET = object()
"""A keyword not given (``tangent_weight=None`` means "no local frames")."""


def codec_options(options=None, *, level=None, color=None, color_weight=None,
                  tangent_weight=_UNSET, density_weighting=None):
    """``options`` (default ``CodecOptions()``) with the keywords given (not None) put in, each
    checked with the encoder's own message first.

    Returns
    -------
    CodecOptions
    """
    from .options import CodecOptions

    if options is None:
        options = CodecOptions()
    elif not isinstance(options, CodecOptions):
        raise InputError(f"options must be a CodecOptions, got {type(options).__name__}")
    given = {}
    if color_weight is not None:
        if not (isinstance(color_weight, (int, float, np.floating))
                and 0 < color_weight <= MAX_COLOR_WEIGHT):
            raise InputError(f"color_weight must be a positive number up to "
                             f"{MAX_COLOR_WEIGHT:g}, got {color_weight!r}")
        given["color_weight"] = float(color_weight)
    if tangent_weight is not _UNSET:
        if tangent_weight is not None:
            tw = float(np.float32(tangent_weight)) if isinstance(
                tangent_weight, (int, float, np.floating)) else math.nan
            if not 0 < tw <= 1:
                raise InputError(f"tangent_weight must be in (0, 1] or None, got "
                                 f"{tangent_weight!r}")
            tangent_weight = float(tangent_weight)
        given["tangent_weight"] = tangent_weight
    for k, v in (("level", level), ("color", color), ("density_weighting", density_weighting)):
        if v is not None:
            given[k] = int(v) if k == "level" and isinstance(v, np.integer) else v
    if given:
        from dataclasses import replace

        options = replace(options, **given)
    return options


@dataclass(frozen=True, eq=False)
class Prepared:
    """What :func:`prepare` makes of a model: everything a rate needs, nothing rate-dependent.

    Attributes
    ----------
    n_surfels : int
        Input surfels (the rate's denominator).
    level : int
        Icosahedral grid level.
    color : bool
        Colour is coded.
    sphere_map : surfidx.sphere.SphericalMap
    grid : (n_grid, 3 or 6) float64
        Resampled layers (x, y, z [, r, g, b]).
    klt : KLT
        As the container stores it (float16 basis).
    coeffs : (n_grid, k) float64
        Normalised (and, with frames, anchored) wavelet coefficients of the KLT layers.
    step : float
        Quantisation step of the finest bit plane.
    color_weight : float
        Weight of colour against geometry.
    tangent_weight : float or None
        Float32-rounded, as the container stores it; None without local frames.
    weight_field : bytes
        The stored density-weight field (empty when unweighted).
    density_gain : float
        :func:`surfidx.codec.density.weighting_gain` of the field, in dB.
    anchors : tuple of int
        Anchor bit plane of each level's local frames (empty without frames).
    mask : bytes
        The coded virtual-region mask (empty: no virtual patch).
    regions : tuple of int
        Region-table codes of the mask's regions.
    virtual_share : float
        Share of the grid's vertices in the mask.
    map_method : int
        Index of the map's method in :data:`MAP_METHODS` (the header's code).
    seconds : dict of str -> float
        Wall seconds of ``map``, ``resample`` and ``transform`` (figures only).
    color_level : int or None
        With colour: the colour grid's level (at least ``level``).
    color_grid : (10·4^color_level + 2, 3) float64 or None
        The colour layers on it (r, g, b, 0..255); ``grid``'s colour is its prefix.
    color_top : int
        The colour layers' top bit plane.
    schedule : tuple of int
        The group (0 geometry, 1 colour) of each bit-plane pass in stream order.
    quantised : surfidx.codec.zerotree.Prepared or None
        With colour: the coefficients quantised on the colour grid's forest.
    allocation : str
    color_importance : float
    level_hints : bool
        The header has an output-level section (:attr:`surfidx.codec.container.Header.level_hints`),
        which :class:`Encoder` fills (:func:`with_level_hints`); :func:`code` writes it with
        codes 0 (the stream's level at any rate).
    """

    n_surfels: int
    level: int
    color: bool
    sphere_map: object
    grid: np.ndarray
    klt: KLT
    coeffs: np.ndarray
    step: float
    color_weight: float
    tangent_weight: float | None
    weight_field: bytes
    density_gain: float
    anchors: tuple
    mask: bytes
    regions: tuple
    virtual_share: float
    map_method: int
    seconds: dict
    color_level: int | None = None
    color_grid: np.ndarray | None = None
    color_top: int = -1
    schedule: tuple = ()
    quantised: object = None
    allocation: str = "rd"
    color_importance: float = 1.0
    level_hints: bool = False

    def report(self) -> dict:
        """What the codec says about itself for a model's stored params: its version, grid
        level, map method, folded triangles, the weights it used."""
        from .resample import PHONG_ALPHA, PHONG_SHARPNESS

        return {"codec_version": CODEC_VERSION, "map_version": MAP_VERSION,
                "grid_level": int(self.level),
                "map_method": self.sphere_map.method, "folded": int(self.sphere_map.folded),
                "color_weight": float(self.color_weight), "tangent_weight": self.tangent_weight,
                "color_level": self.color_level, "allocation": self.allocation if self.color
                else None, "color_importance": float(self.color_importance) if self.color
                else None,
                "density_weighted": bool(self.weight_field),
                "lift": {"phong": PHONG_ALPHA, "sharpness": PHONG_SHARPNESS}}

    def header_bytes(self) -> int:
        """Bytes of the container header for this model (the virtual-region mask included)."""
        return container.header_size(
            self.coeffs.shape[1], zerotree.HEADER_SIZE, frames=self.tangent_weight is not None,
            anchors=len(self.anchors),
            field_bytes=len(self.weight_field) if self.weight_field else None,
            mask_bytes=len(self.mask) if self.mask else None, regions=len(self.regions),
            passes=len(self.schedule) if self.color_level is not None else None,
            hints=self.level_hints)

    def lowest_bytes(self) -> int:
        """The smallest file this model's container can be."""
        finest = self.level if self.color_level is None else self.color_level
        return max(self.header_bytes() + 4, container.min_file_bytes(finest))


def prepare(surfels: SurfelSet, options=None, *, map_options=None, sphere_map=None,
            progress=None, face_patch=None, texture=None) -> Prepared:
    """The rate-independent steps of the encoder: map, resample, mask, KLT, wavelets, density
    weights, frame anchors.

    Parameters
    ----------
    surfels : SurfelSet
        A closed genus-0 surface (mesh input for the default map).
    options : CodecOptions, optional
        The codec's settings (``bits_per_surfel`` is not used here).
    map_options : surfidx.sphere.MapOptions, optional
        The map's, passed to :func:`surfidx.sphere.parameterize`.
    sphere_map : SphericalMap, optional
        A map computed earlier for these surfels (skips the mapping).
    progress : callable, optional
        ``progress(stage, done, total)``: the map's stages, ``"resample"``, ``"transform"``.
    face_patch : (m,) int, optional
        Patch of each of ``surfels.faces`` (see :class:`Encoder`).
    texture : TextureSource or TriangleMesh, optional
        The textured mesh the surfels come from: colour is sampled from its texture on the
        colour grid (:mod:`surfidx.codec.colorgrid`); default the surfels' colours.

    Returns
    -------
    Prepared

    Raises
    ------
    InputError
        Not a SurfelSet, colour asked of surfels without it, a model too far off the origin or
        out of scale, a constant model.
    """
    from ..progress import report
    from ..sphere import parameterize
    from ..sphere.options import MapOptions

    options = codec_options(options)
    if not isinstance(surfels, SurfelSet):
        raise InputError(f"expected a SurfelSet, got {type(surfels).__name__}")
    if map_options is None:
        map_options = MapOptions()
    color = surfels.has_color if options.color is None else options.color
    if color and not surfels.has_color:
        raise InputError("color=True but the surfels have no colour")
    color_weight = options.color_weight
    tangent_weight = options.tangent_weight
    if tangent_weight is not None:
        tangent_weight = float(np.float32(tangent_weight))  # the value the container stores
    if texture is not None and color:
        from .colorgrid import TextureSource

        texture = texture if isinstance(texture, TextureSource) else TextureSource(texture)
    else:
        texture = None
    n_surfels = len(surfels)
    t = {}
    t0 = time.perf_counter()
    if sphere_map is None:
        sphere_map = parameterize(surfels, stress=False, options=map_options, progress=progress)
    t["map"] = time.perf_counter() - t0
    level = sphere_map.grid_level if options.level is None else options.level
    t0 = time.perf_counter()
    report(progress, "resample", 0, 1)
    location = locate_surfels(surfels, sphere_map.points, level)
    grid = resample(surfels, sphere_map.points, level, color=False, location=location)
    clevel, cgrid = None, None
    if color:
        clevel = _color_level(options, level, texture)
        cloc = location if clevel == level else locate_surfels(surfels, sphere_map.points,
                                                               clevel)
        cgrid = sample_colors(surfels, sphere_map.points, clevel, texture=texture,
                              location=cloc)
        grid = np.hstack([grid, cgrid[:len(grid)]])
    mask, regions, virtual_share = b"", (), 0.0
    if surfels.patch is not None:
        mask, regions, virtual_share = _code_mask(surfels, sphere_map.points, location,
                                                  face_patch, level)
    t["resample"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    report(progress, "transform", 0, 1)
    k = grid.shape[1]
    diag = surfels.diagonal
    weights = np.r_[np.full(3, 1.0 / diag), np.full(k - 3, color_weight / 255.0)]
    stored = np.float32(weights)
    if not np.all((stored >= 1.0 / container.MAX_WEIGHT)
                  & (stored <= container.MAX_WEIGHT)):
        raise InputError(f"the model's bounding-box diagonal {diag:.3g} and colour weight "
                         f"{color_weight:.3g} must give unit weights in "
                         f"[{1 / container.MAX_WEIGHT:g}, {container.MAX_WEIGHT:g}]; "
                         "rescale the model")
    area = icosphere(level).vertex_areas()
    frames = tangent_weight is not None
    if color:
        # geometry and colour have their own grids: a block-diagonal KLT, each on its grid
        fg = KLT.fit(grid[:, :3], weights=weights[:3], sample_weights=area)
        fc = KLT.fit(cgrid, weights=weights[3:], sample_weights=icosphere(clevel).vertex_areas())
        basis = np.zeros((6, 6))
        basis[:3, :3], basis[3:, 3:] = fg.basis, fc.basis
        fit = KLT(np.r_[fg.mean, fc.mean], basis, weights,
                  eigenvalues=np.r_[fg.eigenvalues, fc.eigenvalues])
    else:
        fit = KLT.fit(grid, weights=weights, sample_weights=area)
    if not np.all(np.abs(fit.mean) <= container.MAX_MEAN):
        raise InputError(f"the model's centre lies more than {container.MAX_MEAN:g} "
                         "bounding-box diagonals from the origin; move it closer")
    # the values the container stores (float16 basis): encoder and decoder use the same
    klt = KLT(*container.storable(fit.mean, fit.basis, fit.weights),
              eigenvalues=fit.eigenvalues)
    kg = KLT(klt.mean[:3], klt.basis[:3, :3], klt.weights[:3]) if color else klt
    raw = wavelets.forward(kg.forward(grid[:, :3]), level, lifted=True)
    scales = wavelets.level_norms(level)[icosphere(level).level_of]
    plain = raw * scales[:, None]   # forward(..., normalized=True)
    flevel = density.field_level(n_surfels, level)
    field = density.weight_field(sphere_map.points, flevel)
    density_gain = density.weighting_gain(field, flevel)
    density_weighting = options.density_weighting
    if density_weighting is None:
        density_weighting = density_gain >= density.MIN_GAIN_DB
    weight_field = density.pack_field(field, flevel) if density_weighting else b""
    if density_weighting:
        dscale = density.vertex_scales(field, flevel, level)
        plain *= dscale[:, None]
        scales = scales * dscale
    cplain = None
    if color:
        kc = KLT(klt.mean[3:], klt.basis[3:, 3:], klt.weights[3:])
        cscales = wavelets.level_norms(clevel)[icosphere(clevel).level_of]
        if density_weighting:
            cscales = cscales * density.vertex_scales(field, flevel, clevel)
        cplain = wavelets.forward(kc.forward(cgrid), clevel, lifted=True) * cscales[:, None]
    # local frames never lengthen a geometry detail vector: bound the top by the lengths
    top = max(float(np.sqrt(np.einsum("ij,ij->i", plain[:, :3], plain[:, :3])).max()),
              float(np.abs(cplain).max()) if color else 0.0)
    if not top > 0:
        raise InputError("the resampled model is constant; nothing to code")
    step = float(np.float32(top * 2.0 ** -_PLANES))
    anchors = ()
    coeffs = plain
    if frames:
        anchors = tuple(int(a) for a in wavelets.choose_anchors(plain, level, step))
        coeffs = wavelets.forward_anchored(raw, level, tangent_weight=tangent_weight,
                                           scales=scales, step=step, anchors=anchors)
    schedule, color_top, quantised = (), -1, None
    if color:
        full = np.zeros((len(cplain), 6))
        full[:len(coeffs), :3] = coeffs
        full[:, 3:] = cplain
        coeffs = full
        quantised = zerotree.prepare(coeffs, zerotree.grid_forest(clevel), None, None, step=step,
                                     final_plane=0)
        color_top = int(np.max(quantised.magnitudes[3:])).bit_length() - 1
        schedule = _schedule(options, quantised, coeffs, step, color_top, level, clevel,
                             klt.basis[3:, 3:])
    map_method = MAP_METHODS.index(sphere_map.method) if sphere_map.method in MAP_METHODS else 0
    t["transform"] = time.perf_counter() - t0
    report(progress, "transform", 1, 1)
    return Prepared(n_surfels=n_surfels, level=level, color=bool(color), sphere_map=sphere_map,
                    grid=grid, klt=klt, coeffs=coeffs, step=step, color_weight=color_weight,
                    tangent_weight=tangent_weight,
                    weight_field=weight_field, density_gain=density_gain, anchors=anchors,
                    mask=mask, regions=regions, virtual_share=virtual_share,
                    map_method=map_method, seconds=t, color_level=clevel, color_grid=cgrid,
                    color_top=color_top, schedule=schedule, quantised=quantised,
                    allocation=options.allocation,
                    color_importance=options.color_importance,
                    level_hints=bool(options.level_hints))


def _color_level(options, level: int, texture) -> int:
    """The colour grid's level: the option's, else from the texture's texels
    (:func:`surfidx.codec.colorgrid.color_level`)."""
    from .colorgrid import color_level

    if options.color_level is not None:
        if options.color_level < level:
            raise InputError(f"color_level {options.color_level} is below the geometry's grid "
                             f"level {level}; use at least {level} (or None: chosen from the "
                             "texture)")
        return int(options.color_level)
    return color_level(level, None if texture is None else texture.texels)


def _layout(level: int, color_level: int):
    """Groups and depth limits of the six layers of a colour-grid stream."""
    return (0, 0, 0, 1, 1, 1), (level,) * 3 + (color_level,) * 3


def _schedule(options, quantised, coeffs, step, color_top, level, clevel, color_basis):
    """The order of geometry and colour passes (:mod:`surfidx.codec.colorgrid`)."""
    from .colorgrid import fixed_schedule, luma_chroma_weights, pass_distortions, rd_schedule

    top = quantised.header["top_plane"]
    fixed = fixed_schedule(top, color_top, 0)
    if options.allocation == "fixed":
        return fixed
    groups, limits = _layout(level, clevel)
    sched = zerotree.group_schedule(fixed, (top, color_top), 0)
    _, _, bits = zerotree.encode_prepared(quantised, schedule=sched, groups=groups,
                                          depth_limits=limits, marks=True)
    cost = np.diff(np.r_[0.0, bits])
    cg, cc = cost[np.asarray(fixed) == 0], cost[np.asarray(fixed) == 1]
    n_geo = vertex_count(level)
    dg = pass_distortions(coeffs[:n_geo, :3], step, top, 0, np.ones(3))
    dc = pass_distortions(coeffs[:, 3:], step, color_top, 0, luma_chroma_weights(color_basis))
    with np.errstate(divide="ignore", invalid="ignore"):
        gg = 10 * np.log10((dg[:-1] + _FLOOR * dg[0]) / (dg[1:] + _FLOOR * dg[0]))
        gc = 10 * np.log10((dc[:-1] + _FLOOR * dc[0]) / (dc[1:] + _FLOOR * dc[0]))
    return rd_schedule(np.nan_to_num(gg), cg, np.nan_to_num(gc), cc, options.color_importance)


_FLOOR = 1e-12   # relative distortion floor of the schedule's gains (keeps the logs finite)


def pass_bits(prepared: Prepared):
    """The bit-plane passes of a colour-grid stream and what each costs.

    Parameters
    ----------
    prepared : Prepared
        With colour.

    Returns
    -------
    groups : (s,) int64
        The group of each pass in stream order (0 geometry, 1 colour).
    bits : (s,) float64
        Bits each pass takes in the stream (the last pass's include the coder's flush).

    Raises
    ------
    InputError
        A model coded without colour.
    """
    p = prepared
    if p.color_level is None:
        raise InputError("pass_bits needs a stream with colour (geometry alone is one group)")
    q = p.quantised
    groups, limits = _layout(p.level, p.color_level)
    sched = zerotree.group_schedule(p.schedule, (q.header["top_plane"], p.color_top), 0)
    _, _, bits = zerotree.encode_prepared(q, schedule=sched, groups=groups,
                                          depth_limits=limits, marks=True)
    return np.asarray(p.schedule, np.int64), np.diff(np.r_[0.0, bits])


def _code_mask(surfels, sphere_points, location, face_patch, level):
    """The virtual-region mask, region table and virtual share (:mod:`surfidx.codec.restore`)."""
    from scipy.spatial import cKDTree

    from .mask import encode_mask
    from .restore import mask_regions

    patches = grid_patches(surfels, sphere_points, level, face_patch=face_patch,
                           location=location)
    P = len(surfels.patch_cut)
    anchors = np.full(P, -1, np.int64)
    missing = np.setdiff1d(np.arange(P), patches)
    if len(missing):   # a patch below the grid's spacing still gets its grid vertex
        pts = np.asarray(sphere_points, np.float64)
        fp = None if face_patch is None else np.asarray(face_patch, np.int64)
        where = {}
        for p in missing:
            own = np.flatnonzero(surfels.patch == p)
            if len(own):
                where[int(p)] = pts[own[0]]
            elif fp is not None and (fp == p).any():
                c = pts[surfels.faces[np.flatnonzero(fp == p)[0]]].mean(axis=0)
                where[int(p)] = c / max(np.linalg.norm(c), 1e-300)
        if where:
            _, near = cKDTree(icosphere(level).vertices).query(np.array(list(where.values())))
            anchors[list(where)] = near
    bits, codes = mask_regions(patches, level, surfels.patch_cut, anchors=anchors,
                               centres=_patch_centres(surfels, sphere_points, face_patch, P))
    if bits.any():
        return encode_mask(bits, level), codes, float(bits.mean())
    return b"", (), 0.0


def _patch_centres(surfels, sphere_points, face_patch, P):
    """(P, 3) float64: each patch's centre on the unit sphere, the normalised mean of the
    sphere points of its virtual surfels and of its faces' corners (``face_patch``); NaN for a
    patch with neither."""
    pts = np.asarray(sphere_points, np.float64)
    total = np.zeros((P, 3))
    on = np.flatnonzero(surfels.patch >= 0)
    np.add.at(total, surfels.patch[on], pts[on])
    if face_patch is not None and surfels.faces is not None:
        fp = np.asarray(face_patch, np.int64)
        f = np.flatnonzero(fp >= 0)
        np.add.at(total, fp[f], pts[surfels.faces[f]].sum(axis=1))
    norm = np.linalg.norm(total, axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(norm[:, None] > 0, total / norm[:, None], np.nan)


def quantise(prepared: Prepared):
    """The coefficients quantised on the grid's forest (:func:`surfidx.codec.zerotree.prepare`):
    the part of coding shared by every rate."""
    if prepared.quantised is not None:
        return prepared.quantised
    return zerotree.prepare(prepared.coeffs, zerotree.grid_forest(prepared.level), None, None,
                            step=prepared.step, final_plane=0)


def code(prepared: Prepared, bits_per_surfel: float, *, quantised=None, progress=None) -> bytes:
    """A complete ``.sfz`` container of ``prepared`` at a rate.

    Parameters
    ----------
    prepared : Prepared
    bits_per_surfel : float
        The file is at most ``ceil(bits_per_surfel · n_surfels / 8)`` bytes.
    quantised : optional
        :func:`quantise` of ``prepared``, when kept for several rates.
    progress : callable, optional
        ``progress("code", done, 1)`` as the coding starts and ends.

    Returns
    -------
    bytes

    Raises
    ------
    InputError
        When the rate cannot even hold the header and a minimal stream.
    """
    return code_bytes(prepared, max_file_bytes(bits_per_surfel, prepared.n_surfels),
                      quantised=quantised, progress=progress, rate=bits_per_surfel)


def code_bytes(prepared: Prepared, max_bytes: int, *, quantised=None, progress=None,
               rate=None) -> bytes:
    """A container of at most ``max_bytes`` bytes (see :func:`code`)."""
    p = prepared
    budget = int(max_bytes) - p.header_bytes()
    smallest = p.lowest_bytes()
    if budget < smallest - p.header_bytes():
        lowest = 8.0 * smallest / p.n_surfels
        asked = f"{rate} bits/surfel" if rate is not None else f"{max_bytes} bytes"
        raise InputError(f"{asked} cannot hold the header; the lowest rate for this model "
                         f"is {lowest:.3g} bits/surfel ({smallest} bytes)")
    if progress is not None:
        progress("code", 0, 1)
    if quantised is None:
        quantised = quantise(p)
    if p.color_level is None:
        stream, zh = zerotree.encode_prepared(quantised, max_bytes=budget)
    else:
        groups, limits = _layout(p.level, p.color_level)
        stream, zh = zerotree.encode_prepared(
            quantised, max_bytes=budget, groups=groups, depth_limits=limits,
            schedule=zerotree.group_schedule(p.schedule, (quantised.header["top_plane"],
                                                          p.color_top), 0))
    # a stream that finished every plane early may be shorter than the grid's smallest
    # container: pad it with zero bytes, which the decoder reads past the end anyway
    finest = p.level if p.color_level is None else p.color_level
    stream += bytes(max(0, container.min_file_bytes(finest) - p.header_bytes() - len(stream)))
    header = container.Header(
        n_surfels=p.n_surfels, level=p.level, color=p.color, lifted=True,
        mean=p.klt.mean, basis=p.klt.basis, weights=p.klt.weights,
        coder=zerotree.pack_header(zh), map_method=p.map_method,
        tangent_weight=p.tangent_weight, weight_field=p.weight_field,
        anchors=p.anchors, mask=p.mask, regions=p.regions, color_level=p.color_level,
        color_top=p.color_top, schedule=p.schedule,
        level_hints=(0,) * container.MAX_LEVEL_HINTS if p.level_hints else ())
    out = container.pack(header, stream)
    if progress is not None:
        progress("code", 1, 1)
    return out


class Encoder:
    """Expensive set-up once (:func:`prepare`), then :meth:`encode` at any rate (:func:`code`).

    Parameters
    ----------
    surfels : SurfelSet
        A closed genus-0 surface (mesh input for the default map).
    options : CodecOptions, optional
        The codec's settings; the keywords below, when given, override its fields.
    map_options : surfidx.sphere.MapOptions, optional
        The map's settings (:func:`surfidx.sphere.parameterize`).
    level : int, optional
        Icosahedral grid level; default the map's ``grid_level``.
    color : bool, optional
        Code colour (default: when the surfels have it).
    method : {"tutte", "mds"}, optional
        Spherical map (overrides ``map_options.method``).
    color_weight : float, optional
        Weight of colour against geometry (see the module docstring).
    sphere_map : SphericalMap, optional
        A map computed earlier for these surfels (skips the mapping).
    tangent_weight : float or None, optional
        Code the geometry details in local frames with this weight in (0, 1] on their tangential
        components; None codes x, y, z details as they are.
    density_weighting : bool, optional
        Weight coefficients by the input's surfel density on the sphere
        (:mod:`surfidx.codec.density`); default: when its estimated gain is worth it.
    progress : callable, optional
        ``progress(stage, done, total)`` at the stage boundaries of the set-up.
    face_patch : (m,) int, optional
        Patch of each of ``surfels.faces`` (-1: the scan's), for virtual faces whose corners are
        all scan vertices (:func:`surfidx.codec.resample.grid_patches`).
    texture : TriangleMesh or surfidx.codec.colorgrid.TextureSource, optional
        The textured mesh the surfels come from: the colour grid samples its texture
        (:mod:`surfidx.codec.colorgrid`) instead of the surfels' colours.

    Attributes
    ----------
    prepared : Prepared
        The set-up; its fields are also attributes of the encoder (``grid``, ``coeffs``,
        ``klt``, ``sphere_map``, ``level``, ``tangent_weight``, ``weight_field``, ``anchors``,
        ``density_gain``, ``mask``, ``regions``, ``virtual_share``, ``step``, ``n_surfels``,
        ``color``, ``map_method``).
    options : CodecOptions
        As used.
    setup_seconds : dict of str -> float
    """

    def __init__(self, surfels: SurfelSet, *, options=None, map_options=None,
                 level: int | None = None, color: bool | None = None, method: str | None = None,
                 color_weight: float | None = None, sphere_map=None, tangent_weight=_UNSET,
                 density_weighting: bool | None = None, progress=None, face_patch=None,
                 texture=None):
        from dataclasses import replace

        from ..sphere.options import MapOptions

        if not isinstance(surfels, SurfelSet):
            raise InputError(f"expected a SurfelSet, got {type(surfels).__name__}")
        if method is not None and method not in MAP_METHODS:
            raise InputError(f"method must be one of {', '.join(MAP_METHODS)}, got {method!r}")
        map_options = MapOptions() if map_options is None else map_options
        if method is not None:
            map_options = replace(map_options, method=method)
        if color and not surfels.has_color:
            raise InputError("color=True but the surfels have no colour")
        self.options = codec_options(options, level=level, color=color,
                                     color_weight=color_weight, tangent_weight=tangent_weight,
                                     density_weighting=density_weighting)
        self.map_options = map_options
        self.prepared = prepare(surfels, self.options, map_options=map_options,
                                sphere_map=sphere_map, progress=progress, face_patch=face_patch,
                                texture=texture)
        for f in dataclass_fields(Prepared):
            if f.name != "seconds":
                setattr(self, f.name, getattr(self.prepared, f.name))
        self.setup_seconds = dict(self.prepared.seconds)
        self._zerotree = None   # quantise's, at the first encode
        self._reference = surfels if surfels.patch is None else surfels.subset(~surfels.virtual)

    def _prepared(self):
        """The quantised coefficients (:func:`quantise`), made at the first :meth:`encode` and
        kept: each rate then only codes."""
        if self._zerotree is None:
            self._zerotree = quantise(self.prepared)
        return self._zerotree

    def header_bytes(self) -> int:
        """Bytes of the container header for this model (the virtual-region mask included)."""
        return self.prepared.header_bytes()

    def lowest_bytes(self) -> int:
        """The smallest file this model's container can be."""
        return self.prepared.lowest_bytes()

    def encode(self, bits_per_surfel: float, *, progress=None) -> bytes:
        """Encode at a rate (:func:`code`).

        Parameters
        ----------
        bits_per_surfel : float
            Target rate; the file is at most ``ceil(bits_per_surfel · n_surfels / 8)`` bytes.
        progress : callable, optional
            ``progress("code", done, 1)`` as the coding starts and ends (:mod:`surfidx.progress`).

        Returns
        -------
        bytes
            A complete ``.sfz`` container.

        Raises
        ------
        InputError
            When the rate cannot even hold the header and a minimal stream.
        """
        return self.encode_bytes(max_file_bytes(bits_per_surfel, self.n_surfels),
                                 progress=progress, rate=bits_per_surfel)

    def encode_bytes(self, max_bytes: int, *, progress=None, rate=None) -> bytes:
        """Encode into a file of at most ``max_bytes`` bytes (see :meth:`encode`)."""
        p = self.prepared
        if int(max_bytes) - p.header_bytes() < p.lowest_bytes() - p.header_bytes():
            return code_bytes(p, max_bytes, quantised=None, progress=progress, rate=rate)
        out = code_bytes(p, max_bytes, quantised=self._prepared(), progress=progress,
                         rate=rate)
        return with_level_hints(out, self._reference) if p.level_hints else out


def level_hints(blob: bytes, reference: SurfelSet) -> tuple:
    """The output-level codes of a one-part container
    (:attr:`surfidx.codec.container.Header.level_hints`), measured against the surface it codes.

    Why a coarser level can score better: where a prefix has not yet coded the fine levels'
    details, the decoded surface is a smooth surface that lies inside the input's protrusions,
    and PSNR_D2 measures each input point against the tangent plane of its nearest decoded
    point; a coarser grid's nearest points lie further away, and on a convex surface their
    tangent planes pass further out, nearer those input points. On a model with sharp creases
    the finest level's points can score worse at any rate.

    The prefixes measured are the whole stream and each 2^(1/2) times shorter one
    (:data:`HINT_PREFIXES`), the shortest first, each decoded at the stream's level and up to
    :data:`~surfidx.codec.container.MAX_LEVEL_HINTS` levels below (once per grid level read,
    :func:`read_level`) and scored by PSNR_D2 against ``reference`` on :data:`HINT_SAMPLES`
    points per direction. A coarser level that loses more than :data:`HINT_MARGIN` against a
    finer one on a prefix is not measured on the longer ones, and once every coarser level
    has lost so, no longer prefix is measured (the stream's level is kept there). The levels
    kept for them, the stream's own or coarser and never finer for a shorter prefix, are
    those whose largest loss against each prefix's best level is smallest (losses within
    :data:`HINT_SLACK` count as none; then the smallest total loss, then the finer levels).
    Between two neighbouring prefixes whose levels differ and where either
    level loses more than :data:`HINT_TOLERANCE`, their geometric mean is measured too, for
    :data:`HINT_ROUNDS` rounds; each step down is placed at the geometric mean of the two
    prefix lengths it lies between, rounded to a code (:func:`surfidx.codec.container.hint_bytes`),
    and a step that the whole stream takes gets the smallest code above its container's size
    (so that the later steps' codes can follow within the section's gaps).

    Each prefix is decoded once per grid level read, its geometry only, and each level is
    scored on the positions and normals that :func:`decode`'s surfels would have, to the bit,
    without building them (:meth:`surfidx.geometry.metrics.Reference.psnr_d2_sampled_points`);
    the vertices that a virtual-region mask keeps are found once per output level
    (:func:`surfidx.codec.restore.restored_vertices`), as they do not depend on the prefix.

    Parameters
    ----------
    blob : bytes
        A one-part container (its own hints are not read).
    reference : SurfelSet
        The surface it codes (its real surfels, without virtual patches).

    Returns
    -------
    tuple of int
        :data:`~surfidx.codec.container.MAX_LEVEL_HINTS` non-increasing codes in 0 … 255
        (0: that step down never applies).
    """
    from ..geometry.metrics import Reference

    header, stream = container.unpack(blob)
    top = int(header.level)
    depth = min(container.MAX_LEVEL_HINTS, top)
    none = (0,) * container.MAX_LEVEL_HINTS
    if depth == 0 or len(reference) == 0:
        return none
    ref = Reference(reference)
    measured = {}   # prefix length -> PSNR_D2 at offsets 0 … depth (-inf: not measured)
    checked = check_header(header)

    least = container.min_file_bytes(top if header.color_level is None else header.color_level)
    dropped = {}   # offset -> shortest prefix from which it is not measured
    kept = {}   # (output level, level read) -> the grid vertices a decoding keeps

    def measure(size, offsets):
        part = stream[:size]
        offsets = [o for o in offsets if size < dropped.get(o, math.inf)]
        row = [-np.inf] * (depth + 1)
        for read in sorted({read_level(top - o, top) for o in offsets}, reverse=True):
            values = _decode_values(blob, header, part, None, None, checked, read,
                                    geometry=True)
            for o in offsets:
                if read_level(top - o, top) != read:
                    continue
                try:   # as decode_parts decodes the prefix at level top - o
                    row[o] = ref.psnr_d2_sampled_points(
                        *_hint_points(values, header, top - o, read, kept), HINT_SAMPLES)
                except InputError:   # virtual regions that merge on the coarser grid (any prefix)
                    dropped[o] = 0
        measured[size] = row
        for o in range(1, depth + 1):   # a coarser level only loses more on a longer prefix
            if np.isfinite(row[o]) and max(row[:o]) - row[o] > HINT_MARGIN:
                dropped[o] = min(dropped.get(o, size), size)

    sizes = []
    for k in range(HINT_PREFIXES):
        size = int(len(stream) * 2.0 ** (-k / 2))
        if size < 4 or size in sizes or size + len(blob) - len(stream) < least:
            break   # below the grid's smallest container
        sizes.append(size)
    for size in reversed(sizes):   # the shortest first, until every coarser level lost
        if len(dropped) == depth:
            break
        measure(size, range(depth + 1))
    if not measured:
        return none
    for _ in range(HINT_ROUNDS):
        sizes, offsets = _hint_offsets(measured, depth)
        # between two neighbours whose levels differ, the levels from the one to the other
        # where either level would lose more than HINT_TOLERANCE at one of them
        new = {int(round(math.sqrt(sizes[k] * sizes[k - 1]))): range(offsets[k - 1],
                                                                    offsets[k] + 1)
               for k in range(1, len(sizes)) if offsets[k] != offsets[k - 1]
               and max(_loss(measured[sizes[k]], offsets[k - 1]),
                       _loss(measured[sizes[k - 1]], offsets[k])) > HINT_TOLERANCE}
        new = {size: o for size, o in new.items() if size not in measured}
        for size in sorted(new, reverse=True):
            measure(size, new[size])
        if not new:
            break
    sizes, offsets = _hint_offsets(measured, depth)
    head = len(blob) - len(stream)
    codes = []
    for i in range(1, depth + 1):
        coarse = [k for k, o in enumerate(offsets) if o >= i]
        if not coarse:
            break
        k = coarse[0]
        if k == 0:
            # the whole stream steps down: the smallest code above its container (255, always,
            # would leave the next code no gap below HINT_GAPS, so no later step)
            code = 1
            while code < 255 and container.hint_bytes(code, header.n_surfels) <= len(blob):
                code += 1
            codes.append(code)
            continue
        # container sizes: coarser at `below`, finer at `above`
        below, above = sizes[k] + head, sizes[k - 1] + head
        code = int(round(8.0 * math.log2(below * above * 2.0 ** 6 / header.n_surfels ** 2)
                         + 128))
        code = min(max(code, 1), 254)
        while code < 254 and container.hint_bytes(code, header.n_surfels) <= below:
            code += 1
        while code > 1 and container.hint_bytes(code, header.n_surfels) > above:
            code -= 1
        if codes and codes[-1] - code >= container.HINT_GAPS:
            break   # beyond the section's largest gap: this step and the later ones dropped
        codes.append(code)
    return tuple(codes) + (0,) * (container.MAX_LEVEL_HINTS - len(codes))


def _hint_points(values, header, out_level: int, read: int, kept: dict):
    """The positions and normals of the surfels :func:`decode_parts` makes of ``values`` at
    ``out_level`` (what PSNR_D2 reads of them), to the bit. The vertices a virtual-region mask
    keeps depend on the header only (:func:`surfidx.codec.restore.restored_vertices`), so
    ``kept`` holds them per output level and level read, for every prefix of the stream."""
    from .resample import _grid_points

    p, nrm = _grid_points(values[:vertex_count(out_level), :3])
    nrm = nrm / np.linalg.norm(nrm, axis=1)[:, None]   # as the SurfelSet normalises them
    if not header.mask:
        return p, nrm
    key = (out_level, read)
    if key not in kept:
        from .restore import restored_vertices

        region, codes = _regions(header, out_level, read, None)
        kept[key] = restored_vertices(out_level, region, len(codes))
    v = kept[key]
    nrm = nrm[v]
    return p[v], nrm / np.linalg.norm(nrm, axis=1)[:, None]   # the subset's SurfelSet's


def _loss(row, offset: int) -> float:
    """dB a measured prefix loses at ``offset`` against its best measured level."""
    return float(max(row) - row[offset]) if np.isfinite(row[offset]) else math.inf


def with_level_hints(blob: bytes, reference: SurfelSet) -> bytes:
    """A one-part container of :func:`code` with its output-level section filled
    (:func:`level_hints`; the step :class:`Encoder` takes after :func:`code`).

    Parameters
    ----------
    blob : bytes
        A container with an output-level section (``Prepared.level_hints``).
    reference : SurfelSet
        The surface it codes (its real surfels, without virtual patches).

    Returns
    -------
    bytes
        The same container, its codes measured: the stream and its length unchanged.

    Raises
    ------
    InputError
        A container without an output-level section.
    """
    header, stream = container.unpack(blob)
    if not header.level_hints:
        raise InputError("the container has no output-level section (code it with "
                         "CodecOptions(level_hints=True))")
    header.level_hints = level_hints(blob, reference)
    return container.pack(header, stream)


def _hint_offsets(measured: dict, depth: int):
    """The measured prefix lengths, longest first, and the levels below the stream's kept for
    them (non-decreasing along the list) that :func:`level_hints` chooses."""
    import itertools

    sizes = sorted(measured, reverse=True)
    scores = np.array([measured[s] for s in sizes])
    scores = np.where(np.isfinite(scores), scores, np.copysign(1e6, scores))   # ±inf: ±1e6 dB
    loss = np.maximum(scores.max(axis=1, keepdims=True) - scores - HINT_SLACK, 0.0)
    combos = np.array(list(itertools.combinations_with_replacement(range(depth + 1),
                                                                   len(sizes))))
    lost = loss[np.arange(len(sizes)), combos]
    # the first in enumeration order of the smallest (largest loss, total loss, offsets' sum)
    keys = (np.round(lost.max(axis=1), 2), np.round(lost.sum(axis=1), 2), combos.sum(axis=1))
    best = np.lexsort(keys[::-1])[0]
    return sizes, tuple(int(o) for o in combos[best])


def encode(surfels: SurfelSet, *, bits_per_surfel: float | None = None,
           level: int | None = None, color: bool | None = None, method: str | None = None,
           tangent_weight=_UNSET, density_weighting: bool | None = None, face_patch=None,
           options=None, map_options=None, texture=None) -> bytes:
    """One-call encoding (see :class:`Encoder`); ``bits_per_surfel`` defaults to
    ``options.bits_per_surfel``."""
    e = Encoder(surfels, options=options, map_options=map_options, level=level, color=color,
                method=method, tangent_weight=tangent_weight,
                density_weighting=density_weighting, face_patch=face_patch, texture=texture)
    return e.encode(e.options.bits_per_surfel if bits_per_surfel is None else bits_per_surfel)


class PartsEncoder:
    """Several parts (the pieces of one model) coded as one multi-part file.

    Expensive set-up once (one :class:`Encoder` per part), then :meth:`encode` at any rate.

    Parameters
    ----------
    parts : sequence of SurfelSet
        One closed genus-0 surface per part (virtual patches allowed), at least one.
    level : int, optional
        Grid level of every part (default: each part's map's).
    color : bool, optional
        Code colour (default: when every part has it).
    method : {"tutte", "mds"}, optional
    progress : callable, optional
        Passed to each part's :class:`Encoder`.
    face_patches : sequence, optional
        Each part's ``face_patch`` (:class:`Encoder`), or None.
    **encoder_options
        Further :class:`Encoder` keywords (``options``, ``map_options``, ``tangent_weight``,
        ``density_weighting``, ``color_weight``, ``texture``: one textured mesh for all parts).

    Attributes
    ----------
    encoders : list of Encoder
    n_surfels : int
        Input surfels of all parts: the rate denominator.

    Notes
    -----
    A file of one part is exactly that part's :meth:`Encoder.encode`. With several, the bytes a
    rate allows, less the outer header, are split in proportion to the parts' input surfels
    (:func:`surfidx.codec.container.split_budget`), and :func:`surfidx.codec.container.truncate` splits a
    lower rate the same way, so every part of a truncated file is a prefix of its stream.
    """

    def __init__(self, parts, *, level: int | None = None, color: bool | None = None,
                 method: str | None = None, progress=None, face_patches=None,
                 **encoder_options):
        parts = list(parts)
        if not parts:
            raise InputError("PartsEncoder needs at least one part")
        if len(parts) > container.MAX_PARTS:
            raise InputError(f"a file holds at most {container.MAX_PARTS} parts, got "
                             f"{len(parts)}; drop the tiny pieces (surfidx.topology.split_parts)")
        if not all(isinstance(p, SurfelSet) for p in parts):
            raise InputError("parts must be SurfelSets")
        if color is None:
            co = encoder_options.get("options")
            color = co.color if co is not None and co.color is not None else \
                all(p.has_color for p in parts)
        tex = encoder_options.get("texture")
        if tex is not None and color:
            from .colorgrid import TextureSource

            encoder_options["texture"] = tex if isinstance(tex, TextureSource) else \
                TextureSource(tex)
        fps = [None] * len(parts) if face_patches is None else list(face_patches)
        if len(fps) != len(parts):
            raise InputError(f"face_patches has {len(fps)} entries for {len(parts)} parts")
        self.encoders = [Encoder(p, level=level, color=color, method=method, progress=progress,
                                 face_patch=fp, **encoder_options)
                         for p, fp in zip(parts, fps)]
        self.n_surfels = sum(e.n_surfels for e in self.encoders)

    def encode(self, bits_per_surfel: float, *, progress=None) -> bytes:
        """Encode all parts at a rate over their total input surfels.

        Parameters
        ----------
        bits_per_surfel : float
            The whole file is at most ``ceil(bits_per_surfel · n_surfels / 8)`` bytes.

        Returns
        -------
        bytes

        Raises
        ------
        InputError
            When a part's share of the rate cannot hold its header.
        """
        max_bytes = max_file_bytes(bits_per_surfel, self.n_surfels)
        if len(self.encoders) == 1:
            return self.encoders[0].encode(bits_per_surfel, progress=progress)
        budgets = container.split_budget(max_bytes, [e.n_surfels for e in self.encoders])
        out = []
        for i, (e, b) in enumerate(zip(self.encoders, budgets)):
            if b < e.lowest_bytes():
                need = 8.0 * (e.lowest_bytes() * self.n_surfels / e.n_surfels
                              + container.parts_overhead(len(self.encoders))) / self.n_surfels
                raise InputError(f"{bits_per_surfel} bits/surfel leaves part {i} "
                                 f"({e.n_surfels} surfels) {b} bytes, below its smallest "
                                 f"container ({e.lowest_bytes()} bytes); use at least "
                                 f"{need:.3g} bits/surfel")
            out.append(e.encode_bytes(b, progress=progress))
        return container.pack_parts(out)


def encode_parts(parts, *, bits_per_surfel: float, level: int | None = None,
                 color: bool | None = None, method: str | None = None, progress=None,
                 **encoder_options) -> bytes:
    """One-call multi-part encoding (see :class:`PartsEncoder`)."""
    return PartsEncoder(parts, level=level, color=color, method=method, progress=progress,
                        **encoder_options).encode(bits_per_surfel)


def decode_grid(data: bytes, *, bits_per_surfel: float | None = None,
                max_surfels: int = MAX_SURFELS, path=None):
    """Decode a container to its grid layers.

    Parameters
    ----------
    data : bytes
        A ``.sfz`` container.
    bits_per_surfel : float, optional
        Decode only the prefix that fits this rate (over the header's input surfel count).
    max_surfels : int
        Refuse, before decoding, a stream whose grid has more vertices than this.
    path : str, optional
        File name for messages.

    Returns
    -------
    values : (10·4^L + 2, 3 or 6) float64
        Finite, within :data:`MAX_EXTENT` weighted units of the KLT mean.
    header : surfidx.codec.container.Header

    Raises
    ------
    BitstreamError
        Damaged, truncated or foreign data, implausible header values, or decoded values that
        are not finite or out of range.
    InputError
        A rate below what the header needs, or a grid larger than ``max_surfels``.
    """
    header, stream = container.unpack(data, path=path)
    checked = check_header(header, path=path)
    _check_surfels(header.level, header.level, max_surfels, path)
    return _decode_values(data, header, stream, bits_per_surfel, path, checked), header


def _check_surfels(level: int, stream_level: int, max_surfels, path) -> None:
    """Refuse (cheaply, before decoding) an output grid of more than ``max_surfels`` vertices."""
    limit = check_positive_int(max_surfels, "max_surfels")
    if vertex_count(level) <= limit:
        return
    fits = [lv for lv in range(stream_level + 1) if vertex_count(lv) <= limit]
    hint = (f"decode at a coarser level (level={fits[-1]}: {vertex_count(fits[-1]):,} surfels) "
            "or raise max_surfels") if fits else "raise max_surfels"
    raise InputError(f"the stream decodes to {vertex_count(level):,} surfels at grid level "
                     f"{level}, more than max_surfels = {limit:,}; {hint}", path=path)


def check_header(header, *, path=None):
    """The cheap checks of a container header that :func:`surfidx.codec.container.unpack` leaves to
    the codec, before anything is allocated: the coder header and its largest coefficient
    (:data:`MAX_COEFFICIENT`), the grid level, the density-weight field, the local frames'
    anchors and KLT basis.

    Parameters
    ----------
    header : surfidx.codec.container.Header
    path : str, optional

    Returns
    -------
    coder : dict
        The zerotree header.
    klt : KLT
    field : (values, level) or None
        The density-weight field.

    Raises
    ------
    BitstreamError
        Naming ``path``, for any implausible value.
    """
    try:
        zh = zerotree.unpack_header(header.coder)
    except BitstreamError as exc:
        raise BitstreamError(exc.reason, path=path) from None
    if not zh["step"] * 2.0 ** (zh["top_plane"] + 1) <= MAX_COEFFICIENT:
        raise BitstreamError(f"corrupt header (coder step {zh['step']:.3g} at top plane "
                             f"{zh['top_plane']}: coefficients up to "
                             f"{zh['step'] * 2.0 ** (zh['top_plane'] + 1):.3g}, beyond "
                             f"{MAX_COEFFICIENT:g})", path=path)
    if not 0 <= header.level <= MAX_LEVEL:
        raise BitstreamError(f"grid level {header.level} is out of range", path=path)
    field = None
    if header.weight_field:
        field = density.unpack_field(header.weight_field, path=path)
        if field[1] > header.level:
            raise BitstreamError(f"corrupt header (density-weight field level {field[1]} above "
                                 f"the grid level {header.level})", path=path)
    frames = header.tangent_weight is not None
    if frames and header.layers > 3 and (np.any(np.asarray(header.basis)[:3, 3:] != 0)
                                         or np.any(np.asarray(header.basis)[3:, :3] != 0)):
        raise BitstreamError("corrupt header (local frames with a KLT basis that mixes geometry "
                             "and colour)", path=path)
    if frames and (len(header.anchors) != header.level or not header.lifted
                   or any(b > a for a, b in zip(header.anchors, header.anchors[1:]))):
        raise BitstreamError(f"corrupt header (frame anchors {list(header.anchors)} for grid "
                             f"level {header.level})", path=path)
    if header.color_level is not None:
        _stream_schedule(header, zh, path)
        b = np.asarray(header.basis)
        if np.any(b[:3, 3:] != 0) or np.any(b[3:, :3] != 0):
            raise BitstreamError("corrupt header (a colour grid with a KLT basis that mixes "
                                 "geometry and colour)", path=path)
    try:
        klt = KLT.from_arrays(header.mean, header.basis, header.weights)
    except InputError as exc:
        raise BitstreamError(f"corrupt KLT header ({exc.reason})", path=path) from None
    return zh, klt, field


def _decode_values(data, header, stream, bits_per_surfel, path, checked,
                   level: int | None = None, fine: list | None = None, *,
                   geometry: bool = False) -> np.ndarray:
    """The grid values of an unpacked container whose header ``check_header`` passed (see
    :func:`decode_grid`), on the grid of ``level`` (default the stream's; a coarser one reads
    the coefficients down to that level only, see :func:`read_level`). A stream with a colour
    grid appends its decoded colour grid to ``fine`` (when given); with ``geometry``, it gives
    the x, y, z columns only (the same values) and synthesises no colour."""
    level = header.level if level is None else level
    if bits_per_surfel is not None:
        stream = stream[:_served_length(data, header, stream, bits_per_surfel)]
    zh, klt, field = checked
    if header.color_level is not None:
        values, colors = _decode_color_grid(header, stream, path, checked, level, geometry)
        if fine is not None:
            fine.append(colors)
        return values
    frames = header.tangent_weight is not None
    k = header.layers
    ico = icosphere(level)
    cut = (ico.level_of == level) if level < header.level else None
    w, planes = zerotree.decode(stream, ico.n_vertices, k, zerotree.grid_forest(level), None,
                                None, header=zh, planes=True, cut=cut)
    # the stream's level norms: coarser levels' norms depend on the finest level too
    scales = wavelets.level_norms(header.level, lifted=header.lifted)[ico.level_of]
    if field is not None:
        scales = scales * density.vertex_scales(*field, level)
    with np.errstate(over="ignore", invalid="ignore"):
        if frames:
            c = wavelets.inverse_anchored(w, level, tangent_weight=header.tangent_weight,
                                          scales=scales, anchors=header.anchors[:level],
                                          anchor_values=lambda a, rows: zerotree.anchor_values(
                                              planes, a, rows=rows, layers=3))
        else:
            c = wavelets.inverse(w / scales[:, None], level, lifted=header.lifted)
        values = klt.inverse(c)
        spread = np.abs(values * np.asarray(header.weights, np.float64)
                        - np.asarray(header.mean, np.float64))
    if not np.all(np.isfinite(values)):
        raise BitstreamError("decoding produced non-finite values: the file is damaged",
                             path=path)
    if not np.all(spread <= MAX_EXTENT):
        raise BitstreamError(f"decoding produced values {float(spread.max()):.3g} weighted units "
                             f"from the mean, beyond {MAX_EXTENT:g}: the file is damaged",
                             path=path)
    return values


def _served_length(data, header, stream, bits_per_surfel, path=None) -> int:
    """Bytes of a part's embedded ``stream`` that a rate of ``bits_per_surfel`` serves (all of
    them when None)."""
    if bits_per_surfel is None:
        return len(stream)
    keep = max_file_bytes(bits_per_surfel, header.n_surfels) - (len(data) - len(stream))
    if keep < 4:
        raise InputError(f"{bits_per_surfel} bits/surfel is below the lowest rate of this "
                         "file (header plus 4 bytes)", path=path)
    return min(keep, len(stream))


def _default_level(data, header, stream, bits_per_surfel, path) -> int:
    """The grid level a part decodes to by default (see :func:`output_levels`)."""
    return container.hinted_level(header, len(data) - len(stream) + _served_length(
        data, header, stream, bits_per_surfel, path))


def _served_parts(data: bytes, bits_per_surfel, path):
    """A container's parts, unpacked, and the rate left to serve each part at: a multi-part
    file is cut to ``bits_per_surfel`` over all its parts' surfels first (as
    :func:`surfidx.codec.container.truncate` splits it), so that its parts are served whole."""
    data = bytes(data)
    blobs = container.unpack_parts(data, path=path)
    unpacked = [container.unpack(b, path=path) for b in blobs]
    if bits_per_surfel is not None and len(blobs) > 1:
        total = sum(h.n_surfels for h, _ in unpacked)
        data = container.truncate(data, max_file_bytes(bits_per_surfel, total), path=path)
        blobs = container.unpack_parts(data, path=path)
        unpacked = [container.unpack(b, path=path) for b in blobs]
        bits_per_surfel = None
    return blobs, unpacked, bits_per_surfel


def output_levels(data: bytes, *, bits_per_surfel: float | None = None, path=None) -> list:
    """The grid level each part of a container decodes to by default (:func:`decode` without
    ``level``) at a rate.

    The stream's own level, or a coarser one where the encoder measured that the prefix served
    scores a better PSNR_D2 there: the header's output-level hints
    (:func:`surfidx.codec.container.hinted_level` of the size of the part's container served,
    see :func:`level_hints`). The bytes served decide it, so a truncated file decodes as the
    same prefix served; a file without hints (format version 5 and older, or a stream whose
    own level is best at every rate measured) decodes at its own level.

    Parameters
    ----------
    data : bytes
        A ``.sfz`` container.
    bits_per_surfel : float, optional
        The rate it is served at, as for :func:`decode`.
    path : str, optional
        Name for messages.

    Returns
    -------
    list of int
        One level per part, in part order.

    Raises
    ------
    BitstreamError
        A damaged container.
    InputError
        A rate below the file's lowest.
    """
    blobs, unpacked, bits = _served_parts(data, bits_per_surfel, path)
    return [_default_level(b, h, s, bits, path) for b, (h, s) in zip(blobs, unpacked)]


def _decode_color_grid(header, stream, path, checked, level: int, geometry: bool = False):
    """:func:`_decode_values` of a stream with a colour grid: the geometry on the grid of
    ``level``, colour on the colour grid (or, at a coarser ``level``, on its grid), and the
    colour grid's values (with ``geometry``: the geometry only, and None)."""
    zh, klt, field = checked
    full = level >= header.level
    rl = header.color_level if full else level
    ico = icosphere(rl)
    cut = (ico.level_of == rl) if rl < header.color_level else None
    groups, limits = _layout(header.level, header.color_level)
    sched = _stream_schedule(header, zh, path)
    w, planes = zerotree.decode(stream, ico.n_vertices, 6, zerotree.grid_forest(rl), None, None,
                                header=zh, planes=True, cut=cut, schedule=sched, groups=groups,
                                depth_limits=limits)
    gl = min(level, header.level)
    ng = vertex_count(gl)
    gscales = wavelets.level_norms(header.level, lifted=header.lifted)[icosphere(gl).level_of]
    if field is not None:
        gscales = gscales * density.vertex_scales(*field, gl)
    mean = np.asarray(klt.mean, np.float64)
    basis = np.asarray(klt.basis, np.float64)
    unit = np.asarray(klt.weights, np.float64)
    with np.errstate(over="ignore", invalid="ignore"):
        if header.tangent_weight is not None:
            cg = wavelets.inverse_anchored(
                np.ascontiguousarray(w[:ng, :3]), gl, tangent_weight=header.tangent_weight,
                scales=gscales, anchors=header.anchors[:gl],
                anchor_values=lambda a, rows: zerotree.anchor_values(planes, a, rows=rows,
                                                                     layers=3))
        else:
            cg = wavelets.inverse(w[:ng, :3] / gscales[:, None], gl, lifted=header.lifted)
        geo = (cg @ basis[:3, :3] + mean[:3]) / unit[:3]
        spread = float(np.abs(geo * unit[:3] - mean[:3]).max())
        col = None
        if not geometry:
            cscales = wavelets.level_norms(header.color_level,
                                           lifted=header.lifted)[ico.level_of]
            if field is not None:
                cscales = cscales * density.vertex_scales(*field, rl)
            cc = wavelets.inverse(w[:, 3:] / cscales[:, None], rl, lifted=header.lifted)
            col = (cc @ basis[3:, 3:] + mean[3:]) / unit[3:]
            spread = max(spread, float(np.abs(col * unit[3:] - mean[3:]).max()))
    if not (np.all(np.isfinite(geo)) and (col is None or np.all(np.isfinite(col)))):
        raise BitstreamError("decoding produced non-finite values: the file is damaged",
                             path=path)
    if not spread <= MAX_EXTENT:
        raise BitstreamError(f"decoding produced values {spread:.3g} weighted units "
                             f"from the mean, beyond {MAX_EXTENT:g}: the file is damaged",
                             path=path)
    return (geo, None) if geometry else (np.hstack([geo, col[:ng]]), col)


def _stream_schedule(header, zh, path):
    """The passes ``(group, plane)`` a colour-grid header's schedule stands for."""
    try:
        return zerotree.group_schedule(header.schedule, (zh["top_plane"], header.color_top),
                                       zh["final_plane"])
    except InputError:
        raise BitstreamError(f"corrupt header (a schedule of {len(header.schedule)} passes "
                             f"for top planes {zh['top_plane']} and {header.color_top})",
                             path=path) from None


def decode(data: bytes, *, bits_per_surfel: float | None = None, mesh: bool = False,
           level: int | None = None, max_surfels: int = MAX_SURFELS, path=None,
           keep_virtual: bool = False, max_vertices: int | None = None,
           texture: bool = False, texture_size: int | None = None):
    """Decode a container to surfels (or a triangle mesh with the grid's connectivity).

    Parameters
    ----------
    data : bytes
        A ``.sfz`` container (one part or several).
    bits_per_surfel : float, optional
        Serve the embedded stream at this lower rate (of a multi-part file: over all its parts'
        input surfels, split as :func:`surfidx.codec.container.truncate` does).
    mesh : bool
        Return a :class:`~surfidx.TriangleMesh` instead of a :class:`~surfidx.SurfelSet`.
    level : int, optional
        Return the decoded surface on the grid of this level (0 … the stream's level; default:
        :func:`output_levels`, the stream's level or, at the rates where the encoder measured
        that a coarser grid scores a better PSNR_D2, that grid's). Coarser grids
        are prefixes of finer ones, so this keeps the first ``10·4^level + 2`` grid values: fewer surfels of the same surface (a stream holds 4–16 grid
        vertices per input surfel, see :func:`surfidx.geometry.icosphere.choose_level`). A part whose
        grid is coarser than ``level`` is decoded at its own. The stream is read down to
        :func:`read_level` only, so time and memory follow the level asked; a stream whose
        grid is finer than that decodes to values close to, not equal to, the full decoding's.
    max_surfels : int
        Refuse, before decoding, to return more surfels than this (default :data:`MAX_SURFELS`;
        all parts together); a coarser ``level`` returns fewer.
    path : str, optional
    keep_virtual : bool
        Return the closed surface as coded. By default a stream with a virtual-region mask
        decodes to the real surface only: the grid faces over each virtual region are dropped
        and each handle cut's two boundary loops zipped together again
        (:mod:`surfidx.codec.restore`), so the mesh has the input's holes and genus;
        surfels keep the grid vertices of the kept faces (with the faces). At a coarser
        ``level`` the topology stays as long as the virtual regions stay apart on that grid
        (on the smallest grids, a few dozen vertices, nearby holes merge).
    max_vertices : int, optional
        Return at most this many vertices (surfels), all parts together: the decoded mesh
        simplified by quadric-error edge collapses (:func:`surfidx.geometry.simplify_mesh`),
        which keeps the shape far better than a coarser ``level``; surfels are then the
        simplified mesh's vertices with its normals, without faces.
    texture : bool
        With ``mesh``, return the colour of a stream that has colour as a texture instead of
        vertex colours: the image baked on the grid's atlas (:class:`surfidx.geometry.GridAtlas`)
        from the decoded colour layers as a function of sphere points
        (:func:`surfidx.geometry.bake_texture`), the mesh's ``uv``/``uv_faces`` on it and
        ``vertex_colors`` None. The parts of a multi-part file share one image, each part's
        atlas in a tile of a ``k × k`` layout (``k = ceil(sqrt(parts))``). A stream without
        colour decodes to a mesh without texture.
    texture_size : int, optional
        The image's side in texels, 64 … 8192 (default
        :func:`surfidx.geometry.default_texture_size` of the finest part's level: about two
        texels per grid edge); only with ``texture``.

    Returns
    -------
    SurfelSet or TriangleMesh
        All parts of a multi-part file together (concatenated in part order);
        ``to_trimesh()`` converts either.

    Raises
    ------
    InputError
        A level outside 0 … the stream's level, more than ``max_surfels`` surfels, a
        ``max_vertices`` that is not an integer of at least 4, ``texture`` without ``mesh`` or
        with ``max_vertices``, or a ``texture_size`` out of range.
    BitstreamError
        See :func:`decode_grid`; a damaged virtual-region mask or region table.
    """
    if max_vertices is not None:
        from ..geometry.simplify import check_max_vertices

        check_max_vertices(max_vertices)
    _texture_plan(texture, texture_size, mesh=mesh, max_vertices=max_vertices)
    parts = decode_parts(data, bits_per_surfel=bits_per_surfel, mesh=mesh, level=level,
                         max_surfels=max_surfels, path=path, keep_virtual=keep_virtual,
                         texture=texture, texture_size=texture_size)
    out = parts[0] if len(parts) == 1 else _concatenate(
        parts, mesh=mesh, name=Path(path).stem if path else None)
    if max_vertices is None or len(getattr(out, "vertices", out)) <= max_vertices:
        return out
    return _simplified(out, max_vertices)


def _texture_plan(texture, texture_size, *, mesh, max_vertices):
    """What :func:`decode` bakes: None (vertex colours) or ``{"size": texture_size}``, checked
    before anything is decoded."""
    if not isinstance(texture, (bool, np.bool_)):
        raise InputError(f"texture must be True or False, got {texture!r}")
    if not texture:
        if texture_size is not None:
            raise InputError("texture_size was given without texture=True; ask for the "
                             "texture too, or drop texture_size")
        return None
    if not mesh:
        raise InputError("texture=True needs mesh=True: surfels carry colours per surfel, a "
                         "texture needs the mesh's faces")
    if max_vertices is not None:
        raise InputError("texture=True does not combine with max_vertices (a simplified mesh "
                         "has no place on the grid's atlas); use vertex colours "
                         "(texture=False) or drop max_vertices")
    if texture_size is not None:
        from ..geometry.atlas import check_texture_size

        check_texture_size(texture_size)
    return {"size": texture_size}


def _simplified(model, max_vertices: int):
    """A decoded mesh, or surfels with the grid's faces, simplified to ``max_vertices``
    vertices (surfels: the simplified mesh's vertices, normals and cover radii, no faces)."""
    from ..geometry.mesh import TriangleMesh
    from ..geometry.simplify import simplify_mesh

    if isinstance(model, TriangleMesh):
        return simplify_mesh(model, max_vertices)
    m = simplify_mesh(TriangleMesh(model.positions, model.faces, vertex_colors=model.colors,
                                   name=model.name), max_vertices)
    s = m.to_surfels(max_edge_ratio=None)
    return SurfelSet(s.positions, s.normals, s.radii, s.colors, name=s.name)


def _concatenate(parts, *, mesh, name):
    from ..geometry.mesh import TriangleMesh

    if mesh:
        verts = [p.vertices for p in parts]
        off = np.cumsum([0] + [len(v) for v in verts[:-1]])
        faces = np.vstack([p.faces + o for p, o in zip(parts, off)])
        if all(p.texture is not None for p in parts):
            return TriangleMesh(np.vstack(verts), faces, uv=np.vstack([p.uv for p in parts]),
                                uv_faces=np.vstack([p.uv_faces + o for p, o in zip(
                                    parts, np.cumsum([0] + [len(p.uv) for p in parts[:-1]]))]),
                                texture=_tiled([p.texture for p in parts]), name=name)
        cols = [p.vertex_colors for p in parts]
        col = np.vstack(cols) if all(c is not None for c in cols) else None
        return TriangleMesh(np.vstack(verts), faces, vertex_colors=col, name=name)
    off = np.cumsum([0] + [len(p) for p in parts[:-1]])
    cols = [p.colors for p in parts]
    faces = [None if p.faces is None else p.faces + o for p, o in zip(parts, off)]
    return SurfelSet(np.vstack([p.positions for p in parts]),
                     np.vstack([p.normals for p in parts]),
                     np.concatenate([p.radii for p in parts]),
                     np.vstack(cols) if all(c is not None for c in cols) else None,
                     faces=np.vstack(faces) if all(f is not None for f in faces) else None,
                     name=name)


def _tiled(images):
    """Square images of one size in a ``k × k`` layout, row by row from the top
    (``k = ceil(sqrt(len(images)))``), empty tiles black."""
    k = int(np.ceil(np.sqrt(len(images))))
    t = images[0].shape[0]
    out = np.zeros((k * t, k * t, 3), np.uint8)
    for i, im in enumerate(images):
        r, c = divmod(i, k)
        out[r * t:(r + 1) * t, c * t:(c + 1) * t] = im
    return out


def decode_parts(data: bytes, *, bits_per_surfel: float | None = None, mesh: bool = False,
                 level: int | None = None, max_surfels: int = MAX_SURFELS, path=None,
                 keep_virtual: bool = False, texture: bool = False,
                 texture_size: int | None = None) -> list:
    """Decode every part of a container on its own (see :func:`decode`).

    With ``texture``, each part's texture coordinates address its tile of the layout that
    :func:`decode` puts the parts' images in, and each part holds its own tile-sized image.

    Returns
    -------
    list of SurfelSet or TriangleMesh
        One per part (a single-part file gives a list of one).
    """
    bake = _texture_plan(texture, texture_size, mesh=mesh, max_vertices=None)
    blobs, unpacked, bits_per_surfel = _served_parts(data, bits_per_surfel, path)
    checked = [check_header(h, path=path) for h, _ in unpacked]
    if level is not None and not (isinstance(level, (int, np.integer))
                                  and not isinstance(level, bool)
                                  and 0 <= level <= max(h.level for h, _ in unpacked)):
        raise InputError(f"level must be an integer from 0 to the stream's grid level "
                         f"{max(h.level for h, _ in unpacked)}, got {level!r}")
    levels = [_default_level(b, h, s, bits_per_surfel, path) if level is None
              else min(int(level), h.level) for b, (h, s) in zip(blobs, unpacked)]
    limit = check_positive_int(max_surfels, "max_surfels")
    if len(blobs) == 1:
        _check_surfels(levels[0], unpacked[0][0].level, limit, path)
    elif sum(vertex_count(lv) for lv in levels) > limit:
        raise InputError(f"the {len(blobs)} parts decode to "
                         f"{sum(vertex_count(lv) for lv in levels):,} surfels, more than "
                         f"max_surfels = {limit:,}; decode at a coarser level or raise "
                         "max_surfels", path=path)
    name = Path(path).stem if path else None
    tile = None
    if bake is not None:
        from ..geometry.atlas import MIN_TEXTURE_SIZE, default_texture_size

        finest = max(lv if h.color_level is None or lv < h.level else max(lv, h.color_level - 1)
                     for lv, (h, _) in zip(levels, unpacked))
        size = bake["size"] or default_texture_size(finest)
        k = int(np.ceil(np.sqrt(len(blobs))))
        tile = {"size": max(MIN_TEXTURE_SIZE, size // k), "k": k}
    out = []
    for i, (blob, (header, stream), chk, lv) in enumerate(zip(blobs, unpacked, checked, levels)):
        read = read_level(lv, header.level)
        fine = []
        values = _decode_values(blob, header, stream, bits_per_surfel, path, chk, read, fine)
        out.append(_model(values, header, lv, read, mesh=mesh, keep_virtual=keep_virtual,
                          name=name, path=path,
                          tile=None if tile is None else {**tile, "part": i,
                                                          "colors": fine[0] if fine else None}))
    return out


def _textured(mesh, grid_vertex, values, level, tile, grid_faces=None):
    """A decoded grid mesh with its colour as a texture: the image baked on the level's atlas,
    the atlas's texture coordinates in tile ``part`` of a ``k × k`` layout (``grid_faces``:
    the grid face of each of the mesh's faces, where known, for
    :func:`surfidx.geometry.atlas.atlas_uv_faces`)."""
    from ..geometry.atlas import GridColor, atlas_uv_faces, bake_texture, grid_atlas
    from ..geometry.mesh import TriangleMesh

    atlas = grid_atlas(level, size=tile["size"])
    fine = tile.get("colors")
    image = bake_texture(atlas, GridColor(values[:vertex_count(level), 3:6] if fine is None
                                          else fine))
    uv_faces = atlas_uv_faces(atlas, grid_vertex[mesh.faces], grid_faces=grid_faces)
    k = tile["k"]
    col, row = tile["part"] % k, tile["part"] // k
    uv = np.stack([(col + atlas.uv[:, 0]) / k, (k - 1 - row + atlas.uv[:, 1]) / k], 1)
    return TriangleMesh(mesh.vertices, mesh.faces, uv=uv, uv_faces=uv_faces,
                        texture=image, name=mesh.name)


def _regions(header, out_level, read, path):
    """The virtual regions of a stream at the output level (:mod:`surfidx.codec.restore`), from
    the mask's first ``10·4^read + 2`` bits: the stream's regions when ``read`` is its level;
    at a coarser ``read`` level its components stand for them, which holds while each region
    shows there as one component (else an :class:`InputError` says to read the whole grid)."""
    from .mask import decode_mask
    from .restore import check_regions, grid_regions, regions_at

    try:
        bits = decode_mask(header.mask, header.level, upto=read)
    except BitstreamError as exc:
        raise BitstreamError(exc.reason, path=path) from None
    count, region = grid_regions(bits, read)
    if read < header.level and count != len(header.regions):
        raise InputError(f"the stream's {len(header.regions)} virtual regions (holes and cut "
                         f"sides of the input) make {count} on the level-{read} grid that a "
                         f"decoding at level {out_level} reads; decode at level {header.level} "
                         "(the stream's own), or keep the virtual regions (keep_virtual=True, "
                         "--keep-virtual)", path=path)
    check_regions(header.regions, count, path=path)
    return regions_at(region, header.regions, read, out_level)


def _model(values, header, out_level, read, *, mesh, keep_virtual, name, path, tile=None):
    from ..geometry.mesh import TriangleMesh
    from .resample import grid_to_mesh, grid_to_surfels

    values = values[:vertex_count(out_level)]
    bake = mesh and tile is not None and values.shape[1] == 6
    if not header.mask or keep_virtual:
        if not mesh:
            return grid_to_surfels(values, name=name)
        m = grid_to_mesh(values, name=name)
        return _textured(m, np.arange(len(values)), values, out_level, tile) if bake else m
    from .restore import restore     # a stream with a mask only

    region, codes = _regions(header, out_level, read, path)
    r = restore(values[:, :3], out_level, region, codes)
    if mesh:
        col = None if values.shape[1] < 6 else np.clip(
            np.round(values[r.vertices, 3:6]), 0, 255).astype(np.uint8)
        m = TriangleMesh(values[r.vertices, :3], r.faces, vertex_colors=col, name=name)
        return _textured(m, r.vertices, values, out_level, tile, r.grid_faces) if bake else m
    s = grid_to_surfels(values, name=name)
    v = r.vertices
    return SurfelSet(s.positions[v], s.normals[v], s.radii[v],
                     None if s.colors is None else s.colors[v], faces=r.faces, name=name)


def stream_summary(data: bytes, *, path=None) -> dict:
    """What a file holds, without decoding its streams (the masks are decoded: cheap).

    Parameters
    ----------
    data : bytes
    path : str, optional

    Returns
    -------
    dict
        ``version`` (of the file: 4 for a multi-part file or a part with a mask, else the
        part's), ``bytes``, ``parts``, ``surfels`` (all parts), and per part (lists in part
        order): ``part_surfels``, ``part_bytes``, ``levels``, ``holes`` and ``cuts`` (virtual
        regions closing a hole, handle cuts by their two sides), ``mask_bytes`` (the mask section
        with its region table), ``virtual_share`` (share of the grid's vertices in the mask);
        and ``mask_share``: all mask sections' bytes over the file's.

    Raises
    ------
    BitstreamError
        As :func:`surfidx.codec.container.unpack_parts` and :func:`surfidx.codec.container.unpack`.
    """
    from .mask import decode_mask

    data = bytes(data)
    blobs = container.unpack_parts(data, path=path)
    out = {"version": data[4] if len(data) > 4 else None, "bytes": len(data),
           "parts": len(blobs), "part_surfels": [], "part_bytes": [], "levels": [], "holes": [],
           "cuts": [], "mask_bytes": [], "virtual_share": []}
    for b in blobs:
        h, _ = container.unpack(b, path=path)
        out["part_surfels"].append(h.n_surfels)
        out["part_bytes"].append(len(b))
        out["levels"].append(h.level)
        codes = [container.region_cut(c) for c in h.regions]
        out["holes"].append(sum(1 for k, _ in codes if k < 0))
        out["cuts"].append(len({k for k, _ in codes if k >= 0}))
        out["mask_bytes"].append(6 + len(h.mask) + 2 * len(h.regions) if h.mask else 0)
        share = 0.0
        if h.mask:
            if h.level > MAX_LEVEL:
                raise BitstreamError(f"grid level {h.level} is out of range", path=path)
            try:
                share = float(decode_mask(h.mask, h.level).mean())
            except BitstreamError as exc:
                raise BitstreamError(exc.reason, path=path) from None
        out["virtual_share"].append(share)
    out["surfels"] = sum(out["part_surfels"])
    out["mask_share"] = sum(out["mask_bytes"]) / max(len(data), 1)
    return out


def read_sfz(path) -> bytes:
    """Read a ``.sfz`` file's bytes, with a clear error when it is missing."""
    from ..errors import FileFormatError

    p = Path(path)
    if not p.exists():
        raise FileFormatError("no such file", path=p)
    if not p.is_file():
        raise FileFormatError("is not a regular file", path=p)
    try:
        with open(p, "rb") as fh:
            return fh.read()
    except OSError as exc:
        raise FileFormatError(f"cannot read ({exc.strerror or exc})", path=p) from None
