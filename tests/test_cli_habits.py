"""One set of command-line habits on every command: ``-q/--quiet``, ``-v/--verbose``, ``--json``
(with ``{"error": ...}`` on failure) and ``--db``/``$SURFIDX_DB`` where the model database is
used; old spellings kept as hidden aliases."""

from __future__ import annotations

import json
import os
import shutil

import click
import numpy as np
import pytest
from click.testing import CliRunner

from surfidx import TriangleMesh, write_ply
from surfidx.cli import cli
from surfidx.cli.common import DB_ENVVAR, DEFAULT_DB, uses_database

from conftest import EXAMPLES, icosphere_mesh
from helpers import OBJ, foreign_database, make_tree

#: The commands that use the model database; every other command is in OTHER_COMMANDS. A new
#: command must be put in one of the two (the walk below fails on an unlisted one).
DB_COMMANDS = {"ingest", "query", "get", "ls", "show", "errors", "redescribe", "rm", "rename",
               "tag", "untag", "upgrade"}
OTHER_COMMANDS = {"convert", "info", "eval", "render", "geodesic", "parameterize", "resample",
                  "encode", "decode", "datasette-metadata"}

#: Old spellings kept working but hidden from --help: command -> options.
HIDDEN_ALIASES = {"ingest": {"--no-progress"}}


def invoke(args, obj=OBJ, **kw):
    """Run the CLI (with the fake processor and decoder unless ``obj`` says otherwise); an
    ``ingest`` gets ``--workers 1``."""
    args = [str(a) for a in args]
    if args[:1] == ["ingest"] and not {"-j", "--workers"} & set(args):
        args += ["--workers", "1"]
    return CliRunner().invoke(cli, args, obj=obj, **kw)


def walk(command, ctx, path=()):
    """``(name, command)`` of every command under ``command``, through groups of groups."""
    if isinstance(command, click.Group):
        for name in command.list_commands(ctx):
            sub = command.get_command(ctx, name)
            with click.Context(sub, parent=ctx, info_name=name) as sub_ctx:
                yield from walk(sub, sub_ctx, path + (name,))
    else:
        yield " ".join(path), command


def commands():
    with click.Context(cli, info_name="surfidx") as ctx:
        return dict(walk(cli, ctx))


def option(command, opt):
    """The option of ``command`` that ``opt`` spells, or None."""
    return next((p for p in command.params
                 if isinstance(p, click.Option) and opt in p.opts + p.secondary_opts), None)


# ---------------------------------------------------------------------- the options, declared
def test_every_command_is_classified():
    assert set(commands()) == DB_COMMANDS | OTHER_COMMANDS
    assert not DB_COMMANDS & OTHER_COMMANDS


@pytest.mark.parametrize("name", sorted(DB_COMMANDS | OTHER_COMMANDS))
def test_every_command_takes_the_habits(name):
    command = commands()[name]
    quiet, verbose, as_json = option(command, "--quiet"), option(command, "--verbose"), \
        option(command, "--json")
    assert quiet is not None and quiet.opts == ["-q", "--quiet"] and quiet.is_flag, name
    assert verbose is not None and verbose.opts == ["-v", "--verbose"] and verbose.is_flag, name
    assert as_json is not None and as_json.is_flag, name
    db = option(command, "--db")
    assert uses_database(command) == (name in DB_COMMANDS), name
    if name in DB_COMMANDS:
        assert db is not None, f"{name} uses the database but takes no --db"
        assert db.envvar == DB_ENVVAR == "SURFIDX_DB" and db.default == DEFAULT_DB, name
    else:
        assert db is None, name


@pytest.mark.parametrize("name", sorted(DB_COMMANDS | OTHER_COMMANDS))
def test_help_shows_the_habits_and_hides_the_old_spellings(name):
    command = commands()[name]
    hidden = {o for p in command.params if getattr(p, "hidden", False) for o in p.opts}
    assert hidden == HIDDEN_ALIASES.get(name, set()), name
    r = invoke([*name.split(), "--help"])
    assert r.exit_code == 0, r.output
    for text in ("-q, --quiet", "-v, --verbose", "--json"):
        assert text in r.output, (name, text)
    assert ("--db PATH" in r.output) == (name in DB_COMMANDS)
    for old in hidden:
        assert old not in r.output, (name, old)


