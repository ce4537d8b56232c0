"""Codec speed (issue #25): CPU seconds of the Encoder's set-up by step, of ``encode(rate)`` from a
built Encoder, and of decoding (grid only, surfels as ingest decodes, mesh), with each stream's
size and SHA-256 so byte-identity across versions is visible.

The spherical map (not the codec's) is computed once per model and kept in a cache folder
(``--cache``, default ``$TMPDIR/surfidx-codec-speed``) keyed by the model file's content hash, so
a re-run times only the codec. Figures are CPU seconds (``time.process_time``) of one core, the
best of ``--repeat`` runs, with one BLAS/OpenMP thread unless the environment says otherwise.

Run: ``python benchmarks/codec_speed.py [MODEL ...] [--rates 1 2 4 8] [--repeat 3]``
(default model: ``../shared/data/models/igea.ply`` beside the repository).
"""

from __future__ import annotations

import argparse
import hashlib
import os
import pickle
import tempfile
import time
from dataclasses import replace
from pathlib import Path

# one core, as an ingest worker runs (README: one BLAS/OpenMP thread per worker process); idle
# BLAS threads spinning on a loaded machine would otherwise show up in the CPU seconds
os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("MKL_NUM_THREADS", "1")

import surfidx.codec as codec  # noqa: E402
import surfidx.codec.encoder as codec_encoder  # noqa: E402
from surfidx.codec import density, wavelets  # noqa: E402
from surfidx.codec import PartsEncoder, decode, decode_grid  # noqa: E402
from surfidx.topology import read_model  # noqa: E402
from surfidx.codec.klt import KLT  # noqa: E402
from surfidx.pipeline import content_hash  # noqa: E402

from _markdown import Report, add_markdown_option

DEFAULT_MODEL = Path(__file__).resolve().parents[2] / "shared" / "data" / "models" / "igea.ply"
DEFAULT_RATES = (1.0, 2.0, 4.0, 8.0)

# the Encoder's set-up steps: (label, owner, attribute) of the functions it calls
SETUP_STEPS = (
    ("locate", codec_encoder, "locate_surfels"),
    ("resample", codec_encoder, "resample"),
    ("mask", codec_encoder, "_code_mask"),
    ("klt fit", KLT, "fit"),
    ("klt forward", KLT, "forward"),
    ("wavelets", wavelets, "forward"),
    ("density", density, "weight_field"),
    ("density gain", density, "weighting_gain"),
    ("density scales", density, "vertex_scales"),
    ("anchors", wavelets, "choose_anchors"),
    ("frames", wavelets, "forward_anchored"),
)


def _timed_wrapper(fn, totals, label):
    def wrapper(*args, **kwargs):
        t0 = time.process_time()
        try:
            return fn(*args, **kwargs)
        finally:
            totals[label] = totals.get(label, 0.0) + time.process_time() - t0
    return wrapper


def build_encoder(model, maps):
    """The model's PartsEncoder from cached maps, with the CPU seconds of each set-up step."""
    totals = {}
    saved = []
    for label, owner, attr in SETUP_STEPS:
        raw = owner.__dict__[attr]
        fn = raw.__func__ if isinstance(raw, classmethod) else raw
        wrapped = _timed_wrapper(fn, totals, label)
        saved.append((owner, attr, raw))
        setattr(owner, attr, classmethod(wrapped) if isinstance(raw, classmethod) else wrapped)
    try:
        encoders = []
        t0 = time.process_time()
        for i, (part, smap) in enumerate(zip(model.parts, maps)):
            encoders.append(codec.Encoder(part, sphere_map=smap, color=all(
                p.has_color for p in model.parts), face_patch=model.face_patch(i)))
        totals["total"] = time.process_time() - t0
    finally:
        for owner, attr, raw in saved:
            setattr(owner, attr, raw)
    pe = PartsEncoder.__new__(PartsEncoder)
    pe.encoders = encoders
    pe.n_surfels = sum(e.n_surfels for e in encoders)
    return pe, totals


