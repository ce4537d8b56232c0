"""Helpers for benchmarks/retrieval.py: the D2 shape distribution baseline, Princeton Shape
Benchmark retrieval statistics, and exact-surface resampling of a mesh for invariance tests.

D2 (Osada, Funkhouser, Chazelle & Dobkin 2002): the histogram of Euclidean distances between
pairs of points sampled uniformly (area-weighted) on the surface. Scale is normalised by dividing
the distances by their mean; the histogram (``bins`` bins over ``[0, max_ratio)`` times the mean)
is a probability distribution compared with the L1 distance.
"""

from __future__ import annotations

import numpy as np

__all__ = ["sample_surface", "d2_histogram", "l1_distances", "psb_statistics",
           "split_faces", "random_similarity", "sh_descriptor", "l2_distances", "simulate_view",
           "cut_base", "jitter", "largest_piece", "write_off", "query_statistics"]

SH_PARAMS = {"points": 8192, "shells": 32, "lmax": 16, "seed": 0}
"""Settings of the spherical-harmonic shape descriptor baseline (:func:`sh_descriptor`)."""
VIEW_PARAMS = {"distance": 2.5, "pixels": 384, "samples": 400_000, "depth_tol": 0.01}
"""Simulated single view (:func:`simulate_view`): camera distance from the centre in bounding-box
diagonals, z-buffer size, surface samples splatted into it, depth tolerance in diagonals."""
BASE_CUT = 0.06
"""Share of the surface area a base cut removes (:func:`cut_base`)."""
JITTER = 0.002
"""RMS displacement of a noisy scan's vertices, in bounding-box diagonals (:func:`jitter`)."""
D2_PARAMS = {"points": 4096, "pairs": 1 << 20, "bins": 64, "max_ratio": 3.0, "seed": 0}


def sample_surface(vertices, faces, n: int, rng) -> np.ndarray:
    """(n, 3) points uniform over the surface (area-weighted faces, uniform barycentrics)."""
    v = vertices[faces]
    area = 0.5 * np.linalg.norm(np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0]), axis=1)
    f = rng.choice(len(faces), size=n, p=area / area.sum())
    r1, r2 = rng.random(n), rng.random(n)
    s = np.sqrt(r1)
    a, b, c = 1 - s, s * (1 - r2), s * r2
    return a[:, None] * v[f, 0] + b[:, None] * v[f, 1] + c[:, None] * v[f, 2]


def d2_histogram(vertices, faces, *, points=D2_PARAMS["points"], pairs=D2_PARAMS["pairs"],
                 bins=D2_PARAMS["bins"], max_ratio=D2_PARAMS["max_ratio"],
                 seed=D2_PARAMS["seed"]) -> np.ndarray:
    """(bins,) float64 D2 shape distribution (sums to 1), distances divided by their mean."""
    rng = np.random.default_rng(seed)
    p = sample_surface(np.asarray(vertices, float), np.asarray(faces), points, rng)
    i = rng.integers(0, points, pairs)
    j = rng.integers(0, points, pairs)
    keep = i != j
    d = np.linalg.norm(p[i[keep]] - p[j[keep]], axis=1)
    d /= d.mean()
    h, _ = np.histogram(np.minimum(d, max_ratio * (1 - 1e-12)), bins=bins, range=(0, max_ratio))
    return h / h.sum()


def l1_distances(h: np.ndarray) -> np.ndarray:
    """(n, n) L1 distances between the rows of ``h``."""
    return np.abs(h[:, None, :] - h[None, :, :]).sum(-1)


