"""The SQLite model store: one file holding every model's record, compressed asset, descriptors and
thumbnail, plus the bookkeeping of bulk ingestion runs.

The schema is ``surfidx/data/schema.sql`` (package data; ``data_schema/schema.sql`` links to it):
plain tables with readable columns, foreign keys and indexes, so the file can be browsed as it is
with ``sqlite-utils`` or Datasette. The schema version is ``PRAGMA user_version``; opening an older
database runs the migration functions of :data:`MIGRATIONS` in one transaction; a database of a
newer surfidx raises :class:`DatabaseError`. The database runs in WAL mode, so readers
(``surfidx query``) see a consistent state while an ingest writes, and every model is written in
one transaction (never half a model).

Whose file it is
----------------
A surfidx database carries ``PRAGMA application_id`` = :data:`APPLICATION_ID` (``"SFDX"``).
Opening a file reads only; nothing is written to it (not even the journal mode) before it is
known to be a surfidx database or empty: a file with another application's id, or with tables
and no id, is refused. Databases made before the id existed are recognised by their own schema
(every table of :data:`TABLES`, the ``models`` columns) and their ``meta`` row
``schema_version`` equal to ``user_version``; they get the id with their next write. A database
opened with ``readonly=True`` is opened by SQLite read-only (``mode=ro``): it is never written,
a missing or empty (0-byte or schema-less) file is an error, not a new database.

Errors
------
Every ``sqlite3`` error (a damaged file, a read-only file or mount, a full disk, a lock held past
``timeout``, a constraint) is raised as :class:`DatabaseError` naming the file and the cause, in
one line; the transaction it happened in is rolled back.

Names from file names
---------------------
File names are text as the OS gives them (``os.fsdecode``: bytes that are not UTF-8 become lone
surrogates). They are stored through :func:`escape_name`, which is lossless and always valid
UTF-8: an undecodable byte is written ``\\xHH``, and a backslash that would otherwise start such
an escape (one followed by ``\\``, ``x`` or ``u``) is doubled; every other character, backslashes
included, is stored as it is. :func:`unescape_name` gives the OS text back
(``os.fsencode(unescape_name(s))`` are the original bytes).

Example
-------
>>> with Database("surfidx.db") as db:                                   # doctest: +SKIP
...     model_id = db.add(processed_model)
...     ids, matrix = db.descriptor_matrix("shape")
"""

from __future__ import annotations

import contextlib
import datetime as _dt
import functools
import json
import os
import re
import sqlite3

from importlib import resources
from pathlib import Path

import numpy as np

from ..errors import DatabaseError, InputError, SurfidxError
from ..validate import as_array

__all__ = ["Catalog", "QUALITY_KEYS", "SCHEMA_VERSION", "APPLICATION_ID", "schema_sql", "utc_now",
           "escape_name", "unescape_name", "storable_text", "is_storage_failure",
           "datasette_metadata", "MAX_ORIGINAL_BYTES", "PROVENANCE_COLUMNS", "LATEST_SQL"]

#: Schema version written to ``PRAGMA user_version`` by this surfidx (2: unique names, tags,
#: delete triggers that do not depend on the client's foreign-key setting, browsing views;
#: 3: ``model_topology``, what topology repair added to a model; 4: model versions and their
#: provenance columns, the source path relative to the ingest root beside ``source_abs``, the
#: original files of ``ingest --keep-original`` in ``blobs`` and ``original_files``).
SCHEMA_VERSION = 4

#: Largest original file ``ingest --keep-original`` stores (one blob per file, written and read
#: in pieces; SQLite's own limit on a value is 10^9 bytes).
MAX_ORIGINAL_BYTES = 2 ** 29

#: ``PRAGMA application_id`` of a surfidx database: the bytes ``b"SFDX"``.
APPLICATION_ID = int.from_bytes(b"SFDX", "big")

#: Largest model or run id SQLite can hold (a signed 64-bit integer).
_MAX_ID = 2 ** 63 - 1

#: Tables every surfidx database holds (used to tell a surfidx database from a foreign one).
TABLES = ("meta", "models", "assets", "descriptors", "thumbnails", "ingest_runs", "ingest_errors")

#: Migration functions: ``MIGRATIONS[k - 1](conn)`` upgrades a version-``k`` database to
#: version ``k + 1`` (so ``len(MIGRATIONS) == SCHEMA_VERSION - 1``). They run inside the
#: transaction :meth:`Database._migrate` opens and must leave the tables ``schema.sql`` creates.
MIGRATIONS: list = []

QUALITY_KEYS = ("psnr_d1", "psnr_d2", "psnr_y")
#: The ``models`` columns of schema versions 1 to 3 (what tells a surfidx database made before
#: the application id).
_LEGACY_MODEL_COLUMNS = ("id", "name", "source", "content_hash", "n_surfels", "has_color",
                         "bbox_min_x", "bbox_min_y", "bbox_min_z", "bbox_max_x", "bbox_max_y",
                         "bbox_max_z", "ingested_at", "params")
#: What each model version records of how it was made (schema 4).
PROVENANCE_COLUMNS = ("source_abs", "source_bytes", "source_mtime", "surfidx_version",
                      "codec_version", "descriptor_version", "numerics_profile")
_MODEL_COLUMNS = (*_LEGACY_MODEL_COLUMNS, "version", *PROVENANCE_COLUMNS)
#: A row that is the latest version of its name (``m`` is the ``models`` row).
LATEST_SQL = ("NOT EXISTS (SELECT 1 FROM models n WHERE n.name = m.name "
              "AND n.version > m.version)")
_VERSION_REF = re.compile(r"(?s)(.+)@([0-9]+)")


def schema_sql() -> str:
    """The SQL text that creates a current-version database (``surfidx/data/schema.sql``).

    Returns
    -------
    str
    """
    return resources.files("surfidx").joinpath("data", "schema.sql").read_text(encoding="utf-8")


def utc_now() -> str:
    """The current UTC time as ISO 8601 text with a ``Z`` suffix (the database's time format)."""
    now = _dt.datetime.now(_dt.timezone.utc).replace(tzinfo=None)
    return now.isoformat(timespec="milliseconds") + "Z"


_ESCAPE = re.compile(r"\\(?=[\\xu\ud800-\udfff])|[\ud800-\udfff]")
_SURROGATE = re.compile(r"[\ud800-\udfff]")
_UNESCAPE = re.compile(r"\\(\\|x[89a-f][0-9a-f]|ud[89a-f][0-9a-f]{2})")


def _escape_char(m) -> str:
    c = m.group()
    if c == "\\":
        return "\\\\"
    o = ord(c)
    return f"\\x{o - 0xDC00:02x}" if 0xDC80 <= o <= 0xDCFF else f"\\u{o:04x}"


def is_storage_failure(exc: BaseException) -> bool:
    """Whether ``exc`` is a database error that is no fault of the model being written
    (read-only, full disk, damaged file, lock): a bulk operation cannot go on, whereas a model
    the schema refuses (an integrity error) is one failed model."""
    cause = exc.__cause__
    return isinstance(cause, sqlite3.Error) and not isinstance(cause, sqlite3.IntegrityError)


def escape_name(name) -> str:
    """A file name or path as stored in the database: lossless, always valid UTF-8.

    Parameters
    ----------
    name : str or os.PathLike
        Text as the OS gives it (``os.fsdecode``: undecodable bytes are lone surrogates).

    Returns
    -------
    str
        ``name`` with each undecodable byte written ``\\xHH`` (other lone surrogates
        ``\\udXXX``) and each backslash followed by a backslash, ``x``, ``u`` or such a byte
        doubled; unchanged for every UTF-8 name without those backslashes. Inverse:
        :func:`unescape_name`.
    """
    text = os.fspath(name) if isinstance(name, os.PathLike) else str(name)
    if isinstance(text, bytes):
        text = os.fsdecode(text)
    return _ESCAPE.sub(_escape_char, text)


def unescape_name(text: str) -> str:
    """The OS text of a stored name (inverse of :func:`escape_name`).

    Parameters
    ----------
    text : str

    Returns
    -------
    str
        With lone surrogates for undecodable bytes, as ``os.fsdecode`` gives them:
        ``os.fsencode(unescape_name(escape_name(b)))`` is ``b`` for any bytes ``b``.
    """
    def one(m):
        t = m.group(1)
        if t == "\\":
            return t
        return chr(0xDC00 + int(t[1:], 16)) if t[0] == "x" else chr(int(t[1:], 16))

    return _UNESCAPE.sub(one, str(text))


def storable_text(text) -> str:
    """Message text as stored: lone surrogates (undecodable bytes of a file name inside a
    message) become ``\\xHH`` as in :func:`escape_name`; backslashes are kept (a message need
    not be lossless).

    Parameters
    ----------
    text : str

    Returns
    -------
    str
        Valid UTF-8 text.
    """
    return _SURROGATE.sub(lambda m: _escape_char(m), str(text))


def _kind_of_error(exc: sqlite3.Error) -> str:
    """The SQLite result code of ``exc`` by name (``"SQLITE_FULL"``...), or from its message
    when it carries none."""
    name = getattr(exc, "sqlite_errorname", None)
    if name:
        return name
    text = str(exc).lower()
    for needle, code in (("malformed", "SQLITE_CORRUPT"), ("not a database", "SQLITE_NOTADB"),
                         ("readonly", "SQLITE_READONLY"), ("read-only", "SQLITE_READONLY"),
                         ("disk is full", "SQLITE_FULL"), ("locked", "SQLITE_BUSY"),
                         ("busy", "SQLITE_BUSY"), ("unable to open", "SQLITE_CANTOPEN"),
                         ("disk i/o", "SQLITE_IOERR")):
        if needle in text:
            return code
    return "SQLITE_CONSTRAINT" if isinstance(exc, sqlite3.IntegrityError) else "SQLITE_ERROR"


def _sqlite_errors(method):
    """Raise the ``sqlite3.Error`` s of a :class:`Database` method as :class:`DatabaseError`."""
    @functools.wraps(method)
    def wrapper(self, *args, **kwargs):
        try:
            return method(self, *args, **kwargs)
        except sqlite3.Error as exc:
            raise self._error(exc) from exc

    return wrapper


def _map_sqlite_errors(cls):
    """Class decorator: every public method and property of ``cls`` raises the ``sqlite3``
    errors it meets as :class:`DatabaseError` (``transaction`` does so itself)."""
    for name, attr in list(vars(cls).items()):
        if name.startswith("_") or name in ("transaction", "close", "conn"):
            continue
        if isinstance(attr, property):
            setattr(cls, name, property(_sqlite_errors(attr.fget), doc=attr.__doc__))
        elif callable(attr) and not isinstance(attr, (staticmethod, classmethod)):
            setattr(cls, name, _sqlite_errors(attr))
    return cls


