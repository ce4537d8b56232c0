"""``surfidx ingest``, ``query``, ``get``, ``ls``, ``show``, ``errors``, ``redescribe``, ``rm``,
``rename``, ``tag``, ``untag``, ``upgrade`` and ``datasette-metadata``: the model database, each a thin
layer over a :class:`surfidx.Database` method. Each takes ``--db PATH`` (``$SURFIDX_DB``) but
``datasette-metadata``, whose metadata fits any surfidx database.

The model processor (``surfidx.pipeline.process_model``) and the stream decoder
(``surfidx.codec.decode``) are imported when a command needs them; tests (and embedding
applications) inject others through the click context object:
``cli.main(args, obj={"processor": fn, "decoder": fn})`` (and ``"describer"``, the query's
:func:`surfidx.pipeline.describe_model`).
"""

from __future__ import annotations

import io
import re
from pathlib import Path

import click

from ..errors import DatabaseError, InputError, SurfidxError
from ..db.ann import DEFAULT_THRESHOLD
from ..describe.distance import DEFAULT_SHAPE_WEIGHT
from ..describe.partial import PARTIAL_SHARE, is_partial
from ..codec.options import DEFAULT_BITS_PER_SURFEL
from ..geometry.axes import UP_AXES
from ..progress import report
from .group import cli
from .common import (allow_outside_textures, common_options, echo_json, export_options,
                      options_file_option, outside_textures_option, plain, rate_option)

__all__ = ["ingest_command", "query", "get", "ls", "show", "errors", "redescribe_command",
           "parse_model_ref", "rm", "rename", "tag", "untag", "datasette_metadata_command",
           "topology_line", "echo_params", "upgrade"]


def _injected(key):
    ctx = click.get_current_context(silent=True)
    obj = ctx.find_root().obj if ctx is not None else None
    return obj.get(key) if isinstance(obj, dict) else None


def _processor():
    from ingest import resolve_processor

    return resolve_processor(_injected("processor"))


def _decoder():
    decoder = _injected("decoder")
    if decoder is not None:
        return decoder
    try:
        from ..codec import decode
    except ImportError as exc:
        raise SurfidxError(f"the stream decoder surfidx.codec.decode is not available ({exc})") \
            from exc
    return decode


def parse_model_ref(text: str):
    """``"id:12"`` or ``"12"`` → 12 (an id); anything else is a model name (str: a name for
    its latest version, ``NAME@N`` for version N, :meth:`surfidx.Database.resolve`)."""
    m = re.fullmatch(r"(?:id:)?(\d+)", text.strip())
    if m:
        return int(m.group(1))
    if text.startswith("id:"):
        raise InputError(f"{text!r} is not a model id; write id:N with an integer N")
    return text


def _open(db_path, console, *, readonly=True):
    """The database of a command: read-only (``ls``, ``show``, ``query``, ``get``, ``errors``:
    never written, a missing or empty file is an error), or for writing an existing one."""
    from ..database import Database

    console.detail(f"database {db_path}{' (read-only)' if readonly else ''}")
    return Database(db_path, create=False, readonly=readonly)


def _fmt(v, spec=".2f"):
    if v is None:
        return "-"
    if isinstance(v, float):
        return format(v, spec)
    return str(v)


def _table(rows, columns):
    """Print rows (dicts) as a fixed-width table with the given (key, header) columns (cells
    through :func:`plain`: a name holding a newline or an escape sequence stays in its cell)."""
    cells = [[plain(_fmt(r.get(k))) for k, _ in columns] for r in rows]
    widths = [max([len(h)] + [len(c[i]) for c in cells]) for i, (_, h) in enumerate(columns)]
    click.echo("  ".join(h.ljust(w) for (_, h), w in zip(columns, widths)).rstrip())
    for c in cells:
        click.echo("  ".join(v.ljust(w) for v, w in zip(c, widths)).rstrip())


