"""CPU cost of the surfidx commands as a user meets them: one process per command, start-up
included.

Each command runs as a subprocess (``python -m surfidx ...``, or ``python -c "import surfidx"``)
with ``PYTHONPATH`` set to the tree under test (``--tree``, default this checkout), and its CPU
time is the user + system time of the whole process tree (``resource.getrusage(RUSAGE_CHILDREN)``
before and after). Every command runs once unmeasured first (so that numba's cache of compiled
kernels is filled, Python's bytecode is compiled and files are in the page cache), then
``--repeat`` times; the table shows the median and the minimum (the minimum is what an idle
machine gives; the median what this one gave). The single view and the ingests run once each,
after the database's ingest and a query of an open sphere have loaded the kernels they use.
Bytecode is kept in a folder of the run (``PYTHONPYCACHEPREFIX``), as a user's Python keeps it,
whatever ``PYTHONDONTWRITEBYTECODE`` says.

Commands
--------
* ``import surfidx`` and ``surfidx --help``: the fixed cost of any command;
* ``surfidx info FILE`` of the median-size retrieval model;
* ``surfidx query FILE`` of a 642-vertex icosphere (small) and of the median-size retrieval model
  (by vertex count in ``meta.csv``; ``--query-models`` names others), against a database of a few retrieval models built once per
  tree (``ingest -j 1``);
* ``surfidx query FILE`` of a simulated single view (``--view MODEL``, default d071, a view of
  about 10k vertices; ``benchmarks/_shape_baselines.simulate_view`` with the seed
  ``benchmarks/retrieval.py --partial view`` gives it);
* ``surfidx query NAME`` and ``surfidx get NAME -o FILE.sfz`` / ``FILE.ply`` of a stored model
  (d045, in that database): a query by a stored model's descriptors, a copy of its stream and a
  decode of it;
* ``surfidx decode FILE.sfz -o FILE.glb`` / ``FILE.ply`` of each of ``--decode`` textured
  models (default the YCB banana; a folder of ``../shared/data/models`` holding
  ``textured_simple_reoriented.obj``), encoded once per run at 8 bits/surfel (``encode``, not
  measured): a textured GLB (the image baked on the grid's atlas, PNG) and the surfels;
* ``surfidx ingest -j 1`` of each of ``--ingest`` retrieval models into a new database, one
  process per model (per-model CPU, and their mean).

Run ``python benchmarks/latency.py [--tree /work/main] [--repeat 3] [--skip ingest view stored decode]
[--json out.json] [--markdown]``; two runs with different ``--tree`` and ``--json`` give the
before/after table: ``python benchmarks/latency.py --compare before.json after.json
[--markdown]``.
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

from _markdown import Report, add_markdown_option

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared" / "data" / "retrieval"
MODELS = ROOT.parent / "shared" / "data" / "models"
DECODE_MODELS = ("ycb_banana",)
DECODE_BITS = 8      # bits/surfel of the decoded streams
DB_MODELS = ("d073", "d000", "d045", "d019", "d060")
INGEST_MODELS = ("d073", "d019", "d045", "d087", "d060")
STORED_MODEL = "d045"  # of DB_MODELS: the stored model that query NAME and get name
VIEW_SEED = 100_000     # retrieval.py --partial view: seed * 100_000 + model index * 100 + view


def cpu_run(cmd, *, env, cwd, timeout=1800) -> tuple[float, int]:
    """(CPU seconds of the process tree, exit code) of one command."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    proc = subprocess.run(cmd, env=env, cwd=cwd, stdout=subprocess.DEVNULL,
                          stderr=subprocess.PIPE, timeout=timeout)
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    if proc.returncode != 0:
        print(f"  {' '.join(map(str, cmd[-3:]))}: exit {proc.returncode}: "
              f"{proc.stderr.decode(errors='replace')[-300:]}", file=sys.stderr)
    return cpu, proc.returncode


