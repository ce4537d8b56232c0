"""Queries by a partial scan: telling one from a complete model, and the distance for it.

A scan of part of an object (one view of a depth camera, a scan without its base) is closed by
the topology repair with virtual patches (:attr:`surfidx.SurfelSet.patch`) before it is mapped,
so its descriptors describe a closed surface of which the patches are invented. The share of
the closed surface's area that is virtual (``virtual_area_share`` of
:meth:`surfidx.topology.Model.summary`) tells a partial scan from a complete model: a complete
model of genus > 0 gains only the thin lids of its handle cuts, a single view gains a cap about
as large as itself. :func:`is_partial` compares that share with :data:`PARTIAL_SHARE`.

A partial query is compared by :func:`partial_l2`: the default distance
(:func:`surfidx.describe.distance.weighted_l2`) with the squared distance of each part of the
``shape`` vector multiplied by its :data:`PARTIAL_PART_WEIGHTS` factor; the stored vectors are
the same as for complete queries. The factors are all 1 (the default distance): on simulated
single views of a labelled collection no re-weighting of the parts, and no description of the
real surface alone (``describe_grid(virtual=)``), ranked better when chosen on half the models
and scored on the others (``benchmarks/retrieval.py --partial view --partial-study`` prints the
figures). The threshold lies between the largest virtual share of the complete models there
(a few per cent: handle lids, and a base cut's cap) and the smallest of a single view (about 40
per cent).
"""

from __future__ import annotations

import numpy as np

from ..errors import InputError
from .distance import DEFAULT_SHAPE_WEIGHT, check_shape_weight, combine_distances

__all__ = ["PARTIAL_SHARE", "PARTIAL_PART_WEIGHTS", "is_partial", "partial_l2", "part_slices"]

#: Virtual share of the closed surface's area above which a query is a partial scan.
PARTIAL_SHARE = 0.2
#: Factor of each shape part's squared distance (and of the KLT ``spectrum``'s) in
#: :func:`partial_l2`, relative to the default distance (1 everywhere, as now, is
#: :func:`surfidx.describe.distance.weighted_l2`: no measured re-weighting ranked partial scans
#: better).
PARTIAL_PART_WEIGHTS = {"shells": 1.0, "d2": 1.0, "radial": 1.0, "spectral": 1.0,
                        "normals": 1.0, "heat": 1.0, "layers": 1.0, "spectrum": 1.0}


def part_slices() -> dict:
    """Where each part lies in the ``shape`` vector.

    Returns
    -------
    dict of str -> slice
        By part name (:data:`surfidx.describe.descriptors.SHAPE_PARTS`), in order.
    """
    # imported here: the command line reads this module's constants without loading numba
    from .descriptors import (D2_BINS, HEAT_BINS, HEAT_TIMES, LAYERS_LMAX, NORMALS_LMAX,
                              RADIAL_BINS, SHAPE_PARTS, SHELL_LMAX, SHELLS, SPECTRAL_K)

    dims = {"shells": SHELLS * (SHELL_LMAX + 1), "d2": D2_BINS, "radial": RADIAL_BINS,
            "spectral": SPECTRAL_K, "normals": NORMALS_LMAX + 1,
            "heat": len(HEAT_TIMES) * HEAT_BINS, "layers": 3 * (LAYERS_LMAX + 1)}
    out, start = {}, 0
    for name in SHAPE_PARTS:
        out[name] = slice(start, start + dims[name])
        start += dims[name]
    return out


def is_partial(virtual_share, *, threshold: float = PARTIAL_SHARE) -> bool:
    """Whether a query whose closed surface is ``virtual_share`` virtual is a partial scan.

    Parameters
    ----------
    virtual_share : float
        Virtual faces' area over the closed surface's (0 for a model the repair left alone).
    threshold : float
        Share above which the query is partial (default :data:`PARTIAL_SHARE`).

    Returns
    -------
    bool

    Raises
    ------
    InputError
        ``virtual_share`` or ``threshold`` not a number in [0, 1].
    """
    values = []
    for name, v in (("virtual_share", virtual_share), ("threshold", threshold)):
        try:
            f = float(v)
        except (TypeError, ValueError):
            f = float("nan")
        if not 0.0 <= f <= 1.0:
            raise InputError(f"{name} must be a number in [0, 1], got {v!r}")
        values.append(f)
    return values[0] > values[1]


def _part_factors(dim: int) -> np.ndarray:
    """(dim,) factor of each entry's squared difference in the ``shape`` vector."""
    f = np.ones(dim)
    for name, sl in part_slices().items():
        f[sl] = PARTIAL_PART_WEIGHTS[name]
    return f


def partial_l2(query, stored, present, *,
               shape_weight: float = DEFAULT_SHAPE_WEIGHT) -> np.ndarray:
    """The distance of a partial scan to every stored model (signature of
    :func:`surfidx.describe.distance.weighted_l2`, so it goes where that goes: ``distance=`` of
    :meth:`surfidx.db.SearchIndex.query`).

    The squared difference of each part of the ``shape`` vector, and of the ``spectrum``, is
    multiplied by its :data:`PARTIAL_PART_WEIGHTS` factor; the texture term and the rule that
    combines it are those of :func:`~surfidx.describe.distance.weighted_l2`.

    Parameters
    ----------
    query : dict of str -> (d_k,) float32
    stored : dict of str -> (m, d_k) float32
    present : dict of str -> (m,) bool
    shape_weight : float
        ``w`` in [0, 1].

    Returns
    -------
    (m,) float64

    Raises
    ------
    InputError
        ``shape_weight`` outside [0, 1], or a ``shape`` vector of another length than the
        descriptors of this version.
    """
    w = check_shape_weight(shape_weight)
    q = np.asarray(query["shape"], np.float64)
    dim = part_slices()["layers"].stop
    if q.shape != (dim,) or stored["shape"].shape[1] != dim:
        raise InputError(f"partial_l2 compares shape vectors of {dim} values, got "
                         f"{q.shape[-1]} and {stored['shape'].shape[1]}; recompute the "
                         "descriptors (surfidx redescribe)")
    diff = stored["shape"].astype(np.float64) - q
    sq = (diff * diff) @ _part_factors(dim)
    if "spectrum" in query and "spectrum" in stored:
        ds = stored["spectrum"].astype(np.float64) - np.asarray(query["spectrum"], np.float64)
        sq = sq + np.where(present["spectrum"],
                           PARTIAL_PART_WEIGHTS["spectrum"] * np.einsum("ij,ij->i", ds, ds), 0.0)
    dt = None
    if "texture" in query and "texture" in stored and w < 1.0:
        dtx = stored["texture"].astype(np.float64) - np.asarray(query["texture"], np.float64)
        dt = np.sqrt(np.einsum("ij,ij->i", dtx, dtx))
    return combine_distances(np.sqrt(sq), dt, present.get("texture"), w)