# ---------------------------------------------------------------------- ingest
@cli.command("ingest")
@click.argument("paths", nargs=-1, required=True, type=click.Path())
@click.option("-j", "--workers", type=click.IntRange(min=1), default=None,
              help="Worker processes (of the local pool, or of --scheduler local); default: "
                   "as many as the machine's cores.")
@click.option("--scheduler", metavar="ADDRESS", default=None,
              help="Run the per-model work on a Dask cluster: tcp://HOST:PORT of a running "
                   "`dask scheduler`, or 'local' to start one with --workers worker processes "
                   "(needs surfidx[distributed]).")
@click.option("--retries", type=click.IntRange(min=0), default=2, show_default=True,
              help="With --scheduler: times a model whose worker died is re-run before it is "
                   "recorded as failed.")
@rate_option(help="Coding rate of the stored streams (default: the options file's, else "
                  f"{DEFAULT_BITS_PER_SURFEL:g}).")
@options_file_option
@click.option("--name", default=None,
              help="Name of the stored model (one file only; default: the file's stem, or when "
                   "another model has it the parent folder's name, then STEM-2, STEM-3...).")
@click.option("--tag", "tags", multiple=True, help="Tag every stored model (repeatable).")
@click.option("--replace", default=None, metavar="MODEL",
              help="Store the one file given as the next version of this stored model (NAME, "
                   "NAME@N or id:N). Without it, a changed file ingested again from the same "
                   "path becomes the next version of its model.")
@click.option("--keep-original", is_flag=True,
              help="Also store each new model's original files (the file, its MTL and "
                   "textures, glTF buffers), deduplicated by SHA-256; `get --original` writes "
                   "them back. Files over 512 MiB fail their model.")
@click.option("--up", default=None, metavar="AXIS",
              help=f"The models' up axis, shown upwards in their thumbnails: {', '.join(UP_AXES)} "
                   "(default: the options file's, else the format's: +y for meshes, +z for "
                   "scanners' point clouds).")
@outside_textures_option
@click.option("--no-progress", is_flag=True, hidden=True,
              help="Hide the progress bar (the old spelling; -q also hides the notes).")
@common_options(db=True)
def ingest_command(paths, workers, scheduler, retries, bits_per_surfel, options, name, tags,
                   replace, keep_original, up, no_progress, *, db_path, console):
    """Process model files and folders (recursively) into the database.

    Models already stored (same file and texture bytes) are skipped, so re-running an interrupted
    ingest resumes it. A file that fails is recorded (see `surfidx errors`) and the run goes on;
    so is a file that is not a regular file (a FIFO, a device, a link to one), skipped unread.
    An OBJ with UVs but no texture named gets <stem>_texture.png, <stem>.png or the folder's only
    PNG. With --scheduler the models are processed on a Dask cluster's workers (which need the
    package and read access to the paths); this process alone writes the database.
    Folders are searched for PLY, OBJ, OFF, STL, GLB/glTF, PCD, XYZ, PTS, LAS/LAZ and E57
    files; a folder with none is an error. The exit status is 1 when any file failed (what could be stored is).
    Without --workers, as many worker processes run as the machine has cores; the progress bar
    (on a terminal) moves within each model as its stages finish (per model with --scheduler).
    A model is a name with versions: a changed file ingested again from the same path (or
    with --replace NAME) is stored as the next version of its model, and commands that name a
    model use its latest version unless told NAME@N. Stored sources are paths relative to the
    folder given (the absolute path in the source_abs column).
    """
    import ingest

    from ..geometry.axes import check_up
    from ..options import ProcessOptions

    if up is not None:
        options = (options or ProcessOptions()).updated(up=check_up(up))
    console.detail(f"database {db_path}")
    # ingest.run (what Database.ingest runs for files) opens the database itself, after every
    # argument and the scheduler were checked: a bad call leaves no new file behind
    summary = ingest.run(list(paths), db=db_path, workers=workers,
                         bits_per_surfel=bits_per_surfel, options=options,
                         processor=_processor(),
                         progress=console.live and not no_progress, scheduler=scheduler,
                         retries=retries, name=name, tags=list(tags),
                         allow_outside_textures=allow_outside_textures(),
                         replace=None if replace is None else parse_model_ref(replace),
                         keep_original=keep_original)
    console.detail(f"stored ids: {', '.join(map(str, summary.ids)) or '-'}")
    if console.json:
        echo_json({"run": summary.run_id, "stored": summary.stored, "skipped": summary.skipped,
                   "failed": summary.failed, "ids": summary.ids, "seconds": summary.seconds,
                   "errors": [{"path": p, "error": e} for p, e in summary.errors],
                   "skips": [{"path": p, "reason": r} for p, r in summary.skips]})
        if summary.failed:
            raise click.exceptions.Exit(1)
        return
    for path, message in summary.skips:
        console.note(f"skipped: {path}: {message}")
    for path, message in summary.errors:
        line = message if message.startswith(path) else f"{path}: {message}"
        click.echo(plain(f"failed: {line}"), err=True)
    click.echo(plain(f"{db_path}: {summary}"))
    if summary.failed:
        raise click.ClickException(f"{summary.failed} file(s) failed (the others were stored); "
                                   "see `surfidx errors`")


