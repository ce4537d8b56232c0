"""Per-stage CPU time of ingesting a model, on the example, shared and retrieval models.

Every model goes through :func:`surfidx.pipeline.process_model` (what ``surfidx ingest`` runs
per file: read, map, resample, transform, code, decode for the quality figures, describe,
thumbnail; only the database write is left out) in a worker process. The stage functions are
wrapped, in the worker only, by a timer that charges each call's CPU time
(``time.process_time``: this process, not the machine's load) to its stage, less the time of
the listed stages nested in it (self time: the balancing of a level prolonged round by round is charged to
``map.balance``, not to ``map.prolong``). What no stage claims is ``other``.

Stages (module attribute -> stage name) are listed in :data:`STAGES`; ``map.*`` stages are the
spherical map's steps (coarse-to-fine levels, decimation, prolongation, Tutte maps,
balancing, point-cloud proxy, quality figures), ``describe.*`` the descriptors' costly parts
(Laplace–Beltrami spectrum, shells' harmonics, Driscoll–Healy expansions, views), ``describe``
the rest of them.

The table gives, per stage, the median, 90th percentile and maximum CPU seconds over the
models, the same per 10k surfels, and the exponent ``b`` of a least-squares fit
``seconds ~ a * n ** b`` over the models' surfel counts ``n`` (a stage that costs n log n
fits about 1.1 over this range). Models that fail (the awkward topologies, until they are
repaired) are listed apart.

Run::

    python benchmarks/profile.py [--set examples shared retrieval] [--workers 1] [--limit N]
        [--per-model] [--json out.json]

Workers are warmed up first (imports, numba caches) on the smallest example model. One worker
(the default) measures each model on an otherwise idle machine, as the per-model targets are
stated. Workers on all cores share the caches and the memory bandwidth: each model then costs
more CPU time, the largest maps most (the README gives both figures).

``--mode query`` times :func:`surfidx.pipeline.describe_model` instead: what ``surfidx query
FILE`` computes for its example (read, map, resample, describe; nothing coded or decoded).
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import os
import statistics
import sys
import time
import warnings
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("MKL_NUM_THREADS", "1")

from surfidx.numerics import use_portable_profile  # noqa: E402

use_portable_profile()   # before numpy loads: the bytes the surfidx command makes
import numpy as np  # noqa: E402

from _markdown import Report, add_markdown_option

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared" / "data"

#: (module, attribute, stage): the functions whose self CPU time is charged to a stage. An
#: attribute ``Class.method`` is patched on the class; a function is patched in every loaded
#: ``surfidx`` module that holds it (``from .x import f`` binds the name there).
STAGES = (
    ("surfidx.io.reading", "read_surfels", "read"),
    ("surfidx.io.reading", "read_geometry", "read"),
    ("surfidx.topology.model", "read_model", "read"),
    ("surfidx.topology.model", "repair_model", "read"),
    ("surfidx.geometry.graph", "sphere_of_influence_graph", "graph"),
    ("surfidx.geometry.geodesics", "GeodesicSolver.__init__", "geodesics"),
    ("surfidx.sphere.multilevel", "mesh_map", "map.multilevel"),
    ("surfidx.sphere.decimate", "decimate", "map.decimate"),
    ("surfidx.sphere.decimate", "Hierarchy.undo", "map.prolong"),
    ("surfidx.sphere.tutte", "tutte_map", "map.tutte"),
    ("surfidx.sphere.balance", "balance", "map.balance"),
    ("surfidx.sphere.cloud", "cloud_map", "map.proxy"),
    ("surfidx.sphere.proxy", "proxy_mesh", "map.proxy"),
    ("surfidx.sphere.quality", "_count_folds", "map.quality"),
    ("surfidx.sphere.quality", "_area_distortion", "map.quality"),
    ("surfidx.sphere.quality", "_sparse_sampling", "map.quality"),
    ("surfidx.codec.resample", "resample", "resample"),
    ("surfidx.codec.resample", "locate_surfels", "resample"),
    ("surfidx.codec.klt", "KLT.fit", "klt"),
    ("surfidx.codec.wavelets", "forward", "wavelets"),
    ("surfidx.codec.wavelets", "forward_anchored", "wavelets"),
    ("surfidx.codec.wavelets", "choose_anchors", "wavelets"),
    ("surfidx.codec.density", "weight_field", "density"),
    ("surfidx.codec", "Encoder.encode", "coding"),
    ("surfidx.codec", "decode", "decode"),
    ("surfidx.geometry.metrics", "evaluate", "evaluate"),
    ("surfidx.geometry.metrics", "Reference.psnr_d2", "evaluate"),
    ("surfidx.geometry.metrics", "Reference.psnr_d2_at_least", "evaluate"),
    ("surfidx.describe.descriptors", "describe_grid", "describe"),
    ("surfidx.describe.descriptors", "log_spectrum", "describe.spectrum"),
    ("surfidx.describe.descriptors", "_shell_energies", "describe.shells"),
    ("surfidx.describe.descriptors", "degree_energies", "describe.harmonics"),
    ("surfidx.describe.views", "model_views", "describe.views"),
    ("surfidx.render", "render", "thumbnail"),
)

_self: dict = {}
_stack: list = []
_maps: list = []     # (surfels, SphericalMap) of each part mapped in the current model


def _wrap(fn, stage):
    def timed(*args, **kwargs):
        t0 = time.process_time()
        _stack.append(0.0)
        try:
            return fn(*args, **kwargs)
        finally:
            spent = time.process_time() - t0
            nested = _stack.pop()
            _self[stage] = _self.get(stage, 0.0) + spent - nested
            if _stack:
                _stack[-1] += spent
    timed.__wrapped__ = fn
    timed.__name__ = getattr(fn, "__name__", "timed")
    return timed


def _instrument():
    """Wrap every function of :data:`STAGES` (in this process only)."""
    import importlib

    import surfidx
    import surfidx.pipeline  # noqa: F401  (everything the ingest path imports)
    for modname, _, _ in STAGES:           # the modules the stages live in, loaded first
        importlib.import_module(modname)
    modules = [m for n, m in list(sys.modules.items())
               if m is not None and (n == "surfidx" or n.startswith("surfidx."))]
    for modname, attr, stage in STAGES:
        mod = importlib.import_module(modname)
        if "." in attr:
            cls_name, meth = attr.split(".")
            cls = getattr(mod, cls_name)
            raw = cls.__dict__[meth]
            if isinstance(raw, classmethod):
                setattr(cls, meth, classmethod(_wrap(raw.__func__, stage)))
            else:
                setattr(cls, meth, _wrap(raw, stage))
            continue
        orig = getattr(mod, attr)
        timed = _wrap(orig, stage)
        for m in modules:
            for key, val in list(vars(m).items()):
                if val is orig:
                    setattr(m, key, timed)
    import surfidx.sphere
    import surfidx.sphere.mapping as mapping
    orig = mapping.parameterize

    def recorded(surfels, **kwargs):
        m = orig(surfels, **kwargs)
        _maps.append((surfels, m))
        return m
    for m in modules + [surfidx.sphere]:
        for key, val in list(vars(m).items()):
            if val is orig:
                setattr(m, key, recorded)
    surfidx.sphere.parameterize = recorded
    _ = surfidx


def fold_counts(maps) -> dict:
    """Folds counted independently of the map's bookkeeping, summed over the parts: input
    triangles turned clockwise on the sphere (``mesh_inverted``; a point cloud's surfels have
    none), folded triangles of the spherical Delaunay triangulation (``delaunay_folds``), and
    the area-weighted area distortion over the parts."""
    from surfidx.geometry.unitsphere import hull_triangles, orientation
    from surfidx.sphere import count_folds

    inv = dfold = 0
    ad = wsum = 0.0
    for s, m in maps:
        f = s.faces
        if f is not None and len(f):
            f = f[(f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 0] != f[:, 2])]
            k = int(np.count_nonzero(orientation(m.points, f) <= 0))
            inv += min(k, len(f) - k)       # a global mirror is not a fold
        dfold += count_folds(s, m.points, triangles=hull_triangles(m.points))[0]
        ad += len(s) * m.area_distortion
        wsum += len(s)
    return {"mesh_inverted": inv, "delaunay_folds": dfold,
            "area_distortion": ad / max(wsum, 1)}


def _warm(path: str, mode: str):
    _instrument()
    _run(path, mode)


def _run(path: str, mode: str = "ingest") -> dict:
    from surfidx.pipeline import describe_model, process_model

    _self.clear()
    _maps.clear()
    t0 = time.process_time()
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            rec = (process_model if mode == "ingest" else describe_model)(path)
    except Exception as exc:  # noqa: BLE001 - a benchmark lists what fails
        return {"path": path, "error": f"{type(exc).__name__}: {str(exc)[:120]}",
                "total": time.process_time() - t0}
    total = time.process_time() - t0
    stages = dict(_self)
    stages["other"] = max(0.0, total - sum(stages.values()))
    folds = fold_counts(_maps)
    _maps.clear()
    map_cpu = sum(v for k, v in stages.items() if k.startswith("map."))
    if mode != "ingest":
        return {"path": path, "n": rec.n_surfels, "total": total, "stages": stages}
    return {"path": path, "n": rec.n_surfels, "total": total, "stages": stages,
            "psnr_d2": rec.quality.get("psnr_d2"), "folded": rec.params.get("folded"),
            "map_cpu": map_cpu, **folds}


_MODEL_SUFFIXES = (".obj", ".ply", ".off", ".stl", ".glb", ".gltf")


def _model_file(p: Path) -> str:
    """A model file, or the mesh file of a model folder (an OBJ beside its texture)."""
    if p.is_dir():
        inside = sorted(f for f in p.iterdir() if f.suffix.lower() in _MODEL_SUFFIXES)
        return str(inside[0])
    return str(p)


def model_set(name: str) -> list[str]:
    """The model files of a set: ``examples``, ``shared`` or ``retrieval`` (genus 0)."""
    if name in ("examples", "shared"):
        base = ROOT / "examples" / "models" if name == "examples" else SHARED / "models"
        return sorted(_model_file(p) for p in base.iterdir()
                      if p.is_dir() or p.suffix.lower() in _MODEL_SUFFIXES)
    if name in ("retrieval", "retrieval-all"):
        base = SHARED / "retrieval"
        with open(base / "meta.csv", newline="") as fh:
            rows = list(csv.DictReader(fh))
        return [str(base / r["path"]) for r in rows
                if name == "retrieval-all" or int(r["genus"]) == 0]
    raise SystemExit(f"unknown set {name!r}: examples, shared, retrieval or retrieval-all")


def _fit_exponent(n, t) -> float:
    n, t = np.asarray(n, float), np.asarray(t, float)
    ok = (n > 0) & (t > 1e-4)
    if ok.sum() < 3 or np.ptp(np.log(n[ok])) < 0.5:
        return math.nan
    return float(np.polyfit(np.log(n[ok]), np.log(t[ok]), 1)[0])


def _pct(values, q):
    return float(np.percentile(values, q)) if values else math.nan


TABLE_HEADERS = ["stage", "median s", "p90 s", "max s", "med s/10k", "p90 s/10k", "exponent"]


def table(results: list[dict]) -> list[list[str]]:
    """Rows of :data:`TABLE_HEADERS`: each stage's CPU seconds over the models, and the total."""
    ok = [r for r in results if "stages" in r]
    names = sorted({s for r in ok for s in r["stages"]},
                   key=lambda s: ([x[2] for x in STAGES] + ["other"]).index(s))
    rows = []
    for s in names + ["total"]:
        t = [r["total"] if s == "total" else r["stages"].get(s, 0.0) for r in ok]
        per = [x / (r["n"] / 1e4) for x, r in zip(t, ok)]
        rows.append([s, f"{_pct(t, 50):.3f}", f"{_pct(t, 90):.3f}", f"{max(t):.3f}",
                     f"{_pct(per, 50):.3f}", f"{_pct(per, 90):.3f}",
                     f"{_fit_exponent([r['n'] for r in ok], t):.2f}"])
    return rows


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--set", nargs="+", default=["examples", "shared", "retrieval"],
                    choices=["examples", "shared", "retrieval", "retrieval-all"])
    ap.add_argument("--workers", type=int, default=1,
                    help="worker processes (1: each model has the machine to itself)")
    ap.add_argument("--limit", type=int, default=None, help="first N models of each set")
    ap.add_argument("--per-model", action="store_true", help="print a line per model")
    ap.add_argument("--json", type=Path, default=None,
                    help="write every model's figures here (rewritten after each model)")
    ap.add_argument("--files", nargs="+", default=None,
                    help="these model files instead of --set (the set name is 'files')")
    ap.add_argument("--mode", choices=["ingest", "query"], default="ingest",
                    help="time process_model (ingest) or describe_model (query FILE)")
    add_markdown_option(ap, "profile")
    args = ap.parse_args(argv)
    if args.markdown is not None and args.mode == "query" and args.markdown.name == "profile.md":
        args.markdown = args.markdown.with_name("profile_query.md")

    import surfidx

    jobs = []
    if args.files:
        args.set = ["files"]
        jobs = [("files", f) for f in args.files]
    for s in ([] if args.files else args.set):
        files = model_set(s)[: args.limit]
        jobs += [(s, f) for f in files]
    warm = min(model_set("examples"), key=os.path.getsize)
    report = Report(args.markdown.stem if args.markdown else "profile",
                    f"Per-stage CPU time ({args.mode})", args.markdown,
                    note=f"Each model through `surfidx.pipeline."
                         f"{'process_model' if args.mode == 'ingest' else 'describe_model'}` in a "
                         f"worker process, the CPU seconds (`time.process_time` of the worker) "
                         f"charged to each stage less the stages nested in it: median, 90th "
                         f"percentile and maximum over the models, the same per 10k surfels, and "
                         f"the exponent b of a fit seconds ~ a n^b over the surfel counts n.")
    report.text(f"surfidx {surfidx.__version__}: {args.mode}, {len(jobs)} models, "
                f"{args.workers} workers; CPU seconds per model.")
    results = []
    with ProcessPoolExecutor(args.workers, initializer=_warm, initargs=(warm, args.mode)) as ex:
        futures = [(s, ex.submit(_run, f, args.mode)) for s, f in jobs]
        for i, (s, fut) in enumerate(futures, 1):
            r = fut.result()
            r["set"] = s
            results.append(r)
            if args.json:
                args.json.write_text(json.dumps(results, indent=1))
            if args.per_model:
                msg = r.get("error") or (f"n={r['n']:7d} total {r['total']:6.2f} s  " + (
                    f"folds {r['delaunay_folds']}/{r['mesh_inverted']} ad "
                    f"{r['area_distortion']:.3f} d2 {r['psnr_d2']:.1f}  "
                    if args.mode == "ingest" else "") + "  ".join(
                    f"{k} {v:.2f}" for k, v in sorted(r["stages"].items(), key=lambda kv: -kv[1])[:5]))
                print(f"  [{i}/{len(jobs)}] {s:9s} {Path(r['path']).name:22s} {msg}", flush=True)
    for s in args.set + ["all"]:
        sub = [r for r in results if s == "all" or r["set"] == s]
        ok = [r for r in sub if "stages" in r]
        if not ok:
            continue
        n = [r["n"] for r in ok]
        report.heading(f"{s}: {len(ok)} models ({min(n):,}-{max(n):,} surfels, median "
                       f"{int(statistics.median(n)):,})")
        report.table(TABLE_HEADERS, table(ok))
        t = [r["total"] for r in ok]
        line = (f"whole {args.mode} CPU s: median {_pct(t, 50):.2f}, p90 {_pct(t, 90):.2f}, "
                f"max {max(t):.2f}, mean {statistics.mean(t):.2f}")
        if args.mode == "ingest":
            line += (f"; models with Delaunay folds {sum(r['delaunay_folds'] > 0 for r in ok)}, "
                     f"with inverted input triangles {sum(r['mesh_inverted'] > 0 for r in ok)}")
        report.text(line)
    failed = [r for r in results if "error" in r]
    if failed:
        report.heading(f"failed ({len(failed)})")
        for r in failed:
            report.print(f"{Path(r['path']).name}: {r['error']}")
    report.finish()
    if args.json:
        args.json.write_text(json.dumps(results, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
