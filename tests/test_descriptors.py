"""Descriptors: invariances by construction and the distance."""

import numpy as np
import pytest

from surfidx import InputError
from surfidx.describe.descriptors import DESCRIPTOR_VERSION, describe_grid, descriptor_distance
from surfidx.geometry.icosphere import icosphere


def _shape(v):
    return v * (1 + 0.3 * v[:, [0]] ** 2 + 0.2 * v[:, [1]] * v[:, [2]]) * [1.0, 1.6, 2.3]


def _rot(seed):
    q, _ = np.linalg.qr(np.random.default_rng(seed).normal(size=(3, 3)))
    return q


def test_object_rotation_translation_scale_invariance():
    v = icosphere(5).vertices
    s = _shape(v)
    col = np.clip((v + 1) * 120, 0, 255)
    a = describe_grid(np.c_[s, col], 5)
    b = describe_grid(np.c_[2.7 * s @ _rot(1).T + [4, -1, 9], col], 5)
    for k in set(a.vectors) - {"views"}:     # views are seen from directions fixed in space
        np.testing.assert_allclose(a.vectors[k], b.vectors[k], atol=1e-5)
    assert set(a.vectors) == {"shape", "layers", "texture", "spectrum", "views"}
    assert a.params["lmax"] == 24 and a.params["normalization"] == "4pi"
    assert a.params["version"] == DESCRIPTOR_VERSION == 9 and a.params["shape"]["shells"] == 8
    assert a.params["shape"]["spectral_k"] == 30
    # a reflection too, and the descriptor does see a different shape
    c = describe_grid(np.c_[0.3 * s * [1, -1, 1] - 5, col], 5)
    np.testing.assert_allclose(a.vectors["shape"], c.vectors["shape"], atol=1e-5)
    d = describe_grid(np.c_[s * [1.0, 1.0, 1.5], col], 5)
    assert np.linalg.norm(a.vectors["shape"] - d.vectors["shape"]) > 0.1


def test_shape_measures_the_surface_not_the_sphere_sampling():
    """The same surface sampled through a different (non-uniform) sphere map: the area-weighted
    measure parts of the shape descriptor barely move, unlike the per-layer sphere energies (the
    ``layers`` kind and the shape vector's layers part, the parameterisation's view)."""
    from surfidx.describe.descriptors import LAYERS_LMAX, SHAPE_PARTS

    v = icosphere(6).vertices
    u = v * [1.0, 1.0, 2.5]
    u /= np.linalg.norm(u, axis=1, keepdims=True)  # crowds the grid samples toward the equator
    a = describe_grid(_shape(v), 6).vectors
    b = describe_grid(_shape(u), 6).vectors
    other = describe_grid(_shape(v) * [1.0, 1.0, 1.6], 6).vectors
    n_layers = 3 * (LAYERS_LMAX + 1)
    measure = slice(0, a["shape"].size - n_layers)    # the layers part comes last
    d_same = np.linalg.norm(a["shape"][measure] - b["shape"][measure])
    d_other = np.linalg.norm(a["shape"][measure] - other["shape"][measure])
    assert d_same < 0.1 * d_other
    rel = lambda x, y: np.linalg.norm(x - y) / np.linalg.norm(x)  # noqa: E731
    assert rel(a["shape"][measure], b["shape"][measure]) < 0.5 * rel(a["layers"], b["layers"])
    assert SHAPE_PARTS[-1] == "layers"


def test_sphere_rotation_invariance():
    """The map is canonical up to a rotation of the sphere: energies must not depend on it."""
    v = icosphere(6).vertices
    a = describe_grid(_shape(v), 6)
    b = describe_grid(_shape(v @ _rot(2).T), 6)
    for kind in ("shape", "layers"):
        rel = np.linalg.norm(a.vectors[kind] - b.vectors[kind]) / np.linalg.norm(a.vectors[kind])
        assert rel < 0.01, kind
    other = describe_grid(v * [1.0, 1.0, 3.0], 6)
    assert descriptor_distance(a.vectors, b.vectors) < 0.1 * descriptor_distance(a.vectors, other.vectors)


