"""Shared fixtures: the real data beside the repository, small synthetic models."""

from __future__ import annotations

from pathlib import Path

from surfidx.numerics import use_portable_profile

use_portable_profile()   # before numpy loads: the test process makes the bytes the command makes

import numpy as np  # noqa: E402  (isort: skip)
import pytest
from hypothesis import settings

# Property tests draw the same examples on every run and never fail on the clock: a loaded
# machine must not turn a passing example into a failure (no test asserts wall-clock time).
settings.register_profile("surfidx", deadline=None, derandomize=True)
settings.load_profile("surfidx")

REPO = Path(__file__).resolve().parents[1]
SHARED = REPO.parent / "shared" / "data"
EXAMPLES = REPO / "examples" / "models"


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """``../shared/data`` (skips the test when it is absent)."""
    if not SHARED.is_dir():
        pytest.skip("../shared/data is not present")
    return SHARED


@pytest.fixture(scope="session")
def models(shared_data) -> Path:
    return shared_data / "models"


def icosphere_mesh(level: int = 3):
    """A unit-sphere triangle mesh (vertices, faces) by subdividing an icosahedron."""
    t = (1 + 5 ** 0.5) / 2
    v = np.array([[-1, t, 0], [1, t, 0], [-1, -t, 0], [1, -t, 0], [0, -1, t], [0, 1, t],
                  [0, -1, -t], [0, 1, -t], [t, 0, -1], [t, 0, 1], [-t, 0, -1], [-t, 0, 1]], float)
    f = np.array([[0, 11, 5], [0, 5, 1], [0, 1, 7], [0, 7, 10], [0, 10, 11], [1, 5, 9], [5, 11, 4],
                  [11, 10, 2], [10, 7, 6], [7, 1, 8], [3, 9, 4], [3, 4, 2], [3, 2, 6], [3, 6, 8],
                  [3, 8, 9], [4, 9, 5], [2, 4, 11], [6, 2, 10], [8, 6, 7], [9, 8, 1]])
    v /= np.linalg.norm(v, axis=1)[:, None]
    for _ in range(level):
        verts = list(v)
        cache = {}

        def mid(a, b):
            key = (min(a, b), max(a, b))
            if key not in cache:
                m = verts[a] + verts[b]
                verts.append(m / np.linalg.norm(m))
                cache[key] = len(verts) - 1
            return cache[key]

        nf = []
        for a, b, c in f:
            ab, bc, ca = mid(a, b), mid(b, c), mid(c, a)
            nf += [[a, ab, ca], [b, bc, ab], [c, ca, bc], [ab, bc, ca]]
        v, f = np.array(verts), np.array(nf)
    return v, f


def torus_mesh(R=2.0, r=0.7, nu=40, nv=16):
    """A closed genus-1 triangle mesh (vertices, faces): ``nu x nv`` quads around radii R, r."""
    u = 2 * np.pi * np.arange(nu) / nu
    w = 2 * np.pi * np.arange(nv) / nv
    U, W = np.meshgrid(u, w, indexing="ij")
    v = np.stack([(R + r * np.cos(W)) * np.cos(U), (R + r * np.cos(W)) * np.sin(U),
                  r * np.sin(W)], -1).reshape(-1, 3)
    i, j = np.meshgrid(np.arange(nu), np.arange(nv), indexing="ij")
    i, j = i.ravel(), j.ravel()

    def idx(a, b):
        return (a % nu) * nv + (b % nv)
    f = np.concatenate([np.stack([idx(i, j), idx(i + 1, j), idx(i + 1, j + 1)], 1),
                        np.stack([idx(i, j), idx(i + 1, j + 1), idx(i, j + 1)], 1)])
    return v, f


def tube_mesh(k=8, m=60, h=0.8):
    """(vertices, faces) of a long closed tube: ``m`` rings of ``k`` vertices ``h`` apart, closed
    by a pole at each end."""
    a = 2 * np.pi * np.arange(k) / k
    rings = [np.c_[np.cos(a + (j % 2) * np.pi / k), np.sin(a + (j % 2) * np.pi / k),
                   np.full(k, j * h)] for j in range(m)]
    v = np.vstack(rings + [[0, 0, -1.0], [0, 0, (m - 1) * h + 1.0]])
    f = []
    for j in range(m - 1):
        for i in range(k):
            a0, a1 = j * k + i, j * k + (i + 1) % k
            b0, b1 = (j + 1) * k + i, (j + 1) * k + (i + 1) % k
            f += [[a0, a1, b0], [a1, b1, b0]] if j % 2 == 0 else [[a0, a1, b1], [a0, b1, b0]]
    s, t = m * k, m * k + 1
    for i in range(k):
        f += [[s, (i + 1) % k, i], [t, (m - 1) * k + i, (m - 1) * k + (i + 1) % k]]
    return v, np.array(f)


@pytest.fixture
def sphere_surfels():
    """A unit-sphere SurfelSet (level-3 icosphere, 642 surfels) with a colour gradient."""
    from surfidx import TriangleMesh

    v, f = icosphere_mesh(3)
    col = np.clip((v + 1) * 127.5, 0, 255).astype(np.uint8)
    return TriangleMesh(v, f, vertex_colors=col, name="sphere").to_surfels()
