"""``surfidx encode`` and ``surfidx decode``."""

from __future__ import annotations

import click

from ..sphere.options import METHODS
from .common import (common_options, echo_json, export_options, input_options,
                      options_file_option, plain, rate_option)
from .group import cli

__all__ = ["encode", "decode", "output_summary"]


@cli.command()
@click.argument("input", type=click.Path(dir_okay=False))
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False),
              help="The .sfz file to write.")
@rate_option(dest="bits",
             help="Rate in bits per input surfel; the whole file is at most ceil(B·n/8) bytes "
                  "(required unless the --options file sets codec.bits_per_surfel).")
@click.option("--no-color", is_flag=True, help="Code geometry only.")
@click.option("--level", type=click.IntRange(0, 9), default=None,
              help="Icosahedral grid level (default: chosen from the surfel count).")
@click.option("--method", type=click.Choice(METHODS), default=None,
              help="Spherical map: fold-free Tutte with area balancing (default), or the "
                   "original MDS.")
@click.option("--tangent-weight", type=float, default=None,
              help="Weight in (0, 1] of the tangential geometry details in local frames "
                   "(default 0.5).")
@click.option("--no-frames", is_flag=True, help="Code x, y, z details as they are (no local frames).")
@click.option("--density-weighting/--no-density-weighting", default=None,
              help="Weight coefficients by the input's surfel density on the sphere (default: "
                   "when the estimated gain is at least 1 dB).")
@click.option("--color-importance", type=float, default=None,
              help="Weight of colour in the measure the coder maximises, PSNR_D2 + w * "
                   "PSNR_YUV (default 1).")
@click.option("--allocation", type=click.Choice(["rd", "fixed"]), default=None,
              help="Order of geometry and colour bit planes: by gain of that measure per bit "
                   "(rd, default) or plane by plane (fixed).")
@input_options
@options_file_option
@common_options
def encode(input, output, bits, no_color, level, method, tangent_weight, no_frames,
           density_weighting, color_importance, allocation, texture, samples, options, *,
           console):
    """Encode a model into an embedded .sfz bitstream.

    A mesh that is not one closed genus-0 piece is repaired first (surfidx.topology.read_model, that is
    surfidx.topology.repair_model: holes capped, handles cut, pinches split, tiny pieces
    dropped); the virtual patches are coded as a mask, so decoding gives back the open (or
    genus-g) surface, and each piece is one part of the file."""
    from dataclasses import replace

    from ..codec import PartsEncoder, stream_summary
    from ..codec.encoder import codec_options
    from ..io import write_atomic
    from ..topology import read_model
    from ..options import ProcessOptions
    from ..progress import report
    from .common import allow_outside_textures

    if no_frames and tangent_weight is not None:
        raise click.UsageError("--tangent-weight and --no-frames exclude each other")
    if bits is None and options is None:
        raise click.UsageError("Missing option '--bits-per-surfel' (or an --options file, "
                               "whose codec.bits_per_surfel is used).")
    opts = ProcessOptions.resolve(options, bits_per_surfel=bits, samples=samples, level=level,
                                  method=method)
    if no_frames:
        opts = replace(opts, codec=replace(opts.codec, tangent_weight=None))
    elif tangent_weight is not None:     # checked with the encoder's own message
        opts = replace(opts, codec=codec_options(opts.codec, tangent_weight=tangent_weight))
    if no_color:
        opts = opts.updated(**{"codec.color": False})
    if color_importance is not None:
        opts = opts.updated(**{"codec.color_importance": color_importance})
    if allocation is not None:
        opts = opts.updated(**{"codec.allocation": allocation})
    bits = opts.codec.bits_per_surfel
    with console.progress() as progress:
        report(progress, "read", 0, 1)
        model = read_model(input, texture=texture, samples=opts.samples, options=opts.repair,
                           allow_outside_textures=allow_outside_textures())
        report(progress, "read", 1, 1)
        parts = list(model.parts)
        fps = [model.face_patch(i) for i in range(len(parts))]
        dropped = model.parts_dropped
        pe = PartsEncoder(parts, options=opts.codec, map_options=opts.map,
                          density_weighting=density_weighting, progress=progress,
                          face_patches=fps, texture=model.texture)
        data = pe.encode(bits, progress=progress)
        report(progress, "write", 0, 1)
        write_atomic(output, lambda tmp: tmp.write_bytes(data))
    summary = stream_summary(data)
    enc = pe.encoders[0]
    n = pe.n_surfels
    out = {"output": str(output), "surfels": n, "bytes": len(data),
           "bits_per_surfel": 8.0 * len(data) / n,
           "level": enc.level if len(parts) == 1 else [e.level for e in pe.encoders],
           "color": enc.color, "folded": sum(e.sphere_map.folded for e in pe.encoders),
           "tangent_weight": enc.tangent_weight,
           "density_weighted": any(bool(e.weight_field) for e in pe.encoders),
           "seconds": enc.setup_seconds if len(parts) == 1 else
           [e.setup_seconds for e in pe.encoders],
           "parts": len(parts), "dropped_parts": dropped, "holes": sum(summary["holes"]),
           "cuts": sum(summary["cuts"]), "mask_bytes": sum(summary["mask_bytes"]),
           "mask_share": summary["mask_share"]}
    if console.json:
        echo_json(out)
    else:
        lv = enc.level if len(parts) == 1 else "/".join(str(e.level) for e in pe.encoders)
        extra = ""
        if len(parts) > 1 or out["mask_bytes"]:
            extra = (f"; {len(parts)} part{'s' if len(parts) > 1 else ''}, {out['holes']} "
                     f"holes, {out['cuts']} cuts, mask {out['mask_bytes']} bytes")
        click.echo(f"{output}: {len(data)} bytes, {out['bits_per_surfel']:.3f} bits/surfel "
                   f"({n} surfels, grid level {lv}{', colour' if enc.color else ''}{extra})")


