"""The database commands: ingest, query, get, ls, show, errors (click.testing.CliRunner)."""

from __future__ import annotations

import json
import sqlite3

import numpy as np
import pytest
from click.testing import CliRunner
from PIL import Image

from surfidx import read_surfels
from surfidx.cli import cli
from surfidx.cli.db import parse_model_ref
from surfidx.database import Database

from helpers import DECODED, OBJ, fake_processor, make_tree

def invoke(args, obj=OBJ):
    """Run the CLI; an ``ingest`` without ``--workers`` gets ``--workers 1`` (ids in file
    order; the default worker count is tested in test_ingest.py)."""
    args = [str(a) for a in args]
    if args[:1] == ["ingest"] and not {"-j", "--workers"} & set(args):
        args += ["--workers", "1"]
    return CliRunner().invoke(cli, args, obj=obj)


@pytest.fixture
def filled(tmp_path):
    """A database holding the 6 models of make_tree (one failing file recorded)."""
    root = make_tree(tmp_path / "data", 6, extra={"bad.ply": "FAIL"})
    db = tmp_path / "s.db"
    r = invoke(["ingest", root, "--db", db, "--no-progress"])
    assert r.exit_code == 1, r.output                  # stored what it could, then exit 1
    assert "Error: 1 file(s) failed (the others were stored)" in r.stderr
    return root, db


def test_ingest_summary_and_rerun(filled, tmp_path):
    root, db = filled
    r = invoke(["ingest", root, "--db", db, "--workers", 2, "--json", "--no-progress"])
    assert r.exit_code == 1, r.output
    out = json.loads(r.stdout)
    assert (out["stored"], out["skipped"], out["failed"]) == (0, 6, 1)
    assert out["errors"][0]["error"].endswith("deliberately unusable model")
    r = invoke(["ingest", root / "m0.ply", "--db", tmp_path / "new.db", "--no-progress"])
    assert r.exit_code == 0 and "stored 1, skipped 0, failed 0" in r.stdout


def test_ingest_prints_failures(tmp_path):
    root = make_tree(tmp_path / "data", 1, extra={"bad.ply": "FAIL"})
    r = invoke(["ingest", root, "--db", tmp_path / "x.db", "--no-progress"])
    assert r.exit_code == 1                        # the good file is stored, then exit 1
    assert f"failed: {root / 'bad.ply'}: deliberately unusable model" in r.stderr
    assert "stored 1, skipped 0, failed 1" in r.stdout


def test_query_by_file_returns_example_first(filled, tmp_path):
    root, db = filled
    r = invoke(["query", root / "sub" / "m3.ply", "--db", db, "-k", 3, "--json",
                "--include-self"])
    assert r.exit_code == 0, r.output
    out = json.loads(r.stdout)
    assert list(out) == ["results"] and len(out["results"]) == 3
    first = out["results"][0]
    assert set(first) == {"id", "name", "version", "source", "distance"}
    assert (first["name"], first["distance"]) == ("m3", pytest.approx(0.0, abs=1e-6))
    assert isinstance(first["id"], int) and isinstance(first["distance"], float)
    assert first["source"] == "sub/m3.ply"
    d = [x["distance"] for x in out["results"]]
    assert d == sorted(d)
    with Database(db) as database:                    # the example was not stored
        assert database.count() == 6


def test_query_by_id_table_and_weights(filled):
    _, db = filled
    r = invoke(["query", "id:4", "--db", db, "-k", 10, "--include-self"])   # m1, coloured
    assert r.exit_code == 0, r.output
    lines = r.stdout.splitlines()
    assert lines[0].split() == ["rank", "id", "name", "version", "distance", "source"]
    assert lines[1].split()[:3] == ["1", "4", "m1"] and len(lines) == 7
    shape_only = json.loads(invoke(["query", "id:4", "--db", db, "--json", "--include-self",
                                    "--shape-weight", 1]).stdout)["results"]
    tex_heavy = json.loads(invoke(["query", "id:4", "--db", db, "--json", "--include-self",
                                   "--shape-weight", 0]).stdout)["results"]
    assert shape_only[0]["id"] == tex_heavy[0]["id"] == 4
    assert [x["distance"] for x in shape_only] != [x["distance"] for x in tex_heavy]


