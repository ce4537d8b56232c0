"""Shape and texture descriptors from the spherical representation the codec uses.

The resampled layers on the icosahedral grid are decorrelated by a KLT (geometry and colour
separately), each KLT layer is sampled from the icosahedral grid onto a Driscoll–Healy grid and
expanded in spherical harmonics with pyshtools; the per-degree energies form the descriptor.

Invariance, by construction:

* rotation and reflection of the **sphere** (the map is canonical only up to a rotation): the
  energy of each degree ``l`` is invariant under any orthogonal transform of the sphere;
* rotation and reflection of the **object**: the KLT layers are the object's coordinates along its
  principal axes, which turn with the object (up to sign, which per-degree energies ignore);
* translation: the KLT mean is removed;
* scale: geometric layers are divided by the square root of the total geometric variance.

Descriptor vectors (float32), by kind:

``shape``  — the retrieval shape descriptor (version 5), five parts concatenated
           (:data:`SHAPE_PARTS`), part ``k`` scaled by
           ``SHAPE_PART_WEIGHTS[k] · 1.15 / SHAPE_PART_MEDIANS[k]`` (the medians are each part's
           median distance between different models of the retrieval benchmark's genus-0 set, so
           a part of weight 1 has median distance 1.15), so that the plain L2 distance of two
           shape vectors is ``sqrt(Σ_k (scale_k · d_k)²)`` over the parts' own distances:

           * *shells* (``SHELLS·(SHELL_LMAX+1)``): the grid surface's area measure split into
             ``SHELLS`` concentric shells (radius relative to the area-weighted RMS radius, up to
             ``SHELL_RMAX``), the sqrt per-degree energy of each shell's measure on the direction
             sphere, degrees 0..``SHELL_LMAX`` (Kazhdan, Funkhouser & Rusinkiewicz 2003, on the grid
             surface; damped by ``exp(-l(l+1)/(4·SHELL_KAPPA))`` as a von Mises smoothing would);
           * *D2* (``D2_BINS``): sqrt of the distribution of distances between area-weighted random
             pairs of grid vertices over their mean (Osada et al. 2002), ``D2_PAIRS`` pairs from a
             fixed seed;
           * *radial* (``RADIAL_BINS``): sqrt of the area-weighted distribution of the distance to
             the centroid over the RMS radius;
           * *spectral* (``SPECTRAL_K``): the Laplace–Beltrami spectrum of the grid surface
             ("Shape-DNA", Reuter, Wolter & Peinecke 2006): the first ``SPECTRAL_K`` non-zero
             eigenvalues of the cotangent Laplacian (lumped mass) of the grid mesh at level
             ``min(level, SPECTRAL_LEVEL)``, as ``log(λ_i · A / (4π i))`` with ``A`` the surface
             area (Weyl's law makes the values O(1) and the part scale invariant). Intrinsic, so
             unchanged by bending: the part that tells articulated classes apart;
           * *layers* (``3·(LAYERS_LMAX+1)``): the spherical-harmonic energies of the three
             geometric KLT layers as functions on the sphere, ``sqrt(E_jl)`` per layer ``j`` and
             degree ``l``, degrees 0..``LAYERS_LMAX`` on the Driscoll–Healy grid
             of degree ``LAYERS_GRID_LMAX``: the parameterisation's view of the shape, where the
             other parts see the surface as a measure or an intrinsic metric.

           Area weights are the 3D areas of the grid mesh (the icosphere's triangles at the
           resampled positions), so shells, D2 and radial measure the surface, not the sphere
           map: limbs the map squeezes keep their surface share. They use the grid of level
           ``min(level, SHAPE_LEVEL)`` (a prefix of the grid). Square roots make the L2 distance
           a Hellinger one. The weights (:data:`SHAPE_PART_WEIGHTS`, version 7) were chosen by
           measurement on the models of ``benchmarks/retrieval.py`` (which prints the retrieval
           figures), in the middle of a plateau of weights that give the same figures.
``layers`` (3·(lmax+1),) — ``sqrt`` of the per-degree energies (pyshtools) of the three geometric
           KLT layers up to the ``lmax`` argument (the raw vector of the shape vector's layers
           part, kept for other distances).
``texture`` (3·(lmax+1) + 3,) — the same for the colour KLT layers (colour units /255) followed by
           the mean colour /255; absent without colour. An orthogonal map of colour space (a turn
           about the grey axis) leaves the colour layers' energies unchanged: such a recolouring
           is seen through the mean colour;
``spectrum`` (3,) — the normalised geometric KLT eigenvalues (sum 1).
``views`` (k·d,) — the model's surface seen from the ``k`` directions of
           :func:`surfidx.describe.views.view_directions`, ``d`` values per view
           (:func:`surfidx.describe.views.model_views`): what a query by a single-view scan is
           compared with (:func:`surfidx.describe.views.partial_view_l2`). Not rotation
           invariant as a vector (the directions are fixed in space); a query's view is matched
           to the nearest of them.

Invariance of ``shape``: rotation and reflection by per-degree energies of a point measure (exact,
computed with complex spherical harmonics at the points), by distances, by the intrinsic
spectrum and by the per-degree energies of the KLT layers; translation by the area centroid and
the KLT mean; scale by the RMS radius, the mean pair distance, the area and the total variance;
the sphere map through which surface points the grid samples and, for the layers part, through
where the map puts them.

The distance of two descriptor sets is :func:`descriptor_distance`, the one-pair form of the
search distance :func:`surfidx.describe.distance.weighted_l2`.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

from ..jit import numba
import numpy as np
import scipy.sparse as sp

from ..errors import InputError
from ..geometry.sparse import SPDSolver
from ..tolerance import TOL
from ..validate import as_array
from ..geometry.icosphere import icosphere, vertex_count
from ..geometry.mesh import cotangent_laplacian, vertex_area_shares
from ..codec.klt import KLT
from .harmonics import degree_spectrum, expand_dh
from .distance import DEFAULT_KINDS, DEFAULT_SHAPE_WEIGHT, check_shape_weight, weighted_l2
from .views import model_views, view_params

__all__ = ["DescriptorSet", "describe_grid", "descriptor_distance", "descriptor_params",
           "DEFAULT_LMAX",
           "SH_NORMALIZATION", "DESCRIPTOR_VERSION"]

from .options import DEFAULT_LMAX  # noqa: E402  (defined with DescribeOptions)
SH_NORMALIZATION = "4pi"  # pyshtools norm=1: 4π-normalised real harmonics, no Condon-Shortley phase
"""Normalisation of the spherical harmonics the descriptors use (stored with them)."""
DESCRIPTOR_VERSION = 8
"""Version of the descriptor vectors; queries refuse to compare vectors of different versions."""

SHELLS = 8
SHELL_LMAX = 8
SHELL_RMAX = 2.5
SHELL_KAPPA = 10.0
D2_BINS = 64
D2_RMAX = 3.0
D2_PAIRS = 1 << 20
_DRAW_BUCKETS = 1 << 16   # slices of [0, 1] bounding each D2 draw's search (a power of two)
RADIAL_BINS = 32
RADIAL_RMAX = 3.0
SPECTRAL_K = 30
SPECTRAL_LEVEL = 5
#: Relative accuracy of the Lanczos Ritz pairs (ARPACK ``tol``): the eigenvalues come out
#: to about its square.
SPECTRAL_TOL = 1e-8
SHAPE_LEVEL = 6
LAYERS_LMAX = 12
LAYERS_GRID_LMAX = 24
SEED = 0
#: Names of the parts of the ``shape`` vector, in order.
SHAPE_PARTS = ("shells", "d2", "radial", "spectral", "layers")
#: Median distance between different models of each unscaled shape part (shells, D2, radial,
#: spectral, layers) on the retrieval benchmark's genus-0 set.
SHAPE_PART_MEDIANS = (0.1191, 0.1799, 0.3515, 1.989, 0.3359)
#: Relative weight of each shape part (its median distance becomes 1.15 × the weight): chosen
#: by measurement on the retrieval models, genus > 0 ones repaired, in the middle of a plateau
#: where changing any one weight a little keeps the figures (``benchmarks/retrieval.py`` prints
#: them).
SHAPE_PART_WEIGHTS = (0.5, 0.25, 0.25, 3.0, 2.0)
SHAPE_PART_SCALES = tuple(1.15 * w / m for w, m in zip(SHAPE_PART_WEIGHTS, SHAPE_PART_MEDIANS))


@dataclass
class DescriptorSet:
    """The descriptor vectors of one model and the conventions that produced them.

    Attributes
    ----------
    vectors : dict of str -> (d,) float32
        By kind: ``shape``, ``layers``, ``spectrum``, ``views`` and, with colour, ``texture``.
    params : dict
        The conventions that make two descriptors comparable: ``lmax``, ``normalization``,
        ``version`` (the grid level is not one: energies at a degree do not depend on it).
    """

    vectors: dict
    params: dict


def _dh_points(lmax: int) -> np.ndarray:
    """(n, 2n, 3) unit vectors of the Driscoll–Healy grid (sampling=2) of degree ``lmax``."""
    n = 2 * (lmax + 1)
    lat = np.radians(90.0 - 180.0 * np.arange(n) / n)
    lon = np.radians(360.0 * np.arange(2 * n) / (2 * n))
    clat, slat = np.cos(lat)[:, None], np.sin(lat)[:, None]
    return np.stack([clat * np.cos(lon), clat * np.sin(lon), np.broadcast_to(slat, (n, 2 * n))],
                    axis=-1)


@functools.lru_cache(maxsize=16)
def _ico_to_dh(level: int, lmax: int) -> sp.csr_matrix:
    """Sparse (n_dh, n_grid) barycentric interpolation from the icosahedral grid to the DH grid
    (exact point location in the icosphere's triangulation, built once per level and lmax)."""
    from ..codec.resample import locate

    ico = icosphere(level)
    q = _dh_points(lmax).reshape(-1, 3)
    tri, idx, bary = locate(ico.vertices, q, triangles=ico.faces)
    rows = np.repeat(np.arange(len(q)), 3)
    return sp.csr_matrix((bary.ravel(), (rows, tri[idx].ravel())), shape=(len(q), ico.n_vertices))


def degree_energies(layers: np.ndarray, level: int, lmax: int, *,
                     grid_lmax: int | None = None) -> np.ndarray:
    """(k, lmax+1) per-degree energies (pyshtools, 4π norm) of grid layers (n_grid, k).

    The layers are interpolated onto the Driscoll–Healy grid of degree ``grid_lmax`` (default
    ``lmax``; a larger grid samples the layers more densely) and expanded up to degree ``lmax``.
    """
    grid_lmax = lmax if grid_lmax is None else max(int(grid_lmax), lmax)
    n = 2 * (grid_lmax + 1)
    dh = (_ico_to_dh(level, grid_lmax) @ layers).reshape(n, 2 * n, -1)
    out = np.empty((layers.shape[1], lmax + 1))
    for j in range(layers.shape[1]):
        out[j] = degree_spectrum(expand_dh(dh[:, :, j], lmax))
    return out


def _grid_areas(x: np.ndarray, level: int) -> np.ndarray:
    """(n_grid,) 3D area share of each grid vertex (a third of its incident triangles' areas)."""
    f = icosphere(level).faces
    v = x[f]
    a = 0.5 * np.linalg.norm(np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0]), axis=1)
    return vertex_area_shares(f, a, len(x))


