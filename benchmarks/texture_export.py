"""Colour written as vertex colours or as a texture baked on the grid's atlas: luma PSNR
against a dense sampling of the original texture, and the bytes of each file.

For each textured model of the shared data the model is read and coded as ``ingest`` does
(``_textured``: repaired into parts, the textured mesh as the colour source, so the colour grid
is sampled from the texture), once at the largest rate, and the others are its prefixes. At each rate the decoded grid mesh is written as GLB twice: with
vertex colours (``--vertex-colors``) and with its colour as a texture (PNG, and WebP at quality
90). Each written GLB is read back with trimesh; luma PSNR (BT.709) against the original mesh and its
own texture is :func:`surfidx.geometry.metrics.psnr_luma_surface` (``SAMPLES`` points on each
surface, each compared with the other surface's colour at its closest point). Colour on the grid is limited by the grid level: the texture can only carry
the detail the colour layers hold.

    python benchmarks/texture_export.py [--models spot ycb_banana] [--rates 2 4 8] [--markdown]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import warnings
from pathlib import Path

from surfidx.numerics import use_portable_profile

use_portable_profile()

import numpy as np  # noqa: E402

from surfidx import TriangleMesh  # noqa: E402
from surfidx.codec import decode, max_file_bytes  # noqa: E402
from surfidx.codec.container import truncate  # noqa: E402
from surfidx.geometry.metrics import psnr_luma_surface  # noqa: E402
from surfidx.io import read_mesh, write_model  # noqa: E402

from _markdown import Report, add_markdown_option  # noqa: E402
from _textured import parts_encoder, read_textured, real_surfels  # noqa: E402

DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "models"
MODELS = {"spot": "spot/spot_triangulated.obj",
          "ycb_banana": "ycb_banana/textured_simple_reoriented.obj",
          "ycb_scissors": "ycb_scissors/textured_simple_reoriented.obj"}
RATES = (2.0, 4.0, 8.0)
SAMPLES = 200_000


def _read_back(path: Path) -> TriangleMesh:
    """A written GLB read back through trimesh, with its vertex colours or texture."""
    import trimesh

    tm = trimesh.load(path, force="mesh", process=False)
    vis = tm.visual
    if isinstance(vis, trimesh.visual.TextureVisuals) and vis.uv is not None:
        image = np.asarray(vis.material.baseColorTexture.convert("RGB"))
        mesh = TriangleMesh(tm.vertices, tm.faces, uv=vis.uv, uv_faces=tm.faces, texture=image)
    else:
        mesh = TriangleMesh(tm.vertices, tm.faces,
                            vertex_colors=np.asarray(vis.vertex_colors)[:, :3])
    return mesh


def measure(name: str, data: Path, rates):
    path = data / MODELS[name]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        reference = read_mesh(path)
    model = read_textured(path)
    surfels = real_surfels(model)
    enc = parts_encoder(model)
    # the rates count the input's surfels, not the virtual patches'
    stream = enc.encode(max(rates) * len(surfels) / enc.n_surfels)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for rate in rates:
            row = {"model": name, "n": len(surfels), "rate": rate}
            variants = {"vertex colours": dict(texture=False),
                        "texture PNG": dict(texture=True),
                        "texture WebP q90": dict(texture=True, image_format="webp")}
            for label, opts in variants.items():
                fmt = opts.pop("image_format", "png")
                m = decode(truncate(stream, max_file_bytes(rate, len(surfels))), mesh=True,
                           **opts)
                out = Path(tmp) / f"{name}_{rate:g}_{len(row)}.glb"
                write_model(m, out, image_format=fmt)
                row[label] = (psnr_luma_surface(reference, _read_back(out), samples=SAMPLES),
                              out.stat().st_size)
                if m.texture is not None:
                    row["size"] = m.texture.shape[0]
            rows.append(row)
    return rows


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--models", nargs="+", choices=sorted(MODELS),
                    default=["spot", "ycb_banana", "ycb_scissors"])
    ap.add_argument("--rates", nargs="+", type=float, default=list(RATES),
                    help="bits per input surfel; the stream is coded at the largest and the "
                         "others are its prefixes")
    ap.add_argument("--data", type=Path, default=DATA)
    add_markdown_option(ap, "texture_export")
    args = ap.parse_args(argv)
    if not args.data.is_dir():
        print(f"no shared data at {args.data}", file=sys.stderr)
        return 1
    report = Report("texture_export", "Colour out: vertex colours or a texture", args.markdown,
                    note=f"Luma PSNR (dB) of each GLB against the original texture "
                         f"(psnr_luma_surface, {SAMPLES:,} points on each surface); bytes of "
                         f"the GLB.")
    rows = []
    for name in args.models:
        rows += measure(name, args.data, sorted(args.rates))
    labels = ["vertex colours", "texture PNG", "texture WebP q90"]
    report.table(["model", "surfels", "b/s", "texture"]
                 + [f"{k} {w}" for k in labels for w in ("Y dB", "bytes")],
                 [[r["model"], r["n"], f"{r['rate']:g}", f"{r.get('size', '-')}²"]
                  + [v for k in labels for v in (f"{r[k][0]:.2f}", f"{r[k][1]:,}")]
                  for r in rows])
    report.finish()
    return 0


if __name__ == "__main__":
    sys.exit(main())