def test_db_falls_back_to_the_environment_then_the_default(tmp_path, monkeypatch):
    root = make_tree(tmp_path / "data", 2)
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("SURFIDX_DB", str(tmp_path / "env.db"))
    assert invoke(["ingest", root, "-q"]).exit_code == 0
    assert (tmp_path / "env.db").exists() and not (tmp_path / DEFAULT_DB).exists()
    r = invoke(["ls", "--json"])
    assert r.exit_code == 0 and len(json.loads(r.stdout)["models"]) == 2
    monkeypatch.delenv("SURFIDX_DB")
    r = invoke(["ls", "--json"])
    assert r.exit_code == 1
    assert json.loads(r.stdout)["error"].startswith(f"{DEFAULT_DB}: no such database")


# ---------------------------------------------------------------------- --json on failure
def _failing(tmp_path):
    """Command name -> arguments that make it fail (a missing file, a foreign database) and a
    part of the message."""
    missing = tmp_path / "missing.ply"
    foreign = tmp_path / "shop.db"
    foreign_database(foreign)
    root = make_tree(tmp_path / "data", 1)
    not_ours = f"{foreign}: not a surfidx database"
    db = ["--db", foreign]
    return {
        "convert": (["convert", missing, "-o", tmp_path / "o.ply"], "missing.ply"),
        "info": (["info", missing], "missing.ply"),
        "eval": (["eval", missing, missing], "missing.ply"),
        "render": (["render", missing, "-o", tmp_path / "o.png"], "missing.ply"),
        "geodesic": (["geodesic", missing, "--source", 0, "--target", 1], "missing.ply"),
        "parameterize": (["parameterize", missing, "-o", tmp_path / "o.ply"], "missing.ply"),
        "resample": (["resample", missing, "-o", tmp_path / "o.ply"], "missing.ply"),
        "encode": (["encode", missing, "-o", tmp_path / "o.sfz", "--bits-per-surfel", 4],
                   "missing.ply"),
        "decode": (["decode", tmp_path / "missing.sfz", "-o", tmp_path / "o.ply"],
                   "missing.sfz"),
        "datasette-metadata": (["datasette-metadata", "-o", tmp_path / "nowhere" / "m.json"],
                               "nowhere"),
        "ingest": (["ingest", root, *db], not_ours),
        "query": (["query", "id:1", *db], not_ours),
        "get": (["get", "1", "-o", tmp_path / "o.ply", *db], not_ours),
        "ls": (["ls", *db], not_ours),
        "show": (["show", "1", *db], not_ours),
        "errors": (["errors", *db], not_ours),
        "redescribe": (["redescribe", *db], not_ours),
        "rm": (["rm", "1", *db], not_ours),
        "rename": (["rename", "1", "new", *db], not_ours),
        "tag": (["tag", "1", "t", *db], not_ours),
        "untag": (["untag", "1", "t", *db], not_ours),
        "upgrade": (["upgrade", *db], not_ours),
    }


def test_every_command_fails_as_json(tmp_path):
    cases = _failing(tmp_path)
    assert set(cases) == DB_COMMANDS | OTHER_COMMANDS
    for name, (args, message) in cases.items():
        r = invoke(args + ["--json"])
        assert r.exit_code == 1, (name, r.output)
        out = json.loads(r.stdout)                      # one JSON object, nothing else
        assert list(out) == ["error"] and message in out["error"], (name, out)
        assert "Traceback" not in r.output and not r.stdout.startswith("Error"), name
        r = invoke(args)                                # and without --json: one line
        assert r.exit_code == 1 and r.stdout == "", (name, r.output)
        assert r.stderr.startswith("Error: ") and message in r.stderr, (name, r.stderr)
        assert len(r.stderr.strip().splitlines()) == 1, (name, r.stderr)


def test_usage_errors_as_json(tmp_path):
    r = invoke(["decode", tmp_path / "x.sfz", "--json"])           # -o missing
    assert r.exit_code == 2
    assert json.loads(r.stdout) == {"error": "Missing option '-o' / '--output'."}
    r = invoke(["get", "1", "-o", tmp_path / "x.ply", "--level", "high", "--json"])
    assert r.exit_code == 2 and "'high' is not a valid integer" in json.loads(r.stdout)["error"]
    r = invoke(["ls", "-q", "-v", "--json"])
    assert r.exit_code == 2
    assert json.loads(r.stdout) == {"error": "--quiet and --verbose exclude each other"}
    r = invoke(["no-such-command", "--json"])
    assert r.exit_code == 2 and "No such command" in json.loads(r.stdout)["error"]
    r = invoke(["decode", tmp_path / "x.sfz"])                      # without --json: click's
    assert r.exit_code == 2 and "Missing option '-o' / '--output'" in r.stderr
    assert r.stdout == ""


