"""Fuzzing the readers and the decoder with hostile input (issue 28): every case must end in a
result with finite values or a clean library error, in bounded time and memory.

Cases are seeded mutations of small valid inputs:

* **streams**: ``.sfz`` containers of a level-3 icosphere (colour, local frames, density
  weights, geometry only) with bytes flipped, set to boundary values, cut, extended or moved;
  with header fields (level, flags, counts, KLT mean/basis/weights, coder step, anchors, weight
  field) set to boundary values; most of them resealed (lengths and checksums recomputed) so that
  the parser and decoder, not the checksum, must refuse them;
* **files**: PLY (ASCII and binary meshes, point clouds, surfels), OBJ with MTL and texture
  (damaged, huge or outside images too) and OFF (plain, COFF, counts on the header line), with
  lines and tokens replaced by boundary values, repeated, dropped or cut, and raw bytes damaged.

Each case runs in a worker process with an address-space limit; a case that outlives the time
limit is counted as a hang (the worker is killed and replaced), a MemoryError or a worker killed
by the kernel as a memory kill, and any exception other than a :class:`surfidx.SurfidxError` (or
an output with non-finite values) as a crash, listed after the table.

Run: ``python benchmarks/fuzz.py [--streams 10000] [--files 1000] [--workers 2] [--timeout 30]
[--memory-mb 4096] [--seed 0]``. ``tests/test_fuzz.py`` runs the same generators in-process on a
few hundred cases.
"""

from __future__ import annotations

import argparse
import io as _io
import multiprocessing as mp
import os
import struct
import sys
import tempfile
import time
import traceback
import warnings
import zlib
from pathlib import Path

from surfidx.numerics import use_portable_profile  # noqa: E402

use_portable_profile()   # before numpy loads: the bytes the surfidx command makes
import numpy as np


OUTCOMES = ("ok", "clean error", "crash", "hang", "memory kill")

_INTERESTING_TOKENS = ("0", "-1", "1", "2", "3", "-0", "nan", "NaN", "inf", "-inf", "1e309",
                       "1e31", "-1e31", "3.4e38", "1e-45", "1e-320", "99999999999999999999",
                       "4294967296", "2147483648", "1000000", "", "abc", "1/1/1", "//", "0x10",
                       "1e6", "-2147483649", "0.5")
_INTERESTING_LINES = ("f 1 1 2", "f 5 5 9", "f 1 2", "f 0 0 0", "f -1 -2 -3", "f 1 2 3 4 5 6",
                      "v 1 2", "v nan 0 0", "v 1e31 0 0", "v 0 0 0", "vt", "vt 0.5",
                      "mtllib missing.mtl", "mtllib ../outside.mtl", "mtllib /etc",
                      "usemtl x", "o thing", "f 1/1 2/2 3/3", "f 1//1 2//2 3//3",
                      "3 0 0 1", "1000000 0 1 2", "4 0 1 2", "0 0 0", "OFF", "COFF",
                      "element vertex 4294967295", "element face 1000000000000",
                      "property list uint int vertex_indices", "property float nx",
                      "format binary_big_endian 1.0", "format ascii 1.0", "end_header",
                      "map_Kd ../outside.png", "map_Kd /etc/hostname", "map_Kd bomb.png",
                      "map_Kd damaged.png", "map_Kd missing.png", "map_Kd .", "# comment")
_INTERESTING_BYTES = (0, 1, 0x7F, 0x80, 0xFE, 0xFF)
_INTERESTING_U32 = (0, 1, 2, 0x7FFFFFFF, 0x80000000, 0xFFFFFFFF, 1000, 65535, 65536)
_INTERESTING_F32 = (0.0, -0.0, 1.0, -1.0, 3.4e38, -3.4e38, 1e-45, 1e-38, 1e20, 1e-20, 1e12,
                    float("nan"), float("inf"), float("-inf"), 65504.0, 2.0, 0.5)


