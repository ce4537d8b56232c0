"""Colour on its own grid: the colour layers sampled on a finer icosahedral grid than the
geometry's, from the texture itself, and the order of geometry and colour bit planes in the
one embedded stream.

* **Level.** A textured model's colour grid has about one vertex per texel the model's
  texture coordinates cover (:func:`texels`, :func:`color_level`), at least the geometry's
  level and at most :data:`MAX_COLOR_LEVELS_ABOVE` above it (and :data:`MAX_COLOR_LEVEL`), so
  decoding stays in proportion to the stream. A model with vertex colours only keeps the
  geometry's level: its colours hold nothing finer.
* **Sampling.** Each colour-grid vertex is located in the spherical triangulation of the
  mapped surfels (:func:`surfidx.codec.resample.locate_surfels`); its preimage is the linear
  point of that triangle on the surface, and its colour is the texture's at the point of the
  textured mesh nearest that preimage (:class:`TextureSource`: barycentric in the mesh's
  triangle, then texture coordinates, then a bilinear look-up). The preimage lies on the
  input's own triangles wherever the surfels' faces are the mesh's (or their bisections), so
  the nearest point is the point itself there; on virtual patches it is the nearest real
  surface. Without a texture the surfels' colours are interpolated as
  :func:`surfidx.codec.resample.resample` does.
* **Schedule.** Geometry (layers 0–2) and colour (layers 3–5) are two groups of the zerotree
  coder (:func:`surfidx.codec.zerotree.encode_prepared`), each coded as it would be alone; the
  stream interleaves their bit-plane passes in an order stored in the header.
  :func:`rd_schedule` orders them greedily by the gain in the combined measure
  ``PSNR_D2 + color_importance · PSNR_YUV`` per bit: each pass's cost is measured by coding
  once, its distortion decrease computed exactly from the coefficients (in the wavelet domain,
  where the normalised coefficients' squared error stands for the surface's), colour
  distortion weighted to luma and chroma 6:1:1 through the colour KLT.
  :func:`fixed_schedule` is the old split: plane ``p`` of geometry, then plane ``p`` of colour.
"""

from __future__ import annotations

import numpy as np

from ..errors import InputError
from ..geometry.icosphere import vertex_count
from ..jit import njit

__all__ = ["TextureSource", "texels", "color_level", "sample_colors", "rd_schedule",
           "fixed_schedule", "pass_distortions", "luma_chroma_weights", "MAX_COLOR_LEVEL",
           "MAX_COLOR_LEVELS_ABOVE", "YUV_WEIGHTS", "ALLOCATIONS"]

MAX_COLOR_LEVEL = 8
"""Finest colour grid the encoder picks (655,362 vertices)."""

MAX_COLOR_LEVELS_ABOVE = 1
"""Most levels the colour grid lies above the geometry's (4 colour samples per geometry
vertex): the decoder's work stays in proportion to the geometry. A second level reads little
more luma at the rates the codec serves (``benchmarks/allocation.py``) and costs four times the
decoding."""

YUV_WEIGHTS = (6.0, 1.0, 1.0)
"""Weights of the Y, U and V (BT.601) squared errors in the colour distortion of the schedule
(the 6:1:1 of MPEG's combined colour PSNR)."""

ALLOCATIONS = ("rd", "fixed")
"""Bit allocations between geometry and colour: rate–distortion ordered passes
(:func:`rd_schedule`) or the fixed split of one colour weight (:func:`fixed_schedule`)."""

_YUV = np.array([[0.299, 0.587, 0.114],
                 [-0.168736, -0.331264, 0.5],
                 [0.5, -0.418688, -0.081312]])


def texels(mesh) -> float:
    """Texels of a textured mesh's texture its faces cover: the summed texture-coordinate area
    of its faces times the image's size (overlapping charts count twice).

    Parameters
    ----------
    mesh : TriangleMesh
        With ``uv``, ``uv_faces`` and ``texture``.

    Returns
    -------
    float
    """
    uv = np.asarray(mesh.uv, np.float64)[np.asarray(mesh.uv_faces)]
    d1, d2 = uv[:, 1] - uv[:, 0], uv[:, 2] - uv[:, 0]
    area = 0.5 * np.abs(d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0]).sum()
    h, w = np.asarray(mesh.texture).shape[:2]
    return float(area * h * w)


