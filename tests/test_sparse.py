"""The nested-dissection SPD factorisation shared by the sphere stage."""

import numpy as np
import pytest
import scipy.sparse as sp

from surfidx import InputError
from surfidx.geometry.sparse import SPDSolver, spd_factor


def _laplacian(rng, i, j, m, extra=0.0):
    w = rng.uniform(0.1, 2.0, len(i))
    lap = sp.csr_matrix((np.concatenate([-w, -w]), (np.concatenate([i, j]),
                                                    np.concatenate([j, i]))), shape=(m, m))
    deg = np.bincount(i, w, minlength=m) + np.bincount(j, w, minlength=m) + 1.0
    a = lap + sp.diags(deg)
    if extra:                               # a new pattern, still symmetric positive definite
        a = a + extra * (sp.eye(m, k=5) + sp.eye(m, k=-5))
    return a.tocsc()


def _graph(rng, m=400, k=1500):
    i, j = rng.integers(0, m, k), rng.integers(0, m, k)
    return i[i != j], j[i != j]


def test_solutions_match_a_direct_solve_across_values_and_patterns():
    """Newton's steps factor matrices of one pattern again and again: each solution is the
    system's (so the order is undone), also after the pattern changes and is ordered afresh."""
    from scipy.sparse.linalg import spsolve

    rng = np.random.default_rng(0)
    m = 400
    i, j = _graph(rng, m)
    solver = SPDSolver()
    b = rng.normal(size=m)
    for extra in (0.0, 0.0, 0.5, 0.5):
        a = _laplacian(rng, i, j, m, extra)
        x = solver.factor(a).solve(b)
        np.testing.assert_allclose(x, spsolve(a, b), rtol=1e-10, atol=1e-12)
        np.testing.assert_allclose(a @ x, b, atol=1e-10)


def test_several_right_hand_sides_and_complex_hermitian():
    rng = np.random.default_rng(1)
    m = 300
    i, j = _graph(rng, m, 1000)
    a = _laplacian(rng, i, j, m)
    b = rng.normal(size=(m, 3))
    x = spd_factor(a).solve(b)
    assert x.shape == (m, 3)
    np.testing.assert_allclose(a @ x, b, atol=1e-10)
    # a Hermitian positive definite system (the layout's normal equations)
    h = sp.random(m, m, density=0.02, random_state=2) * (1 + 1j)
    h = (h.conj().T @ h + sp.eye(m)).tocsc()
    bc = rng.normal(size=m) + 1j * rng.normal(size=m)
    np.testing.assert_allclose(h @ spd_factor(h).solve(bc), bc, atol=1e-10)


def test_same_matrix_same_bits():
    """The order has a fixed seed: two factorisations give the same solution bit for bit."""
    rng = np.random.default_rng(3)
    m = 2000
    i, j = _graph(rng, m, 8000)
    a = _laplacian(rng, i, j, m)
    b = rng.normal(size=m)
    np.testing.assert_array_equal(spd_factor(a).solve(b), spd_factor(a.copy()).solve(b))


def test_kept_factors_serve_an_equal_matrix_only():
    """``keep``: an equal matrix (another copy, another format) gets the last factors back,
    a matrix of other values is factored anew; both solve their own system."""
    rng = np.random.default_rng(4)
    m = 300
    i, j = _graph(rng, m, 1000)
    a = _laplacian(rng, i, j, m)
    solver = SPDSolver(keep=True)
    first = solver.factor(a)
    assert solver.factor(a.tocsr().copy()) is first
    b = rng.normal(size=m)
    np.testing.assert_array_equal(first.solve(b), spd_factor(a).solve(b))
    a2 = a.copy()
    a2.data = a2.data * 2.0
    second = solver.factor(a2)
    assert second is not first
    np.testing.assert_allclose(a2 @ second.solve(b), b, atol=1e-10)
    plain = SPDSolver()
    assert plain.factor(a) is not plain.factor(a)      # without keep: factored each time


def test_tiny_and_singular():
    np.testing.assert_allclose(spd_factor(sp.csc_matrix([[2.0]])).solve(np.array([4.0])), [2.0])
    a = sp.csc_matrix(np.array([[1.0, -1.0, 0.0], [-1.0, 2.0, -1.0], [0.0, -1.0, 1.0]]))
    with pytest.raises(RuntimeError, match="singular"):
        spd_factor(a)           # a Laplacian without its shift: a zero pivot


def test_order_cuts_the_fill_of_a_mesh_laplacian():
    """On a grid surface's Laplacian the nested-dissection factors hold far fewer entries than
    SuperLU's own column order gives (the reason for the module)."""
    from scipy.sparse.linalg import splu

    from surfidx.geometry.icosphere import icosphere

    ico = icosphere(5)
    n = ico.n_vertices
    adj = sp.csr_matrix((np.ones(len(ico.neighbor_indices)), ico.neighbor_indices,
                         ico.neighbor_indptr), shape=(n, n))
    lap = (sp.diags(np.asarray(adj.sum(axis=1)).ravel() + 0.1) - adj).tocsr()
    theirs = splu(lap.tocsc(), permc_spec="COLAMD")
    assert spd_factor(lap).nnz < 0.6 * (theirs.L.nnz + theirs.U.nnz)


def test_a_known_pattern_is_factored_in_its_given_order():
    """A solver handed a pattern and its order factors a matrix of that pattern in that order
    (the same solution, bit for bit, as one that asks METIS) and orders another pattern
    itself."""
    from surfidx.geometry.sparse import nested_dissection

    rng = np.random.default_rng(4)
    m = 500
    i, j = _graph(rng, m, 2000)
    a = sp.csr_matrix(_laplacian(rng, i, j, m))
    a.sort_indices()
    order = nested_dissection(a)
    b = rng.normal(size=m)
    given = SPDSolver(pattern=(a.indptr, a.indices), order=order)
    np.testing.assert_array_equal(given.factor(a).solve(b), SPDSolver().factor(a).solve(b))
    other = _laplacian(rng, i, j, m, extra=0.5)          # another pattern: ordered afresh
    np.testing.assert_array_equal(given.factor(other).solve(b), spd_factor(other).solve(b))
    np.testing.assert_allclose(other @ given.factor(other).solve(b), b, atol=1e-10)
    np.testing.assert_array_equal(given.factor(a).solve(b), SPDSolver().factor(a).solve(b))


def test_a_given_order_needs_its_pattern():
    a = sp.csr_matrix(sp.eye(4))
    with pytest.raises(InputError, match="a pattern and its order together"):
        SPDSolver(order=np.arange(4))
    with pytest.raises(InputError, match="the order has 3 entries for a pattern of 4 rows"):
        SPDSolver(pattern=(a.indptr, a.indices), order=np.arange(3))
