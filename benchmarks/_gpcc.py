"""MPEG G-PCC (the TMC13 reference software's ``tmc3``) as a baseline of the rate-distortion
benchmark, when the binary is found.

``tmc3`` codes integer coordinates, so the surfels' positions are voxelised first on a grid of
``2**INPUT_DEPTH`` cells along the bounding cube's side (an error some 100 dB below the peak,
negligible at every rate measured). Lossy geometry is then coded two ways, as MPEG's common test
conditions do:

* **octree**: ``positionQuantizationScale = 2**(depth - INPUT_DEPTH)``, i.e. an octree of
  ``depth`` levels over the bounding cube (duplicates merged);
* **trisoup**: the same quantisation with ``trisoupNodeSizeLog2`` 2..4: triangles inside each
  node, their surface resampled at the decoder. Trisoup needs points about one voxel apart, so
  its depths are chosen around the input's spacing (:func:`trisoup_depths`).

With colour, the RGB attribute is coded by RAHT (``--attribute=color --transformType=0``) at a
``qp`` paired with the geometry's depth (:func:`colour_qp`: finer geometry, finer colour, as the
test conditions pair them).

The rate is the whole bitstream ``tmc3`` writes (``len(out.bin) * 8 / n``). The evaluated points
are those ``tmc3 --mode=1`` decodes from it, scaled back to model units; like Draco's they carry no
normals, so each takes the normal of its nearest *input* surfel (favouring G-PCC, see
``_draco.py``), and radii from their spacing. Times are the encoder's and the decoder's wall
seconds (process start included).
"""

from __future__ import annotations

import math
import os
import shutil
import subprocess
import tempfile
import time
from pathlib import Path

import numpy as np

from surfidx.geometry.mesh import spacing_radii
from surfidx.geometry.surfels import SurfelSet

__all__ = ["INPUT_DEPTH", "OCTREE_DEPTHS", "TRISOUP_NODES", "find_tmc3", "colour_qp",
           "trisoup_depths", "gpcc_point", "gpcc_settings"]

#: Bits per axis of the voxelised input.
INPUT_DEPTH = 16
#: Octree depths swept (bits per axis after quantisation), like Draco's 6..14.
OCTREE_DEPTHS = tuple(range(6, 15))
#: Trisoup node sizes (log2 voxels) swept at each trisoup depth.
TRISOUP_NODES = (2, 3, 4)
#: Where the shared tools keep the binary (beside the repository).
DEFAULT_TMC3 = Path(__file__).resolve().parents[2] / "shared" / "tools" / "tmc13" / "tmc3"
#: Seconds one tmc3 run may take before it is abandoned.
TIMEOUT_S = 600


def find_tmc3(explicit: Path | None = None) -> Path | None:
    """The ``tmc3`` binary: ``explicit`` when given, else the shared tools' one, else ``tmc3``
    on PATH; None when that is not an executable file."""
    for cand in ((explicit,) if explicit else (DEFAULT_TMC3, shutil.which("tmc3"))):
        if cand and Path(cand).is_file() and os.access(cand, os.X_OK):
            return Path(cand)
    return None


def colour_qp(depth: int) -> int:
    """RAHT quantisation parameter paired with an octree depth: 22 at depth 12 and above, 6 more
    per level below, at most 51."""
    return int(min(51, max(22, 22 + 6 * (12 - depth))))


def trisoup_depths(surfels: SurfelSet) -> tuple[int, ...]:
    """Trisoup depths around the one whose voxel matches the surfels' median spacing (from one
    level below it to two above)."""
    from scipy.spatial import cKDTree

    d, _ = cKDTree(surfels.positions).query(surfels.positions, k=2)
    spacing = float(np.median(d[:, 1]))
    side = float((surfels.positions.max(0) - surfels.positions.min(0)).max())
    base = int(round(math.log2(side / max(spacing, side * 2.0 ** -INPUT_DEPTH))))
    return tuple(d for d in range(base - 1, base + 3) if 4 <= d <= 12)


def gpcc_settings(surfels: SurfelSet) -> list[tuple[str, int, int]]:
    """Every ``(mode, depth, trisoup node log2)`` swept: octree at :data:`OCTREE_DEPTHS` (node 0),
    trisoup at :func:`trisoup_depths` x :data:`TRISOUP_NODES`."""
    out = [("octree", d, 0) for d in OCTREE_DEPTHS]
    out += [("trisoup", d, t) for d in trisoup_depths(surfels) for t in TRISOUP_NODES]
    return out


