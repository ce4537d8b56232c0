"""What ``get``/``decode`` write: PSNR_D2 of the default output level and of a vertex budget.

For each model (a few shared models and retrieval meshes), the model is read and repaired
as ingest does, coded once at the top rate with output-level hints
(``CodecOptions(level_hints=True)``; off by default, for their encoding cost, which the second
table gives), and the stream's prefixes at each rate are decoded:

* ``old``: at the level whose vertex count is closest to the input's surfel count (the former
  default, one level or more below the stream's own);
* ``stream``: at the stream's own level (the default before the level followed the prefix);
* ``default``: as :func:`surfidx.codec.decode` does with hints (and which level): the stream's
  own, or the coarser one its header's output-level hints give for the prefix served
  (:func:`surfidx.codec.output_levels`; measured by the encoder,
  :func:`surfidx.codec.level_hints`);
* ``best``: the best PSNR_D2 over every level 0 … the stream's (and which level), so
  ``default - best`` says what the default rule leaves on the table;
* ``max_vertices``: ``decode(..., mesh=True, max_vertices=n)`` with ``n`` the input's vertex
  count (the full-level mesh simplified by quadric-error edge collapses), measured on its
  vertices (``vtx``) and, beside the full level's, as a surface (``surf``: 4 samples per input
  surfel drawn on each mesh, so both are measured at the same density), and the CPU seconds of
  the simplification.

PSNR_D2 is symmetric point-to-plane against the scan's own surfels, peak = its bounding-box
diagonal (:mod:`surfidx.geometry.metrics`).

The second table is the encoding's cost: CPU seconds of the encoder's set-up (map, resampling,
transform), of the top rate's encoding with hints, and of the hints' measurement alone
(:func:`surfidx.codec.with_level_hints` of each part again, the same bytes), and the hints'
share of the whole encoding.

Run::

    python benchmarks/output_level.py                       # spot, homer, armadillo, d000
    python benchmarks/output_level.py --models spot d000 --rates 1 2 8 --json out.json
    python benchmarks/output_level.py --markdown            # docs/benchmarks/output_level.md
"""

from __future__ import annotations

import argparse
import json
import sys
import time
import warnings
from pathlib import Path

from surfidx.numerics import use_portable_profile

use_portable_profile()   # before numpy loads: the bytes the surfidx command makes
import numpy as np  # noqa: E402

from surfidx.codec import (CodecOptions, PartsEncoder, decode, max_file_bytes,  # noqa: E402
                           output_levels, with_level_hints)
from surfidx.codec.container import truncate, unpack_parts, unpack  # noqa: E402
from surfidx.geometry.icosphere import vertex_count  # noqa: E402
from surfidx.geometry.metrics import Reference  # noqa: E402
from surfidx.topology import read_model  # noqa: E402

from _markdown import Report, add_markdown_option  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
DATA = REPO.parent / "shared" / "data"
MODELS = {
    "spot": ("models/spot/spot_triangulated.obj", "models/spot/spot_texture.png"),
    "homer": ("models/homer.obj", None),
    "armadillo": ("models/armadillo.obj", None),
    "d000": ("retrieval/meshes/d000.off", None),
    "bunny": ("models/bunny_hr.obj", None),
    "banana": ("models/ycb_banana/textured_simple_reoriented.obj", None),
    "d001": ("retrieval/meshes/d001.off", None),
    "d002": ("retrieval/meshes/d002.off", None),
    "frag_115": ("models/frag_115.ply", None),
}
RATES = (1.0, 2.0, 3.56, 8.0)
SURFACE_SAMPLES = 4   # per input surfel, on both meshes of the surface comparison


def old_level(n: int, level: int) -> int:
    """The former default: the level (at most ``level``) whose vertex count is closest to
    ``n`` (the lower on a tie)."""
    return min(range(level + 1), key=lambda lv: (abs(vertex_count(lv) - n), lv))


