"""Browsing a model database in Datasette: the ``surfidx`` Datasette plugin.

Registered by the entry point ``[project.entry-points.datasette] surfidx = "surfidx.browse"``
(installed with ``pip install 'surfidx[browse]'``), so ``datasette shapes.db`` loads it by itself;
Datasette imports this module, ``import surfidx`` never does. In a surfidx database it

* shows the stored figures rounded (PSNR to 0.01 dB, rates to 0.001 bit per surfel, other reals
  to 6 significant digits) in tables, views and query results (:func:`render_cell`; the JSON and
  CSV exports keep every digit);
* shows each model's thumbnail (the ``thumbnail``/``png`` cells of the browsing views, and beside
  the name in ``models``), served by the route ``/-/surfidx/DB/ID.png``;
* offers each model as GLB from its row (a link beside the name in ``models`` and the row page,
  beside the id in ``model_gallery``): ``/-/surfidx/DB/ID.glb[?bits=B][&level=L]`` decodes the
  stored stream on request through :meth:`surfidx.database.Database.export` (as ``surfidx get ID -o
  NAME.glb --bits B --level L`` writes it), answered as ``model/gltf-binary`` with the model's
  name as the file name.

A request for a model that is not stored, in a database that is not a surfidx one, is answered
404; an id that is not an integer, a bad ``bits``/``level`` or a stored row that cannot be
decoded (damaged) 400, with the reason (never the server's path of the file). The cells are found by column name (``id``,
``model_id``, ``name``, ``thumbnail``, ``png``) and the models by id through
:class:`surfidx.database.Database`, so the plugin follows the schema as it changes.
"""

from __future__ import annotations

import asyncio
import math
import re
import tempfile
from pathlib import Path
from urllib.parse import quote

import markupsafe
from datasette import hookimpl
from datasette.utils import tilde_decode, tilde_encode
from datasette.utils.asgi import BadRequest, NotFound, Response

__all__ = ["render_cell", "register_routes", "model_glb", "model_png", "figure_text",
           "FIGURE_DECIMALS", "THUMBNAIL_HEIGHT"]

#: Decimals shown of the figures by column name; other reals get 6 significant digits.
FIGURE_DECIMALS = {"psnr_d1": 2, "psnr_d2": 2, "psnr_y": 2, "bits_per_surfel": 3,
                   "virtual_area_share": 3}

#: Height in CSS pixels of a thumbnail in a table cell.
THUMBNAIL_HEIGHT = 96

#: Cells holding a model's thumbnail PNG, by column name.
_THUMBNAIL_COLUMNS = ("thumbnail", "png")
_ID = re.compile(r"-?[0-9]{1,19}")


def figure_text(column: str, value: float) -> str:
    """A stored real as shown: :data:`FIGURE_DECIMALS` of ``column``, else 6 significant
    digits (NaN and infinities as Python writes them).

    Parameters
    ----------
    column : str
    value : float

    Returns
    -------
    str
    """
    if not math.isfinite(value):
        return str(value)
    places = FIGURE_DECIMALS.get(column)
    return f"{value:.{places}f}" if places is not None else f"{value:.6g}"


async def _is_surfidx(datasette, database: str) -> bool:
    """Whether a database of ``datasette`` is a surfidx one (its application id, or for a file
    made before the id existed its ``models`` and ``assets`` tables); remembered per instance."""
    from surfidx.db.catalog import APPLICATION_ID

    known = datasette.__dict__.setdefault("_surfidx_databases", {})
    if database not in known:
        try:
            db = datasette.get_database(database)
            app = (await db.execute("PRAGMA application_id")).first()[0]
            tables = set(await db.table_names())
        except Exception:                       # a database Datasette itself cannot read
            return False
        known[database] = app == APPLICATION_ID or {"models", "assets", "descriptors"} <= tables
    return known[database]


