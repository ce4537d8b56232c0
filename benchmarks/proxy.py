"""Proxy meshes of the closed models in ../shared/data/models with their faces dropped.

Prints, per model: surfels, proxy vertices, closed, genus (the automatic grid ladder asks for
genus 0; '-' and the error when no grid gave it), distance surfels -> proxy relative to the
bounding-box diagonal (max, mean) and seconds. Run: python benchmarks/proxy.py [NAME ...]
"""

from __future__ import annotations

import sys
import time
import warnings
from pathlib import Path

from surfidx.numerics import use_portable_profile  # noqa: E402

use_portable_profile()   # before numpy loads: the bytes the surfidx command makes
import numpy as np

import surfidx
from surfidx import SurfelSet, TriangleMesh
from surfidx.errors import SurfidxError
from surfidx.sphere.proxy import closest_points, proxy_mesh

MODELS = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "models"
NAMES = ["armadillo.obj", "bunny_hr.obj", "cow.obj", "falconstatue.obj", "homer.obj",
         "horse.ply", "igea.ply", "koala.obj", "nefertiti.obj", "rocker-arm.obj", "scorpion.obj",
         "spot/spot_triangulated.obj", "ycb_banana/textured_simple_reoriented.obj",
         "ycb_scissors/textured_simple_reoriented.obj"]


def main(names):
    warnings.simplefilter("ignore")
    print(f"{'model':44s} {'surfels':>8s} {'src g':>5s} {'proxy V':>8s} {'closed':>6s} "
          f"{'genus':>5s} {'max d':>7s} {'mean d':>8s} {'s':>6s}")
    for name in names:
        mesh = surfidx.read_mesh(MODELS / name)
        src = mesh.topology()
        s = surfidx.read_surfels(MODELS / name)
        s = SurfelSet(s.positions, s.normals, s.radii)  # faces dropped
        diag = float(np.linalg.norm(np.ptp(s.positions, axis=0)))
        t = time.perf_counter()
        try:
            v, f = proxy_mesh(s)
        except SurfidxError as exc:
            print(f"{name:44s} {len(s):8d} {str(src.genus):>5s} {'-':>8s} {'-':>6s} "
                  f"{getattr(exc, 'genus', '-')!s:>5s} {time.perf_counter() - t:6.1f}s  {exc}")
            continue
        sec = time.perf_counter() - t
        topo = TriangleMesh(v, f).topology()
        _, _, d = closest_points(s.positions, v, f)
        print(f"{name:44s} {len(s):8d} {str(src.genus):>5s} {len(v):8d} {str(topo.closed):>6s} "
              f"{str(topo.genus):>5s} {d.max() / diag:7.4f} {d.mean() / diag:8.5f} {sec:6.1f}",
              flush=True)


if __name__ == "__main__":
    main(sys.argv[1:] or NAMES)