def _write_ply(path: Path, coords: np.ndarray, colors: np.ndarray | None) -> None:
    head = ["ply", "format ascii 1.0", f"element vertex {len(coords)}",
            "property float x", "property float y", "property float z"]
    if colors is not None:
        head += ["property uchar red", "property uchar green", "property uchar blue"]
    table = coords if colors is None else np.hstack([coords, colors.astype(np.int64)])
    with open(path, "w") as f:
        f.write("\n".join(head + ["end_header"]) + "\n")
        np.savetxt(f, table, fmt="%d")


def _read_ply(path: Path, color: bool) -> tuple[np.ndarray, np.ndarray | None]:
    """The vertices (and RGB) of an ASCII PLY written by tmc3 (``--outputBinaryPly=0``)."""
    with open(path) as f:
        props, n, element = [], 0, None
        for line in f:
            w = line.split()
            if w[:1] == ["element"]:
                element = w[1]
                if element == "vertex":
                    n = int(w[2])
            elif w[:1] == ["property"] and element == "vertex":
                props.append(w[-1])
            elif w == ["end_header"]:
                break
        table = np.loadtxt(f, max_rows=n, ndmin=2) if n else np.zeros((0, len(props)))
    idx = {p: i for i, p in enumerate(props)}
    xyz = table[:, [idx["x"], idx["y"], idx["z"]]]
    rgb = None
    if color:
        rgb = np.clip(np.round(table[:, [idx["red"], idx["green"], idx["blue"]]]), 0, 255)
        rgb = rgb.astype(np.uint8)
    return xyz, rgb


def _run(args: list[str]) -> float:
    t0 = time.perf_counter()
    proc = subprocess.run(args, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                          timeout=TIMEOUT_S)
    if proc.returncode != 0:
        tail = " | ".join(proc.stdout.strip().splitlines()[-3:])
        raise RuntimeError(f"tmc3 exited with {proc.returncode}: {tail}")
    return time.perf_counter() - t0


def gpcc_point(tmc3: Path, surfels: SurfelSet, *, mode: str, depth: int, node: int,
               color: bool) -> tuple[int, SurfelSet, float, float]:
    """Encode and decode once: ``(bytes, decoded surfels, encode s, decode s)``."""
    from scipy.spatial import cKDTree

    pos = surfels.positions
    lo = pos.min(axis=0)
    side = float((pos.max(axis=0) - lo).max()) or 1.0
    top = 2 ** INPUT_DEPTH - 1
    coords = np.round((pos - lo) / side * top).astype(np.int64)
    with tempfile.TemporaryDirectory(prefix="gpcc_") as tmp:
        tmp = Path(tmp)
        _write_ply(tmp / "in.ply", coords, surfels.colors if color else None)
        common = ["--outputBinaryPly=0", f"--compressedStreamPath={tmp / 'out.bin'}"]
        enc = [str(tmc3), "--mode=0", f"--uncompressedDataPath={tmp / 'in.ply'}",
               f"--reconstructedDataPath={tmp / 'enc.ply'}", "--mergeDuplicatedPoints=1",
               f"--positionQuantizationScale={2.0 ** (depth - INPUT_DEPTH):.10g}",
               f"--trisoupNodeSizeLog2={node if mode == 'trisoup' else 0}", *common]
        if color:
            enc += ["--attribute=color", "--transformType=0", f"--qp={colour_qp(depth)}"]
        t_enc = _run(enc)
        nbytes = (tmp / "out.bin").stat().st_size
        t_dec = _run([str(tmc3), "--mode=1", f"--reconstructedDataPath={tmp / 'dec.ply'}",
                      *common])
        xyz, rgb = _read_ply(tmp / "dec.ply", color)
    if len(xyz) < 2:
        raise RuntimeError(f"tmc3 decoded {len(xyz)} points")
    points = xyz / top * side + lo
    _, nearest = cKDTree(pos).query(points, k=1, workers=-1)
    decoded = SurfelSet(points, surfels.normals[nearest], spacing_radii(points), rgb,
                        name=surfels.name)
    return nbytes, decoded, t_enc, t_dec
