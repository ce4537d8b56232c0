"""Stage progress: the callback's events in order, results unchanged with one, the CLI's display
(--quiet, --verbose, a terminal), describe_model against process_model, ingest's bar within a
model and its default worker count."""

from __future__ import annotations

import io
import os

import numpy as np
import pytest
from click.testing import CliRunner

import ingest
from surfidx.cli import cli
from surfidx.database import Database
from surfidx.pipeline import describe_model, process_model
from surfidx.progress import STAGES, StageLog, stage_fraction
from surfidx.validate import accepts_keyword

from conftest import icosphere_mesh
from helpers import fake_processor, make_tree

trimesh = pytest.importorskip("trimesh")


@pytest.fixture(scope="module")
def ball(tmp_path_factory):
    """A coloured level-3 icosphere (642 vertices) as a GLB file: a multilevel map of 2 levels."""
    root = tmp_path_factory.mktemp("ball")
    v, f = icosphere_mesh(3)
    v = v * (1 + 0.2 * v[:, :1] ** 2)              # not a sphere: the map has work to do
    col = np.clip((v + 1) * 127.5, 0, 255).astype(np.uint8)
    path = root / "ball.glb"
    trimesh.Trimesh(v, f, vertex_colors=col, process=False).export(path)
    return path


class Recorder:
    def __init__(self):
        self.events = []

    def __call__(self, stage, done, total):
        self.events.append((stage, done, total))

    def stages(self):
        out = []
        for s, _, _ in self.events:
            if not out or out[-1] != s:
                out.append(s)
        return out


@pytest.fixture(scope="module")
def processed(ball):
    rec = Recorder()
    with_cb = process_model(ball, progress=rec)
    return with_cb, process_model(ball), rec


def test_process_model_reports_stages_in_order_and_changes_nothing(processed):
    with_cb, without, rec = processed
    assert rec.stages() == ["read", "map", "figures", "resample", "transform", "code",
                            "decode", "evaluate", "describe", "thumbnail"]
    assert [STAGES.index(s) for s in rec.stages()] == sorted(STAGES.index(s)
                                                             for s in rec.stages())
    levels = [(d, t) for s, d, t in rec.events if s == "map" and t > 1]
    assert levels and levels[-1][0] == levels[-1][1]               # the last level is the total
    assert [d for d, _ in levels] == list(range(1, levels[-1][1] + 1))
    assert all(0 <= d <= t for _, d, t in rec.events)
    assert with_cb.stream == without.stream                        # byte-identical
    for kind, vec in without.descriptors.items():
        assert np.array_equal(with_cb.descriptors[kind], vec)


def test_describe_model_equals_ingest_descriptors(ball, processed):
    _, ref, _ = processed
    rec = Recorder()
    d = describe_model(ball, progress=rec)
    assert rec.stages() == ["read", "map", "figures", "resample", "describe"]
    assert set(d.descriptors.vectors) == set(ref.descriptors)
    for kind, vec in ref.descriptors.items():
        assert d.descriptors.vectors[kind].dtype == vec.dtype
        assert np.array_equal(d.descriptors.vectors[kind], vec), kind   # bit-equal
    assert d.descriptors.params == ref.params["descriptors"]
    assert (d.content_hash, d.name, d.has_color, d.grid_level) == (
        ref.content_hash, ref.name, ref.has_color, ref.params["grid_level"])
    assert d.thumbnail is None
    assert describe_model(ball, thumbnail_size=32).thumbnail.startswith(b"\x89PNG")
    with pytest.raises(Exception, match="method must be one of tutte, mds, got 'nope'"):
        describe_model(ball, method="nope")


def test_stage_log_display_and_times():
    out = io.StringIO()
    log = StageLog(out, live=True, verbose=True)
    for event in [("read", 0, 1), ("read", 1, 1), ("map", 0, 1), ("map", 1, 3), ("map", 3, 3),
                  ("code", 0, 1)]:
        log(*event)
    log.close()
    text = out.getvalue()
    assert "reading\u2026" in text and "mapping (level 1/3)\u2026" in text and "coding" in text
    lines = [ln.strip("\r ") for ln in text.splitlines()]
    assert [ln.split()[0] for ln in lines[-4:]] == ["read", "map", "code", "total"]
    assert set(log.seconds) == {"read", "map", "code"}
    quiet = io.StringIO()
    log = StageLog(quiet)
    log("read", 0, 1)
    log.close()
    assert quiet.getvalue() == ""


def test_stage_fraction_grows_through_the_stages():
    fr = [stage_fraction(s, d, 1) for s in STAGES for d in (0, 1)]
    assert fr == sorted(fr) and fr[0] == 0 and 0.99 <= fr[-1] <= 1
    assert stage_fraction("map", 2, 4) < stage_fraction("map", 3, 4)
    assert stage_fraction("unknown", 1, 1) == 0.0


# ---------------------------------------------------------------------- CLI
def _run(args, obj=None):
    return CliRunner().invoke(cli, [str(a) for a in args], obj=obj)