def output_summary(out: dict) -> str:
    """The one line ``decode`` and ``get`` print about what they wrote."""
    rate = ("full rate" if out.get("bits_per_surfel") is None
            else f"{out['bits_per_surfel']:g} bits/surfel")
    if out["format"] == "sfz":
        return f"{out['output']}: {out['bytes']:,} bytes of stream at {rate}"
    what = f"{out['surfels']:,} surfels"
    if out.get("faces") is not None:
        what = f"mesh of {out['surfels']:,} vertices and {out['faces']:,} faces"
    level = "" if out.get("level") is None else f", grid level {out['level']}"
    if out.get("texture"):
        level += f", {out['texture']}² texture"
    return f"{out['output']}: {what} ({out['format'].upper()}{level}) at {rate}"


@cli.command()
@click.argument("input", type=click.Path(dir_okay=False))
@export_options
@click.option("--keep-virtual", is_flag=True,
              help="Keep the virtual patches topology repair added (the closed surface as "
                   "coded); by default they are dropped and handle cuts zipped again.")
@common_options
def decode(input, output, fmt, bits_per_surfel, level, mesh, max_surfels, max_vertices, text,
           texture, texture_size, image_format, image_quality, keep_virtual, *, console):
    """Decode a .sfz file (optionally at a lower rate) to PLY, OBJ or GLB, or cut it to a
    lower rate as a .sfz."""
    from ..codec import MAX_SURFELS, decode as _decode, max_file_bytes, read_sfz
    from ..codec.container import part_surfels, truncate, unpack_parts
    from ..io import output_format, write_atomic, write_model
    from ..io.texture import check_image_options
    from ..pipeline import export_texture, output_level
    from ..progress import report

    bits = bits_per_surfel
    fmt = output_format(output, fmt, allowed=("ply", "obj", "glb", "sfz"))
    image_format, image_quality = check_image_options(image_format, image_quality)
    out = {"input": str(input), "output": str(output), "format": fmt, "bits_per_surfel": bits}
    with console.progress() as progress:
        report(progress, "read", 0, 1)
        data = read_sfz(input)
        if fmt == "sfz":
            n = sum(part_surfels(p, path=input) for p in unpack_parts(data, path=input))
            cut = data if bits is None else truncate(data, max_file_bytes(bits, n), path=input)
            console.detail(f"{len(cut):,} of the stream's {len(data):,} bytes kept")
            report(progress, "write", 0, 1)
            write_atomic(output, lambda tmp: tmp.write_bytes(cut))
            out["bytes"] = len(cut)
        else:
            as_mesh = fmt in ("obj", "glb") if mesh is None else mesh
            textured = export_texture(texture, fmt=fmt, mesh=as_mesh, max_vertices=max_vertices,
                                      texture_size=texture_size)
            report(progress, "decode", 0, 1)
            model = _decode(data, bits_per_surfel=bits, mesh=as_mesh, level=level, path=input,
                            max_surfels=MAX_SURFELS if max_surfels is None else max_surfels,
                            keep_virtual=keep_virtual, max_vertices=max_vertices,
                            texture=textured, texture_size=texture_size)
            report(progress, "write", 0, 1)
            write_model(model, output, format=fmt, text=text, image_format=image_format,
                        image_quality=image_quality)
            image = getattr(model, "texture", None)
            if level is None:
                level = output_level(data, bits_per_surfel=bits, path=input)
            out.update({"surfels": len(model.vertices) if as_mesh else len(model),
                        "level": level, "faces": len(model.faces) if as_mesh else None,
                        "texture": None if image is None else int(image.shape[0])})
    if console.json:
        echo_json(out)
    else:
        click.echo(plain(output_summary(out)))
