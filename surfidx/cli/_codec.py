"""``surfidx encode`` and ``surfidx decode``."""

from __future__ import annotations

import click

from . import cli
from ._common import command_errors, echo_json, input_options
from ._convert import outside_textures_option, read_model


@cli.command()
@click.argument("input", type=click.Path(dir_okay=False))
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False),
              help="The .sfz file to write.")
@click.option("--bits-per-surfel", "bits", type=float, required=True,
              help="Rate in bits per input surfel; the whole file is at most ceil(B·n/8) bytes.")
@click.option("--no-color", is_flag=True, help="Code geometry only.")
@click.option("--level", type=click.IntRange(0, 9), default=None,
              help="Icosahedral grid level (default: chosen from the surfel count).")
@click.option("--method", type=click.Choice(["tutte", "mds"]), default="tutte",
              help="Spherical map: fold-free Tutte with area balancing, or the original MDS.")
@click.option("--tangent-weight", type=float, default=None,
              help="Weight in (0, 1] of the tangential geometry details in local frames "
                   "(default 0.5).")
@click.option("--no-frames", is_flag=True, help="Code x, y, z details as they are (no local frames).")
@click.option("--density-weighting/--no-density-weighting", default=None,
              help="Weight coefficients by the input's surfel density on the sphere (default: "
                   "when the estimated gain is at least 1 dB).")
@input_options
@outside_textures_option
@click.option("--json", "as_json", is_flag=True, help="Print the figures as JSON.")
@command_errors
def encode(input, output, bits, no_color, level, method, tangent_weight, no_frames,
           density_weighting, texture, samples, allow_outside_textures, as_json):
    """Encode a model into an embedded .sfz bitstream."""
    from ..codec import TANGENT_WEIGHT, Encoder
    from ..io import write_atomic

    if no_frames and tangent_weight is not None:
        raise click.UsageError("--tangent-weight and --no-frames exclude each other")
    tw = None if no_frames else (TANGENT_WEIGHT if tangent_weight is None else tangent_weight)
    s = read_model(input, texture, samples, allow_outside_textures)
    enc = Encoder(s, level=level, color=False if no_color else None, method=method,
                  tangent_weight=tw, density_weighting=density_weighting)
    data = enc.encode(bits)
    write_atomic(output, lambda tmp: tmp.write_bytes(data))
    out = {"output": str(output), "surfels": len(s), "bytes": len(data),
           "bits_per_surfel": 8.0 * len(data) / len(s), "level": enc.level, "color": enc.color,
           "folded": enc.sphere_map.folded, "tangent_weight": enc.tangent_weight,
           "density_weighted": bool(enc.weight_field), "seconds": enc.setup_seconds}
    if as_json:
        echo_json(out)
    else:
        click.echo(f"{output}: {len(data)} bytes, {out['bits_per_surfel']:.3f} bits/surfel "
                   f"({len(s)} surfels, grid level {enc.level}{', colour' if enc.color else ''})")


@cli.command()
@click.argument("input", type=click.Path(dir_okay=False))
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False),
              help="Surfel PLY (or mesh PLY with --mesh) to write.")
@click.option("--bits-per-surfel", "bits", type=float, default=None,
              help="Decode only the prefix of the embedded stream that fits this rate.")
@click.option("--mesh", is_flag=True, help="Write a triangle mesh with the grid's connectivity.")
@click.option("--level", type=int, default=None,
              help="Grid level of the output (default: the stream's; lower: fewer surfels).")
@click.option("--max-surfels", type=click.IntRange(min=1), default=None,
              help="Refuse to decode to more surfels than this (default 2,621,442, the level-9 "
                   "grid); --level gives fewer.")
@command_errors
def decode(input, output, bits, mesh, level, max_surfels):
    """Decode a .sfz file (optionally at a lower rate) to PLY."""
    from ..codec import MAX_SURFELS, decode as _decode, read_sfz
    from ..io import write_ply

    data = read_sfz(input)
    model = _decode(data, bits_per_surfel=bits, mesh=mesh, level=level, path=input,
                    max_surfels=MAX_SURFELS if max_surfels is None else max_surfels)
    if mesh:
        _write_mesh(model, output)
        click.echo(f"{output}: mesh with {len(model.vertices)} vertices, {len(model.faces)} faces")
    else:
        write_ply(model, output)
        click.echo(f"{output}: {len(model)} surfels")


def _write_mesh(mesh, path):
    """A mesh PLY (every grid vertex is used, so surfel order equals vertex order)."""
    from ..io import write_ply

    write_ply(mesh.to_surfels(), path)
