"""Topology through the codec: real scans repaired, coded with their virtual-region mask, decoded.

For each model (``../shared/data/models``; default the Stanford bunny with its 5 holes, the
genus-1 rocker arm, the pinched cow, and a closed genus-0 model of similar size beside each:
``bunny_hr``, ``armadillo``, ``spot``) the mesh is split into its pieces
(:func:`surfidx.topology.split_parts`), each piece closed (:func:`surfidx.topology.close_surface`)
and turned into surfels with its patches (``surfidx.codec.restore.closed_surfels``), all
parts coded as one file (:class:`surfidx.codec.PartsEncoder`, geometry only) and decoded to the
real surface (:func:`surfidx.codec.decode`). One row per model and rate (2 and 4 bits/surfel):

* the input's and the decoded mesh's topology, each counted independently with
  :func:`surfidx.topology.analysis`: boundary loops, genus (of the largest piece), pieces; the
  kept pieces' loops and genus of every piece (each piece analysed on its own: what decoding
  must restore, the dropped tiny pieces' loops not counted); ``same`` says whether the decoded
  loops, genus of every piece and pieces are the kept pieces' (:func:`restored`);
* the stream: bytes, the mask sections' bytes (mask, its length, region table) and their share
  of the file, the virtual share of the grid;
* PSNR_D2 (:func:`surfidx.geometry.metrics.psnr_d2`) of the decoded real surface (surfels) against the
  input's surfels (one per used vertex, peak: the input's bounding-box diagonal);
* CPU time (``time.process_time``) of the repair and of the encoder set-up (the map dominates).

:func:`measure` gives the row dictionaries for one model (``benchmarks/topology.py`` can call it).

Run: ``python benchmarks/topology_codec.py [--models a.obj,b.obj] [--rates 2,4]``
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
from surfidx.codec import PartsEncoder, decode, stream_summary
from surfidx.geometry.mesh import TriangleMesh
from surfidx.geometry.metrics import psnr_d2
from surfidx.topology import analyse, close_surface, split_parts
from surfidx.codec.restore import closed_surfels

from _markdown import Report, add_markdown_option

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
MODELS = ["cow.obj", "spot/spot_triangulated.obj", "rocker-arm.obj", "armadillo.obj",
          "stanford-bunny.obj", "bunny_hr.obj"]


def topology(vertices, faces) -> dict:
    """Boundary loops, genus of the largest piece, genus of every piece (sorted), pieces,
    pinched vertices, non-manifold edges."""
    r = analyse(vertices, faces)
    return dict(loops=r.holes, genus=r.genus[0], genera=tuple(sorted(r.genus)), pieces=r.parts,
                pinched=r.pinched_vertices, nonmanifold=r.nonmanifold_edges)


def kept_topology(parts) -> dict:
    """What decoding must restore: boundary loops (summed) and genus (sorted) of the pieces
    :func:`~surfidx.topology.split_parts` kept, each counted on its own with
    :func:`~surfidx.topology.analysis`, and their number (the dropped tiny pieces, with their
    loops, are not stored)."""
    rs = [analyse(p.vertices, p.faces) for p in parts.parts]
    return dict(loops=sum(r.holes for r in rs),
                genera=tuple(sorted(g for r in rs for g in r.genus)), pieces=len(rs))


def restored(after, kept) -> bool:
    """Whether the decoded mesh's topology (:func:`topology`) is the kept pieces'
    (:func:`kept_topology`): loops, genus of every piece and pieces equal."""
    return (after["loops"] == kept["loops"] and after["genera"] == kept["genera"]
            and after["pieces"] == kept["pieces"])


def measure(path, *, rates=(2.0, 4.0), level=None) -> list:
    """Rows (dicts) for one model at each rate; see the module docstring."""
    path = Path(path)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        mesh = surfidx.read_mesh(path)
        ref = TriangleMesh(mesh.vertices, mesh.faces).to_surfels(max_edge_ratio=None)
    before = topology(mesh.vertices, mesh.faces)
    t = time.process_time()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        parts = split_parts(mesh.vertices, mesh.faces)
    closed = [close_surface(p.vertices, p.faces) for p in parts.parts]
    t_repair = time.process_time() - t
    kept = kept_topology(parts)
    built = [closed_surfels(c) for c in closed]
    t = time.process_time()
    enc = PartsEncoder([b[0] for b in built], face_patches=[b[1] for b in built], color=False,
                       level=level)
    t_setup = time.process_time() - t
    rows = []
    name = path.parent.name if path.parent.name in ("spot",) or path.parent.name.startswith(
        "ycb") else path.stem
    for rate in rates:
        data = enc.encode(rate)
        summ = stream_summary(data)
        m = decode(data, mesh=True)
        s = decode(data)
        after = topology(m.vertices, m.faces)
        rows.append(dict(
            model=name, rate=rate, V=len(ref), parts=len(closed), dropped=parts.dropped,
            loops_in=before["loops"], genus_in=before["genus"], pieces_in=before["pieces"],
            loops_out=after["loops"], genus_out=after["genus"], pieces_out=after["pieces"],
            loops_kept=kept["loops"], genera_kept=kept["genera"], genera_out=after["genera"],
            manifold=after["pinched"] == 0 and after["nonmanifold"] == 0,
            same=restored(after, kept),
            bytes=len(data), mask_bytes=sum(summ["mask_bytes"]), mask_share=summ["mask_share"],
            virtual_grid=float(np.dot(summ["virtual_share"], summ["part_surfels"])
                               / summ["surfels"]),
            psnr_d2=psnr_d2(ref, s, peak=ref.diagonal), t_repair=t_repair, t_setup=t_setup))
    return rows


COLS = ["model", "rate", "V", "parts", "loops_in", "loops_kept", "loops_out", "genus_in",
        "genus_out", "genera_kept", "genera_out", "pieces_in", "pieces_out", "manifold", "same", "bytes", "mask_bytes", "mask_share",
        "virtual_grid", "psnr_d2", "t_repair", "t_setup"]


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--models", default=",".join(MODELS))
    ap.add_argument("--rates", default="2,4")
    ap.add_argument("--level", type=int, default=None)
    add_markdown_option(ap, "topology_codec")
    args = ap.parse_args(argv)
    rates = [float(r) for r in args.rates.split(",")]
    report = Report("topology_codec", "Topology through the codec", args.markdown,
                    note="Real scans split into pieces, closed, coded with their virtual-region "
                         "mask (geometry only) and decoded to the real surface: the input's, "
                         "the kept pieces' and the decoded mesh's boundary loops, genus and "
                         "pieces (`same`: decoding restored them), the stream and its mask's "
                         "share, PSNR_D2 of the decoded surfels against the input's, and the CPU "
                         "seconds of the repair and the encoder set-up.")
    rows = []
    for m in [m for m in args.models.split(",") if m]:
        for row in measure(DATA / "models" / m, rates=rates, level=args.level):
            rows.append([f"{row[c]:.3f}" if isinstance(row[c], float) else row[c]
                         for c in COLS])
            print(f"  {m} at {row['rate']:g} b/s measured", flush=True)
    report.table(COLS, rows)
    report.finish()


if __name__ == "__main__":
    main()
