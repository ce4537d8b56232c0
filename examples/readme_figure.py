"""The README's picture, made by surfidx itself: ``python examples/readme_figure.py``.

A database of the bundled models (``examples/models``) and a few coloured solids is queried with a
rotated, moved and rescaled copy of the armadillo (top row: the query and the stored thumbnails
of its nearest models, as ``surfidx query --sheet`` draws them); the bottom row is spot's one
stored stream served at rising rates, decoded and rendered with :func:`surfidx.render.render`.
About a minute on two cores. Writes ``docs/images/surfidx.png`` (``-o`` for another file).
"""

from __future__ import annotations

import argparse
import io
import tempfile
from pathlib import Path

import surfidx  # before numpy: the portable numerics profile for this process
from surfidx.numerics import use_portable_profile

use_portable_profile()

import numpy as np  # noqa: E402
import trimesh  # noqa: E402
from PIL import Image, ImageDraw, ImageFont  # noqa: E402

from surfidx.render import render  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
MODELS = ROOT / "examples" / "models"
TILE = 180
CAPTION = 34
RATES = (0.75, 1.0, 2.0, 4.0, 8.0)


def solids():
    """A few simple coloured shapes to fill the database (name -> trimesh.Trimesh).

    Each has a few hundred vertices at least: a stream at 8 bits/surfel must hold its header.
    """
    shapes = {
        "torus": trimesh.creation.torus(major_radius=1.0, minor_radius=0.35, major_sections=48,
                                        minor_sections=24),
        "capsule": trimesh.creation.capsule(height=1.5, radius=0.5, count=[24, 24]),
        "ball": trimesh.creation.icosphere(subdivisions=4),
        "cone": trimesh.creation.cone(radius=0.8, height=1.6, sections=48).subdivide().subdivide(),
    }
    colours = {"torus": (214, 120, 60), "capsule": (80, 140, 200), "ball": (120, 180, 90),
               "cone": (190, 90, 160)}
    for name, mesh in shapes.items():
        mesh.visual.vertex_colors = np.tile((*colours[name], 255), (len(mesh.vertices), 1))
    return shapes


def moved_armadillo(path: Path) -> None:
    """The armadillo rotated, moved and rescaled, written to ``path``."""
    s = surfidx.read_surfels(MODELS / "armadillo.obj")
    q, _ = np.linalg.qr(np.random.default_rng(7).normal(size=(3, 3)))
    surfidx.write_ply(s.transformed(rotation=q * np.sign(np.linalg.det(q)),
                                    translation=[1, 2, 3], scale=3.0), path)


def tile(image: Image.Image, lines, *, outline=None) -> Image.Image:
    """One picture in a white tile of TILE pixels, captioned below."""
    out = Image.new("RGB", (TILE, TILE + CAPTION), "white")
    image = image.convert("RGB")
    image.thumbnail((TILE, TILE))
    out.paste(image, ((TILE - image.width) // 2, (TILE - image.height) // 2))
    draw = ImageDraw.Draw(out)
    font = ImageFont.load_default()
    for j, text in enumerate(lines):
        draw.text((6, TILE + 3 + 14 * j), text, fill=(30, 30, 30), font=font)
    if outline:
        draw.rectangle([0, 0, TILE - 1, TILE + CAPTION - 1], outline=outline, width=2)
    return out


def row(title: str, tiles) -> Image.Image:
    """Tiles side by side under a title line."""
    head = 22
    out = Image.new("RGB", (TILE * len(tiles), head + TILE + CAPTION), "white")
    ImageDraw.Draw(out).text((6, 5), title, fill=(0, 0, 0), font=ImageFont.load_default())
    for n, t in enumerate(tiles):
        out.paste(t, (n * TILE, head))
    return out


def figure(db_path: Path, work: Path) -> Image.Image:
    """Build the database, query it and serve spot at several rates; the picture."""
    with surfidx.Database.open(db_path) as db:
        db.ingest([str(MODELS)], workers=2)
        for name, mesh in solids().items():
            if not db.list_models(name_like=name):
                db.ingest(mesh, name=name, tags=["solid"])
        query = work / "armadillo_moved.ply"
        moved_armadillo(query)
        example = db.example(str(query), thumbnail=True)
        hits = db.query(example, k=len(RATES) - 1)
        top = [tile(Image.open(io.BytesIO(example.thumbnail)), ["query: a moved copy",
                                                                "of the armadillo"],
                    outline=(200, 0, 0))]
        for rank, hit in enumerate(hits, 1):
            png = db.get_thumbnail(hit["id"])
            top.append(tile(Image.open(io.BytesIO(png)),
                            [f"#{rank} {hit['name'][:18]}", f"distance {hit['distance']:.3g}"]))
        spot = db.list_models(name_like="spot%")[0]
        reference = surfidx.read_surfels(spot["source_abs"],
                                         texture=MODELS / "spot" / "spot_texture.png")
        bottom = []
        for rate in RATES:
            decoded = db.get(spot["id"], bits_per_surfel=rate)
            size = len(db.get_sfz(spot["id"], bits_per_surfel=rate))
            quality = surfidx.evaluate(reference, decoded)
            picture = Image.fromarray(render(decoded, width=TILE, height=TILE,
                                             view=(-120.0, 15.0)))
            bottom.append(tile(picture, [f"{rate:g} bits/surfel, {size:,} B",
                                         f"D2 {quality['psnr_d2']:.1f} dB, "
                                         f"Y {quality['psnr_y']:.1f} dB"]))
    rows = [row("query by example (surfidx query FILE --sheet)", top),
            row("one stored stream, any rate (surfidx get spot --bits-per-surfel B)", bottom)]
    out = Image.new("RGB", (max(r.width for r in rows), sum(r.height for r in rows)), "white")
    y = 0
    for r in rows:
        out.paste(r, (0, y))
        y += r.height
    return out


def main(argv=None) -> None:
    """Write the picture (``-o``), with a database in a temporary folder unless ``--db``."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("-o", "--output", type=Path, default=ROOT / "docs" / "images"
                        / "surfidx.png")
    parser.add_argument("--db", type=Path, help="Database to build or reuse (default: temporary).")
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        picture = figure(args.db or Path(tmp) / "figure.db", Path(tmp))
    args.output.parent.mkdir(parents=True, exist_ok=True)
    picture.save(args.output, optimize=True)
    print(f"{args.output}: {picture.width}x{picture.height}")


if __name__ == "__main__":
    main()
