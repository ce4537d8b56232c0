"""Choose the KLT's geometry/colour weight (``surfidx.codec.COLOR_WEIGHT``) by rate–distortion.

Before the KLT, geometry is in units of the bounding-box diagonal and colour in units of 255 times
the weight ``w``. The zerotree coder spends bits on the largest normalised wavelet coefficients
first, so ``w`` sets the split of the embedded stream between geometry and texture: a small ``w``
starves the colour (low luma PSNR), a large one starves the geometry (low PSNR_D2).

For a textured model sampled densely (default: spot with its texture, its mesh split by edge
midpoints ``--subdivide`` times, 2 by default: 47k vertices, one surfel per vertex with the texture
averaged around it), the spherical map is computed once; then for every weight an ``Encoder`` (resampling,
KLT, wavelets) is built and encoded at each rate, and the decoded surfels are measured against the
input: PSNR_D1, PSNR_D2 (peak = bounding-box diagonal) and luma PSNR (BT.709, peak 255). The table
also flags the issue's colour target at 3.56 bits/surfel (PSNR_Y >= 30 dB and PSNR_D2 >= 65 dB).

Run::

    python benchmarks/color_weight.py                                 # spot, default weights
    python benchmarks/color_weight.py --model banana --subdivide 1
    python benchmarks/color_weight.py --weights 0.02 0.05 0.1 --rates 2 3.56 8 --json cw.json
"""

from __future__ import annotations

import argparse
import json
import sys
import time
import warnings
from pathlib import Path

from surfidx import codec
from surfidx.numerics import use_portable_profile  # noqa: E402

use_portable_profile()   # before numpy loads: the bytes the surfidx command makes
import numpy as np

from surfidx.io import read_mesh
from surfidx.geometry.mesh import TriangleMesh
from surfidx.geometry.metrics import evaluate
from surfidx.sphere import parameterize

from _markdown import Report, add_markdown_option

REPO = Path(__file__).resolve().parents[1]
DATA = REPO.parent / "shared" / "data" / "models"
MODELS = {
    "spot": ("spot/spot_triangulated.obj", "spot/spot_texture.png"),
    "banana": ("ycb_banana/textured_simple_reoriented.obj", None),  # texture via its MTL
}
WEIGHTS = (0.01, 0.02, 0.05, 0.1, 0.2, 0.4)
RATES = (0.89, 2.0, 3.56, 8.0)
TARGET_RATE, TARGET_Y, TARGET_D2 = 3.56, 30.0, 65.0


def _split(v, f):
    """Midpoint subdivision: vertices and faces, each face into four (corner order kept)."""
    e = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    uniq, inv = np.unique(np.sort(e, axis=1), axis=0, return_inverse=True)
    mid = 0.5 * (v[uniq[:, 0]] + v[uniq[:, 1]])
    ab, bc, ca = (inv.reshape(3, -1) + len(v))
    a, b, c = f.T
    faces = np.concatenate([np.stack(t, 1) for t in ((a, ab, ca), (b, bc, ab), (c, ca, bc),
                                                      (ab, bc, ca))])
    return np.vstack([v, mid]), faces


def subdivide(mesh: TriangleMesh) -> TriangleMesh:
    """Split every triangle into four by its edge midpoints, the UV triangulation alike."""
    v, f = _split(mesh.vertices, mesh.faces)
    uv = uvf = None
    if mesh.uv is not None and mesh.uv_faces is not None:
        uv, uvf = _split(mesh.uv, mesh.uv_faces)
    return TriangleMesh(v, f, uv=uv, uv_faces=uvf, texture=mesh.texture, name=mesh.name)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--model", choices=sorted(MODELS), default="spot")
    ap.add_argument("--subdivide", type=int, default=2,
                    help="midpoint subdivisions of the mesh before taking one surfel per vertex "
                         "(default 2); the default map needs this triangulation")
    ap.add_argument("--weights", nargs="+", type=float, default=list(WEIGHTS))
    ap.add_argument("--rates", nargs="+", type=float, default=list(RATES))
    ap.add_argument("--level", type=int, default=None, help="grid level (default: auto)")
    ap.add_argument("--data", type=Path, default=DATA)
    ap.add_argument("--json", type=Path, metavar="OUT.json")
    add_markdown_option(ap, "color_weight")
    args = ap.parse_args(argv)

    path, texture = MODELS[args.model]
    kw = {"texture": args.data / texture} if texture else {}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        mesh = read_mesh(args.data / path, **kw)
        for _ in range(args.subdivide):
            mesh = subdivide(mesh)
        surfels = mesh.to_surfels()
    if not surfels.has_color:
        print(f"{args.model} has no colour", file=sys.stderr)
        return 1
    t0 = time.perf_counter()
    sphere_map = parameterize(surfels, stress=False)
    report = Report("color_weight", "Geometry/colour weight of the KLT", args.markdown,
                    note=f"For each weight, an Encoder of the textured model encoded at each rate "
                         f"and decoded: PSNR_D1, PSNR_D2 (peak: the bounding-box diagonal) and "
                         f"luma PSNR; the colour target at {TARGET_RATE:g} bits/surfel is "
                         f"PSNR_Y >= {TARGET_Y:g} dB and PSNR_D2 >= {TARGET_D2:g} dB.")
    report.text(f"{args.model}: {len(surfels)} surfels ({args.subdivide} subdivisions), map "
                f"{time.perf_counter() - t0:.1f} s, {sphere_map.folded} folded triangles")
    rows, table = [], []
    for w in args.weights:
        enc = codec.Encoder(surfels, sphere_map=sphere_map, color=True, color_weight=w,
                            level=args.level)
        for rate in args.rates:
            data = enc.encode(rate)
            m = evaluate(surfels, codec.decode(data))
            row = {"weight": w, "target_rate": rate, "rate": len(data) * 8 / len(surfels),
                   **{k: m[k] for k in ("psnr_d1", "psnr_d2", "psnr_y")}}
            rows.append(row)
            flag = ""
            if rate == TARGET_RATE:
                ok = row["psnr_y"] >= TARGET_Y and row["psnr_d2"] >= TARGET_D2
                flag = "PASS" if ok else "FAIL"
            table.append([f"{w:g}", f"{rate:g}", f"{row['rate']:.3f}", f"{row['psnr_d1']:.2f}",
                          f"{row['psnr_d2']:.2f}", f"{row['psnr_y']:.2f}", flag])
            print(f"  weight {w:g} at {rate:g} b/s measured", flush=True)
    report.table(["weight", "target", "bits/surfel", "PSNR_D1", "PSNR_D2", "PSNR_Y",
                  "colour target"], table)
    report.finish()
    if args.json:
        args.json.write_text(json.dumps({"model": args.model, "n": len(surfels),
                                         "subdivide": args.subdivide, "rows": rows}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
