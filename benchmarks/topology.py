"""Topology repair benchmark: what each real model is, what the repair adds, whether it maps.

For the five real models of issue 24 (``../shared/data/models``: the Stanford bunny with its
holes, the pinched cow, the genus-1 rocker arm, the genus-3 YCB scissors, the open ten-piece
RGB-D fragment ``frag_115``) and the genus > 0 models of ``../shared/data/retrieval``
(``meta.csv``), prints one row per model:

* before: holes, pinched vertices, genus (of the largest piece), pieces;
* added: holes filled, handles cut, pinched vertices split, virtual share of the area, parts
  kept and dropped (:func:`surfidx.topology.split_parts`);
* whether every closed part maps with :func:`surfidx.sphere.parameterize` (as the surfels
  ``TriangleMesh(v, f).to_surfels()`` with mesh faces), the fold count of the maps;
* CPU time (``time.process_time``) of the repair (analysis + split + close) beside the map's,
  and their ratio (the target: repair at most 10 % of a model's ingest, which the map bounds
  from below).

``--no-map`` leaves the maps out (repair figures only); ``--models a.obj,b.ply`` chooses the
models (paths under ``../shared/data/models`` or ``../shared/data/retrieval``);
``--no-retrieval`` leaves the retrieval models out; ``--mask`` adds the size of the virtual
mask coded per grid vertex (:mod:`surfidx.codec.mask`) at the map's grid level.

``--ingest`` prints the issue's table instead, one row per model of ``--models`` (default the
five real models), everything through the ingest path as it is:

* before (:func:`surfidx.topology.analysis` of the file's mesh): holes, genus (largest piece),
  pieces;
* what the repair added (:func:`surfidx.topology.read_model`'s :meth:`~surfidx.topology.Model.summary`):
  holes filled, handles cut, pinched vertices split, parts kept (dropped), virtual share of the
  area;
* CPU time (``time.process_time``) of the repair (analyse + split_parts + close_surface +
  closed_mesh, on the file's mesh) and of the whole ingest of the model
  (:func:`surfidx.pipeline.process_model` at ingest's 8 bits/surfel: read and repair, map,
  resample, code, decode, evaluate, describe, thumbnail), and the repair's share of it (target
  <= 10 %); whether the ingest succeeded;
* the stored stream decoded at 2 and 4 bits/surfel (prefixes of the one stream,
  :func:`surfidx.codec.decode`, virtual region dropped, cuts zipped): boundary loops, genus and
  pieces counted independently on the decoded mesh (``topology`` of
  ``benchmarks/topology_codec.py``: :func:`~surfidx.topology.analysis`) against the input's,
  the kept pieces' in brackets (``same``: loops, genus of every piece and pieces equal to the
  kept pieces', ``restored`` there: the dropped tiny pieces are not stored),
  PSNR_D2 of the decoded real surface against the input's surfels (one per used vertex, peak
  the input's diagonal) and the mask sections' share of the stream.

``--dp`` prints instead the CPU time of closing one hole by its rim length: a cone open at its
base, closed with ``RepairOptions(dp_max_loop=rim)`` (Liepa's O(n³) programme on the whole rim)
and with the default ``dp_max_loop`` (longer rims split by chords first); the figures behind
that default.

Run: ``python benchmarks/topology.py [--no-map] [--no-retrieval] [--models ...] [--mask]``,
``python benchmarks/topology.py --ingest [--models ...] [--rates 2,4]``,
``python benchmarks/topology.py --dp [--rims 100,300,600,1000]``
"""

from __future__ import annotations

import argparse
import csv
import time
import warnings
from pathlib import Path

import numpy as np

import surfidx
from surfidx.geometry.mesh import TriangleMesh
from surfidx.topology import RepairOptions, analyse, close_surface, split_parts

from _markdown import Report, add_markdown_option

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
MODELS = ["stanford-bunny.obj", "cow.obj", "rocker-arm.obj",
          "ycb_scissors/textured_simple_reoriented.obj", "frag_115.ply"]


def retrieval_models() -> list:
    """The genus > 0 models of the retrieval collection (``meta.csv``)."""
    with open(DATA / "retrieval" / "meta.csv") as fh:
        return [f"retrieval/{r['path']}" for r in csv.DictReader(fh) if int(r["genus"]) > 0]