def cached_maps(path, model, cache: Path):
    """The spherical map of each part, computed once (as ingest maps them) and kept on disk."""
    from surfidx.sphere import parameterize

    cache.mkdir(parents=True, exist_ok=True)
    key = cache / f"{content_hash(path)}.pkl"
    if key.exists():
        with open(key, "rb") as fh:
            return pickle.load(fh)
    t0 = time.process_time()
    # the stage records (read-only figure mappings) are not the codec's input: left out
    maps = [replace(parameterize(p, method="tutte", stress=False), stages=())
            for p in model.parts]
    print(f"  (mapped in {time.process_time() - t0:.1f} s CPU; cached in {key})")
    part = key.with_suffix(".part")
    with open(part, "wb") as fh:
        pickle.dump(maps, fh)
    part.replace(key)     # whole or absent: an interrupted run leaves no half-written cache
    return maps


def best(fn, repeat):
    """(result, least CPU seconds over ``repeat`` calls)."""
    out, least = None, float("inf")
    for _ in range(repeat):
        t0 = time.process_time()
        out = fn()
        least = min(least, time.process_time() - t0)
    return out, least


def run(path: Path, rates, repeat: int, cache: Path, report) -> None:
    model = read_model(path)
    n = sum(len(p) for p in model.parts)
    report.heading(f"{path.name}: {n:,} surfels, {len(model.parts)} part(s)")
    maps = cached_maps(path, model, cache)
    warm, _ = build_encoder(model, maps)   # load the compiled kernels, build the grid tables
    warm_stream = warm.encode(rates[0])
    decode(warm_stream)
    decode(warm_stream, mesh=True)
    del warm, warm_stream
    pe, steps = build_encoder(model, maps)
    report.text(f"Grid level {pe.encoders[0].level}, {pe.encoders[0].grid.shape[0]:,} vertices.")
    inner = sum(v for k, v in steps.items() if k != "total")
    report.table(["Encoder set-up step", "CPU s"],
                 [[label, f"{steps[label]:.3f}"] for label, _, _ in SETUP_STEPS if label in steps]
                 + [["other", f"{steps['total'] - inner:.3f}"],
                    ["total", f"{steps['total']:.3f}"]])
    t0 = time.process_time()
    pe.encode(rates[0])
    report.text(f"First encode (the coder's per-model preparation included): "
                f"{time.process_time() - t0:.3f} s at {rates[0]:g} b/s.")
    rows = []
    for rate in rates:
        data, t_enc = best(lambda: pe.encode(rate), repeat)
        if len(pe.encoders) == 1:
            _, t_grid = best(lambda: decode_grid(data), repeat)
            grid = f"{t_grid:.3f}"
        else:
            grid = "-"
        _, t_surf = best(lambda: decode(data), repeat)
        _, t_mesh = best(lambda: decode(data, mesh=True), repeat)
        rows.append([f"{rate:g}", f"{len(data):,}", f"{t_enc:.3f}", grid, f"{t_surf:.3f}",
                     f"{t_mesh:.3f}", hashlib.sha256(data).hexdigest()[:16]])
    report.table(["rate", "bytes", "encode s", "decode grid s", "decode surfels s",
                  "decode mesh s", "sha256"], rows)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("models", nargs="*", type=Path, default=[DEFAULT_MODEL])
    ap.add_argument("--rates", type=float, nargs="+", default=list(DEFAULT_RATES))
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--cache", type=Path,
                    default=Path(tempfile.gettempdir()) / "surfidx-codec-speed")
    add_markdown_option(ap, "codec_speed")
    args = ap.parse_args()
    report = Report("codec_speed", "Codec speed", args.markdown,
                    note=f"CPU seconds of one core (`time.process_time`), the best of "
                         f"{args.repeat} runs: the Encoder's set-up by step (the spherical map "
                         f"is cached and not timed), `encode(rate)` from a built Encoder, and "
                         f"decoding to the grid, to surfels as ingest decodes and to a mesh; "
                         f"each stream's size and the start of its SHA-256.")
    for path in args.models:
        run(path, args.rates, args.repeat, args.cache, report)
    report.finish()


if __name__ == "__main__":
    main()
