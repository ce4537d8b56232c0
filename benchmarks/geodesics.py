"""Accuracy and speed of surfidx geodesics against exact mesh geodesics.

For every closed genus-0 model of ``../shared/data/models`` (one surfel per mesh vertex) and a
finely sampled unit sphere (level-6 icosphere, 40,962 surfels; exact geodesics are arc lengths):

* exact reference: MMP exact polyhedral geodesics (``pygeodesic``, benchmark-only dependency) from
  ``--sources`` random sources. MMP on a 134k-vertex mesh takes ~100 s per source, so the
  propagation is bounded to the ``--ball`` graph-nearest vertices of each source (all vertices on
  models smaller than that); targets are drawn among the vertices inside;
* graph: Dijkstra on the spheres-of-influence graph (defaults of :class:`surfidx.GeodesicSolver`);
* refined: the same paths straightened on the surface (``refine=True``; ``--refine-targets``
  targets per source);
* heat: potpourri3d's point-cloud heat method (``PointCloudHeatSolver``) on the surfel centres;

reported as mean and 95th percentile of the absolute relative error ``|d / d_exact - 1|`` (and the
mean signed error). A second table sweeps the normal-angle threshold, the sphere-radius scale,
the surface-test limit ``max_offset`` and its length limit ``MIDPOINT_SLACK`` (graph distances
only; ``--no-sweep`` skips it); a third times graph construction and one source to all on Igea
(one core).

Run: ``python benchmarks/geodesics.py [--sources 20] [--ball 10000] [--models igea bunny_hr ...]``.
"""

from __future__ import annotations

import argparse
import sys
import time
import warnings
from pathlib import Path

from surfidx.numerics import use_portable_profile  # noqa: E402

use_portable_profile()   # before numpy loads: the bytes the surfidx command makes
import numpy as np

from surfidx import TriangleMesh, read_surfels
from surfidx.geometry.geodesics import GeodesicSolver
from surfidx.geometry.icosphere import icosphere
from surfidx.geometry import graph as sig
from surfidx.geometry.graph import DEFAULT_MAX_ANGLE, DEFAULT_MAX_OFFSET, DEFAULT_SCALE

from _markdown import Report, add_markdown_option

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "models"
MODELS = {
    "igea": "igea.ply", "bunny_hr": "bunny_hr.obj", "horse": "horse.ply",
    "armadillo": "armadillo.obj", "nefertiti": "nefertiti.obj", "koala": "koala.obj",
    "scorpion": "scorpion.obj", "falconstatue": "falconstatue.obj", "homer": "homer.obj",
    "spot": "spot/spot_triangulated.obj", "banana": "ycb_banana/textured_simple_reoriented.obj",
}
ANGLES = (30.0, 45.0, 60.0, 90.0, 120.0, 180.0)
SCALES = (1.0, 1.5, 1.75, 2.0, 2.5)
OFFSETS = (None, 0.05, 0.07, 0.15, 0.2)  # surface-test limits besides DEFAULT_MAX_OFFSET
SLACKS = (float("inf"), 1.5, 1.0)        # surface-test length limits besides MIDPOINT_SLACK


def load(name):
    if name == "sphere":
        grid = icosphere(6)
        return TriangleMesh(grid.vertices, grid.faces, name="sphere").to_surfels()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return read_surfels(DATA / MODELS[name])


def reference(s, name, solver, sources, ball, ntarget, rng):
    """Exact distances (sources x targets), with the targets per source."""
    n = len(s)
    gd = solver.distances(sources)
    targets = np.empty((len(sources), ntarget), np.int64)
    exact = np.empty((len(sources), ntarget))
    if name == "sphere":
        for a, src in enumerate(sources):
            cand = np.flatnonzero(np.arange(n) != src)
            targets[a] = rng.choice(cand, ntarget, replace=False)
            exact[a] = np.arccos(np.clip(s.positions[targets[a]] @ s.positions[src], -1, 1))
        return targets, exact
    import pygeodesic.geodesic as pg

    geo = pg.PyGeodesicAlgorithmExact(s.positions, s.faces)
    for a, src in enumerate(sources):
        order = np.argsort(gd[a])
        if ball < n:
            inside = order[1:ball]
            # MMP's values near max_distance are not final (wavefront cut): keep a wide margin
            limit = 1.5 * gd[a][order[ball]]
        else:
            inside, limit = order[1:], 1e100
        targets[a] = rng.choice(inside, ntarget, replace=False)
        d, _ = geo.geodesicDistances(np.array([src]), targets[a], max_distance=limit)
        exact[a] = d
    return targets, exact