# ---------------------------------------------------------------------- -q and -v
@pytest.fixture(scope="module")
def small(tmp_path_factory):
    """A small coloured closed mesh (a level-3 icosphere, 642 vertices) as PLY, and its .sfz."""
    root = tmp_path_factory.mktemp("small")
    v, f = icosphere_mesh(3)
    v = v * [1.0, 1.2, 0.9]
    col = np.clip((v + 1) * 127.5, 0, 255).astype(np.uint8)
    ply = root / "small.ply"
    write_ply(TriangleMesh(v, f, vertex_colors=col, name="small").to_surfels(), ply)
    sfz = root / "small.sfz"
    r = invoke(["encode", ply, "-o", sfz, "--bits-per-surfel", 8, "--level", 3, "-q"])
    assert r.exit_code == 0, r.output
    return ply, sfz


def test_quiet_runs_print_nothing_on_stderr(small, tmp_path):
    """On a terminal (the context object's "terminal"), -q leaves stderr empty where the
    progress display would show."""
    ply, sfz = small
    terminal = {**OBJ, "terminal": True}
    runs = [["convert", ply, "-o", tmp_path / "c.ply"], ["info", ply], ["info", sfz],
            ["decode", sfz, "-o", tmp_path / "d.ply"], ["decode", sfz, "-o", tmp_path / "d.sfz",
                                                        "--bits-per-surfel", 4],
            ["eval", ply, tmp_path / "d.ply"], ["render", ply, "-o", tmp_path / "r.png",
                                                "--size", 32],
            ["geodesic", ply, "--source", 0, "--target", 5]]
    for args in runs:
        r = invoke(args, obj=terminal)
        assert r.exit_code == 0, (args, r.output)
        assert "reading\u2026" in r.stderr, args                  # the display, without -q
        r = invoke(args + ["-q"], obj=terminal)
        assert r.exit_code == 0, (args, r.output)
        assert r.stderr == "" and r.stdout, args
        r = invoke(args + ["--quiet", "--json"], obj=terminal)
        assert r.exit_code == 0 and r.stderr == "", args
        json.loads(r.stdout)


def test_quiet_ingest_hides_bar_and_notes_but_not_failures(tmp_path):
    root = make_tree(tmp_path / "data", 2, extra={"bad.ply": "FAIL"})
    os.mkfifo(root / "pipe.ply")
    terminal = {**OBJ, "terminal": True}
    r = invoke(["ingest", root, "--db", tmp_path / "a.db"], obj=terminal)
    assert r.exit_code == 1
    assert "ingest:" in r.stderr and "skipped: " in r.stderr and "failed: " in r.stderr
    r = invoke(["ingest", root, "--db", tmp_path / "b.db", "-q"], obj=terminal)
    assert r.exit_code == 1 and "stored 2, skipped 1, failed 1" in r.stdout
    assert r.stderr.splitlines() == [
        f"failed: {root / 'bad.ply'}: deliberately unusable model",
        "Error: 1 file(s) failed (the others were stored); see `surfidx errors`"]


def test_no_progress_is_a_hidden_alias_of_quiets_bar(tmp_path):
    """``ingest --no-progress`` (the old spelling) hides the bar; the notes stay."""
    root = make_tree(tmp_path / "data", 2)
    os.mkfifo(root / "pipe.ply")
    r = invoke(["ingest", root, "--db", tmp_path / "a.db", "--no-progress"],
               obj={**OBJ, "terminal": True})
    assert r.exit_code == 0, r.output
    assert r.stderr.splitlines() == [f"skipped: {root / 'pipe.ply'}: not a regular file: a "
                                     "named pipe (FIFO)"]
    assert "--no-progress" not in invoke(["ingest", "--help"]).output


