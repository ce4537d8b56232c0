"""Google Draco's point-cloud coder (through DracoPy) as the baseline of the rate-distortion benchmark.

Draco codes positions only (quantised to ``quantization_bits`` per axis over the bounding cube, then
kd-tree coded at compression level 10), optionally with the RGB colours as a lossless uint8
attribute. It codes no normals and no radii, so to evaluate its output with the same metrics as
surfidx's decoded surfels:

* **normals**: each decoded point takes the normal of its nearest *input* surfel. The metrics' D2
  uses the normals of the set searched, so the test-to-reference direction of D2 needs normals on
  Draco's points; borrowing the input's is the most favourable choice for Draco (an oracle it would
  not have at the decoder), so D2 never penalises Draco for missing normals.
* **radii**: from the decoded points' spacing (:func:`surfidx.geometry.mesh.spacing_radii`, distance to the
  6th nearest neighbour); no metric uses them.

The timings cover ``DracoPy.encode`` / ``DracoPy.decode`` only, not this evaluation bookkeeping.
Draco keeps every input point (coincident ones after coarse quantisation too), so the decoded set has
as many points as the input, in its own order.

Needs the ``bench`` extra: ``pip install DracoPy`` (tested with DracoPy 2.2, whose
``encode(points, quantization_bits=, compression_level=, colors=)`` writes a point cloud when no
faces are given, and ``decode(bytes)`` returns a ``DracoPointCloud`` with ``points`` and ``colors``).
"""

from __future__ import annotations

import time

import numpy as np

from surfidx.geometry.mesh import spacing_radii
from surfidx.geometry.surfels import SurfelSet

__all__ = ["DEFAULT_BITS", "DEFAULT_LEVEL", "draco_encode", "draco_decode", "draco_point"]

#: Quantisation settings (bits per coordinate) swept by the benchmark.
DEFAULT_BITS = tuple(range(6, 15))
#: Draco compression level (0 fastest .. 10 smallest; 10 is its best kd-tree point-cloud coding).
DEFAULT_LEVEL = 10


def dracopy():
    """The DracoPy module; without it, exit naming the extra that installs it."""
    try:
        import DracoPy
    except ImportError as exc:  # pragma: no cover - depends on the environment
        raise SystemExit("the Draco baseline needs DracoPy: pip install -e '.[bench]' "
                         f"(or pip install DracoPy) [{exc}]") from exc
    return DracoPy


def draco_encode(surfels: SurfelSet, *, bits: int, color: bool, level: int = DEFAULT_LEVEL) -> bytes:
    """Draco point-cloud bytes of the surfels' positions (and RGB colours when ``color``)."""
    DracoPy = dracopy()
    colors = surfels.colors if color else None
    return DracoPy.encode(surfels.positions.astype(np.float32), quantization_bits=int(bits),
                          compression_level=int(level), colors=colors)


def draco_decode(data: bytes, reference: SurfelSet, *, color: bool) -> SurfelSet:
    """Decode Draco bytes into a :class:`SurfelSet` evaluable against ``reference``.

    Normals are those of the nearest reference surfel, radii from the decoded points' spacing (see
    the module docstring); colours are Draco's decoded RGB attribute when ``color``.
    """
    return to_surfels(dracopy().decode(data), reference, color=color)


def to_surfels(decoded, reference: SurfelSet, *, color: bool) -> SurfelSet:
    """A decoded ``DracoPointCloud`` as surfels (normals of the nearest reference surfel)."""
    from scipy.spatial import cKDTree

    points = np.asarray(decoded.points, np.float64).reshape(-1, 3)
    _, nearest = cKDTree(reference.positions).query(points, k=1, workers=-1)
    colors = None
    if color:
        if decoded.colors is None:
            raise RuntimeError("Draco returned no colour attribute for a stream coded with colours")
        colors = np.asarray(decoded.colors, np.uint8).reshape(-1, 3)
    return SurfelSet(points, reference.normals[nearest], spacing_radii(points), colors,
                     name=reference.name)


def draco_point(surfels: SurfelSet, *, bits: int, color: bool,
                level: int = DEFAULT_LEVEL) -> tuple[bytes, SurfelSet, float, float]:
    """Encode and decode once: ``(bytes, decoded surfels, encode seconds, decode seconds)``."""
    DracoPy = dracopy()
    t0 = time.perf_counter()
    data = draco_encode(surfels, bits=bits, color=color, level=level)
    t_enc = time.perf_counter() - t0
    t0 = time.perf_counter()
    decoded = DracoPy.decode(data)
    t_dec = time.perf_counter() - t0
    return data, to_surfels(decoded, surfels, color=color), t_enc, t_dec