def run(path: Path, *, do_map: bool, do_mask: bool) -> dict:
    mesh = surfidx.read_mesh(path)
    t = time.process_time()
    before = analyse(mesh.vertices, mesh.faces)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        parts = split_parts(mesh.vertices, mesh.faces)
    closed = [close_surface(p.vertices, p.faces) for p in parts.parts]
    t_repair = time.process_time() - t
    area = sum(float(TriangleMesh(c.vertices, c.faces).face_areas().sum()) for c in closed)
    varea = sum(float(TriangleMesh(c.vertices, c.faces).face_areas()[c.virtual_faces].sum())
                for c in closed)
    row = dict(
        model=path.parent.name if path.parent.name.startswith("ycb") else path.stem,
        V=before.vertices, holes=before.holes, pinched=before.pinched_vertices,
        genus=before.genus[0], pieces=before.parts,
        filled=sum(c.report.holes_filled for c in closed),
        cut=sum(c.report.handles_cut for c in closed),
        split=sum(c.report.pinched_vertices for c in closed),
        virtual_v=sum(c.report.virtual_vertices for c in closed),
        virtual_area=varea / area if area > 0 else 0.0,
        parts=len(closed), dropped=parts.dropped, t_repair=t_repair)
    if do_map:
        from surfidx.sphere import parameterize
        ok, folds, t_map, mask_bytes, grid, bits = True, 0, 0.0, 0, 0, 0
        for c in closed:
            t = time.process_time()
            try:
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    s = TriangleMesh(c.vertices, c.faces).to_surfels()
                    m = parameterize(s, stress=False)
                folds += m.folded
                if do_mask:
                    from surfidx.codec.mask import grid_mask_bytes
                    nb, ng = grid_mask_bytes(s, m, c)
                    mask_bytes += nb
                    grid += ng
                    bits += 2 * len(s)        # the stream at 2 bits/surfel
            except surfidx.SurfidxError as exc:
                ok = False
                row["error"] = str(exc)[:60]
            t_map += time.process_time() - t
        row.update(maps="yes" if ok else "NO", folds=folds, t_map=t_map,
                   ratio=t_repair / t_map if t_map > 0 else float("nan"))
        if do_mask:
            row.update(mask_bytes=mask_bytes, grid=grid,
                       mask_share_2bps=8 * mask_bytes / bits if bits else float("nan"))
    return row


def ingest_row(path: Path, rates) -> dict:
    """One row of the ``--ingest`` table (see the module docstring)."""
    import sys

    from surfidx.codec import decode, max_file_bytes, stream_summary
    from surfidx.topology import read_model
    from surfidx.geometry.metrics import psnr_d2
    from surfidx.pipeline import process_model
    from surfidx.topology import closed_mesh

    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from topology_codec import kept_topology, restored, topology

    name = path.parent.name if path.parent.name.startswith("ycb") else path.stem
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        mesh = surfidx.read_mesh(path)
        ref = TriangleMesh(mesh.vertices, mesh.faces).to_surfels(max_edge_ratio=None)
        t = time.process_time()
        before = analyse(mesh.vertices, mesh.faces)
        parts = None
        if not before.is_sphere:
            parts = split_parts(mesh.vertices, mesh.faces)
            colors = mesh._vertex_colors()
            for p in parts.parts:
                closed_mesh(close_surface(p.vertices, p.faces),
                            colors=None if colors is None else colors[p.vertex_index])
        t_repair = time.process_time() - t
        if parts is None:
            parts = split_parts(mesh.vertices, mesh.faces)
        kept = kept_topology(parts)
        summ = read_model(path).summary()
    inp = topology(mesh.vertices, mesh.faces)
    row = dict(model=name, V=len(ref), holes=before.holes, genus=before.genus[0],
               pieces=before.parts, filled=summ["holes_filled"], cut=summ["handles_cut"],
               split=summ["pinched_vertices"], parts=f"{summ['parts']} ({summ['parts_dropped']})",
               virtual_area=summ["virtual_area_share"], t_repair=t_repair)
    t = time.process_time()
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            rec = process_model(path, bits_per_surfel=8.0)
    except surfidx.SurfidxError as exc:
        row.update(ingest="NO", error=str(exc)[:80], t_ingest=time.process_time() - t)
        return row
    t_ingest = time.process_time() - t
    row.update(t_ingest=t_ingest, share=100 * t_repair / t_ingest, ingest="yes")
    n = rec.n_surfels
    full = stream_summary(rec.stream)
    mask_bytes = sum(full["mask_bytes"])
    for r in rates:
        m = decode(rec.stream, bits_per_surfel=r, mesh=True)
        s = decode(rec.stream, bits_per_surfel=r)
        out = topology(m.vertices, m.faces)
        key = f"{r:g}"
        row[f"loops@{key}"] = f"{inp['loops']}({kept['loops']})/{out['loops']}"
        row[f"genus@{key}"] = f"{inp['genus']}/{out['genus']}"
        row[f"pieces@{key}"] = f"{inp['pieces']}({kept['pieces']})/{out['pieces']}"
        row[f"same@{key}"] = "yes" if restored(out, kept) else "NO"
        row[f"psnr_d2@{key}"] = psnr_d2(ref, s, peak=ref.diagonal)
        row[f"mask%@{key}"] = 100 * mask_bytes / max_file_bytes(r, n)
    return row


