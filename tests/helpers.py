"""Helpers shared by several test files: processor and decoder doubles for ingest and the
command line, model trees, small images and database files, synthetic meshes.

Test files import them with ``from helpers import ...`` (``tests/`` is on ``sys.path``, as for
``conftest``); a test file never imports another test file.
"""

from __future__ import annotations

import io
import os
import signal
import subprocess
import sqlite3
import sys
import time
from pathlib import Path

import numpy as np

from surfidx import InputError, SurfelSet, TriangleMesh
from surfidx.pipeline import ProcessedModel, content_hash


TESTS = Path(__file__).resolve().parent


_PYTEST_PID = os.getpid()


def fake_processor(path, *, bits_per_surfel=8.0, texture=None, samples=None, level=None):
    """A deterministic stand-in for surfidx.pipeline.process_model, driven by the file's text.

    ``FAIL`` raises InputError, ``BOOM`` RuntimeError, ``CRASH`` kills the worker process,
    ``INTERRUPT`` raises KeyboardInterrupt, ``SLOW`` sleeps 0.3 s, ``HANG`` 60 s; ``color`` (or
    a texture) gives colour. Descriptors, stream and thumbnail derive from the content hash.
    """
    path = Path(path)
    data = path.read_bytes()
    if b"FAIL" in data:
        raise InputError("deliberately unusable model", path=path)
    if b"BOOM" in data:
        raise RuntimeError("kaboom")
    if b"CRASH" in data:
        if os.getpid() == _PYTEST_PID:           # never end the test process itself
            raise RuntimeError("CRASH double called in-process")
        os._exit(3)
    if b"INTERRUPT" in data:
        raise KeyboardInterrupt
    if b"SLOW" in data:
        time.sleep(0.3)
    if b"HANG" in data:
        time.sleep(60)
    h = content_hash(path, texture=texture)
    seed = int(h[:8], 16)
    rng = np.random.default_rng(seed)
    color = texture is not None or b"color" in data
    desc = {"shape": rng.standard_normal(12).astype(np.float32)}
    if color:
        desc["texture"] = rng.standard_normal(6).astype(np.float32)
    stream = rng.integers(0, 256, 64, dtype=np.uint8).tobytes()
    n = 100 + seed % 1000
    return ProcessedModel(
        name=path.stem, source=str(path.resolve()), content_hash=h, n_surfels=n,
        has_color=color, bbox=np.array([[0.0, 0, 0], [1, 1, 1]]), stream=stream,
        format_version=1, rate=8.0 * len(stream) / n,
        quality={"psnr_d1": 50.0, "psnr_d2": 60.0, "psnr_y": 30.0 if color else None},
        descriptors=desc, thumbnail=tiny_png(seed), params={"bits_per_surfel": bits_per_surfel,
                                                            "texture": texture},
        timings={})


def make_tree(root: Path, n: int = 6, *, extra: dict | None = None) -> Path:
    """A folder of ``n`` small model files (.ply/.obj/.off, nested), plus ``extra`` name->text."""
    root.mkdir(parents=True, exist_ok=True)
    suffixes = [".ply", ".obj", ".off"]
    for i in range(n):
        sub = root / ("sub" if i % 2 else "")
        sub.mkdir(exist_ok=True)
        (sub / f"m{i}{suffixes[i % 3]}").write_text(f"model {i}\n" + ("color\n" if i % 2 else ""))
    (root / "notes.txt").write_text("not a model")
    (root / ".hidden.ply").write_text("hidden")
    for name, text in (extra or {}).items():
        (root / name).write_text(text)
    return root


def bytes_name(folder: Path, name: bytes, data: bytes) -> str:
    """Write ``data`` to the file ``name`` (raw bytes, maybe not UTF-8) in ``folder``; its OS
    text path (``os.fsdecode``)."""
    path = os.path.join(os.fsencode(folder), name)
    with open(path, "wb") as fh:
        fh.write(data)
    return os.fsdecode(path)


def process_dead(pid: int) -> bool:
    """The process is gone (or a zombie waiting for its new parent to reap it)."""
    try:
        with open(f"/proc/{pid}/stat") as fh:
            return fh.read().rsplit(")", 1)[1].split()[0] == "Z"
    except FileNotFoundError:
        return True


