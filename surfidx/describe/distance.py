"""The distance between two models' descriptors, one definition for every search.

:func:`weighted_l2` is vectorised over the stored models: the exact scan of
:class:`surfidx.db.search.SearchIndex` uses it, the approximate index re-ranks its candidates
with it, and :func:`surfidx.describe.descriptors.descriptor_distance` is its one-pair form. It
lives with the descriptors it compares, below the store. With the shape weight ``w`` in [0, 1] (default :data:`DEFAULT_SHAPE_WEIGHT`
= 0.7)::

    d = w * ||Δshape|| + (1 - w) * ||Δtexture||   query and model both coloured
    d = ||Δshape||                                otherwise

where the shape vector is ``"shape"`` with the KLT ``"spectrum"`` appended (when both carry one)
and ``Δ`` is the difference between query and stored vector. The ``"shape"`` vector holds its
parts already weighted (shells, D2, radial, Laplace–Beltrami spectrum, normals, heat kernel
histograms and the spherical-harmonic energies of the geometric KLT layers;
:data:`surfidx.describe.descriptors.SHAPE_PART_WEIGHTS`), so its
plain L2 distance is the weighted sum of squares of the parts' distances. The texture term
counts only when the query and the stored model both have colour (both carry a ``"texture"``
descriptor and the model's ``has_color`` is set); a pair without it is compared by shape alone,
at full weight, so ``w = 1`` is pure shape distance for every pair. Any function with the
signature of :func:`weighted_l2` can be passed as ``distance=`` instead.
"""

from __future__ import annotations

import numpy as np

from ..errors import InputError

__all__ = ["weighted_l2", "check_shape_weight", "combine_distances", "squared_distances",
           "DEFAULT_SHAPE_WEIGHT", "DEFAULT_KINDS"]

#: Default ``w``: the weight of the shape term beside the texture term (one constant for the
#: library, :func:`surfidx.describe.descriptors.descriptor_distance` and the CLI).
DEFAULT_SHAPE_WEIGHT = 0.7

#: Descriptor kinds a :class:`surfidx.db.search.SearchIndex` loads by default.
DEFAULT_KINDS = ("shape", "spectrum", "texture")


def check_shape_weight(shape_weight) -> float:
    """``shape_weight`` as a float in [0, 1].

    Raises
    ------
    InputError
        Outside [0, 1] (or not a number).
    """
    try:
        w = float(shape_weight)
    except (TypeError, ValueError):
        w = float("nan")
    if not 0.0 <= w <= 1.0:
        raise InputError(f"shape_weight must be in [0, 1], got {shape_weight!r}")
    return w


def weighted_l2(query, stored, present, *,
                shape_weight: float = DEFAULT_SHAPE_WEIGHT) -> np.ndarray:
    """Weighted L2 distance of a query to every stored model (the default search distance).

    Parameters
    ----------
    query : dict of str -> (d_k,) float32
        The query's descriptors; ``"shape"`` is required, ``"spectrum"`` is optional,
        ``"texture"`` marks a coloured query.
    stored : dict of str -> (m, d_k) float32
        The stored descriptors, one row per model (rows of absent kinds are zeros).
    present : dict of str -> (m,) bool
        Which rows of ``stored[kind]`` hold a descriptor (for ``"texture"``: the model has
        colour and a texture descriptor).
    shape_weight : float
        ``w`` in [0, 1].

    Returns
    -------
    (m,) float64
        ``w * ||Δshape|| + (1 - w) * ||Δtexture||`` where both have colour, else ``||Δshape||``
        (shape with the spectrum appended where both have one).
    """
    sq = squared_distances(stored["shape"], query["shape"])
    if "spectrum" in query and "spectrum" in stored:
        sq = sq + np.where(present["spectrum"], squared_distances(stored["spectrum"], query["spectrum"]), 0.0)
    dt = None
    if "texture" in query and "texture" in stored and shape_weight < 1.0:
        dt = np.sqrt(squared_distances(stored["texture"], query["texture"]))
    return combine_distances(np.sqrt(sq), dt, present.get("texture"), shape_weight)


def combine_distances(ds, dt, coloured, w) -> np.ndarray:
    """The rule of :func:`weighted_l2` from the shape distances ``ds`` (m,), the texture
    distances ``dt`` (m,) or None (no texture term) and which rows are ``coloured`` (m,) bool."""
    if dt is None or w >= 1.0 or coloured is None or not coloured.any():
        return ds
    return np.where(coloured, w * ds + (1.0 - w) * dt, ds)


def squared_distances(matrix, vec) -> np.ndarray:
    """Row-wise squared distance of ``matrix`` (m, d) float32 to ``vec`` (d,), as float64."""
    diff = matrix.astype(np.float64) - np.asarray(vec, np.float64)
    return np.einsum("ij,ij->i", diff, diff)
