"""The codec's settings, in one frozen object: the rate of the stored stream and the weights
that split its bits (:class:`CodecOptions`)."""

from __future__ import annotations

from dataclasses import dataclass

from ..geometry.icosphere import MAX_LEVEL
from ..validate import check_option_fields, option

__all__ = ["CodecOptions", "COLOR_WEIGHT", "TANGENT_WEIGHT", "MAX_COLOR_WEIGHT",
           "DEFAULT_BITS_PER_SURFEL", "COLOR_IMPORTANCE", "MAX_COLOR_IMPORTANCE", "ALLOCATION"]

DEFAULT_BITS_PER_SURFEL = 8.0
"""Full rate of a stored stream, bits per input surfel (lower rates are served by truncation)."""

COLOR_WEIGHT = 0.02
"""Unit weight of colour (in units of 255) against geometry (in units of the bounding-box
diagonal).

With ``allocation="fixed"`` it splits the bits between geometry and texture (both groups'
planes in one order): this value gave the best sum of PSNR_D2 and luma PSNR on the textured
models of ``benchmarks/color_weight.py``. With ``allocation="rd"`` (the default) the order of
the planes is chosen by :data:`COLOR_IMPORTANCE` and this weight only sets the colour layers'
quantisation units.
"""

COLOR_IMPORTANCE = 1.0
"""Weight of colour fidelity in the combined distortion measure the coder minimises:
``PSNR_D2 + color_importance · PSNR_YUV`` (YUV 6:1:1). The coder spends each next bit-plane pass
where it raises this measure most per bit (:mod:`surfidx.codec.colorgrid`);
``benchmarks/allocation.py`` prints the measure, PSNR_D2 and luma PSNR at several values and
rates, and the fixed split beside them."""

MAX_COLOR_IMPORTANCE = 1e3
"""Largest ``color_importance``."""

ALLOCATION = "rd"
"""Default bit allocation between geometry and colour (``"rd"`` or ``"fixed"``)."""

TANGENT_WEIGHT = 0.5
"""Weight of the tangential geometry components in local frames (see :mod:`surfidx.codec.encoder`)."""

MAX_COLOR_WEIGHT = 1e3
"""Largest ``color_weight`` the encoder takes (so colours stay within the decoder's extent)."""


@dataclass(frozen=True)
class CodecOptions:
    """Settings of :class:`surfidx.codec.Encoder` and the rate of the stored stream.

    Attributes
    ----------
    bits_per_surfel : float
        Full rate of the stored stream (lower rates are served by truncation).
    level : int or None
        Icosahedral grid level (None: the map's ``grid_level``).
    color : bool or None
        Code colour (None: when the surfels have it).
    color_weight : float
        Unit weight of colour against geometry, in (0, :data:`MAX_COLOR_WEIGHT`]: with
        ``allocation="fixed"`` it splits the bits (both groups' planes in one order); with
        ``"rd"`` it only sets the colour layers' quantisation units.
    color_importance : float
        Weight of colour in the combined measure ``PSNR_D2 + color_importance · PSNR_YUV``
        that ``allocation="rd"`` maximises, in (0, :data:`MAX_COLOR_IMPORTANCE`].
    allocation : {"rd", "fixed"}
        Order of geometry and colour bit planes in the stream: by gain of the combined measure
        per bit, or plane by plane (the split ``color_weight`` gives).
    color_level : int or None
        Grid level of the colour layers (None: from the texture's texels the model covers,
        the geometry's level for vertex colours; :func:`surfidx.codec.colorgrid.color_level`);
        at least the geometry's.
    tangent_weight : float or None
        Weight in (0, 1] of the tangential components of local frames (None: x, y, z details,
        no frames). The container stores it float32-rounded.
    density_weighting : bool or None
        Weight coefficients by the surfel density on the sphere (None: when its estimated gain
        is worth it, :mod:`surfidx.codec.density`).
    level_hints : bool
        Measure, on prefixes of the coded stream, the grid level that gives the best PSNR_D2
        against the input and store where the default output level steps down
        (:func:`surfidx.codec.encoder.level_hints`; a few decodings of the stream, and an
        output-level section of :data:`~surfidx.codec.container.HINT_SECTION_BYTES` bytes, so
        container format 6). Off by default: the measurement adds a fifth to a half to the
        encoding's CPU time (``benchmarks/output_level.py``,
        ``docs/benchmarks/output_level.md``) for gains mostly below 1.5 bits per surfel;
        without it a stream (format 5, 4 or 3) decodes at its own level at every rate.
    """

    bits_per_surfel: float = option(DEFAULT_BITS_PER_SURFEL, min=0, min_open=True)
    level: int | None = option(None, max=MAX_LEVEL)
    color: bool | None = None
    color_weight: float = option(COLOR_WEIGHT, min=0, min_open=True, max=MAX_COLOR_WEIGHT)
    color_importance: float = option(COLOR_IMPORTANCE, min=0, min_open=True,
                                     max=MAX_COLOR_IMPORTANCE)
    allocation: str = option(ALLOCATION, choices=("rd", "fixed"))
    color_level: int | None = option(None, max=MAX_LEVEL)
    tangent_weight: float | None = option(TANGENT_WEIGHT, min=0, min_open=True, max=1)
    density_weighting: bool | None = None
    level_hints: bool = False

    def __post_init__(self):
        check_option_fields(self)