def psb_statistics(dist: np.ndarray, labels, *, queries=None) -> dict:
    """Leave-one-out Princeton Shape Benchmark statistics.

    Parameters
    ----------
    dist : (n, n) float64
        Distances; ``inf`` marks a model that cannot be retrieved (ranked last, in index order).
    labels : sequence of n str
    queries : (n,) bool, optional
        Which models are queried (default all); a query whose class has no other model is skipped.
        A query whose own row is all ``inf`` (its descriptor failed) scores 0 everywhere.

    Returns
    -------
    dict
        ``nn``, ``ft`` (first tier), ``st`` (second tier), ``dcg`` (normalised), ``map`` (mean
        average precision), ``n`` (queries scored) and ``per_query`` arrays of each statistic.
    """
    labels = np.asarray(labels)
    n = len(labels)
    queries = np.ones(n, bool) if queries is None else np.asarray(queries, bool)
    out = {k: [] for k in ("nn", "ft", "st", "dcg", "map")}
    qidx = []
    for q in np.flatnonzero(queries):
        rel_total = int(np.sum(labels == labels[q])) - 1
        if rel_total < 1:
            continue
        qidx.append(q)
        row = dist[q].astype(float).copy()
        if not np.any(np.isfinite(np.delete(row, q))):
            for k in out:
                out[k].append(0.0)
            continue
        row[q] = np.nan
        order = np.argsort(np.where(np.isnan(row), np.inf, row), kind="stable")
        order = order[order != q]
        rel = (labels[order] == labels[q]).astype(float)
        c = rel_total
        out["nn"].append(rel[0])
        out["ft"].append(rel[:c].sum() / c)
        out["st"].append(rel[:2 * c].sum() / c)
        disc = np.r_[1.0, 1.0 / np.log2(np.arange(2, len(rel) + 1))]
        ideal = disc[:c].sum()
        out["dcg"].append(float((rel * disc).sum() / ideal))
        hits = np.cumsum(rel)
        ranks = np.arange(1, len(rel) + 1)
        out["map"].append(float(np.sum(rel * hits / ranks) / c))
    res = {k: float(np.mean(v)) if v else float("nan") for k, v in out.items()}
    res["n"] = len(qidx)
    res["per_query"] = {k: np.asarray(v) for k, v in out.items()}
    res["queries"] = np.asarray(qidx, int)
    return res


def random_similarity(rng):
    """A random rotation (det +1), a log-uniform scale in [0.2, 5] and a translation."""
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    q = q * np.sign(np.diag(r))
    if np.linalg.det(q) < 0:
        q[:, 0] = -q[:, 0]
    scale = float(np.exp(rng.uniform(np.log(0.2), np.log(5.0))))
    shift = rng.normal(scale=10.0, size=3)
    return q, scale, shift


def split_faces(vertices, faces, fraction: float, rng):
    """Resample a triangle mesh without changing its surface: a random ``fraction`` of the faces
    is split 1→3 at a random interior point (Dirichlet(2,2,2) barycentrics), so the vertex set (the
    surfels) and the connectivity change while the surface stays exactly the same."""
    vertices = np.asarray(vertices, float)
    faces = np.asarray(faces, np.int64)
    pick = rng.random(len(faces)) < fraction
    f = faces[pick]
    w = rng.dirichlet([2.0, 2.0, 2.0], size=len(f))
    new = np.einsum("fk,fkd->fd", w, vertices[f])
    m = len(vertices) + np.arange(len(f))
    a, b, c = f[:, 0], f[:, 1], f[:, 2]
    added = np.concatenate([np.c_[a, b, m], np.c_[b, c, m], np.c_[c, a, m]])
    return np.vstack([vertices, new]), np.vstack([faces[~pick], added])


def l2_distances(h: np.ndarray, g: np.ndarray | None = None) -> np.ndarray:
    """(n, m) L2 distances between the rows of ``h`` and those of ``g`` (default ``h``)."""
    g = h if g is None else g
    return np.sqrt(np.maximum(((h[:, None, :] - g[None, :, :]) ** 2).sum(-1), 0.0))