def _urls(datasette, database: str, model_id: int) -> tuple:
    base = f"/-/surfidx/{tilde_encode(database)}/{int(model_id)}"
    return datasette.urls.path(base + ".png"), datasette.urls.path(base + ".glb")


def _model_id(row, column: str, table):
    """The model id of a row when ``column`` is where the plugin adds its links, else None."""
    keys = set(row.keys())
    if table == "models" and column == "name" and "id" in keys:
        return row["id"]
    if table != "models" and column == "id" and "name" in keys and "model_id" not in keys:
        return row["id"]                        # model_gallery and views like it
    return None


def _thumb_id(row, column: str):
    """The model id of a thumbnail cell's row (a foreign key Datasette expanded to its label
    is a dict holding it)."""
    if column not in _THUMBNAIL_COLUMNS:
        return None
    keys = set(row.keys())
    got = row["model_id"] if "model_id" in keys else row["id"] if "id" in keys else None
    return got.get("value") if isinstance(got, dict) else got


@hookimpl(tryfirst=True)                  # before datasette-render-images' data URIs
def render_cell(row, value, column, table, database, datasette):
    """Rounded figures, thumbnails and the GLB link in a surfidx database's cells (see the
    module notes); None (Datasette's own rendering) elsewhere."""
    if not (isinstance(value, float) or column in _THUMBNAIL_COLUMNS
            or column in ("name", "id")):
        return None

    async def render():
        if not await _is_surfidx(datasette, database):
            return None
        if isinstance(value, float):
            if table is None and column not in FIGURE_DECIMALS:
                return None                     # a custom query's reals: as computed
            return figure_text(column, value)
        thumb = _thumb_id(row, column) if isinstance(value, bytes) else None
        if isinstance(thumb, int):
            png, glb = _urls(datasette, database, thumb)
            return markupsafe.Markup(
                f'<a href="{glb}" download><img src="{png}" height="{THUMBNAIL_HEIGHT}" '
                f'loading="lazy" alt="thumbnail of model {thumb}"></a>')
        mid = _model_id(row, column, table)
        if not isinstance(mid, int) or isinstance(mid, bool):
            return None
        png, glb = _urls(datasette, database, mid)
        text = markupsafe.escape(value)
        if table == "models":
            return markupsafe.Markup(
                f'<img src="{png}" height="{THUMBNAIL_HEIGHT}" loading="lazy" alt="" '
                f'style="vertical-align: middle"> {text} '
                f'<a href="{glb}" download class="surfidx-glb">GLB</a>')
        return markupsafe.Markup(f'{text} <a href="{glb}" download class="surfidx-glb">GLB</a>')

    return render


def _target(datasette, request) -> tuple:
    """The database file and model id a route names (NotFound / BadRequest otherwise)."""
    name = tilde_decode(request.url_vars["database"])
    try:
        db = datasette.get_database(name)
    except KeyError:
        raise NotFound(f"no database {name!r}") from None
    if db.path is None or db.is_memory:
        raise NotFound(f"database {name!r} is not a file")
    ref = request.url_vars["id"]
    if not _ID.fullmatch(ref):
        raise BadRequest(f"model id must be an integer, got {ref!r}")
    return name, Path(db.path), int(ref)


def _number(request, key: str, kind):
    text = request.args.get(key)
    if text is None or text == "":
        return None
    try:
        value = kind(text)
    except ValueError:
        raise BadRequest(f"{key} must be a{'n integer' if kind is int else ' number'}, "
                         f"got {text!r}") from None
    if kind is float and not (math.isfinite(value) and value > 0):
        raise BadRequest(f"{key} must be a positive number of bits per surfel, got {text!r}")
    return value


def _open(path: Path, name: str):
    """The surfidx database at ``path`` read-only, or NotFound when it is none."""
    from surfidx import Database, DatabaseError

    try:
        return Database.open(path, readonly=True, create=False)
    except DatabaseError as exc:
        if "damaged" in exc.reason:
            raise BadRequest(f"{name}: {exc.reason}") from None
        raise NotFound(f"{name}: not a surfidx database ({exc.reason})") from None


