"""Retrieval and invariance benchmark of the surfidx shape descriptors, beside a D2 baseline.

Data: ``../shared/data/retrieval`` (``labels.csv``: path,class; ``meta.csv``: genus, watertight,
...). Every model goes through the ingest code path up to the descriptors — read
(:func:`surfidx.read_surfels`) → spherical map (:func:`surfidx.sphere.parameterize`, the
pipeline's default method, no stress figure) → resampling on the icosahedral grid at
:func:`surfidx.icosphere.choose_level` (what :class:`surfidx.codec.Encoder` does before coding;
the coding itself is skipped) → :func:`surfidx.descriptors.describe_grid` →
:func:`surfidx.descriptors.descriptor_distance`. Models that cannot be mapped (genus > 0 raises
:class:`surfidx.TopologyError`) are failures: listed, never retrieved (ranked last) and scoring 0
as queries in the "all" rows. The D2 shape distribution (Osada et al. 2002; see
``_shape_baselines.py``) is computed in the same run on every model.

Statistics (leave-one-out, Princeton Shape Benchmark): nearest neighbour, first tier, second
tier, normalised DCG, mean average precision. "genus-0" rows restrict both queries and database to
the genus-0 models (``meta.csv``), as the issue's reference figures (D2 NN 0.62 mAP 0.53; Kazhdan
SH NN 0.68 mAP 0.53); a query whose class has no other model there is skipped.

Invariance: for a subset of genus-0 models, a copy that is randomly rotated, scaled (0.2–5×),
translated and resampled (a random 30% of the faces split 1→3 at random interior points: the same
surface, different surfels, different connectivity, possibly another grid level) goes through the
same path; the ratio of its descriptor distance to the model over the median distance between
different models must stay below 5%.

Cache: the per-model spherical-map results (grid layers, level, map figures) and D2 histograms are
stored in ``--cache`` (default ``/tmp/surfidx_retrieval_cache``), one file per model and variant,
keyed by the file's SHA-256, the variant, the map method and a hash of the source of every module
on the path to the grid (so a new parameterisation recomputes). Descriptors are recomputed from the
cached grids on every run (cheap), so descriptor changes need no ``--no-cache``.

Run: ``python benchmarks/retrieval.py [--workers 2] [--invariance 19|all|0] [--no-cache]
[--lmax L] [--json out.json]``
"""

from __future__ import annotations

import argparse
import csv
import hashlib
import json
import os
import sys
import time
import warnings
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("MKL_NUM_THREADS", "1")

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _shape_baselines as sb  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared" / "data" / "retrieval"
CACHE = Path("/tmp/surfidx_retrieval_cache")
SPLIT_FRACTION = 0.3
_CODE_MODULES = ("sphere", "spherical.py", "resample.py", "io.py", "mesh.py", "icosphere.py",
                 "surfels.py", "graph.py", "_tolerance.py")
"""Files and folders of ``surfidx/`` whose code determines the cache (a folder: all of its
``.py`` files, in sorted order, with their paths)."""
TARGET = {"nn": 0.75, "map": 0.60}
REFERENCE = {"D2 (issue)": {"nn": 0.62, "map": 0.53}, "Kazhdan SH (issue)": {"nn": 0.68,
                                                                               "map": 0.53}}


def code_version(method: str) -> str:
    """Hash of everything that determines the cached grid and D2 histogram."""
    h = hashlib.sha256()
    import surfidx

    h.update(surfidx.__version__.encode())
    for name in _CODE_MODULES:
        p = ROOT / "surfidx" / name
        for f in sorted(p.rglob("*.py")) if p.is_dir() else [p] if p.exists() else []:
            h.update(str(f.relative_to(ROOT)).encode())
            h.update(f.read_bytes())
    h.update((Path(__file__).resolve().parent / "_shape_baselines.py").read_bytes())
    h.update(json.dumps({"method": method, "d2": sb.D2_PARAMS, "split": SPLIT_FRACTION},
                        sort_keys=True).encode())
    return h.hexdigest()[:16]


