"""Textured scans: surfidx against what a user would pick instead (a Draco mesh with UVs plus the
texture as a JPEG or WebP image), luma and geometry at equal total bytes.

For each textured model (the bundled spot, and the YCB banana and scissors of the shared data):

* **surfidx**: the model read and repaired as ``ingest`` reads it (``surfidx.topology.read_model``:
  one surfel per mesh vertex; a surface of higher genus cut at its handles, the cuts closed by
  virtual patches) and coded as ``ingest`` codes it (``surfidx.codec.PartsEncoder`` with the
  textured mesh as the colour source) at each rate, decoded as ``get`` decodes it, as a mesh with
  its colour as a texture (``decode(mesh=True, texture=True)``: the input's genus and holes
  restored). Bytes: the whole ``.sfz``.
* **Draco + image**: the mesh split at its UV seams (one vertex per vertex/UV pair, as a glTF
  holds it) and coded by Draco (DracoPy, compression level 10) with its texture coordinates, at
  position quantisation ``DRACO_BITS`` and UV quantisation ``UV_BITS``; the texture resized
  (Lanczos) to each of ``SIZES`` (those not above its own size) and written as JPEG (4:2:0) and
  WebP (method 6) at each of ``QUALITIES`` (``surfidx.io.texture.encode_image``). Bytes: the
  Draco file plus the image file (no container around them: this favours the baseline).

Measures, the same functions for every coder (``surfidx.geometry.metrics``):

* **Y dB**: :func:`~surfidx.geometry.metrics.psnr_luma_surface` of the decoded mesh against the
  original mesh and texture (``--samples`` points on each surface, each compared with the other's
  colour at its closest surface point, both directions, the worse; peak 255);
* **D2 dB**: symmetric point-to-plane PSNR (:class:`~surfidx.geometry.metrics.Reference`) between
  ``--samples`` uniform samples of the original surface and as many of the decoded one (peak:
  the original's bounding-box diagonal);
* **b/s**: total bits per input surfel (a vertex of the input mesh; the virtual surfels of a
  repaired model's patches not counted).

Pairing at a total budget of ``rate * surfels / 8`` bytes, per image format, two ways:

* **shape matched**: for each UV precision the cheapest Draco setting whose D2 is at least
  surfidx's at that rate, with the image (size, quality) that fits the remaining bytes, the
  pair with the best luma; "-" when none fits. The baseline buys no colour with shape.
* **best colour**: the (Draco setting, image) pair with the best luma within the budget,
  whatever its geometry (its D2 beside it).

**Texture alone, no geometry**: the ceiling of every codec that sends the colour as this
texture: the whole budget spent on the image alone (per format, each of ``ALONE_SIZES`` not
above the texture's own, at the highest quality 1 … 100 whose file fits, the best of them),
its luma measured on the original geometry. A surfidx luma above it would need colour coded
better than the image codec codes the texture itself.

Pairs are ranked by the luma expected from the two errors added (the image's on the original
geometry, the Draco setting's quantised positions and UVs with the original texture); the
chosen pair is then measured as decoded (quantised positions and UVs with the decoded image).

    python benchmarks/texture.py [--models spot ycb_banana] [--rates 1 2 3.56 8 16] [--markdown]

Needs the ``bench`` extra (DracoPy).
"""

from __future__ import annotations

import argparse
import io
import sys
import time
import warnings
from pathlib import Path

from surfidx.numerics import use_portable_profile

use_portable_profile()   # before numpy loads: the bytes the surfidx command makes

import numpy as np  # noqa: E402

from surfidx import TriangleMesh  # noqa: E402
from surfidx.errors import SurfidxError  # noqa: E402
from surfidx.geometry.metrics import Reference, psnr_luma_surface  # noqa: E402
from surfidx.io import read_mesh  # noqa: E402
from surfidx.io.texture import encode_image  # noqa: E402