def test_query_sheet(filled, tmp_path):
    _, db = filled
    out = tmp_path / "sheet.png"
    r = invoke(["query", "id:1", "--db", db, "-k", 4, "--sheet", out])
    assert r.exit_code == 0, r.output
    im = Image.open(out)
    assert im.size == (5 * 160, 190)
    # The query tile holds the stored thumbnail's solid colour.
    with Database(db) as d:
        import io
        colour = Image.open(io.BytesIO(d.get_thumbnail(1))).convert("RGB").getpixel((0, 0))
    assert im.convert("RGB").getpixel((80, 80)) == colour


def test_get_writes_ply_at_rate(filled, tmp_path):
    _, db = filled
    DECODED.clear()
    out = tmp_path / "m.ply"
    r = invoke(["get", "m4", "--db", db, "-o", out])
    assert r.exit_code == 0, r.output
    assert len(read_surfels(out)) == 16 and DECODED[-1] == (64, None)
    r = invoke(["get", "id:1", "--db", db, "-o", out, "--bits-per-surfel", 5])
    assert r.exit_code == 0 and "5 surfels (PLY) at 5 bits/surfel (model 1, m0)" in r.stdout
    assert len(read_surfels(out)) == 5 and DECODED[-1] == (64, 5.0)
    r = invoke(["get", "m4", "--db", db, "-o", out, "--level", 2])      # passed to the decoder
    assert r.exit_code == 0 and len(read_surfels(out)) == 5 and DECODED[-1] == (64, None, 2)


def test_get_of_the_stream_imports_no_codec(filled, tmp_path):
    """``surfidx get NAME -o FILE.sfz`` copies the stored stream: it loads neither the codec's
    kernels (numba) nor scipy, and writes the stored bytes."""
    import subprocess
    import sys

    _, db = filled
    out = tmp_path / "m.sfz"
    code = ("import sys, json\n"
            "from surfidx.cli import cli\n"
            f"cli.main(['get', 'm4', '--db', {str(db)!r}, '-o', {str(out)!r}], "
            "standalone_mode=False)\n"
            "print(json.dumps(sorted({m.split('.')[0] for m in sys.modules} & "
            "{'numba', 'scipy', 'trimesh', 'PIL'})))\n")
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         timeout=120, check=True)
    assert json.loads(res.stdout.splitlines()[-1]) == []
    with Database(db) as d:
        assert out.read_bytes() == d.get_sfz(d.resolve("m4"))


def test_ls_show_errors(filled):
    root, db = filled
    r = invoke(["ls", "--db", db, "--json"])
    models = json.loads(r.stdout)["models"]
    assert [m["name"] for m in models] == ["m0", "m2", "m4", "m1", "m3", "m5"]
    r = invoke(["ls", "--db", db])
    assert r.exit_code == 0 and r.stdout.splitlines()[0].startswith("id")
    assert len(r.stdout.splitlines()) == 7
    r = invoke(["show", "m1", "--db", db, "--json"])
    out = json.loads(r.stdout)
    assert out["model"]["name"] == "m1" and out["model"]["has_color"] is True
    assert out["model"]["descriptors"] == {"shape": 12, "texture": 6}
    assert out["model"]["asset"]["bytes"] == 64 and out["model"]["bbox_max"] == [1, 1, 1]
    assert out["last_run"]["failed"] == 1
    assert out["last_run"]["errors"][0]["path"] == str(root / "bad.ply")
    r = invoke(["show", "4", "--db", db])
    assert r.exit_code == 0 and "descriptors      shape (12), texture (6)" in r.stdout
    assert "deliberately unusable model" in r.stdout
    for args in (["errors"], ["ls", "--errors"]):
        r = invoke(args + ["--db", db])
        assert r.exit_code == 0 and "bad.ply" in r.stdout and "deliberately" in r.stdout
    errs = json.loads(invoke(["errors", "--db", db, "--json", "--run", 1]).stdout)["errors"]
    assert len(errs) == 1 and errs[0]["run_id"] == 1
    r = invoke(["errors", "--db", db, "--run", 1])
    assert r.exit_code == 0


def test_db_from_environment(filled, monkeypatch):
    _, db = filled
    monkeypatch.setenv("SURFIDX_DB", str(db))
    r = invoke(["ls", "--json"])
    assert r.exit_code == 0 and len(json.loads(r.stdout)["models"]) == 6


def test_no_errors_and_empty_db(tmp_path):
    root = make_tree(tmp_path / "d", 1)
    db = tmp_path / "e.db"
    invoke(["ingest", root, "--db", db, "--no-progress"])
    r = invoke(["errors", "--db", db])
    assert r.exit_code == 0 and r.stdout.strip() == "no ingest failures"