def test_distance_weights_and_errors():
    v = icosphere(4).vertices
    a = describe_grid(np.c_[_shape(v), np.full((len(v), 3), 200.0)], 4).vectors
    b = describe_grid(np.c_[_shape(v), np.full((len(v), 3), 20.0)], 4).vectors
    assert descriptor_distance(a, b, shape_weight=1.0) == pytest.approx(0.0, abs=1e-6)
    assert descriptor_distance(a, b, shape_weight=0.0) > 0.5
    g = {k: x for k, x in a.items() if k != "texture"}
    assert descriptor_distance(g, b) == pytest.approx(0.0, abs=1e-6)  # texture dropped
    with pytest.raises(InputError, match=r"shape_weight must be in \[0, 1\]"):
        descriptor_distance(a, b, shape_weight=2)
    with pytest.raises(InputError, match="lacks its 'shape' vector"):
        descriptor_distance({}, b)
    c = dict(a, shape=a["shape"][:75])  # a version-1 (lmax 24) shape vector
    with pytest.raises(InputError, match="descriptor dimensions differ"):
        descriptor_distance(a, c)


def test_bad_input():
    v = icosphere(3).vertices
    with pytest.raises(InputError, match="values must have shape"):
        describe_grid(v[:10], 3)
    with pytest.raises(InputError, match="3 or 6 columns"):
        describe_grid(np.c_[v, v[:, :1]], 3)
    with pytest.raises(InputError, match="zero variance"):
        describe_grid(np.zeros_like(v), 3)
    with pytest.raises(InputError, match="zero area"):
        describe_grid(v * [1.0, 0.0, 0.0], 3)
    with pytest.raises(InputError, match="lmax must be an integer"):
        describe_grid(v, 3, lmax=1)


def test_spectral_part_is_the_sphere_laplacian_spectrum():
    """On the unit sphere the Laplace–Beltrami eigenvalues are l(l+1), multiplicity 2l+1."""
    from surfidx.describe.descriptors import SPECTRAL_K, log_spectrum

    exact = np.concatenate([np.full(2 * l + 1, l * (l + 1.0)) for l in range(1, 7)])[:SPECTRAL_K]
    want = np.log(exact / np.arange(1, SPECTRAL_K + 1))
    for level in (3, 5):   # the dense and the shift-invert solver
        got = log_spectrum(icosphere(level).vertices, level)
        assert np.max(np.abs(got - want)) < (0.02 if level == 5 else 0.06)


def test_spectral_part_is_intrinsic_and_finite_on_squeezed_grids():
    """Bending a surface without stretching keeps its spectrum; a map squeezing grid points onto
    each other (zero-area triangles) still gives a finite descriptor."""
    from surfidx.describe.descriptors import log_spectrum

    v = icosphere(4).vertices
    flat = v * [1.0, 1.0, 0.05]            # a thin disc, then bent around the x axis
    r = 1.5
    bent = np.c_[flat[:, 0], r * np.sin(flat[:, 1] / r), r * (1 - np.cos(flat[:, 1] / r))]
    bent = bent + np.c_[np.zeros((len(v), 1)), -flat[:, [2]] * np.sin(flat[:, 1] / r)[:, None],
                        flat[:, [2]] * np.cos(flat[:, 1] / r)[:, None]]
    a, b = log_spectrum(flat, 4), log_spectrum(bent, 4)
    other = log_spectrum(v * [1.0, 2.0, 0.05], 4)
    assert np.linalg.norm(a - b) < 0.2 * np.linalg.norm(a - other)
    squeezed = v.copy()
    squeezed[squeezed[:, 2] > 0.9] = [0.0, 0.0, 1.0]
    assert np.all(np.isfinite(log_spectrum(squeezed, 4)))
    assert np.all(np.isfinite(describe_grid(squeezed, 4).vectors["shape"]))


