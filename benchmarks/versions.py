"""Versions and originals: the upgrade of a schema-3 database (what surfidx 0.1.0 made before
model versions) to the current schema, and the size ``ingest --keep-original`` adds.

Upgrade
-------
A schema-3 database of N models is made from ``tests/data/schema3_main.db`` (the two bundled
examples as main's release stored them) by copying its rows N/2 times under new names, hashes
and source paths (streams, descriptors, thumbnails and tags included, so the file's size per
model is a real one), with plain sqlite3. Opening it with :class:`surfidx.Database` then copies
the file beside it (SQLite's online backup) and runs the migrations in one transaction; the
table gives the file's size, the time of the whole open (wall and CPU), and the time of the
backup alone (the same copy, measured once more on its own).

Originals
---------
The bundled examples (``examples/models``: the armadillo OBJ, spot's OBJ with its texture) are
ingested with the real pipeline at the default rate, without and with ``--keep-original``; the
table gives each database's size (pages in use, after a checkpoint), the original files'
bytes and the blobs' bytes. Then spot's OBJ is edited (a comment line appended) and ingested
again as its next version: only the OBJ's bytes are added, the texture's blob is shared. The
ingests' wall time is mostly the pipeline's and follows the machine's load; the originals'
own cost is reading and writing their bytes once more.

Run: ``python benchmarks/versions.py [--sizes 1000 10000] [--markdown]``.
"""

from __future__ import annotations

import argparse
import os
import shutil
import sqlite3
import sys
import tempfile
import time
import warnings
from pathlib import Path

from surfidx.numerics import use_portable_profile  # noqa: E402

use_portable_profile()   # before numpy loads: the bytes the surfidx command makes

from _markdown import Report, add_markdown_option  # noqa: E402

# benchmarks/ingest.py must not shadow the ingest package Database.ingest imports
sys.path[:] = [p for p in sys.path if Path(p or ".").resolve() != Path(__file__).resolve().parent]

from surfidx.database import Database  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
FIXTURE = ROOT / "tests" / "data" / "schema3_main.db"
EXAMPLES = ROOT / "examples" / "models"


def make_schema3(path: Path, n: int) -> None:
    """A schema-3 database of ``n`` models: the fixture's two rows copied ``n / 2`` times."""
    shutil.copy(FIXTURE, path)
    conn = sqlite3.connect(path)
    conn.execute("PRAGMA journal_mode = WAL")
    cols = [r[1] for r in conn.execute("PRAGMA table_info(models)") if r[1] != "id"]
    base = conn.execute("SELECT id FROM models ORDER BY id").fetchall()
    conn.execute("BEGIN")
    for k in range(1, n // len(base)):
        for (mid,) in base:
            new = conn.execute(
                f"INSERT INTO models ({', '.join(cols)}) SELECT "
                + ", ".join("name || ? " if c == "name" else
                            "hex(randomblob(32))" if c == "content_hash" else
                            "replace(source, '/models/', ?)" if c == "source" else c
                            for c in cols)
                + " FROM models WHERE id = ?", (f"-{k}", f"/models/batch{k}/", mid)).lastrowid
            for table in ("assets", "thumbnails", "descriptors", "tags", "model_topology"):
                tcols = [r[1] for r in conn.execute(f"PRAGMA table_info({table})")
                         if r[1] != "model_id"]
                conn.execute(f"INSERT INTO {table} (model_id, {', '.join(tcols)}) SELECT ?, "
                             f"{', '.join(tcols)} FROM {table} WHERE model_id = ?", (new, mid))
    conn.execute("COMMIT")
    conn.execute("PRAGMA wal_checkpoint(TRUNCATE)")
    conn.close()


def upgrade_rows(sizes, folder: Path) -> list:
    rows = []
    for n in sizes:
        path = folder / f"s3_{n}.db"
        make_schema3(path, n)
        size = path.stat().st_size
        t0, c0 = time.perf_counter(), time.process_time()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)
            db = Database(path)
        wall, cpu = time.perf_counter() - t0, time.process_time() - c0
        with db:
            count = db.count()
            backup = db.backup_path
        # the backup alone, once more (what part of the open it was)
        src = sqlite3.connect(backup)
        t0 = time.perf_counter()
        dest = sqlite3.connect(folder / "copy.db")
        src.backup(dest)
        dest.close()
        src.close()
        copy = time.perf_counter() - t0
        (folder / "copy.db").unlink()
        rows.append([f"{count:,}", f"{size / 1e6:.1f}", f"{wall:.2f}", f"{cpu:.2f}",
                     f"{copy:.2f}", f"{max(wall - copy, 0.0):.2f}"])
        for f in folder.glob(f"s3_{n}.db*"):
            f.unlink()
    return rows