from _draco import dracopy  # noqa: E402
from _markdown import Report, add_markdown_option  # noqa: E402
from _textured import parts_encoder, read_textured, real_surfels  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
DATA = REPO.parent / "shared" / "data" / "models"
#: name -> (path relative to the bundled examples or the shared data, texture or None)
MODELS = {"spot": (REPO / "examples" / "models" / "spot" / "spot_triangulated.obj",
                   REPO / "examples" / "models" / "spot" / "spot_texture.png"),
          "ycb_banana": ("ycb_banana/textured_simple_reoriented.obj", None),
          "ycb_scissors": ("ycb_scissors/textured_simple_reoriented.obj", None)}
#: The issue's range (1 … 16), and two rates above it where the baseline's mesh alone fits.
RATES = (1.0, 2.0, 3.56, 8.0, 16.0, 32.0, 64.0)
DRACO_BITS = tuple(range(6, 15))
UV_BITS = (8, 10, 12)
DRACO_LEVEL = 10
SIZES = (128, 256, 512, 1024, 2048)
ALONE_SIZES = (64, 96, 128, 192, 256, 384, 512, 768, 1024, 1536, 2048)
QUALITIES = (20, 40, 60, 80, 95)
FORMATS = ("jpeg", "webp")
TARGETS = {3.56: 36.0, 16.0: 42.0}   # the luma targets (dB) at these rates
SAMPLES = 50_000


# ---------------------------------------------------------------------- measuring
class Model:
    """A textured model, its surfels and the references every decoded mesh is measured against."""

    def __init__(self, name: str, data: Path, samples: int):
        path, texture = MODELS[name]
        path = Path(path) if Path(path).is_absolute() else data / path
        kw = {} if texture is None else {"texture": texture}
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            self.mesh = read_mesh(path, **kw)
        self.model = read_textured(path, texture)
        self.surfels = real_surfels(self.model)
        self.name, self.samples, self.n = name, samples, len(self.surfels)
        self.resized, self.files, self.lumas = {}, {}, {}   # image_alone's, across budgets
        self.reference = Reference(self.mesh.to_surfels(samples=samples))

    def psnr_d2(self, mesh: TriangleMesh) -> float:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            return self.reference.psnr_d2(mesh.to_surfels(samples=self.samples, seed=1))

    def psnr_y(self, mesh: TriangleMesh) -> float:
        return psnr_luma_surface(self.mesh, mesh, samples=self.samples)

    def rate(self, nbytes: int) -> float:
        return nbytes * 8 / self.n


def run_surfidx(model: Model, rates) -> list[dict]:
    from surfidx.codec import decode

    # as ingest codes it: colour sampled from the texture on its own grid
    enc = parts_encoder(model.model)
    rows = []
    for rate in rates:
        # the encoder's rate counts the virtual surfels too: the same bytes as the baselines'
        data = enc.encode(rate * model.n / enc.n_surfels)
        t0 = time.perf_counter()
        dec = decode(data, mesh=True, texture=True)
        t_dec = time.perf_counter() - t0
        rows.append({"target": rate, "bytes": len(data), "rate": model.rate(len(data)),
                     "y": model.psnr_y(dec), "d2": model.psnr_d2(dec), "dec_s": t_dec})
    return rows


def run_draco(model: Model) -> list[dict]:
    """Every Draco setting: bytes, D2, the luma its quantised positions and UVs leave with the
    original texture, and the decoded mesh (UVs, no image yet)."""
    DracoPy = dracopy()
    tm = model.mesh.to_trimesh()   # split at the UV seams: per-vertex texture coordinates
    verts = np.asarray(tm.vertices, np.float32)
    faces = np.asarray(tm.faces, np.uint32)
    uv = np.asarray(tm.visual.uv, np.float64)   # DracoPy asks float64 texture coordinates
    rows = []
    for q in DRACO_BITS:
        for tq in UV_BITS:
            data = DracoPy.encode(verts, faces, quantization_bits=q,
                                  compression_level=DRACO_LEVEL, tex_coord=uv,
                                  tex_coord_quantization_bits=tq)
            d = DracoPy.decode(data)
            f = np.asarray(d.faces, np.int64).reshape(-1, 3)
            dec_uv = np.asarray(d.tex_coord, np.float64).reshape(-1, 2)
            mesh = TriangleMesh(np.asarray(d.points, np.float64).reshape(-1, 3), f, uv=dec_uv,
                                uv_faces=f, texture=model.mesh.texture)
            rows.append({"setting": f"q{q}/uv{tq}", "bytes": len(data),
                         "rate": model.rate(len(data)), "d2": model.psnr_d2(mesh),
                         "y": model.psnr_y(mesh), "mesh": mesh})
    return rows