def test_heat_part_is_intrinsic_and_tells_limbs_from_bodies():
    """The heat histograms come from the spectral part's eigenpairs: bending a thin strip keeps
    them, a strip of another length (more or less of it far from the middle) does not; each
    time's histogram is a distribution (its square roots' squares sum to 1)."""
    from surfidx.describe.descriptors import (HEAT_BINS, HEAT_TIMES, heat_part,
                                              laplacian_eigenpairs)

    v = icosphere(4).vertices
    flat = v * [1.0, 3.0, 0.05]
    r = 1.5
    bent = np.c_[flat[:, 0], r * np.sin(flat[:, 1] / r), r * (1 - np.cos(flat[:, 1] / r))]
    bent = bent + np.c_[np.zeros((len(v), 1)), -flat[:, [2]] * np.sin(flat[:, 1] / r)[:, None],
                        flat[:, [2]] * np.cos(flat[:, 1] / r)[:, None]]

    def heat(x):
        return heat_part(*laplacian_eigenpairs(x, 4, vectors=True))

    a, b = heat(flat), heat(bent)
    assert a.shape == (len(HEAT_TIMES) * HEAT_BINS,)
    np.testing.assert_allclose((a.reshape(len(HEAT_TIMES), -1) ** 2).sum(axis=1), 1.0)
    for other in (v * [1.0, 1.0, 0.05], v * [1.0, 6.0, 0.05]):
        assert np.linalg.norm(a - b) < 0.05 * np.linalg.norm(a - heat(other))
    lam, phi, share = laplacian_eigenpairs(flat, 4, vectors=True)
    np.testing.assert_allclose(share @ phi ** 2, 1.0, rtol=1e-6)       # mean square 1
    np.testing.assert_allclose(lam, laplacian_eigenpairs(flat, 4)[0], rtol=1e-10, atol=1e-12)


def test_normals_part_is_the_gaussian_image_energy():
    """A sphere faces every way equally: its normals' measure has energy at degree 0 only; a
    flattened ellipsoid's normals crowd at its poles (degree 2)."""
    from surfidx.describe.descriptors import NORMALS_LMAX, normal_energies

    v = icosphere(5).vertices
    round_ = normal_energies(v, 5, None)
    assert round_.shape == (NORMALS_LMAX + 1,)
    assert round_[0] == pytest.approx(1.0 / np.sqrt(4.0 * np.pi))    # orthonormal Y_00
    assert np.all(round_[1:] < 0.001)
    flat = normal_energies(v * [1.0, 1.0, 0.3], 5, None)
    assert flat[2] > 0.3
    assert flat[1] < 0.01            # a closed surface's normals balance: no degree-1 energy
    # weighing out half of the surface (the faces of the x > 0 half as virtual) unbalances them
    half = normal_energies(v, 5, (v[:, 0] < 0).astype(float))
    assert half[1] > 0.2


def test_describe_grid_rejects_level_zero():
    with pytest.raises(InputError, match="level >= 1"):
        describe_grid(icosphere(0).vertices, 0)


def test_cotangent_laplacian_identities():
    """Symmetric, rows summing to 0, and x^T L x is the Dirichlet energy: for a linear function
    f = a.p on a closed surface, sum over triangles of area * |grad f|^2 restricted to the plane."""
    from surfidx.geometry.mesh import cotangent_laplacian

    ico = icosphere(3)
    p = ico.vertices * [1.0, 1.5, 2.0]
    f = ico.faces
    v = p[f]
    cot = np.empty((len(f), 3))
    for a in range(3):
        e1, e2 = v[:, (a + 1) % 3] - v[:, a], v[:, (a + 2) % 3] - v[:, a]
        cot[:, a] = np.einsum("ij,ij->i", e1, e2) / np.linalg.norm(np.cross(e1, e2), axis=1)
    lap = cotangent_laplacian(f, cot, len(p))
    assert abs(lap - lap.T).max() < 1e-12
    np.testing.assert_allclose(np.asarray(lap.sum(axis=1)).ravel(), 0.0, atol=1e-10)
    g = np.array([0.3, -0.2, 0.9])
    n = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
    area = 0.5 * np.linalg.norm(n, axis=1)
    n /= 2 * area[:, None]
    tangential = g - (n @ g)[:, None] * n
    want = float(np.sum(area * np.einsum("ij,ij->i", tangential, tangential)))
    x = p @ g
    assert float(x @ (lap @ x)) == pytest.approx(want, rel=1e-10)