def used_bytes(path: Path) -> int:
    conn = sqlite3.connect(path)
    conn.execute("PRAGMA wal_checkpoint(TRUNCATE)")
    n = conn.execute("PRAGMA page_count").fetchone()[0] - conn.execute(
        "PRAGMA freelist_count").fetchone()[0]
    size = n * conn.execute("PRAGMA page_size").fetchone()[0]
    conn.close()
    return size


def originals_rows(folder: Path, workers: int) -> list:
    src = folder / "models"
    shutil.copytree(EXAMPLES, src)
    (src / "README.md").unlink()
    files = sum(f.stat().st_size for f in src.rglob("*") if f.is_file()
                and f.suffix in (".obj", ".png"))
    rows = []
    for keep in (False, True):
        path = folder / f"keep_{keep}.db"
        t0 = time.perf_counter()
        with Database(path) as db:
            s = db.ingest([src], workers=workers, keep_original=keep)
            assert s.stored == 2, s.errors
            blobs = db.conn.execute("SELECT coalesce(sum(bytes), 0) FROM blobs").fetchone()[0]
        rows.append(["--keep-original" if keep else "without", f"{used_bytes(path):,}",
                     f"{files:,}", f"{blobs:,}", f"{time.perf_counter() - t0:.1f}"])
    base = int(rows[0][1].replace(",", ""))
    for r in rows:
        r.insert(2, f"{100 * (int(r[1].replace(',', '')) / base - 1):+.0f} %")
    # a second version of spot: only the edited OBJ is added
    obj = src / "spot" / "spot_triangulated.obj"
    with open(obj, "a") as fh:
        fh.write("# edited\n")
    path = folder / "keep_True.db"
    before = used_bytes(path)
    t0 = time.perf_counter()
    with Database(path) as db:
        db.ingest([obj], workers=1, keep_original=True)
        blobs = db.conn.execute("SELECT coalesce(sum(bytes), 0) FROM blobs").fetchone()[0]
        version = db.get_model("spot_triangulated")["version"]
    after = used_bytes(path)
    rows.append([f"spot edited (version {version})", f"{after:,}",
                 f"+{after - before:,} B", f"{obj.stat().st_size:,}", f"{blobs:,}",
                 f"{time.perf_counter() - t0:.1f}"])
    return rows


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[1000, 10000])
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--skip-originals", action="store_true")
    add_markdown_option(ap, "versions")
    args = ap.parse_args(argv)
    report = Report("versions", "Versions and originals: upgrade time, original files' size",
                    args.markdown,
                    note="The upgrade of a schema-3 database (surfidx 0.1.0 before model "
                         "versions) on its first open, and the size `ingest --keep-original` "
                         "adds to the bundled examples; see the script's notes. The ingests' "
                         "wall time is mostly the pipeline's and follows the machine's load "
                         f"(load average {os.getloadavg()[0]:.1f} at the start).")
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        report.table(["models", "file MB", "open + upgrade s", "CPU s", "backup alone s",
                      "upgrade without backup s"], upgrade_rows(args.sizes, folder),
                     title="Upgrade of a schema-3 database (3 -> 4), once per size")
        if not args.skip_originals:
            report.table(["ingest", "database bytes", "size vs without", "original files B",
                          "blob bytes", "wall s"], originals_rows(folder, args.workers),
                         title="--keep-original on examples/models (default rate)")
    report.finish(None if argv is None else [sys.argv[0], *argv])


if __name__ == "__main__":
    main()
