"""Read time of the scanner formats on a generated 1M-point scan: LAS, LAZ and E57 through
surfidx's readers (:mod:`surfidx.io.las`, :mod:`surfidx.io.e57`, as ``read_surfels`` calls them,
before the surfel conversion), beside the libraries read directly (``laspy.read`` with the
single-threaded and the parallel lazrs backend, ``pye57.E57.read_scan``).

The scan is a noisy sphere of radius 10 m sampled like a terrestrial scan: millimetre
coordinates (LAS scale 0.001, offset in the hundreds of thousands of metres), 16-bit RGB and
intensity; the E57 holds it as two scans of half the points, each with its own pose, 1 % of
the points marked invalid, colour and intensity. Each measurement runs in a fresh process
(import and numba set-up excluded from the time), best of ``--repeat``: wall time, CPU time of
the process and its peak resident memory. A first table says how densely LASzip packs the scan
and, its best case, identical points in each point format, beside
``surfidx.io.MAX_LAZ_POINTS_PER_BYTE``, the most a LAZ file may announce.

Run: ``python benchmarks/scanformats.py [--points 1000000] [--repeat 3] [--dir DIR]
[--markdown]``.
"""

from __future__ import annotations

import argparse
import json
import os
import struct
import subprocess
import sys
import tempfile
import textwrap
from pathlib import Path

import numpy as np

from _markdown import Report, add_markdown_option


def make_scan(n: int, seed: int = 0):
    """``(positions (n, 3) float64, rgb (n, 3) uint16, intensity (n,) uint16)``."""
    rng = np.random.default_rng(seed)
    v = rng.normal(size=(n, 3))
    v /= np.linalg.norm(v, axis=1)[:, None]
    p = v * (10.0 + rng.normal(scale=0.002, size=(n, 1))) + [512_000.0, 5_403_000.0, 310.0]
    rgb = (np.clip((v + 1) * 127.5, 0, 255).astype(np.uint16) * 257)
    intensity = rng.integers(0, 4096, n).astype(np.uint16)
    return p, rgb, intensity


def write_las(path: Path, p, rgb, intensity) -> None:
    import laspy

    h = laspy.LasHeader(point_format=3, version="1.2")
    h.scales = [0.001] * 3
    h.offsets = [512_000.0, 5_403_000.0, 300.0]
    las = laspy.LasData(h)
    las.x, las.y, las.z = p.T
    las.red, las.green, las.blue = rgb.T
    las.intensity = intensity
    las.write(str(path))


def write_e57(path: Path, p, rgb, intensity) -> None:
    import pye57

    n = len(p)
    half = n // 2
    invalid = np.zeros(n, np.int8)
    invalid[::100] = 2
    poses = [(np.array([1.0, 0, 0, 0]), np.zeros(3)),
             (np.array([np.cos(0.3), 0, 0, np.sin(0.3)]), np.array([1.5, -2.0, 0.25]))]
    e = pye57.E57(str(path), mode="w")
    centre = p.mean(axis=0)
    for (rot, shift), sl in zip(poses, (slice(0, half), slice(half, n))):
        q = p[sl] - centre
        e.write_scan_raw({"cartesianX": q[:, 0], "cartesianY": q[:, 1], "cartesianZ": q[:, 2],
                          "colorRed": (rgb[sl, 0] >> 8).astype(np.uint8),
                          "colorGreen": (rgb[sl, 1] >> 8).astype(np.uint8),
                          "colorBlue": (rgb[sl, 2] >> 8).astype(np.uint8),
                          "intensity": intensity[sl].astype(np.float32) / 4095,
                          "cartesianInvalidState": invalid[sl]},
                         rotation=rot, translation=shift + centre)
    e.close()


def points_per_byte(path: Path) -> float:
    """Points of a LAZ file per byte of its compressed point data."""
    head = path.read_bytes()[:375]
    (offset,) = struct.unpack_from("<I", head, 96)
    count = struct.unpack_from("<I", head, 107)[0] or struct.unpack_from("<Q", head, 247)[0]
    return count / (path.stat().st_size - offset)