def measure(name: str, data_dir: Path, rates) -> list[dict]:
    path, texture = MODELS[name]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        model = read_model(data_dir / path,
                           texture=None if texture is None else data_dir / texture)
    surfels = model.surfels
    ref = Reference(surfels if surfels.patch is None else surfels.subset(~surfels.virtual))
    n = len(surfels)
    t0 = time.process_time()
    pe = PartsEncoder(list(model.parts), options=CodecOptions(level_hints=True))
    t1 = time.process_time()
    stream = pe.encode(max(rates))
    t2 = time.process_time()
    for part, blob in zip(model.parts, unpack_parts(stream)):
        real = part if part.patch is None else part.subset(~part.virtual)
        assert with_level_hints(blob, real) == blob
    cost = {"setup_seconds": t1 - t0, "code_seconds": t2 - t1,
            "hint_seconds": time.process_time() - t2}
    level = max(unpack(b)[0].level for b in unpack_parts(stream))
    rows = []
    for rate in rates:
        data = truncate(stream, max_file_bytes(rate, pe.n_surfels))
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            per_level = {lv: ref.psnr_d2(decode(data, level=lv)) for lv in range(level + 1)}
            full = decode(data, mesh=True)
            t0 = time.process_time()
            small = decode(data, mesh=True, max_vertices=n)
            seconds = time.process_time() - t0 - _decode_seconds(data)
            surf_full = ref.psnr_d2(full.to_surfels(samples=SURFACE_SAMPLES * n))
            surf_small = ref.psnr_d2(small.to_surfels(samples=SURFACE_SAMPLES * n))
            vtx_small = ref.psnr_d2(small.to_surfels(max_edge_ratio=None))
        best = max(per_level, key=per_level.get)
        old = old_level(n, level)
        rows.append({
            "model": name, "n": n, "rate": rate, "level": level, "old_level": old,
            "old": per_level[old], "stream": per_level[level],
            "default_level": max(output_levels(data)), "default": ref.psnr_d2(decode(data)),
            "best_level": best, "best": per_level[best],
            "max_vertices": len(small.vertices), "simplified_vtx": vtx_small,
            "full_surf": surf_full, "simplified_surf": surf_small,
            "simplify_seconds": max(seconds, 0.0), **cost})
    return rows


def _decode_seconds(data: bytes) -> float:
    t0 = time.process_time()
    decode(data, mesh=True)
    return time.process_time() - t0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--models", nargs="+", choices=sorted(MODELS),
                    default=["spot", "homer", "armadillo", "d000"])
    ap.add_argument("--rates", nargs="+", type=float, default=list(RATES),
                    help="bits per input surfel; the stream is coded at the largest and the "
                         "others are its prefixes")
    ap.add_argument("--data", type=Path, default=DATA)
    ap.add_argument("--json", type=Path, metavar="OUT.json")
    add_markdown_option(ap, "output_level")
    args = ap.parse_args(argv)
    if not args.data.is_dir():
        print(f"no shared data at {args.data}", file=sys.stderr)
        return 1
    report = Report(
        "output_level", "What get/decode write: the default output level and max_vertices",
        args.markdown,
        note="PSNR_D2 (dB, symmetric point-to-plane against the scan's surfels). Each model "
             "coded once at the top rate, its prefixes decoded. old: the level whose vertex "
             "count is closest to the input's; stream: the stream's own level; default: the "
             "level decode chooses from the prefix (output_levels: the stream's own, or a "
             "coarser one where the header's output-level hints, measured by the encoder, say "
             "it scores better); best: the best of every "
             "level; N = max_vertices=n (the full level simplified), measured at its vertices "
             "(vtx) and as a surface beside the full level (surf, 4 samples per input surfel); "
             "s: CPU seconds of the simplification.")
    rows = []
    for name in args.models:
        rows += measure(name, args.data, sorted(args.rates))
    report.table(["model", "n", "b/s", "L", "old (L)", "stream", "default (L)", "best (L)",
                  "default - best", "N", "vtx", "surf full", "surf N", "s"],
                 [[r["model"], f"{r['n']:,}", f"{r['rate']:g}", f"{r['level']}",
                   f"{r['old']:.2f} ({r['old_level']})", f"{r['stream']:.2f}",
                   f"{r['default']:.2f} ({r['default_level']})",
                   f"{r['best']:.2f} ({r['best_level']})", f"{r['default'] - r['best']:+.2f}",
                   f"{r['max_vertices']:,}", f"{r['simplified_vtx']:.2f}",
                   f"{r['full_surf']:.2f}", f"{r['simplified_surf']:.2f}",
                   f"{r['simplify_seconds']:.2f}"] for r in rows])
    first = {r["model"]: r for r in rows}   # the cost is per model
    report.table(["model", "n", "set-up s", "encode s (hints incl.)", "hints s",
                  "hints / (set-up + encode)"],
                 [[r["model"], f"{r['n']:,}", f"{r['setup_seconds']:.2f}",
                   f"{r['code_seconds']:.2f}", f"{r['hint_seconds']:.2f}",
                   f"{100 * r['hint_seconds'] / (r['setup_seconds'] + r['code_seconds']):.0f} %"]
                  for r in first.values()])
    worst = min(r["default"] - r["best"] for r in rows)
    before = min(r["stream"] - r["best"] for r in rows)
    gap = min(r["simplified_surf"] - r["full_surf"] for r in rows)
    report.text(f"default vs best level: worst {worst:+.2f} dB (target >= -0.2; the stream's "
                f"own level: {before:+.2f}); max_vertices=n vs the full level as surfaces: "
                f"worst {gap:+.2f} dB (target >= -1)")
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1))
    report.finish()
    return 0


if __name__ == "__main__":
    sys.exit(main())