# ---------------------------------------------------------------------- seeds
def _icosphere(level: int):
    t = (1 + 5 ** 0.5) / 2
    v = np.array([[-1, t, 0], [1, t, 0], [-1, -t, 0], [1, -t, 0], [0, -1, t], [0, 1, t],
                  [0, -1, -t], [0, 1, -t], [t, 0, -1], [t, 0, 1], [-t, 0, -1], [-t, 0, 1]], float)
    f = np.array([[0, 11, 5], [0, 5, 1], [0, 1, 7], [0, 7, 10], [0, 10, 11], [1, 5, 9], [5, 11, 4],
                  [11, 10, 2], [10, 7, 6], [7, 1, 8], [3, 9, 4], [3, 4, 2], [3, 2, 6], [3, 6, 8],
                  [3, 8, 9], [4, 9, 5], [2, 4, 11], [6, 2, 10], [8, 6, 7], [9, 8, 1]])
    v /= np.linalg.norm(v, axis=1)[:, None]
    for _ in range(level):
        verts, cache, nf = list(v), {}, []

        def mid(a, b):
            key = (min(a, b), max(a, b))
            if key not in cache:
                m = verts[a] + verts[b]
                verts.append(m / np.linalg.norm(m))
                cache[key] = len(verts) - 1
            return cache[key]

        for a, b, c in f:
            ab, bc, ca = mid(a, b), mid(b, c), mid(c, a)
            nf += [[a, ab, ca], [b, bc, ab], [c, ca, bc], [ab, bc, ca]]
        v, f = np.array(verts), np.array(nf)
    return v, f


def _png(size=(4, 4), colour=(200, 30, 30)) -> bytes:
    from PIL import Image

    buf = _io.BytesIO()
    Image.new("RGB", size, colour).save(buf, "PNG")
    return buf.getvalue()


def _bomb_png(side: int = 50000) -> bytes:
    d = bytearray(_png((1, 1)))
    d[16:24] = struct.pack(">II", side, side)
    d[29:33] = struct.pack(">I", zlib.crc32(bytes(d[12:29])))
    return bytes(d)


def _ply(v, f=None, *, text=True, normals=False, radius=False, colour=False) -> bytes:
    from plyfile import PlyData, PlyElement

    fields = [("x", "<f4"), ("y", "<f4"), ("z", "<f4")]
    if normals:
        fields += [("nx", "<f4"), ("ny", "<f4"), ("nz", "<f4")]
    if radius:
        fields += [("radius", "<f4")]
    if colour:
        fields += [("red", "u1"), ("green", "u1"), ("blue", "u1")]
    data = np.zeros(len(v), fields)
    for i, a in enumerate("xyz"):
        data[a] = v[:, i]
        if normals:
            data["n" + a] = v[:, i]
    if radius:
        data["radius"] = 0.1
    if colour:
        data["red"] = 200
    elements = [PlyElement.describe(data, "vertex")]
    if f is not None:
        fd = np.empty(len(f), [("vertex_indices", "i4", (3,))])
        fd["vertex_indices"] = f
        elements.append(PlyElement.describe(fd, "face"))
    buf = _io.BytesIO()
    PlyData(elements, text=text).write(buf)
    return buf.getvalue()


