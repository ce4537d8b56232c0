"""View-based descriptors: what a depth camera sees of a model from a fixed set of directions.

A scan from one depth camera holds the surface that faces the camera, and its outline is the
outline of the whole model seen from there. So a partial query is compared with each stored
model's *views*: for every direction of :func:`view_directions` (the vertices of the level-
:data:`VIEW_LEVEL` icosphere), the model's surface (uniform area samples of the decoded grid
mesh) is projected orthographically onto the plane across the direction; the silhouette is the
set of pixels any sample falls in and the depth the nearest sample's height towards the camera.

Each view is described invariantly to a turn and a reflection in the image plane, to
translation and to scale: about the silhouette's centroid, distances are divided by its RMS
radius ``R`` (pixels) and heights by ``R`` in model units, measured from their silhouette mean;
for each of :data:`VIEW_RINGS` rings (linear split between the two nearest ring radii, up to
:data:`VIEW_RMAX`) the angular Fourier coefficients ``Σ w·exp(-ikθ)`` of degrees
``0..VIEW_HARMONICS-1`` of the silhouette (``w = 1``) and of the depth (``w`` = height) over the
silhouette's pixel count are taken, and their moduli kept (a turn shifts the phase only, a
reflection conjugates). Per view: ``2·VIEW_RINGS·VIEW_HARMONICS`` values (silhouette block, then
depth block times :data:`VIEW_DEPTH_WEIGHT`).

The views are not invariant as a set: the directions are fixed in space, so a turned model is
seen from other directions. A query's view is compared with every stored view and the nearest
counts, which tolerates any turn up to the spacing of the directions.

A partial scan is seen from where the camera stood: the direction from which the least of it
is back-facing (:func:`scan_direction`), from rings of :data:`SCAN_TURNS` directions
:data:`SCAN_TILTS` degrees around it (the stored directions lie up to half their spacing from
the camera, in a direction that depends on the pose), and from the opposite direction, as the
winding of a scan file may be inward. :func:`view_distance` compares a query's views with a
model's by the smallest distance over the pairs (a partial query: one direction against all of
the model's), :func:`view_set_distance` two complete models by the mean nearest-view distance
both ways. :func:`expand_by_first` ranks the models after a partial query's first match also by
their distance to it as complete models (query expansion).
"""

from __future__ import annotations

import functools

import numpy as np

from ..errors import InputError
from ..jit import njit
from ..validate import as_array

__all__ = ["VIEW_LEVEL", "VIEW_PIXELS", "VIEW_SAMPLES", "VIEW_RINGS", "VIEW_HARMONICS",
           "VIEW_RMAX", "VIEW_DEPTH_WEIGHT", "view_directions", "surface_samples",
           "view_vector", "model_views", "scan_direction", "tilted_directions", "scan_views",
           "view_dim", "SCAN_TILTS", "SCAN_TURNS",
           "view_distance", "view_set_distance", "view_params", "partial_view_l2",
           "EXPANSION_WEIGHT", "expand_by_first"]

#: Icosphere level whose vertices are the view directions (level 1: 42 directions).
VIEW_LEVEL = 1
#: Side of the square image a view is rasterised into, in pixels.
VIEW_PIXELS = 64
#: Uniform area samples of the surface splatted into each image.
VIEW_SAMPLES = 1 << 15
#: Rings of the polar description, over radii 0..VIEW_RMAX (in silhouette RMS radii).
VIEW_RINGS = 8
#: Angular Fourier degrees 0..VIEW_HARMONICS-1 kept per ring.
VIEW_HARMONICS = 8
#: Largest radius of the rings, in silhouette RMS radii (pixels beyond fall in the last ring).
VIEW_RMAX = 2.5
#: Factor of the depth block beside the silhouette block of a view vector.
VIEW_DEPTH_WEIGHT = 1.0
#: Seed of the surface samples (the same model gives the same views).
VIEW_SEED = 0
#: Icosphere level whose vertices are the candidate camera directions of a scan (2,562).
SCAN_DIRECTION_LEVEL = 4
#: Icosphere level of the first, coarse search for a scan's camera direction (162).
SCAN_COARSE_LEVEL = 2
#: Coarse directions near which the fine level is searched.
SCAN_COARSE_KEEP = 3
#: Angles (degrees) from a scan's camera direction of the further directions it is seen from.
SCAN_TILTS = (8.0, 16.0)
#: How many directions each angle of :data:`SCAN_TILTS` from the camera direction a scan is
#: seen from.
SCAN_TURNS = 8
#: Weight of the alignment with the mean normal that breaks ties between camera directions.
SCAN_DIRECTION_TIE = 1e-3
#: Weight of the first match's complete-model distances in the ranking of a single-view query
#: (:func:`expand_by_first`; ``benchmarks/retrieval.py --partial view --expansion`` measures it).
EXPANSION_WEIGHT = 4.0