def test_shape_vector_is_the_weighted_parts():
    """``shape`` is the parts side by side, each times its scale, the layers part last: the
    per-degree energies of the geometric KLT layers (:func:`layers_part`)."""
    from surfidx.describe import descriptors as D
    from surfidx.codec.klt import KLT

    v = icosphere(5).vertices
    x = _shape(v)
    geo = KLT.fit(x, sample_weights=icosphere(5).vertex_areas())
    total = float(np.sum(geo.eigenvalues))
    g = geo.forward(x) / np.sqrt(total)
    parts = D.shape_parts(x, 5, g)
    assert tuple(parts) == D.SHAPE_PARTS
    assert parts["layers"].size == 3 * (D.LAYERS_LMAX + 1)
    np.testing.assert_allclose(parts["layers"], D.layers_part(g, 5))
    want = np.concatenate([s * parts[k] for k, s in zip(D.SHAPE_PARTS, D.SHAPE_PART_SCALES)])
    got = describe_grid(x, 5).vectors["shape"]
    np.testing.assert_allclose(got, want.astype(np.float32), rtol=1e-5, atol=1e-6)
    assert len(D.SHAPE_PART_SCALES) == len(D.SHAPE_PARTS) == len(D.SHAPE_PART_MEDIANS)


def test_degree_energies_on_a_finer_grid():
    """A degree-2 function: its energy sits at degree 2, the same on the DH grid of its lmax and
    on a finer one."""
    from surfidx.describe.descriptors import degree_energies

    v = icosphere(5).vertices
    f = (v[:, 0] * v[:, 1])[:, None]           # a degree-2 harmonic
    a = degree_energies(f, 5, 8)[0]
    b = degree_energies(f, 5, 8, grid_lmax=32)[0]
    assert a.shape == b.shape == (9,)
    assert a[2] > 100 * (a.sum() - a[2]) and b[2] > 100 * (b.sum() - b[2])
    assert b[2] == pytest.approx(a[2], rel=0.02)


def test_descriptor_distance_is_the_search_distance():
    """descriptor_distance is weighted_l2 for one pair, with search's default shape weight."""
    import inspect

    from surfidx.describe import distance as search

    rng = np.random.default_rng(3)
    a = {"shape": rng.random(20), "spectrum": rng.random(3), "texture": rng.random(6)}
    b = {"shape": rng.random(20), "spectrum": rng.random(3), "texture": rng.random(6)}
    assert (inspect.signature(descriptor_distance).parameters["shape_weight"].default
            == search.DEFAULT_SHAPE_WEIGHT)
    for w in (0.0, 0.4, search.DEFAULT_SHAPE_WEIGHT, 1.0):
        want = search.weighted_l2(a, {k: v[None] for k, v in b.items()},
                                  {k: np.ones(1, bool) for k in b}, shape_weight=w)[0]
        ds = np.sqrt(np.sum((a["shape"] - b["shape"]) ** 2)
                     + np.sum((a["spectrum"] - b["spectrum"]) ** 2))
        dt = np.linalg.norm(a["texture"] - b["texture"])
        assert descriptor_distance(a, b, shape_weight=w) == pytest.approx(want, rel=1e-12)
        assert want == pytest.approx(w * ds + (1 - w) * dt, rel=1e-12)
    no_colour = {k: v for k, v in b.items() if k != "texture"}
    assert descriptor_distance(a, no_colour) == pytest.approx(ds, rel=1e-12)
    with pytest.raises(InputError, match="descriptor dimensions differ \\('spectrum'"):
        descriptor_distance(a, {"shape": b["shape"]})
    with pytest.raises(InputError, match="descriptor dimensions differ \\('texture'"):
        descriptor_distance(a, dict(b, texture=b["texture"][:3]))
    with pytest.raises(InputError, match=r"shape_weight must be in \[0, 1\], got 'x'"):
        descriptor_distance(a, b, shape_weight="x")


