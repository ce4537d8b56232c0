"""``surfidx ingest``, ``query``, ``get``, ``ls``, ``show``, ``errors`` and ``redescribe``: the model
database.

The model processor (``surfidx.pipeline.process_model``) and the stream decoder
(``surfidx.codec.decode``) are imported when a command needs them; tests (and embedding
applications) inject others through the click context object:
``cli.main(args, obj={"processor": fn, "decoder": fn})``.
"""

from __future__ import annotations

import io
import re
from pathlib import Path

import click

from .._errors import DatabaseError, InputError, SurfidxError
from . import cli
from ._common import command_errors, echo_json, plain

__all__ = ["ingest_command", "query", "get", "ls", "show", "errors", "redescribe_command",
           "parse_model_ref"]

_DB_HELP = "Database file (default surfidx.db, or $SURFIDX_DB)."


def _db_option(func):
    return click.option("--db", "db_path", default="surfidx.db", envvar="SURFIDX_DB",
                        show_default=False, type=click.Path(dir_okay=False), help=_DB_HELP)(func)


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
    """``"id:12"`` or ``"12"`` → 12 (an id); anything else is a model name (str)."""
    m = re.fullmatch(r"(?:id:)?(\d+)", text.strip())
    if m:
        return int(m.group(1))
    if text.startswith("id:"):
        raise InputError(f"{text!r} is not a model id; write id:N with an integer N")
    return text


def _open(db_path, *, readonly=True):
    """The database of a command: read-only (``ls``, ``show``, ``query``, ``get``, ``errors``:
    never written, a missing or empty file is an error), or for writing an existing one."""
    from ..database import Database

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
@_db_option
@click.option("-j", "--workers", type=click.IntRange(min=1), default=1, show_default=True,
              help="Worker processes (of the local pool, or of --scheduler local).")
@click.option("--scheduler", metavar="ADDRESS", default=None,
              help="Run the per-model work on a Dask cluster: tcp://HOST:PORT of a running "
                   "`dask scheduler`, or 'local' to start one with --workers worker processes "
                   "(needs surfidx[distributed]).")
@click.option("--retries", type=click.IntRange(min=0), default=2, show_default=True,
              help="With --scheduler: times a model whose worker died is re-run before it is "
                   "recorded as failed.")
@click.option("--bits-per-surfel", type=click.FloatRange(min=0, min_open=True), default=8.0,
              show_default=True, help="Coding rate of the stored streams.")
@click.option("--no-progress", is_flag=True, help="Hide the progress bar.")
@click.option("--json", "as_json", is_flag=True, help="Print the summary as JSON.")
@command_errors
def ingest_command(paths, db_path, workers, scheduler, retries, bits_per_surfel, no_progress,
                   as_json):
    """Process model files and folders (recursively) into the database.

    Models already stored (same file and texture bytes) are skipped, so re-running an interrupted
    ingest resumes it. A file that fails is recorded (see `surfidx errors`) and the run goes on;
    so is a file that is not a regular file (a FIFO, a device, a link to one), skipped unread.
    An OBJ with UVs but no texture named gets <stem>_texture.png, <stem>.png or the folder's only
    PNG. With --scheduler the models are processed on a Dask cluster's workers (which need the
    package and read access to the paths); this process alone writes the database.
    """
    import ingest

    summary = ingest.run(list(paths), db=db_path, workers=workers,
                         bits_per_surfel=bits_per_surfel, processor=_processor(),
                         progress=not no_progress, scheduler=scheduler, retries=retries)
    if as_json:
        echo_json({"run": summary.run_id, "stored": summary.stored, "skipped": summary.skipped,
                   "failed": summary.failed, "ids": summary.ids, "seconds": summary.seconds,
                   "errors": [{"path": p, "error": e} for p, e in summary.errors],
                   "skips": [{"path": p, "reason": r} for p, r in summary.skips]})
        return
    for path, message in summary.skips:
        click.echo(plain(f"skipped: {path}: {message}"), err=True)
    for path, message in summary.errors:
        line = message if message.startswith(path) else f"{path}: {message}"
        click.echo(plain(f"failed: {line}"), err=True)
    click.echo(plain(f"{db_path}: {summary}"))


