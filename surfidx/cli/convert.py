"""``surfidx convert`` and ``surfidx info``."""

from __future__ import annotations

import warnings
from pathlib import Path

import click

from ..errors import SurfidxError
from .common import (allow_outside_textures, ascii_option, common_options, echo_json,
                      input_options, output_format_option, plain, reading)
from .group import cli

__all__ = ["convert", "info"]


@cli.command()
@click.argument("input", type=click.Path(dir_okay=False))
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False),
              help="File to write: .ply (surfels, binary little-endian), .obj or .glb.")
@output_format_option(formats=("ply", "obj", "glb"))
@input_options
@ascii_option
@common_options
def convert(input, output, fmt, texture, samples, text, *, console):
    """Convert a mesh or point cloud (PLY, OBJ, OFF, STL, glTF/GLB, PCD, XYZ, PTS, LAS/LAZ,
    E57) to surfels, written as PLY, OBJ or GLB."""
    from ..io import output_format, write_model
    from ..progress import report

    fmt = output_format(output, fmt)               # before reading: a bad suffix fails fast
    with console.progress() as progress:
        s = reading(progress, input, texture, samples)
        report(progress, "write", 0, 1)
        write_model(s, output, format=fmt, text=text)
    if console.json:
        echo_json({"input": str(input), "output": str(output), "format": fmt,
                   "surfels": len(s), "color": s.has_color})
        return
    click.echo(plain(f"{output}: {len(s)} surfels{' with colour' if s.has_color else ''}"))


@cli.command()
@click.argument("input", type=click.Path(dir_okay=False))
@input_options
@common_options
def info(input, texture, samples, *, console):
    """Surfel count, bounding box, colour and, for meshes, closedness, holes, pinched vertices,
    genus and pieces with what the repair before storing would add; for a .sfz stream, its
    container header and what it holds (parts, virtual patches, mask share)."""
    from ..progress import report

    with console.progress() as progress:
        if Path(input).suffix.lower() == ".sfz":
            report(progress, "read", 0, 1)
            out = _stream_info(input)
        else:
            s = reading(progress, input, texture, samples)
            lo, hi = s.bounds
            out = {"file": str(input), "surfels": len(s), "color": s.has_color,
                   "bbox_min": lo.tolist(), "bbox_max": hi.tolist(), "diagonal": s.diagonal,
                   "mean_radius": float(s.radii.mean())}
            mesh = _input_mesh(input, s)
            if mesh is not None:
                out.update(_mesh_info(*mesh))
            else:
                out["mesh"] = False
    _echo(out, console.json)


def _input_mesh(input, surfels):
    """``(vertices, faces)`` of the input mesh as the file has it (the surfels' own faces for a
    surfel PLY with faces), or None for points."""
    from ..io import MESH_SUFFIXES, read_mesh

    has_faces = surfels.faces is not None and len(surfels.faces) > 0
    if has_faces or Path(input).suffix.lower() in MESH_SUFFIXES:
        try:
            with warnings.catch_warnings():     # the surfels' read said them already
                warnings.simplefilter("ignore")
                m = read_mesh(input, allow_outside_textures=allow_outside_textures())
            return m.vertices, m.faces
        except SurfidxError:
            if not has_faces:
                return None
    return (surfels.positions, surfels.faces) if has_faces else None


def _mesh_info(vertices, faces) -> dict:
    """Closedness, holes, pinches, genus and pieces of a mesh (:func:`surfidx.topology.analysis`)
    and what the repair would add."""
    from ..geometry.mesh import TriangleMesh
    from ..topology import analyse

    topo = TriangleMesh(vertices, faces).topology()
    r = analyse(vertices, faces)
    return {"mesh": True, "faces": topo.faces, "closed": topo.closed,
            "components": topo.components, "boundary_edges": topo.boundary_edges,
            "nonmanifold_vertices": topo.nonmanifold_vertices, "euler": topo.euler,
            "genus": topo.genus, "holes": r.holes, "pinched_vertices": r.pinched_vertices,
            "nonmanifold_edges": r.nonmanifold_edges, "pieces": r.parts,
            "piece_genus": list(r.genus), "orientable": r.orientable,
            "storable": r.orientable, "stored_as_read": r.is_sphere,
            "repair_holes_filled": r.holes if not r.is_sphere else 0,
            "repair_handles_cut": r.handles, "repair_pinched_split": r.pinched_vertices,
            "repair_patches": r.patches if not r.is_sphere else 0,
            "repair_parts": r.parts - r.parts_dropped, "repair_parts_dropped": r.parts_dropped}


def _stream_info(path) -> dict:
    """The container header of a .sfz file (of its first part), as the fields a user asks
    about, and what the file holds (:func:`surfidx.codec.stream_summary`): parts, holes and
    handle cuts coded as virtual regions, the mask's bytes and share of the file, the virtual
    share of the grid."""
    from ..codec import MAP_METHODS, check_header, read_sfz
    from ..codec.container import unpack, unpack_parts
    from ..geometry.icosphere import vertex_count

    data = read_sfz(path)
    parts = _parts_info(path, data)          # checks the outer header of a multi-part file
    header, stream = unpack(unpack_parts(data, path=path)[0], path=path)
    field = check_header(header, path=path)[2]
    n = sum(parts["part_surfels"])
    out = {"file": str(path), "format_version": data[4] if len(data) > 4 else header.version,
           "bytes": len(data), "input_surfels": n,
           "bits_per_surfel": 8.0 * len(data) / n if n else None,
           "grid_level": header.level,
           "grid_vertices": vertex_count(header.level), "color": header.color,
           "color_level": header.color_level if header.color_level is not None
           else (header.level if header.color else None),
           "color_passes": sum(header.schedule) if header.schedule else None,
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
    out.update(parts)
    return out


def _parts_info(path, data) -> dict:
    """:func:`surfidx.codec.stream_summary` of a file, as the fields ``info`` prints."""
    from ..codec import stream_summary

    s = stream_summary(data, path=path)
    return {"parts": s["parts"], "part_surfels": s["part_surfels"],
            "holes": sum(s["holes"]), "cuts": sum(s["cuts"]),
            "mask_bytes": sum(s["mask_bytes"]), "mask_share": s["mask_share"],
            "virtual_share": float(sum(v * n for v, n in zip(s["virtual_share"],
                                                              s["part_surfels"]))
                                   / max(sum(s["part_surfels"]), 1))}


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
    from ..geometry.mesh import TriangleMesh

    return TriangleMesh(surfels.positions, surfels.faces).topology()