def connect(path: Path, mode: str, timeout: float) -> sqlite3.Connection:
    """Open ``path`` with SQLite's URI ``mode`` (``"ro"``, ``"rw"`` or ``"rwc"``); the one place
    surfidx connects (tests replace it to fake a read-only mount or a full disk)."""
    uri = Path(os.path.abspath(path)).as_uri() + f"?mode={mode}"
    return sqlite3.connect(uri, uri=True, timeout=timeout, isolation_level=None,
                           check_same_thread=False)


def split_statements(script: str):
    """Split an SQL script into complete statements (``sqlite3.complete_statement``)."""
    buf = ""
    for line in script.splitlines(keepends=True):
        buf += line
        if sqlite3.complete_statement(buf):
            stmt = buf.strip()
            buf = ""
            if stmt.rstrip(";").strip() and not all(
                    ln.strip().startswith("--") or not ln.strip() for ln in stmt.splitlines()):
                yield stmt
    if buf.strip() and not all(ln.strip().startswith("--") or not ln.strip()
                               for ln in buf.splitlines()):
        raise DatabaseError("schema.sql ends with an incomplete statement")  # pragma: no cover


def _create_missing(conn) -> None:
    """Run the statements of ``schema.sql`` that create a table, index, trigger or view the
    database lacks (the additive part of a migration: it leaves the objects ``schema.sql``
    creates)."""
    have = {r[0] for r in conn.execute("SELECT name FROM sqlite_master")}
    pattern = re.compile(r"CREATE\s+(?:UNIQUE\s+)?(?:TABLE|INDEX|TRIGGER|VIEW)\s+(\w+)", re.I)
    for stmt in split_statements(schema_sql()):
        m = pattern.search(stmt)
        if m and m.group(1) not in have:
            conn.execute(stmt)


def _free_name(conn, name: str, source, *, exclude=None) -> str:
    """``name`` if no model has it, else the parent folder's name of ``source`` (an absolute
    path, or None), else ``name-2``, ``name-3``, ... (the first free one); ``exclude`` is a model
    id that does not count."""
    def taken(n):
        row = conn.execute("SELECT id FROM models WHERE name = ?", (n,)).fetchone()
        return row is not None and row[0] != exclude

    if not taken(name):
        return name
    source = source or ""
    parent = escape_name(Path(unescape_name(source)).parent.name) if source.startswith("/") \
        else ""
    if parent and not taken(parent):
        return parent
    k = 2
    while taken(f"{name}-{k}"):
        k += 1
    return f"{name}-{k}"


def _v1_to_v2(conn) -> None:
    """Schema 1 → 2: models sharing a name are renamed as :meth:`Database.add` names them
    (the lowest id keeps it), the name index becomes unique, rows orphaned by deletes without
    foreign keys are removed, and the tags table, delete triggers and views are created."""
    rows = conn.execute("SELECT id, name, source FROM models WHERE name IN (SELECT name FROM "
                        "models GROUP BY name HAVING count(*) > 1) ORDER BY name, id").fetchall()
    seen = set()
    for mid, name, source in rows:
        if name not in seen:
            seen.add(name)
            continue
        conn.execute("UPDATE models SET name = ? WHERE id = ?",
                     (_free_name(conn, name, source, exclude=mid), mid))
    conn.execute("DROP INDEX IF EXISTS models_name")
    for table in ("assets", "descriptors", "thumbnails"):
        conn.execute(f"DELETE FROM {table} WHERE model_id NOT IN (SELECT id FROM models)")
    conn.execute("DELETE FROM ingest_errors WHERE run_id NOT IN (SELECT id FROM ingest_runs)")


MIGRATIONS.append(_v1_to_v2)


def _v2_to_v3(conn) -> None:
    """Schema 2 → 3: the ``model_topology`` table, and the delete trigger of ``models`` that
    also removes its rows (the old trigger is dropped and created as ``schema.sql`` has it)."""
    conn.execute("DROP TRIGGER IF EXISTS models_delete_rows")


MIGRATIONS.append(_v2_to_v3)


def _relative_sources(conn) -> dict:
    """``{id: source}`` of the models whose stored source is an absolute path: the path
    relative to the longest absolute folder an ingest run was given that holds it, else the
    file's name (the folder it was read from is its root)."""
    roots = set()
    for (paths,) in conn.execute("SELECT paths FROM ingest_runs"):
        try:
            roots.update(p.rstrip("/") for p in json.loads(paths)
                         if isinstance(p, str) and p.startswith("/") and p.rstrip("/"))
        except ValueError:
            continue
    roots = sorted(roots, key=len, reverse=True)
    out = {}
    for mid, source in conn.execute("SELECT id, source FROM models"):
        if not str(source).startswith("/"):
            continue
        root = next((r for r in roots if source.startswith(r + "/")), None)
        out[mid] = source[len(root) + 1:] if root else source.rsplit("/", 1)[-1]
    return out


def _v3_to_v4(conn) -> None:
    """Schema 3 → 4: ``models`` rebuilt as ``schema.sql`` has it (every row version 1; the
    stored absolute path moves to ``source_abs`` and ``source`` becomes the path relative to
    the ingest root, :func:`_relative_sources`; the surfidx, codec and descriptor versions and
    the numerics profile taken from the record's ``params`` and asset, NULL where they say
    nothing; file size and time unknown, NULL); the ``blobs`` and ``original_files`` tables.
    Runs with foreign keys off (:meth:`Catalog._migrate`), so rebuilding ``models`` touches no
    row that refers to it; the ids stay. Rows left behind by a client that deleted a model with
    foreign keys off and no trigger are removed (as in :func:`_v1_to_v2`)."""
    for (view,) in conn.execute("SELECT name FROM sqlite_master WHERE type = 'view'").fetchall():
        conn.execute(f'DROP VIEW "{view}"')
    conn.execute("DROP TRIGGER IF EXISTS models_delete_rows")
    relative = _relative_sources(conn)
    conn.execute("ALTER TABLE models RENAME TO models_schema3")
    create = re.compile(r"CREATE\s+TABLE\s+models\s*\(", re.I)
    conn.execute(next(s for s in split_statements(schema_sql()) if create.search(s)))
    assets = "assets" in {r[0] for r in conn.execute("SELECT name FROM sqlite_master")}
    legacy = ", ".join(_LEGACY_MODEL_COLUMNS)
    json_of = "CASE WHEN json_valid(o.params) THEN json_extract(o.params, '{}') END"
    conn.execute(
        f"INSERT INTO models ({legacy}, version, source_abs, surfidx_version, codec_version, "
        "descriptor_version, numerics_profile) "
        f"SELECT {', '.join('o.' + c for c in _LEGACY_MODEL_COLUMNS)}, 1, "
        "CASE WHEN o.source LIKE '/%' THEN o.source END, "
        f"{json_of.format('$.provenance.surfidx')}, "
        + ("(SELECT format_version FROM assets a WHERE a.model_id = o.id), " if assets else
           "NULL, ")
        + f"{json_of.format('$.descriptors.version')}, "
        f"{json_of.format('$.provenance.numerics_profile')} FROM models_schema3 o")
    conn.executemany("UPDATE models SET source = ? WHERE id = ?",
                     [(src, mid) for mid, src in relative.items()])
    conn.execute("DROP TABLE models_schema3")
    have = {r[0] for r in conn.execute("SELECT name FROM sqlite_master WHERE type = 'table'")}
    for table in ("assets", "descriptors", "thumbnails", "tags", "model_topology"):
        if table in have:
            conn.execute(f"DELETE FROM {table} WHERE model_id NOT IN (SELECT id FROM models)")
    conn.execute("DELETE FROM ingest_errors WHERE run_id NOT IN (SELECT id FROM ingest_runs)")


MIGRATIONS.append(_v3_to_v4)

_TOPOLOGY_COLUMNS = ("parts", "parts_dropped", "holes_filled", "handles_cut", "pinched_vertices",
                     "virtual_surfels", "virtual_area_share")


def _topology_row(topology, name):
    """The ``model_topology`` values of a record's ``topology`` dict (None: no row)."""
    if topology is None:
        return None
    if not isinstance(topology, dict):
        raise InputError(f"model {name!r}: topology must be a dict or None, got "
                         f"{type(topology).__name__}")
    vals = []
    for col in _TOPOLOGY_COLUMNS:
        v = topology.get(col, 1 if col == "parts" else 0)
        try:
            v = float(v) if col == "virtual_area_share" else int(v)
        except (TypeError, ValueError):
            raise InputError(f"model {name!r}: topology[{col!r}] must be a number, got "
                             f"{v!r}") from None
        ok = 0 <= v <= 1 if col == "virtual_area_share" else v >= (1 if col == "parts" else 0)
        if not ok:
            raise InputError(f"model {name!r}: topology[{col!r}] = {v!r} is out of range "
                             "(parts >= 1, counts >= 0, virtual_area_share in 0..1)")
        vals.append(v)
    return (*vals, _to_json(topology, f"model {name!r} topology"))


def _iso_utc(seconds: float) -> str:
    """A POSIX time as the database's ISO 8601 UTC text (microseconds, ``Z``)."""
    t = _dt.datetime.fromtimestamp(seconds, _dt.timezone.utc).replace(tzinfo=None)
    return t.isoformat(timespec="microseconds") + "Z"


def _text_or_none(value):
    return None if value is None else str(value)


def datasette_metadata() -> dict:
    """Datasette metadata for a surfidx database (``surfidx/data/datasette.json``): titles,
    the models' ``name`` as the label of every ``model_id``, and the browsing views.

    Returns
    -------
    dict
    """
    return json.loads(resources.files("surfidx").joinpath("data", "datasette.json")
                      .read_text(encoding="utf-8"))


def _json_default(o):
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, Path):
        return str(o)
    raise TypeError(f"{type(o).__name__} is not JSON serialisable")


_INSERT_DESCRIPTOR = ("INSERT INTO descriptors (model_id, kind, dimension, vector, convention) "
                      "VALUES (?, ?, ?, ?, ?)")


def _descriptor_rows(descriptors: dict, convention: str, label: str) -> list:
    """(kind, dimension, little-endian float32 bytes, convention) per descriptor, by kind;
    non-finite or non-vector values raise :class:`InputError` naming ``label``."""
    rows = []
    for kind, vec in sorted(descriptors.items()):
        v = as_array(vec, f"{label} descriptor {kind!r}", dtype=np.float32, shape=(None,))
        rows.append((str(kind), int(v.size), v.astype("<f4").tobytes(), convention))
    return rows


def _to_json(value, name: str) -> str:
    try:
        return json.dumps(value, default=_json_default, sort_keys=True, allow_nan=False)
    except (TypeError, ValueError) as exc:
        raise InputError(f"{name} must be JSON-serialisable ({exc})") from exc