# ---------------------------------------------------------------------- query
@cli.command()
@click.argument("example")
@_db_option
@click.option("-k", "k", type=click.IntRange(min=1), default=10, show_default=True,
              help="Number of results.")
@click.option("--shape-weight", type=click.FloatRange(0.0, 1.0), default=0.7, show_default=True,
              help="Weight w of shape against texture distance (1 = shape only).")
@click.option("--sheet", type=click.Path(dir_okay=False),
              help="Also draw the query and its results side by side into this PNG.")
@click.option("--json", "as_json", is_flag=True, help="Print JSON.")
@command_errors
def query(example, db_path, k, shape_weight, sheet, as_json):
    """Find the stored models most similar to EXAMPLE.

    EXAMPLE is a model file (processed like an ingest, not stored) or id:N (a stored model).
    Distance: w*|shape difference| + (1-w)*|texture difference| when both have colour, else
    the shape difference alone (shape: the shape descriptor with the KLT spectrum appended).
    """
    from ..search import SearchIndex

    with _open(db_path) as db:
        if re.fullmatch(r"id:.*", example):
            qid = parse_model_ref(example)
            rec = db.get_model(qid)
            descriptors = db.get_descriptors(qid)
            label, qthumb, has_color = rec["name"], db.get_thumbnail(qid), rec["has_color"]
        else:
            import ingest

            path = Path(example)
            if not path.is_file():
                raise InputError("no such model file (give a file, or id:N for a stored model)",
                                 path=example)
            model = _processor()(str(path), bits_per_surfel=8.0,
                                 texture=ingest.find_texture(path))
            descriptors, label = dict(model.descriptors), model.name
            qthumb, has_color = model.thumbnail, model.has_color
        if not has_color:
            descriptors.pop("texture", None)
        ids, dist = SearchIndex(db).query(descriptors, k=k, shape_weight=shape_weight)
        rows = []
        for i, d in zip(ids.tolist(), dist.tolist()):
            rec = db.get_model(i)
            rows.append({"id": i, "name": rec["name"], "source": rec["source"], "distance": d})
        if sheet:
            thumbs = [db.get_thumbnail(r["id"]) for r in rows]
            _contact_sheet(sheet, (label, qthumb), [(r, t) for r, t in zip(rows, thumbs)])
    if as_json:
        echo_json({"results": rows})
        return
    for rank, r in enumerate(rows, 1):
        r["rank"] = rank
        r["distance_s"] = f"{r['distance']:.6g}"
    _table(rows, [("rank", "rank"), ("id", "id"), ("name", "name"), ("distance_s", "distance"),
                  ("source", "source")])
    if sheet:
        click.echo(plain(f"{sheet}: query and {len(rows)} results"), err=True)


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
@click.argument("model")
@_db_option
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False),
              help="Surfel PLY to write.")
@click.option("--bits-per-surfel", type=click.FloatRange(min=0, min_open=True), default=None,
              help="Decode only this rate's prefix of the stream (default: all of it).")
@click.option("--level", type=int, default=None,
              help="Grid level of the output (default: the stream's; lower: fewer surfels).")
@command_errors
def get(model, db_path, output, bits_per_surfel, level):
    """Decode a stored model (ID, id:ID or NAME) to a surfel PLY, optionally at a lower rate."""
    from ..io import write_ply

    with _open(db_path) as db:
        mid = db.resolve(parse_model_ref(model))
        stream = db.get_stream(mid)
        name = db.get_model(mid)["name"]
    options = {} if level is None else {"level": level}
    surfels = _decoder()(stream, bits_per_surfel=bits_per_surfel, **options)
    write_ply(surfels, output)
    rate = "full rate" if bits_per_surfel is None else f"{bits_per_surfel:g} bits/surfel"
    click.echo(plain(f"{output}: {len(surfels)} surfels of model {mid} ({name}) at {rate}"))


