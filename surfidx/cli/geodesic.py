"""``surfidx geodesic``: distance and shortest path between two surfels."""

from __future__ import annotations

import click

from .common import command_errors, echo_json, input_options, read_input
from .group import cli


@cli.command()
@click.argument("input", type=click.Path(dir_okay=False))
@click.option("--source", "source", required=True, type=int, help="Source surfel index.")
@click.option("--target", "target", required=True, type=int, help="Target surfel index.")
@click.option("--refine", is_flag=True, help="Straighten the graph path on the surface.")
@click.option("-o", "--output", type=click.Path(dir_okay=False), default=None,
              help="Write the path as a PLY (x y z float64 in path order, int surfel: -1 for "
                   "refined in-between points).")
@click.option("--max-angle", type=float, default=None,
              help="Largest normal angle (degrees) between linked surfels.")
@click.option("--bridge", is_flag=True, help="Join disconnected parts with straight links.")
@click.option("--json", "as_json", is_flag=True, help="Print JSON.")
@input_options
@command_errors
def geodesic(input, source, target, refine, output, max_angle, bridge, as_json, texture, samples):
    """Geodesic distance and path between surfels SOURCE and TARGET of INPUT.

    Surfel indices follow the input's order (for a mesh, its vertex order).
    """
    from ..geometry.geodesics import GeodesicSolver
    from ..geometry.graph import DEFAULT_MAX_ANGLE

    s = read_input(input, texture, samples)
    solver = GeodesicSolver(s, max_angle=DEFAULT_MAX_ANGLE if max_angle is None else max_angle,
                            bridge=bridge)
    path = solver.path(source, target, refine=refine)
    if output is not None:
        path.write_ply(output)
    if as_json:
        echo_json({"distance": path.length, "path": path.indices, "refined": bool(path.refined),
                   "points": int(len(path.points))})
        return
    click.echo(f"distance {path.length:.9g}")
    click.echo(f"refined  {'yes' if path.refined else 'no'} ({len(path.points)} points)")
    click.echo("path     " + " ".join(str(int(i)) for i in path.indices))
    if output is not None:
        click.echo(f"{output}: {len(path.points)} path points")