@pytest.mark.parametrize("args, message", [
    (["query", "id:1"], "nothing.db: no such database"),
    (["get", "1", "-o", "x.ply"], "nothing.db: no such database"),
    (["ls"], "nothing.db: no such database"),
])
def test_missing_database(tmp_path, args, message):
    db = tmp_path / "nothing.db"
    r = invoke(args + ["--db", db])
    assert r.exit_code == 1 and message in r.output
    assert r.output.startswith("Error: ") and len(r.output.strip().splitlines()) == 1
    assert not db.exists()


def test_cli_errors(filled, tmp_path):
    root, db = filled
    cases = [
        (["get", "99", "-o", tmp_path / "x.ply"], "no model with id 99"),
        (["get", "nobody", "-o", tmp_path / "x.ply"], "no model named 'nobody'"),
        (["show", "id:77"], "no model with id 77"),
        (["query", "id:x"], "'id:x' is not a model id"),
        (["query", tmp_path / "none.ply"], "none.ply: no such model file"),
        (["errors", "--run", 9], "no ingest run with id 9"),
    ]
    for args, message in cases:
        r = invoke(args + ["--db", db])
        assert r.exit_code == 1, (args, r.output)
        assert r.output.startswith("Error: ") and message in r.output, r.output
    r = invoke(["ingest", tmp_path / "missing", "--db", db])
    assert r.exit_code == 1 and "missing: no such file or folder" in r.output


def test_foreign_database_cli(tmp_path):
    path = tmp_path / "shop.db"
    conn = sqlite3.connect(path)
    conn.execute("CREATE TABLE orders (id INTEGER)")
    conn.commit()
    conn.close()
    make_tree(tmp_path / "data", 1)
    for args in (["ls"], ["ingest", tmp_path / "data"]):
        r = invoke(args + ["--db", path, "--no-progress"] if args[0] == "ingest"
                   else args + ["--db", path])
        assert r.exit_code == 1
        assert r.output.startswith(f"Error: {path}: not a surfidx database")


def test_missing_processor_and_decoder(filled, tmp_path, monkeypatch):
    import surfidx.pipeline as pipeline

    root, db = filled
    monkeypatch.delattr(pipeline, "describe_model", raising=False)
    r = invoke(["query", root / "m0.ply", "--db", db], obj={})    # a file query describes
    assert r.exit_code == 1 and "describe_model is not available" in r.output
    monkeypatch.delattr(pipeline, "process_model", raising=False)
    r = invoke(["ingest", root, "--db", db, "--no-progress"], obj={})
    assert r.exit_code == 1 and "process_model is not available" in r.output
    monkeypatch.setitem(__import__("sys").modules, "surfidx.codec", None)
    r = invoke(["get", "1", "--db", db, "-o", tmp_path / "x.ply"], obj={})
    assert r.exit_code == 1 and "surfidx.codec.decode is not available" in r.output


def test_parse_model_ref():
    assert parse_model_ref("12") == 12 and parse_model_ref("id:7") == 7
    assert parse_model_ref("bunny") == "bunny"
    with pytest.raises(Exception, match="'id:q' is not a model id"):
        parse_model_ref("id:q")


def test_ingest_scheduler_without_distributed(tmp_path, monkeypatch):
    import sys

    root = make_tree(tmp_path / "data", 1)
    monkeypatch.setitem(sys.modules, "distributed", None)
    r = invoke(["ingest", root, "--db", tmp_path / "x.db", "--scheduler", "tcp://127.0.0.1:1"])
    assert r.exit_code == 1
    assert "Error: ingestion on a Dask cluster needs dask.distributed" in r.output
    assert "pip install 'surfidx[distributed]'" in r.output
    assert not (tmp_path / "x.db").exists()


# ---------------------------------------------------------------------- one line, no writes (#30)
def _one_error_line(r, message):
    assert r.exit_code == 1, r.output
    assert r.output.startswith("Error: ") and message in r.output, r.output
    assert len(r.output.strip().splitlines()) == 1, r.output


def _digest(path):
    import hashlib

    return hashlib.sha256(path.read_bytes()).hexdigest()


READ_COMMANDS = [["ls"], ["ls", "--errors"], ["errors"], ["show", "1"], ["query", "id:1"],
                 ["get", "1", "-o", "out.ply"]]