def file_seeds() -> list[tuple[str, dict]]:
    """Small valid inputs: (entry file name, {file name: bytes})."""
    v, f = _icosphere(2)
    vs = "".join(f"v {a:.6f} {b:.6f} {c:.6f}\n" for a, b, c in v)
    fs = "".join(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in f)
    vts = "".join(f"vt {0.5 + 0.4 * a:.5f} {0.5 + 0.4 * b:.5f}\n" for a, b, c in v)
    fts = "".join(f"f {a + 1}/{a + 1} {b + 1}/{b + 1} {c + 1}/{c + 1}\n" for a, b, c in f)
    vcs = "".join(f"v {a:.6f} {b:.6f} {c:.6f} 0.8 0.2 0.1\n" for a, b, c in v)
    quads = "".join(f"f {a + 1} {b + 1} {c + 1} {c + 1}\n" for a, b, c in f[:10])
    off_v = "".join(f"{a:.6f} {b:.6f} {c:.6f}\n" for a, b, c in v)
    off_c = "".join(f"{a:.6f} {b:.6f} {c:.6f} 255 128 0 255\n" for a, b, c in v)
    off_f = "".join(f"3 {a} {b} {c}\n" for a, b, c in f)
    extras = {"bomb.png": _bomb_png(), "damaged.png": _png()[:40], "../outside.png": _png()}
    return [
        ("m.obj", {"m.obj": (vs + fs).encode()}),
        ("t.obj", {"t.obj": ("mtllib t.mtl\n" + vs + vts + fts).encode(),
                   "t.mtl": b"newmtl m\nKd 1 1 1\nmap_Kd tex.png\n", "tex.png": _png(), **extras}),
        ("c.obj", {"c.obj": (vcs + fs + quads).encode()}),
        ("m.off", {"m.off": (f"OFF\n{len(v)} {len(f)} 0\n" + off_v + off_f).encode()}),
        ("h.off", {"h.off": (f"OFF {len(v)} {len(f)} 0\n# c\n" + off_v + off_f).encode()}),
        ("c.off", {"c.off": (f"COFF\n{len(v)} {len(f)} 0\n" + off_c + off_f).encode()}),
        ("a.ply", {"a.ply": _ply(v, f, text=True, colour=True)}),
        ("b.ply", {"b.ply": _ply(v, f, text=False)}),
        ("p.ply", {"p.ply": _ply(v, text=True)}),
        ("s.ply", {"s.ply": _ply(v, text=False, normals=True, radius=True, colour=True)}),
    ]


