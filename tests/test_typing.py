"""The public surface type-checks: ``surfidx`` ships ``py.typed`` and ``__init__.pyi`` (the lazy
names for IDEs and type checkers), and mypy accepts a script that uses them."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from conftest import REPO

SCRIPT = '''
from pathlib import Path

import numpy as np

import surfidx
from surfidx import (TOL, Database, DescriptorSet, Encoder, InputError, MapOptions, SurfelSet,
                     SurfidxError, TriangleMesh, decode, describe_grid, encode, parameterize,
                     read_surfels)

s: SurfelSet = surfidx.read_surfels(Path("model.ply"), samples=1000)
t: SurfelSet = read_surfels("model.obj", texture="model.png")
mesh: TriangleMesh = surfidx.read_mesh("model.off")
n: int = len(s)
positions: np.ndarray = s.positions
stream: bytes = encode(s, bits_per_surfel=8.0)
again: bytes = Encoder(s, level=5).encode(4.0)
back = decode(stream, bits_per_surfel=2.0)
cloud = s.to_trimesh()
tm = mesh.to_trimesh()
smap: surfidx.SphericalMap = parameterize(s, options=MapOptions())
grid = np.zeros((surfidx.Icosphere(3).n_vertices, 3))
d: DescriptorSet = describe_grid(grid, 3)
level: int = surfidx.choose_level(len(s))
model: surfidx.ProcessedModel = surfidx.process_model("model.ply", bits_per_surfel=8.0)
with Database("models.db") as db:
    db.add(model)
err: type[SurfidxError] = InputError
version: str = surfidx.__version__
tol = TOL
'''


def test_mypy_accepts_the_public_surface(tmp_path):
    pytest.importorskip("mypy")
    script = tmp_path / "use_surfidx.py"
    script.write_text(SCRIPT)
    out = subprocess.run(
        [sys.executable, "-m", "mypy", "--follow-imports=silent", "--ignore-missing-imports",
         "--no-incremental", "--cache-dir", str(tmp_path / "cache"), "--python-executable",
         sys.executable, str(script)],
        capture_output=True, text=True, cwd=REPO, timeout=600,
        env=dict(os.environ, PYTHONPATH=str(REPO), MYPYPATH=str(REPO)))
    assert out.returncode == 0, out.stdout + out.stderr