def wait_dead(pids, seconds=60.0) -> list:
    """The pids still alive after waiting up to ``seconds`` for them to end."""
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline and not all(process_dead(p) for p in pids):
        time.sleep(0.1)
    return [p for p in pids if not process_dead(p)]


def pid_processor(path, **kw):
    """``fake_processor`` that first writes its process id to ``<path>.pid`` (whole: written
    beside it, then renamed, so a reader never sees an empty file)."""
    tmp = Path(str(path) + ".pid.tmp")
    tmp.write_text(str(os.getpid()))
    os.replace(tmp, Path(str(path) + ".pid"))
    return fake_processor(path, **kw)


_ORPHAN_SCRIPT = """
import sys
sys.path.insert(0, {tests!r})
import ingest, helpers
ingest.run([{root!r}], db={db!r}, processor=helpers.pid_processor, progress=False,
           workers=2, **{extra})
"""


def kill_parent_and_watch_workers(tmp_path, n_pids, extra="{}"):
    """Run an ingest in a subprocess (one HANG model, one quick one), SIGKILL it once its workers
    have started the models; returns the worker pids still alive after that."""
    root = tmp_path / "data"
    root.mkdir()
    (root / "a.ply").write_text("model a")               # done at once: that worker idles
    (root / "b.ply").write_text("model b HANG")          # busy for 60 s
    script = _ORPHAN_SCRIPT.format(tests=str(TESTS), root=str(root), db=str(tmp_path / "o.db"),
                                   extra=extra)
    proc = subprocess.Popen([sys.executable, "-c", script], stderr=subprocess.PIPE)
    try:
        deadline = time.monotonic() + 120
        while len(list(root.glob("*.pid"))) < n_pids and time.monotonic() < deadline:
            assert proc.poll() is None, proc.stderr.read().decode()[-2000:]
            time.sleep(0.1)
        pids = sorted({int(p.read_text()) for p in root.glob("*.pid")})
        assert proc.pid not in pids and len(pids) >= 1
        os.kill(proc.pid, signal.SIGKILL)                 # only the parent, as the OOM killer
    finally:
        proc.wait()
        proc.stderr.close()
    alive = wait_dead(pids)
    for pid in alive:                                     # never leave orphans behind
        os.kill(pid, signal.SIGKILL)
    return alive


def tiny_png(seed: int = 0, size: int = 8) -> bytes:
    """A small solid-colour PNG made with Pillow."""
    from PIL import Image

    rgb = tuple(int(c) for c in np.random.default_rng(seed).integers(0, 256, 3))
    buf = io.BytesIO()
    Image.new("RGB", (size, size), rgb).save(buf, format="PNG")
    return buf.getvalue()


def foreign_database(path, *, user_version=0, application_id=0, tables=("meta", "models")):
    conn = sqlite3.connect(path)
    for t in tables:
        conn.execute(f"CREATE TABLE {t} (key TEXT, value TEXT)")
    conn.execute(f"PRAGMA user_version = {user_version}")
    conn.execute(f"PRAGMA application_id = {application_id}")
    conn.commit()
    conn.close()


def damage_database(path):
    """Overwrite every page but the first (the header and the table list) with garbage."""
    size = path.stat().st_size
    rng = np.random.default_rng(7)
    with open(path, "r+b") as fh:
        fh.seek(4096)
        fh.write(rng.integers(0, 256, size - 4096, dtype=np.uint8).tobytes())


def write_png(path, size=(4, 4), colour=(200, 30, 30)):
    from PIL import Image

    Image.new("RGB", size, colour).save(path)
    return path


def write_bomb_png(path, side=50000):
    """A valid 1-pixel PNG whose header declares ``side`` × ``side`` pixels."""
    import io as _io
    import struct
    import zlib

    from PIL import Image

    buf = _io.BytesIO()
    Image.new("RGB", (1, 1)).save(buf, "PNG")
    d = bytearray(buf.getvalue())
    d[16:24] = struct.pack(">II", side, side)
    d[29:33] = struct.pack(">I", zlib.crc32(bytes(d[12:29])))
    path.write_bytes(bytes(d))
    return path


