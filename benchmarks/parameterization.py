"""Spherical parameterization benchmark: folds, stress, area distortion, grid PSNR, holes, time.

For every closed genus-0 model and each method (default ``tutte`` and the original ``mds``):
folded triangles of the spherical Delaunay triangulation and of the input mesh (faces turned
clockwise on the sphere; 0 for an embedding), normalised landmark stress, area
distortion (RMS of log area ratio), infinite-rate PSNR D1/D2 of the uncompressed grid
reconstruction at the default level (:func:`surfidx.geometry.icosphere.choose_level`) against the input,
coverage holes (share of input surfels with no reconstructed surfel within twice the mean
spacing) and time. Prints a table; the last column says whether the targets (no input
triangle turned over, holes ≤ 0.5 %, PSNR_D2 ≥ 70 dB) are met.

``--collection`` instead maps every genus-0 model of ``../shared/data/retrieval`` (models the
project was not tuned on, listed in its ``meta.csv``) and prints one summary row per method: how
many models meet each target, how many turn an input triangle over, mean and median figures;
``--points`` drops the faces first, so every model is mapped as a point cloud (through a proxy
mesh), and ``--rows OUT.csv`` writes each model's figures.

Run: ``python benchmarks/parameterization.py [--models a.obj,b.ply] [--methods tutte,mds]``
or ``python benchmarks/parameterization.py --collection [--workers 2] [--points] [--rows F]``
"""

from __future__ import annotations

import argparse
import csv
import sys
import time
import warnings
from pathlib import Path

from surfidx.numerics import use_portable_profile  # noqa: E402

use_portable_profile()   # before numpy loads: the bytes the surfidx command makes
import numpy as np
from scipy.spatial import cKDTree

import surfidx
from surfidx.geometry.icosphere import choose_level
from surfidx.geometry.metrics import evaluate
from surfidx.sphere import count_folds, parameterize
from surfidx.codec.resample import grid_to_surfels, resample

from _markdown import Report, add_markdown_option

MODELS = ["igea.ply", "bunny_hr.obj", "horse.ply", "armadillo.obj", "nefertiti.obj", "koala.obj",
          "scorpion.obj", "falconstatue.obj", "homer.obj", "spot/spot_triangulated.obj",
          "ycb_banana/textured_simple_reoriented.obj"]
DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "models"
COLLECTION = DATA.parent / "retrieval"


def holes(reference, test) -> float:
    """Share of reference surfels with no test surfel within twice the mean spacing."""
    spacing = cKDTree(reference.positions).query(reference.positions, k=2)[0][:, 1].mean()
    d, _ = cKDTree(test.positions).query(reference.positions)
    return float(np.mean(d > 2 * spacing))


def run(name: str, method: str, *, root: Path = DATA, points: bool = False) -> dict:
    s = surfidx.read_surfels(root / name)
    if points:      # the same surfels as a point cloud: mapped through a proxy mesh
        s = surfidx.SurfelSet(s.positions, s.normals, s.radii, colors=s.colors)
    m = parameterize(s, method=method)
    inverted = 0
    if s.faces is not None and len(s.faces):
        from surfidx.geometry.unitsphere import orientation
        f = s.faces[(s.faces[:, 0] != s.faces[:, 1]) & (s.faces[:, 1] != s.faces[:, 2])
                    & (s.faces[:, 0] != s.faces[:, 2])]
        k = int(np.count_nonzero(orientation(m.points, f) <= 0))
        inverted = min(k, len(f) - k)          # a global mirror is not a fold
    delaunay = count_folds(s, m.points)[0]
    level = choose_level(len(s), sparse_sampling=m.sparse_sampling)
    t = time.perf_counter()
    vals = resample(s, m.points, level)
    g = grid_to_surfels(vals)
    t_res = time.perf_counter() - t
    ev = evaluate(s, g)
    gaps = holes(s, g)
    return {"model": name.split("/")[0], "method": method,
            "n": len(s), "fold%": 100 * delaunay / max(2 * len(s) - 4, 1), "folds": delaunay,
            "inverted": inverted,
            "stress": m.landmark_stress, "area_dist": m.area_distortion,
            "sparse": m.sparse_sampling, "level": level,
            "psnr_d1": ev["psnr_d1"], "psnr_d2": ev["psnr_d2"], "holes%": 100 * gaps,
            "t_map": m.seconds, "t_resample": t_res,
            "targets": "met" if (inverted == 0 and gaps <= 0.005
                                 and ev["psnr_d2"] >= 70) else "missed"}


def _collection_job(job):
    warnings.simplefilter("ignore")
    name, method, points = job
    try:
        return {**run(name, method, root=COLLECTION, points=points), "model": name}
    except surfidx.SurfidxError as exc:
        return {"model": name, "method": method, "error": str(exc)}


