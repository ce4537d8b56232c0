"""The ``texture`` descriptor on the textured shared models (spot, ycb_banana): invariant under a
similarity of the model and a resampling of its surface, and it tells recolourings apart.

Every model and copy goes through the ingest path (surfels → spherical map → grid → descriptor).
The scale of the figures is the median texture distance between differently coloured models:
the two models and their recolourings (another model's texture on the same UVs, a hue turn, a
channel permutation, the inverted colours).
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from surfidx.describe.descriptors import texture_vector, describe_grid
from surfidx.geometry.icosphere import choose_level
from surfidx.io import read_mesh
from surfidx.geometry.mesh import TriangleMesh
from surfidx.codec.resample import resample
from surfidx.sphere import parameterize

TEXTURED = {"spot": ("spot/spot_triangulated.obj", "spot/spot_texture.png"),
            "ycb_banana": ("ycb_banana/textured_simple_reoriented.obj", None)}


def _surfels(mesh):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return mesh.to_surfels()


def _grid(mesh, *, textures=()):
    """(grids, level): the grid of the mesh's surfels and of the same surfels coloured by each
    of ``textures`` (one geometry, one map)."""
    surfels = _surfels(mesh)
    m = parameterize(surfels, stress=False)
    level = choose_level(len(surfels), sparse_sampling=m.sparse_sampling)
    grids = [resample(surfels, m.points, level)]
    for tex in textures:
        other = _surfels(TriangleMesh(mesh.vertices, mesh.faces, uv=mesh.uv,
                                      uv_faces=mesh.uv_faces, texture=tex))
        grids.append(resample(other, m.points, level))
    return grids, level


def _copy(mesh, rng):
    """A random rotation, scale (0.2–5×) and translation of a textured mesh with 30 % of its
    faces split 1→3 at a random interior point (positions and UVs alike): the same textured
    surface, other surfels."""
    v, f = np.asarray(mesh.vertices, float), np.asarray(mesh.faces, np.int64)
    uv, uvf = np.asarray(mesh.uv, float), np.asarray(mesh.uv_faces, np.int64)
    pick = rng.random(len(f)) < 0.3
    w = rng.dirichlet([2.0, 2.0, 2.0], size=int(pick.sum()))

    def split(points, faces):
        new = np.einsum("fk,fkd->fd", w, points[faces[pick]])
        m = len(points) + np.arange(len(new))
        a, b, c = faces[pick].T
        return (np.vstack([points, new]),
                np.vstack([faces[~pick], np.c_[a, b, m], np.c_[b, c, m], np.c_[c, a, m]]))

    v, f = split(v, f)
    uv, uvf = split(uv, uvf)
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    q = q * np.sign(np.diag(r))
    scale = float(np.exp(rng.uniform(np.log(0.2), np.log(5.0))))
    return TriangleMesh(scale * v @ q.T + rng.normal(scale=10.0, size=3), f, uv=uv,
                        uv_faces=uvf, texture=mesh.texture)


def _hue_turn(rgb, degrees):
    """Colours turned about the grey axis through mid-grey (clipped to 0..255)."""
    t = np.radians(degrees)
    k = np.ones(3) / np.sqrt(3.0)
    kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    rot = np.eye(3) + np.sin(t) * kx + (1 - np.cos(t)) * kx @ kx
    return np.clip((rgb - 127.5) @ rot.T + 127.5, 0.0, 255.0)


@pytest.fixture(scope="module")
def textured(models):
    """Per model: its texture vector, the vectors of one copy and of its recolourings."""
    meshes = {}
    for name, (path, tex) in TEXTURED.items():
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            meshes[name] = read_mesh(models / path, **({} if tex is None
                                                       else {"texture": models / tex}))
    out = {}
    for name, mesh in meshes.items():
        others = [m.texture for o, m in meshes.items() if o != name]
        (grid, other), level = _grid(mesh, textures=others)
        col = grid[:, 3:]
        recoloured = {"other texture": texture_vector(other[:, 3:], level, 24),
                      "hue 120": texture_vector(_hue_turn(col, 120.0), level, 24),
                      "channels": texture_vector(col[:, [2, 0, 1]], level, 24),
                      "inverted": texture_vector(255.0 - col, level, 24)}
        (copy,), clevel = _grid(_copy(mesh, np.random.default_rng(7)))
        out[name] = {"grid": grid, "level": level,
                     "vector": texture_vector(col, level, 24),
                     "copy": texture_vector(copy[:, 3:], clevel, 24),
                     "recoloured": recoloured}
    return out


def _median(textured):
    vecs = [t["vector"] for t in textured.values()]
    vecs += [v for t in textured.values() for v in t["recoloured"].values()]
    return float(np.median([np.linalg.norm(a - b) for i, a in enumerate(vecs)
                            for b in vecs[i + 1:]]))


def test_texture_vector_is_describe_grids(textured):
    t = textured["spot"]
    d = describe_grid(t["grid"], t["level"]).vectors["texture"]
    np.testing.assert_allclose(d, t["vector"], rtol=1e-6, atol=1e-7)


def test_texture_invariant_under_similarity_and_resampling(textured):
    """A rotated, moved, rescaled and resampled copy stays within 5 % of the median distance
    between differently coloured models (measured: spot 0.7 %, ycb_banana 0.1 %)."""
    med = _median(textured)
    for name, t in textured.items():
        assert np.linalg.norm(t["copy"] - t["vector"]) <= 0.05 * med, name


def test_texture_tells_recolourings_apart(textured):
    """The same shape recoloured is farther than the invariance copy, by a wide margin: a hue
    turn about the grey axis is an orthogonal map of colour space, which leaves the colour KLT
    layers' energies as they are, so it is seen through the mean colour."""
    for name, t in textured.items():
        d_copy = np.linalg.norm(t["copy"] - t["vector"])
        for how, vec in t["recoloured"].items():
            assert np.linalg.norm(vec - t["vector"]) > 5.0 * d_copy, (name, how)
    # the hue turn changes only the mean colour (the last three values), up to clipping
    t = textured["ycb_banana"]
    turned = t["recoloured"]["hue 120"]
    layers = slice(0, turned.size - 3)
    assert (np.linalg.norm(turned[layers] - t["vector"][layers])
            < 0.2 * np.linalg.norm(turned - t["vector"]))
