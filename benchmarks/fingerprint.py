"""SHA-256 fingerprints of what an ingest stores for each model: stream, descriptors, thumbnail.

A refactoring that must not change behaviour is checked by running this before and after and
comparing the two JSON files: the same file gives byte-identical streams and descriptors.

Run::

    python benchmarks/fingerprint.py [--set examples shared retrieval] [--workers 2]
        [--limit N] --json out.json
    python benchmarks/fingerprint.py --compare before.json after.json

Each model runs :func:`surfidx.pipeline.process_model` with its defaults in a worker process that
computes in surfidx's portable numerics profile (the profile the ``surfidx`` command uses).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import sys
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path

from _markdown import Report, add_markdown_option

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared" / "data"


def _models(sets):
    out = []
    if "examples" in sets:
        out += [ROOT / "examples/models/armadillo.obj", ROOT / "examples/models/spot/spot_triangulated.obj"]
    if "shared" in sets:
        for p in sorted((SHARED / "models").iterdir()):
            if p.is_dir():
                objs = sorted(p.glob("*.obj")) + sorted(p.glob("*.ply"))
                out += objs[:1]
            elif p.suffix in (".obj", ".ply", ".off"):
                out.append(p)
    if "retrieval" in sets:
        out += sorted((SHARED / "retrieval/meshes").glob("*.off"))
    return out


def _key(path: Path) -> str:
    """The model's name in the JSON: relative to the repository for its own files (so that two
    checkouts compare), else relative to the folder beside it (``shared/data/...``)."""
    for base in (ROOT, ROOT.parent):
        if path.is_relative_to(base):
            return str(path.relative_to(base))
    return str(path)


def _sha(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()[:16]


def _start_worker():
    from surfidx.numerics import use_portable_profile

    use_portable_profile()


def _one(path: str) -> tuple[str, dict]:
    import numpy as np

    from surfidx.errors import SurfidxError
    from surfidx.pipeline import process_model

    try:
        m = process_model(path)
    except SurfidxError as exc:
        return path, {"error": str(exc)}
    desc = {k: _sha(np.ascontiguousarray(v).tobytes()) for k, v in sorted(m.descriptors.items())}
    params = {k: v for k, v in m.params.items() if k not in ("texture",)}
    return path, {"stream": _sha(m.stream), "bytes": len(m.stream), "descriptors": desc,
                  "thumbnail": _sha(m.thumbnail), "quality": m.quality,
                  "params": _sha(json.dumps(params, sort_keys=True, default=str).encode())}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--set", nargs="+", default=["examples", "shared", "retrieval"])
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--limit", type=int)
    ap.add_argument("--json")
    ap.add_argument("--compare", nargs=2, metavar=("BEFORE", "AFTER"))
    ap.add_argument("--ignore", nargs="*", default=[],
                    help="fields left out of --compare (e.g. params thumbnail)")
    add_markdown_option(ap, "fingerprint")
    args = ap.parse_args(argv)
    if args.compare:
        a, b = (json.loads(Path(p).read_text()) for p in args.compare)
        differ = 0
        for key in sorted(set(a) | set(b)):
            ra = {k: v for k, v in a.get(key, {}).items() if k not in args.ignore}
            rb = {k: v for k, v in b.get(key, {}).items() if k not in args.ignore}
            if ra != rb:
                differ += 1
                fields = sorted(k for k in set(ra) | set(rb) if ra.get(k) != rb.get(k))
                print(f"DIFFERS {Path(key).name}: {', '.join(fields)}")
        print(f"{len(set(a) | set(b)) - differ} models identical, {differ} differ")
        return 1 if differ else 0
    models = _models(args.set)[: args.limit]
    import multiprocessing as mp

    results = {}
    with ProcessPoolExecutor(args.workers, mp_context=mp.get_context("spawn"),
                             initializer=_start_worker) as pool:
        futures = [pool.submit(_one, str(p)) for p in models]
        for i, fut in enumerate(as_completed(futures), 1):
            path, rec = fut.result()
            results[_key(Path(path))] = rec
            print(f"[{i}/{len(models)}] {Path(path).name}: {rec.get('stream', rec.get('error'))}",
                  file=sys.stderr, flush=True)
    results = dict(sorted(results.items()))
    text = json.dumps(results, indent=1, sort_keys=True)
    if args.json:
        Path(args.json).write_text(text)
    elif not args.markdown:
        print(text)
    if args.markdown:
        report = Report("fingerprint", "Fingerprints of what an ingest stores", args.markdown,
                        note="The first 16 hex digits of the SHA-256 of each model's stored "
                             "stream, descriptors (all kinds together) and thumbnail, as "
                             "`process_model` makes them in the portable numerics profile: the "
                             "same file gives the same bytes, so these change only when the "
                             "code changes what it stores.")
        rows = []
        for key, rec in results.items():
            if "error" in rec:
                rows.append([key, "-", "-", "-", "-", rec["error"][:80]])
                continue
            desc = _sha("".join(rec["descriptors"].values()).encode())
            rows.append([key, rec["bytes"], rec["stream"][:16], desc[:16], rec["thumbnail"][:16],
                         ""])
        report.table(["model", "bytes", "stream", "descriptors", "thumbnail", "error"], rows)
        report.finish()
    return 0


if __name__ == "__main__":
    sys.exit(main())
