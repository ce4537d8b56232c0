"""``surfidx eval`` (distortion measures) and ``surfidx render`` (splat renderer to PNG)."""

from __future__ import annotations

import math
import re

import click

from ..errors import InputError
from .common import (command_errors, echo_json, input_options, outside_textures_option, plain,
                      read_input)
from .group import cli

_EVAL_ORDER = ("psnr_d1", "psnr_d2", "psnr_y", "hausdorff", "rmse_d1", "rmse_d2", "peak",
               "n_reference", "n_test")


@cli.command("eval")
@click.argument("reference", type=click.Path(dir_okay=False))
@click.argument("test", type=click.Path(dir_okay=False))
@click.option("--peak", type=float, default=None,
              help="PSNR peak instead of the reference's bounding-box diagonal.")
@click.option("--json", "as_json", is_flag=True, help="Print JSON.")
@outside_textures_option
@command_errors
def eval_(reference, test, peak, as_json):
    """Distortion of TEST against REFERENCE: PSNR D1/D2, luma PSNR and Hausdorff.

    MPEG pc_error definitions, symmetric (the worse of the two directions); the peak is the
    reference's bounding-box diagonal, Hausdorff is relative to it. Zero error gives a PSNR of
    inf (Infinity in JSON); psnr_y is null/- when either model has no colour.
    """
    from ..geometry.metrics import evaluate

    res = evaluate(read_input(reference), read_input(test), peak=peak)
    if as_json:
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
              help="three-quarter (default), front, back, left, right, top, bottom, or "
                   "principal (along the model's smallest principal axis, as thumbnails).")
@click.option("--azimuth", type=float, default=None,
              help="Camera azimuth in degrees (0 = front, 90 = right); instead of --view.")
@click.option("--elevation", type=float, default=None,
              help="Camera elevation in degrees (90 = top); instead of --view.")
@click.option("--up", default="y", show_default=True,
              help="Model axis shown upwards: x, y, z, -x, -y or -z.")
@click.option("--size", default="800x800", show_default=True, help="Image size WIDTHxHEIGHT.")
@click.option("--path", "path_file", type=click.Path(dir_okay=False), default=None,
              help="PLY polyline (vertex x y z in order) to overlay, e.g. a geodesic path.")
@click.option("--supersample", type=int, default=2, show_default=True,
              help="Render at N times the size and average down (anti-aliasing).")
@input_options
@click.option("--json", "as_json", is_flag=True, help="Print JSON.")
@command_errors
def render_(input, output, view, azimuth, elevation, up, size, path_file, supersample, texture,
            samples, as_json):
    """Render a model to a PNG as lit, z-buffered disk splats (colours when present)."""
    from ..render import read_polyline, render, save_png

    width, height = _parse_size(size)
    if view is not None and (azimuth is not None or elevation is not None):
        raise InputError("give either --view or --azimuth/--elevation, not both")
    if azimuth is not None or elevation is not None:
        view = (azimuth or 0.0, elevation or 0.0)
    elif view is None:
        view = "three-quarter"
    path = read_polyline(path_file) if path_file is not None else None
    s = read_input(input, texture, samples)
    img = render(s, width=width, height=height, view=view, up=up, path_points=path,
                 supersample=supersample)
    save_png(img, output)
    if as_json:
        echo_json({"input": str(input), "output": str(output), "width": width, "height": height,
                   "surfels": len(s), "view": view})
        return
    click.echo(plain(f"{output}: {width}x{height}, {len(s)} surfels"))
