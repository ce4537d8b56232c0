"""``surfidx parameterize`` and ``surfidx resample``: the spherical map and the grid reconstruction."""

from __future__ import annotations

import click

from ..sphere.options import METHODS
from .common import common_options, echo_json, input_options, reading
from .group import cli

__all__ = ["parameterize", "resample"]

_METHOD_HELP = "tutte: fold-free Tutte map with area balancing; mds: original spherical MDS."


@cli.command()
@click.argument("input", type=click.Path(dir_okay=False))
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False),
              help="Surfel PLY to write, with the sphere position as properties sx sy sz.")
@click.option("--method", type=click.Choice(METHODS), default=METHODS[0], show_default=True,
              help=_METHOD_HELP)
@click.option("--seed", type=int, default=0, show_default=True, help="Landmark seed.")
@input_options
@common_options
def parameterize(input, output, method, seed, texture, samples, *, console):
    """Map a closed genus-0 model onto the unit sphere."""
    from ..io import write_ply
    from ..progress import report
    from ..sphere import parameterize as run

    with console.progress() as progress:
        s = reading(progress, input, texture, samples)
        m = run(s, method=method, seed=seed, progress=progress)
        report(progress, "write", 0, 1)
        write_ply(s, output, extra={"sx": m.points[:, 0], "sy": m.points[:, 1],
                                    "sz": m.points[:, 2]})
    fig = {"file": str(input), "output": str(output), **m.figures()}
    if console.json:
        echo_json(fig)
        return
    click.echo(f"{output}: {len(s)} surfels on the sphere ({m.method}), "
               f"{m.folded}/{m.triangles} folded triangles ({100 * m.fold_fraction:.3f}%), "
               f"landmark stress {m.landmark_stress:.4f}, area distortion "
               f"{m.area_distortion:.3f}, {m.seconds:.2f} s")


@cli.command()
@click.argument("input", type=click.Path(dir_okay=False))
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False),
              help="PLY to write: grid surfels, or with --mesh the grid mesh as surfels with faces.")
@click.option("--level", type=click.IntRange(0, 9), default=None,
              help="Grid level (default: chosen from the surfel count).")
@click.option("--method", type=click.Choice(METHODS), default=METHODS[0], show_default=True,
              help=_METHOD_HELP)
@click.option("--mesh/--surfels", "as_mesh", default=False,
              help="Write the grid's triangle mesh, or its surfels (default).")
@input_options
@common_options
def resample(input, output, level, method, as_mesh, texture, samples, *, console):
    """Map a model to the sphere and write its uncompressed icosahedral-grid reconstruction."""
    from ..io import write_ply
    from ..progress import report
    from ..sphere import parameterize as run
    from ..codec.resample import grid_to_mesh, grid_to_surfels, resample as resample_grid

    with console.progress() as progress:
        s = reading(progress, input, texture, samples)
        m = run(s, method=method, stress=False, progress=progress)
        lev = m.grid_level if level is None else level
        report(progress, "resample", 0, 1)
        vals = resample_grid(s, m.points, lev)
        g = grid_to_surfels(vals, name=s.name)
        if as_mesh:
            g = grid_to_mesh(vals, name=s.name).to_surfels()
        report(progress, "write", 0, 1)
        write_ply(g, output)
    out = {"file": str(input), "output": str(output), "level": lev, "grid_vertices": len(vals),
           "mesh": as_mesh, "folded": m.folded, "fold_fraction": m.fold_fraction}
    if console.json:
        echo_json(out)
        return
    click.echo(f"{output}: level-{lev} grid, {len(vals)} vertices"
               f"{' (mesh)' if as_mesh else ''}; map folds {m.folded}/{m.triangles}")
