"""``surfidx eval`` (distortion measures) and ``surfidx render`` (splat renderer to PNG)."""

from __future__ import annotations

import math
import re

import click

from ..errors import InputError
from ..geometry.axes import UP_AXES
from .common import common_options, echo_json, input_options, plain, reading
from .group import cli

__all__ = ["eval_", "render_"]

_EVAL_ORDER = ("psnr_d1", "psnr_d2", "psnr_y", "hausdorff", "rmse_d1", "rmse_d2", "peak",
               "n_reference", "n_test")


@cli.command("eval")
@click.argument("reference", type=click.Path(dir_okay=False))
@click.argument("test", type=click.Path(dir_okay=False))
@click.option("--peak", type=float, default=None,
              help="PSNR peak instead of the reference's bounding-box diagonal.")
@click.option("--test-texture", type=click.Path(dir_okay=False), default=None,
              help="Texture image for a TEST OBJ whose UVs name none (--texture is "
                   "REFERENCE's).")
@input_options
@common_options
def eval_(reference, test, peak, test_texture, texture, samples, *, console):
    """Distortion of TEST against REFERENCE: PSNR D1/D2, luma PSNR and Hausdorff.

    MPEG pc_error definitions, symmetric (the worse of the two directions); the peak is the
    reference's bounding-box diagonal, Hausdorff is relative to it. Zero error gives a PSNR of
    inf (Infinity in JSON); psnr_y is null/- when either model has no colour. --texture and
    --samples say how REFERENCE is read (as by info and convert), --test-texture TEST's
    texture.
    """
    from ..geometry.metrics import evaluate
    from ..progress import report

    with console.progress() as progress:
        ref = reading(progress, reference, texture, samples)
        tst = reading(progress, test, test_texture)
        for role, path, s in (("reference", reference, ref), ("test", test, tst)):
            console.detail(f"{role} {path}: {len(s):,} surfels"
                           f"{', colour' if s.has_color else ', no colour'}")
        report(progress, "evaluate", 0, 1)
        res = evaluate(ref, tst, peak=peak)
    if console.json:
        echo_json(res)
        return
    for key in _EVAL_ORDER:
        val = res[key]
        if val is None:
            text = "-"
        elif isinstance(val, float):
            text = "inf" if math.isinf(val) else f"{val:.6g}"
        else:
            text = str(val)
        click.echo(f"{key:12s} {text}")


def _parse_size(text: str) -> tuple[int, int]:
    m = re.fullmatch(r"\s*(\d+)\s*(?:[xX]\s*(\d+)\s*)?", text)
    if not m:
        raise InputError(f"--size must be WIDTHxHEIGHT (e.g. 800x600) or one number, got {text!r}")
    w = int(m.group(1))
    h = int(m.group(2)) if m.group(2) else w
    if not (1 <= w <= 8192 and 1 <= h <= 8192):
        raise InputError(f"--size must lie between 1 and 8192 pixels per side, got {w}x{h}")
    return w, h


@cli.command("render")
@click.argument("input", type=click.Path(dir_okay=False))
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False),
              help="PNG file to write.")
@click.option("--view", default=None,
              help="three-quarter (default), front, back, left, right, top, bottom, "
                   "principal (along the model's smallest principal axis), or thumbnail (as "
                   "stored thumbnails: three-quarter, principal when the model is flat).")
@click.option("--azimuth", type=float, default=None,
              help="Camera azimuth in degrees (0 = front, 90 = right); instead of --view.")
@click.option("--elevation", type=float, default=None,
              help="Camera elevation in degrees (90 = top); instead of --view.")
@click.option("--up", default=None, metavar="AXIS",
              help=f"Model axis shown upwards: {', '.join(UP_AXES)} (default: the format's: +y "
                   "for meshes, +z for scanners' point clouds).")
@click.option("--size", default="800x800", show_default=True, help="Image size WIDTHxHEIGHT.")
@click.option("--path", "path_file", type=click.Path(dir_okay=False), default=None,
              help="PLY polyline (vertex x y z in order) to overlay, e.g. a geodesic path.")
@click.option("--supersample", type=int, default=2, show_default=True,
              help="Render at N times the size and average down (anti-aliasing).")
@input_options
@common_options
def render_(input, output, view, azimuth, elevation, up, size, path_file, supersample, texture,
            samples, *, console):
    """Render a model to a PNG as lit, z-buffered disk splats (colours when present)."""
    from ..io import up_axis
    from ..progress import report
    from ..render import read_polyline, render, save_png

    width, height = _parse_size(size)
    if view is not None and (azimuth is not None or elevation is not None):
        raise InputError("give either --view or --azimuth/--elevation, not both")
    if azimuth is not None or elevation is not None:
        view = (azimuth or 0.0, elevation or 0.0)
    elif view is None:
        view = "three-quarter"
    path = read_polyline(path_file) if path_file is not None else None
    with console.progress() as progress:
        s = reading(progress, input, texture, samples)
        report(progress, "render", 0, 1)
        img = render(s, width=width, height=height, view=view,
                     up=up_axis(input) if up is None else up, path_points=path,
                     supersample=supersample)
        report(progress, "write", 0, 1)
        save_png(img, output)
    if console.json:
        echo_json({"input": str(input), "output": str(output), "width": width, "height": height,
                   "surfels": len(s), "view": view})
        return
    click.echo(plain(f"{output}: {width}x{height}, {len(s)} surfels"))