@pytest.mark.parametrize("big", ["9223372036854775808", "id:99999999999999999999999"])
def test_ids_of_64_bits_and_more(filled, tmp_path, big):
    _, db = filled
    n = big.removeprefix("id:")
    for args in (["show", big], ["get", big, "-o", tmp_path / "x.ply"], ["query", f"id:{n}"]):
        _one_error_line(invoke(args + ["--db", db]), f"no model with id {n}")
    _one_error_line(invoke(["errors", "--run", n, "--db", db]), f"no ingest run with id {n}")


def test_damaged_database_is_one_line(filled, tmp_path):
    from helpers import damage_database

    _, db = filled
    damage_database(db)
    for args in (["show", "1"], ["query", "id:1"], ["get", "1", "-o", tmp_path / "x.ply"],
                 ["ls"], ["redescribe"]):
        _one_error_line(invoke(args + ["--db", db]), "the database file is damaged")


def test_foreign_file_with_meta_and_models_is_one_line_and_untouched(tmp_path):
    from helpers import foreign_database

    path = tmp_path / "app.db"
    foreign_database(path, user_version=1)
    before = _digest(path)
    root = make_tree(tmp_path / "data", 1)
    for args in READ_COMMANDS + [["ingest", root, "--no-progress"], ["redescribe"]]:
        _one_error_line(invoke(args + ["--db", path]), f"{path}: not a surfidx database")
    assert _digest(path) == before


@pytest.mark.parametrize("content", [None, b""])
def test_read_commands_on_missing_or_empty_file_write_nothing(tmp_path, content, monkeypatch):
    monkeypatch.chdir(tmp_path)
    path = tmp_path / "e.db"
    if content is not None:
        path.write_bytes(content)
    message = "no such database" if content is None else "is an empty file"
    for args in READ_COMMANDS + [["redescribe"]]:
        _one_error_line(invoke(args + ["--db", path]), f"{path}: {message}")
    assert sorted(p.name for p in tmp_path.iterdir()) == ([] if content is None else ["e.db"])
    if content is not None:
        assert path.read_bytes() == b""


def test_read_commands_never_write(filled, tmp_path):
    root, db = filled
    con = sqlite3.connect(db)                     # as the previous surfidx left it: no marker
    con.execute("PRAGMA application_id = 0")
    con.commit()
    con.close()
    before = _digest(db)
    for args in READ_COMMANDS:
        args = [tmp_path / a if a == "out.ply" else a for a in args]
        r = invoke(args + ["--db", db])
        assert r.exit_code == 0, (args, r.output)
    assert _digest(db) == before
    (root / "new.ply").write_text("model new")                   # a write marks it
    assert invoke(["ingest", root / "new.ply", "--db", db, "--no-progress"]).exit_code == 0
    con = sqlite3.connect(db)
    assert con.execute("PRAGMA application_id").fetchone()[0] == int.from_bytes(b"SFDX", "big")
    con.close()


def test_read_only_database_ingest_is_one_line(filled, tmp_path, monkeypatch):
    import surfidx.db.catalog as dbmod

    root, db = filled
    (root / "new.ply").write_text("model new")
    before = _digest(db)
    real_connect = dbmod.connect
    monkeypatch.setattr(dbmod, "connect", lambda p, mode, t: real_connect(p, "ro", t))
    r = invoke(["ingest", root, "--db", db, "--no-progress"])
    _one_error_line(r, "cannot write: the database is read-only (attempt to write a readonly "
                       "database)")
    assert _digest(db) == before


def test_full_disk_ingest_is_one_line_and_the_database_stays_whole(tmp_path, monkeypatch):
    import surfidx.db.catalog as dbmod

    root = tmp_path / "data"
    root.mkdir()
    for i in range(12):
        (root / f"m{i:02d}.ply").write_text(f"model {i}")
    real_connect = dbmod.connect

    def small(p, mode, t):
        conn = real_connect(p, mode, t)
        conn.execute("PRAGMA max_page_count = 30")
        return conn

    def big_processor(path, **kw):
        m = fake_processor(path, **kw)
        m.stream = bytes(np.random.default_rng(len(str(path))).integers(0, 256, 9000, np.uint8))
        return m

    db = tmp_path / "full.db"
    monkeypatch.setattr(dbmod, "connect", small)
    import ingest

    with pytest.raises(dbmod.DatabaseError, match="the disk is full"):
        ingest.run([root], db=db, processor=big_processor, progress=False, batch=1)
    r = invoke(["ingest", root, "--db", db, "--no-progress"], obj={"processor": big_processor})
    _one_error_line(r, f"{db}: the disk is full (database or disk is full)")
    monkeypatch.undo()
    with Database(db) as d:
        assert d.conn.execute("PRAGMA integrity_check").fetchone()[0] == "ok"
        n = d.count()
        assert 0 < n < 12 and d.db["assets"].count == d.db["thumbnails"].count == n
        runs = d.runs()                                   # the counts are what was committed
        assert [r["status"] for r in runs] == ["failed", "failed"]
        assert sum(r["stored"] for r in runs) == n


