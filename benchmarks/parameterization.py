"""Spherical parameterization benchmark: folds, stress, area distortion, grid PSNR, holes, time.

For every closed genus-0 model and each method (default ``tutte`` and the original ``mds``):
fold fraction of the spherical Delaunay triangulation, normalised landmark stress, area
distortion (RMS of log area ratio), infinite-rate PSNR D1/D2 of the uncompressed grid
reconstruction at the default level (:func:`surfidx.icosphere.choose_level`) against the input,
coverage holes (share of input surfels with no reconstructed surfel within twice the mean
spacing) and time. Prints a table; the last column says whether the issue's targets (folds
≤ 0.01 %, holes ≤ 0.5 %, PSNR_D2 ≥ 70 dB) are met.

Run: ``python benchmarks/parameterization.py [--models a.obj,b.ply] [--methods tutte,mds]``
"""

from __future__ import annotations

import argparse
import sys
import time
import warnings
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

import surfidx
from surfidx.icosphere import choose_level
from surfidx.metrics import evaluate
from surfidx.parameterize import parameterize
from surfidx.resample import grid_to_surfels, resample

MODELS = ["igea.ply", "bunny_hr.obj", "horse.ply", "armadillo.obj", "nefertiti.obj", "koala.obj",
          "scorpion.obj", "falconstatue.obj", "homer.obj", "spot/spot_triangulated.obj",
          "ycb_banana/textured_simple_reoriented.obj"]
DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "models"


def holes(reference, test) -> float:
    """Share of reference surfels with no test surfel within twice the mean spacing."""
    spacing = cKDTree(reference.positions).query(reference.positions, k=2)[0][:, 1].mean()
    d, _ = cKDTree(test.positions).query(reference.positions)
    return float(np.mean(d > 2 * spacing))


def run(name: str, method: str) -> dict:
    s = surfidx.read_surfels(DATA / name)
    m = parameterize(s, method=method)
    level = choose_level(len(s))
    t = time.perf_counter()
    vals = resample(s, m.points, level)
    g = grid_to_surfels(vals)
    t_res = time.perf_counter() - t
    ev = evaluate(s, g)
    return {"model": name.split("/")[0], "method": method,
            "n": len(s), "fold%": 100 * m.fold_fraction, "folds": m.folded,
            "stress": m.landmark_stress, "area_dist": m.area_distortion, "level": level,
            "psnr_d1": ev["psnr_d1"], "psnr_d2": ev["psnr_d2"], "holes%": 100 * holes(s, g),
            "t_map": m.seconds, "t_resample": t_res,
            "targets": "met" if (m.fold_fraction <= 1e-4 and holes(s, g) <= 0.005
                                 and ev["psnr_d2"] >= 70) else "missed"}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--models", default=",".join(MODELS))
    ap.add_argument("--methods", default="tutte,mds")
    args = ap.parse_args(argv)
    warnings.simplefilter("ignore")
    cols = ["model", "method", "n", "folds", "fold%", "stress", "area_dist", "level", "psnr_d1",
            "psnr_d2", "holes%", "t_map", "t_resample", "targets"]
    print(" | ".join(cols))
    print(" | ".join("---" for _ in cols))
    for name in args.models.split(","):
        for method in args.methods.split(","):
            try:
                r = run(name, method)
            except surfidx.SurfidxError as exc:
                print(f"{name} | {method} | error: {exc}")
                continue
            print(" | ".join(f"{r[c]:.4g}" if isinstance(r[c], float) else str(r[c])
                             for c in cols), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
