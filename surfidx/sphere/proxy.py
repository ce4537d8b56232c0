"""Proxy meshes for surfel sets without faces: a closed genus-0 triangulation to map to the sphere.

:func:`proxy_mesh` reconstructs a closed, manifold, outward-wound triangle mesh from an oriented
point cloud: the signed distance of Hoppe et al. (1992) -- the distance to the tangent planes of
the nearest surfels, Gaussian-weighted over a few of them -- is sampled on a voxel grid in a narrow
band around the surfels only; the grid nodes outside the band take the sign of the band around
them (each connected region of them is labelled by the majority sign of the band nodes it touches,
the region touching the grid border is outside), so the zero set is one clean closed surface with
no spurious sheets far from the data. Marching cubes (Lewiner et al. 2003, the topologically
consistent variant of :func:`skimage.measure.marching_cubes`) extracts it; the largest connected
piece is kept and checked to be closed, manifold and of genus 0.

:func:`transfer` carries per-vertex values of the proxy (e.g. its sphere positions) to arbitrary
points: the exact closest point on the mesh (KD-tree candidates, certified by a distance bound, and
a compiled point-triangle projection) and barycentric interpolation there.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from ..jit import njit
from scipy import ndimage
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from ..errors import InputError, TopologyError
from ..validate import as_array, check_positive_int
from ..geometry.closest import closest_on_triangle, closest_points, project_to_candidates  # noqa: F401
from ..geometry.mesh import TriangleMesh
from ..geometry.surfels import SurfelSet

__all__ = ["proxy_mesh", "transfer", "closest_points", "auto_resolution", "MAX_RESOLUTION",
           "MIN_POINTS"]

MIN_POINTS = 32
"""Fewest surfels :func:`proxy_mesh` accepts."""

MAX_RESOLUTION = 512
"""Most grid cells along the longest bounding-box axis (``resolution`` argument)."""

_AUTO_MAX = 200  # automatic grid: at most this many cells along the longest axis (8M nodes)
_AUTO_MIN = 24   # ... and at least this many
_NEIGHBOURS = 8  # surfels averaged in the signed distance
_AGREE = 0.5  # cosine: neighbours whose normals are within 60 degrees of the nearest's count
_DISK_CELLS = 12  # surfel disks are rasterised up to this many cells from their centres
_LADDER = (1.0, 1.4, 0.7, 2.0, 0.5)  # automatic grid: multiples of extent / spacing tried
_BAND = 3        # half width of the narrow band, in grid cells
_ZERO_GUARD = 1e-3  # |field| is kept above this fraction of a cell: no vertex sits on a grid node


# ---------------------------------------------------------------------- signed distance
def _spacing(points: np.ndarray) -> float:
    """Median distance to the 3rd nearest other surfel (robust to duplicated points)."""
    k = min(3, len(points) - 1)
    d, _ = cKDTree(points).query(points, k=k + 1)
    s = float(np.median(d[:, k]))
    if not s > 0:
        pos = d[:, k][d[:, k] > 0]
        if not len(pos):
            raise InputError("all surfels coincide; a proxy surface needs points spread over it")
        s = float(np.median(pos))
    return s


def _signed_distance(tree, points, normals, x, sigma, k):
    """Gaussian-weighted mean distance of ``x`` to the tangent planes of its ``k`` nearest
    surfels (those facing like the nearest), and the matching weighted normal."""
    d, idx = tree.query(x, k=k, workers=-1)
    if k == 1:
        d, idx = d[:, None], idx[:, None]
    nrm = normals[idx]
    plane = np.einsum("nkj,nkj->nk", x[:, None, :] - points[idx], nrm)
    ref = np.argmin(d, axis=1)
    rows = np.arange(len(d))
    w = np.exp(-((d - d[rows, ref][:, None]) / sigma) ** 2)  # relative: never all underflow
    # only surfels facing like the nearest one: across a thin part, the planes of the far side
    # would pull the field to the wrong sign and glue the two sides (spurious handles)
    w = w * (np.einsum("nkj,nj->nk", nrm, nrm[rows, ref]) > _AGREE)
    ws = w.sum(axis=1)
    f = (w * plane).sum(axis=1) / ws
    g = (w[:, :, None] * nrm).sum(axis=1) / ws[:, None]
    return f, g


def _disk_samples(points, normals, radii, h, *, most: int):
    """Points spread over each surfel's disk at most a cell apart (the centre alone for disks
    smaller than a cell; radii are capped at ``most`` cells), yielded in groups."""
    level = np.minimum(np.ceil(radii / h), most).astype(np.int64)
    yield points[level <= 1]
    # tangent frames
    a = np.where(np.abs(normals[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    t1 = np.cross(normals, a)
    t1 /= np.linalg.norm(t1, axis=1)[:, None]
    t2 = np.cross(normals, t1)
    for lev in np.unique(level[level > 1]):
        sel = np.flatnonzero(level == lev)
        g = np.arange(-lev, lev + 1)
        u, v = np.meshgrid(g, g, indexing="ij")
        keep = u ** 2 + v ** 2 <= lev ** 2
        u, v = u[keep] / lev, v[keep] / lev  # unit disk, step 1/lev
        r = np.minimum(radii[sel], most * h)[:, None, None]
        off = r * (u[None, :, None] * t1[sel][:, None, :] + v[None, :, None] * t2[sel][:, None, :])
        yield (points[sel][:, None, :] + off).reshape(-1, 3)


def _grid_field(points, normals, radii, h, spacing):
    """The signed distance on a padded grid of step ``h``; returns (field, origin)."""
    # disks reach up to _DISK_CELLS cells beyond their centres, the band _BAND cells further
    pad = _BAND + 2 + int(min(np.ceil(radii.max() / h), _DISK_CELLS))
    lo = points.min(axis=0) - pad * h
    dims = np.ceil((points.max(axis=0) - points.min(axis=0)) / h).astype(np.int64) + 2 * pad + 1
    # band: nodes within _BAND cells (Chebyshev) of a node next to a surfel's disk (disks cover
    # the surface, so sparse regions leave no gap through which outside would leak inside)
    occ = np.zeros(dims, bool)
    for x in _disk_samples(points, normals, radii, h, most=_DISK_CELLS):
        ijk = np.floor((x - lo) / h).astype(np.int64)
        ijk = ijk[np.all((ijk >= 0) & (ijk < dims - 1), axis=1)]
        for c in np.ndindex(2, 2, 2):
            occ[tuple((ijk + np.array(c)).T)] = True
    band = ndimage.binary_dilation(occ, structure=np.ones((3, 3, 3), bool), iterations=_BAND)
    for axis in range(3):  # the border layer stays outside, so the surface is closed
        band[(slice(None),) * axis + (0,)] = False
        band[(slice(None),) * axis + (-1,)] = False
    nodes = np.argwhere(band)
    tree = cKDTree(points)
    sigma = max(h, spacing)
    f, _ = _signed_distance(tree, points, normals, lo + nodes * h, sigma, min(_NEIGHBOURS,
                                                                             len(points)))
    limit = (_BAND + 1) * h
    f = np.clip(f, -limit, limit)
    field = np.zeros(dims)
    field[tuple(nodes.T)] = f
    # regions outside the band: the majority sign of the band nodes they touch (6-neighbours);
    # the region touching the grid border is outside whatever the vote
    lab, nlab = ndimage.label(~band)
    vote = np.zeros(nlab + 1)
    sgn = np.sign(field)
    for axis in range(3):
        for shift in (1, -1):
            nb_lab = np.roll(lab, shift, axis=axis)
            touch = band & (nb_lab > 0)
            # np.roll wraps: the border layers are never band nodes (padding), so no false touch
            vote += np.bincount(nb_lab[touch], sgn[touch], minlength=nlab + 1)
    sign = np.where(vote >= 0, 1.0, -1.0)
    border = np.unique(np.concatenate([lab[[0, -1]].ravel(), lab[:, [0, -1]].ravel(),
                                       lab[:, :, [0, -1]].ravel()]))
    border = border[border > 0]
    if vote[border].sum() < 0:
        raise TopologyError("the surfel normals point inward (the signed distance is negative "
                            "around the outside of the cloud); flip them so they point outward")
    sign[border] = 1.0
    sign[0] = 0.0
    outside = ~band
    field[outside] = sign[lab[outside]] * limit
    guard = _ZERO_GUARD * h
    small = np.abs(field) < guard
    field[small] = np.where(field[small] < 0, -guard, guard)
    return field, lo


# ---------------------------------------------------------------------- mesh clean-up
def _largest_component(v, f):
    n = len(v)
    e = np.concatenate([f[:, [0, 1]], f[:, [1, 2]]])
    g = sp.coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(n, n))
    ncomp, lab = connected_components(g, directed=False)
    if ncomp > 1:
        big = np.argmax(np.bincount(lab[f[:, 0]], minlength=ncomp))
        f = f[lab[f[:, 0]] == big]
    used = np.unique(f)
    remap = np.full(n, -1, np.int64)
    remap[used] = np.arange(len(used))
    return np.ascontiguousarray(v[used]), np.ascontiguousarray(remap[f])


def _merge_duplicates(v, f):
    """Merge vertices with identical coordinates; drop triangles that collapse."""
    uv, inv = np.unique(v, axis=0, return_inverse=True)
    if len(uv) == len(v):
        return v, f
    f = inv.ravel()[f]
    f = f[(f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 0] != f[:, 2])]
    return uv, f


def check_topology(v, f, *, genus0: bool):
    """Check that a proxy surface is one closed, manifold, consistently oriented piece (of
    genus 0 with ``genus0``).

    Parameters
    ----------
    v : ndarray of float64, shape (n, 3)
        The surface's vertices.
    f : ndarray of int, shape (m, 3)
        Its triangles.
    genus0 : bool
        Require genus 0.

    Raises
    ------
    TopologyError
        When the surface is not.
    """
    topo = TriangleMesh(v, f).topology()
    if not topo.closed or topo.nonmanifold_vertices:
        raise TopologyError(
            f"the proxy surface is not one closed manifold piece ({topo.boundary_edges} boundary "
            f"edges, {topo.nonmanifold_edges} non-manifold edges, {topo.nonmanifold_vertices} "
            "pinched vertices); pass a finer resolution or a denser point cloud")
    he = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    if len(np.unique(he[:, 0] * len(v) + he[:, 1])) != len(he):
        raise TopologyError("the proxy surface is not consistently oriented; pass a finer "
                            "resolution or a denser point cloud")
    if genus0 and topo.genus != 0:
        err = TopologyError(
            f"the proxy surface has genus {topo.genus} (Euler characteristic {topo.euler}); only "
            "genus-0 surfaces map to the sphere: change the resolution (a coarse grid can bridge "
            "close parts) or use method 'mds'")
        err.genus = topo.genus
        raise err
    return topo


def _extract(p, nrm, radii, h, spacing):
    """Marching cubes of the grid field; the largest piece, duplicates merged."""
    from skimage.measure import marching_cubes

    field, lo = _grid_field(p, nrm, radii, h, spacing)
    v, f, _, _ = marching_cubes(field, level=0.0, spacing=(h, h, h), method="lewiner",
                                allow_degenerate=True)
    v = np.asarray(v, np.float64) + lo
    f = np.asarray(f, np.int64)
    if not len(f):
        raise TopologyError("the point cloud encloses no volume at this resolution; check that "
                            "the normals point outward or pass a finer resolution")
    v, f = _merge_duplicates(v, f)
    return _largest_component(v, f)


# ---------------------------------------------------------------------- public: proxy mesh
def auto_resolution(points, *, scale: float = 1.0) -> int:
    """Grid cells along the longest bounding-box axis for a cell ``1 / scale`` times the
    automatic one (the median distance to the 3rd nearest point), clipped to 24 .. 200.

    Parameters
    ----------
    points : (n, 3) float64
    scale : float
        Positive; below 1 a coarser grid.

    Returns
    -------
    int
    """
    p = as_array(points, "points", shape=(None, 3), min_len=4)
    cells = scale * float((p.max(axis=0) - p.min(axis=0)).max()) / _spacing(p)
    return int(np.clip(np.ceil(cells), _AUTO_MIN, _AUTO_MAX))


def proxy_mesh(surfels, *, resolution: int | None = None, genus0: bool = True,
               project: bool = True):
    """A closed, manifold, outward-wound triangle mesh approximating an oriented point cloud.

    Parameters
    ----------
    surfels : SurfelSet
        Positions and outward unit normals (faces, radii and colours are ignored).
    resolution : int, optional
        Grid cells along the longest bounding-box axis (16 .. ``MAX_RESOLUTION``). By default the
        cell is the median distance to the 3rd nearest surfel, within 24 .. 200 cells, so the proxy
        has about as many vertices as there are surfels; when that proxy is not closed (genus 0
        with ``genus0``), grids 1.4, 0.7, 2 and 0.5 times as fine are tried in turn (clipped to
        24 .. 200) and the first good one is returned; the error of the first is raised if none.
    genus0 : bool
        Raise :class:`TopologyError` unless the proxy has genus 0 (what a spherical map needs).
    project : bool
        Move each proxy vertex onto the weighted tangent planes of its nearest surfels (one
        Newton step of the signed distance, at most half a cell): lowers the distance to the
        points from about a tenth of a cell to a fraction of that.

    Returns
    -------
    vertices : (m, 3) float64
    faces : (k, 3) int64
        Counter-clockwise seen from outside (positive signed volume).

    Raises
    ------
    InputError
        Not a SurfelSet, fewer than ``MIN_POINTS`` surfels, all surfels coincident, a resolution
        out of range.
    TopologyError
        The proxy is not one closed manifold piece, or (``genus0``) its genus is not 0; the error's
        ``genus`` attribute holds the genus.
    """
    if not isinstance(surfels, SurfelSet):
        raise InputError(f"surfels must be a SurfelSet, got {type(surfels).__name__}")
    n = len(surfels.positions)
    if n < MIN_POINTS:
        raise InputError(f"too few surfels for a proxy surface: {n} (need at least {MIN_POINTS}); "
                         "use a denser point cloud")
    p, nrm = surfels.positions, surfels.normals
    extent = float((p.max(axis=0) - p.min(axis=0)).max())
    spacing = _spacing(p)
    if resolution is None:
        # the cell about the surfel spacing; when that proxy is not closed genus 0 (a coarse grid
        # bridges close parts, a fine one opens gaps where the sampling is sparse), finer and
        # coarser grids are tried in turn and the first good one is kept
        base = extent / spacing
        ladder = [int(np.clip(np.ceil(base * m), _AUTO_MIN, _AUTO_MAX)) for m in _LADDER]
        ladder = list(dict.fromkeys(ladder))
    else:
        cells = check_positive_int(resolution, "resolution", minimum=16)
        if cells > MAX_RESOLUTION:
            raise InputError(f"resolution must be at most {MAX_RESOLUTION} cells, got {cells}; "
                             "a finer grid would not fit in memory")
        ladder = [cells]
    first = None
    for cells in ladder:
        h = extent / cells
        try:
            v, f = _extract(p, nrm, surfels.radii, h, spacing)
            check_topology(v, f, genus0=genus0)
            break
        except TopologyError as exc:
            first = first or exc
    else:
        raise first
    if project:
        d, g = _signed_distance(cKDTree(p), p, nrm, v, max(h, spacing), min(_NEIGHBOURS, n))
        gl = np.maximum(np.linalg.norm(g, axis=1), 1e-300)
        step = np.clip(d / gl, -0.5 * h, 0.5 * h)
        v = v - step[:, None] * (g / gl[:, None])
    vol = TriangleMesh(v, f).signed_volume()
    if vol < 0:
        f = f[:, [0, 2, 1]]
    return np.ascontiguousarray(v), np.ascontiguousarray(f)


def transfer(points, vertices, faces, values):
    """Per-vertex values of a mesh carried to arbitrary points by barycentric interpolation at
    their closest points on the mesh.

    Parameters
    ----------
    points : (n, 3) float64
        E.g. surfel positions.
    vertices : (m, 3) float64
    faces : (k, 3) int64
    values : (m, d) or (m,) float64
        One value per mesh vertex (e.g. its sphere position; renormalise after the transfer).

    Returns
    -------
    (n, d) or (n,) float64
        Values at the points; linear functions of position are reproduced exactly on the mesh.

    Raises
    ------
    InputError
        Bad shapes, non-finite values, face indices out of range, a ``values`` row count other
        than the vertex count.
    """
    vertices = as_array(vertices, "vertices", shape=(None, 3))
    values = as_array(values, "values")
    if values.ndim not in (1, 2) or len(values) != len(vertices):
        raise InputError(f"values must have shape ({len(vertices)},) or ({len(vertices)}, d): one "
                         f"row per mesh vertex, got {values.shape}")
    face, bary, _ = closest_points(points, vertices, faces)
    faces = np.asarray(faces, np.int64)
    corners = values[faces[face]]  # (n, 3) or (n, 3, d)
    if values.ndim == 1:
        return np.einsum("nc,nc->n", corners, bary)
    return np.einsum("ncd,nc->nd", corners, bary)