def stream_seeds() -> list[bytes]:
    """Valid ``.sfz`` streams of a coloured level-3 icosphere (about 0.2-2 KB each)."""
    from surfidx import TriangleMesh
    from surfidx.codec import Encoder
    from surfidx.sphere import SphericalMap

    v, f = _icosphere(3)
    p = v * (1 + 0.2 * v[:, [0]] ** 2)
    col = np.clip((v + 1) * 127, 0, 255)
    # the deformed sphere's map is the sphere it came from: no need to compute one
    sphere_map = SphericalMap(v, "tutte", folded=0, triangles=len(f), landmark_stress=np.nan,
                              area_distortion=0.0, seconds=0.0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        s = TriangleMesh(p, f, vertex_colors=col, name="seed").to_surfels()
        full = Encoder(s, level=4, density_weighting=True, sphere_map=sphere_map)
        plain = Encoder(s, level=3, color=False, tangent_weight=None, density_weighting=False,
                        sphere_map=sphere_map)
        return [full.encode(2.5), full.encode(6.0), plain.encode(3.0), plain.encode(12.0)]


# ---------------------------------------------------------------------- mutations
def _mutate_bytes(data: bytes, rng) -> bytes:
    d = bytearray(data)
    for _ in range(int(rng.integers(1, 4))):
        op = int(rng.integers(0, 8))
        n = len(d)
        if n == 0:
            d = bytearray(rng.integers(0, 256, int(rng.integers(1, 64)), dtype=np.uint8).tobytes())
            continue
        i = int(rng.integers(0, n))
        if op == 0:
            d[i] ^= 1 << int(rng.integers(0, 8))
        elif op == 1:
            d[i] = int(rng.choice(_INTERESTING_BYTES))
        elif op == 2:
            d[i] = int(rng.integers(0, 256))
        elif op == 3:
            del d[i:]
        elif op == 4:
            d += rng.integers(0, 256, int(rng.integers(1, 256)), dtype=np.uint8).tobytes()
        elif op == 5:
            del d[i:i + int(rng.integers(1, 64))]
        elif op == 6:
            j = int(rng.integers(0, n))
            d[j:j] = d[i:i + int(rng.integers(1, 64))]
        elif i + 4 <= n:
            if rng.random() < 0.5:
                struct.pack_into("<I", d, i, int(rng.choice(_INTERESTING_U32)))
            else:
                struct.pack_into("<f", d, i, float(rng.choice(_INTERESTING_F32)))
    return bytes(d)


def _mutate_text(data: bytes, rng) -> bytes:
    lines = data.decode("latin-1").split("\n")
    for _ in range(int(rng.integers(1, 4))):
        op = int(rng.integers(0, 8))
        i = int(rng.integers(0, len(lines))) if lines else 0
        if not lines:
            lines = [str(rng.choice(_INTERESTING_LINES))]
        elif op <= 2:  # replace a token
            tok = lines[i].split(" ")
            tok[int(rng.integers(0, len(tok)))] = str(rng.choice(_INTERESTING_TOKENS))
            lines[i] = " ".join(tok)
        elif op == 3:  # drop or add a token
            tok = lines[i].split(" ")
            if rng.random() < 0.5 and len(tok) > 1:
                del tok[int(rng.integers(0, len(tok)))]
            else:
                tok.insert(int(rng.integers(0, len(tok) + 1)), str(rng.choice(_INTERESTING_TOKENS)))
            lines[i] = " ".join(tok)
        elif op == 4:
            lines.insert(i, str(rng.choice(_INTERESTING_LINES)))
        elif op == 5:
            lines[i:i] = [lines[i]] * int(rng.integers(1, 50))
        elif op == 6:
            del lines[i:i + int(rng.integers(1, 20))]
        else:
            j = int(rng.integers(0, len(lines)))
            lines[i], lines[j] = lines[j], lines[i]
    return "\n".join(lines).encode("latin-1")


def _tail_offset(data: bytes, grid: bool = True):
    """Where the container's tail (stream length, CRCs) starts, or None if unparsable
    (``grid=False``: where its colour-grid section would start)."""
    if len(data) < 16:
        return None
    flags, k, clen = data[5], data[7], struct.unpack_from("<H", data, 14)[0]
    if k not in (3, 6):
        return None
    off = 16 + 4 * k + 2 * k * k + 4 * (1 if k <= 3 else 2) + clen
    if flags & 4:
        if len(data) < off + 5:
            return None
        off += 5 + data[off + 4]
    if flags & 8:
        if len(data) < off + 2:
            return None
        off += 2 + struct.unpack_from("<H", data, off)[0]
    if flags & 16:
        if len(data) < off + 4:
            return None
        off += 4 + struct.unpack_from("<I", data, off)[0]
        if len(data) < off + 2:
            return None
        off += 2 + 2 * struct.unpack_from("<H", data, off)[0]
    if flags & 32 and grid:
        if len(data) < off + 3:
            return None
        off += 3 + (data[off + 2] + 7) // 8
    if flags & 64 and data[4] >= 6 and grid:       # output-level hints (format version 6)
        off += 2
    return off if len(data) >= off + 12 else None


def _colour_grid_offset(data: bytes):
    """Where a version-5 container's colour-grid section starts, or None."""
    if len(data) < 16 or not data[5] & 32:
        return None
    return _tail_offset(data, grid=False)


def _reseal(data: bytes) -> bytes:
    """Recompute the stream length and both checksums, so only the values are wrong."""
    off = _tail_offset(data)
    if off is None:
        return data
    d = bytearray(data)
    stream = bytes(d[off + 12:])
    struct.pack_into("<I", d, off, len(stream))
    struct.pack_into("<I", d, off + 4, zlib.crc32(bytes(d[:off + 4])))
    struct.pack_into("<I", d, off + 8, zlib.crc32(stream))
    return bytes(d)


def _mutate_header(data: bytes, rng) -> bytes:
    """Set one header field to a boundary value."""
    d = bytearray(data)
    k = d[7] if len(d) > 7 and d[7] in (3, 6) else 6
    coder = 16 + 4 * k + 2 * k * k + 4 * (1 if k <= 3 else 2)
    field = int(rng.integers(0, 11))
    try:
        if field == 0:
            d[6] = int(rng.choice([0, 1, 5, 6, 7, 8, 9, 10, 12, 13, 255]))  # level
        elif field == 1:
            d[5] = int(rng.integers(0, 256))                                # flags
        elif field == 2:
            d[7] = int(rng.choice([0, 3, 6, 7, 255]))                       # layers
        elif field == 3:
            struct.pack_into("<I", d, 8, int(rng.choice(_INTERESTING_U32)))  # n_surfels
        elif field == 4:                                                     # KLT mean
            struct.pack_into("<f", d, 16 + 4 * int(rng.integers(0, k)),
                             float(rng.choice(_INTERESTING_F32)))
        elif field == 5:                                                     # basis (float16)
            struct.pack_into("<e", d, 16 + 4 * k + 2 * int(rng.integers(0, k * k)),
                             float(rng.choice([0.0, 1.0, -1.0, 2.0, 65504.0, float("nan"),
                                               float("inf"), 1e-7])))
        elif field == 6:                                                     # weights
            struct.pack_into("<f", d, 16 + 4 * k + 2 * k * k, float(rng.choice(_INTERESTING_F32)))
        elif field == 7:                                                     # coder step / planes
            if rng.random() < 0.5:
                struct.pack_into("<f", d, coder + 4, float(rng.choice(_INTERESTING_F32)))
            else:
                d[coder + int(rng.integers(0, 4))] = int(rng.choice(_INTERESTING_BYTES))
        elif field == 8:                                                     # tangent w., anchors
            off = coder + 8
            if rng.random() < 0.5:
                struct.pack_into("<f", d, off, float(rng.choice(_INTERESTING_F32)))
            else:
                d[off + 4 + int(rng.integers(0, 6))] = int(rng.choice(_INTERESTING_BYTES))
        elif field == 9:                                                     # coder length
            struct.pack_into("<H", d, 14, int(rng.choice([0, 1, 7, 9, 255, 65535])))
        else:                                         # colour grid: level, top, passes, order
            off = _colour_grid_offset(bytes(d))
            if off is not None:
                d[off + int(rng.integers(0, 4))] = int(rng.choice(_INTERESTING_BYTES))
    except (IndexError, struct.error):
        pass
    return bytes(d)


def stream_cases(seeds, count: int, seed: int = 0):
    """``count`` mutated streams: ("stream", bytes)."""
    rng = np.random.default_rng(seed)
    for _ in range(count):
        data = seeds[int(rng.integers(0, len(seeds)))]
        r = rng.random()
        if r < 0.35:
            data = _mutate_header(data, rng)
        elif r < 0.85:
            data = _mutate_bytes(data, rng)
        else:
            data = _mutate_bytes(_mutate_header(data, rng), rng)
        if rng.random() < 0.75:
            data = _reseal(data)
        yield ("stream", data)


def file_cases(seeds, count: int, seed: int = 0):
    """``count`` mutated model files: (suffix class, (entry, {name: bytes}))."""
    rng = np.random.default_rng(seed)
    for _ in range(count):
        entry, files = seeds[int(rng.integers(0, len(seeds)))]
        files = dict(files)
        target = entry if rng.random() < 0.8 or len(files) == 1 else \
            list(files)[int(rng.integers(0, len(files)))]
        data = files[target]
        binary = target.endswith(".png") or (target.endswith(".ply") and b"binary" in data[:200])
        if binary and target.endswith(".ply") and rng.random() < 0.5:
            head, sep, body = data.partition(b"end_header\n")
            data = _mutate_text(head, rng) + sep + body
        elif binary or rng.random() < 0.25:
            data = _mutate_bytes(data, rng)
        else:
            data = _mutate_text(data, rng)
        files[target] = data
        yield (file_kind(entry), (entry, files))


def file_kind(entry: str) -> str:
    """The input class of a model file name."""
    return {".ply": "PLY", ".obj": "OBJ/MTL", ".off": "OFF"}[Path(entry).suffix]


# ---------------------------------------------------------------------- running one case
def _finite(*arrays) -> bool:
    return all(a is None or np.all(np.isfinite(np.asarray(a, np.float64))) for a in arrays)


def run_case(kind: str, payload, workdir: Path) -> tuple[str, str]:
    """Run one case in this process: (outcome, detail); never raises."""
    from surfidx import SurfidxError

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            warnings.showwarning = lambda *args, **kwargs: None  # read_surfels shows its own
            with np.errstate(all="ignore"):
                if kind == "stream":
                    from surfidx.codec import decode

                    s = decode(payload)
                    good = _finite(s.positions, s.normals, s.radii) and np.all(
                        np.abs(s.positions) < np.finfo(np.float32).max)
                else:
                    from surfidx import read_surfels

                    entry, files = payload
                    case = Path(tempfile.mkdtemp(dir=workdir))
                    model = case / "model"
                    model.mkdir()
                    for name, data in files.items():
                        (model / name).write_bytes(data)
                    s = read_surfels(model / entry)
                    good = _finite(s.positions, s.normals, s.radii) and np.all(s.radii > 0)
        return ("ok", "") if good else ("crash", "non-finite output")
    except SurfidxError:
        return "clean error", ""
    except MemoryError:
        return "memory kill", "MemoryError"
    except Exception as exc:  # noqa: BLE001 - the point is to catch anything
        tb = traceback.extract_tb(exc.__traceback__)[-1]
        return "crash", f"{type(exc).__name__}: {exc} ({Path(tb.filename).name}:{tb.lineno})"


# ---------------------------------------------------------------------- workers
def _worker(conn, memory_mb: int, workdir: str):
    import resource

    if memory_mb:
        soft = memory_mb * 2 ** 20
        resource.setrlimit(resource.RLIMIT_AS, (soft, soft))
    work = Path(workdir)
    while True:
        task = conn.recv()
        if task is None:
            return
        conn.send(run_case(*task, work))


class _Pool:
    """Worker processes that run one case at a time, replaced when they hang or die."""

    def __init__(self, n: int, memory_mb: int, workdir: str):
        self.ctx = mp.get_context("fork")
        self.args = (memory_mb, workdir)
        self.workers = [self._start() for _ in range(n)]

    def _start(self):
        parent, child = self.ctx.Pipe()
        proc = self.ctx.Process(target=_worker, args=(child, *self.args), daemon=True)
        proc.start()
        return [proc, parent, None, 0.0]  # process, pipe, current task, start time

    def run(self, tasks, timeout: float, on_result):
        tasks = iter(tasks)
        busy = True
        while busy:
            busy = False
            for w in self.workers:
                proc, conn, task, t0 = w
                if task is None:
                    nxt = next(tasks, None)
                    if nxt is None:
                        continue
                    conn.send(nxt)
                    w[2], w[3] = nxt, time.monotonic()
                    busy = True
                    continue
                busy = True
                if conn.poll(0.002):
                    try:
                        on_result(task, conn.recv())
                    except EOFError:
                        on_result(task, self._death(proc))
                        w[:] = self._start()
                        continue
                    w[2] = None
                elif not proc.is_alive():
                    on_result(task, self._death(proc))
                    w[:] = self._start()
                elif time.monotonic() - t0 > timeout:
                    proc.kill()
                    proc.join()
                    on_result(task, ("hang", f"over {timeout:g} s"))
                    w[:] = self._start()

    @staticmethod
    def _death(proc):
        proc.join()
        code = proc.exitcode
        if code in (-9, 137):  # SIGKILL: the kernel's out-of-memory killer
            return "memory kill", "killed by SIGKILL"
        return "crash", f"worker died (exit code {code})"

    def close(self):
        for proc, conn, _, _ in self.workers:
            try:
                conn.send(None)
            except OSError:
                pass
            proc.join(timeout=5)
            if proc.is_alive():
                proc.kill()


def main(argv=None):
    from _markdown import Report, add_markdown_option   # here: tests load this file by path

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--streams", type=int, default=10_000)
    ap.add_argument("--files", type=int, default=1_000)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--timeout", type=float, default=30.0, help="seconds per case")
    ap.add_argument("--memory-mb", type=int, default=4096,
                    help="address-space limit of each worker (0: none)")
    ap.add_argument("--seed", type=int, default=0)
    add_markdown_option(ap, "fuzz")
    args = ap.parse_args(argv)
    report = Report("fuzz", "Fuzzing the readers and the decoder", args.markdown,
                    note="Seeded mutations of small valid streams and model files, each run in "
                         "a worker process with a time and an address-space limit: `ok` is a "
                         "result with finite values, `clean errors` a surfidx error; crashes, "
                         "hangs and memory kills are failures and are listed below the table.")

    t0 = time.perf_counter()
    sseeds, fseeds = stream_seeds(), file_seeds()
    # warm the worker image: compile the numba kernels once, in the parent, before forking
    with tempfile.TemporaryDirectory() as tmp:
        for seed in sseeds:
            run_case("stream", seed, Path(tmp))
        for entry in fseeds:
            run_case("PLY", entry, Path(tmp))
    print(f"seeds ready in {time.perf_counter() - t0:.1f} s "
          f"({len(sseeds)} streams of {min(map(len, sseeds))}-{max(map(len, sseeds))} bytes, "
          f"{len(fseeds)} files)", file=sys.stderr)

    classes = ["stream", "PLY", "OBJ/MTL", "OFF"]
    counts = {c: dict.fromkeys(OUTCOMES, 0) for c in classes}
    crashes = []

    def on_result(task, result):
        outcome, detail = result
        counts[task[0]][outcome] += 1
        if outcome in ("crash", "hang", "memory kill") and len(crashes) < 50:
            crashes.append((task[0], outcome, detail))

    def tasks():
        yield from stream_cases(sseeds, args.streams, args.seed)
        yield from file_cases(fseeds, args.files, args.seed + 1)

    with tempfile.TemporaryDirectory() as work:
        pool = _Pool(args.workers, args.memory_mb, work)
        t1 = time.perf_counter()
        try:
            pool.run(tasks(), args.timeout, on_result)
        finally:
            pool.close()
        elapsed = time.perf_counter() - t1

    report.text(f"\n{args.streams} streams and {args.files} files, seed {args.seed}, "
                f"{args.workers} workers, {args.timeout:g} s and {args.memory_mb} MB per case, "
                f"{elapsed:.0f} s\n")
    head = ["input class", "cases", "ok", "clean errors", "crashes", "hangs", "memory kills"]
    report.markdown("| " + " | ".join(head) + " |")
    report.markdown("|" + "---|" * len(head))
    total = dict.fromkeys(OUTCOMES, 0)
    for c in classes:
        n = sum(counts[c].values())
        for o in OUTCOMES:
            total[o] += counts[c][o]
        report.markdown(f"| {c} | {n:,} | "
                        + " | ".join(f"{counts[c][o]:,}" for o in OUTCOMES) + " |")
    report.markdown(f"| all | {sum(total.values()):,} | "
                    + " | ".join(f"{total[o]:,}" for o in OUTCOMES) + " |")
    for kind, outcome, detail in crashes:
        report.print(f"{kind}: {outcome}: {detail}")
    report.finish()
    return 0 if not crashes else 1


if __name__ == "__main__":
    sys.exit(main())
