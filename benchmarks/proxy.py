"""Proxy meshes of the closed models in ../shared/data/models with their faces dropped.

Prints, per model: surfels, proxy vertices, closed, genus (the automatic grid ladder asks for
genus 0; '-' and the error when no grid gave it), distance surfels -> proxy relative to the
bounding-box diagonal (max, mean) and seconds. Run: python benchmarks/proxy.py [NAME ...]
[--markdown [FILE]]
"""

from __future__ import annotations

import argparse
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

from _markdown import Report, add_markdown_option

MODELS = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "models"
NAMES = ["armadillo.obj", "bunny_hr.obj", "cow.obj", "falconstatue.obj", "homer.obj",
         "horse.ply", "igea.ply", "koala.obj", "nefertiti.obj", "rocker-arm.obj", "scorpion.obj",
         "spot/spot_triangulated.obj", "ycb_banana/textured_simple_reoriented.obj",
         "ycb_scissors/textured_simple_reoriented.obj"]


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("names", nargs="*", default=NAMES, help="models under ../shared/data/models")
    add_markdown_option(ap, "proxy")
    args = ap.parse_args(argv)
    report = Report("proxy", "Proxy meshes of point clouds", args.markdown,
                    note="The closed models of `../shared/data/models` with their faces dropped, "
                         "mapped through the proxy mesh reconstructed from the oriented surfels: "
                         "the source's genus, the proxy's vertices, closedness and genus, the "
                         "distance of the surfels to the proxy relative to the bounding-box "
                         "diagonal, and wall seconds.")
    warnings.simplefilter("ignore")
    rows = []
    for name in args.names:
        mesh = surfidx.read_mesh(MODELS / name)
        src = mesh.topology()
        s = surfidx.read_surfels(MODELS / name)
        s = SurfelSet(s.positions, s.normals, s.radii)  # faces dropped
        diag = float(np.linalg.norm(np.ptp(s.positions, axis=0)))
        t = time.perf_counter()
        try:
            v, f = proxy_mesh(s)
        except SurfidxError as exc:
            rows.append([name, len(s), src.genus, "-", "-", getattr(exc, "genus", "-"), "-", "-",
                         f"{time.perf_counter() - t:.1f}", str(exc)])
            continue
        sec = time.perf_counter() - t
        topo = TriangleMesh(v, f).topology()
        _, _, d = closest_points(s.positions, v, f)
        rows.append([name, len(s), src.genus, len(v), topo.closed, topo.genus,
                     f"{d.max() / diag:.4f}", f"{d.mean() / diag:.5f}", f"{sec:.1f}", ""])
        print(f"  {name} done", flush=True)
    report.table(["model", "surfels", "src genus", "proxy V", "closed", "genus", "max d",
                  "mean d", "s", "error"], rows)
    report.finish()


if __name__ == "__main__":
    main()