def _fail(exc, name: str, mid: int):
    """The HTTP error of a surfidx error about model ``mid``: 404 when it is not stored, 400
    when the request or the stored row is bad."""
    from surfidx import DatabaseError

    text = exc.reason                           # without the server's file path
    if isinstance(exc, DatabaseError) and re.search(r"\bno model\b|has no (stored stream|"
                                                   r"thumbnail)", text) \
            and "damaged" not in text:
        return NotFound(f"{name}: {text}")
    return BadRequest(f"{name}: model {mid}: {text}")


def model_glb(path, model_id: int, *, bits_per_surfel: float | None = None,
              level: int | None = None) -> tuple:
    """A stored model decoded to GLB bytes, as ``surfidx get ID -o NAME.glb`` writes it.

    Parameters
    ----------
    path : str or os.PathLike
        The database file (opened read-only).
    model_id : int
    bits_per_surfel : float, optional
        The stream truncated to this rate (default: all of it).
    level : int, optional
        Grid level (default: the stream's own).

    Returns
    -------
    name : str
        The model's name.
    data : bytes
        The GLB file.

    Raises
    ------
    surfidx.SurfidxError
        No such model, a bad rate or level, a stream that cannot be decoded.
    """
    from surfidx import Database

    with Database.open(path, readonly=True, create=False) as db:
        name = db.get_model(int(model_id))["name"]
        with tempfile.TemporaryDirectory(prefix="surfidx-glb-") as tmp:
            out = Path(tmp) / "model.glb"
            db.export(int(model_id), out, format="glb", bits_per_surfel=bits_per_surfel,
                      level=level)
            return name, out.read_bytes()


def model_png(path, model_id: int) -> bytes:
    """A stored model's thumbnail PNG (:meth:`surfidx.database.Database.get_thumbnail`).

    Raises
    ------
    surfidx.DatabaseError
        No such model or thumbnail.
    """
    from surfidx import Database

    with Database.open(path, readonly=True, create=False) as db:
        return db.get_thumbnail(int(model_id))


def _file_name(name: str, ext: str) -> str:
    """``Content-Disposition`` of a download named after a model (ASCII fallback and the
    UTF-8 name)."""
    plain = re.sub(r"[^A-Za-z0-9._-]+", "_", name).strip("._") or "model"
    return f"attachment; filename=\"{plain}.{ext}\"; filename*=UTF-8''{quote(name + '.' + ext, safe='')}"


async def _glb_view(datasette, request):
    from surfidx import SurfidxError

    name, path, mid = _target(datasette, request)
    bits = _number(request, "bits", float)
    level = _number(request, "level", int)
    _open(path, name).close()
    try:
        model, data = await asyncio.to_thread(model_glb, path, mid, bits_per_surfel=bits,
                                              level=level)
    except SurfidxError as exc:
        raise _fail(exc, name, mid) from None
    return Response(data, content_type="model/gltf-binary",
                    headers={"content-disposition": _file_name(model, "glb"),
                             "cache-control": "no-store"})


async def _png_view(datasette, request):
    from surfidx import SurfidxError

    name, path, mid = _target(datasette, request)
    _open(path, name).close()
    try:
        data = await asyncio.to_thread(model_png, path, mid)
    except SurfidxError as exc:
        raise _fail(exc, name, mid) from None
    return Response(data, content_type="image/png", headers={"cache-control": "no-store"})


@hookimpl
def register_routes(datasette):
    """``/-/surfidx/DB/ID.glb`` and ``/-/surfidx/DB/ID.png`` (see the module notes)."""
    return [
        (r"^/-/surfidx/(?P<database>[^/]+)/(?P<id>[^/]+)\.glb$", _glb_view),
        (r"^/-/surfidx/(?P<database>[^/]+)/(?P<id>[^/]+)\.png$", _png_view),
    ]