# ---------------------------------------------------------------------- ls, show, errors
@cli.command()
@_db_option
@click.option("--errors", "show_errors", is_flag=True, help="List ingest failures instead.")
@click.option("--json", "as_json", is_flag=True, help="Print JSON.")
@command_errors
def ls(db_path, show_errors, as_json):
    """List the stored models (or, with --errors, the ingest failures)."""
    if show_errors:
        return _print_errors(db_path, None, as_json)
    with _open(db_path) as db:
        rows = db.list_models()
    if as_json:
        echo_json({"models": rows})
        return
    _table(rows, [("id", "id"), ("name", "name"), ("n_surfels", "surfels"),
                  ("has_color", "colour"), ("bytes", "bytes"), ("bits_per_surfel", "bits/surfel"),
                  ("psnr_d1", "PSNR D1"), ("psnr_y", "PSNR Y"), ("source", "source")])


@cli.command()
@click.argument("model")
@_db_option
@click.option("--json", "as_json", is_flag=True, help="Print JSON.")
@command_errors
def show(model, db_path, as_json):
    """One model's record, asset figures and descriptors, and the last ingest run's errors."""
    with _open(db_path) as db:
        rec = db.get_model(parse_model_ref(model))
        run = db.last_run()
        run_errors = db.errors(run["id"]) if run else []
    rec["bbox_min"], rec["bbox_max"] = rec["bbox"][0].tolist(), rec["bbox"][1].tolist()
    del rec["bbox"]
    out = {"model": rec, "last_run": None if run is None else {**run, "errors": run_errors}}
    if as_json:
        echo_json(out)
        return
    for key in ("id", "name", "source", "content_hash", "n_surfels", "has_color", "bbox_min",
                "bbox_max", "ingested_at"):
        val = rec[key]
        if isinstance(val, list):
            val = " ".join(f"{x:.6g}" for x in val)
        click.echo(f"{key:16s} {plain(val)}")
    click.echo(f"{'params':16s} {plain(echo_params(rec['params']))}")
    asset = rec["asset"] or {}
    for key in ("format_version", "bits_per_surfel", "bytes", "psnr_d1", "psnr_d2", "psnr_y"):
        click.echo(f"{key:16s} {_fmt(asset.get(key), '.4g')}")
    kinds = ", ".join(f"{k} ({d})" for k, d in rec["descriptors"].items()) or "-"
    click.echo(f"{'descriptors':16s} {plain(kinds)}")
    if run is not None:
        click.echo(f"{'last run':16s} {run['id']} {run['status']}: stored {run['stored']}, "
                   f"skipped {run['skipped']}, failed {run['failed']}")
        for e in run_errors:
            click.echo(plain(f"  failed {e['path']}: {e['error']}"))


def echo_params(params) -> str:
    """``params`` as compact JSON text."""
    import json

    return json.dumps(params, sort_keys=True, default=str)


@cli.command()
@_db_option
@click.option("--run", "run_id", type=int, default=None, help="Only this run's failures.")
@click.option("--json", "as_json", is_flag=True, help="Print JSON.")
@command_errors
def errors(db_path, run_id, as_json):
    """List the files ingest runs could not store, with their error messages."""
    _print_errors(db_path, run_id, as_json)


def _print_errors(db_path, run_id, as_json):
    with _open(db_path) as db:
        if run_id is not None and all(r["id"] != run_id for r in db.runs()):
            raise DatabaseError(f"no ingest run with id {run_id}", path=db_path)
        rows = db.errors(run_id)
    if as_json:
        echo_json({"errors": rows})
        return
    if not rows:
        click.echo("no ingest failures")
        return
    _table(rows, [("run_id", "run"), ("at", "at"), ("path", "path"), ("error", "error")])


@cli.command("redescribe")
@_db_option
@click.option("--all", "everything", is_flag=True,
              help="Recompute every model, not only those with outdated descriptors.")
@click.option("--json", "as_json", is_flag=True, help="Print JSON.")
@command_errors
def redescribe_command(db_path, everything, as_json):
    """Recompute stored descriptors from the stored assets (after an upgrade changed them)."""
    from ..pipeline import redescribe

    with _open(db_path, readonly=False) as db:
        out = redescribe(db, everything=everything)
    if as_json:
        echo_json(out)
    else:
        click.echo(f"redescribed {out['redescribed']}, up to date {out['current']}, "
                   f"failed {len(out['failed'])}")
        for mid, msg in out["failed"].items():
            click.echo(plain(f"  failed id {mid}: {msg}"))
    if out["failed"]:
        raise click.ClickException(f"{len(out['failed'])} model(s) could not be redescribed")