# ---------------------------------------------------------------------- query
@cli.command()
@click.argument("example")
@click.option("-k", "k", type=click.IntRange(min=1), default=10, show_default=True,
              help="Number of results.")
@click.option("--shape-weight", type=click.FloatRange(0.0, 1.0), default=DEFAULT_SHAPE_WEIGHT,
              show_default=True,
              help="Weight w of shape against texture distance (1 = shape only).")
@click.option("--sheet", type=click.Path(dir_okay=False),
              help="Also draw the query and its results side by side into this PNG.")
@click.option("--include-self", is_flag=True,
              help="Keep the query model itself among the results when it is stored.")
@click.option("--exact", is_flag=True,
              help="Scan every stored model instead of using the approximate index (which "
                   f"is used from {DEFAULT_THRESHOLD:,} stored models on; its results are "
                   "re-ranked by the exact distance).")
@click.option("--tag", "tags", multiple=True,
              help="Only models with this tag (repeatable: all of them).")
@click.option("--where", default=None, metavar="FILTER",
              help="Only models passing this filter on their stored figures, e.g. "
                   "'surfels > 10000 and colour = true' (fields: surfels, colour, psnr_d1, "
                   "psnr_d2, psnr_y, bytes, bits_per_surfel, ingested_at, name, id).")
@click.option("--all-versions", is_flag=True,
              help="Compare with every stored version, not only each model's latest.")
@click.option("--partial/--complete", "partial", default=None,
              help="Compare EXAMPLE as a scan of part of an object (--partial) or as a complete "
                   "model (--complete); default: partial when the repair added more than "
                   f"{100 * PARTIAL_SHARE:g} % of its surface.")