def sh_descriptor(vertices, faces, *, points=SH_PARAMS["points"], shells=SH_PARAMS["shells"],
                  lmax=SH_PARAMS["lmax"], seed=SH_PARAMS["seed"]) -> np.ndarray:
    """(shells·(lmax+1),) rotation-invariant spherical-harmonic shape descriptor (Kazhdan,
    Funkhouser & Rusinkiewicz 2003), on surface samples instead of a voxel grid.

    ``points`` area-weighted samples of the surface, centred on their mean and scaled so that
    their mean distance to it is 1/2 (Kazhdan's normalisation: the unit ball holds the shape), are
    split linearly between the two nearest of ``shells`` concentric spheres over radii [0, 1]
    (samples farther out go to the last one); each sphere's measure on the direction sphere gives
    the norm of each degree ``0..lmax``. Compared with the L2 distance."""
    from scipy.special import sph_harm_y

    rng = np.random.default_rng(seed)
    p = sample_surface(np.asarray(vertices, float), np.asarray(faces), points, rng)
    y = p - p.mean(axis=0)
    r = np.linalg.norm(y, axis=1)
    y = y / (2.0 * r.mean())
    r = r / (2.0 * r.mean())
    theta = np.arccos(np.clip(y[:, 2] / np.maximum(r, 1e-300), -1.0, 1.0))
    phi = np.arctan2(y[:, 1], y[:, 0])
    s = np.minimum(r * (shells - 1), shells - 1)
    lo = np.minimum(np.floor(s).astype(np.int64), shells - 2)
    t = s - lo
    out = np.zeros((shells, lmax + 1))
    for l in range(lmax + 1):
        for m in range(l + 1):
            yl = sph_harm_y(l, m, theta, phi)
            e = 0.0
            for part in (yl.real, yl.imag):
                c = (np.bincount(lo, weights=part * (1 - t), minlength=shells)
                     + np.bincount(lo + 1, weights=part * t, minlength=shells))
                e = e + c ** 2
            out[:, l] += e if m == 0 else 2.0 * e
    return np.sqrt(out).ravel() / points


def _face_components(faces: np.ndarray, n_vertices: int) -> np.ndarray:
    """Connected-component label of each face (faces sharing a vertex are connected)."""
    import scipy.sparse as sp
    from scipy.sparse.csgraph import connected_components

    m = len(faces)
    rows = np.repeat(np.arange(m), 3)
    inc = sp.csr_matrix((np.ones(3 * m), (rows, faces.ravel())), shape=(m, n_vertices))
    _, lab = connected_components(inc @ inc.T, directed=False)
    return lab


def largest_piece(vertices, faces):
    """The largest connected piece (by face count) of a mesh, unused vertices dropped."""
    vertices, faces = np.asarray(vertices, float), np.asarray(faces, np.int64)
    if len(faces) == 0:
        return vertices[:0], faces
    lab = _face_components(faces, len(vertices))
    keep = faces[lab == np.argmax(np.bincount(lab))]
    used, inv = np.unique(keep, return_inverse=True)
    return vertices[used], inv.reshape(-1, 3)


def simulate_view(vertices, faces, rng, *, distance=VIEW_PARAMS["distance"],
                  pixels=VIEW_PARAMS["pixels"], samples=VIEW_PARAMS["samples"],
                  depth_tol=VIEW_PARAMS["depth_tol"]):
    """A single-view scan of a mesh from a random camera: (vertices, faces) of the largest
    connected piece of the faces a pinhole camera sees.

    The camera looks at the bounding-box centre from a uniformly random direction, ``distance``
    diagonals away, with a field of view that holds the whole model. A face is kept when it faces
    the camera (its normal has a positive component towards the camera, either winding taken as
    outward: the meshes are closed and consistently oriented) and it is visible: its centroid is
    no more than ``depth_tol`` diagonals behind the depth buffer at its pixel, the buffer being the
    nearest of ``samples`` area-weighted surface samples splatted into ``pixels``² pixels."""
    v, f = np.asarray(vertices, float), np.asarray(faces, np.int64)
    lo, hi = v.min(axis=0), v.max(axis=0)
    diag = float(np.linalg.norm(hi - lo))
    centre = 0.5 * (lo + hi)
    d = rng.normal(size=3)
    d /= np.linalg.norm(d)
    eye = centre + distance * diag * d
    fwd = -d
    up = np.array([0.0, 1.0, 0.0]) if abs(fwd[1]) < 0.9 else np.array([1.0, 0.0, 0.0])
    right = np.cross(fwd, up)
    right /= np.linalg.norm(right)
    up = np.cross(right, fwd)

    def project(p):
        q = p - eye
        z = q @ fwd
        return (q @ right) / z, (q @ up) / z, z

    half = 0.5 / (distance - 0.5) * 1.05       # tan of half the field of view
    tri = v[f]
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    cen = tri.mean(axis=1)
    signed = np.einsum("ij,ij->i", normal, eye - cen)
    # outward normals: the winding whose normals point away from the centre on the whole
    if np.einsum("ij,ij->", normal, cen - v.mean(axis=0)) < 0:
        signed = -signed
    facing = signed > 0
    pts = sample_surface(v, f, samples, rng)
    u, w, z = project(pts)
    px = np.clip(((u / half + 1) * 0.5 * pixels).astype(np.int64), 0, pixels - 1)
    py = np.clip(((w / half + 1) * 0.5 * pixels).astype(np.int64), 0, pixels - 1)
    depth = np.full(pixels * pixels, np.inf)
    np.minimum.at(depth, py * pixels + px, z)
    u, w, z = project(cen)
    px = np.clip(((u / half + 1) * 0.5 * pixels).astype(np.int64), 0, pixels - 1)
    py = np.clip(((w / half + 1) * 0.5 * pixels).astype(np.int64), 0, pixels - 1)
    visible = z <= depth[py * pixels + px] + depth_tol * diag
    return largest_piece(v, f[facing & visible])


