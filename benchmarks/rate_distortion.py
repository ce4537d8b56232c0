"""Rate-distortion of surfidx's spherical-wavelet codec against Google Draco's point-cloud coder
and, when a ``tmc3`` binary is found, MPEG G-PCC.

For every closed genus-0 model of ``../shared/data/models`` (geometry only, and with colour where
the model has it), surfidx's codec is set up once per model (``surfidx.codec.Encoder``: spherical
map, resampling, KLT, wavelets; its ``setup_seconds`` printed apart) and then encoded at each rate
(default 0.5, 0.89, 1.39, 2, 3.56, 8 bits/surfel) and decoded with ``surfidx.codec.decode``. Beside
it, Draco codes the same points at quantisation 6..14 bits (compression level 10, RGB attribute
when colour is on). Both decoded sets are measured against the input surfels with
``surfidx.geometry.metrics.evaluate``:

* **rate**: whole file bytes * 8 / input surfels (the container's header and checksums included;
  for Draco ``len(bytes) * 8 / n``);
* **PSNR_D1, PSNR_D2**: symmetric point-to-point / point-to-plane, peak = the input's bounding-box
  diagonal; **PSNR_Y**: BT.709 luma, peak 255 (colour runs only);
* **enc s / dec s**: ``Encoder.encode(rate)`` (setup excluded) and ``decode`` for surfidx;
  ``DracoPy.encode`` / ``DracoPy.decode`` for Draco.

When ``tmc3`` (MPEG's G-PCC reference software, TMC13) is found (``--tmc3``, else
``../shared/tools/tmc13/tmc3``, else on PATH), G-PCC codes the same points too: octree at depths
6..14 and trisoup at node sizes 2..4 around the input's spacing, the RGB attribute by RAHT at a
qp paired with the depth in colour runs; whole bitstream counted (see ``benchmarks/_gpcc.py``).
Without the binary the G-PCC rows are skipped with a note. The summary gives, per run and rate up
to 4 bits/surfel, surfidx's PSNR_D2 against G-PCC's best (octree or trisoup) at the same rate
(INFO: the issue sets no margin).

Draco (and G-PCC) store no normals: its decoded points get the normal of their nearest input surfel (the
metrics' D2 uses the normals of the set searched, here needed in the test-to-reference direction)
and radii from their spacing; see ``benchmarks/_draco.py``. This favours Draco.

The textured models (spot, banana) are sampled densely (``--samples``, default 100000 uniform
surface samples) so texture detail finer than the vertex spacing survives; both of their runs
(geometry only and colour) use those samples, and their rates count bits per sampled surfel.

The summary checks the issue's targets (PASS/FAIL; "NOT RUN" when the run did not cover them):

1. Igea, geometry only: PSNR_D2 >= 70 dB at 0.89, >= 74 at 1.39, >= 79 at 3.56 bits/surfel.
2. Every model and variant, every rate <= 4 bits/surfel: surfidx's PSNR_D2 at least 10 dB above
   Draco's at the same (actual) rate, Draco's PSNR_D2 interpolated linearly in log-rate between its
   quantisation settings; "below Draco's range" (no verdict) where Draco's smallest rate is higher.
3. Colour runs at 3.56 bits/surfel: PSNR_Y >= 30 dB and PSNR_D2 >= 65 dB.
4. Embedded stream: for each rate B < 8, ``decode(encode(8), bits_per_surfel=B)`` within 0.5 dB of
   ``decode(encode(B))`` (PSNR_D2, and PSNR_Y in colour runs).
5. Igea (geometry only): encode after parameterisation <= 5 s and decode <= 2 s at every rate.
   "Encode" is ``Encoder.encode(rate)`` plus, when the Encoder reports a per-stage breakdown of
   its setup, the setup stages after the spherical map (see ``_encode_after_map``).

Run (about 20 minutes on 2 cores for everything)::

    python benchmarks/rate_distortion.py                         # all models, both coders
    python benchmarks/rate_distortion.py --quick                 # homer + spot, 3 rates
    python benchmarks/rate_distortion.py --models igea homer --rates 0.89 3.56
    python benchmarks/rate_distortion.py --coders draco          # Draco half only
    python benchmarks/rate_distortion.py --json rd.json --plot rd.png

Needs the ``bench`` extra (``pip install -e '.[bench]'``: DracoPy, matplotlib).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
import traceback
import warnings
from pathlib import Path

from surfidx.numerics import use_portable_profile  # noqa: E402

use_portable_profile()   # before numpy loads: the bytes the surfidx command makes
import numpy as np

from surfidx.errors import InputError
from surfidx.io import read_surfels
from surfidx.geometry.metrics import evaluate

from _draco import DEFAULT_BITS, DEFAULT_LEVEL, draco_point
from _gpcc import find_tmc3, gpcc_point, gpcc_settings

from _markdown import Report, add_markdown_option

REPO = Path(__file__).resolve().parents[1]
DATA = REPO.parent / "shared" / "data" / "models"

#: name -> (file, texture image or None, textured). Every model is closed, genus 0, one component.
MODELS = {
    "igea": ("igea.ply", None, False),
    "bunny_hr": ("bunny_hr.obj", None, False),
    "horse": ("horse.ply", None, False),
    "armadillo": ("armadillo.obj", None, False),
    "nefertiti": ("nefertiti.obj", None, False),
    "koala": ("koala.obj", None, False),
    "scorpion": ("scorpion.obj", None, False),
    "falconstatue": ("falconstatue.obj", None, False),
    "homer": ("homer.obj", None, False),
    "spot": ("spot/spot_triangulated.obj", "spot/spot_texture.png", True),
    "banana": ("ycb_banana/textured_simple_reoriented.obj", None, True),  # texture via its MTL
}
RATES = (0.5, 0.89, 1.39, 2.0, 3.56, 8.0)
QUICK_MODELS = ("homer", "spot")
QUICK_RATES = (0.89, 2.0, 3.56)
QUICK_SAMPLES = 20_000
TOP_RATE = 8.0

IGEA_D2 = {0.89: 70.0, 1.39: 74.0, 3.56: 79.0}
MARGIN_OVER_DRACO = 10.0
MARGIN_MAX_RATE = 4.0
COLOR_RATE, COLOR_Y, COLOR_D2 = 3.56, 30.0, 65.0
PREFIX_TOL = 0.5
IGEA_ENC_S, IGEA_DEC_S = 5.0, 2.0


# ---------------------------------------------------------------------- helpers
def fmt(x, width=8, digits=2) -> str:
    if x is None:
        return f"{'-':>{width}}"
    if isinstance(x, float) and math.isinf(x):
        return f"{'inf':>{width}}"
    return f"{x:>{width}.{digits}f}"


def measure(reference, decoded) -> dict:
    m = evaluate(reference, decoded)
    return {k: m[k] for k in ("psnr_d1", "psnr_d2", "psnr_y", "hausdorff")}


def load(name: str, data: Path, samples: int | None):
    path, texture, textured = MODELS[name]
    kw = {}
    if texture:
        kw["texture"] = data / texture
    if textured and samples:
        kw["samples"] = samples
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return read_surfels(data / path, **kw), textured


def interp_log_rate(points, rate):
    """Draco's PSNR_D2 at ``rate`` by linear interpolation over log-rate; None outside its range.

    Returns ``(value, where)`` with ``where`` in ``"in"``, ``"below"``, ``"above"``.
    """
    pts = sorted((r["rate"], r["psnr_d2"]) for r in points)
    rates = np.array([p[0] for p in pts])
    psnr = np.array([p[1] for p in pts])
    if rate < rates[0]:
        return None, "below"
    if rate > rates[-1]:
        return None, "above"
    return float(np.interp(math.log(rate), np.log(rates), psnr)), "in"


def _encode_after_map(encoder) -> float | None:
    """Seconds of the Encoder's setup after the spherical map, if it reports a breakdown.

    Looks for a dict attribute ``setup_seconds`` / ``setup_timings`` / ``timings`` (stage -> seconds) and sums every
    stage but the parameterisation ones (names containing ``map``, ``param``, ``sphere`` or
    ``graph``/``geodesic``). Returns None when there is no breakdown.
    """
    for attr in ("setup_seconds", "setup_timings", "timings", "stage_seconds"):
        t = getattr(encoder, attr, None)
        if isinstance(t, dict) and t:
            skip = ("map", "param", "spher", "graph", "geodesic", "embed", "read", "total")
            return float(sum(v for k, v in t.items()
                             if isinstance(v, (int, float)) and not any(s in k.lower() for s in skip)))
    return None


# ---------------------------------------------------------------------- coders
def run_draco(surfels, color: bool, bits_list, level: int) -> list[dict]:
    n = len(surfels)
    rows = []
    for bits in bits_list:
        data, decoded, t_enc, t_dec = draco_point(surfels, bits=bits, color=color, level=level)
        rows.append({"coder": "draco", "setting": f"q={bits}", "quantization_bits": bits,
                     "bytes": len(data), "rate": len(data) * 8 / n, "enc_s": t_enc,
                     "dec_s": t_dec, **measure(surfels, decoded)})
    return rows


def run_gpcc(surfels, color: bool, tmc3) -> list[dict]:
    """Every G-PCC setting (octree and trisoup); a setting tmc3 fails on is reported and
    skipped."""
    n = len(surfels)
    rows = []
    for mode, depth, node in gpcc_settings(surfels):
        setting = f"oct {depth}" if mode == "octree" else f"tri {depth}/{node}"
        try:
            nbytes, decoded, t_enc, t_dec = gpcc_point(tmc3, surfels, mode=mode, depth=depth,
                                                       node=node, color=color)
        except RuntimeError as exc:
            REPORT.print(f"   gpcc {setting} skipped: {exc}")
            continue
        rows.append({"coder": "gpcc", "setting": setting, "mode": mode, "depth": depth,
                     "node": node, "bytes": nbytes, "rate": nbytes * 8 / n, "enc_s": t_enc,
                     "dec_s": t_dec, **measure(surfels, decoded)})
    return rows


def pareto(rows: list[dict]) -> list[dict]:
    """The rows no other row beats at a lower or equal rate (PSNR_D2), by rate."""
    out = []
    for r in sorted(rows, key=lambda r: (r["rate"], -r["psnr_d2"])):
        if not out or r["psnr_d2"] > out[-1]["psnr_d2"]:
            out.append(r)
    return out


_WARMED = False


def run_surfidx(surfels, rates, level, method) -> dict:
    """One Encoder, every rate; plus the embedded-prefix check against an 8 bits/surfel stream."""
    global _WARMED
    from surfidx import codec

    n = len(surfels)
    t0 = time.perf_counter()
    # surface samples (no faces) get the default map too: through a closed proxy mesh
    kw = {} if method is None else {"method": method}
    enc = codec.Encoder(surfels, level=level, **kw)
    wall_setup = time.perf_counter() - t0
    setup = getattr(enc, "setup_seconds", wall_setup)
    setup = float(sum(setup.values()) if isinstance(setup, dict) else setup)
    if not _WARMED:  # first call compiles/loads numba kernels: keep it out of the timings
        codec.decode(enc.encode(min(rates)))
        _WARMED = True
    rows, streams = [], {}
    skipped = []
    for rate in sorted(set(rates) | {TOP_RATE}):
        t0 = time.perf_counter()
        try:
            data = enc.encode(rate)
        except InputError as exc:   # a rate below what the header needs: say so, go on
            skipped.append(f"{rate:g} b/s skipped: {exc}")
            continue
        t_enc = time.perf_counter() - t0
        streams[rate] = data
        if rate not in rates:
            continue
        t0 = time.perf_counter()
        decoded = codec.decode(data)
        t_dec = time.perf_counter() - t0
        rows.append({"coder": "surfidx", "setting": f"{rate:g} b/s", "target_rate": rate,
                     "bytes": len(data), "rate": len(data) * 8 / n, "enc_s": t_enc,
                     "dec_s": t_dec, **measure(surfels, decoded)})
    prefix = []
    direct = {r["target_rate"]: r for r in rows}
    for rate in sorted(r for r in rates if r < TOP_RATE and r in direct):
        t0 = time.perf_counter()
        decoded = codec.decode(streams[TOP_RATE], bits_per_surfel=rate)
        t_dec = time.perf_counter() - t0
        m = measure(surfels, decoded)
        prefix.append({"rate": rate, "dec_s": t_dec, **m,
                       "direct_psnr_d2": direct[rate]["psnr_d2"],
                       "direct_psnr_y": direct[rate]["psnr_y"]})
    return {"setup_s": setup, "after_map_s": _encode_after_map(enc), "rows": rows,
            "prefix": prefix, "skipped": skipped}


# ---------------------------------------------------------------------- printing
HEADER = (f"{'coder':<8} {'setting':<9} {'bits/surfel':>11} {'PSNR_D1':>8} {'PSNR_D2':>8} "
          f"{'PSNR_Y':>8} {'enc s':>7} {'dec s':>7}")


def print_run(run: dict) -> None:
    title = f"== {run['model']} ({run['n']} surfels, {run['variant']})"
    if run.get("surfidx_setup_s") is not None:
        title += f"; surfidx Encoder setup {run['surfidx_setup_s']:.2f} s"
    REPORT.print(title + " ==")
    if run.get("surfidx_error"):
        REPORT.print(f"   surfidx FAILED: {run['surfidx_error']}")
    for note in run.get("surfidx_skipped", []):
        REPORT.print(f"   surfidx {note}")
    REPORT.print(HEADER)
    for r in run["rows"]:
        REPORT.print(f"{r['coder']:<8} {r['setting']:<9} {r['rate']:>11.3f} {fmt(r['psnr_d1'])} "
              f"{fmt(r['psnr_d2'])} {fmt(r['psnr_y'])} {fmt(r['enc_s'], 7, 3)} "
              f"{fmt(r['dec_s'], 7, 3)}")
    if run.get("prefix"):
        REPORT.print("   prefix of the 8 b/s stream:  " + "  ".join(
            f"{p['rate']:g}: D2 {fmt(p['psnr_d2'], 0)} (direct {fmt(p['direct_psnr_d2'], 0)})"
            for p in run["prefix"]))
    REPORT.print(flush=True)


# ---------------------------------------------------------------------- targets
def check_targets(runs: list[dict], coders) -> list[dict]:
    out = []

    def add(name, status, detail):
        out.append({"target": name, "status": status, "detail": detail})

    by = {(r["model"], r["variant"]): r for r in runs}
    has_surfidx = "surfidx" in coders

    def srow(run, rate):
        for r in run["rows"]:
            if r["coder"] == "surfidx" and r["target_rate"] == rate:
                return r
        return None

    # 1. Igea geometry PSNR_D2
    igea = by.get(("igea", "geometry"))
    for rate, need in IGEA_D2.items():
        name = f"igea geometry PSNR_D2 >= {need:g} dB at {rate:g} b/s"
        r = srow(igea, rate) if igea and has_surfidx else None
        if r is None:
            add(name, "NOT RUN", "igea/surfidx/rate not in this run")
        else:
            add(name, "PASS" if r["psnr_d2"] >= need else "FAIL",
                f"{r['psnr_d2']:.2f} dB at {r['rate']:.3f} b/s")

    # 2. >= 10 dB above Draco at rates <= 4
    if not has_surfidx:
        add(f"surfidx >= {MARGIN_OVER_DRACO:g} dB over Draco at rates <= {MARGIN_MAX_RATE:g} b/s",
            "NOT RUN", "surfidx codec not run")
    for run in runs:
        if not has_surfidx:
            break
        draco = [r for r in run["rows"] if r["coder"] == "draco"]
        for r in run["rows"]:
            if r["coder"] != "surfidx" or r["target_rate"] > MARGIN_MAX_RATE:
                continue
            name = (f"{run['model']} {run['variant']} at {r['target_rate']:g} b/s: "
                    f">= {MARGIN_OVER_DRACO:g} dB over Draco")
            if not draco:
                add(name, "NOT RUN", "Draco not run")
                continue
            ref, where = interp_log_rate(draco, r["rate"])
            if where == "below":
                lo = min(d["rate"] for d in draco)
                add(name, "below Draco's range",
                    f"surfidx {r['psnr_d2']:.2f} dB at {r['rate']:.3f} b/s; Draco's smallest "
                    f"rate {lo:.3f} b/s")
            elif where == "above":
                add(name, "above Draco's range", f"surfidx at {r['rate']:.3f} b/s")
            else:
                gap = r["psnr_d2"] - ref
                add(name, "PASS" if gap >= MARGIN_OVER_DRACO else "FAIL",
                    f"surfidx {r['psnr_d2']:.2f} dB vs Draco {ref:.2f} dB at {r['rate']:.3f} b/s "
                    f"({gap:+.2f} dB)")
        if run.get("surfidx_error"):
            add(f"{run['model']} {run['variant']}: surfidx codec", "FAIL", run["surfidx_error"])

    # 2b. against G-PCC, best of octree and trisoup (no margin set: INFO)
    for run in runs:
        gpcc = pareto([r for r in run["rows"] if r["coder"] == "gpcc"
                       and math.isfinite(r["psnr_d2"])])
        if not has_surfidx or not gpcc:
            continue
        for r in run["rows"]:
            if r["coder"] != "surfidx" or r["target_rate"] > MARGIN_MAX_RATE:
                continue
            name = (f"{run['model']} {run['variant']} at {r['target_rate']:g} b/s: "
                    f"surfidx vs G-PCC (best of octree and trisoup)")
            ref, where = interp_log_rate(gpcc, r["rate"])
            if where != "in":
                add(name, "INFO", f"surfidx {r['psnr_d2']:.2f} dB at {r['rate']:.3f} b/s, "
                    f"{where} G-PCC's range ({gpcc[0]['rate']:.3f}..{gpcc[-1]['rate']:.3f} b/s)")
            else:
                add(name, "INFO", f"surfidx {r['psnr_d2']:.2f} dB vs G-PCC {ref:.2f} dB at "
                    f"{r['rate']:.3f} b/s ({r['psnr_d2'] - ref:+.2f} dB)")

    # 3. colour quality at 3.56
    color_runs = [r for r in runs if r["variant"] == "colour"]
    if not color_runs:
        add(f"colour: PSNR_Y >= {COLOR_Y:g} and PSNR_D2 >= {COLOR_D2:g} at {COLOR_RATE:g} b/s",
            "NOT RUN", "no coloured model in this run")
    for run in color_runs:
        name = (f"{run['model']} colour at {COLOR_RATE:g} b/s: PSNR_Y >= {COLOR_Y:g}, "
                f"PSNR_D2 >= {COLOR_D2:g}")
        r = srow(run, COLOR_RATE) if has_surfidx else None
        if r is None:
            add(name, "NOT RUN", "surfidx or that rate not in this run")
        else:
            ok = r["psnr_y"] is not None and r["psnr_y"] >= COLOR_Y and r["psnr_d2"] >= COLOR_D2
            add(name, "PASS" if ok else "FAIL",
                f"PSNR_Y {fmt(r['psnr_y'], 0)} dB, PSNR_D2 {r['psnr_d2']:.2f} dB")

    # 4. embedded prefix
    if not has_surfidx:
        add(f"prefix of an 8 b/s stream within {PREFIX_TOL:g} dB of direct coding", "NOT RUN",
            "surfidx codec not run")
    for run in runs:
        if not has_surfidx:
            break
        for p in run.get("prefix", []):
            diffs = [abs(p["psnr_d2"] - p["direct_psnr_d2"])]
            detail = f"D2 prefix {p['psnr_d2']:.2f} vs direct {p['direct_psnr_d2']:.2f}"
            if p["psnr_y"] is not None and p["direct_psnr_y"] is not None:
                diffs.append(abs(p["psnr_y"] - p["direct_psnr_y"]))
                detail += f"; Y prefix {p['psnr_y']:.2f} vs direct {p['direct_psnr_y']:.2f}"
            diffs = [0.0 if math.isnan(d) else d for d in diffs]  # inf - inf
            add(f"{run['model']} {run['variant']}: prefix of 8 b/s at {p['rate']:g} b/s within "
                f"{PREFIX_TOL:g} dB", "PASS" if max(diffs) <= PREFIX_TOL else "FAIL", detail)

    # 5. Igea timings
    rows = [r for r in (igea or {}).get("rows", []) if r["coder"] == "surfidx"]
    if not rows:
        add(f"igea encode <= {IGEA_ENC_S:g} s, decode <= {IGEA_DEC_S:g} s", "NOT RUN",
            "igea/surfidx not in this run")
    else:
        extra = igea.get("surfidx_after_map_s") or 0.0
        enc = max(r["enc_s"] for r in rows) + extra
        dec = max(r["dec_s"] for r in rows)
        how = (f"slowest encode() {enc - extra:.2f} s + setup after the map {extra:.2f} s"
               if igea.get("surfidx_after_map_s") is not None else
               f"slowest encode() {enc:.2f} s (setup {igea['surfidx_setup_s']:.2f} s incl. the map "
               "reported apart: the Encoder gives no per-stage breakdown)")
        add(f"igea encode after parameterisation <= {IGEA_ENC_S:g} s",
            "PASS" if enc <= IGEA_ENC_S else "FAIL", how)
        add(f"igea decode <= {IGEA_DEC_S:g} s", "PASS" if dec <= IGEA_DEC_S else "FAIL",
            f"slowest decode {dec:.2f} s")
    return out


def print_targets(targets: list[dict]) -> None:
    REPORT.print("== targets ==")
    for t in targets:
        REPORT.print(f"{t['status']:<20} {t['target']}: {t['detail']}")
    counts = {}
    for t in targets:
        counts[t["status"]] = counts.get(t["status"], 0) + 1
    REPORT.print("   " + ", ".join(f"{v} {k}" for k, v in sorted(counts.items())))


# ---------------------------------------------------------------------- plot / json
def plot(runs: list[dict], out: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    models = list(dict.fromkeys(r["model"] for r in runs))
    cols = min(4, len(models))
    rows = math.ceil(len(models) / cols)
    fig, axes = plt.subplots(rows, cols, figsize=(4.2 * cols, 3.4 * rows), squeeze=False)
    style = {("surfidx", "geometry"): ("C0", "-", "o"), ("draco", "geometry"): ("C1", "-", "s"),
             ("surfidx", "colour"): ("C0", "--", "^"), ("draco", "colour"): ("C1", "--", "v"),
             ("gpcc", "geometry"): ("C2", "-", "D"), ("gpcc", "colour"): ("C2", "--", "d")}
    for ax, model in zip(axes.ravel(), models):
        for run in (r for r in runs if r["model"] == model):
            for coder in ("surfidx", "draco", "gpcc"):
                rows = [r for r in run["rows"]
                        if r["coder"] == coder and math.isfinite(r["psnr_d2"])]
                pts = [(r["rate"], r["psnr_d2"]) for r in pareto(rows)]
                if not pts:
                    continue
                c, ls, mk = style[(coder, run["variant"])]
                ax.plot([p[0] for p in pts], [p[1] for p in pts], color=c, linestyle=ls,
                        marker=mk, markersize=4, label=f"{coder} ({run['variant']})")
        ax.set_xscale("log")
        ax.set_title(f"{model} ({runs[[r['model'] for r in runs].index(model)]['n']} surfels)",
                     fontsize=10)
        ax.set_xlabel("bits / input surfel")
        ax.set_ylabel("PSNR D2 (dB)")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=7)
    for ax in axes.ravel()[len(models):]:
        ax.set_visible(False)
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    plt.close(fig)


def _jsonable(x):
    if isinstance(x, float) and not math.isfinite(x):
        return str(x)
    if isinstance(x, dict):
        return {k: _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    if isinstance(x, np.generic):
        return x.item()
    return x


# ---------------------------------------------------------------------- main
REPORT = None


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--models", nargs="+", choices=sorted(MODELS), metavar="NAME",
                    help="models to run (default all): " + " ".join(MODELS))
    ap.add_argument("--rates", nargs="+", type=float, help=f"bits/surfel (default {RATES})")
    ap.add_argument("--quick", action="store_true",
                    help=f"{' + '.join(QUICK_MODELS)} at rates {QUICK_RATES}, textured models "
                         f"sampled at {QUICK_SAMPLES} unless --samples is given")
    ap.add_argument("--coders", nargs="+", choices=("surfidx", "draco", "gpcc"),
                    default=["surfidx", "draco", "gpcc"],
                    help="gpcc runs only when a tmc3 binary is found (see --tmc3)")
    ap.add_argument("--tmc3", type=Path, default=None,
                    help="MPEG G-PCC's tmc3 binary (default: ../shared/tools/tmc13/tmc3, "
                         "else tmc3 on PATH)")
    ap.add_argument("--variants", nargs="+", choices=("geometry", "colour"),
                    default=["geometry", "colour"],
                    help="geometry only, and with colour (coloured models only)")
    ap.add_argument("--samples", type=int, default=None,
                    help="uniform surface samples for the textured models (default 100000; 0 = one "
                         "surfel per mesh vertex)")
    ap.add_argument("--draco-bits", nargs="+", type=int, default=list(DEFAULT_BITS),
                    help="Draco quantisation bits (default 6..14)")
    ap.add_argument("--draco-level", type=int, default=DEFAULT_LEVEL,
                    help="Draco compression level 0..10 (default 10)")
    ap.add_argument("--level", type=int, default=None, help="surfidx grid level (default: auto)")
    ap.add_argument("--method", default=None, help="surfidx spherical-map method (default: auto)")
    ap.add_argument("--data", type=Path, default=DATA, help=f"models folder (default {DATA})")
    ap.add_argument("--json", type=Path, metavar="OUT.json", help="write every figure as JSON")
    ap.add_argument("--plot", type=Path, metavar="OUT.png", help="PSNR_D2 against rate, per model")
    add_markdown_option(ap, "rate_distortion")
    args = ap.parse_args(argv)
    global REPORT
    REPORT = Report("rate_distortion", "Rate-distortion against Draco and G-PCC", args.markdown,
                    note="surfidx's codec set up once per model and encoded at each rate, beside "
                         "Google Draco's point-cloud coder (the `bench` extra) at quantisation "
                         "6..14 and MPEG G-PCC (tmc3, octree and trisoup) when found: rate in bits per input surfel (whole file), PSNR_D1, PSNR_D2 "
                         "(peak: the bounding-box diagonal), PSNR_Y (colour runs), encode and "
                         "decode seconds.")

    models = args.models or (list(QUICK_MODELS) if args.quick else list(MODELS))
    rates = sorted(set(args.rates or (QUICK_RATES if args.quick else RATES)))
    if any(not r > 0 for r in rates):
        ap.error("rates must be positive")
    samples = args.samples if args.samples is not None else (QUICK_SAMPLES if args.quick
                                                                else 100_000)
    coders = list(args.coders)
    if "surfidx" in coders:
        try:
            from surfidx import codec  # noqa: F401
            codec.Encoder, codec.decode  # noqa: B018
        except (ImportError, AttributeError) as exc:
            print(f"warning: surfidx.codec is not available ({exc}); running Draco only",
                  file=sys.stderr)
            coders.remove("surfidx")
    if not args.data.is_dir():
        ap.error(f"models folder {args.data} not found; pass --data")
    tmc3 = None
    if "gpcc" in coders:
        tmc3 = find_tmc3(args.tmc3)
        if tmc3 is None:
            where = args.tmc3 or "the shared tools or PATH"
            REPORT.print(f"G-PCC skipped: no tmc3 binary found ({where}); pass --tmc3 PATH "
                         "to run it\n")
            coders.remove("gpcc")

    REPORT.print(f"rates {', '.join(f'{r:g}' for r in rates)} bits/surfel; Draco q={args.draco_bits} "
          f"level {args.draco_level}; textured models: "
          f"{samples if samples else 'per-vertex'} samples; coders: {', '.join(coders)}\n",
          flush=True)
    t_start = time.perf_counter()
    runs = []
    for name in models:
        surfels, textured = load(name, args.data, samples or None)
        variants = [v for v in args.variants if v == "geometry" or (v == "colour" and textured
                                                                      and surfels.has_color)]
        for variant in variants:
            s = surfels if variant == "colour" else surfels.without_color()
            color = variant == "colour"
            run = {"model": name, "variant": variant, "n": len(s), "rows": [], "prefix": [],
                   "surfidx_setup_s": None, "surfidx_after_map_s": None}
            if "surfidx" in coders:
                try:
                    res = run_surfidx(s, rates, args.level, args.method)
                    run["rows"] += res["rows"]
                    run["prefix"] = res["prefix"]
                    run["surfidx_setup_s"] = res["setup_s"]
                    run["surfidx_after_map_s"] = res["after_map_s"]
                    run["surfidx_skipped"] = res["skipped"]
                except Exception as exc:  # report and go on with the other models
                    traceback.print_exc()
                    run["surfidx_error"] = f"{type(exc).__name__}: {exc}"
            if "draco" in coders:
                run["rows"] += run_draco(s, color, args.draco_bits, args.draco_level)
            if "gpcc" in coders:
                run["rows"] += run_gpcc(s, color, tmc3)
            runs.append(run)
            print_run(run)
    targets = check_targets(runs, coders)
    print_targets(targets)
    elapsed = time.perf_counter() - t_start
    REPORT.print(f"\ntotal {elapsed:.0f} s")
    REPORT.finish()
    if args.json:
        meta = {"rates": rates, "draco_bits": args.draco_bits, "draco_level": args.draco_level,
                "tmc3": str(tmc3) if tmc3 else None,
                "samples": samples, "coders": coders, "models": models, "seconds": elapsed}
        args.json.write_text(json.dumps(_jsonable({"meta": meta, "runs": runs,
                                                   "targets": targets}), indent=1))
    if args.plot:
        plot(runs, args.plot)
    return 0


if __name__ == "__main__":
    sys.exit(main())