def test_d2_draws_and_distances_are_numpys():
    """D2's kernels give what ``Generator.choice(p=w)`` and ``np.linalg.norm`` give, bit for
    bit: the inverse-CDF draws (with zero weights, ties at bucket edges and u = 0) and the
    pair distances."""
    from surfidx.describe.descriptors import pair_distances, search_right

    rng = np.random.default_rng(5)
    w = rng.random(3001) ** 4
    w[rng.integers(0, len(w), 400)] = 0.0          # zero weights: runs of equal cdf values
    w /= w.sum()
    draws = np.random.default_rng(9).choice(len(w), 50_000, p=w)
    cdf = np.cumsum(w)
    cdf /= cdf[-1]
    u = np.random.default_rng(9).random(50_000)
    assert np.array_equal(search_right(cdf, u), draws)
    edges = np.r_[0.0, np.arange(1, 1 << 16) / (1 << 16), cdf[:-1], np.nextafter(cdf[:-1], 0)]
    edges = edges[(edges >= 0) & (edges < 1)]
    assert np.array_equal(search_right(cdf, edges), np.searchsorted(cdf, edges, side="right"))
    y = rng.normal(size=(500, 3)) * rng.random((500, 1)) * 1e3
    i, j = rng.integers(0, 500, 20_000), rng.integers(0, 500, 20_000)
    assert np.array_equal(pair_distances(y, i, j), np.linalg.norm(y[i] - y[j], axis=1))