def rel_stats(d, exact):
    ok = np.isfinite(exact) & (exact > 0) & (exact < 1e50)
    e = d[ok] / exact[ok] - 1.0
    return 100 * np.mean(np.abs(e)), 100 * np.percentile(np.abs(e), 95), 100 * np.mean(e)


REPORT = None


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--models", nargs="+", default=["sphere", *MODELS])
    ap.add_argument("--sources", type=int, default=20)
    ap.add_argument("--targets", type=int, default=200, help="targets per source (graph, heat)")
    ap.add_argument("--refine-targets", type=int, default=10)
    ap.add_argument("--ball", type=int, default=10000)
    ap.add_argument("--no-heat", action="store_true")
    ap.add_argument("--no-sweep", action="store_true")
    add_markdown_option(ap, "geodesics")
    args = ap.parse_args(argv)
    global REPORT
    REPORT = Report("geodesics", "Geodesics against exact mesh geodesics", args.markdown,
                    note="Relative error of the spheres-of-influence graph's distances (and of "
                         "the refined paths and the heat method) against exact polyhedral "
                         "geodesics (MMP, `pygeodesic`, the `bench` extra), a sweep of the "
                         "graph's parameters, and the graph's build and query times on Igea.")
    rng = np.random.default_rng(0)
    rows, sweep = [], []
    t_all = time.time()
    for name in args.models:
        t0 = time.time()
        s = load(name)
        try:
            solver = GeodesicSolver(s)
        except Exception as exc:  # report and go on with the other models
            print(f"  {name}: {type(exc).__name__}: {exc}", file=sys.stderr, flush=True)
            continue
        sources = rng.choice(len(s), args.sources, replace=False)
        targets, exact = reference(s, name, solver, sources, args.ball, args.targets, rng)
        t_exact = time.time() - t0
        full = solver.distances(sources)
        graph = np.take_along_axis(full, targets, axis=1)
        k = args.refine_targets
        t1 = time.time()
        refined = np.stack([solver.distances([src], targets=targets[a, :k], refine=True)[0]
                            for a, src in enumerate(sources)])
        t_ref = (time.time() - t1) / refined.size
        row = {"model": name, "n": len(s), "graph": rel_stats(graph, exact),
               "refined": rel_stats(refined, exact[:, :k]), "t_ref": t_ref}
        if not args.no_heat:
            import potpourri3d as pp3d

            heat = pp3d.PointCloudHeatSolver(s.positions)
            hd = np.stack([heat.compute_distance(int(src))[targets[a]]
                           for a, src in enumerate(sources)])
            row["heat"] = rel_stats(hd, exact)
        rows.append(row)
        if not args.no_sweep:
            slack0 = sig.MIDPOINT_SLACK
            combos = ([(a, DEFAULT_SCALE, DEFAULT_MAX_OFFSET, slack0) for a in ANGLES]
                      + [(DEFAULT_MAX_ANGLE, sc, DEFAULT_MAX_OFFSET, slack0) for sc in SCALES
                         if sc != DEFAULT_SCALE]
                      + [(DEFAULT_MAX_ANGLE, DEFAULT_SCALE, off, slack0) for off in OFFSETS]
                      + [(DEFAULT_MAX_ANGLE, DEFAULT_SCALE, DEFAULT_MAX_OFFSET, sl)
                         for sl in SLACKS])
            for ang, sc, off, sl in combos:
                sig.MIDPOINT_SLACK = sl     # a module constant the graph build reads each call
                try:
                    sv = GeodesicSolver(s, max_angle=ang, scale=sc, max_offset=off)
                    d = np.take_along_axis(sv.distances(sources), targets, axis=1)
                    sweep.append((name, (ang, sc, off, sl), sv.graph.degrees.mean(),
                                  rel_stats(d, exact)))
                except Exception as exc:  # a disconnected graph at a strict angle
                    sweep.append((name, (ang, sc, off, sl), float("nan"),
                                  (np.nan, np.nan, np.nan)))
                    print(f"  {name} angle {ang} scale {sc} offset {off} slack {sl}: "
                          f"{type(exc).__name__}: {exc}"[:150], file=sys.stderr)
                finally:
                    sig.MIDPOINT_SLACK = slack0
        stats = " ".join(f"{key} {row[key][0]:.2f}/{row[key][1]:.2f}%" for key in
                         ("graph", "refined", "heat") if key in row)
        print(f"  {name}: {len(s)} surfels, exact {t_exact:.1f} s, total {time.time() - t0:.1f} s;"
              f" {stats}", file=sys.stderr, flush=True)

    REPORT.print("\nRelative error vs exact geodesics, % (|mean| / p95 / signed mean); "
          f"{args.sources} sources, {args.targets} targets each ({args.refine_targets} refined)")
    head = f"{'model':13s} {'surfels':>8s} | {'graph':^20s} | {'refined':^20s} | {'heat':^20s} | ms/ref"
    REPORT.print(head)
    REPORT.print("-" * len(head))
    for r in rows:
        cells = []
        for key in ("graph", "refined", "heat"):
            v = r.get(key)
            cells.append("n/a".center(20) if v is None else f"{v[0]:5.2f} {v[1]:5.2f} {v[2]:+6.2f}  ")
        REPORT.print(f"{r['model']:13s} {r['n']:8d} | " + " | ".join(cells) + f" | {1e3 * r['t_ref']:6.1f}")
    mean = lambda key, i: np.mean([r[key][i] for r in rows if key in r])  # noqa: E731
    REPORT.print(f"{'mean':13s} {'':8s} | " + " | ".join(
        f"{mean(k, 0):5.2f} {mean(k, 1):5.2f} {mean(k, 2):+6.2f}  " if any(k in r for r in rows)
        else "n/a".center(20) for k in ("graph", "refined", "heat")))

    if sweep:
        REPORT.print("\nGraph distances: mean |relative error| % by normal-angle threshold, scale, "
              "surface-test limit and its length limit (mean degree in brackets)")
        combos = list(dict.fromkeys(c for _, c, _, _ in sweep))
        label = lambda c: (f"{c[0]:g}d x{c[1]:g} o{c[2] if c[2] is not None else '-'}"  # noqa: E731
                           f" s{c[3]:g}")
        REPORT.print(f"{'model':13s} " + " ".join(f"{label(c):>22s}" for c in combos))
        for name in dict.fromkeys(m for m, *_ in sweep):
            cells = []
            for c in combos:
                hit = [x for x in sweep if x[0] == name and x[1] == c][0]
                cells.append(f"{hit[3][0]:6.2f} [{hit[2]:4.1f}]")
            REPORT.print(f"{name:13s} " + " ".join(f"{c:>22s}" for c in cells))
        cells = [f"{np.mean([x[3][0] for x in sweep if x[1] == c]):6.2f}" for c in combos]
        REPORT.print(f"{'mean':13s} " + " ".join(f"{c:>22s}" for c in cells))

    if "igea" in args.models:
        s = load("igea")
        tb, tq = [], []
        for _ in range(3):
            t = time.process_time()
            sv = GeodesicSolver(s)
            tb.append(time.process_time() - t)
        for src in range(0, 50000, 10000):
            t = time.process_time()
            sv.distances([src])
            tq.append(time.process_time() - t)
        REPORT.print(f"\nIgea ({len(s)} surfels, {sv.graph.n_edges} edges): graph build "
              f"{np.median(tb):.2f} s, one source to all {np.median(tq):.3f} s "
              "(CPU time, median; one core)")
    REPORT.print(f"\n(benchmark wall time {time.time() - t_all:.0f} s)")
    REPORT.finish()


if __name__ == "__main__":
    main()