def _hist(values, weights, bins, rmax):
    h, _ = np.histogram(np.minimum(values, rmax * (1 - 1e-12)), bins=bins, range=(0.0, rmax),
                        weights=weights)
    return h / max(h.sum(), 1e-300)


def _shell_energies(y: np.ndarray, w: np.ndarray) -> np.ndarray:
    """(SHELLS, SHELL_LMAX+1) sqrt per-degree energies of the shells' area measures."""
    from scipy.special import sph_harm_y

    r = np.linalg.norm(y, axis=1)
    theta = np.arccos(np.clip(y[:, 2] / np.maximum(r, 1e-300), -1.0, 1.0))
    phi = np.arctan2(y[:, 1], y[:, 0])
    shell = np.minimum((r / SHELL_RMAX * SHELLS).astype(np.int64), SHELLS - 1)
    out = np.zeros((SHELLS, SHELL_LMAX + 1))
    cos = [np.cos(m * phi) for m in range(SHELL_LMAX + 1)]     # each order's, for every degree
    sin = [np.sin(m * phi) for m in range(SHELL_LMAX + 1)]
    for l in range(SHELL_LMAX + 1):
        for m in range(l + 1):
            wy = w * sph_harm_y(l, m, theta, 0.0).real
            c = np.bincount(shell, weights=wy * cos[m], minlength=SHELLS)
            c2 = c ** 2
            if m:
                c = np.bincount(shell, weights=wy * sin[m], minlength=SHELLS)
                c2 = 2.0 * (c2 + c ** 2)
            out[:, l] += c2
    damp = np.exp(-np.arange(SHELL_LMAX + 1) * np.arange(1, SHELL_LMAX + 2) / (4 * SHELL_KAPPA))
    return np.sqrt(out) * damp