def view_dim() -> int:
    """Length of one view's vector: ``2·VIEW_RINGS·VIEW_HARMONICS``."""
    return 2 * VIEW_RINGS * VIEW_HARMONICS


@functools.lru_cache(maxsize=4)
def view_directions(level: int = VIEW_LEVEL) -> np.ndarray:
    """(k, 3) float64 unit view directions: the vertices of the level-``level`` icosphere."""
    from ..geometry.icosphere import icosphere

    d = np.array(icosphere(level).vertices, dtype=np.float64)
    d.flags.writeable = False
    return d


def surface_samples(vertices, faces, count: int = VIEW_SAMPLES, *, seed: int = VIEW_SEED):
    """(count, 3) float64 points uniform over a triangle mesh's area (fixed seed).

    Raises
    ------
    InputError
        The mesh has zero area.
    """
    v = np.ascontiguousarray(vertices, np.float64)
    f = np.ascontiguousarray(faces, np.int64)
    area = _triangle_areas(v, f)
    total = float(area.sum())
    if not total > 0:
        raise InputError("the surface has zero area; it has no views to describe")
    rng = np.random.default_rng(seed)
    cdf = np.cumsum(area) / total
    idx = np.minimum(np.searchsorted(cdf, rng.random(count), side="right"), len(f) - 1)
    r1, r2 = rng.random(count), rng.random(count)
    s = np.sqrt(r1)
    a, b, c = 1.0 - s, s * (1.0 - r2), s * r2
    t = f[idx]
    return a[:, None] * v[t[:, 0]] + b[:, None] * v[t[:, 1]] + c[:, None] * v[t[:, 2]]


@njit(cache=True)
def _triangle_areas(v, f):  # pragma: no cover - compiled
    """(m,) float64 area of each triangle, half the length of ``(b - a) × (c - a)``: the
    operations of ``np.cross`` and ``np.linalg.norm`` in their order (the same bits), without
    the (m, 3, 3) corner array a fine grid's millions of faces would fill."""
    out = np.empty(f.shape[0])
    for i in range(f.shape[0]):
        a, b, c = f[i, 0], f[i, 1], f[i, 2]
        u0, u1, u2 = v[b, 0] - v[a, 0], v[b, 1] - v[a, 1], v[b, 2] - v[a, 2]
        w0, w1, w2 = v[c, 0] - v[a, 0], v[c, 1] - v[a, 1], v[c, 2] - v[a, 2]
        c0 = u1 * w2 - u2 * w1
        c1 = u2 * w0 - u0 * w2
        c2 = u0 * w1 - u1 * w0
        out[i] = 0.5 * np.sqrt((c0 * c0 + c1 * c1) + c2 * c2)
    return out