def test_verbose_prints_stage_times_and_details(small, tmp_path):
    ply, sfz = small
    r = invoke(["decode", sfz, "-o", tmp_path / "d.ply", "-v"])
    assert r.exit_code == 0, r.output
    stages = [ln.split()[0] for ln in r.stderr.splitlines()]
    assert stages == ["read", "decode", "write", "total"]
    r = invoke(["eval", ply, tmp_path / "d.ply", "-v", "--json"])
    assert r.exit_code == 0, r.output
    assert f"reference {ply}: 642 surfels, colour" in r.stderr
    assert "evaluate" in [ln.split()[0] for ln in r.stderr.splitlines()]
    json.loads(r.stdout)                                      # stdout stays JSON
    root = make_tree(tmp_path / "data", 2)
    db = tmp_path / "v.db"
    r = invoke(["ingest", root, "--db", db, "-v"])
    assert r.exit_code == 0 and f"database {db}" in r.stderr and "stored ids: 1, 2" in r.stderr
    r = invoke(["ls", "--db", db, "--verbose"])
    assert r.exit_code == 0 and r.stderr.splitlines() == [f"database {db} (read-only)",
                                                           "2 model(s)"]
    assert invoke(["ls", "--db", db]).stderr == ""


# ---------------------------------------------------------------------- the gaps filled
def test_datasette_metadata_json(tmp_path):
    r = invoke(["datasette-metadata", "--json"])
    assert r.exit_code == 0 and "databases" in json.loads(r.stdout)
    out = tmp_path / "meta.json"
    r = invoke(["datasette-metadata", "-o", out, "--json"])
    assert r.exit_code == 0, r.output
    assert json.loads(r.stdout) == {"output": str(out), "bytes": out.stat().st_size}


def test_eval_takes_the_references_texture(tmp_path):
    src = EXAMPLES / "spot"
    obj = tmp_path / "spot.obj"                 # alone: its texture is not found by itself
    shutil.copy(src / "spot_triangulated.obj", obj)
    png = src / "spot_texture.png"
    coloured = tmp_path / "coloured.ply"
    assert invoke(["convert", obj, "-o", coloured, "--texture", png, "-q"]).exit_code == 0
    r = invoke(["eval", obj, coloured, "--json"])
    assert r.exit_code == 0, r.output
    assert json.loads(r.stdout)["psnr_y"] is None             # the reference has no colour
    r = invoke(["eval", obj, coloured, "--texture", png, "--json"])
    assert r.exit_code == 0, r.output
    assert json.loads(r.stdout)["psnr_y"] == float("inf")     # the same colours
    r = invoke(["eval", coloured, obj, "--test-texture", png, "--json"])
    assert r.exit_code == 0 and json.loads(r.stdout)["psnr_y"] == float("inf")


def test_decode_and_get_share_their_options():
    names = lambda c: {o for p in c.params for o in p.opts + p.secondary_opts}  # noqa: E731
    cmds = commands()
    shared = {"-o", "--output", "--format", "--bits-per-surfel", "--level", "--mesh",
              "--surfels", "--max-surfels", "--ascii"}
    assert shared <= names(cmds["decode"]) and shared <= names(cmds["get"])
    for a, b in (("decode", "get"), ("get", "decode")):
        for opt in shared - {"-o", "--output"}:
            pa, pb = option(cmds[a], opt), option(cmds[b], opt)
            assert (pa.help, pa.type.name, pa.name) == (pb.help, pb.type.name, pb.name), opt
    # get's -o says what decode's says, and that several models go into a folder
    po, go = option(cmds["decode"], "-o"), option(cmds["get"], "-o")
    assert go.help.startswith(po.help) and "folder" in go.help and po.name == go.name
    assert {"--mesh", "--surfels"} <= names(cmds["resample"])


def test_a_partial_failure_as_json_is_one_object(tmp_path):
    """``redescribe --json`` with models that fail: the summary alone on stdout, exit 1 (no
    error line after it)."""
    root = make_tree(tmp_path / "data", 2)
    db = tmp_path / "r.db"
    assert invoke(["ingest", root, "--db", db, "-q"]).exit_code == 0   # streams of noise
    r = invoke(["redescribe", "--db", db, "--all", "--json"])
    assert r.exit_code == 1 and r.stderr == ""
    out = json.loads(r.stdout)
    assert out["redescribed"] == 0 and len(out["failed"]) == 2
    r = invoke(["redescribe", "--db", db, "--all"])
    assert r.exit_code == 1 and "Error: 2 model(s) could not be redescribed" in r.stderr