def shape_parts(x: np.ndarray, level: int, layers: np.ndarray, *, virtual=None) -> dict:
    """The unscaled parts of the ``shape`` descriptor, by name (:data:`SHAPE_PARTS`).

    Parameters
    ----------
    x : (n_grid, 3) float64
        Grid positions at level ``level``.
    layers : (n_grid, 3) float64
        The geometric KLT layers over the square root of the total geometric variance.
    virtual : (n_grid,) bool, optional
        Grid vertices that sample a virtual patch: the measure parts (shells, D2, radial) then
        weigh them by zero, so they describe the scanned surface only (centroid and scale
        included); the spectral and layers parts need the closed surface and keep it.

    The measure parts (shells, D2, radial) use the grid of level ``min(level, SHAPE_LEVEL)`` (a
    prefix of ``x``): 40,962 area-weighted samples resolve degree-8 shells and 64-bin histograms.
    """
    spectral = log_spectrum(x, level)
    part = {"layers": layers_part(layers, level)}
    level = min(level, SHAPE_LEVEL)
    x = x[:vertex_count(level)]
    a = _grid_areas(x, level)
    if virtual is not None:
        a = np.where(virtual[:vertex_count(level)], 0.0, a)
    if not a.sum() > 0:
        raise InputError("the resampled surface has zero area; cannot normalise its scale")
    w = a / a.sum()
    y = x - w @ x
    rms = np.sqrt(w @ np.einsum("ij,ij->i", y, y))
    y = y / rms
    part["shells"] = _shell_energies(y, w).ravel()
    rng = np.random.default_rng(SEED)
    cdf = np.cumsum(w)
    cdf /= cdf[-1]
    i = search_right(cdf, rng.random(D2_PAIRS))
    j = search_right(cdf, rng.random(D2_PAIRS))
    d = pair_distances(y, i, j)
    part["d2"] = np.sqrt(_hist(d / max(d.mean(), 1e-300), None, D2_BINS, D2_RMAX))
    part["radial"] = np.sqrt(_hist(np.linalg.norm(y, axis=1), w, RADIAL_BINS, RADIAL_RMAX))
    part["spectral"] = spectral
    return {name: part[name] for name in SHAPE_PARTS}