@_map_sqlite_errors
class Catalog:
    """A surfidx model database (an SQLite file), built on ``sqlite_utils.Database``.

    Parameters
    ----------
    path : str or os.PathLike
        The database file.
    create : bool
        Create the file when it does not exist, and the schema in a new or empty file. With
        ``False`` a missing or empty file raises :class:`DatabaseError` (nothing is created).
    readonly : bool
        Open it read-only (SQLite ``mode=ro``): nothing is ever written, not even the schema of
        an empty file; a missing or empty file raises :class:`DatabaseError`.
    timeout : float
        Seconds to wait for a lock another process holds before raising :class:`DatabaseError`.

    Attributes
    ----------
    path : pathlib.Path
    readonly : bool
    upgraded_from : int or None
        The schema version this open upgraded the file from (None: nothing was upgraded).
    backup_path : pathlib.Path or None
        The copy of the file kept before that upgrade (:meth:`backup_name`).
    db : sqlite_utils.Database
        The underlying connection wrapper, for ad-hoc queries (``db.db["models"].rows``).

    Raises
    ------
    DatabaseError
        The file is missing or empty (``create=False`` or ``readonly``), is not an
        SQLite database, is damaged, belongs to another application, or was written by a newer
        surfidx (higher schema version).

    Notes
    -----
    Use it as a context manager (``with Database(path) as db:``) or call :meth:`close`. Writes
    are explicit transactions (:meth:`transaction`); the connection runs in autocommit mode
    otherwise. Matrices from :meth:`descriptor_matrix` are cached until this connection or any
    other connection writes (``PRAGMA data_version``). Every method raises the ``sqlite3``
    errors it meets as :class:`DatabaseError` (see the module's notes).
    """

    def __init__(self, path, *, create: bool = True, readonly: bool = False,
                 timeout: float = 30.0):
        self.path = Path(path)
        self.readonly = bool(readonly)
        self.timeout = float(timeout)
        self._conn = None
        self._needs_marker = False
        self.upgraded_from = None
        self.backup_path = None
        if self.path.is_dir():
            raise DatabaseError("is a directory, not a database file", path=self.path)
        if self.path.exists() and not self.path.is_file():     # SQLite would block on a FIFO
            raise DatabaseError("is not a regular file (a FIFO, device or socket), not a "
                                "database file", path=self.path)
        if not self.path.exists() and (not create or self.readonly):
            raise DatabaseError("no such database; create it with `surfidx ingest`",
                                path=self.path)
        self._create = bool(create) and not self.readonly
        if not self._create and self._is_empty_file():
            raise DatabaseError("is an empty file, not a surfidx database yet; create it with "
                                "`surfidx ingest`", path=self.path)
        mode = "ro" if self.readonly else "rwc" if create else "rw"
        try:
            conn = connect(self.path, mode, self.timeout)
        except sqlite3.Error as exc:
            raise DatabaseError(f"cannot open ({exc})", path=self.path) from exc
        self._conn = conn
        self._cache: dict = {}
        self._cache_version = None
        try:
            self._check_and_prepare()
        except BaseException:
            self._conn = None
            conn.close()
            raise

    def _is_empty_file(self) -> bool:
        """0 bytes and no write-ahead log with content: no database in it yet."""
        wal = self.path.with_name(self.path.name + "-wal")
        return self.path.stat().st_size == 0 and not (wal.exists() and wal.stat().st_size > 0)

    def _error(self, exc: sqlite3.Error) -> DatabaseError:
        """The :class:`DatabaseError` (one line: file, what happened, what to do) of an
        ``sqlite3`` error."""
        code = _kind_of_error(exc)
        if code.startswith("SQLITE_NOTADB"):
            text = f"not an SQLite database ({exc})"
        elif code.startswith("SQLITE_CORRUPT"):
            text = (f"the database file is damaged ({exc}); restore it from a backup, or save "
                    "what is left with `sqlite3 FILE .recover`")
        elif code.startswith("SQLITE_READONLY"):
            text = (f"cannot write: the database is read-only ({exc}); check the permissions of "
                    "the file and its folder, and that the disk is not mounted read-only")
        elif code.startswith("SQLITE_FULL"):
            text = (f"the disk is full ({exc}); the transaction was rolled back, free some space "
                    "and run the command again")
        elif code.startswith(("SQLITE_BUSY", "SQLITE_LOCKED")):
            text = (f"the database is locked by another process ({exc}) for longer than "
                    f"{self.timeout:g} s; run the command again when that one has finished")
        elif code.startswith("SQLITE_CANTOPEN"):
            text = f"cannot open ({exc})"
        elif code.startswith("SQLITE_IOERR"):
            text = f"input/output error ({exc}); check the disk"
        elif code.startswith("SQLITE_CONSTRAINT"):
            text = f"a record does not fit the schema ({exc})"
        else:
            text = f"SQLite error ({exc})"
        return DatabaseError(" ".join(text.split()), path=self.path)

    # ------------------------------------------------------------------ opening
    def _identify(self):
        """``(kind, version)`` with kind ``"surfidx"``, ``"legacy"`` (a surfidx database without
        the application id) or ``"empty"``; reads only. Raises for any other file."""
        conn = self._conn
        try:
            app_id = conn.execute("PRAGMA application_id").fetchone()[0]
            version = conn.execute("PRAGMA user_version").fetchone()[0]
            tables = {r[0] for r in conn.execute(
                "SELECT name FROM sqlite_master WHERE type = 'table'")}
        except sqlite3.Error as exc:
            raise self._error(exc) from exc
        tables = {t for t in tables if not t.startswith("sqlite_")}
        newer = DatabaseError(
            f"schema version {version} was written by a newer surfidx (this one reads up to "
            f"version {SCHEMA_VERSION}); upgrade surfidx", path=self.path)
        if app_id == APPLICATION_ID:
            if version > SCHEMA_VERSION:
                raise newer
            if version < 1 or not tables:
                raise DatabaseError(f"carries surfidx's application id but no schema "
                                    f"(user_version {version}, {len(tables)} tables); the file "
                                    "is damaged", path=self.path)
            return "surfidx", version
        if app_id != 0:
            raise DatabaseError(f"not a surfidx database (application_id "
                                f"0x{app_id & 0xFFFFFFFF:08x} is another application's); "
                                "choose another --db file", path=self.path)
        if not tables:
            if version > 0:
                raise DatabaseError(f"not a surfidx database (user_version {version} but no "
                                    "tables)", path=self.path)
            return "empty", 0
        if version == 0 or not self._is_legacy(tables, version):
            raise DatabaseError(
                "not a surfidx database (it holds other tables: "
                + ", ".join(sorted(tables)[:5]) + (", ..." if len(tables) > 5 else "")
                + "); choose another --db file", path=self.path)
        if version > SCHEMA_VERSION:
            raise newer
        return "legacy", version

    def _is_legacy(self, tables: set, version: int) -> bool:
        """A surfidx database made before the application id: every surfidx table, the
        ``models`` columns, and a ``meta`` row ``schema_version`` equal to ``user_version``."""
        if not set(TABLES) <= tables:
            return False
        conn = self._conn
        try:
            columns = {r[1] for r in conn.execute("PRAGMA table_info(models)")}
            row = conn.execute("SELECT value FROM meta WHERE key = 'schema_version'").fetchone()
        except sqlite3.OperationalError:            # meta without key/value: someone else's
            return False
        except sqlite3.Error as exc:
            raise self._error(exc) from exc
        return (set(_LEGACY_MODEL_COLUMNS) <= columns and row is not None
                and str(row[0]) == str(version))

    def _check_and_prepare(self) -> None:
        conn = self._conn
        kind, version = self._identify()
        try:
            conn.execute(f"PRAGMA busy_timeout = {int(self.timeout * 1000)}")
            conn.execute("PRAGMA foreign_keys = ON")
            if kind == "empty" and not self._create:
                raise DatabaseError("holds no surfidx schema yet (an empty SQLite file); "
                                    "create it with `surfidx ingest`", path=self.path)
            if self.readonly:
                conn.execute("PRAGMA query_only = ON")
                if version < SCHEMA_VERSION:
                    raise DatabaseError(
                        f"schema version {version} is older than this surfidx's "
                        f"({SCHEMA_VERSION}) and a read-only open cannot upgrade it; run "
                        "`surfidx upgrade` once (it keeps a copy of the file as it was)",
                        path=self.path)
                return
            # Known to be ours (or empty) from here on: writing is allowed.
            conn.execute("PRAGMA journal_mode = WAL")
        except sqlite3.Error as exc:
            raise self._error(exc) from exc
        self._needs_marker = kind == "legacy"
        if version < SCHEMA_VERSION:
            self._migrate()

    def _migrate(self) -> None:
        """Create the schema (empty file) or run the migrations, in one transaction.

        Before an existing database is upgraded, a copy of it as it is is written beside it
        (:meth:`_backup`): the older surfidx that made it still opens that. The migrations run
        with foreign keys off (a table rebuilt must not cascade into the rows that refer to
        it) and end with ``PRAGMA foreign_key_check``; any failure rolls everything back."""
        conn = self._conn
        before = conn.execute("PRAGMA user_version").fetchone()[0]
        backup = self._backup(before) if before > 0 else None
        try:
            conn.execute("PRAGMA foreign_keys = OFF")
            conn.execute("PRAGMA legacy_alter_table = ON")
            conn.execute("BEGIN IMMEDIATE")
        except sqlite3.Error as exc:
            raise self._error(exc) from exc
        try:
            # Re-read inside the write lock: another process may have done it meanwhile.
            version = conn.execute("PRAGMA user_version").fetchone()[0]
            if version == 0:
                for stmt in split_statements(schema_sql()):
                    conn.execute(stmt)
                from .. import __version__

                conn.executemany("INSERT INTO meta (key, value) VALUES (?, ?)",
                                 [("created_by", f"surfidx {__version__}"),
                                  ("created_at", utc_now())])
            else:
                for k in range(version, SCHEMA_VERSION):
                    MIGRATIONS[k - 1](conn)
                _create_missing(conn)
                broken = conn.execute("PRAGMA foreign_key_check").fetchone()
                if broken is not None:
                    raise sqlite3.IntegrityError(f"row {broken[1]} of table {broken[0]} refers "
                                                 f"to a missing row of {broken[2]}")
            conn.execute("INSERT OR REPLACE INTO meta (key, value) VALUES ('schema_version', ?)",
                         (str(SCHEMA_VERSION),))
            conn.execute(f"PRAGMA application_id = {APPLICATION_ID}")
            conn.execute(f"PRAGMA user_version = {int(SCHEMA_VERSION)}")
            conn.execute("COMMIT")
            self._needs_marker = False
        except BaseException as exc:
            self._rollback()
            if isinstance(exc, sqlite3.Error):
                raise DatabaseError(f"upgrading the schema to version {SCHEMA_VERSION} failed "
                                    f"({self._error(exc).reason}); the file is unchanged",
                                    path=self.path) from exc
            raise
        finally:
            try:
                conn.execute("PRAGMA legacy_alter_table = OFF")
                conn.execute("PRAGMA foreign_keys = ON")
            except sqlite3.Error:  # pragma: no cover - the connection is unusable anyway
                pass
        if not 0 < version < SCHEMA_VERSION:        # new, or upgraded meanwhile by another
            if backup is not None:
                with contextlib.suppress(OSError):
                    backup.unlink()
            return
        self.upgraded_from, self.backup_path = version, backup
        if backup is not None:
            import warnings

            warnings.warn(f"{self.path}: upgraded from schema version {version} to "
                          f"{SCHEMA_VERSION}; the file as it was is kept as {backup} (the older "
                          "surfidx that made it opens that one; delete it when not needed)",
                          UserWarning, stacklevel=4)

    def backup_name(self, version: int) -> Path:
        """Where :meth:`_backup` keeps the schema-``version`` file before an upgrade:
        ``NAME.schema-VERSION.bak`` beside it."""
        return self.path.with_name(f"{self.path.name}.schema-{int(version)}.bak")

    def _backup(self, version: int) -> Path:
        """Copy the database as it is (SQLite's online backup: consistent, WAL content
        included) to :meth:`backup_name`, through a temporary file renamed into place.

        Raises
        ------
        DatabaseError
            The copy cannot be written (full disk, read-only folder): nothing is upgraded.
        """
        import tempfile

        target = self.backup_name(version)
        tmp = None
        try:
            fd, name = tempfile.mkstemp(dir=target.parent, prefix=f".{target.name}.",
                                        suffix=".part")
            os.close(fd)
            tmp = Path(name)                # a fresh file of its own: no link is followed
            dest = sqlite3.connect(tmp)
            try:
                self._conn.backup(dest)
            finally:
                dest.close()
            os.replace(tmp, target)
        except (sqlite3.Error, OSError) as exc:
            if tmp is not None:
                with contextlib.suppress(OSError):
                    tmp.unlink()
            raise DatabaseError(f"schema version {version} must be upgraded to "
                                f"{SCHEMA_VERSION}, and the copy kept before that cannot be "
                                f"written to {target} ({exc}); free some space or make the "
                                "folder writable; the file is unchanged", path=self.path) \
                from exc
        return target

    def _rollback(self) -> None:
        """ROLLBACK if a transaction is open (SQLite may have rolled back already, e.g. after
        a full disk); an error of the rollback itself is not the one to report."""
        conn = self._conn
        if conn is not None and conn.in_transaction:
            try:
                conn.execute("ROLLBACK")
            except sqlite3.Error:  # pragma: no cover - the connection is unusable anyway
                pass

    # ------------------------------------------------------------------ lifecycle
    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    @property
    def db(self):
        """The ``sqlite_utils.Database`` of this connection (imported on first use: its import
        is slow, and a query does not need it)."""
        if getattr(self, "_sqlite_utils", None) is None:
            import sqlite_utils

            self._sqlite_utils = sqlite_utils.Database(self.conn)
        return self._sqlite_utils

    def close(self) -> None:
        """Close the connection (idempotent); after changes of models, first bring the
        approximate index beside the file up to date (:func:`surfidx.db.ann.update`)."""
        if self._conn is not None and getattr(self, "_index_dirty", False):
            self._index_dirty = False
            self._update_index()
        if self._conn is not None:
            self._conn.close()
            self._conn = None

    def __repr__(self):
        return f"Database({str(self.path)!r})"

    @property
    def conn(self) -> sqlite3.Connection:
        """The open ``sqlite3.Connection``."""
        if self._conn is None:
            raise DatabaseError("the database is closed", path=self.path)
        return self._conn

    @property
    def schema_version(self) -> int:
        """``PRAGMA user_version`` of the file."""
        return int(self.conn.execute("PRAGMA user_version").fetchone()[0])

    def damage(self, *, limit: int = 3) -> str | None:
        """What SQLite's ``PRAGMA quick_check`` finds wrong with the file, or None.

        quick_check reads every page once (b-tree structure, record formats, free list; not
        whether indexes match their tables): far cheaper than ``integrity_check``, yet it
        finds the damaged pages that make a lookup miss a row a scan still reads. Run when a
        run of writes starts (:meth:`check_intact`) and when a lookup finds nothing.

        Parameters
        ----------
        limit : int
            Most problems reported.

        Returns
        -------
        str or None
            The first problems, ``"; "``-joined; None when the check passes.
        """
        try:
            rows = [str(r[0]) for r in self.conn.execute(f"PRAGMA quick_check({int(limit)})")]
        except sqlite3.DatabaseError as exc:
            if _kind_of_error(exc).startswith(("SQLITE_CORRUPT", "SQLITE_NOTADB")):
                return str(exc)
            raise
        lines = [ln.strip() for r in rows for ln in r.splitlines()
                 if ln.strip() and not ln.startswith("***")]
        return None if lines == ["ok"] else "; ".join(lines[:limit])

    def check_intact(self) -> None:
        """Refuse a damaged file (:meth:`damage`) before writing into it.

        Raises
        ------
        DatabaseError
            Naming the problem SQLite found and the ways out (a backup, ``sqlite3 .recover``).
        """
        problem = self.damage()
        if problem is not None:
            raise self._damaged(problem)

    def _damaged(self, problem: str) -> DatabaseError:
        return DatabaseError(f"the database file is damaged (PRAGMA quick_check: {problem}); "
                             "restore it from a backup, or save what is left with "
                             "`sqlite3 FILE .recover`", path=self.path)

    def _missing(self, message: str) -> DatabaseError:
        """The error of a lookup that found nothing: ``message``, unless the file is damaged
        (then a damaged page, not a missing record, may be the cause)."""
        problem = self.damage()
        if problem is not None:
            return self._damaged(problem)
        return DatabaseError(message, path=self.path)

    def _one(self, sql: str, params, message: str):
        """The one row ``sql`` selects, or :meth:`_missing` with ``message``."""
        row = self.conn.execute(sql, params).fetchone()
        if row is None:
            raise self._missing(message)
        return row

    @contextlib.contextmanager
    def transaction(self):
        """One write transaction (``BEGIN IMMEDIATE`` ... ``COMMIT``); nested calls are savepoints.

        Everything written in the block is committed together or, on any exception (including
        ``KeyboardInterrupt``), rolled back. Invalidates the descriptor-matrix cache. The first
        write to a surfidx database made before :data:`APPLICATION_ID` sets it.

        Raises
        ------
        DatabaseError
            The database was opened read-only, or SQLite cannot begin or commit (read-only
            file, full disk, lock held past ``timeout``...): nothing of the block is kept.
        """
        conn = self.conn
        if self.readonly:
            raise DatabaseError("opened read-only; open it without readonly=True to write",
                                path=self.path)
        self._cache.clear()
        if conn.in_transaction:
            try:
                conn.execute("SAVEPOINT surfidx_nested")
            except sqlite3.Error as exc:
                raise self._error(exc) from exc
            try:
                yield self
            except BaseException:
                if conn.in_transaction:
                    try:
                        conn.execute("ROLLBACK TO SAVEPOINT surfidx_nested")
                        conn.execute("RELEASE SAVEPOINT surfidx_nested")
                    except sqlite3.Error:  # pragma: no cover - the outer rollback follows
                        pass
                raise
            else:
                try:
                    conn.execute("RELEASE SAVEPOINT surfidx_nested")
                except sqlite3.Error as exc:  # pragma: no cover
                    raise self._error(exc) from exc
            return
        try:
            conn.execute("BEGIN IMMEDIATE")
            if self._needs_marker:
                conn.execute(f"PRAGMA application_id = {APPLICATION_ID}")
        except sqlite3.Error as exc:
            self._rollback()
            raise self._error(exc) from exc
        try:
            yield self
        except BaseException:
            self._rollback()
            raise
        else:
            try:
                conn.execute("COMMIT")
            except sqlite3.Error as exc:
                self._rollback()
                raise self._error(exc) from exc
            self._needs_marker = False
        finally:
            self._cache.clear()

    # ------------------------------------------------------------------ writing models
    def add(self, model, *, exact_name: bool = False, replace=None) -> int:
        """Store one processed model: its row, asset, descriptors and thumbnail, in one transaction.

        A model read from the absolute path of a stored model (``source_abs``) is stored as
        that model's next version (same name, version + 1, its tags copied), unless
        ``exact_name`` names it; ``replace`` makes it the next version of the model it names.

        Parameters
        ----------
        model : surfidx.pipeline.ProcessedModel
        exact_name : bool
            Store ``model.name`` as a new model or fail; by default a name another model has
            is replaced by the model's parent folder's name, or else ``NAME-2``, ``NAME-3``, ...
            (the first free one; ``model.name`` is left as it was).
        replace : int or str, optional
            A stored model (:meth:`resolve`): store this one as its next version.

        Returns
        -------
        int
            The new model's (version's) id.

        Raises
        ------
        InputError
            A field of ``model`` is invalid (bbox shape, non-finite descriptor, non-JSON params).
        DatabaseError
            A model with the same content hash is already stored, ``replace`` names no model,
            or (``exact_name``) one with the same name.

        Notes
        -----
        The descriptor conventions (``model.params["descriptors"]``, a dict, e.g. lmax and
        normalisation) are copied to every descriptor row's ``convention`` column so that
        :meth:`descriptor_matrix` can refuse to mix incompatible vectors. ``name`` and
        ``source`` (OS text from file names) are stored through :func:`escape_name`.
        """
        row, asset, descs, png = self._rows_of(model)
        topo = _topology_row(getattr(model, "topology", None), row["name"])
        with self.transaction():
            existing = self.conn.execute("SELECT id, name, version FROM models "
                                         "WHERE content_hash = ?",
                                         (row["content_hash"],)).fetchone()
            if existing is not None:
                raise DatabaseError(
                    f"model {row['name']!r} is already stored as id {existing[0]} "
                    f"({existing[1]}@{existing[2]}, same content hash "
                    f"{row['content_hash'][:12]}...)", path=self.path)
            previous = None
            if replace is not None:
                previous = self.resolve(replace)
            elif not exact_name and row["source_abs"] is not None:
                hit = self.conn.execute("SELECT name FROM models WHERE source_abs = ? "
                                        "ORDER BY id DESC LIMIT 1",
                                        (row["source_abs"],)).fetchone()
                if hit is not None:
                    previous = self.resolve(hit[0])
            if previous is not None:
                row["name"], row["version"] = self.conn.execute(
                    "SELECT name, (SELECT max(version) FROM models n WHERE n.name = m.name) + 1 "
                    "FROM models m WHERE id = ?", (previous,)).fetchone()
            elif exact_name:
                other = self.conn.execute("SELECT id FROM models WHERE name = ?",
                                          (row["name"],)).fetchone()
                if other is not None:
                    raise DatabaseError(f"the name {row['name']!r} is taken by model {other[0]}; "
                                        "choose another name (or rename that model)",
                                        path=self.path)
            else:
                row["name"] = _free_name(self.conn, row["name"], row["source_abs"])
            cols = list(row)
            cur = self.conn.execute(
                f"INSERT INTO models ({', '.join(cols)}) VALUES ({', '.join('?' * len(cols))})",
                [row[c] for c in cols])
            model_id = int(cur.lastrowid)
            self.conn.execute(
                "INSERT INTO assets (model_id, stream, format_version, bits_per_surfel, bytes, "
                "psnr_d1, psnr_d2, psnr_y) VALUES (?, ?, ?, ?, ?, ?, ?, ?)",
                (model_id, *asset))
            self.conn.executemany(_INSERT_DESCRIPTOR, [(model_id, *d) for d in descs])
            self.conn.execute("INSERT INTO thumbnails (model_id, png) VALUES (?, ?)",
                              (model_id, png))
            if topo is not None:
                self.conn.execute(
                    f"INSERT INTO model_topology (model_id, {', '.join(_TOPOLOGY_COLUMNS)}, "
                    f"details) VALUES ({', '.join('?' * (len(_TOPOLOGY_COLUMNS) + 2))})",
                    (model_id, *topo))
            if previous is not None:
                self.conn.execute("INSERT INTO tags (model_id, tag) SELECT ?, tag FROM tags "
                                  "WHERE model_id = ?", (model_id, previous))
            self._descriptors_touched()
        return model_id

    @staticmethod
    def _rows_of(model):
        name = escape_name(model.name)
        if not name:
            raise InputError("model name must not be empty")
        h = str(model.content_hash)
        if not h:
            raise InputError(f"model {name!r}: content_hash must not be empty")
        bbox = as_array(model.bbox, f"model {name!r} bbox", shape=(2, 3))
        n = int(model.n_surfels)
        if n < 0:
            raise InputError(f"model {name!r}: n_surfels must be >= 0, got {n}")
        for what in ("stream", "thumbnail"):
            if not isinstance(getattr(model, what), (bytes, bytearray, memoryview)):
                raise InputError(f"model {name!r}: {what} must be bytes, "
                                 f"got {type(getattr(model, what)).__name__}")
        params = dict(model.params or {})
        provenance = params.get("provenance") if isinstance(params.get("provenance"),
                                                            dict) else {}
        conventions = params.get("descriptors") if isinstance(params.get("descriptors"),
                                                              dict) else {}
        source = os.fspath(model.source) if isinstance(model.source, os.PathLike) \
            else str(model.source)
        absolute = os.path.isabs(source)
        relative = getattr(model, "source_rel", None) or (os.path.basename(source) if absolute
                                                          else source)
        size = getattr(model, "source_bytes", None)
        mtime = getattr(model, "source_mtime", None)
        descriptor_version = conventions.get("version")
        row = {"name": name, "source": escape_name(relative), "content_hash": h,
               "n_surfels": n, "has_color": int(bool(model.has_color)),
               **{f"bbox_{c}_{a}": float(bbox[i, j])
                  for i, c in enumerate(("min", "max")) for j, a in enumerate("xyz")},
               "ingested_at": utc_now(), "params": _to_json(params, f"model {name!r} params"),
               "version": 1, "source_abs": escape_name(source) if absolute else None,
               "source_bytes": None if size is None else int(size),
               "source_mtime": None if mtime is None else _iso_utc(float(mtime)),
               "surfidx_version": _text_or_none(provenance.get("surfidx")),
               "codec_version": int(model.format_version),
               "descriptor_version": descriptor_version
               if isinstance(descriptor_version, int) else None,
               "numerics_profile": _text_or_none(provenance.get("numerics_profile"))}
        quality = dict(model.quality or {})
        q = []
        for key in QUALITY_KEYS:
            v = quality.get(key)
            q.append(None if v is None or not np.isfinite(float(v)) else float(v))
        stream = bytes(model.stream)
        asset = (stream, int(model.format_version), float(model.rate), len(stream), *q)
        convention = _to_json(params.get("descriptors", {}),
                              f"model {name!r} params['descriptors']")
        descs = _descriptor_rows(model.descriptors or {}, convention, f"model {name!r}")
        return row, asset, descs, bytes(model.thumbnail)

    # ------------------------------------------------------------------ original files
    def keep_original(self, model_id: int, files, *, content_hash: str | None = None,
                      hashed=(), max_bytes: int = MAX_ORIGINAL_BYTES) -> dict:
        """Store a model version's original files as blobs (deduplicated by SHA-256), in one
        transaction (joins an open one).

        Each file is read twice in pieces of 1 MiB (never whole in memory): once for its hash
        (the blob's key; a blob stored already is not written again), once into the blob, and
        the second read must give the same hash.

        Parameters
        ----------
        model_id : int
        files : sequence of (str, os.PathLike, str)
            ``(relative path, file, role)`` as :func:`surfidx.io.original_files` gives them.
        content_hash : str, optional
            The model's content hash: the SHA-256 of the files ``hashed`` names, in that order,
            must equal it (the files are those the model was made of, unchanged since).
        hashed : sequence of os.PathLike
            The files of ``content_hash`` (the model file, then its texture).
        max_bytes : int
            Largest file stored (at most :data:`MAX_ORIGINAL_BYTES`).

        Returns
        -------
        dict
            ``files`` (count), ``bytes`` (their sizes' sum), ``new_bytes`` (of blobs not
            stored before).

        Raises
        ------
        InputError
            A file larger than ``max_bytes``, one that changed while it was read,
            or files that do not give ``content_hash``.
        DatabaseError
            No model has this id.
        """
        import hashlib

        from ..io.files import file_pieces

        model_id = self._check_id(model_id)
        order = {os.path.abspath(p): k for k, p in enumerate(hashed)}
        files = sorted(files, key=lambda f: order.get(os.path.abspath(f[1]), len(order)))
        whole = hashlib.sha256()
        digests = []
        for rel, path, _ in files:
            size = os.stat(path).st_size
            limit = min(int(max_bytes), MAX_ORIGINAL_BYTES)
            if size > limit:
                raise InputError(f"{size:,} bytes, more than an original file may have "
                                 f"({limit:,}); ingest it without --keep-original", path=path)
            h = hashlib.sha256()
            n = 0
            for chunk in file_pieces(path, lambda fh, k: fh.read(min(k, 1 << 20))):
                h.update(chunk)
                n += len(chunk)
                if os.path.abspath(path) in order:
                    whole.update(chunk)
            digests.append((h.hexdigest(), n))
        if content_hash is not None and order and whole.hexdigest() != content_hash:
            raise InputError("changed since it was read for this model (its content hash "
                             "differs); ingest it again", path=files[0][1])
        stored = new = 0
        with self.transaction():
            self._check_id(model_id)
            self._one("SELECT 1 FROM models WHERE id = ?", (model_id,),
                      f"no model with id {model_id}")
            for (rel, path, role), (digest, n) in zip(files, digests):
                stored += n
                if self.conn.execute("SELECT 1 FROM blobs WHERE sha256 = ?",
                                     (digest,)).fetchone() is None:
                    cur = self.conn.execute("INSERT INTO blobs (sha256, bytes, data) "
                                            "VALUES (?, ?, zeroblob(?))", (digest, n, n))
                    h = hashlib.sha256()
                    at = 0
                    with self.conn.blobopen("blobs", "data", cur.lastrowid) as blob:
                        for chunk in file_pieces(path, lambda fh, k: fh.read(min(k, 1 << 20))):
                            if at + len(chunk) > n:
                                break
                            blob.write(chunk)
                            h.update(chunk)
                            at += len(chunk)
                    if at != n or h.hexdigest() != digest:
                        raise InputError("changed while it was kept as an original; ingest it "
                                         "again", path=path)
                    new += n
                self.conn.execute("INSERT INTO original_files (model_id, path, role, sha256) "
                                  "VALUES (?, ?, ?, ?)",
                                  (model_id, escape_name(rel), str(role), digest))
        return {"files": len(files), "bytes": stored, "new_bytes": new}

    def original_files(self, id_or_name) -> list:
        """A model version's original files (none unless it was ingested with
        ``--keep-original``), the source file first.

        Returns
        -------
        list of dict
            Keys ``path`` (relative, as written back), ``role``, ``bytes``, ``sha256``.
        """
        model_id = self.resolve(id_or_name)
        keys = ("path", "role", "bytes", "sha256")
        return [dict(zip(keys, r)) for r in self.conn.execute(
            "SELECT o.path, o.role, b.bytes, o.sha256 FROM original_files o JOIN blobs b "
            "ON b.sha256 = o.sha256 WHERE o.model_id = ? ORDER BY o.role = 'companion', o.path",
            (model_id,))]

    def original_pieces(self, sha256: str, *, size: int = 1 << 20):
        """The bytes of a stored original file, in pieces of at most ``size`` bytes.

        Raises
        ------
        DatabaseError
            No blob has this hash.
        """
        rowid, n = self._one("SELECT rowid, bytes FROM blobs WHERE sha256 = ?", (str(sha256),),
                             f"no original file with SHA-256 {sha256}")
        with self.conn.blobopen("blobs", "data", rowid, readonly=True) as blob:
            if len(blob) != n:
                raise self._damaged(f"blob {sha256} holds {len(blob):,} bytes, its row says "
                                    f"{n:,}")
            while True:
                chunk = blob.read(int(size))
                if not chunk:
                    return
                yield chunk

    def delete(self, model_id: int) -> None:
        """Delete a model with its asset, descriptors and thumbnail.

        Raises
        ------
        DatabaseError
            No model has this id.
        """
        model_id = self._check_id(model_id)
        with self.transaction():
            if self.conn.execute("DELETE FROM models WHERE id = ?", (model_id,)).rowcount == 0:
                raise self._missing(f"no model with id {model_id}")
            self._descriptors_touched()

    def remove(self, *models) -> list:
        """Delete models given by name (every version), or versions given by id or
        ``NAME@N``, with their assets, descriptors, thumbnails, tags and original files (and
        the blobs no other version holds), all in one transaction (none is deleted if one is
        not found).

        Parameters
        ----------
        *models : int or str
            Ids, names or ``NAME@N`` (:meth:`resolve_all`).

        Returns
        -------
        list of dict
            ``{"id", "name", "version"}`` of each version removed, in the order given.

        Raises
        ------
        DatabaseError
            A model is not found (nothing is deleted).
        InputError
            No model given.
        """
        if len(models) == 1 and isinstance(models[0], (list, tuple)):
            models = tuple(models[0])
        if not models:
            raise InputError("name at least one model to remove")
        with self.transaction():
            rows = {}
            for m in models:
                for r in self._ref_rows(m)[0]:
                    rows.setdefault(int(r[0]), r)
            for i in rows:
                self.delete(i)
        return [{"id": i, "name": r[1], "version": int(r[2])} for i, r in rows.items()]

    def rename(self, model, new_name: str) -> dict:
        """Give a model (every version of it) another (unique) name.

        Returns
        -------
        dict
            ``{"id", "old_name", "name"}``.

        Raises
        ------
        InputError
            An empty name.
        DatabaseError
            No such model, or another model has ``new_name``.
        """
        name = escape_name(new_name)
        if not name.strip():
            raise InputError("a model name must not be empty")
        with self.transaction():
            mid = self.resolve(model)
            old = self._one("SELECT name FROM models WHERE id = ?", (mid,),
                            f"no model with id {mid}")[0]
            other = self.conn.execute("SELECT id FROM models WHERE name = ? AND name != ?",
                                      (name, old)).fetchone()
            if other is not None:
                raise DatabaseError(f"the name {name!r} is taken by model {other[0]}; choose "
                                    "another", path=self.path)
            self.conn.execute("UPDATE models SET name = ? WHERE name = ?", (name, old))
        return {"id": mid, "old_name": old, "name": name}

    def tag(self, models, tags) -> int:
        """Add tags to models (tags they already carry are kept once): a name tags every
        version of it, an id or ``NAME@N`` one version (:meth:`resolve_all`); a new version
        gets the tags of the latest one.

        Parameters
        ----------
        models : int, str or sequence of them
        tags : str or sequence of str

        Returns
        -------
        int
            Tags newly added.

        Raises
        ------
        InputError
            An empty tag or no tag.
        DatabaseError
            A model is not found (nothing is changed).
        """
        return self._per_tag(models, tags, "INSERT OR IGNORE INTO tags (model_id, tag) "
                                           "VALUES (?, ?)")

    def untag(self, models, tags) -> int:
        """Remove tags from models; returns how many were removed (see :meth:`tag`)."""
        return self._per_tag(models, tags, "DELETE FROM tags WHERE model_id = ? AND tag = ?")

    def _per_tag(self, models, tags, sql: str) -> int:
        """Run ``sql`` with ``(model id, tag)`` for every model and tag in one transaction
        (a missing model rolls it all back); returns the rows changed."""
        tags = self._tags_of(tags)
        models = [models] if isinstance(models, (str, int, np.integer)) else list(models)
        changed = 0
        with self.transaction():
            for mid in dict.fromkeys(i for m in models for i in self.resolve_all(m)):
                for t in tags:
                    changed += self.conn.execute(sql, (mid, t)).rowcount
        return changed

    def tags(self, model=None):
        """A model's tags (sorted list), or with no model every tag with its model count."""
        if model is None:
            return dict(self.conn.execute("SELECT tag, count(*) FROM tags GROUP BY tag "
                                          "ORDER BY tag"))
        mid = self.resolve(model)
        return [r[0] for r in self.conn.execute("SELECT tag FROM tags WHERE model_id = ? "
                                                "ORDER BY tag", (mid,))]

    @staticmethod
    def _tags_of(tags) -> list:
        tags = [tags] if isinstance(tags, str) else list(tags)
        out = [storable_text(t).strip() for t in tags]
        if not out or not all(out):
            raise InputError("give at least one tag, and no empty tag")
        return list(dict.fromkeys(out))

    def set_descriptors(self, model_id: int, descriptors: dict, convention: dict) -> None:
        """Replace one model's descriptor vectors, in one transaction.

        Parameters
        ----------
        model_id : int
        descriptors : dict of str -> (d,) array_like
            The new vectors by kind; kinds not named here are deleted.
        convention : dict
            Their conventions (:func:`surfidx.describe.descriptors.descriptor_params`), written to every
            row's ``convention`` and to the model's ``params["descriptors"]``.

        Raises
        ------
        DatabaseError
            No model has this id.
        InputError
            A non-finite vector or a convention that is not JSON.
        """
        model_id = self._check_id(model_id)
        conv = _to_json(convention, f"model {model_id} descriptor convention")
        rows = [(model_id, *d) for d in _descriptor_rows(descriptors, conv, f"model {model_id}")]
        with self.transaction():
            got = self._one("SELECT params FROM models WHERE id = ?", (model_id,),
                            f"no model with id {model_id}")
            params = json.loads(got[0])
            params["descriptors"] = json.loads(conv)
            self.conn.execute("UPDATE models SET params = ? WHERE id = ?",
                              (_to_json(params, f"model {model_id} params"), model_id))
            self.conn.execute("DELETE FROM descriptors WHERE model_id = ?", (model_id,))
            self.conn.executemany(_INSERT_DESCRIPTOR, rows)
            self._descriptors_touched()

    # ------------------------------------------------------------------ approximate index hooks
    def descriptors_changed(self) -> None:
        """Record that models or descriptors changed (increments the ``meta`` counter
        ``descriptor_generation`` that :mod:`surfidx.db.ann` compares with its index).

        :meth:`add`, :meth:`delete` and :meth:`set_descriptors` call it themselves; a writer
        that changes the tables with its own SQL must call it in the same transaction.
        """
        with self.transaction():
            self._descriptors_touched()

    def _descriptors_touched(self) -> None:
        self.conn.execute("INSERT INTO meta (key, value) VALUES ('descriptor_generation', '1') "
                          "ON CONFLICT (key) DO UPDATE SET value = CAST(value AS INTEGER) + 1")
        self._index_dirty = True

    def index_state(self) -> dict:
        """What an approximate index of this database must match (cheap: indexed look-ups).

        Returns
        -------
        dict
            ``generation`` (:meth:`descriptors_changed`), ``schema_version``, ``models`` (count),
            ``max_model_id``, ``max_descriptor_rowid``.
        """
        conn = self.conn
        row = conn.execute("SELECT value FROM meta WHERE key = 'descriptor_generation'").fetchone()
        return {"generation": int(row[0]) if row else 0,
                "schema_version": int(conn.execute("PRAGMA user_version").fetchone()[0]),
                "models": int(conn.execute("SELECT count(*) FROM models").fetchone()[0]),
                "max_model_id": int(conn.execute("SELECT max(id) FROM models").fetchone()[0]
                                    or 0),
                "max_descriptor_rowid": int(conn.execute(
                    "SELECT max(rowid) FROM descriptors").fetchone()[0] or 0)}

    def descriptor_rows(self, ids, kinds) -> tuple:
        """The descriptors of some models, read by id (for re-ranking candidates).

        Parameters
        ----------
        ids : (n,) int64
        kinds : sequence of str
            The first is required: models without it are left out.

        Returns
        -------
        ids : (m,) int64
            The stored models of ``ids`` holding ``kinds[0]``, ascending.
        stored : dict of str -> (m, d_k) float32
            Rows of absent kinds are zeros.
        present : dict of str -> (m,) bool
            For ``"texture"``: the model has colour and a texture descriptor.

        Raises
        ------
        DatabaseError
            Vectors of one kind with different dimensions.
        """
        ids = np.unique(as_array(ids, "ids", dtype=np.int64, shape=(None,)))
        kinds = tuple(kinds)
        rows, color = [], []
        for start in range(0, ids.size, 500):
            chunk = ids[start:start + 500].tolist()
            marks = ", ".join("?" * len(chunk))
            rows += self.conn.execute(
                f"SELECT kind, model_id, vector FROM descriptors WHERE model_id IN ({marks}) "
                f"AND +kind IN ({', '.join('?' * len(kinds))})",     # + : by primary key
                chunk + list(kinds)).fetchall()
            color += self.conn.execute(f"SELECT id, has_color FROM models WHERE id IN ({marks})",
                                       chunk).fetchall()
        rows.sort(key=lambda r: (r[0], r[1]))
        color.sort()
        cid = np.array([c[0] for c in color], np.int64)
        cval = np.array([bool(c[1]) for c in color], bool)
        per_kind = {}
        for kind in kinds:
            sel = [r for r in rows if r[0] == kind]
            dims = {len(r[2]) for r in sel}
            if len(dims) > 1:
                raise DatabaseError(f"descriptors of kind {kind!r} have different dimensions "
                                    f"{sorted(d // 4 for d in dims)}; run `surfidx redescribe` "
                                    "to recompute them with this surfidx's descriptors",
                                    path=self.path)
            kid = np.fromiter((r[1] for r in sel), np.int64, len(sel))
            mat = np.frombuffer(b"".join(r[2] for r in sel), "<f4").reshape(
                len(sel), (dims.pop() // 4) if dims else 0)
            per_kind[kind] = (kid, mat)
        out_ids = np.intersect1d(per_kind[kinds[0]][0], cid)
        stored, present = {}, {}
        for kind in kinds:
            kid, mat = per_kind[kind]
            full = np.zeros((out_ids.size, mat.shape[1]), np.float32)
            has = np.isin(out_ids, kid)
            if kid.size:
                full[has] = mat[np.searchsorted(kid, out_ids[has])]
            if kind == "texture":
                has &= cval[np.searchsorted(cid, out_ids)]
            stored[kind], present[kind] = full, has
        return out_ids, stored, present

    def _update_index(self) -> None:
        """Update the approximate index after this connection changed models; a failure leaves
        it stale, which the next query finds and repairs (so it is a warning, not an error)."""
        import warnings

        try:
            from . import ann
            from ..describe.distance import DEFAULT_KINDS

            ann.update(self, kinds=DEFAULT_KINDS)
        except (ImportError, OSError, RuntimeError, SurfidxError, sqlite3.Error) as exc:
            warnings.warn(f"{self.path}: the approximate index was not updated ({exc}); the "
                          "next query rebuilds it", RuntimeWarning, stacklevel=3)

    def descriptor_conventions(self) -> dict:
        """Model ids by descriptor convention: ``{convention JSON text: [ids ascending]}``."""
        out = {}
        for conv, mid in self.conn.execute(
                "SELECT DISTINCT convention, model_id FROM descriptors ORDER BY model_id"):
            out.setdefault(conv, []).append(int(mid))
        return out

    # ------------------------------------------------------------------ reading models
    def has_hash(self, content_hash: str) -> bool:
        """Whether a model with this content hash is stored."""
        return self.conn.execute("SELECT 1 FROM models WHERE content_hash = ?",
                                 (str(content_hash),)).fetchone() is not None

    def ids_of_hashes(self, content_hashes) -> list:
        """Ids of the stored models with these content hashes (unknown hashes are left out)."""
        out = []
        for h in dict.fromkeys(str(h) for h in content_hashes):
            row = self.conn.execute("SELECT id FROM models WHERE content_hash = ?",
                                    (h,)).fetchone()
            if row is not None:
                out.append(int(row[0]))
        return out

    def hashes(self) -> set:
        """The content hashes of all stored models (one query, for bulk skipping)."""
        return {r[0] for r in self.conn.execute("SELECT content_hash FROM models")}

    def _check_id(self, model_id) -> int:
        if isinstance(model_id, bool) or not isinstance(model_id, (int, np.integer)):
            raise InputError(f"model id must be an integer, got {model_id!r}")
        if not -_MAX_ID - 1 <= int(model_id) <= _MAX_ID:
            raise DatabaseError(f"no model with id {int(model_id)} (ids are 64-bit integers)",
                                path=self.path)
        return int(model_id)

    def _versions_named(self, text: str) -> list:
        """``(id, name, version)`` of every version of the model named ``text`` (as stored,
        :func:`escape_name` of the OS text, or as printed), by version; several names matching
        is an error."""
        rows = self.conn.execute(
            "SELECT id, name, version FROM models WHERE name IN (?, ?) ORDER BY version",
            (escape_name(text), storable_text(text))).fetchall()
        if len({r[1] for r in rows}) > 1:
            ids = ", ".join(str(r[0]) for r in rows)
            raise DatabaseError(f"name {text!r} matches {len(rows)} models (ids {ids}); give "
                                "the id", path=self.path)
        return rows

    def _ref_rows(self, id_or_name) -> tuple:
        """``(rows, whole)``: the ``(id, name, version)`` rows a reference names, and whether
        it names a whole model (a name: every version) rather than one version (an id, or
        ``NAME@N``)."""
        if isinstance(id_or_name, str):
            rows = self._versions_named(id_or_name)
            if rows:
                return rows, True
            m = _VERSION_REF.fullmatch(id_or_name)
            if m is not None:
                rows = self._versions_named(m.group(1))
                if rows:
                    want = int(m.group(2))
                    hit = [r for r in rows if r[2] == want]
                    if not hit:
                        have = ", ".join(str(r[2]) for r in rows)
                        raise DatabaseError(f"model {storable_text(m.group(1))!r} has no "
                                            f"version {want} (it has {have})", path=self.path)
                    return hit, False
            raise self._missing(f"no model named {storable_text(id_or_name)!r}")
        model_id = self._check_id(id_or_name)
        row = self._one("SELECT id, name, version FROM models WHERE id = ?", (model_id,),
                        f"no model with id {model_id}")
        return [tuple(row)], False

    def resolve(self, id_or_name) -> int:
        """The id of a model version given by id (int), by name (str: its latest version) or
        by ``NAME@N`` (version N of NAME).

        A name is matched as stored (:func:`escape_name` of the OS text) or as printed;
        ``NAME@N`` is read as a version only when no model is named so.

        Raises
        ------
        DatabaseError
            No such model or version, or the name is shared by several models.
        """
        rows, _ = self._ref_rows(id_or_name)
        return int(rows[-1][0])

    def resolve_all(self, id_or_name) -> list:
        """The ids a reference names: every version of a model given by name, the one version
        of an id or ``NAME@N`` (:meth:`resolve`), ascending by version.

        Returns
        -------
        list of int
        """
        rows, _ = self._ref_rows(id_or_name)
        return [int(r[0]) for r in rows]

    def versions(self, id_or_name) -> list:
        """Every version of the model a reference names (any of its versions), oldest first.

        Returns
        -------
        list of dict
            Keys ``id``, ``version``, ``ingested_at``, ``content_hash``, ``n_surfels``,
            ``bytes``, ``source``, ``source_abs``, ``source_bytes``, ``source_mtime``,
            ``surfidx_version``, ``has_original``.
        """
        mid = self.resolve(id_or_name)
        keys = ("id", "version", "ingested_at", "content_hash", "n_surfels", "bytes", "source",
                "source_abs", "source_bytes", "source_mtime", "surfidx_version", "has_original")
        rows = self.conn.execute(
            "SELECT m.id, m.version, m.ingested_at, m.content_hash, m.n_surfels, a.bytes, "
            "m.source, m.source_abs, m.source_bytes, m.source_mtime, m.surfidx_version, "
            "EXISTS (SELECT 1 FROM original_files o WHERE o.model_id = m.id) "
            "FROM models m LEFT JOIN assets a ON a.model_id = m.id "
            "WHERE m.name = (SELECT name FROM models WHERE id = ?) ORDER BY m.version",
            (mid,)).fetchall()
        out = [dict(zip(keys, r)) for r in rows]
        for r in out:
            r["has_original"] = bool(r["has_original"])
        return out

    def get_model(self, id_or_name) -> dict:
        """One model's record with its asset figures and descriptor kinds.

        Parameters
        ----------
        id_or_name : int or str
            Model id, or model name (which must be unique).

        Returns
        -------
        dict
            The ``models`` row (``params`` decoded, ``has_color`` bool, ``bbox`` a (2, 3) float64
            array instead of the six columns), plus ``"asset"`` (``format_version``,
            ``bits_per_surfel``, ``bytes``, ``psnr_d1``, ``psnr_d2``, ``psnr_y``),
            ``"descriptors"`` (kind -> dimension), ``"tags"``, ``"topology"`` (what topology
            repair added: the ``model_topology`` row with its ``details``, or None for a model
            stored as it was read), ``"latest"`` (whether no later version of the name exists)
            and ``"original"`` (:meth:`original_files`, empty without one). ``id_or_name``
            is read as :meth:`resolve` reads it (a name: its latest version).

        Raises
        ------
        DatabaseError
            No such model, or an ambiguous name.
        """
        model_id = self.resolve(id_or_name)
        conn = self.conn
        rec = dict(zip(_MODEL_COLUMNS, self._one(
            f"SELECT {', '.join(_MODEL_COLUMNS)} FROM models WHERE id = ?", (model_id,),
            f"no model with id {model_id}")))
        rec["has_color"] = bool(rec["has_color"])
        rec["params"] = json.loads(rec["params"])
        rec["latest"] = bool(conn.execute(f"SELECT {LATEST_SQL} FROM models m WHERE id = ?",
                                          (model_id,)).fetchone()[0])
        rec["original"] = self.original_files(model_id)
        rec["bbox"] = np.array([[rec.pop(f"bbox_{c}_{a}") for a in "xyz"] for c in ("min", "max")])
        a = conn.execute("SELECT format_version, bits_per_surfel, bytes, psnr_d1, psnr_d2, psnr_y "
                         "FROM assets WHERE model_id = ?", (model_id,)).fetchone()
        rec["asset"] = None if a is None else dict(zip(
            ("format_version", "bits_per_surfel", "bytes", *QUALITY_KEYS), a))
        rec["descriptors"] = dict(conn.execute(
            "SELECT kind, dimension FROM descriptors WHERE model_id = ? ORDER BY kind",
            (model_id,)).fetchall())
        rec["tags"] = [r[0] for r in conn.execute(
            "SELECT tag FROM tags WHERE model_id = ? ORDER BY tag", (model_id,))]
        t = conn.execute(f"SELECT {', '.join(_TOPOLOGY_COLUMNS)}, details FROM model_topology "
                         "WHERE model_id = ?", (model_id,)).fetchone()
        rec["topology"] = None if t is None else dict(
            json.loads(t[-1]), **dict(zip(_TOPOLOGY_COLUMNS, t[:-1])))
        return rec

    def get_stream(self, id_or_name) -> bytes:
        """The stored compressed asset (a complete container file) of a model.

        Raises
        ------
        DatabaseError
            No such model (or it has no asset).
        """
        return self._blob(id_or_name, "SELECT stream FROM assets WHERE model_id = ?",
                          "stored stream")

    def get_thumbnail(self, id_or_name) -> bytes:
        """The stored PNG thumbnail of a model.

        Raises
        ------
        DatabaseError
            No such model (or it has no thumbnail).
        """
        return self._blob(id_or_name, "SELECT png FROM thumbnails WHERE model_id = ?",
                          "thumbnail")

    def _blob(self, id_or_name, sql: str, what: str) -> bytes:
        """The one blob ``sql`` selects for a model (by its id), or :class:`DatabaseError`
        naming ``what`` it lacks."""
        model_id = self.resolve(id_or_name)
        return bytes(self._one(sql, (model_id,), f"model {model_id} has no {what}")[0])

    def get_descriptors(self, id_or_name) -> dict:
        """A model's descriptor vectors.

        Returns
        -------
        dict of str -> (d,) float32
        """
        model_id = self.resolve(id_or_name)
        return {kind: np.frombuffer(blob, "<f4").astype(np.float32)
                for kind, blob in self.conn.execute(
                    "SELECT kind, vector FROM descriptors WHERE model_id = ? ORDER BY kind",
                    (model_id,))}

    def select_ids(self, *, tag=None, where: str | None = None, all_versions: bool = False):
        """The ids of the models that carry every tag of ``tag`` and pass the filter ``where``
        (:func:`surfidx.db.filters.where_sql`), ascending; latest versions only unless
        ``all_versions``.

        Parameters
        ----------
        tag : str or sequence of str, optional
        where : str, optional
        all_versions : bool

        Returns
        -------
        (n,) int64
        """
        where, args = self._model_conditions(tag=tag, where=where, all_versions=all_versions)
        cur = self.conn.execute(
            "SELECT m.id FROM models m LEFT JOIN assets a ON a.model_id = m.id"
            + (" WHERE " + " AND ".join(where) if where else "") + " ORDER BY m.id", args)
        return np.fromiter((r[0] for r in cur), np.int64)

    def superseded(self) -> int:
        """Number of stored versions that are not their model's latest."""
        return int(self.conn.execute(f"SELECT count(*) FROM models m WHERE NOT ({LATEST_SQL})")
                   .fetchone()[0])

    def _model_conditions(self, *, tag=None, name_like=None, where=None,
                          all_versions: bool = False) -> tuple:
        """SQL conditions on ``models m`` / ``assets a`` and their parameters, of
        :meth:`list_models`' selection (latest versions unless ``all_versions``). The
        latest-version condition, a probe per row, is left out while no model has a version
        past 1 (every row is then its name's latest; told by the partial index on later
        versions)."""
        later = not all_versions and self.conn.execute(
            "SELECT 1 FROM models WHERE version > 1 LIMIT 1").fetchone() is not None
        filter_text, where, args = where, [LATEST_SQL] if later else [], []
        for t in ([] if tag is None else [tag] if isinstance(tag, str) else list(tag)):
            where.append("m.id IN (SELECT model_id FROM tags WHERE tag = ?)")
            args.append(str(t))
        if name_like is not None:
            where.append("m.name LIKE ?")
            args.append(str(name_like))
        if filter_text is not None:
            from .filters import where_sql

            sql, more = where_sql(filter_text)
            where.append(f"({sql})")
            args += more
        return where, args

    def list_models(self, *, tag=None, name_like: str | None = None,
                    where: str | None = None, all_versions: bool = False) -> list:
        """The models (their latest versions, or every version), by id, with their asset
        figures and tags (no blobs).

        Parameters
        ----------
        tag : str or sequence of str, optional
            Only models carrying every one of these tags.
        name_like : str, optional
            Only models whose name matches this SQL ``LIKE`` pattern (``%`` any text, ``_`` one
            character; case-insensitive for ASCII).
        where : str, optional
            Only models passing this filter on their stored figures
            (:func:`surfidx.db.filters.where_sql`, e.g. ``"surfels > 10000 and colour = true"``).
        all_versions : bool
            Every stored version instead of each model's latest.

        Returns
        -------
        list of dict
            Keys ``id``, ``name``, ``source``, ``content_hash``, ``n_surfels``, ``has_color``,
            ``ingested_at``, ``bits_per_surfel``, ``bytes``, ``psnr_d1``, ``psnr_d2``,
            ``psnr_y``, ``version``, ``versions`` (how many the name has), ``source_abs``,
            ``has_original``, ``tags`` (sorted list).
        """
        keys = ("id", "name", "source", "content_hash", "n_surfels", "has_color", "ingested_at",
                "bits_per_surfel", "bytes", *QUALITY_KEYS, "version", "versions", "source_abs",
                "has_original")
        where, args = self._model_conditions(tag=tag, name_like=name_like, where=where,
                                             all_versions=all_versions)
        cur = self.conn.execute(
            "SELECT m.id, m.name, m.source, m.content_hash, m.n_surfels, m.has_color, "
            "m.ingested_at, a.bits_per_surfel, a.bytes, a.psnr_d1, a.psnr_d2, a.psnr_y, "
            "m.version, (SELECT count(*) FROM models n WHERE n.name = m.name), m.source_abs, "
            "EXISTS (SELECT 1 FROM original_files o WHERE o.model_id = m.id) "
            "FROM models m LEFT JOIN assets a ON a.model_id = m.id"
            + (" WHERE " + " AND ".join(where) if where else "") + " ORDER BY m.id", args)
        out = [dict(zip(keys, r)) for r in cur]
        tags = {}
        for mid, t in self.conn.execute("SELECT model_id, tag FROM tags ORDER BY tag"):
            tags.setdefault(mid, []).append(t)
        for r in out:
            r["has_color"] = bool(r["has_color"])
            r["has_original"] = bool(r["has_original"])
            r["tags"] = tags.get(r["id"], [])
        return out

    def count(self) -> int:
        """Number of stored model versions (rows of ``models``)."""
        return int(self.conn.execute("SELECT count(*) FROM models").fetchone()[0])

    def color_mask(self, ids) -> np.ndarray:
        """``has_color`` of the given model ids.

        Parameters
        ----------
        ids : (m,) int64

        Returns
        -------
        (m,) bool
        """
        ids = as_array(ids, "ids", dtype=np.int64, shape=(None,))
        table = dict(self.conn.execute("SELECT id, has_color FROM models"))
        return np.fromiter((bool(table.get(int(i), 0)) for i in ids), bool, ids.size)

    # ------------------------------------------------------------------ descriptors
    def descriptor_matrix(self, kinds) -> tuple:
        """The stored descriptor vectors of one kind, or of several kinds side by side.

        Parameters
        ----------
        kinds : str or sequence of str
            ``"shape"``, or e.g. ``("shape", "texture")``: then only models holding every kind
            are returned and their vectors are concatenated in the order given.

        Returns
        -------
        ids : (m,) int64
            Model ids, ascending.
        matrix : (m, d) float32
            One row per model (read-only; cached until the database is written).

        Raises
        ------
        DatabaseError
            Vectors of one kind differ in dimension or in convention (``params["descriptors"]``
            at ingest time): ``surfidx redescribe`` recomputes them.
        InputError
            ``kinds`` is empty.
        """
        kinds = (kinds,) if isinstance(kinds, str) else tuple(kinds)
        if not kinds:
            raise InputError("kinds must name at least one descriptor kind")
        version = self.conn.execute("PRAGMA data_version").fetchone()[0]
        if version != self._cache_version:
            self._cache.clear()
            self._cache_version = version
        if kinds not in self._cache:
            per_kind = [self._kind_matrix(k) for k in kinds]
            ids = per_kind[0][0]
            for other, _ in per_kind[1:]:
                ids = np.intersect1d(ids, other, assume_unique=True)
            mats = [m[np.searchsorted(i, ids)] if len(ids) else m[:0] for i, m in per_kind]
            matrix = np.ascontiguousarray(np.hstack(mats), dtype=np.float32)
            ids = ids.astype(np.int64)
            ids.flags.writeable = False
            matrix.flags.writeable = False
            self._cache[kinds] = (ids, matrix)
        return self._cache[kinds]

    def _kind_matrix(self, kind: str):
        rows = self.conn.execute(
            "SELECT model_id, dimension, convention, vector FROM descriptors WHERE kind = ? "
            "ORDER BY model_id", (kind,)).fetchall()
        if not rows:
            return np.zeros(0, np.int64), np.zeros((0, 0), np.float32)
        dims = {r[1] for r in rows}
        if len(dims) > 1:
            raise DatabaseError(f"descriptors of kind {kind!r} have different dimensions "
                                f"{sorted(dims)}; run `surfidx redescribe` to recompute them "
                                "with this surfidx's descriptors", path=self.path)
        conventions = {r[2] for r in rows}
        if len(conventions) > 1:
            raise DatabaseError(f"descriptors of kind {kind!r} were made with different "
                                f"conventions {sorted(conventions)[:2]}; run `surfidx "
                                "redescribe` to recompute them with this surfidx's descriptors",
                                path=self.path)
        d = dims.pop()
        ids = np.fromiter((r[0] for r in rows), np.int64, len(rows))
        matrix = np.frombuffer(b"".join(r[3] for r in rows), "<f4").reshape(len(rows), d)
        return ids, matrix.astype(np.float32)

    def descriptor_kinds(self) -> dict:
        """Stored descriptor kinds with their number of models: ``{kind: count}``."""
        return dict(self.conn.execute(
            "SELECT kind, count(*) FROM descriptors GROUP BY kind ORDER BY kind"))

    # ------------------------------------------------------------------ ingest runs
    def start_run(self, paths, *, workers: int = 1, bits_per_surfel=None) -> int:
        """Record the start of an ingest run.

        Parameters
        ----------
        paths : sequence of str or os.PathLike
            The files and folders given.
        workers : int
        bits_per_surfel : float, optional

        Returns
        -------
        int
            The run id.
        """
        with self.transaction():
            cur = self.conn.execute(
                "INSERT INTO ingest_runs (started_at, paths, workers, bits_per_surfel, status) "
                "VALUES (?, ?, ?, ?, 'running')",
                (utc_now(), json.dumps([escape_name(p) for p in paths]), int(workers),
                 None if bits_per_surfel is None else float(bits_per_surfel)))
        return int(cur.lastrowid)

    def record_error(self, run_id: int, path, message: str) -> None:
        """Record a file a run could not store (joins an open transaction if there is one).

        ``path`` is stored through :func:`escape_name`, ``message`` with undecodable bytes as
        ``\\xHH``.
        """
        with self.transaction():
            self.conn.execute("INSERT INTO ingest_errors (run_id, path, error, at) "
                              "VALUES (?, ?, ?, ?)", (int(run_id), escape_name(path),
                                                      storable_text(message), utc_now()))

    def update_run(self, run_id: int, *, stored: int, skipped: int, failed: int) -> None:
        """Update a running run's counts (so a killed run still shows how far it came)."""
        with self.transaction():
            self.conn.execute("UPDATE ingest_runs SET stored = ?, skipped = ?, failed = ? "
                              "WHERE id = ?", (int(stored), int(skipped), int(failed),
                                               int(run_id)))

    def finish_run(self, run_id: int, *, stored: int, skipped: int, failed: int,
                   status: str = "finished") -> None:
        """Record the end of a run: its counts and ``status``.

        Parameters
        ----------
        status : {"finished", "interrupted", "failed"}

        Raises
        ------
        InputError
            Unknown status.
        DatabaseError
            No run with this id.
        """
        if status not in ("finished", "interrupted", "failed"):
            raise InputError(f"status must be 'finished', 'interrupted' or 'failed', "
                             f"got {status!r}")
        with self.transaction():
            cur = self.conn.execute(
                "UPDATE ingest_runs SET finished_at = ?, stored = ?, skipped = ?, failed = ?, "
                "status = ? WHERE id = ?",
                (utc_now(), int(stored), int(skipped), int(failed), status, int(run_id)))
            if cur.rowcount == 0:
                raise self._missing(f"no ingest run with id {run_id}")

    def runs(self) -> list:
        """All ingest runs, oldest first, as dicts (``paths`` decoded)."""
        keys = ("id", "started_at", "finished_at", "paths", "workers", "bits_per_surfel",
                "stored", "skipped", "failed", "status")
        out = [dict(zip(keys, r)) for r in self.conn.execute(
            f"SELECT {', '.join(keys)} FROM ingest_runs ORDER BY id")]
        for r in out:
            r["paths"] = json.loads(r["paths"])
        return out

    def last_run(self):
        """The most recent ingest run (dict as in :meth:`runs`), or None."""
        runs = self.runs()
        return runs[-1] if runs else None

    def errors(self, run_id=None) -> list:
        """Recorded ingest failures, oldest first.

        Parameters
        ----------
        run_id : int, optional
            Only this run's failures.

        Returns
        -------
        list of dict
            Keys ``run_id``, ``path``, ``error``, ``at``.
        """
        sql = "SELECT run_id, path, error, at FROM ingest_errors"
        args = ()
        if run_id is not None and not -_MAX_ID - 1 <= int(run_id) <= _MAX_ID:
            return []                               # no run has such an id
        if run_id is not None:
            sql += " WHERE run_id = ?"
            args = (int(run_id),)
        return [dict(zip(("run_id", "path", "error", "at"), r))
                for r in self.conn.execute(sql + " ORDER BY id", args)]

    # ------------------------------------------------------------------ the one-call API
    @classmethod
    def open(cls, path, *, readonly: bool = False, create: bool = True,
             timeout: float = 30.0) -> "Database":
        """Open (and by default create) a database: ``surfidx.Database.open("scans.db")``.

        Parameters
        ----------
        path : str or os.PathLike
        readonly, create, timeout
            As for :class:`Database`.

        Returns
        -------
        Database
        """
        return cls(path, create=create, readonly=readonly, timeout=timeout)