def run_images(model: Model) -> list[dict]:
    """Every image (format, size, quality): bytes, and luma on the original geometry."""
    from PIL import Image

    tex = model.mesh.texture
    h, w = tex.shape[:2]
    rows = []
    for size in SIZES:
        if size > max(h, w):
            continue
        small = _resized(tex, size)
        for fmt in FORMATS:
            for quality in QUALITIES:
                data = encode_image(small, image_format=fmt, image_quality=quality)
                with Image.open(io.BytesIO(data)) as im:
                    decoded = np.asarray(im.convert("RGB"))
                m = model.mesh
                on_original = TriangleMesh(m.vertices, m.faces, uv=m.uv, uv_faces=m.uv_faces,
                                           texture=decoded)
                rows.append({"format": fmt, "size": size, "quality": quality,
                             "bytes": len(data), "y": model.psnr_y(on_original),
                             "image": decoded})
    return rows


def _resized(texture: np.ndarray, size: int) -> np.ndarray:
    """The texture resized (Lanczos) so that its longer side is ``size``."""
    from PIL import Image

    h, w = texture.shape[:2]
    side = (max(1, round(w * size / max(h, w))), max(1, round(h * size / max(h, w))))
    if side == (w, h):
        return texture
    return np.asarray(Image.fromarray(texture, "RGB").resize(side, Image.LANCZOS))


def image_alone(model: Model, fmt: str, budget: float) -> dict | None:
    """The texture as one ``fmt`` image within ``budget`` bytes, no geometry (see the module
    docstring): per size the highest quality whose file fits (by bisection: a file grows with
    the quality), the size whose image reads the best luma on the original geometry. Files and
    lumas are kept on ``model`` for the next budget."""
    tex = model.mesh.texture
    best = None
    for size in ALONE_SIZES:
        if size > max(tex.shape[:2]) or len(_image_file(model, fmt, size, 1)) > budget:
            continue
        lo, hi, fit = 2, 100, 1
        while lo <= hi:
            q = (lo + hi) // 2
            if len(_image_file(model, fmt, size, q)) <= budget:
                lo, fit = q + 1, q
            else:
                hi = q - 1
        y = _image_luma(model, fmt, size, fit)
        if best is None or y > best["y"]:
            nbytes = len(_image_file(model, fmt, size, fit))
            best = {"y": y, "bytes": nbytes, "rate": model.rate(nbytes),
                    "setting": f"{size}² q{fit}"}
    return best


def _image_file(model: Model, fmt: str, size: int, quality: int) -> bytes:
    """The texture resized to ``size`` as a ``fmt`` file at ``quality`` (kept on ``model``)."""
    key = (fmt, size, quality)
    if key not in model.files:
        if size not in model.resized:
            model.resized[size] = _resized(model.mesh.texture, size)
        model.files[key] = encode_image(model.resized[size], image_format=fmt,
                                        image_quality=quality)
    return model.files[key]


def _image_luma(model: Model, fmt: str, size: int, quality: int) -> float:
    """Luma of :func:`_image_file`'s image on the original geometry (kept on ``model``)."""
    from PIL import Image

    key = (fmt, size, quality)
    if key not in model.lumas:
        with Image.open(io.BytesIO(_image_file(model, fmt, size, quality))) as im:
            decoded = np.asarray(im.convert("RGB"))
        m = model.mesh
        model.lumas[key] = model.psnr_y(TriangleMesh(m.vertices, m.faces, uv=m.uv,
                                                     uv_faces=m.uv_faces, texture=decoded))
    return model.lumas[key]