def color_level(level: int, texel_count: float | None) -> int:
    """The colour grid's level for a geometry grid of ``level``: the coarsest with at least
    ``texel_count`` vertices, within ``level`` … ``min(level + MAX_COLOR_LEVELS_ABOVE,
    MAX_COLOR_LEVEL)`` (``level`` without a texture).

    Parameters
    ----------
    level : int
    texel_count : float or None
        :func:`texels` of the model's texture; None: vertex colours only.

    Returns
    -------
    int
    """
    top = max(level, min(level + MAX_COLOR_LEVELS_ABOVE, MAX_COLOR_LEVEL))
    if texel_count is None:
        return level
    lc = level
    while lc < top and vertex_count(lc) < texel_count:
        lc += 1
    return lc


class TextureSource:
    """A textured mesh as a colour function of points on (or near) its surface: the texture at
    the nearest surface point (module notes).

    Parameters
    ----------
    mesh : TriangleMesh
        With ``uv``, ``uv_faces`` and ``texture``; the nearest surface point is exact
        (:func:`surfidx.geometry.closest.closest_points`).

    Raises
    ------
    InputError
        A mesh without a texture.
    """

    def __init__(self, mesh):
        if getattr(mesh, "texture", None) is None or mesh.uv is None or mesh.uv_faces is None:
            raise InputError("a TextureSource needs a mesh with texture coordinates and a "
                             "texture image")
        self.mesh = mesh
        self.vertices = np.ascontiguousarray(mesh.vertices, np.float64)
        self.faces = np.ascontiguousarray(mesh.faces, np.int64)
        self.texels = texels(mesh)

    def __call__(self, points) -> np.ndarray:
        """(n, 3) float64 colours (0..255) at points (n, 3) float64."""
        from ..geometry.mesh import sample_texture

        from ..geometry.closest import closest_points

        face, bary, _ = closest_points(np.ascontiguousarray(points, np.float64), self.vertices,
                                       self.faces)
        uv = np.einsum("ij,ijk->ik", bary, np.asarray(self.mesh.uv, np.float64)[
            np.asarray(self.mesh.uv_faces)[face]])
        return sample_texture(np.asarray(self.mesh.texture), uv)


def sample_colors(surfels, sphere_points, level: int, *, texture=None,
                  location=None) -> np.ndarray:
    """The colour layers on the level-``level`` grid (module notes).

    Parameters
    ----------
    surfels : SurfelSet
    sphere_points : (n, 3) float64
    level : int
    texture : TextureSource, optional
        Sample this texture; default the surfels' colours.
    location : tuple, optional
        :func:`surfidx.codec.resample.locate_surfels` of the surfels at ``level``.

    Returns
    -------
    (10·4^level + 2, 3) float64
        r, g, b in 0..255.
    """
    from .resample import locate_surfels

    if location is None:
        location = locate_surfels(surfels, sphere_points, level)
    tri, idx, bary = location[:3]
    corners = np.take(tri, idx, axis=0)
    if texture is None:
        col = np.asarray(surfels.colors, np.float64)
        return np.einsum("qk,qkl->ql", bary, col[corners])
    pos = np.asarray(surfels.positions, np.float64)
    points = np.einsum("qk,qkl->ql", bary, pos[corners])
    return texture(points)


def pass_distortions(coeffs, step: float, top: int, final: int, weights) -> np.ndarray:
    """The weighted squared error of coefficients coded down to each plane.

    Parameters
    ----------
    coeffs : (n, k) float64
    step : float
    top, final : int
        The group's planes.
    weights : (k,) float64
        Weight of each layer's squared error.

    Returns
    -------
    (top - final + 2,) float64
        Before any pass, then after the pass of each plane ``top`` … ``final``.
    """
    c = np.asarray(coeffs, np.float64)
    a = np.abs(c)
    q = np.floor(a / step + 0.5).astype(np.int64)
    w = np.asarray(weights, np.float64)
    out = [float((c * c).sum(axis=0) @ w)]
    planes = np.arange(int(top), int(final) - 1, -1, dtype=np.int64)
    fracs = np.array([(2.0 ** (p - 1) - 0.5) if p > 0 else 0.0 for p in planes.tolist()])
    sums = _plane_squared_errors(np.ascontiguousarray(a), np.ascontiguousarray(q), planes,
                                 fracs, float(step))
    out += [float(row @ w) for row in sums]
    return np.array(out)