def off_sphere(head, vertex=lambda p: " ".join(map(str, p)), sep="\n"):
    from conftest import icosphere_mesh

    v, f = icosphere_mesh(3)
    return (head.format(nv=len(v), nf=len(f)) + sep + "".join(vertex(p) + "\n" for p in v)
            + "".join(f"3 {a} {b} {c}\n" for a, b, c in f))


def sphere_with_holes(centres, level=3):
    """An icosphere with the faces of each listed vertex's star removed (one hole each)."""
    from conftest import icosphere_mesh

    v, f = icosphere_mesh(level)
    return v, f[~np.isin(f, centres).any(axis=1)]


def voxel_plate(width, holes):
    """Boundary surface of a one-voxel-thick plate ``width x 3`` with the listed cells empty:
    genus ``len(holes)``."""
    cells = {(i, j, 0) for i in range(width) for j in range(3)} - {(i, j, 0) for i, j in holes}
    index, verts, faces = {}, [], []

    def vid(p):
        if p not in index:
            index[p] = len(verts)
            verts.append(p)
        return index[p]
    for c in sorted(cells):
        for a in range(3):
            b, d = (a + 1) % 3, (a + 2) % 3
            for sign in (1, -1):
                nb = list(c)
                nb[a] += sign
                if tuple(nb) in cells:
                    continue
                p = np.array(c)
                if sign > 0:
                    p[a] += 1
                eb, ed = np.eye(3, dtype=int)[b], np.eye(3, dtype=int)[d]
                q = [p, p + eb, p + eb + ed, p + ed]
                if sign < 0:
                    q = q[::-1]
                ids = [vid(tuple(int(x) for x in s)) for s in q]
                faces += [[ids[0], ids[1], ids[2]], [ids[0], ids[2], ids[3]]]
    return np.array(verts, float), np.array(faces)


def tetrahedron(offset=(0, 0, 0)):
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], float) + offset
    f = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    return v, f


def moebius(n=24):
    t = 2 * np.pi * np.arange(n) / n
    top = np.c_[np.cos(t) * (2 + 0.5 * np.cos(t / 2)), np.sin(t) * (2 + 0.5 * np.cos(t / 2)),
                0.5 * np.sin(t / 2)]
    bot = np.c_[np.cos(t) * (2 - 0.5 * np.cos(t / 2)), np.sin(t) * (2 - 0.5 * np.cos(t / 2)),
                -0.5 * np.sin(t / 2)]
    v = np.vstack([top, bot])
    f = []
    for i in range(n):
        a, b, c, d = i, n + i, (i + 1) % n, n + (i + 1) % n
        if i == n - 1:        # the half twist: the last quad joins top to bottom
            c, d = n, 0
        f += [[a, b, d], [a, d, c]]
    return v, np.array(f)


def pinched_sphere():
    """An icosphere whose vertex 50 is merged into vertex 0 (far apart): one pinched vertex."""
    from conftest import icosphere_mesh

    v, f = icosphere_mesh(3)
    f = np.where(f == 50, 0, f)
    keep = np.ones(len(v), bool)
    keep[50] = False
    remap = np.cumsum(keep) - 1
    return v[keep], remap[f]


def limbs_surfels(level=3):
    """A sphere with two long thin limbs pulled out of it (a synthetic shape with limbs)."""
    from conftest import icosphere_mesh

    v, f = icosphere_mesh(level)
    v = v.copy()
    for axis in (0, 1):
        d = v[:, axis]
        tip = d > 0.85
        v[tip, axis] += 4.0 * (d[tip] - 0.85) / 0.15
    return TriangleMesh(v, f, name="limbs").to_surfels()


DECODED = []