def _weird_tree(root):
    from helpers import bytes_name

    root.mkdir()
    bytes_name(root, b"red\x1b[31mX.ply", b"model red")
    bytes_name(root, b"two\nlines.ply", b"model two lines")
    bytes_name(root, b"caf\xe9.ply", b"model cafe")
    bytes_name(root, b"evil\x1b[2J.obj", b"FAIL")
    return root


def test_names_are_escaped_in_text_and_exact_in_json(tmp_path):
    root = _weird_tree(tmp_path / "data")
    db = tmp_path / "w.db"
    r = invoke(["ingest", root, "--db", db, "--no-progress"])
    assert r.exit_code == 1, r.output
    assert "\x1b" not in r.output and "failed: " in r.stderr and "evil\\x1b[2J.obj" in r.stderr
    assert len(r.stderr.strip().splitlines()) == 2            # the failure, then the exit line
    r = invoke(["ls", "--db", db])
    assert r.exit_code == 0 and "\x1b" not in r.stdout
    lines = r.stdout.splitlines()
    assert len(lines) == 4                                    # header + 3 models, one line each
    assert {ln.split()[1] for ln in lines[1:]} == {"red\\x1b[31mX", "two\\nlines", "caf\\xe9"}
    models = json.loads(invoke(["ls", "--db", db, "--json"]).stdout)["models"]
    assert {m["name"] for m in models} == {"red\x1b[31mX", "two\nlines", "caf\\xe9"}
    for args in (["errors"], ["show", "caf\\xe9"], ["show", "1"], ["query", "id:1"]):
        r = invoke(args + ["--db", db])
        assert r.exit_code == 0 and "\x1b" not in r.stdout, (args, r.output)
    r = invoke(["errors", "--db", db])
    assert len(r.stdout.splitlines()) == 2 and "evil\\x1b[2J.obj" in r.stdout
    errs = json.loads(invoke(["errors", "--db", db, "--json"]).stdout)["errors"]
    assert errs[0]["path"] == str(root / "evil\x1b[2J.obj")
    r = invoke(["show", "caf\\xe9", "--db", db])              # as printed, undecodable byte
    assert r.exit_code == 0 and "name             caf\\xe9\n" in r.stdout
    r = invoke(["show", "nobody\x1b[0m", "--db", db])
    _one_error_line(r, "no model named 'nobody\\x1b[0m'")


def test_skipped_files_are_reported(tmp_path):
    import os

    root = make_tree(tmp_path / "data", 1)
    os.mkfifo(root / "pipe.ply")
    r = invoke(["ingest", root, "--db", tmp_path / "s.db", "--no-progress", "--json"])
    assert r.exit_code == 0, r.output
    out = json.loads(r.stdout)
    assert out["skips"] == [{"path": str(root / "pipe.ply"),
                             "reason": "not a regular file: a named pipe (FIFO)"}]
    r = invoke(["ingest", root, "--db", tmp_path / "s.db", "--no-progress"])
    assert f"skipped: {root / 'pipe.ply'}: not a regular file" in r.stderr


def test_unmapped_sqlite_error_is_one_line():
    import click

    from surfidx.cli.common import command_errors

    @click.command()
    @command_errors
    def boom():
        raise sqlite3.OperationalError("no such table: x\nsecond line")

    r = CliRunner().invoke(boom, [])
    _one_error_line(r, "SQLite error (no such table: x\\nsecond line)")


def test_warnings_are_one_line_and_resource_warnings_are_not_shown():
    """A command's warnings are printed as one line each; a ResourceWarning (which the garbage
    collector may raise during a command for an object that is not the command's) and a
    DeprecationWarning are not."""
    import warnings

    import click

    from surfidx.cli.common import command_errors

    @click.command()
    @command_errors
    def warn():
        warnings.warn("3 degenerate faces were dropped", UserWarning)
        warnings.warn("unclosed file <_io.BufferedReader name=17>", ResourceWarning)
        warnings.warn("old API", DeprecationWarning)

    r = CliRunner().invoke(warn, [])
    assert r.exit_code == 0
    assert r.output.strip().splitlines() == ["warning: 3 degenerate faces were dropped"]