def pair(model: Model, draco: list[dict], images: list[dict], fmt: str, budget: float,
         d2_floor: float | None) -> dict | None:
    """The Draco setting and image of ``fmt`` within ``budget`` bytes (see the module
    docstring): shape matched when ``d2_floor`` is given, else the best colour."""
    imgs = [i for i in images if i["format"] == fmt]
    geometry = draco
    if d2_floor is not None:   # per UV precision, the cheapest positions as good as surfidx's
        geometry = []
        for uv_bits in {g["setting"].split("/")[1] for g in draco}:
            ok = [g for g in draco if g["setting"].endswith("/" + uv_bits)
                  and g["d2"] >= d2_floor]
            if ok:
                geometry.append(min(ok, key=lambda g: g["bytes"]))
    choices = [(g, i) for g in geometry for i in imgs if g["bytes"] + i["bytes"] <= budget]
    if not choices:
        return None
    g, i = max(choices, key=lambda c: (_joint_y(c[0]["y"], c[1]["y"]), c[0]["d2"],
                                       -c[0]["bytes"] - c[1]["bytes"]))
    m = g["mesh"]
    joint = TriangleMesh(m.vertices, m.faces, uv=m.uv, uv_faces=m.uv_faces, texture=i["image"])
    nbytes = g["bytes"] + i["bytes"]
    return {"setting": f"{g['setting']} + {i['size']}² q{i['quality']}", "bytes": nbytes,
            "rate": model.rate(nbytes), "y": model.psnr_y(joint), "d2": g["d2"]}


def _joint_y(y_geometry: float, y_image: float) -> float:
    """Luma PSNR expected of a Draco setting with an image: their errors' MSEs added (the UV
    and position quantisation's, measured with the original texture, and the image's, measured
    on the original geometry)."""
    mse = 10.0 ** (-y_geometry / 10.0) + 10.0 ** (-y_image / 10.0)
    return -10.0 * np.log10(mse)


# ---------------------------------------------------------------------- output
def _ceiling_note(name: str, ours: list[dict], ceiling: dict) -> str:
    """What the texture alone reads at the whole budget of each target rate of the issue
    (36 dB at 3.56 b/s, 42 dB at 16 b/s), beside surfidx."""
    parts = []
    for rate, target in TARGETS.items():
        got = {fmt: a for fmt in FORMATS for r, a in ceiling[fmt] if r == rate and a}
        mine = [r["y"] for r in ours if r["target"] == rate]
        if not got or not mine:
            continue
        fmt = max(got, key=lambda f: got[f]["y"])
        y = got[fmt]["y"]
        verdict = ("below the target, so no codec of this family (the model's colour sent as "
                   "this texture) can meet it at this rate") if y < target else "at or above it"
        parts.append(f"at {rate:g} b/s the texture alone ({fmt.upper()} {got[fmt]['setting']}, "
                     f"the whole budget, no geometry) reads Y {y:.2f} dB against the target "
                     f"{target:g} dB, {verdict}; surfidx {mine[0]:.2f} dB")
    return f"{name}: " + "; ".join(parts) + "." if parts else f"{name}: no target rate measured."


