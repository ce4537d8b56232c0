"""Distortion measures between two surfel sets, as the point-cloud compression field defines them.

The definitions follow MPEG's ``pc_error`` tool (the metric software of the G-PCC/V-PCC
standards), symmetric version:

* **D1 (point-to-point)**: every point ``b`` of the probed set finds its nearest neighbour ``a`` in
  the searched set; its error is ``|b - a|^2``.
* **D2 (point-to-plane)**: the same pairs; the error is ``((b - a) . n_a)^2``, the offset projected
  on the normal of the point found in the searched set.
* The mean squared error of one direction is the mean over the probed points. The symmetric MSE is
  the larger of the two directions (reference searched with the test points probed, and the
  test searched with the reference points probed).
* ``PSNR = 10 log10(peak^2 / MSE) = 20 log10(peak / RMS)`` with ``peak`` the bounding-box diagonal
  of the **reference** (pc_error's ``-r`` set to the diagonal).
* **Luma**: ``Y = 0.2126 R + 0.7152 G + 0.0722 B`` (BT.709, as pc_error), squared difference of Y
  between nearest neighbours in both directions, the larger MSE, peak 255.
* **Luma on the surface** (:func:`psnr_luma_surface`, for coloured meshes): each mesh is sampled
  uniformly over its area; every sample's colour is compared with the other mesh's colour at the
  closest point of its surface (vertex colours interpolated, or the texture read there), both
  directions, the larger MSE, peak 255. Two independent samplings of one textured mesh agree
  exactly, whereas nearest-neighbour pairing of two samplings (:func:`psnr_luma`) misreads every
  pair that straddles a sharp edge of the texture: its floor falls with the texture's contrast.
* **Hausdorff**: the largest nearest-neighbour distance over both directions, divided by the peak
  (a relative distance; multiply by ``peak`` for model units).

An MSE of exactly zero (identical geometry or colours) gives a PSNR of ``inf``.

Nearest neighbours come from :class:`scipy.spatial.cKDTree` queried on all cores; when several
points are at the same distance the tree's choice is kept (it changes D2 and luma, never D1).
"""

from __future__ import annotations

import math

import numpy as np

from ..errors import InputError
from ..validate import as_array, check_positive_int
from .mesh import TriangleMesh
from .surfels import SurfelSet

__all__ = ["LUMA_WEIGHTS", "SURFACE_SAMPLES", "psnr_d1", "psnr_d2", "psnr_luma",
           "psnr_luma_surface", "hausdorff", "evaluate", "Reference"]

#: BT.709 luma weights of R, G, B (those of MPEG's pc_error).
LUMA_WEIGHTS = (0.2126, 0.7152, 0.0722)

_COLOR_PEAK = 255.0

#: Uniform samples per mesh of :func:`psnr_luma_surface` (its default).
SURFACE_SAMPLES = 200_000

# Points per KD query block of Reference._probed: large enough that a block's query overhead is
# small, small enough that a test set far below a floor stops after a few blocks.
_PROBE_BLOCK = 1 << 17


# ---------------------------------------------------------------------- kernels (private)
class _Pairs:
    """Nearest neighbours both ways between a reference and a test set, computed once.

    ``fwd`` pairs each test point with its nearest reference point (reference searched), ``bwd``
    each reference point with its nearest test point (test searched).
    """

    def __init__(self, reference: SurfelSet, test: SurfelSet):
        self.reference, self.test = reference, test
        self.d_fwd, self.i_fwd = _nearest(_tree(reference), test.positions)
        self.d_bwd, self.i_bwd = _nearest(_tree(test), reference.positions)

    def mse_d1(self) -> float:
        return max(float(np.mean(self.d_fwd ** 2)), float(np.mean(self.d_bwd ** 2)))

    def mse_d2(self) -> float:
        r, t = self.reference, self.test
        return max(_mse_d2(t, r, self.i_fwd), _mse_d2(r, t, self.i_bwd))

    def mse_luma(self) -> float:
        yr, yt = _luma(self.reference.colors), _luma(self.test.colors)
        fwd = (yt - yr[self.i_fwd]) ** 2
        bwd = (yr - yt[self.i_bwd]) ** 2
        return max(float(np.mean(fwd)), float(np.mean(bwd)))

    def max_distance(self) -> float:
        return max(float(self.d_fwd.max()), float(self.d_bwd.max()))


def _tree(s: SurfelSet):
    """The KD-tree of a set's positions."""
    from scipy.spatial import cKDTree

    return cKDTree(s.positions)