@numba.njit(cache=True)
def search_right(cdf, u):  # pragma: no cover - compiled
    """``np.searchsorted(cdf, u, side="right")`` for a non-decreasing ``cdf`` ending at 1 and
    ``u`` in [0, 1): the inverse-CDF draws of ``Generator.choice(p=...)``, the same indices.
    A table of :data:`_DRAW_BUCKETS` equal slices of [0, 1] bounds each binary search to the
    few entries of its slice, where ``searchsorted`` searches the whole ``cdf`` for each of D2's
    million draws."""
    n, buckets = len(cdf), _DRAW_BUCKETS
    start = np.empty(buckets + 1, np.int64)      # first index whose cdf exceeds b / buckets
    k = 0
    for b in range(buckets + 1):
        v = b / buckets
        while k < n and cdf[k] <= v:
            k += 1
        start[b] = k
    out = np.empty(len(u), np.int64)
    for q in range(len(u)):
        x = u[q]
        b = int(x * buckets)        # exact: buckets is a power of two, b / buckets <= x
        lo, hi = start[b], start[b + 1]
        while lo < hi:
            mid = (lo + hi) >> 1
            if cdf[mid] <= x:
                lo = mid + 1
            else:
                hi = mid
        out[q] = lo
    return out


@numba.njit(cache=True)
def pair_distances(y, i, j):  # pragma: no cover - compiled
    """``np.linalg.norm(y[i] - y[j], axis=1)``, the same sums in the same order, without the
    two gathered ``(k, 3)`` copies."""
    out = np.empty(len(i))
    for q in range(len(i)):
        a, b = i[q], j[q]
        d0, d1, d2 = y[a, 0] - y[b, 0], y[a, 1] - y[b, 1], y[a, 2] - y[b, 2]
        out[q] = np.sqrt((d0 * d0 + d1 * d1) + d2 * d2)
    return out


