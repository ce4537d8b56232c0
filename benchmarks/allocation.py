"""Colour at its own resolution and the bits split between shape and colour: PSNR_D2 and luma
PSNR on the surface against the original texture, per rate, for the fixed split and the
rate–distortion ordered one.

For each textured model of the shared data the streams are coded once at the largest rate and
the lower rates are their prefixes. Variants:

* ``main`` — colour from the vertex colours on the geometry's grid, fixed split (``color_level``
  = the geometry's, ``allocation="fixed"``, no texture source): what the codec did before the
  colour grid;
* ``fixed`` — colour sampled from the texture on its own finer grid, fixed split;
* ``rd λ`` — the same, passes ordered by gain of ``PSNR_D2 + λ · PSNR_YUV`` per bit
  (``allocation="rd"``, ``color_importance=λ``).

Luma PSNR (BT.709, peak 255) is measured on the surface
(:func:`surfidx.geometry.metrics.psnr_luma_surface`): each mesh (the original with its
texture, the decoded grid mesh with its baked texture) is sampled uniformly at ``SAMPLES``
points and each sample compared with the other mesh's colour at the closest surface point
(larger MSE of the two directions), so the measure has no nearest-neighbour sampling floor.
PSNR_D2 is point-to-plane against the input surfels. ``J`` is ``PSNR_D2 + λ·luma`` with the
default λ. ``geo-only D2`` is a colourless stream given exactly the geometry passes' bits of
the ``rd`` stream at that rate.

    python benchmarks/allocation.py [--models spot ycb_banana] [--rates 1 2 3.56 8 16]
                                    [--importance 0.5 1 2] [--jobs 2] [--markdown]
"""

from __future__ import annotations

import argparse
import sys
import time
import warnings
from pathlib import Path

from surfidx.numerics import use_portable_profile

use_portable_profile()

import numpy as np  # noqa: E402

from surfidx.codec import Encoder, decode  # noqa: E402
from surfidx.codec.options import COLOR_IMPORTANCE, CodecOptions  # noqa: E402
from surfidx.geometry.metrics import evaluate, psnr_luma_surface  # noqa: E402
from surfidx.topology import read_model  # noqa: E402

from _markdown import Report, add_markdown_option  # noqa: E402

DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "models"
MODELS = {"spot": "spot/spot_triangulated.obj",
          "ycb_banana": "ycb_banana/textured_simple_reoriented.obj",
          "ycb_scissors": "ycb_scissors/textured_simple_reoriented.obj"}
RATES = (1.0, 2.0, 3.56, 8.0, 16.0)
SAMPLES = 50_000


def _geometry_bits(enc, max_bytes):
    """Bits of the geometry passes in the first ``max_bytes`` bytes of ``enc``'s stream."""
    from surfidx.codec.encoder import pass_bits

    groups, cost = pass_bits(enc.prepared)
    budget = 8.0 * (max_bytes - enc.header_bytes())
    geo, used = 0.0, 0.0
    for g, c in zip(groups, cost):
        take = min(c, max(budget - used, 0.0))
        used += take
        if g == 0:
            geo += take
    return geo


def measure(name, path, rates, importances):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        model = read_model(path)
    surfels = model.surfels
    reference = model.texture

    base = Encoder(model.parts[0], options=CodecOptions(color=False))
    smap = base.sphere_map
    level = base.level
    variants = {"main": dict(options=CodecOptions(allocation="fixed", color_level=level))}
    variants["fixed"] = dict(options=CodecOptions(allocation="fixed"), texture=reference)
    for lam in importances:
        variants[f"rd {lam:g}"] = dict(options=CodecOptions(color_importance=lam),
                                       texture=reference)
    rows = []
    top = max(rates)
    encs = {}
    for label, kw in variants.items():
        t0 = time.process_time()
        encs[label] = Encoder(model.parts[0], sphere_map=smap, **kw)
        setup = time.process_time() - t0
        stream = encs[label].encode(top)
        for rate in rates:
            t0 = time.process_time()
            m = decode(stream, bits_per_surfel=rate, mesh=True, texture=True)
            dt = time.process_time() - t0
            s = decode(stream, bits_per_surfel=rate)
            d2 = evaluate(surfels, s)["psnr_d2"]
            luma = psnr_luma_surface(reference, m, samples=SAMPLES)
            rows.append({"model": name, "variant": label, "rate": rate, "d2": d2, "luma": luma,
                         "decode": dt, "setup": setup,
                         "levels": f"{encs[label].level}/{encs[label].prepared.color_level}"})
    # geometry of the default rd stream against a colourless stream with its geometry bits
    default = f"rd {COLOR_IMPORTANCE:g}"
    if default in encs:
        e = encs[default]
        for r in rows:
            if r["variant"] != default:
                continue
            from surfidx.codec import max_file_bytes

            gbits = _geometry_bits(e, max_file_bytes(r["rate"], e.n_surfels))
            nb = int(base.header_bytes() + np.ceil(gbits / 8.0) + 1)
            s = decode(base.encode_bytes(max(nb, base.lowest_bytes())))
            r["geo_only"] = evaluate(surfels, s)["psnr_d2"]
    return rows


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--models", nargs="+", choices=sorted(MODELS), default=["spot", "ycb_banana"])
    ap.add_argument("--rates", nargs="+", type=float, default=list(RATES))
    ap.add_argument("--importance", nargs="+", type=float, default=[0.5, 1.0, 2.0])
    ap.add_argument("--data", type=Path, default=DATA)
    ap.add_argument("--jobs", type=int, default=2, help="models measured at once")
    add_markdown_option(ap, "allocation")
    args = ap.parse_args(argv)
    if not args.data.is_dir():
        print(f"no shared data at {args.data}", file=sys.stderr)
        return 1
    report = Report("allocation", "Colour grid and shape/colour bit allocation", args.markdown,
                    note=f"PSNR_D2 (dB) against the input surfels; luma PSNR (dB) on the surface "
                         f"against the original texture ({SAMPLES:,} samples each way); "
                         f"J = PSNR_D2 + {COLOR_IMPORTANCE:g} · luma; decode = CPU seconds of "
                         "a textured mesh decode; levels = geometry/colour grid levels.")
    from concurrent.futures import ProcessPoolExecutor

    with ProcessPoolExecutor(max_workers=max(1, args.jobs)) as pool:
        results = list(pool.map(measure, args.models,
                                [args.data / MODELS[n] for n in args.models],
                                [args.rates] * len(args.models),
                                [args.importance] * len(args.models)))
    for name, rows in zip(args.models, results):
        table = []
        for r in rows:
            table.append([r["variant"], r["levels"], f"{r['rate']:g}", f"{r['d2']:.2f}",
                          f"{r['luma']:.2f}", f"{r['d2'] + COLOR_IMPORTANCE * r['luma']:.2f}",
                          f"{r['geo_only']:.2f}" if "geo_only" in r else "",
                          f"{r['decode']:.2f}"])
        report.table(["variant", "levels", "b/s", "PSNR_D2", "luma", "J", "geo-only D2",
                      "decode s"], table, title=name)
    report.finish()
    return 0


if __name__ == "__main__":
    sys.exit(main())
