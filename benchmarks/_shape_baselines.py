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
           "split_faces", "random_similarity"]

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