def layers_part(layers: np.ndarray, level: int) -> np.ndarray:
    """(3·(LAYERS_LMAX+1),) the *layers* part: ``sqrt(E_jl)``, the per-degree energies of the
    geometric KLT layers (n_grid, 3), degrees 0..``LAYERS_LMAX`` on the Driscoll–Healy grid of
    degree ``LAYERS_GRID_LMAX``."""
    e = degree_energies(layers, level, LAYERS_LMAX, grid_lmax=LAYERS_GRID_LMAX)
    return np.sqrt(np.maximum(e, 0)).ravel()


def _shape_vector(parts: dict) -> np.ndarray:
    """The ``shape`` descriptor: the parts, each times its :data:`SHAPE_PART_SCALES` entry."""
    return np.concatenate([s * parts[name] for name, s in zip(SHAPE_PARTS, SHAPE_PART_SCALES)])


@functools.lru_cache(maxsize=4)
def _grid_solver(level: int) -> SPDSolver:
    """The factoriser of the level-``level`` grid's Laplacians: every model's has the grid's
    connectivity, so its nested-dissection order is computed once per level."""
    return SPDSolver()


def log_spectrum(x: np.ndarray, level: int, *, max_level: int = SPECTRAL_LEVEL) -> np.ndarray:
    """(SPECTRAL_K,) ``log(λ_i A / (4π i))`` of the grid surface's Laplace–Beltrami operator.

    Cotangent stiffness ``K`` and lumped (barycentric) mass ``M`` on the icosphere mesh of level
    ``min(level, max_level)`` at the resampled positions (a prefix of ``x``). Cotangents of
    degenerate triangles are clipped at ±``1/TOL.degenerate_angle`` and vertex masses floored, so
    a squeezed map gives a finite spectrum. Dense solve up to 700 vertices; beyond, shift-invert
    Lanczos on the standard form ``M^-½ K M^-½`` (one operator solve per Lanczos step, none with
    ``M``) with one LU factor in the grid's nested-dissection order.
    """
    import scipy.linalg
    from scipy.sparse.linalg import LinearOperator, eigsh

    lev = min(level, max_level)
    f = icosphere(lev).faces
    n = vertex_count(lev)
    v = x[:n][f]
    area2 = np.linalg.norm(np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0]), axis=1)
    total = 0.5 * float(area2.sum())
    if not total > 0:
        raise InputError("the resampled surface has zero area; cannot normalise its scale")
    cot = np.empty((len(f), 3))
    for a in range(3):
        e1, e2 = v[:, (a + 1) % 3] - v[:, a], v[:, (a + 2) % 3] - v[:, a]
        cot[:, a] = np.einsum("ij,ij->i", e1, e2) / np.maximum(area2, 1e-300)
    cot = np.clip(cot, -1.0 / TOL.degenerate_angle, 1.0 / TOL.degenerate_angle)
    stiff = cotangent_laplacian(f, cot, n)
    mass = vertex_area_shares(f, 0.5 * area2, n)
    mass = np.maximum(mass, TOL.degenerate_area * total / n)
    k = SPECTRAL_K
    if n <= 700:
        lam = scipy.linalg.eigh(stiff.toarray(), np.diag(mass), eigvals_only=True,
                                subset_by_index=(0, k))
    else:
        # the standard form C = M^-1/2 K M^-1/2 shifted below 0, so that K - sigma M is
        # positive definite (a plain LU works); (C - sigma)^-1 y = M^1/2 (K - sigma M)^-1 M^1/2 y
        sigma = -0.1 * 4.0 * np.pi / total
        lu = _grid_solver(lev).factor(stiff + sp.diags(-sigma * mass))
        root = np.sqrt(mass)

        def solve(y):
            return root * lu.solve(root * y.ravel())

        # a fixed start vector: ARPACK's own random start depends on its earlier calls
        v0 = np.random.default_rng(SEED).standard_normal(n)
        mu = eigsh(LinearOperator((n, n), matvec=solve, dtype=np.float64), k=k + 1,
                   which="LA", v0=v0, tol=SPECTRAL_TOL, return_eigenvectors=False)
        lam = np.sort(sigma + 1.0 / mu)
    lam = np.maximum(lam[1:k + 1] * total / (4.0 * np.pi), 1e-12)
    return np.log(lam / np.arange(1, k + 1))