def test_sh_expansion_loads_shtools_alone_and_pyshtools_reuses_it():
    """expand_dh loads SHTOOLS' extension without pyshtools' ``__init__``; a later import of
    pyshtools uses that same module (one copy in the process)."""
    import json
    import subprocess
    import sys

    code = ("import sys, json\n"
            "import numpy as np\n"
            "from surfidx.describe.harmonics import expand_dh\n"
            "expand_dh(np.ones((8, 16)), 3)\n"
            "alone = 'pyshtools' not in sys.modules\n"
            "ext = sys.modules.get('pyshtools._SHTOOLS')\n"
            "import pyshtools.backends.shtools\n"
            "same = ext is not None and sys.modules['pyshtools._SHTOOLS'] is ext\n"
            "print(json.dumps([alone, same]))\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         timeout=300, check=True).stdout
    assert json.loads(out.splitlines()[-1]) == [True, True]


def test_sh_expansion_is_pyshtools_fortran_bit_for_bit():
    """expand_dh and degree_spectrum give what pyshtools' Fortran SHExpandDH and its
    ``spectrum`` give, to the bit, on grids of the sizes the descriptors use and others."""
    from pyshtools.backends import shtools
    from pyshtools.spectralanalysis import spectrum

    from surfidx.describe.harmonics import degree_spectrum, expand_dh

    rng = np.random.default_rng(4)
    for lmax_grid, lmax in ((24, 24), (24, 12), (32, 32), (7, 3)):
        n = 2 * (lmax_grid + 1)
        grid = rng.standard_normal((n, 2 * n))
        want = shtools.SHExpandDH(grid, norm=1, sampling=2, csphase=1, lmax_calc=lmax)
        got = expand_dh(grid, lmax)
        assert got.shape == (2, lmax + 1, lmax + 1)
        assert np.array_equal(got, want)
        assert np.array_equal(degree_spectrum(got),
                              spectrum(want, normalization="4pi", unit="per_l"))


def test_sh_expansion_rejects_bad_grids():
    from surfidx.describe.harmonics import expand_dh

    with pytest.raises(InputError, match=r"is \(n, 2n\) with n even, got shape \(51, 102\)"):
        expand_dh(np.zeros((51, 102)), 12)
    with pytest.raises(InputError, match=r"is \(n, 2n\) with n even, got shape \(50, 50\)"):
        expand_dh(np.zeros((50, 50)), 12)
    with pytest.raises(InputError, match=r"lmax must be in 0\.\.24 for a grid of 50 latitudes, "
                                         r"got 25"):
        expand_dh(np.zeros((50, 100)), 25)


def test_describing_loads_no_plotting_or_table_library():
    """Describing a grid imports SHTOOLS' compiled transform only (``pyshtools._SHTOOLS``), not
    pyshtools' package (whose classes load matplotlib, xarray, astropy and pandas); importing
    the package later in the same process still works."""
    import json
    import subprocess
    import sys

    code = ("import sys, json\n"
            "from surfidx.describe.descriptors import describe_grid\n"
            "from surfidx.geometry.icosphere import icosphere\n"
            "v = icosphere(3).vertices\n"
            "describe_grid(v * [1.0, 1.5, 2.0], 3)\n"
            "heavy = {'pyshtools', 'matplotlib', 'xarray', 'astropy', 'pandas'}\n"
            "loaded = {m for m in sys.modules if m != 'pyshtools._SHTOOLS'}\n"
            "print(json.dumps(sorted({m.split('.')[0] for m in loaded} & heavy)))\n"
            "import pyshtools\n"                   # the package still imports afterwards
            "print(pyshtools.expand.SHExpandDH is not None)\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         timeout=300, check=True).stdout.strip().splitlines()
    assert json.loads(out[-2]) == []
    assert out[-1] == "True"


def test_stored_grid_orders_are_metis_orders():
    """The grid Laplacians' nested-dissection orders shipped with the package are METIS's
    (``python -m surfidx.describe.gridorder`` writes them), one for every grid level the
    spectral part factors (more than 700 vertices, up to its level)."""
    from surfidx.describe.descriptors import SPECTRAL_LEVEL
    from surfidx.describe.gridorder import ORDER_LEVELS, grid_order, stored_grid_order
    from surfidx.geometry.icosphere import vertex_count

    assert ORDER_LEVELS == tuple(lev for lev in range(SPECTRAL_LEVEL + 1)
                                 if vertex_count(lev) > 700)
    for level in ORDER_LEVELS:
        np.testing.assert_array_equal(stored_grid_order(level), grid_order(level))
    assert stored_grid_order(SPECTRAL_LEVEL + 1) is None


def test_grid_solver_factors_the_grid_pattern_without_metis(monkeypatch):
    import scipy.sparse as sp

    import surfidx.geometry.sparse as sparse
    from surfidx.describe.gridorder import ORDER_LEVELS, grid_pattern, grid_solver

    def no_metis(a):
        raise AssertionError("METIS asked for a stored order")

    monkeypatch.setattr(sparse, "nested_dissection", no_metis)
    for level in ORDER_LEVELS:
        indptr, indices = grid_pattern(level)
        n = len(indptr) - 1
        a = sp.csr_matrix((-np.ones(len(indices)), indices, indptr), shape=(n, n))
        a.setdiag(8.0)                       # diagonally dominant: positive definite
        b = np.ones(n)
        np.testing.assert_allclose(a @ grid_solver(level).factor(a).solve(b), b, atol=1e-10)


def test_spectrum_is_the_same_with_the_stored_order_and_with_metis(monkeypatch):
    """The grid Laplacian factored in the stored order gives the eigenpairs that a solver
    asking METIS gives, bit for bit."""
    import surfidx.describe.descriptors as descriptors
    from surfidx.geometry.sparse import SPDSolver

    x = _shape(icosphere(4).vertices)
    stored = descriptors.laplacian_eigenpairs(x, 4, vectors=True)
    monkeypatch.setattr(descriptors, "grid_solver", lambda level: SPDSolver())
    ordered = descriptors.laplacian_eigenpairs(x, 4, vectors=True)
    for a, b in zip(stored, ordered):
        np.testing.assert_array_equal(a, b)


def test_harmonic_transform_is_planned_without_timing():
    """The descriptors' transform (100 longitudes) is planned from the stored FFTW wisdom, not
    by timing candidate plans: the same bytes in every fresh process, whatever the load (a
    timed plan could round differently)."""
    import subprocess
    import sys

    code = ("import hashlib, numpy as np\n"
            "from surfidx.describe.harmonics import expand_dh\n"
            "g = np.random.default_rng(0).random((50, 100))\n"
            "print(hashlib.sha256(expand_dh(g, 24).tobytes()).hexdigest())\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         timeout=120, check=True).stdout.split()
    assert out[-1] == "b4ab1a33fa3aa981d5f56537bcaf55158c75aadacf4d1da55f2026b83d3a60e8"