@outside_textures_option
@options_file_option
@common_options(db=True)
def query(example, k, shape_weight, sheet, include_self, exact, tags, where, all_versions,
          partial, options, *, db_path, console):
    """Find the stored models most similar to EXAMPLE.

    EXAMPLE is a model file (mapped, resampled and described as an ingest would, nothing coded
    or stored), a stored model's NAME, or id:N. The query model itself is left out of the
    results when it is stored (--include-self keeps it). Distance: w*|shape difference| +
    (1-w)*|texture difference| when both have colour, else the shape difference alone (shape:
    the shape descriptor with the KLT spectrum appended). A partial scan (one view, a scan
    with holes: a large share of its closed surface added by the repair, or --partial) is
    compared by its views: what it holds seen from its camera, against each stored model's
    views (such a file is described by its views alone, without the spherical map, unless no stored model has views). A model file's stages are shown on stderr when it is a terminal (--quiet:
    never; --verbose: their times).
    """
    with _open(db_path, console) as db, console.progress() as progress:
        # a model file is described by surfidx.pipeline.describe_model (imported then), or
        # by the processor or describer the context object injects
        ex = db.example(example, processor=_injected("processor"),
                        describer=_injected("describer"), thumbnail=bool(sheet),
                        progress=progress, allow_outside_textures=allow_outside_textures(),
                        options=options, partial=partial)
        label, qthumb = ex.name, ex.thumbnail
        report(progress, "search", 0, 1)
        rows = db.query(ex, k=k, shape_weight=shape_weight, include_self=include_self,
                        exact=exact, tag=list(tags) or None, where=where,
                        partial=partial, all_versions=all_versions)
        if partial is None:
            partial = is_partial(ex.virtual_share)
        if partial:
            console.note(f"{label}: compared as a partial scan ({100 * ex.virtual_share:.0f} % "
                         "of its closed surface added by the repair)")
        if sheet:
            thumbs = [db.get_thumbnail(r["id"]) for r in rows]
            _contact_sheet(sheet, (label, qthumb), [(r, t) for r, t in zip(rows, thumbs)])
    if console.json:
        echo_json({"results": rows})
        return
    for rank, r in enumerate(rows, 1):
        r["rank"] = rank
        r["distance_s"] = f"{r['distance']:.6g}"
    _table(rows, [("rank", "rank"), ("id", "id"), ("name", "name"), ("version", "version"),
                  ("distance_s", "distance"), ("source", "source")])
    if sheet:
        console.note(f"{sheet}: query and {len(rows)} results")