def cut_base(vertices, faces, *, share=BASE_CUT, axis=1):
    """The mesh without its base: the faces whose centroid lies in the lowest ``share`` of the
    surface area along ``axis`` (default y, the collection's up axis) are removed; largest
    piece kept."""
    v, f = np.asarray(vertices, float), np.asarray(faces, np.int64)
    tri = v[f]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    h = tri[:, :, axis].mean(axis=1)
    order = np.argsort(h, kind="stable")
    cum = np.cumsum(area[order]) / area.sum()
    drop = order[cum <= share]
    keep = np.ones(len(f), bool)
    keep[drop] = False
    return largest_piece(v, f[keep])


def jitter(vertices, rng, *, rms=JITTER):
    """Vertices moved by Gaussian noise of RMS length ``rms`` bounding-box diagonals."""
    v = np.asarray(vertices, float)
    diag = float(np.linalg.norm(v.max(axis=0) - v.min(axis=0)))
    return v + rng.normal(scale=rms * diag / np.sqrt(3.0), size=v.shape)


def write_off(path, vertices, faces) -> None:
    """Write a triangle mesh as an OFF file."""
    v, f = np.asarray(vertices, float), np.asarray(faces, np.int64)
    with open(path, "w") as fh:
        fh.write(f"OFF\n{len(v)} {len(f)} 0\n")
        np.savetxt(fh, v, fmt="%.9g")
        np.savetxt(fh, np.c_[np.full(len(f), 3), f], fmt="%d")


def query_statistics(dist: np.ndarray, query_labels, labels, own=None) -> dict:
    """Statistics of queries that are not in the collection (a partial scan of a stored model).

    Parameters
    ----------
    dist : (q, n) float64
        Distance of each query to each stored model (``inf``: cannot be retrieved).
    query_labels : (q,) str
    labels : (n,) str
    own : (q,) int, optional
        The stored model each query was made from (it counts as relevant: its class).

    Returns
    -------
    dict
        Means of ``own`` (own model first), ``nn`` (class of the first result), ``ft`` (first
        tier: share of the class among the first class-size results), ``map``; ``own_rank``
        (median rank of the own model, 1 = first); ``per_query`` arrays. A query whose row is
        all ``inf`` (its scan could not be described) scores 0 and ranks its model last.
    """
    labels, query_labels = np.asarray(labels), np.asarray(query_labels)
    out = {k: [] for k in ("own", "nn", "ft", "map", "own_rank")}
    for q in range(len(dist)):
        if not np.isfinite(dist[q]).any():     # the query failed: 0 everywhere, ranked last
            for k, v in (("nn", 0.0), ("ft", 0.0), ("map", 0.0), ("own", 0.0),
                         ("own_rank", len(labels))):
                if k not in ("own", "own_rank") or own is not None:
                    out[k].append(v)
            continue
        order = np.argsort(dist[q], kind="stable")
        rel = (labels[order] == query_labels[q]).astype(float)
        c = rel.sum()
        out["nn"].append(rel[0])
        out["ft"].append(rel[:int(c)].sum() / c)
        hits = np.cumsum(rel)
        out["map"].append(float(np.sum(rel * hits / np.arange(1, len(rel) + 1)) / c))
        if own is not None:
            rank = int(np.flatnonzero(order == own[q])[0]) + 1
            out["own"].append(float(rank == 1))
            out["own_rank"].append(rank)
    res = {k: float(np.mean(v)) if v else float("nan") for k, v in out.items()}
    res["own_rank"] = float(np.median(out["own_rank"])) if out["own_rank"] else float("nan")
    res["n"] = len(dist)
    res["per_query"] = {k: np.asarray(v) for k, v in out.items()}
    return res