def describe_grid(values, level: int, *, lmax: int = DEFAULT_LMAX,
                  virtual=None) -> DescriptorSet:
    """Descriptors of a model from its layers on the icosahedral grid.

    Parameters
    ----------
    values : (n_grid, 3) or (n_grid, 6) float64
        x, y, z (and r, g, b in 0..255) at the vertices of the level-``level`` icosphere.
    level : int
        Grid level.
    lmax : int
        Largest spherical-harmonic degree (keyword-only; stored in ``params``).
    virtual : (n_grid,) bool, optional
        The grid vertices that sample a virtual patch (the codec's mask): the measure parts of
        the ``shape`` vector then describe the real surface only (:func:`shape_parts`), which is
        what a partial scan holds. Default: every vertex counts.

    Returns
    -------
    DescriptorSet

    Raises
    ------
    InputError
        On a wrong shape for the level, NaNs, a degenerate (zero-variance) geometry, a bad lmax,
        or a ``virtual`` mask of another length than the grid or that covers every vertex.
    """
    ico = icosphere(level)
    values = as_array(values, "values", shape=(ico.n_vertices, None))
    if values.shape[1] not in (3, 6):
        raise InputError(f"values must have 3 or 6 columns (x y z [r g b]), got {values.shape[1]}")
    if level < 1:
        raise InputError(f"the shape descriptor needs a grid of level >= 1 (42 vertices), got "
                         f"level {level}; resample on a finer grid")
    if not (isinstance(lmax, (int, np.integer)) and 2 <= lmax <= 128):
        raise InputError(f"lmax must be an integer in 2..128, got {lmax!r}")
    if virtual is not None:
        virtual = as_array(virtual, "virtual", dtype=bool, shape=(ico.n_vertices,))
        if virtual.all():
            raise InputError("the virtual mask covers every grid vertex; there is no real "
                             "surface to describe (pass virtual=None)")
    area = ico.vertex_areas()
    geo = KLT.fit(values[:, :3], sample_weights=area)
    total = float(np.sum(geo.eigenvalues))
    if not total > 0:
        raise InputError("the geometry has zero variance; cannot normalise its scale")
    g = geo.forward(values[:, :3]) / np.sqrt(total)
    vectors = {
        "shape": _shape_vector(shape_parts(values[:, :3], level, g, virtual=virtual)),
        "layers": np.sqrt(np.maximum(degree_energies(g, level, lmax), 0)).ravel(),
        "spectrum": np.asarray(geo.eigenvalues) / total,
        "views": model_views(values[:, :3], ico.faces).ravel(),
    }
    if values.shape[1] == 6:
        vectors["texture"] = texture_vector(values[:, 3:], level, lmax)
    vectors = {k: np.asarray(v, np.float32) for k, v in vectors.items()}
    return DescriptorSet(vectors, descriptor_params(lmax=lmax))