def _contact_sheet(out, query_item, results, *, tile: int = 160, cols: int = 6):
    """Draw the query thumbnail and the results' thumbnails in a grid, captioned."""
    from PIL import Image, ImageDraw, ImageFont

    def picture(png):
        try:
            im = Image.open(io.BytesIO(png))
            im.load()
            im = im.convert("RGB")
        except Exception:
            im = Image.new("RGB", (tile, tile), (200, 200, 200))
        im.thumbnail((tile, tile))
        return im

    items = [(picture(query_item[1]), ["query", str(query_item[0])])]
    for rank, (row, png) in enumerate(results, 1):
        items.append((picture(png), [f"#{rank} id {row['id']} d={row['distance']:.4g}",
                                     str(row["name"])]))
    font = ImageFont.load_default()
    cap = 30
    ncols = min(cols, len(items))
    nrows = (len(items) + ncols - 1) // ncols
    sheet = Image.new("RGB", (ncols * tile, nrows * (tile + cap)), "white")
    draw = ImageDraw.Draw(sheet)
    for n, (im, lines) in enumerate(items):
        x, y = (n % ncols) * tile, (n // ncols) * (tile + cap)
        sheet.paste(im, (x + (tile - im.width) // 2, y + (tile - im.height) // 2))
        if n == 0:
            draw.rectangle([x, y, x + tile - 1, y + tile + cap - 1], outline=(200, 0, 0), width=2)
        for j, text in enumerate(lines):
            draw.text((x + 4, y + tile + 2 + 13 * j), text[:26], fill="black", font=font)
    sheet.save(out, format="PNG")


# ---------------------------------------------------------------------- get
@cli.command()
@click.argument("models", nargs=-1)
@click.option("--tag", "tags", multiple=True,
              help="Also every model with this tag (repeatable: all of them); -o is a folder.")
@click.option("--all", "every", is_flag=True, help="Every stored model; -o is a folder.")
@click.option("--thumbnails", is_flag=True,
              help="Write the models' stored thumbnails (NAME.png) instead of the models.")
@click.option("--original", is_flag=True,
              help="Write the original files kept by `ingest --keep-original` (the file, its "
                   "MTL and textures, byte for byte, in their layout) into the folder -o "
                   "names (several models: one subfolder each, NAME).")
@export_options(folder=True)
@common_options(db=True)
def get(models, tags, every, thumbnails, original, output, fmt, bits_per_surfel, level, mesh,
        max_surfels, max_vertices, text, texture, texture_size, image_format, image_quality, *,
        db_path, console):
    """Export stored models (ID, id:ID, NAME for its latest version or NAME@N): decoded to PLY,
    OBJ or GLB, or the stream as .sfz, optionally at a lower rate. One model goes to the file -o
    names; several (or --tag, --all, --thumbnails) go into the folder -o names, one file each,
    NAME.FORMAT (default GLB). --original writes the files the model was ingested from."""
    from .codec import output_summary

    if every and (models or tags):
        raise InputError("--all selects every model; give it without models or --tag")
    if not (models or tags or every):
        raise InputError("name a model (ID, id:ID or NAME), several, --tag T or --all")
    if original:
        return _get_original(models, tags, every, thumbnails, output, db_path, console)
    options = dict(bits_per_surfel=bits_per_surfel, level=level, mesh=mesh,
                   max_surfels=max_surfels, max_vertices=max_vertices, text=text,
                   texture=texture, texture_size=texture_size, image_format=image_format,
                   image_quality=image_quality)
    if len(models) == 1 and not (tags or every or thumbnails):
        if Path(output).is_dir():
            raise InputError(f"{output} is a folder; give a file to write one model to "
                             f"(a folder takes several models, --tag, --all or --thumbnails)")
        sfz = (fmt or Path(output).suffix).lower().endswith("sfz")
        with _open(db_path, console) as db, console.progress() as progress:
            report(progress, "write" if sfz else "decode", 0, 1)
            out = db.export(parse_model_ref(models[0]), output, format=fmt,
                            decoder=None if sfz else _decoder(), **options)
        if console.json:
            echo_json(out)
            return
        click.echo(plain(f"{output_summary(out)} (model {out['id']}, {out['name']})"))
        return
    if Path(output).exists() and not Path(output).is_dir():
        raise InputError(f"{output} is a file; several models go into a folder")
    fmt = fmt or "glb"
    with _open(db_path, console) as db:
        written, failed = db.export_many([parse_model_ref(m) for m in models] or None, output,
                                         tag=(list(tags) or None) if not every else None,
                                         format=fmt, thumbnails=thumbnails,
                                         **({} if thumbnails or fmt == "sfz"
                                            else {"decoder": _decoder()}),
                                         **({} if thumbnails else options))
    if console.json:
        echo_json({"written": written, "failed": [{"model": m, "error": e} for m, e in failed]})
    else:
        for rec in written:
            console.note(plain(f"{rec['output']} (model {rec['id']}, {rec['name']})"))
        click.echo(plain(f"{output}: {len(written)} written, {len(failed)} failed"))
        for m, e in failed:
            click.echo(plain(f"Error: {m}: {e}"), err=True)
    if failed:
        raise click.exceptions.Exit(1)


def _get_original(models, tags, every, thumbnails, output, db_path, console):
    """``get --original``: the original files of each model selected, into ``output``."""
    if thumbnails:
        raise InputError("give either --original or --thumbnails")
    if Path(output).exists() and not Path(output).is_dir():
        raise InputError(f"{output} is a file; --original writes into a folder")
    with _open(db_path, console) as db:
        ids = [db.resolve(parse_model_ref(m)) for m in models]
        if tags:
            ids += [r["id"] for r in db.list_models(tag=list(tags))]
        if every:
            ids = [r["id"] for r in db.list_models()]
        ids = list(dict.fromkeys(ids))
        if not ids:
            raise InputError("the selection names no stored model")
        single = len(ids) == 1 and len(models) == 1 and not (tags or every)
        out = [db.export_original(mid, output, subfolder=not single) for mid in ids]
    if console.json:
        echo_json(out[0] if single else {"written": out})
        return
    for rec in out:
        for f in rec["files"]:
            console.note(plain(f"{Path(rec['output']) / f['path']} ({f['bytes']:,} bytes)"))
        click.echo(plain(f"{rec['output']}: original of model {rec['id']} ({rec['name']}@"
                         f"{rec['version']}), {len(rec['files'])} file(s)"))


# ---------------------------------------------------------------------- ls, show, errors
@cli.command()
@click.option("--errors", "show_errors", is_flag=True, help="List ingest failures instead.")
@click.option("--tag", "tags", multiple=True, help="Only models with this tag (repeatable: all).")
@click.option("--name-like", default=None,
              help="Only models whose name matches this SQL LIKE pattern (%: any text).")
@click.option("--where", default=None, metavar="FILTER",
              help="Only models passing this filter on their stored figures (as for query).")
@click.option("--all-versions", is_flag=True,
              help="Every stored version, not only each model's latest.")
@common_options(db=True)
def ls(show_errors, tags, name_like, where, all_versions, *, db_path, console):
    """List the stored models, each by its latest version (or, with --errors, the ingest
    failures)."""
    if show_errors:
        return _print_errors(db_path, None, console)
    with _open(db_path, console) as db:
        rows = db.list_models(tag=list(tags) or None, name_like=name_like, where=where,
                              all_versions=all_versions)
    console.detail(f"{len(rows)} model(s)")
    if console.json:
        echo_json({"models": rows})
        return
    for r in rows:
        r["tags_s"] = ",".join(r["tags"]) or None
        # the number, and how many versions the name has when more than this one
        r["version_s"] = (str(r["version"]) if r["versions"] == 1
                          else f"{r['version']} ({r['versions']} stored)")
    _table(rows, [("id", "id"), ("name", "name"), ("version_s", "version"), ("tags_s", "tags"),
                  ("n_surfels", "surfels"),
                  ("has_color", "colour"), ("bytes", "bytes"), ("bits_per_surfel", "bits/surfel"),
                  ("psnr_d1", "PSNR D1"), ("psnr_y", "PSNR Y"), ("source", "source")])


@cli.command()
@click.argument("model")
@common_options(db=True)
def show(model, *, db_path, console):
    """One model's record (NAME: its latest version, NAME@N: version N), its provenance, asset
    figures, descriptors, original files and versions, and the last ingest run's errors."""
    with _open(db_path, console) as db:
        rec = db.get_model(parse_model_ref(model))
        rec["versions"] = db.versions(rec["id"])
        run = db.last_run()
        run_errors = db.errors(run["id"]) if run else []
    rec["bbox_min"], rec["bbox_max"] = rec["bbox"][0].tolist(), rec["bbox"][1].tolist()
    del rec["bbox"]
    out = {"model": rec, "last_run": None if run is None else {**run, "errors": run_errors}}
    if console.json:
        echo_json(out)
        return
    for key in ("id", "name", "version", "source", "source_abs", "content_hash", "source_bytes",
                "source_mtime", "n_surfels", "has_color", "bbox_min", "bbox_max", "ingested_at",
                "surfidx_version", "codec_version", "descriptor_version", "numerics_profile"):
        val = rec[key]
        if isinstance(val, list):
            val = " ".join(f"{x:.6g}" for x in val)
        click.echo(f"{key:16s} {plain(_fmt(val))}")
    click.echo(f"{'params':16s} {plain(echo_params(rec['params']))}")
    asset = rec["asset"] or {}
    for key in ("format_version", "bits_per_surfel", "bytes", "psnr_d1", "psnr_d2", "psnr_y"):
        click.echo(f"{key:16s} {_fmt(asset.get(key), '.4g')}")
    kinds = ", ".join(f"{k} ({d})" for k, d in rec["descriptors"].items()) or "-"
    click.echo(f"{'descriptors':16s} {plain(kinds)}")
    click.echo(f"{'topology':16s} {plain(topology_line(rec.get('topology')))}")
    files = rec["original"]
    click.echo(f"{'original':16s} " + (plain(", ".join(f"{f['path']} ({f['bytes']:,} bytes)"
                                                       for f in files)) if files else
                                       "not kept (ingest --keep-original keeps it)"))
    click.echo(f"{'versions':16s} {len(rec['versions'])}")
    for v in rec["versions"]:
        mark = "*" if v["id"] == rec["id"] else " "
        click.echo(plain(f" {mark}{v['version']:>4}  id {v['id']}  {v['ingested_at']}  "
                         f"{v['content_hash'][:12]}  {v['n_surfels']} surfels  "
                         f"{_fmt(v['bytes'])} bytes  original "
                         f"{'kept' if v['has_original'] else '-'}  {v['source']}"))
    if run is not None:
        click.echo(f"{'last run':16s} {run['id']} {run['status']}: stored {run['stored']}, "
                   f"skipped {run['skipped']}, failed {run['failed']}")
        for e in run_errors:
            click.echo(plain(f"  failed {e['path']}: {e['error']}"))


def topology_line(topology) -> str:
    """What topology repair added to a model, in one line (``stored as read`` when nothing)."""
    if not topology:
        return "stored as read (one closed genus-0 piece)"
    t = topology
    parts = f"{t.get('parts', 1)} part{'s' if t.get('parts', 1) != 1 else ''}"
    if t.get("parts_dropped"):
        parts += f" ({t['parts_dropped']} tiny dropped)"
    return (f"{parts}; holes filled {t.get('holes_filled', 0)}, handles cut "
            f"{t.get('handles_cut', 0)}, pinched vertices split {t.get('pinched_vertices', 0)}; "
            f"virtual {100 * float(t.get('virtual_area_share', 0.0)):.2f} % of the area "
            f"({t.get('virtual_surfels', 0)} surfels)")


def echo_params(params) -> str:
    """``params`` as compact JSON text."""
    import json

    return json.dumps(params, sort_keys=True, default=str)


@cli.command()
@click.option("--run", "run_id", type=int, default=None, help="Only this run's failures.")
@common_options(db=True)
def errors(run_id, *, db_path, console):
    """List the files ingest runs could not store, with their error messages."""
    _print_errors(db_path, run_id, console)


def _print_errors(db_path, run_id, console):
    with _open(db_path, console) as db:
        if run_id is not None and all(r["id"] != run_id for r in db.runs()):
            raise DatabaseError(f"no ingest run with id {run_id}", path=db_path)
        rows = db.errors(run_id)
    if console.json:
        echo_json({"errors": rows})
        return
    if not rows:
        click.echo("no ingest failures")
        return
    _table(rows, [("run_id", "run"), ("at", "at"), ("path", "path"), ("error", "error")])


@cli.command("redescribe")
@click.option("--all", "everything", is_flag=True,
              help="Recompute every model, not only those with outdated descriptors.")
@common_options(db=True)
def redescribe_command(everything, *, db_path, console):
    """Recompute stored descriptors from the stored assets (after an upgrade changed them)."""
    from ..pipeline import redescribe

    with _open(db_path, console, readonly=False) as db:
        out = redescribe(db, everything=everything)
    if console.json:
        echo_json(out)
        if out["failed"]:
            raise click.exceptions.Exit(1)
    else:
        click.echo(f"redescribed {out['redescribed']}, up to date {out['current']}, "
                   f"failed {len(out['failed'])}")
        for mid, msg in out["failed"].items():
            click.echo(plain(f"  failed id {mid}: {msg}"))
    if out["failed"]:
        raise click.ClickException(f"{len(out['failed'])} model(s) could not be redescribed")


# ---------------------------------------------------------------------- rm, rename, tag, untag
@cli.command()
@click.argument("models", nargs=-1, required=True)
@common_options(db=True)
def rm(models, *, db_path, console):
    """Remove stored models (NAME: every version; NAME@N, ID or id:ID: one version; several at
    once) with their assets, descriptors, thumbnails, tags and original files (and the blobs no
    other version holds); none is removed when one is not found."""
    with _open(db_path, console, readonly=False) as db:
        removed = db.remove(*[parse_model_ref(m) for m in models])
    if console.json:
        echo_json({"removed": removed})
        return
    for r in removed:
        click.echo(plain(f"removed model {r['id']} ({r['name']}@{r['version']})"))


@cli.command()
@click.argument("model")
@click.argument("new_name")
@common_options(db=True)
def rename(model, new_name, *, db_path, console):
    """Give a stored model (ID, id:ID or NAME) another name (names are unique)."""
    with _open(db_path, console, readonly=False) as db:
        out = db.rename(parse_model_ref(model), new_name)
    if console.json:
        echo_json(out)
        return
    click.echo(plain(f"model {out['id']}: {out['old_name']} -> {out['name']}"))


def _tag_command(name, method, verb):
    @cli.command(name, help=f"{method.capitalize()} a stored model (NAME: every version of "
                            f"it; NAME@N, ID or id:ID: one version): "
                            f"{'add' if method == 'tag' else 'remove'} the TAGS given.")
    @click.argument("model")
    @click.argument("tags", nargs=-1, required=True)
    @common_options(db=True)
    def command(model, tags, *, db_path, console):
        with _open(db_path, console, readonly=False) as db:
            ref = parse_model_ref(model)
            mid = db.resolve(ref)
            changed = getattr(db, method)(ref, list(tags))       # a name: every version
            now = db.tags(mid)
        if console.json:
            echo_json({"id": mid, verb: changed, "tags": now})
            return
        click.echo(plain(f"model {mid}: {verb} {changed}; tags: {', '.join(now) or '-'}"))

    return command


tag = _tag_command("tag", "tag", "added")
untag = _tag_command("untag", "untag", "removed")


# ---------------------------------------------------------------------- upgrade
@cli.command()
@common_options(db=True)
def upgrade(*, db_path, console):
    """Bring a database made by an older surfidx to this one's schema, in one transaction,
    after keeping a copy of the file as it was (NAME.schema-N.bak beside it). The read-only
    commands (ls, show, query, get) ask for it; the writing ones upgrade by themselves."""
    import warnings

    from ..database import Database
    from ..db.catalog import SCHEMA_VERSION

    console.detail(f"database {db_path}")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)        # said below
        with Database(db_path, create=False) as db:
            before, backup = db.upgraded_from, db.backup_path
    out = {"database": str(db_path), "schema_version": SCHEMA_VERSION, "upgraded_from": before,
           "backup": None if backup is None else str(backup)}
    if console.json:
        echo_json(out)
        return
    if before is None:
        click.echo(plain(f"{db_path}: schema version {SCHEMA_VERSION} already"))
    else:
        click.echo(plain(f"{db_path}: upgraded from schema version {before} to "
                         f"{SCHEMA_VERSION}; the file as it was is kept as {backup}"))


# ---------------------------------------------------------------------- datasette
@cli.command("datasette-metadata")
@click.option("-o", "--output", type=click.Path(dir_okay=False), default=None,
              help="Write it to this file instead of printing it.")
@common_options
def datasette_metadata_command(output, *, console):
    """Print the Datasette metadata of a surfidx database (titles, model names as the labels of
    model_id, browsing views). Use: surfidx datasette-metadata -o meta.json; datasette
    surfidx.db --metadata meta.json (thumbnails as images with datasette-render-images).
    The metadata is JSON already: --json changes only the line printed after writing it to
    a file."""
    import json

    from ..db.catalog import datasette_metadata
    from ..io import write_atomic

    console.detail("the metadata of surfidx/data/datasette.json (for any surfidx database)")
    text = json.dumps(datasette_metadata(), indent=2) + "\n"
    if output is None:
        click.echo(text, nl=False)
        return
    write_atomic(output, lambda tmp: tmp.write_text(text, encoding="utf-8"))
    if console.json:
        echo_json({"output": str(output), "bytes": len(text.encode("utf-8"))})
        return
    click.echo(plain(f"{output}: Datasette metadata"))