def fake_decode(stream: bytes, *, bits_per_surfel=None, **level) -> SurfelSet:
    """A stand-in for surfidx.codec.decode: a surfel set built from the stream's bytes; a lower
    rate keeps a prefix (one surfel per 4 bytes, at least 3), a ``level`` the first level + 3."""
    DECODED.append((len(stream), bits_per_surfel, *level.values()))
    data = np.frombuffer(stream, np.uint8).astype(np.float64)
    n = len(data) // 4 if bits_per_surfel is None else max(3, int(bits_per_surfel))
    n = min(n, len(data) // 4, level.get("level", n) + 3)
    pos = data[: 3 * n].reshape(n, 3)
    normals = np.tile([0.0, 0.0, 1.0], (n, 1))
    return SurfelSet(pos, normals, np.full(n, 0.5), name="decoded")


OBJ = {"processor": fake_processor, "decoder": fake_decode}


def checker_sphere(level: int = 3, size: int = 256, checks: int = 8):
    """A unit sphere mesh textured with a black-and-white checkerboard of ``checks`` × ``checks``
    squares on longitude/latitude texture coordinates (split at the date line)."""
    from surfidx import TriangleMesh
    from surfidx.geometry.icosphere import icosphere

    ico = icosphere(level)
    v = np.asarray(ico.vertices, np.float64)
    f = np.asarray(ico.faces, np.int64)
    u = (np.arctan2(v[:, 1], v[:, 0]) / (2 * np.pi)) % 1.0
    t = np.arccos(np.clip(v[:, 2], -1, 1)) / np.pi
    cu = u[f]
    wrap = (cu.max(axis=1) - cu.min(axis=1)) > 0.5
    cu[wrap] = np.where(cu[wrap] < 0.5, cu[wrap] + 1.0, cu[wrap])
    uv = np.column_stack([cu.ravel(), 1.0 - t[f].ravel()])
    ij = np.indices((size, size))
    board = ((ij[0] * checks // size + ij[1] * checks // size) % 2 * 255).astype(np.uint8)
    image = np.repeat(board[:, :, None], 3, axis=2)
    return TriangleMesh(v, f, uv=uv, uv_faces=np.arange(3 * len(f)).reshape(-1, 3),
                        texture=image, name="checker")


def glb_json(path) -> dict:
    """The JSON chunk of a GLB file."""
    import json
    import struct

    data = Path(path).read_bytes()
    length = struct.unpack("<I", data[12:16])[0]
    return json.loads(data[20:20 + length])


def coloured_limbs() -> SurfelSet:
    """:func:`limbs_surfels` (level 3, 1038 surfels) coloured by position."""
    s = limbs_surfels(3)
    lo, hi = s.bounds
    col = np.clip((s.positions - lo) / (hi - lo) * 255, 0, 255).astype(np.uint8)
    return SurfelSet(s.positions, s.normals, s.radii, col, faces=s.faces, name="limbs")


def capsule(length=2.0, radius=0.6, n=24, rings=10):
    """(vertices, faces) of a closed capsule along z: two hemispheres joined by a cylinder."""
    import trimesh

    m = trimesh.creation.capsule(height=length, radius=radius, count=[n, rings])
    return np.asarray(m.vertices, float), np.asarray(m.faces, np.int64)


def one_view(v, f, direction=(1.0, 0.3, 0.2)):
    """The faces of a closed convex mesh that face a camera far along ``direction``: what a
    single view of it scans (a convex shape hides nothing else)."""
    d = np.asarray(direction, float)
    t = v[f]
    keep = f[np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]) @ d > 0]
    used, inv = np.unique(keep, return_inverse=True)
    return v[used], inv.reshape(-1, 3)


def write_off(path, v, f):
    """Write vertices and triangles as an OFF file; returns ``path``."""
    with open(path, "w") as fh:
        fh.write(f"OFF\n{len(v)} {len(f)} 0\n")
        np.savetxt(fh, v, fmt="%.9g")
        np.savetxt(fh, np.c_[np.full(len(f), 3), f], fmt="%d")
    return path


def _shape(kind: str):
    import trimesh

    return {"ball": lambda: trimesh.creation.icosphere(subdivisions=3),
            "capsule": lambda: trimesh.creation.capsule(height=1.0, radius=0.4, count=[16, 16]),
            "box": lambda: trimesh.creation.box(extents=[1, 2, 3]).subdivide().subdivide(),
            "cylinder": lambda: trimesh.creation.cylinder(radius=0.5, height=2.0,
                                                          sections=32).subdivide()}[kind]()


def shapes_database(path, entries):
    """A database at ``path`` holding small primitive shapes: ``entries`` are
    ``(kind, name, tags)`` with kind ``ball``, ``capsule``, ``box`` or ``cylinder``."""
    from surfidx.database import Database

    with Database.open(path) as db:
        for kind, name, tags in entries:
            db.ingest(_shape(kind), name=name, **({"tags": list(tags)} if tags else {}))
    return path