def file_hash(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _load_model(path: Path, variant):
    """The surfels and mesh (vertices, faces) of a model or of its transformed, resampled copy."""
    import surfidx
    from surfidx.mesh import TriangleMesh

    mesh = surfidx.read_mesh(path)
    v, f = np.asarray(mesh.vertices, float), np.asarray(mesh.faces)
    if variant is not None:
        rng = np.random.default_rng(variant["seed"])
        rot, scale, shift = sb.random_similarity(rng)
        v, f = sb.split_faces(v, f, variant["fraction"], rng)
        v = scale * v @ rot.T + shift
        mesh = TriangleMesh(v, f, name=path.stem)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        surfels = mesh.to_surfels()
    return surfels, v, f


def compute(job: dict) -> dict:
    """Worker: map one model (or copy) to the sphere and resample it; D2 histogram. Cached."""
    cache_file = job["cache_file"]
    if cache_file is not None and Path(cache_file).exists():
        with np.load(cache_file, allow_pickle=False) as z:
            rec = json.loads(str(z["meta"]))
            rec["d2"] = z["d2"]
            rec["grid"] = z["grid"] if "grid" in z else None
        rec["cached"] = True
        return rec
    import surfidx
    from surfidx.icosphere import choose_level
    from surfidx.sphere import parameterize
    from surfidx.resample import resample

    path = Path(job["path"])
    t0 = time.perf_counter()
    surfels, v, f = _load_model(path, job["variant"])
    d2 = sb.d2_histogram(v, f)
    rec = {"path": job["path"], "variant": job["variant"], "n_surfels": len(surfels),
           "error": None, "cached": False}
    grid = None
    try:
        m = parameterize(surfels, method=job["method"], stress=False)
        level = choose_level(len(surfels), sparse_sampling=m.sparse_sampling)
        grid = resample(surfels, m.points, level)
        rec.update(level=level, area_distortion=float(m.area_distortion), folded=int(m.folded),
                   map_seconds=float(m.seconds))
    except surfidx.SurfidxError as exc:
        rec["error"] = f"{type(exc).__name__}: {exc}"
    except Exception as exc:  # a library bug: recorded as a failure, named as such
        rec["error"] = f"unexpected {type(exc).__name__} (library bug): {exc}"
    rec["seconds"] = time.perf_counter() - t0
    if cache_file is not None:
        Path(cache_file).parent.mkdir(parents=True, exist_ok=True)
        tmp = Path(str(cache_file) + f".{os.getpid()}.tmp.npz")
        arrays = {"meta": np.array(json.dumps(rec)), "d2": d2}
        if grid is not None:
            arrays["grid"] = grid
        np.savez(tmp, **arrays)
        os.replace(tmp, cache_file)
    rec["d2"], rec["grid"] = d2, grid
    return rec


def read_table(path: Path) -> list[dict]:
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


def describe(rec, lmax):
    from surfidx.descriptors import describe_grid

    if rec["grid"] is None:
        return None
    return describe_grid(rec["grid"], rec["level"], lmax=lmax).vectors


def distance_matrix(descs, **kw) -> np.ndarray:
    """(n, n) descriptor_distance between every pair; inf where a descriptor is missing."""
    from surfidx.descriptors import descriptor_distance

    n = len(descs)
    d = np.full((n, n), np.inf)
    for i in range(n):
        if descs[i] is None:
            continue
        d[i, i] = 0.0
        for j in range(i + 1, n):
            if descs[j] is not None:
                d[i, j] = d[j, i] = descriptor_distance(descs[i], descs[j], **kw)
    return d


def fmt_row(cells, widths):
    return " | ".join(str(c).ljust(w) for c, w in zip(cells, widths))


def print_table(header, rows):
    widths = [max(len(str(r[i])) for r in [header] + rows) for i in range(len(header))]
    print(fmt_row(header, widths))
    print(fmt_row(["-" * w for w in widths], widths))
    for r in rows:
        print(fmt_row(r, widths))


def run_jobs(jobs, workers):
    results = [None] * len(jobs)
    todo = []
    for i, job in enumerate(jobs):
        if job["cache_file"] is not None and Path(job["cache_file"]).exists():
            results[i] = compute(job)
        else:
            todo.append(i)
    if todo:
        print(f"computing {len(todo)} of {len(jobs)} models ({workers} workers)...",
              file=sys.stderr, flush=True)
    t0 = time.perf_counter()
    if workers > 1 and len(todo) > 1:
        import multiprocessing as mp

        with ProcessPoolExecutor(workers, mp_context=mp.get_context("spawn")) as ex:
            futs = {ex.submit(compute, jobs[i]): i for i in todo}
            for k, fut in enumerate(as_completed(futs), 1):
                results[futs[fut]] = fut.result()
                r = results[futs[fut]]
                print(f"  [{k}/{len(todo)}] {Path(r['path']).name}"
                      f"{' copy' if r['variant'] else ''} {r['seconds']:.1f}s "
                      f"{'FAILED' if r['error'] else ''} ({time.perf_counter() - t0:.0f}s)",
                      file=sys.stderr, flush=True)
    else:
        for k, i in enumerate(todo, 1):
            results[i] = compute(jobs[i])
            print(f"  [{k}/{len(todo)}] {Path(jobs[i]['path']).name}", file=sys.stderr,
                  flush=True)
    return results


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=DATA)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--cache", type=Path, default=CACHE)
    ap.add_argument("--no-cache", action="store_true", help="recompute and do not store")
    ap.add_argument("--method", default="tutte", help="spherical map method")
    ap.add_argument("--lmax", type=int, default=None, help="descriptor lmax (default: library's)")
    ap.add_argument("--invariance", default="19",
                    help="models for the invariance test: a count (first genus-0 model of each "
                         "class, then the next ones), 'all' (genus-0) or 0")
    ap.add_argument("--seed", type=int, default=1, help="seed of the invariance copies")
    ap.add_argument("--confusion", action="store_true", help="print per-class figures")
    ap.add_argument("--json", type=Path, default=None, help="write the figures to this file")
    ap.add_argument("--limit", type=int, default=None, help="first N models only (smoke test)")
    args = ap.parse_args(argv)
    warnings.simplefilter("ignore")

    from surfidx.descriptors import DEFAULT_LMAX

    lmax = DEFAULT_LMAX if args.lmax is None else args.lmax
    labels = read_table(args.data / "labels.csv")[:args.limit]
    meta = {r["path"]: r for r in read_table(args.data / "meta.csv")}
    paths = [r["path"] for r in labels]
    classes = np.array([r["class"] for r in labels])
    genus = np.array([int(meta[p]["genus"]) if p in meta and meta[p]["genus"] != "" else -1
                      for p in paths])
    g0 = genus == 0

    # invariance subset: first genus-0 model of each class, then the next ones
    order = []
    for rank in range(len(paths)):
        for c in dict.fromkeys(classes):
            idx = [i for i in np.flatnonzero((classes == c) & g0)]
            if rank < len(idx):
                order.append(idx[rank])
    n_inv = len(order) if args.invariance == "all" else int(args.invariance)
    inv_models = [int(i) for i in order[:n_inv]]

    version = code_version(args.method)
    cache_dir = None if args.no_cache else args.cache / version
    jobs = []
    for p in paths:
        h = file_hash(args.data / p)
        jobs.append({"path": str(args.data / p), "variant": None, "method": args.method,
                     "cache_file": None if cache_dir is None else str(cache_dir / f"{h}.npz")})
    for i in inv_models:
        variant = {"seed": int(args.seed * 1000 + i), "fraction": SPLIT_FRACTION}
        h = file_hash(args.data / paths[i])
        jobs.append({"path": str(args.data / paths[i]), "variant": variant,
                     "method": args.method,
                     "cache_file": None if cache_dir is None else
                     str(cache_dir / f"{h}-copy{variant['seed']}.npz")})
    t0 = time.perf_counter()
    recs = run_jobs(jobs, args.workers)
    t_compute = time.perf_counter() - t0
    base, copies = recs[:len(paths)], recs[len(paths):]

    t0 = time.perf_counter()
    descs = [describe(r, lmax) for r in base]
    t_describe = time.perf_counter() - t0
    failed = [i for i, d in enumerate(descs) if d is None]
    ours = distance_matrix(descs)
    d2 = sb.l1_distances(np.stack([r["d2"] for r in base]))

    # ----------------------------------------------------------------- retrieval table
    stats = {}
    rows = []
    for subset, mask in (("all", np.ones(len(paths), bool)), ("genus-0", g0)):
        idx = np.flatnonzero(mask)
        for name, dist in (("surfidx", ours), ("D2", d2)):
            s = sb.psb_statistics(dist[np.ix_(idx, idx)], classes[idx])
            stats[(name, subset)] = s
            ok = "" if name != "surfidx" or subset != "genus-0" else (
                "yes" if s["nn"] >= TARGET["nn"] and s["map"] >= TARGET["map"] else "no")
            rows.append([name, subset, s["n"], f"{s['nn']:.3f}", f"{s['ft']:.3f}",
                         f"{s['st']:.3f}", f"{s['dcg']:.3f}", f"{s['map']:.3f}", ok])
    mapped = np.array([d is not None for d in descs])
    idx = np.flatnonzero(mapped)
    s = sb.psb_statistics(ours[np.ix_(idx, idx)], classes[idx])
    stats[("surfidx", "mapped")] = s
    rows.append(["surfidx", "mapped only", s["n"], f"{s['nn']:.3f}", f"{s['ft']:.3f}",
                 f"{s['st']:.3f}", f"{s['dcg']:.3f}", f"{s['map']:.3f}", ""])
    for name, ref in REFERENCE.items():
        rows.append([name, "genus-0", "", f"{ref['nn']:.2f}", "", "", "", f"{ref['map']:.2f}", ""])
    print(f"\nRetrieval, leave-one-out ({len(paths)} models, {len(set(classes))} classes, "
          f"{int(g0.sum())} genus-0; lmax {lmax}; map '{args.method}'; "
          f"target genus-0 NN >= {TARGET['nn']}, mAP >= {TARGET['map']})\n")
    print_table(["descriptor", "models", "queries", "NN", "FT", "ST", "DCG", "mAP", "target met"],
                rows)

    if args.confusion:
        print("\nPer class (genus-0 database): queries, NN and mAP, surfidx vs D2; "
              "surfidx nearest-neighbour classes of the misses\n")
        idx = np.flatnonzero(g0)
        so, sd = stats[("surfidx", "genus-0")], stats[("D2", "genus-0")]
        crow = []
        for c in dict.fromkeys(classes):
            qs = [k for k, q in enumerate(so["queries"]) if classes[idx][q] == c]
            if not qs:
                continue
            sub = ours[np.ix_(idx, idx)]
            misses = []
            for k in qs:
                q = so["queries"][k]
                row = sub[q].copy()
                row[q] = np.inf
                nn = classes[idx][int(np.argmin(row))]
                if nn != c:
                    misses.append(nn)
            crow.append([c, len(qs), f"{so['per_query']['nn'][qs].mean():.2f}",
                         f"{so['per_query']['map'][qs].mean():.2f}",
                         f"{sd['per_query']['nn'][qs].mean():.2f}",
                         f"{sd['per_query']['map'][qs].mean():.2f}", ",".join(misses)])
        print_table(["class", "q", "NN", "mAP", "D2 NN", "D2 mAP", "surfidx NN misses"], crow)

    # ----------------------------------------------------------------- invariance
    inv_rows, ratios = [], []
    fin = np.isfinite(ours) & ~np.eye(len(paths), dtype=bool)
    med = float(np.median(ours[fin])) if fin.any() else float("nan")
    med_d2 = float(np.median(d2[~np.eye(len(paths), dtype=bool)]))
    if copies:
        from surfidx.descriptors import descriptor_distance

        for i, rec in zip(inv_models, copies):
            if descs[i] is None or rec["grid"] is None:
                inv_rows.append([Path(paths[i]).stem, classes[i], "-", "-", "failed", "", "", ""])
                continue
            dc = describe(rec, lmax)
            r = descriptor_distance(descs[i], dc) / med
            rd2 = float(np.abs(base[i]["d2"] - rec["d2"]).sum()) / med_d2
            ratios.append(r)
            inv_rows.append([Path(paths[i]).stem, classes[i],
                             f"{base[i]['n_surfels']}→{rec['n_surfels']}",
                             f"{base[i]['level']}→{rec['level']}", f"{100 * r:.2f}",
                             "yes" if r < 0.05 else "NO", f"{100 * rd2:.2f}",
                             f"{base[i]['area_distortion']:.2f}/{rec['area_distortion']:.2f}"])
        print(f"\nInvariance: distance(model, rotated+scaled+translated+resampled copy) / "
              f"median distance between different models (surfidx median {med:.4g}); "
              f"target < 5%\n")
        print_table(["model", "class", "surfels", "level", "ratio %", "< 5%", "D2 ratio %",
                     "area dist. model/copy"], inv_rows)
        if ratios:
            a = np.asarray(ratios)
            print(f"\nratio %: median {100 * np.median(a):.2f}, max {100 * a.max():.2f}, "
                  f"{int(np.sum(a < 0.05))}/{len(a)} below 5%")

    # ----------------------------------------------------------------- failures
    print(f"\nFailures ({len(failed)} of {len(paths)} models; genus from meta.csv):")
    for i in failed:
        print(f"  {paths[i]} ({classes[i]}, genus {genus[i]}): {base[i]['error']}")
    t_map = sum(r.get("seconds", 0.0) for r in recs)
    print(f"\nTime: map+resample {t_compute:.0f} s wall ({t_map:.0f} s CPU-sum incl. cached "
          f"records' original times), describe {t_describe:.1f} s; cache "
          f"{'off' if cache_dir is None else cache_dir}")

    if args.json is not None:
        out = {"lmax": lmax, "method": args.method, "code_version": version,
               "retrieval": {f"{k[0]}/{k[1]}": {m: v[m] for m in ("nn", "ft", "st", "dcg", "map",
                                                                    "n")}
                             for k, v in stats.items()},
               "invariance": {"median_distance": med,
                              "ratios": {Path(paths[i]).stem: r for i, r in
                                         zip([i for i, c in zip(inv_models, copies)
                                              if descs[i] is not None and c["grid"] is not None],
                                             ratios)}},
               "failures": {paths[i]: base[i]["error"] for i in failed}}
        args.json.write_text(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