def collection(methods, workers: int, report, *, rows_csv=None, points: bool = False) -> None:
    """One summary row per method over the genus-0 models of the retrieval collection; with
    ``rows_csv``, every model's figures are written there too."""
    from concurrent.futures import ProcessPoolExecutor

    with open(COLLECTION / "meta.csv", newline="") as fh:
        names = [r["path"] for r in csv.DictReader(fh) if int(r["genus"]) == 0]
    cols = ["method", "models", "errors", "fold-free", "folds<=0.01%", "folds<=0.1%", "folds>1%",
            "holes<=0.5%", "psnr_d2>=70", "all targets", "inverting", "median fold%",
            "mean fold%", "mean holes%", "median psnr_d2", "map s (sum)"]
    report.markdown(" | ".join(cols))
    report.markdown(" | ".join("---" for _ in cols))
    all_rows = []
    for method in methods:
        with ProcessPoolExecutor(max(workers, 1)) as ex:
            rows = list(ex.map(_collection_job, [(n, method, points) for n in names]))
        all_rows += rows
        ok = [r for r in rows if "error" not in r]
        fr = np.array([r["fold%"] for r in ok])
        ho = np.array([r["holes%"] for r in ok])
        d2 = np.array([r["psnr_d2"] for r in ok])
        vals = [method, len(rows), len(rows) - len(ok), int((fr == 0).sum()),
                int((fr <= 0.01).sum()), int((fr <= 0.1).sum()), int((fr > 1).sum()),
                int((ho <= 0.5).sum()), int((d2 >= 70).sum()),
                sum(r["targets"] == "met" for r in ok), sum(r["inverted"] > 0 for r in ok),
                f"{np.median(fr):.4f}", f"{fr.mean():.3f}", f"{ho.mean():.2f}",
                f"{np.median(d2):.1f}", f"{sum(r['t_map'] for r in ok):.0f}"]
        report.markdown(" | ".join(str(v) for v in vals), flush=True)
    if rows_csv is not None:
        keys = list(dict.fromkeys(k for r in all_rows for k in r))
        with open(rows_csv, "w", newline="") as fh:
            writer = csv.DictWriter(fh, fieldnames=keys)
            writer.writeheader()
            writer.writerows(all_rows)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--models", default=",".join(MODELS))
    ap.add_argument("--methods", default="tutte,mds")
    ap.add_argument("--collection", action="store_true",
                    help="summarise the genus-0 models of ../shared/data/retrieval instead")
    ap.add_argument("--workers", type=int, default=1, help="processes for --collection")
    ap.add_argument("--rows", metavar="OUT.csv", help="--collection: every model's figures")
    ap.add_argument("--points", action="store_true",
                    help="--collection: drop the faces, map every model as a point cloud")
    add_markdown_option(ap, "parameterization")
    args = ap.parse_args(argv)
    warnings.simplefilter("ignore")
    if args.markdown is not None and args.collection and args.markdown.name == "parameterization.md":
        args.markdown = args.markdown.with_name("parameterization_collection.md")
    report = Report(args.markdown.stem if args.markdown else "parameterization",
                    "Spherical parameterization" + (" over the retrieval collection"
                                                    if args.collection else ""),
                    args.markdown,
                    note="Folded triangles of the spherical Delaunay triangulation and input "
                         "triangles turned clockwise on the sphere, normalised "
                         "landmark stress, area distortion (RMS of log area ratio), infinite-rate "
                         "PSNR D1/D2 of the uncompressed grid reconstruction against the input, "
                         "coverage holes and time; the targets: no input triangle turned over, "
                         "holes <= 0.5 %, PSNR_D2 >= 70 dB.")
    if args.collection:
        collection(args.methods.split(","), args.workers, report, rows_csv=args.rows,
                   points=args.points)
        report.finish()
        return 0
    cols = ["model", "method", "n", "inverted", "folds", "fold%", "stress", "area_dist", "sparse", "level",
            "psnr_d1", "psnr_d2", "holes%", "t_map", "t_resample", "targets"]
    report.markdown(" | ".join(cols))
    report.markdown(" | ".join("---" for _ in cols))
    for name in args.models.split(","):
        for method in args.methods.split(","):
            try:
                r = run(name, method)
            except surfidx.SurfidxError as exc:
                report.markdown(f"{name} | {method} | error: {exc}")
                continue
            report.markdown(" | ".join(f"{r[c]:.4g}" if isinstance(r[c], float) else str(r[c])
                             for c in cols), flush=True)
    report.finish()
    return 0


if __name__ == "__main__":
    sys.exit(main())
