"""``surfidx geodesic``: distance and shortest path between two surfels."""

from __future__ import annotations

import click

from .common import common_options, echo_json, input_options, reading
from .group import cli

__all__ = ["geodesic"]


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
@input_options
@common_options
def geodesic(input, source, target, refine, output, max_angle, bridge, texture, samples, *,
             console):
    """Geodesic distance and path between surfels SOURCE and TARGET of INPUT.

    Surfel indices follow the input's order (for a mesh, its vertex order).
    """
    from ..geometry.geodesics import GeodesicSolver
    from ..geometry.graph import DEFAULT_MAX_ANGLE
    from ..progress import report

    with console.progress() as progress:
        s = reading(progress, input, texture, samples)
        report(progress, "path", 0, 1)
        solver = GeodesicSolver(s, max_angle=DEFAULT_MAX_ANGLE if max_angle is None
                                else max_angle, bridge=bridge)
        path = solver.path(source, target, refine=refine)
        if output is not None:
            report(progress, "write", 0, 1)
            path.write_ply(output)
    console.detail(f"{len(s):,} surfels read; path of {len(path.indices)} surfels")
    if console.json:
        echo_json({"distance": path.length, "path": path.indices, "refined": bool(path.refined),
                   "points": int(len(path.points))})
        return
    click.echo(f"distance {path.length:.9g}")
    click.echo(f"refined  {'yes' if path.refined else 'no'} ({len(path.points)} points)")
    click.echo("path     " + " ".join(str(int(i)) for i in path.indices))
    if output is not None:
        click.echo(f"{output}: {len(path.points)} path points")