def texture_vector(colors: np.ndarray, level: int, lmax: int) -> np.ndarray:
    """(3·(lmax+1) + 3,) the ``texture`` descriptor of grid colours (n_grid, 3) in 0..255: sqrt
    per-degree energies of the colour KLT layers (units /255, sphere-area weights), then the
    area-weighted mean colour /255."""
    area = icosphere(level).vertex_areas()
    col = colors / 255.0
    c = KLT.fit(col, sample_weights=area).forward(col)
    mean_col = (area @ col) / area.sum()
    return np.concatenate([np.sqrt(np.maximum(degree_energies(c, level, lmax), 0)).ravel(),
                           mean_col])


def descriptor_params(*, lmax: int = DEFAULT_LMAX) -> dict:
    """The conventions :func:`describe_grid` stores with its vectors (``DescriptorSet.params``).

    Two descriptor sets are comparable when these are equal; the database keeps them with every
    vector (``descriptors.convention``) and ``surfidx redescribe`` recomputes the vectors whose
    conventions differ from this surfidx's.
    """
    return {"lmax": int(lmax), "normalization": SH_NORMALIZATION, "version": DESCRIPTOR_VERSION,
            "shape": {"shells": SHELLS, "shell_lmax": SHELL_LMAX, "shell_rmax": SHELL_RMAX,
                      "shell_kappa": SHELL_KAPPA, "d2_bins": D2_BINS, "d2_rmax": D2_RMAX,
                      "d2_pairs": D2_PAIRS, "radial_bins": RADIAL_BINS,
                      "radial_rmax": RADIAL_RMAX, "spectral_k": SPECTRAL_K,
                      "spectral_level": SPECTRAL_LEVEL, "spectral_tol": SPECTRAL_TOL,
                      "shape_level": SHAPE_LEVEL, "layers_lmax": LAYERS_LMAX,
                      "layers_grid_lmax": LAYERS_GRID_LMAX,
                      "seed": SEED,
                      "part_scales": [float(v) for v in SHAPE_PART_SCALES]},
            "views": view_params()}


def descriptor_distance(a: dict, b: dict, *, shape_weight: float = DEFAULT_SHAPE_WEIGHT) -> float:
    """Distance between two models' descriptor dicts: :func:`surfidx.describe.distance.weighted_l2` (the
    default search distance) for one pair.

    ``d = w·‖Δshape‖ + (1 − w)·‖Δtexture‖`` with ``w = shape_weight``; when either model lacks
    colour the texture term is dropped and ``d = ‖Δshape‖``. The KLT spectrum is part of the shape
    term (appended to the shape vector), whose parts are weighted already
    (:data:`SHAPE_PART_WEIGHTS`).

    Parameters
    ----------
    a, b : dict of str -> (d,) float32
    shape_weight : float
        In [0, 1] (default :data:`surfidx.describe.distance.DEFAULT_SHAPE_WEIGHT`).

    Returns
    -------
    float

    Raises
    ------
    InputError
        ``shape_weight`` outside [0, 1], a missing ``shape`` vector, or vectors of different
        dimensions (another descriptor version or settings).
    """
    w = check_shape_weight(shape_weight)
    for d in (a, b):
        if "shape" not in d:
            raise InputError("a descriptor set lacks its 'shape' vector")
    for kind in ("shape", "spectrum", "texture"):
        na, nb = (np.size(d[kind]) if kind in d else None for d in (a, b))
        if kind != "texture" and na != nb or kind == "texture" and None not in (na, nb) \
                and na != nb:
            raise InputError(f"descriptor dimensions differ ({kind!r}: {na} and {nb} values; "
                             "different descriptor version or settings?); recompute them")
    stored = {k: np.asarray(b[k], np.float64).reshape(1, -1) for k in DEFAULT_KINDS if k in b}
    present = {k: np.ones(1, bool) for k in stored}
    query = {k: np.asarray(a[k], np.float64) for k in DEFAULT_KINDS if k in a}
    return float(weighted_l2(query, stored, present, shape_weight=w)[0])