def _cells(r: dict | None) -> list[str]:
    if r is None:
        return ["-", "-", "-", "-"]
    return [f"{r['rate']:.2f}", f"{r['y']:.2f}", f"{r['d2']:.2f}", r.get("setting", "")]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--models", nargs="+", choices=sorted(MODELS),
                    default=["spot", "ycb_banana", "ycb_scissors"])
    ap.add_argument("--rates", nargs="+", type=float, default=list(RATES),
                    help="total bits per input surfel")
    ap.add_argument("--samples", type=int, default=SAMPLES,
                    help="points sampled on each surface by the metrics")
    ap.add_argument("--data", type=Path, default=DATA)
    add_markdown_option(ap, "texture")
    args = ap.parse_args(argv)
    report = Report(
        "texture", "Textured scans: surfidx against Draco + JPEG / WebP", args.markdown,
        note=f"Luma PSNR (Y, dB) against the original texture (psnr_luma_surface) and PSNR_D2 "
             f"(dB) against the original surface, {args.samples:,} points on each surface; "
             f"rates in total bits per input surfel (= input mesh vertex). Draco + image: "
             f"'shape matched' takes the cheapest Draco setting at least as good as surfidx's "
             f"D2 and spends the rest on the image; 'best colour' the pair with the best luma "
             f"in the budget.")
    rates = sorted(args.rates)
    for name in args.models:
        if not MODELS[name][1] and not args.data.is_dir():
            report.text(f"{name}: skipped, no shared data at {args.data}")
            continue
        model = Model(name, args.data, args.samples)
        tex = model.mesh.texture
        try:
            ours = run_surfidx(model, rates)
        except SurfidxError as exc:
            report.text(f"{name}: skipped, surfidx cannot code it as read ({exc})")
            continue
        summary = model.model.summary() if model.model.repaired else None
        if summary:
            report.text(f"{name}: repaired as ingest repairs it: {summary['parts']} part(s), "
                        f"genus {summary['genus_before']} before, {summary['handles_cut']} "
                        f"handle(s) cut, {summary['holes_filled']} hole(s) filled, "
                        f"{summary['virtual_surfels']:,} virtual surfels "
                        f"({summary['virtual_area_share']:.1%} of the area) not counted in "
                        f"the rate")
        draco = run_draco(model)
        images = run_images(model)
        rows = []
        ceiling = {fmt: [] for fmt in FORMATS}
        for r in ours:
            budget = r["target"] * model.n / 8
            line = [f"{r['target']:g}", f"{r['rate']:.2f}", f"{r['y']:.2f}", f"{r['d2']:.2f}"]
            for fmt in FORMATS:
                line += _cells(pair(model, draco, images, fmt, budget, r["d2"]))
            for fmt in FORMATS:
                line += _cells(pair(model, draco, images, fmt, budget, None))
            for fmt in FORMATS:
                alone = image_alone(model, fmt, budget)
                ceiling[fmt].append((r["target"], alone))
                line += ["-", "-"] if alone is None else [f"{alone['y']:.2f}", alone["setting"]]
            rows.append(line)
        head = ["b/s", "surfidx b/s", "surfidx Y", "surfidx D2"]
        for label in ("shape matched", "best colour"):
            for fmt in ("JPEG", "WebP"):
                head += [f"{fmt} {label} b/s", "Y", "D2", "setting"]
        for fmt in ("JPEG", "WebP"):
            head += [f"{fmt} texture alone, no geometry: Y", "setting"]
        report.table(head, rows, title=f"{name}: {model.n:,} surfels, texture "
                                       f"{tex.shape[1]}×{tex.shape[0]}")
        report.text(_ceiling_note(name, ours, ceiling))
        report.table(["Draco setting", "bytes", "b/s", "D2", "Y with the original texture"],
                     [[g["setting"], f"{g['bytes']:,}", f"{g['rate']:.2f}", f"{g['d2']:.2f}",
                       f"{g['y']:.2f}"] for g in draco],
                     title=f"{name}: Draco mesh with UVs alone")
        report.table(["image", "size", "quality", "bytes", "b/s", "Y on original geometry"],
                     [[i["format"], f"{i['size']}", f"{i['quality']}", f"{i['bytes']:,}",
                       f"{model.rate(i['bytes']):.2f}", f"{i['y']:.2f}"] for i in images],
                     title=f"{name}: texture images alone")
        s = model.surfels
        if s.faces is not None and s.has_color:
            flat = TriangleMesh(s.positions, s.faces, vertex_colors=s.colors)
            report.text(f"{name}: the input surfels' own colours (the texture averaged around "
                        f"each of the {model.n:,} vertices, uncoded) read "
                        f"Y {model.psnr_y(flat):.2f} dB; the original against itself resampled: "
                        f"D2 {model.psnr_d2(model.mesh):.2f} dB.")
    report.finish()
    return 0


if __name__ == "__main__":
    sys.exit(main())