def ingest_table(paths, rates, report) -> None:
    cols = ["model", "V", "holes", "genus", "pieces", "filled", "cut", "split", "parts",
            "virtual_area", "t_repair", "t_ingest", "share", "ingest"]
    for r in rates:
        cols += [f"{c}@{r:g}" for c in ("loops", "genus", "pieces", "same", "psnr_d2", "mask%")]
    report.text("before: holes, genus (largest piece), pieces; added: filled, cut, split, parts "
                "(dropped), virtual share of the area; CPU s: repair, whole ingest (8 b/s), "
                "repair share %; decoded at each rate: input/decoded loops, genus, pieces, "
                "PSNR_D2 dB, mask share of the stream %\n")
    report.markdown(" | ".join(cols), flush=True)
    report.markdown(" | ".join("---" for _ in cols))
    for p in paths:
        row = ingest_row(p, rates)
        cells = []
        for c in cols:
            v = row.get(c, "")
            cells.append(f"{v:.3f}" if isinstance(v, float) else str(v))
        report.markdown(" | ".join(cells) + (f"  ({row['error']})" if "error" in row else ""), flush=True)


def cone(rim: int):
    """(vertices, faces) of a cone open at its base: one hole of ``rim`` vertices."""
    t = 2 * np.pi * np.arange(rim) / rim
    v = np.vstack([np.c_[np.cos(t), np.sin(t), np.zeros(rim)], [[0.0, 0.0, 1.0]]])
    i = np.arange(rim)
    return v, np.c_[np.full(rim, rim), (i + 1) % rim, i]


def dp_table(rims, report) -> None:
    """CPU seconds of closing one hole by rim length, one programme on the whole rim and with
    the default split (see the module docstring)."""
    close_surface(*cone(20))                                 # compile the kernels first
    default = RepairOptions().dp_max_loop
    report.markdown(f"rim | one programme (s) | default dp_max_loop={default} (s)")
    report.markdown("--- | --- | ---")
    for rim in rims:
        v, f = cone(rim)
        cells = []
        for opts in (RepairOptions(dp_max_loop=max(rim, 3)), RepairOptions()):
            t = time.process_time()
            close_surface(v, f, options=opts)
            cells.append(f"{time.process_time() - t:.3f}")
        report.markdown(f"{rim} | " + " | ".join(cells), flush=True)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--models", default=",".join(MODELS))
    ap.add_argument("--no-map", action="store_true")
    ap.add_argument("--no-retrieval", action="store_true")
    ap.add_argument("--mask", action="store_true")
    ap.add_argument("--ingest", action="store_true", help="the issue's table (see above)")
    ap.add_argument("--rates", default="2,4", help="decoding rates of --ingest (bits/surfel)")
    ap.add_argument("--dp", action="store_true", help="hole-closing time by rim length")
    ap.add_argument("--rims", default="100,300,600,1000", help="rim lengths of --dp")
    add_markdown_option(ap, "topology")
    args = ap.parse_args(argv)
    if args.markdown is not None and args.markdown.name == "topology.md" and (args.ingest
                                                                              or args.dp):
        args.markdown = args.markdown.with_name("topology_ingest.md" if args.ingest
                                                else "topology_dp.md")
    if args.dp:
        report = Report(args.markdown.stem if args.markdown else "topology_dp",
                        "Closing a hole by rim length", args.markdown,
                        note="CPU seconds of closing the one hole of an open cone, with one "
                             "dynamic programme over the whole rim and with the default split "
                             "of long rims (`RepairOptions.dp_max_loop`).")
        dp_table([int(r) for r in args.rims.split(",")], report)
        report.finish()
        return
    report = Report(args.markdown.stem if args.markdown else "topology",
                    "Topology repair" + (" through the ingest path" if args.ingest else ""),
                    args.markdown,
                    note="What each real model is (holes, pinched vertices, genus, pieces), "
                         "what the repair adds (holes filled, handles cut, pinches split, the "
                         "virtual share of the area, parts kept and dropped), whether every "
                         "closed part maps, and the CPU seconds of the repair beside the map's.")
    if args.ingest:
        names = [m for m in args.models.split(",") if m]
        ingest_table([DATA / "models" / m if not m.startswith("retrieval/") else DATA / m
                      for m in names], [float(r) for r in args.rates.split(",")], report)
        report.finish()
        return
    names = [m for m in args.models.split(",") if m]
    paths = [DATA / "models" / m if not m.startswith("retrieval/") else DATA / m for m in names]
    if not args.no_retrieval:
        paths += [DATA / m for m in retrieval_models()]
    cols = ["model", "V", "holes", "pinched", "genus", "pieces", "filled", "cut", "split",
            "virtual_v", "virtual_area", "parts", "dropped", "t_repair"]
    if not args.no_map:
        cols += ["maps", "folds", "t_map", "ratio"]
        if args.mask:
            cols += ["grid", "mask_bytes", "mask_share_2bps"]
    report.markdown(" | ".join(cols))
    report.markdown(" | ".join("---" for _ in cols))
    for p in paths:
        row = run(p, do_map=not args.no_map, do_mask=args.mask)
        cells = []
        for c in cols:
            v = row.get(c, "")
            cells.append(f"{v:.3f}" if isinstance(v, float) else str(v))
        report.markdown(" | ".join(cells) + (f"  ({row['error']})" if "error" in row else ""),
                        flush=True)
    report.finish()


if __name__ == "__main__":
    main()