def _plane_basis(d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors spanning the plane across the unit vector ``d``."""
    helper = np.array([1.0, 0.0, 0.0]) if abs(d[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = np.cross(d, helper)
    e1 /= np.linalg.norm(e1)
    return e1, np.cross(d, e1)


def view_vector(points: np.ndarray, direction: np.ndarray) -> np.ndarray:
    """(view_dim(),) float64 description of the surface samples seen from ``direction``.

    Parameters
    ----------
    points : (n, 3) float64
        Uniform area samples of the surface (a scan's, or a whole model's: hidden samples change
        the silhouette not at all and the depth not, the nearest one wins).
    direction : (3,) float64
        Unit vector from the model towards the camera.
    """
    p = as_array(points, "points", shape=(None, 3))
    d = np.asarray(direction, np.float64)
    d = d / np.linalg.norm(d)
    e1, e2 = _plane_basis(d)
    u, v, z = p @ e1, p @ e2, p @ d
    lo_u, lo_v = u.min(), v.min()
    span = max(u.max() - lo_u, v.max() - lo_v)
    if not span > 0:
        raise InputError("the surface projects to a single point; it has no view to describe")
    n = VIEW_PIXELS
    scale = (n - 1e-9) / span
    px = np.minimum(((u - lo_u) * scale).astype(np.int64), n - 1)
    py = np.minimum(((v - lo_v) * scale).astype(np.int64), n - 1)
    cell = py * n + px
    top = np.full(n * n, -np.inf)            # per pixel, the nearest sample's height
    np.maximum.at(top, cell, z)
    pix = np.flatnonzero(np.bincount(cell, minlength=n * n))
    depth = top[pix]
    cx, cy = pix % n + 0.5, pix // n + 0.5
    mx, my = cx.mean(), cy.mean()
    dx, dy = cx - mx, cy - my
    r2 = dx * dx + dy * dy
    rms = np.sqrt(r2.mean())        # > 0: the extreme samples fall in opposite pixel columns
    rho = np.sqrt(r2) / rms
    theta = np.arctan2(dy, dx)
    height = (depth - depth.mean()) / (rms / scale)
    pos = np.minimum(rho / VIEW_RMAX * (VIEW_RINGS - 1), VIEW_RINGS - 1)
    lo = np.minimum(pos.astype(np.int64), VIEW_RINGS - 2)
    t = pos - lo
    k = np.arange(VIEW_HARMONICS)
    phase = np.exp(-1j * theta[:, None] * k[None, :])          # (pixels, harmonics)
    # each pixel's share of its two rings, summed per (ring, degree) in pixel order: the
    # lower ring's shares, then the upper's
    cells = (np.concatenate([lo, lo + 1])[:, None] * VIEW_HARMONICS + k).ravel()
    size = VIEW_RINGS * VIEW_HARMONICS
    out = []
    for w in (np.ones_like(height), height):
        wp = w[:, None] * phase
        share = np.concatenate([(1.0 - t)[:, None] * wp, t[:, None] * wp]).ravel()
        acc = np.empty(size, np.complex128)
        acc.real = np.bincount(cells, share.real, size)
        acc.imag = np.bincount(cells, share.imag, size)
        out.append(np.abs(acc) / len(pix))
    out[1] = out[1] * VIEW_DEPTH_WEIGHT
    return np.concatenate(out)


def model_views(vertices, faces, *, level: int = VIEW_LEVEL) -> np.ndarray:
    """(k, view_dim()) float32 views of a closed model from every direction of
    :func:`view_directions`.

    Parameters
    ----------
    vertices : (n, 3) float64
        The model's surface (the decoded grid positions).
    faces : (m, 3) int64
    """
    p = surface_samples(vertices, faces)
    return np.stack([view_vector(p, d) for d in view_directions(level)]).astype(np.float32)


@functools.lru_cache(maxsize=1)
def _direction_search():
    """The camera directions :func:`scan_direction` tries: the level-
    :data:`SCAN_COARSE_LEVEL` icosphere's vertices, and for each of them the level-
    :data:`SCAN_DIRECTION_LEVEL` vertices within the coarse spacing (the largest angle between
    neighbouring coarse vertices) of it, as an index array per coarse vertex."""
    from ..geometry.icosphere import icosphere

    coarse = icosphere(SCAN_COARSE_LEVEL)
    c = np.asarray(coarse.vertices, np.float64)
    fine = np.asarray(icosphere(SCAN_DIRECTION_LEVEL).vertices, np.float64)
    f = np.asarray(coarse.faces, np.int64)
    edges = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    spacing = float(np.min(np.einsum("ij,ij->i", c[edges[:, 0]], c[edges[:, 1]])))
    near = [np.flatnonzero(fine @ d >= spacing) for d in c]
    c.flags.writeable = False
    fine.flags.writeable = False
    return c, fine, near


def scan_direction(vertices, faces) -> np.ndarray:
    """(3,) unit direction from a single-view scan towards its camera.

    Every face of a single view faces its camera, so the camera direction is the one from which
    the least of the scan is back-facing: the direction of least back-facing projected area
    ``Σ_f A_f·max(-n_f·d, 0)`` (faces as wound), ties going to the area-weighted mean normal.
    It is searched coarse to fine: among the vertices of the level-:data:`SCAN_COARSE_LEVEL`
    icosphere, then among the level-:data:`SCAN_DIRECTION_LEVEL` vertices near the
    :data:`SCAN_COARSE_KEEP` best of them (the whole fine level costs ten times more).

    Raises
    ------
    InputError
        The scan has zero area.
    """
    v = np.asarray(vertices, np.float64)
    t = v[np.asarray(faces, np.int64)]
    na = 0.5 * np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
    area = float(np.linalg.norm(na, axis=1).sum())
    if not area > 0:
        raise InputError("the scan has zero area; its camera direction is unknown")
    mean = na.sum(axis=0) / area
    coarse, fine, near = _direction_search()

    def cost(cand):
        back = np.maximum(-(na @ cand.T), 0.0).sum(axis=0) / area
        return back - SCAN_DIRECTION_TIE * (cand @ mean)

    best = np.argsort(cost(coarse), kind="stable")[:SCAN_COARSE_KEEP]
    idx = np.unique(np.concatenate([near[k] for k in best]))
    return fine[idx[int(np.argmin(cost(fine[idx])))]].copy()


def tilted_directions(direction, *, tilts=SCAN_TILTS, turns: int = SCAN_TURNS):
    """(1 + len(tilts)·turns, 3) float64 unit directions: ``direction``, then for each angle of
    ``tilts`` (degrees) ``turns`` directions that far from it, evenly spaced around it (each
    ring turned half a step from the one before).

    The stored views are seen from fixed directions, up to half their spacing from any
    camera; a scan seen also from directions tilted about as far from its own camera is
    nearly seen from one of them, whatever its pose (its hidden side shows little at such
    tilts).
    """
    d = np.asarray(direction, np.float64)
    d = d / np.linalg.norm(d)
    e1, e2 = _plane_basis(d)
    out = [d[None, :]]
    for ring, tilt in enumerate(tilts):
        phi = 2.0 * np.pi * (np.arange(turns) + 0.5 * ring) / turns
        side = np.cos(phi)[:, None] * e1 + np.sin(phi)[:, None] * e2
        t = np.radians(tilt)
        out.append(np.cos(t) * d + np.sin(t) * side)
    return np.vstack(out)


def scan_views(vertices, faces) -> np.ndarray:
    """(len(SCAN_TILTS)·SCAN_TURNS + 2, view_dim()) float32 views of a single-view scan:
    from its camera direction (:func:`scan_direction`), from the rings of directions
    :data:`SCAN_TILTS` degrees around it (:func:`tilted_directions`), and from the opposite
    direction (the winding of a scan file may be inward)."""
    d = scan_direction(vertices, faces)
    p = surface_samples(vertices, faces)
    return np.stack([view_vector(p, x) for x in tilted_directions(d)]
                    + [view_vector(p, -d)]).astype(np.float32)


def view_distance(query: np.ndarray, stored: np.ndarray) -> np.ndarray:
    """(m,) float64 smallest distance between any view of the query and any view of each model.

    Parameters
    ----------
    query : (q, d) float32
        The query's views.
    stored : (m, k, d) float32
        Each model's views.
    """
    q = np.asarray(query, np.float64)
    s = np.asarray(stored, np.float64)
    sq = (np.einsum("mkd,mkd->mk", s, s)[:, :, None] - 2.0 * np.einsum("mkd,qd->mkq", s, q)
          + np.einsum("qd,qd->q", q, q)[None, None, :])
    return np.sqrt(np.maximum(sq.reshape(len(s), -1).min(axis=1), 0.0))


def view_set_distance(query: np.ndarray, stored: np.ndarray) -> np.ndarray:
    """(m,) float64 distance of a complete model's views to each model's: the mean over the
    query's views of the nearest stored view, and the mean the other way, averaged.

    Parameters
    ----------
    query : (k, d) float32
    stored : (m, k, d) float32
    """
    q = np.asarray(query, np.float64)
    s = np.asarray(stored, np.float64)
    sq = (np.einsum("mkd,mkd->mk", s, s)[:, :, None] - 2.0 * np.einsum("mkd,qd->mkq", s, q)
          + np.einsum("qd,qd->q", q, q)[None, None, :])
    d = np.sqrt(np.maximum(sq, 0.0))                         # (m, k_stored, k_query)
    return 0.5 * (d.min(axis=1).mean(axis=1) + d.min(axis=2).mean(axis=1))


def view_params() -> dict:
    """The conventions of the ``views`` vectors (stored with them)."""
    return {"level": VIEW_LEVEL, "pixels": VIEW_PIXELS, "samples": VIEW_SAMPLES,
            "rings": VIEW_RINGS, "harmonics": VIEW_HARMONICS, "rmax": VIEW_RMAX,
            "depth_weight": VIEW_DEPTH_WEIGHT, "seed": VIEW_SEED}


def partial_view_l2(query, stored, present, *, shape_weight: float = 1.0) -> np.ndarray:
    """The distance of a single-view scan to every stored model (the signature of
    :func:`surfidx.describe.distance.weighted_l2`, for ``distance=`` of
    :meth:`surfidx.db.SearchIndex.query` with ``kinds=("views",)``): the smallest distance
    between a view of the scan (``query["views"]``, :func:`scan_views` flattened) and a view of
    the model (``stored["views"]``, :func:`model_views` flattened); models without views are
    infinitely far. ``shape_weight`` is accepted and unused: views are shape only.

    Raises
    ------
    InputError
        Vectors that are not whole views of :func:`view_dim` values.
    """
    dim = view_dim()
    q = np.asarray(query["views"], np.float64)
    s = np.asarray(stored["views"], np.float32)
    if q.ndim != 1 or q.size % dim or s.ndim != 2 or s.shape[1] % dim or not s.shape[1]:
        raise InputError(f"views vectors hold whole views of {dim} values, got "
                         f"{q.size} and {s.shape[-1]}; recompute the descriptors "
                         "(surfidx redescribe)")
    d = view_distance(q.reshape(-1, dim), s.reshape(len(s), -1, dim))
    return np.where(np.asarray(present["views"], bool), d, np.inf)


def expand_by_first(view_dist, first_dist, *, weight: float = EXPANSION_WEIGHT) -> np.ndarray:
    """A single-view query's ranking, expanded by the complete model of its first match.

    A view finds its own model often but ranks the rest of its class poorly: one side of a
    shape says little about how the other members look from their other sides. The first
    match, once found, is a complete model, and complete models find their class well. So the
    ranking blends the view distance with the first match's distance to every stored model
    (query expansion, Chum et al. 2007), each divided by its median over the finite entries so
    that neither scale dominates. The first match has the smallest view distance and distance 0
    to itself: it stays first.

    Parameters
    ----------
    view_dist : (m,) float64
        :func:`partial_view_l2` of the query (``inf``: a model without views, never returned).
    first_dist : (m,) float64
        The distance of the first match (the smallest ``view_dist``) to every model by the
        complete-model descriptors (:func:`surfidx.describe.weighted_l2`); ``inf`` where a
        model has none (it counts as the farthest).
    weight : float
        Weight of ``first_dist`` (0: the view distance alone).

    Returns
    -------
    (m,) float64
        The blended distances (``inf`` where ``view_dist`` is).

    Raises
    ------
    InputError
        Arrays of different lengths, NaN, or a negative or non-finite ``weight``.
    """
    v = as_array(view_dist, "view_dist", shape=(None,), finite=False)
    c = as_array(first_dist, "first_dist", shape=(v.size,), finite=False)
    w = float(weight)
    if not (np.isfinite(w) and w >= 0.0):
        raise InputError(f"weight must be a finite number >= 0, got {weight!r}")
    if np.isnan(v).any() or np.isnan(c).any():
        raise InputError("view_dist and first_dist must not hold NaN")
    fv, fc = np.isfinite(v), np.isfinite(c)
    if not fv.any():
        return v.copy()
    c = np.where(fc, c, c[fc].max() if fc.any() else 0.0)
    return v / _median_scale(v[fv]) + w * c / _median_scale(c)


def _median_scale(d: np.ndarray) -> float:
    """The median of ``d``, or 1 where it is 0 (every distance 0: nothing to scale)."""
    m = float(np.median(d))
    return m if m > 0.0 else 1.0