def median_model() -> str:
    """The retrieval model of median vertex count."""
    with open(DATA / "meta.csv", newline="") as f:
        rows = sorted(csv.DictReader(f), key=lambda r: int(r["vertices"]))
    return Path(rows[len(rows) // 2]["path"]).stem


def write_sphere(path: Path) -> None:
    """A 642-vertex icosphere as OFF (level 3 of surfidx's icosphere)."""
    from surfidx.geometry.icosphere import icosphere

    ico = icosphere(3)
    with open(path, "w") as f:
        f.write(f"OFF\n{len(ico.vertices)} {len(ico.faces)} 0\n")
        f.writelines("%.9f %.9f %.9f\n" % tuple(p) for p in ico.vertices)
        f.writelines("3 %d %d %d\n" % tuple(t) for t in ico.faces)


def write_open_sphere(path: Path) -> None:
    """The 642-vertex icosphere without its faces above z = 0.5 (an open surface: the warm-up of
    the repair's kernels before the single view is measured)."""
    import numpy as np

    from surfidx.geometry.icosphere import icosphere

    ico = icosphere(3)
    keep = ico.vertices[ico.faces].mean(axis=1)[:, 2] < 0.5
    with open(path, "w") as f:
        f.write(f"OFF\n{len(ico.vertices)} {int(keep.sum())} 0\n")
        f.writelines("%.9f %.9f %.9f\n" % tuple(p) for p in ico.vertices)
        f.writelines("3 %d %d %d\n" % tuple(t) for t in np.asarray(ico.faces)[keep])


def write_view(model: str, path: Path) -> int:
    """The simulated single view of ``model`` that ``retrieval.py --partial view`` makes (its
    first view); returns its vertex count."""
    import numpy as np

    import _shape_baselines as sb
    import surfidx

    mesh = surfidx.read_mesh(DATA / "meshes" / f"{model}.off")
    index = int(model.lstrip("d"))
    rng = np.random.default_rng(VIEW_SEED + index * 100)
    v, f = sb.simulate_view(np.asarray(mesh.vertices, float), np.asarray(mesh.faces, np.int64),
                            rng)
    sb.write_off(path, v, f)
    return len(v)


def compare(before: Path, after: Path, markdown=None, note: str = "") -> int:
    """Print (and with ``markdown`` write) the table of two ``--json`` files: per command the
    median CPU seconds before and after, and their ratio; the ingests' mean at the end."""
    old, new = (json.loads(Path(p).read_text()) for p in (before, after))
    report = Report("latency", "CPU per command, process start included", markdown,
                    note=("Each command in its own process (`python -m surfidx ...`), CPU = user "
                          "+ system time of the process tree, after one unmeasured run (numba's "
                          "cache filled, bytecode compiled); median of the measured runs (one "
                          "run for the single view and each ingest), before and after."))
    report.text(f"before: {old['tree']}; after: {new['tree']}" + (f". {note}" if note else ""))
    rows, ingest = [], {"before": [], "after": []}
    for label in [k for k in old["runs"] if k in new["runs"]]:
        a, b = statistics.median(old["runs"][label]), statistics.median(new["runs"][label])
        rows.append([label, f"{a:.2f}", f"{b:.2f}", f"{b / a:.2f}" if a > 0 else "-"])
        if label.startswith("ingest -j 1 "):
            ingest["before"].append(a)
            ingest["after"].append(b)
    if ingest["before"]:
        a, b = statistics.mean(ingest["before"]), statistics.mean(ingest["after"])
        rows.append([f"ingest -j 1, mean of {len(ingest['before'])}", f"{a:.2f}", f"{b:.2f}",
                     f"{b / a:.2f}"])
    report.table(["command", "CPU s before", "CPU s after", "after/before"], rows)
    report.finish()
    return 0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--tree", type=Path, default=ROOT,
                    help="the surfidx checkout to measure (PYTHONPATH); default this one")
    ap.add_argument("--repeat", type=int, default=3, help="measured runs per command")
    ap.add_argument("--ingest", nargs="*", default=list(INGEST_MODELS),
                    help="retrieval models ingested one per process")
    ap.add_argument("--query-models", nargs="*", default=None,
                    help="retrieval models queried by file (default the median-size one)")
    ap.add_argument("--view", default="d071", help="retrieval model whose single view is queried")
    ap.add_argument("--decode", nargs="*", default=list(DECODE_MODELS),
                    help="textured models (folders of ../shared/data/models) encoded at "
                         f"{DECODE_BITS} bits/surfel, then decoded to GLB and PLY")
    ap.add_argument("--skip", nargs="*", default=[],
                    choices=["query", "info", "ingest", "view", "stored", "decode"],
                    help="leave these commands out")
    ap.add_argument("--work", type=Path, default=None,
                    help="folder for the databases and generated files (default a temporary one)")
    ap.add_argument("--json", type=Path, default=None,
                    help="also write the measured CPU seconds per command to this file")
    ap.add_argument("--compare", nargs=2, type=Path, metavar=("BEFORE", "AFTER"),
                    help="print the before/after table of two --json files (nothing is run)")
    ap.add_argument("--note", default="",
                    help="with --compare: a sentence on the circumstances, printed under the table")
    add_markdown_option(ap, "latency")
    args = ap.parse_args(argv)
    if args.compare:
        return compare(*args.compare, args.markdown, note=args.note)

    tree = args.tree.resolve()
    work = Path(args.work or tempfile.mkdtemp(prefix="surfidx-latency-"))
    work.mkdir(parents=True, exist_ok=True)
    # as a user's Python: compiled bytecode kept (in a folder of the run's own, so that
    # neither tree is written into)
    env = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}
    env.update(PYTHONPATH=str(tree), PYTHONPYCACHEPREFIX=str(work / "pycache"))
    py = [sys.executable]
    cli = py + ["-m", "surfidx"]
    median = median_model()
    median_file = DATA / "meshes" / f"{median}.off"
    sphere = work / "sphere642.off"
    write_sphere(sphere)

    report = Report("latency", "CPU per command, process start included", args.markdown,
                    note=("Each command in its own process (`python -m surfidx ...`), CPU = user + "
                          "system time of the process tree, after one unmeasured run (numba's "
                          "cache filled); median and minimum of the measured runs."))
    rows, measured = [], {}

    def measure(label, cmd, *, repeat=args.repeat, prepare=None, warm=True):
        if warm:
            if prepare:
                prepare()
            cpu_run(cmd, env=env, cwd=work)            # warm: numba cache, bytecode, page cache
        times = []
        for _ in range(repeat):
            if prepare:
                prepare()
            t, code = cpu_run(cmd, env=env, cwd=work)
            times.append(t if code == 0 else float("nan"))
        rows.append([label, f"{statistics.median(times):.2f}", f"{min(times):.2f}"])
        measured[label] = times
        print(f"  {label}: {' '.join(f'{t:.2f}' for t in times)}", file=sys.stderr, flush=True)
        return times

    measure("import surfidx", py + ["-c", "import surfidx"])
    measure("surfidx --help", cli + ["--help"])
    if "info" not in args.skip:
        measure(f"info FILE ({median})", cli + ["info", str(median_file)])
    db = work / "query.db"
    if not ({"query", "view", "stored"} <= set(args.skip)) and not db.exists():
        files = [str(DATA / "meshes" / f"{m}.off") for m in DB_MODELS]
        cpu_run(cli + ["ingest", "-q", "-j", "1", "--db", str(db), *files], env=env, cwd=work)
    if "query" not in args.skip:
        measure("query FILE (642-vertex sphere)", cli + ["query", "-q", "--db", str(db),
                                                        str(sphere)])
        for m in args.query_models or [median]:
            label = f"{m}, median" if m == median else m
            measure(f"query FILE ({label})", cli + ["query", "-q", "--db", str(db),
                                                    str(DATA / "meshes" / f"{m}.off")])
    if "stored" not in args.skip:
        measure(f"query NAME ({STORED_MODEL})",
                cli + ["query", "-q", "--db", str(db), STORED_MODEL])
        for fmt in ("sfz", "ply"):
            measure(f"get NAME -o {fmt.upper()} ({STORED_MODEL})",
                    cli + ["get", "-q", "--db", str(db), STORED_MODEL, "-o",
                           str(work / f"{STORED_MODEL}.{fmt}")])
    if "decode" not in args.skip:
        for m in args.decode or []:
            sfz = work / f"{m}-{DECODE_BITS}.sfz"
            if not sfz.exists():
                cpu_run(cli + ["encode", "-q", str(MODELS / m / "textured_simple_reoriented.obj"),
                               "-o", str(sfz), "--bits-per-surfel", str(DECODE_BITS)],
                        env=env, cwd=work)
            for fmt in ("glb", "ply"):
                measure(f"decode -o {fmt.upper()} ({m}, {DECODE_BITS} b/s)",
                        cli + ["decode", "-q", str(sfz), "-o", str(work / f"{m}.{fmt}")])
    if "view" not in args.skip:
        view, opened = work / f"{args.view}-view.off", work / "open642.off"
        n = write_view(args.view, view)
        write_open_sphere(opened)
        cpu_run(cli + ["query", "-q", "--db", str(db), str(opened)], env=env, cwd=work)
        measure(f"query FILE (view of {args.view}, {n:,} vertices)",
                cli + ["query", "-q", "--db", str(db), str(view)], repeat=1, warm=False)
    if "ingest" not in args.skip and args.ingest:
        ing = work / "ingest.db"
        per = []
        for m in args.ingest:
            def fresh():
                for p in work.glob("ingest.db*"):
                    p.unlink()
            per.append(measure(f"ingest -j 1 {m}", cli + [
                "ingest", "-q", "-j", "1", "--db", str(ing),
                str(DATA / "meshes" / f"{m}.off")], repeat=1, prepare=fresh, warm=False)[0])
        rows.append([f"ingest -j 1, mean of {len(per)}", f"{statistics.mean(per):.2f}", ""])
    report.text(f"tree {tree}, {args.repeat} runs per command (1 for the view and each ingest)")
    report.table(["command", "CPU s (median)", "CPU s (min)"], rows)
    report.finish()
    if args.json:
        args.json.write_text(json.dumps({"tree": str(tree), "runs": measured}, indent=1))
    if args.work is None:
        shutil.rmtree(work, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