@pytest.mark.parametrize("command", ["encode", "parameterize", "resample"])
def test_cli_quiet_verbose_and_terminal(ball, tmp_path, command):
    out = tmp_path / ("x.sfz" if command == "encode" else "x.ply")
    args = [command, ball, "-o", out] + (["--bits-per-surfel", 8] if command == "encode" else [])
    r = _run(args + ["--quiet"], obj={"terminal": True})
    assert r.exit_code == 0, r.output
    assert r.stderr == ""
    r = _run(args + ["--verbose"])
    assert r.exit_code == 0, r.output
    stages = [ln.split()[0] for ln in r.stderr.splitlines()]
    assert stages[0] == "read" and "map" in stages and stages[-1] == "total"
    assert all("s CPU" in ln for ln in r.stderr.splitlines())
    r = _run(args, obj={"terminal": True})
    assert r.exit_code == 0, r.output
    assert "reading\u2026" in r.stderr and "mapping (level" in r.stderr
    if command == "encode":
        assert "coding\u2026" in r.stderr
    r = _run(args)                                      # not a terminal: nothing on stderr
    assert r.exit_code == 0 and r.stderr == ""
    r = _run(args + ["--quiet", "--verbose"])
    assert r.exit_code == 2 and "--quiet and --verbose exclude each other" in r.output


def test_cli_encode_stream_same_with_progress(ball, tmp_path):
    a, b = tmp_path / "a.sfz", tmp_path / "b.sfz"
    assert _run(["encode", ball, "-o", a, "--bits-per-surfel", 4, "--quiet"]).exit_code == 0
    r = _run(["encode", ball, "-o", b, "--bits-per-surfel", 4, "--verbose"],
             obj={"terminal": True})
    assert r.exit_code == 0
    assert a.read_bytes() == b.read_bytes()


def test_cli_query_file_describes_only(ball, tmp_path):
    db = tmp_path / "q.db"
    with Database(db) as d:
        d.add(process_model(ball))
    r = _run(["query", ball, "--db", db, "--include-self", "--json", "--verbose"])
    assert r.exit_code == 0, r.output
    stages = [ln.split()[0] for ln in r.stderr.splitlines()]
    assert "describe" in stages and "code" not in stages and "decode" not in stages
    import json

    rows = json.loads(r.stdout)["results"]
    assert rows[0]["distance"] == 0.0                  # bit-equal descriptors: distance 0
    r = _run(["query", ball, "--db", db, "--quiet", "--sheet", tmp_path / "s.png"],
             obj={"terminal": True})
    assert r.exit_code == 0 and "reading" not in r.stderr
    assert (tmp_path / "s.png").exists()


# ---------------------------------------------------------------------- ingest
def staged_processor(path, *, progress=None, **kw):
    """fake_processor that reports three stages first (and passes CRASH etc. on)."""
    import time

    for stage in ("read", "map", "describe"):
        progress(stage, 0, 1)
        time.sleep(0.12)                # past tqdm's refresh interval: the bar is drawn
        progress(stage, 1, 1)
    return fake_processor(path, **kw)


def test_process_task_passes_progress_only_to_a_processor_that_names_it(tmp_path):
    root = make_tree(tmp_path / "data", 1)
    task = ingest.make_tasks(ingest.discover([root]))[0]
    seen = []
    out = ingest.process_task(task, processor=staged_processor, bits_per_surfel=8.0,
                              stages=lambda *e: seen.append(e))
    assert out.error is None and [e[1] for e in seen[::2]] == ["read", "map", "describe"]
    assert all(e[0] == task.path for e in seen)
    out = ingest.process_task(task, processor=fake_processor, bits_per_surfel=8.0,
                              stages=lambda *e: seen.append(e))    # no progress parameter
    assert out.error is None
    assert accepts_keyword(staged_processor, "progress")
    assert not accepts_keyword(fake_processor, "progress")
    assert not accepts_keyword(object(), "progress")          # no signature


@pytest.mark.parametrize("workers", [1, 2])
def test_ingest_bar_moves_within_models_and_survives_a_crash(tmp_path, capsys, workers):
    extra = {"crash.ply": "CRASH"} if workers > 1 else {}
    root = make_tree(tmp_path / "data", 3, extra=extra)
    # a pool's events are drained at results and heartbeats (here every 0.05 s)
    pool = {} if workers == 1 else {"executor": ingest.ProcessPool(workers, heartbeat=0.05)}
    s = ingest.run([root], db=tmp_path / "s.db", processor=staged_processor, progress=True,
                   workers=workers, **pool)
    assert s.stored == 3 and s.failed == len(extra)
    err = capsys.readouterr().err
    total = 3 + len(extra)
    assert f"{total}.0/{total}" in err
    # within-model positions (fractions of a model) were shown on the way
    assert any(f"{i}.{d}/{total}" in err for i in range(total) for d in range(1, 10))


def test_ingest_default_workers(tmp_path):
    expected = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") \
        else os.cpu_count()
    assert ingest.default_workers() == expected
    root = make_tree(tmp_path / "data", 2)
    s = ingest.run([root], db=tmp_path / "d.db", processor=fake_processor, progress=False)
    assert s.stored == 2
    with Database(tmp_path / "d.db") as d:
        assert d.runs()[-1]["workers"] == expected
    # a processor that cannot go to worker processes runs here when workers is not given
    s = ingest.run([make_tree(tmp_path / "more", 1)], db=tmp_path / "e.db",
                   processor=lambda path, **kw: fake_processor(path, **kw), progress=False)
    assert s.stored == 1
    with Database(tmp_path / "e.db") as d:
        assert d.runs()[-1]["workers"] == 1
    r = CliRunner().invoke(cli, ["ingest", "--help"])
    assert "default: as many as the machine's cores" in " ".join(r.output.split())