def compression(report, scan: Path, folder: Path, n: int) -> None:
    """How densely LASzip packs the generated scan, and ``n`` identical points in each point
    format (its best case), beside the most :func:`surfidx.io.las.read_las` reads."""
    import laspy

    from surfidx.io import MAX_LAZ_POINTS_PER_BYTE

    rows = [["the generated scan (format 3)", f"{points_per_byte(scan):.2f}"]]
    for pf in range(11):
        h = laspy.LasHeader(point_format=pf, version="1.4" if pf >= 6 else "1.3")
        las = laspy.LasData(h)
        las.x = las.y = las.z = np.zeros(n)
        path = folder / f"same{pf}.laz"
        las.write(str(path))
        rows.append([f"{n:,} identical points, format {pf}", f"{points_per_byte(path):.0f}"])
        path.unlink()
    report.table(["LAZ file", "points per compressed byte"], rows,
                 title=f"LAZ density (surfidx.io.MAX_LAZ_POINTS_PER_BYTE = "
                       f"{MAX_LAZ_POINTS_PER_BYTE})")


#: What each row runs; ``PATH`` is the file. The timed part is ``run()``.
CASES = {
    "surfidx": """
        import warnings
        from pathlib import Path
        from surfidx.io.registry import reader
        read = reader(Path(PATH).suffix.lower())
        def run():
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                return len(read(Path(PATH)).positions)
    """,
    "laspy.read (Lazrs)": """
        import laspy
        def run():
            las = laspy.read(PATH, laz_backend=laspy.LazBackend.Lazrs)
            return len(las.x)
    """,
    "laspy.read (LazrsParallel)": """
        import laspy
        def run():
            las = laspy.read(PATH, laz_backend=laspy.LazBackend.LazrsParallel)
            return len(las.x)
    """,
    "pye57 read_scan": """
        import pye57
        def run():
            e = pye57.E57(PATH)
            n = sum(len(e.read_scan(i, colors=True, intensity=True)["cartesianX"])
                    for i in range(e.scan_count))
            e.close()
            return n
    """,
}

_TIMER = """
import resource, time, json
{setup}
best = None
for _ in range({repeat}):
    w, c = time.perf_counter(), time.process_time()
    n = run()
    w, c = time.perf_counter() - w, time.process_time() - c
    best = (w, c) if best is None or w < best[0] else best
print(json.dumps({{"n": n, "wall": best[0], "cpu": best[1],
                  "rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}}))
"""


def measure(case: str, path: Path, repeat: int) -> dict:
    """Time ``CASES[case]`` on ``path`` in a fresh process."""
    setup = textwrap.dedent(CASES[case]).replace("PATH", repr(str(path)))
    code = _TIMER.format(setup=setup, repeat=repeat)
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--points", type=int, default=1_000_000)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--dir", type=Path, default=None, help="where the files go (default: temp)")
    add_markdown_option(ap, "scanformats")
    args = ap.parse_args(argv)
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    report = Report("scanformats", "Scanner formats: read time", args.markdown,
                    note=f"A generated scan of {args.points:,} points (a noisy sphere, "
                         "millimetre coordinates, 16-bit RGB and intensity; the E57 as two "
                         "posed scans with 1 % of the points invalid) read by surfidx's readers "
                         "(the points before the surfel conversion) and by the libraries "
                         f"directly; best of {args.repeat}, each row in a fresh process. The "
                         f"load average was {load:.1f} on {os.cpu_count()} cores: wall time "
                         "grows with it, CPU time little.")
    with tempfile.TemporaryDirectory() as tmp:
        folder = args.dir or Path(tmp)
        folder.mkdir(parents=True, exist_ok=True)
        p, rgb, intensity = make_scan(args.points)
        files = {"LAS": folder / "scan.las", "LAZ": folder / "scan.laz",
                 "E57": folder / "scan.e57"}
        write_las(files["LAS"], p, rgb, intensity)
        write_las(files["LAZ"], p, rgb, intensity)
        write_e57(files["E57"], p, rgb, intensity)
        compression(report, files["LAZ"], folder, args.points)
        cases = [("LAS", "surfidx"), ("LAS", "laspy.read (Lazrs)"),
                 ("LAZ", "surfidx"), ("LAZ", "laspy.read (Lazrs)"),
                 ("LAZ", "laspy.read (LazrsParallel)"),
                 ("E57", "surfidx"), ("E57", "pye57 read_scan")]
        rows = []
        for fmt, case in cases:
            r = measure(case, files[fmt], args.repeat)
            rows.append([fmt, case, f"{files[fmt].stat().st_size / 1e6:.1f}", f"{r['n']:,}",
                         f"{r['wall']:.3f}", f"{r['cpu']:.3f}", f"{r['n'] / r['cpu'] / 1e6:.2f}",
                         f"{r['rss_mb']:.0f}"])
        report.table(["format", "reader", "MB", "points", "wall s", "CPU s", "Mpts per CPU s",
                      "peak RSS MB"], rows, title="Read time")
    report.finish(None if argv is None else [sys.argv[0], *argv])

if __name__ == "__main__":
    main()
