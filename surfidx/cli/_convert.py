"""``surfidx convert`` and ``surfidx info``."""

from __future__ import annotations

from pathlib import Path

import click

from ._common import (allow_outside_textures, command_errors, echo_json, input_options, plain,
                      read_input)
from ._group import cli

__all__ = ["convert", "info"]


@cli.command()
@click.argument("input", type=click.Path(dir_okay=False))
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False),
              help="File to write: .ply (surfels, binary little-endian), .obj or .glb.")
@click.option("--format", "fmt", type=click.Choice(["ply", "obj", "glb"], case_sensitive=False),
              default=None, help="Output format (default: from the output's suffix).")
@input_options
@click.option("--ascii", "text", is_flag=True, help="Write ASCII PLY instead of binary.")
@click.option("--json", "as_json", is_flag=True, help="Print JSON.")
@command_errors
def convert(input, output, fmt, texture, samples, text, as_json):
    """Convert a mesh or point cloud (PLY, OBJ, OFF, STL, glTF/GLB, PCD, XYZ, PTS) to surfels,
    written as PLY, OBJ or GLB."""
    from ..io import output_format, write_model

    fmt = output_format(output, fmt)               # before reading: a bad suffix fails fast
    s = read_input(input, texture, samples)
    write_model(s, output, format=fmt, text=text)
    if as_json:
        echo_json({"input": str(input), "output": str(output), "format": fmt,
                   "surfels": len(s), "color": s.has_color})
        return
    click.echo(plain(f"{output}: {len(s)} surfels{' with colour' if s.has_color else ''}"))


@cli.command()
@click.argument("input", type=click.Path(dir_okay=False))
@input_options
@click.option("--json", "as_json", is_flag=True, help="Print JSON.")
@command_errors
def info(input, texture, samples, as_json):
    """Surfel count, bounding box, colour and (for meshes) closedness and genus; for a .sfz
    stream, its container header."""
    from ..io import read_mesh

    if Path(input).suffix.lower() == ".sfz":
        _echo(_stream_info(input), as_json)
        return
    s = read_input(input, texture, samples)
    lo, hi = s.bounds
    out = {"file": str(input), "surfels": len(s), "color": s.has_color,
           "bbox_min": lo.tolist(), "bbox_max": hi.tolist(), "diagonal": s.diagonal,
           "mean_radius": float(s.radii.mean())}
    if Path(input).suffix.lower() in (".obj", ".off") or s.faces is not None:
        topo = read_mesh(input, allow_outside_textures=allow_outside_textures()).topology() \
            if s.faces is None else _topology_of(s)
        out.update({"mesh": True, "faces": topo.faces, "closed": topo.closed,
                    "components": topo.components, "boundary_edges": topo.boundary_edges,
                    "nonmanifold_vertices": topo.nonmanifold_vertices, "euler": topo.euler,
                    "genus": topo.genus})
    else:
        out["mesh"] = False
    _echo(out, as_json)


def _stream_info(path) -> dict:
    """The container header of a .sfz file, as the fields a user asks about."""
    from ..codec import MAP_METHODS, check_header, read_sfz
    from ..container import unpack
    from ..icosphere import vertex_count

    data = read_sfz(path)
    header, stream = unpack(data, path=path)
    field = check_header(header, path=path)[2]
    out = {"file": str(path), "format_version": header.version, "bytes": len(data),
           "input_surfels": header.n_surfels,
           "bits_per_surfel": 8.0 * len(data) / header.n_surfels if header.n_surfels else None,
           "grid_level": header.level,
           "grid_vertices": vertex_count(header.level), "color": header.color,
           "layers": header.layers, "stream_bytes": len(stream),
           "map_method": MAP_METHODS[header.map_method]
           if header.map_method < len(MAP_METHODS) else header.map_method,
           "local_frames": header.tangent_weight is not None,
           "tangent_weight": header.tangent_weight,
           "frame_anchors": list(header.anchors) if header.tangent_weight is not None else None,
           "density_weighted": bool(header.weight_field), "weight_field_level": None,
           "weight_field_bytes": len(header.weight_field)}
    if field is not None:
        out["weight_field_level"] = field[1]
    return out


def _echo(out: dict, as_json: bool) -> None:
    if as_json:
        echo_json(out)
        return
    for key, val in out.items():
        if isinstance(val, list):
            val = " ".join(f"{x:.6g}" for x in val)
        elif isinstance(val, float):
            val = f"{val:.6g}"
        elif val is None:
            val = "-"
        click.echo(f"{key:22s} {val}")


def _topology_of(surfels):
    from ..mesh import TriangleMesh

    return TriangleMesh(surfels.positions, surfels.faces).topology()