def _nearest(tree, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Distance ``(q,)`` and index ``(q,)`` of the point of ``tree`` nearest each of ``points``
    ``(q, 3)`` (queried on all cores: the answers do not depend on their number)."""
    return tree.query(points, k=1, workers=-1)


def _mse_d2(probed: SurfelSet, searched: SurfelSet, found: np.ndarray) -> float:
    """One direction's D2 MSE: ``probed``'s points against ``searched``'s points ``found``
    ``(n,)`` nearest to them."""
    return float(np.mean(_plane_errors(probed.positions, searched.positions[found],
                                       searched.normals[found])))


def _plane_errors(probe: np.ndarray, found: np.ndarray, found_normals: np.ndarray) -> np.ndarray:
    """(n,) squared offsets ``((probe - found) . n_found)^2``."""
    return np.einsum("ij,ij->i", probe - found, found_normals) ** 2


def _luma(colors: np.ndarray) -> np.ndarray:
    """(n,) float64 BT.709 luma of (n, 3) RGB colours (uint8, or float64 in 0..255)."""
    return colors.astype(np.float64) @ np.asarray(LUMA_WEIGHTS)


def _surface_samples(mesh: TriangleMesh, count: int, seed: int):
    """``count`` points uniform over the mesh's area: positions ``(count, 3)``, faces
    ``(count,)`` and barycentric coordinates ``(count, 3)``."""
    areas = mesh.face_areas()
    rng = np.random.default_rng(seed)
    cdf = np.cumsum(areas)
    face = np.minimum(np.searchsorted(cdf, rng.random(count) * cdf[-1], side="right"),
                      len(areas) - 1)
    r1, r2 = np.sqrt(rng.random(count)), rng.random(count)
    bary = np.stack([1 - r1, r1 * (1 - r2), r1 * r2], axis=1)
    pos = np.einsum("nc,ncd->nd", bary, mesh.vertices[mesh.faces[face]])
    return pos, face, bary


def _surface_luma_mse(probed: TriangleMesh, searched: TriangleMesh, count: int,
                      seed: int) -> float:
    """One direction of :func:`psnr_luma_surface`: ``probed`` sampled, each sample's luma
    against ``searched``'s at the closest point of its surface."""
    from .closest import closest_points

    pos, face, bary = _surface_samples(probed, count, seed)
    found, found_bary, _ = closest_points(pos, searched.vertices, searched.faces)
    diff = _luma(probed.colors_at(face, bary)) - _luma(searched.colors_at(found, found_bary))
    return float(np.mean(diff * diff))


def _psnr(mse: float, peak: float) -> float:
    """``10 log10(peak^2 / mse)``; ``inf`` when ``mse`` is zero, ``-inf`` when it is ``inf``."""
    if mse <= 0.0:
        return math.inf
    if mse == math.inf:
        return -math.inf
    return 10.0 * math.log10(peak * peak / mse)


# ---------------------------------------------------------------------- validation
def _sample(n: int, samples: int, seed: int) -> np.ndarray:
    """Sorted indices of ``min(n, samples)`` of ``n`` points drawn without replacement by
    ``numpy.random.default_rng(seed)`` (all of them when ``n <= samples``)."""
    if n <= samples:
        return np.arange(n)
    return np.sort(np.random.default_rng(seed).choice(n, samples, replace=False))


def _check_set(name, s) -> None:
    if not isinstance(s, SurfelSet):
        raise InputError(f"{name} must be a SurfelSet, got {type(s).__name__}; read files "
                         "with surfidx.read_surfels")
    if len(s) == 0:
        raise InputError(f"the {name} surfel set is empty; distortion needs at least one "
                         "surfel on each side")


def _check_sets(reference, test, *, luma: bool = False) -> None:
    for name, s in (("reference", reference), ("test", test)):
        _check_set(name, s)
    if luma and not (reference.has_color and test.has_color):
        missing = [n for n, s in (("reference", reference), ("test", test)) if not s.has_color]
        raise InputError(f"luma PSNR needs colours on both sets; the {' and '.join(missing)} "
                         f"set{'s have' if len(missing) == 2 else ' has'} none")


def _peak(reference: SurfelSet, peak) -> float:
    if peak is None:
        value = reference.diagonal
        if not value > 0:
            raise InputError("the reference's bounding-box diagonal is zero (all its surfels "
                             "coincide), so it gives no PSNR peak; pass peak= explicitly")
        return value
    value = float(as_array([peak], "peak", shape=(1,))[0])
    if not value > 0:
        raise InputError(f"peak must be a positive number, got {value!r}")
    return value


# ---------------------------------------------------------------------- public API
def psnr_d1(reference: SurfelSet, test: SurfelSet, *, peak: float | None = None) -> float:
    """Symmetric point-to-point (D1) geometry PSNR in dB.

    Parameters
    ----------
    reference : SurfelSet
        The original; its bounding-box diagonal is the peak.
    test : SurfelSet
        The distorted set (any number of surfels).
    peak : float, optional
        Peak signal instead of the reference's bounding-box diagonal (model units).

    Returns
    -------
    float
        ``10 log10(peak^2 / MSE)``, MSE the larger of the two directions' mean squared
        nearest-neighbour distances; ``inf`` when every point of each set lies on a point of the
        other.

    Raises
    ------
    InputError
        When a set is empty or not a :class:`SurfelSet`, or the peak is not positive.
    """
    _check_sets(reference, test)
    return _psnr(_Pairs(reference, test).mse_d1(), _peak(reference, peak))


def psnr_d2(reference: SurfelSet, test: SurfelSet, *, peak: float | None = None) -> float:
    """Symmetric point-to-plane (D2) geometry PSNR in dB.

    The error of a probed point is its offset to its nearest neighbour projected on that
    neighbour's normal, so displacements along the surface cost nothing: for the same pairs D2
    never exceeds D1 and ``psnr_d2 >= psnr_d1``.

    Parameters
    ----------
    reference : SurfelSet
        The original; its bounding-box diagonal is the peak.
    test : SurfelSet
        The distorted set.
    peak : float, optional
        Peak signal instead of the reference's bounding-box diagonal.

    Returns
    -------
    float
        PSNR in dB; ``inf`` for zero error.

    Raises
    ------
    InputError
        When a set is empty or not a :class:`SurfelSet`, or the peak is not positive.
    """
    _check_sets(reference, test)
    return _psnr(_Pairs(reference, test).mse_d2(), _peak(reference, peak))


def psnr_luma(reference: SurfelSet, test: SurfelSet) -> float:
    """Symmetric luma (Y, BT.709) PSNR in dB between nearest neighbours, peak 255.

    Parameters
    ----------
    reference : SurfelSet
        With colours.
    test : SurfelSet
        With colours.

    Returns
    -------
    float
        PSNR in dB; ``inf`` when the nearest neighbours' lumas agree exactly.

    Raises
    ------
    InputError
        When a set is empty, not a :class:`SurfelSet`, or either lacks colours.
    """
    _check_sets(reference, test, luma=True)
    return _psnr(_Pairs(reference, test).mse_luma(), _COLOR_PEAK)


def _check_coloured_mesh(name, mesh) -> None:
    if not isinstance(mesh, TriangleMesh):
        raise InputError(f"{name} must be a TriangleMesh, got {type(mesh).__name__}; read it "
                         "with surfidx.read_mesh (or decode with mesh=True)")
    if not len(mesh.faces) or not mesh.face_areas().sum() > 0:
        raise InputError(f"the {name} mesh has no surface (no faces, or zero total area)")
    textured = mesh.texture is not None and mesh.uv is not None and mesh.uv_faces is not None
    if mesh.vertex_colors is None and not textured:
        raise InputError(f"the {name} mesh has no colour (no vertex colours, and no texture "
                         "with texture coordinates); read it with its texture")


def psnr_luma_surface(reference: TriangleMesh, test: TriangleMesh, *,
                      samples: int = SURFACE_SAMPLES, seed: int = 0) -> float:
    """Symmetric luma (Y, BT.709) PSNR in dB between two coloured surfaces, peak 255.

    Each mesh is sampled at ``samples`` points uniform over its area (colours from its vertex
    colours or its texture, unrounded); every sample is compared with the other mesh's colour at
    the closest point of that mesh's surface. The MSE is the larger of the two directions. Since
    colours are compared at the same surface point (up to rounding), the measure has no
    sampling floor: a mesh against itself reads far above any coding error, with any seed.

    Parameters
    ----------
    reference : TriangleMesh
        The original, with vertex colours or a texture.
    test : TriangleMesh
        The decoded model, with vertex colours or a texture.
    samples : int
        Points sampled on each mesh (default :data:`SURFACE_SAMPLES`).
    seed : int
        Seed of the sampling (the test mesh uses ``seed + 1``).

    Returns
    -------
    float
        PSNR in dB; ``inf`` when the colours agree exactly.

    Raises
    ------
    InputError
        When a mesh is not a :class:`TriangleMesh`, has no surface or no colour, or
        ``samples`` is not a positive integer.
    """
    _check_coloured_mesh("reference", reference)
    _check_coloured_mesh("test", test)
    count = check_positive_int(samples, "samples")
    mse = max(_surface_luma_mse(reference, test, count, seed),
              _surface_luma_mse(test, reference, count, seed + 1))
    return _psnr(mse, _COLOR_PEAK)


def hausdorff(reference: SurfelSet, test: SurfelSet, *, peak: float | None = None) -> float:
    """Symmetric Hausdorff distance between the point sets, relative to the peak.

    Parameters
    ----------
    reference : SurfelSet
    test : SurfelSet
    peak : float, optional
        Divisor instead of the reference's bounding-box diagonal (``peak=1`` gives model units).

    Returns
    -------
    float
        ``max(max_b min_a |b - a|, max_a min_b |a - b|) / peak``; 0 for identical point sets.

    Raises
    ------
    InputError
        When a set is empty or not a :class:`SurfelSet`, or the peak is not positive.
    """
    _check_sets(reference, test)
    return _Pairs(reference, test).max_distance() / _peak(reference, peak)


def evaluate(reference: SurfelSet, test: SurfelSet, *, peak: float | None = None) -> dict:
    """All distortion measures at once (the nearest neighbours are searched only once).

    Parameters
    ----------
    reference : SurfelSet
    test : SurfelSet
    peak : float, optional
        Peak instead of the reference's bounding-box diagonal.

    Returns
    -------
    dict
        ``psnr_d1``, ``psnr_d2`` (dB, ``inf`` for zero error), ``psnr_y`` (dB, or ``None`` when
        either set lacks colour), ``hausdorff`` (relative to the peak), ``rmse_d1``, ``rmse_d2``
        (model units, symmetric), ``peak``, ``n_reference``, ``n_test``.

    Raises
    ------
    InputError
        When a set is empty or not a :class:`SurfelSet`, or the peak is not positive.
    """
    _check_sets(reference, test)
    p = _peak(reference, peak)
    pairs = _Pairs(reference, test)
    mse1, mse2 = pairs.mse_d1(), pairs.mse_d2()
    psnr_y = None
    if reference.has_color and test.has_color:
        psnr_y = _psnr(pairs.mse_luma(), _COLOR_PEAK)
    return {
        "psnr_d1": _psnr(mse1, p),
        "psnr_d2": _psnr(mse2, p),
        "psnr_y": psnr_y,
        "hausdorff": pairs.max_distance() / p,
        "rmse_d1": math.sqrt(mse1),
        "rmse_d2": math.sqrt(mse2),
        "peak": p,
        "n_reference": len(reference),
        "n_test": len(test),
    }


class Reference:
    """A reference surfel set that many test sets are measured against: its KD-tree is built
    once (:func:`psnr_d2` builds both sets' trees on every call).

    Parameters
    ----------
    reference : SurfelSet
        The original; its bounding-box diagonal is the peak.
    peak : float, optional
        Peak signal instead of the reference's bounding-box diagonal.

    Raises
    ------
    InputError
        When the set is empty or not a :class:`SurfelSet`, or the peak is not positive.

    Examples
    --------
    >>> ref = Reference(surfels)                                  # doctest: +SKIP
    >>> ref.psnr_d2(decoded) == psnr_d2(surfels, decoded)        # doctest: +SKIP
    True
    """

    def __init__(self, reference: SurfelSet, *, peak: float | None = None):
        _check_set("reference", reference)
        self.surfels = reference
        self.peak = _peak(reference, peak)
        self._tree = _tree(reference)
        self._directions = [self._probed, self._searched]   # the last to fail a floor first
        self._samples = {}   # (samples, seed) -> the reference's sample (psnr_d2_sampled)

    def _probed(self, test: SurfelSet, limit: float = math.inf) -> float:
        """D2 MSE of the test points against the reference (the reference searched).

        The points go in blocks of :data:`_PROBE_BLOCK`; once the errors summed so far exceed
        ``limit`` times the point count (with a margin far above rounding), the MSE exceeds
        ``limit`` whatever the rest add, and ``inf`` is returned. Otherwise the errors are those
        of one query of all points, so the MSE is the same to the bit."""
        pos = test.positions
        budget = limit * len(pos) * (1.0 + 1e-9)
        errors, total = [], 0.0
        for start in range(0, len(pos), _PROBE_BLOCK):
            block = pos[start:start + _PROBE_BLOCK]
            found = _nearest(self._tree, block)[1]
            err = _plane_errors(block, self.surfels.positions[found], self.surfels.normals[found])
            total += float(err.sum())
            if total > budget:
                return math.inf
            errors.append(err)
        return float(np.mean(np.concatenate(errors)))

    def _searched(self, test: SurfelSet, limit: float = math.inf) -> float:
        """D2 MSE of the reference points against the test set (the test set searched; the
        test set's tree is the cost, so ``limit`` stops nothing early)."""
        found = _nearest(_tree(test), self.surfels.positions)[1]
        return _mse_d2(self.surfels, test, found)

    def psnr_d2(self, test: SurfelSet) -> float:
        """:func:`psnr_d2` of ``test`` against the reference, in dB."""
        _check_set("test", test)
        return _psnr(max(self._probed(test), self._searched(test)), self.peak)

    def psnr_d2_sampled(self, test: SurfelSet, samples: int, *, seed: int = 0) -> float:
        """:func:`psnr_d2` estimated from at most ``samples`` points of each set, in dB.

        Each direction probes a sample and searches the whole other set: ``samples`` test points
        (drawn by ``numpy.random.default_rng(seed)``) against the reference's tree, and as many
        reference points (drawn by the same seed, once per reference) against a tree of all the
        test points, so each point keeps its true nearest neighbour and only the mean is
        estimated. The cost then follows ``samples`` and the test set's tree, whatever the sizes
        of the sets; a set no larger than ``samples`` is used whole.

        Parameters
        ----------
        test : SurfelSet
        samples : int
            Points probed per direction, at least 1.
        seed : int

        Returns
        -------
        float

        Raises
        ------
        InputError
            An empty or non-SurfelSet ``test``, or ``samples`` below 1.
        """
        _check_set("test", test)
        return self._sampled(test.positions, test.normals, check_positive_int(samples, "samples"),
                             seed)

    def psnr_d2_sampled_points(self, positions, normals, samples: int, *,
                               seed: int = 0) -> float:
        """:meth:`psnr_d2_sampled` of a test set given as arrays, without building a
        :class:`SurfelSet` (whose checks cost as much as the estimate on a large set): the same
        figure, to the bit, as for ``SurfelSet(positions, normals, radii)``.

        Parameters
        ----------
        positions : (n, 3) float64
            At least one point.
        normals : (n, 3) float64
            Unit normals (used as given).
        samples : int
        seed : int

        Returns
        -------
        float

        Raises
        ------
        InputError
            Arrays of other shapes, or ``samples`` below 1.
        """
        positions = as_array(positions, "positions", shape=(None, 3))
        normals = as_array(normals, "normals", shape=(len(positions), 3))
        if len(positions) == 0:
            raise InputError("the test set is empty; give at least one point")
        return self._sampled(positions, normals, check_positive_int(samples, "samples"), seed)

    def _sampled(self, positions, normals, samples: int, seed: int) -> float:
        from scipy.spatial import cKDTree

        key = (samples, seed)
        if key not in self._samples:
            self._samples[key] = _sample(len(self.surfels), samples, seed)
        ref = self._samples[key]
        probe = positions[_sample(len(positions), samples, seed)]
        found = self._tree.query(probe, k=1)[1]
        fwd = _plane_errors(probe, self.surfels.positions[found], self.surfels.normals[found])
        # unbalanced, uncompacted: built in about half the time, the same nearest neighbours
        tree = cKDTree(positions, balanced_tree=False, compact_nodes=False)
        pos = self.surfels.positions[ref]
        found = tree.query(pos, k=1)[1]
        bwd = _plane_errors(pos, positions[found], normals[found])
        return _psnr(max(float(np.mean(fwd)), float(np.mean(bwd))), self.peak)

    def psnr_d2_at_least(self, test: SurfelSet, floor: float) -> bool:
        """Whether ``psnr_d2(test) >= floor`` (dB), one direction at a time: the second is
        computed only when the first passes. The direction that failed last goes first (one
        caller's test sets tend to fail the same way: points off the surface where they are
        probed against the reference, a sparse set where it is searched for the reference's
        points); at first, the test points are probed."""
        _check_set("test", test)
        # the largest MSE that passes (the exponent capped: 10.0 ** 301 raises OverflowError)
        limit = self.peak * self.peak * 10.0 ** min(-floor / 10.0, 300.0)
        for k, direction in enumerate(self._directions):
            if not _psnr(direction(test, limit), self.peak) >= floor:
                self._directions.insert(0, self._directions.pop(k))
                return False
        return True