@njit(cache=True)
def _plane_squared_errors(a, q, planes, fracs, step):
    """Per plane and layer, the sum over coefficients of ``(|c| - r)**2``, ``r`` the
    reconstruction once plane ``p`` is coded: ``(kept + frac) · step`` for
    ``kept = (q >> p) << p > 0``, else 0.

    Parameters
    ----------
    a : (n, k) float64
        ``|c|``.
    q : (n, k) int64
        Quantised magnitudes.
    planes : (m,) int64
    fracs : (m,) float64
        ``frac`` of each plane.
    step : float

    Returns
    -------
    (m, k) float64
        The same operations as the array expression ``(err * err).sum(axis=0)``, element by
        element and summed over the coefficients in order, as numpy sums the rows of a
        C-contiguous array along axis 0 (so the caller's figures are bit-identical), in one
        pass over the coefficients for all planes.
    """
    n, k = a.shape
    m = planes.shape[0]
    out = np.zeros((m, k), dtype=np.float64)
    for i in range(n):
        for j in range(k):
            qi = q[i, j]
            ai = a[i, j]
            for t in range(m):
                p = planes[t]
                kept = (qi >> p) << p
                r = (np.float64(kept) + fracs[t]) * step if kept > 0 else 0.0
                e = ai - r
                out[t, j] += e * e
    return out


def fixed_schedule(top: int, color_top: int, final: int) -> tuple:
    """The old split: for each plane from the top, geometry's pass then colour's.

    Returns
    -------
    tuple of int
        The group of each pass (0 geometry, 1 colour).
    """
    order = []
    for p in range(max(top, color_top), final - 1, -1):
        if p <= top:
            order.append(0)
        if p <= color_top:
            order.append(1)
    return tuple(order)


def _chunks(gain, bits):
    """A group's passes in chunks of best gain per bit: from each point, the run of next
    passes with the highest mean slope (the upper hull)."""
    out = []
    i = 0
    n = len(gain)
    while i < n:
        g = np.cumsum(gain[i:])
        b = np.cumsum(bits[i:])
        slope = g / np.maximum(b, 1e-9)
        j = int(np.argmax(slope))
        out.append((float(slope[j]), j + 1))
        i += j + 1
    return out


def rd_schedule(gains_geo, bits_geo, gains_col, bits_col, importance: float) -> tuple:
    """The passes of two groups ordered by gain per bit (module notes).

    Parameters
    ----------
    gains_geo, gains_col : (m,) float64
        dB gain of each pass in its group's PSNR.
    bits_geo, bits_col : (m,) float64
        Measured cost of each pass.
    importance : float
        Weight of the colour PSNR in the combined measure.

    Returns
    -------
    tuple of int
        The group of each pass (0 geometry, 1 colour).
    """
    a = _chunks(np.asarray(gains_geo, np.float64), np.asarray(bits_geo, np.float64))
    b = _chunks(importance * np.asarray(gains_col, np.float64), np.asarray(bits_col, np.float64))
    order = []
    i = j = 0
    while i < len(a) or j < len(b):
        if j >= len(b) or (i < len(a) and a[i][0] >= b[j][0]):
            order += [0] * a[i][1]
            i += 1
        else:
            order += [1] * b[j][1]
            j += 1
    return tuple(order)


def luma_chroma_weights(basis_color) -> np.ndarray:
    """Weight of each colour KLT layer's squared error in the 6:1:1 YUV distortion.

    Parameters
    ----------
    basis_color : (3, 3) float64
        The colour block of the KLT basis (rows: directions in weighted r, g, b).

    Returns
    -------
    (3,) float64
    """
    b = np.asarray(basis_color, np.float64)
    proj = (b @ _YUV.T) ** 2          # (layer, Y/U/V)
    return proj @ np.asarray(YUV_WEIGHTS) / sum(YUV_WEIGHTS)


