"""Balancing and untangling of spherical embeddings: exact gradients, monotone, fold-free."""

import numpy as np
import pytest

from surfidx.sphere import MapOptions
from surfidx.sphere.balance import (PATCH_PATIENCE, Energy, near_inverted, Patch,
                                     untangle_rounds, balance, untangle)
from surfidx.sphere.surface import oriented_faces
from surfidx.sphere.tutte import tutte_map
from surfidx.geometry.unitsphere import orientation as _orientation
from helpers import limbs_surfels


def _start():
    s = limbs_surfels()
    f = oriented_faces(s)
    x, _ = tutte_map(s, options=MapOptions(), iterations=0, gamma=0.15, balance=False)
    return s.positions, f, x


@pytest.mark.parametrize("eps, lam", [(-1.0, 1.0), (0.0, 1.0), (0.0, 0.3), (0.05, 1.0)],
                         ids=["symmetric-dirichlet", "conformal-area", "conformal-area-0.3",
                              "untangling"])
def test_gradient_matches_finite_differences(eps, lam):
    p, f, x = _start()
    energy = Energy(p, f)
    energy.eps, energy.lam = eps, lam
    e, g = energy(x)
    rng = np.random.default_rng(0)
    dv = rng.normal(size=x.shape)
    dv -= np.einsum("ij,ij->i", dv, x)[:, None] * x
    h = 1e-7
    fd = (energy(x + h * dv, grad=False)[0] - energy(x - h * dv, grad=False)[0]) / (2 * h)
    assert abs(fd - np.sum(g * dv)) <= 1e-5 * abs(fd)


def test_uniform_scaling_energy_is_exact():
    """An icosphere mapped onto itself, scaled by the area-matching radius R: every triangle is
    scaled by R, so the energy per area is 2 R² + 2 / R² (4 for an isometry)."""
    from conftest import icosphere_mesh

    v, f = icosphere_mesh(3)
    energy = Energy(v, f)
    e, _ = energy(v)
    r = energy.radius
    # areas are measured projected on the tangent plane at the centroid: equal to the chord
    # triangle's area up to the small tilt of its normal on this grid
    assert abs(e / energy.area3.sum() - (2 * r ** 2 + 2 / r ** 2)) < 1e-4


def test_balance_lowers_energy_and_never_folds():
    p, f, x = _start()
    x2, info = balance(x, p, f, iterations=300)
    assert info["steps"] > 0 and info["energy"] < 0.5 * info["energy_start"]
    np.testing.assert_allclose(np.linalg.norm(x2, axis=1), 1.0, atol=1e-12)
    assert np.all(_orientation(x2, f) > 0)


def test_inverted_start_is_returned_unchanged():
    p, f, x = _start()
    bad = x.copy()
    bad[:, 0] *= -1                      # a mirror: every triangle inverted
    x2, info = balance(bad, p, f)
    assert info["steps"] == 0 and np.array_equal(x2, bad)


def test_preconditioner_solves_the_shifted_cotangent_laplacian():
    """The proxy Hessian annihilates nothing: L z + shift·mean(diag)·z = r for the returned z, and
    on a constant field (L·1 = 0) the solve is exactly the shift's inverse."""
    p, f, _ = _start()
    energy = Energy(p, f)
    solve, _ = energy.preconditioner(shift=1e-3)
    ones = np.ones(3 * len(p))
    z = solve(ones).reshape(-1, 3)
    # every vertex moves alike: a constant field is the Laplacian's null space
    np.testing.assert_allclose(z, z[0, 0], rtol=1e-8)
    r = np.random.default_rng(1).normal(size=3 * len(p))
    z = solve(r)
    assert np.all(np.isfinite(z)) and np.linalg.norm(z) > 0


def test_preconditioning_lowers_energy_faster_on_limbs():
    """The accelerated quadratic proxy: same step count, lower energy than plain L-BFGS."""
    p, f, x = _start()
    _, plain = balance(x, p, f, iterations=40, precondition=False)
    x2, pre = balance(x, p, f, iterations=40, precondition=True)
    assert pre["energy"] < plain["energy"]
    assert np.all(_orientation(x2, f) > 0)


def test_lbfgs_history_is_the_two_loop_recursion():
    """The ring-buffer history gives the textbook two-loop direction over the last ``memory``
    pairs, oldest dropped first."""
    from surfidx.sphere.balance import History

    rng = np.random.default_rng(3)
    n, memory = 50, 4
    pairs = []
    for _ in range(7):
        s = rng.normal(size=n)
        pairs.append((s, 2.0 * s + 0.1 * rng.normal(size=n)))   # positive curvature
    hist = History(memory, n)
    for s, y in pairs:
        hist.push(s, y)
    scale = rng.uniform(1, 2, size=n)
    g = rng.normal(size=n)
    d = hist.direction(g.copy(), lambda r: r / scale, lambda r: r * scale)

    kept = pairs[-memory:]
    q, alphas = -g, []
    for s, y in reversed(kept):
        a = (s @ q) / (y @ s)
        alphas.append(a)
        q = q - a * y
    s, y = kept[-1]
    z = q / scale * ((s @ (s * scale)) / (s @ y))
    for (s, y), a in zip(kept, reversed(alphas)):
        z = z + s * (a - (y @ z) / (y @ s))
    np.testing.assert_allclose(d, z, rtol=1e-10)


def test_conformal_area_energy_of_uniform_scaling_is_exact():
    """Icosphere onto itself scaled by R: det = R², ‖J‖² = 2 R², so the energy per area is
    ‖J‖²/det + lam (det + 1/det) = 2 + lam (R² + 1/R²)."""
    from conftest import icosphere_mesh

    v, f = icosphere_mesh(3)
    energy = Energy(v, f)
    energy.eps, energy.lam = 0.0, 0.5
    e, _ = energy(v)
    r2 = energy.radius ** 2
    assert abs(e / energy.area3.sum() - (2 + 0.5 * (r2 + 1 / r2))) < 1e-4


def test_untangle_removes_inverted_triangles():
    p, f, x = _start()
    bad = x.copy()
    rng = np.random.default_rng(1)
    # scramble a patch: 40 vertices near one point swapped among themselves
    near = np.argsort(np.linalg.norm(x - x[0], axis=1))[:40]
    bad[near] = x[rng.permutation(near)]
    assert np.count_nonzero(_orientation(bad, f) <= 0) > 10
    x2, info = untangle(bad, p, f)
    assert info["min_det"] > 0 and info["rounds"] >= 1
    assert info.get("patch") == 4           # only the rings around the scrambled patch moved
    unchanged = np.all(x2 == bad, axis=1)
    assert unchanged.mean() > 0.5            # measured: 68 % of the vertices
    assert np.all(_orientation(x2, f) > 0)
    np.testing.assert_allclose(np.linalg.norm(x2, axis=1), 1.0, atol=1e-12)


def _half_turn(x):
    """``x`` with a cap turned half a turn about its centre."""
    c = x[0]
    cap = x @ c > np.cos(0.5)
    bad = x.copy()
    bad[cap] = 2 * np.outer(x[cap] @ c, c) - x[cap]
    return bad


def test_a_pinned_patch_gives_way_to_a_wider_one():
    """A cap turned half a turn folds only a ring of triangles at its border, and a patch of one
    ring around them, its borders held on both sides, cannot unwind it; the next, wider patch of
    ``patch_rings`` does, and the map's far side stays where it was."""
    p, f, x = _start()
    bad = _half_turn(x)
    assert np.count_nonzero(_orientation(bad, f) <= 0) > 20
    _, narrow = untangle(bad, p, f, patch_rings=(1,))
    assert "patch" not in narrow                            # the whole map had to move
    x2, info = untangle(bad, p, f, patch_rings=(1, 4))
    assert info["patch"] == 4 and info["inverted"] == 0
    assert np.all(_orientation(x2, f) > 0)
    assert np.all(x2 == bad, axis=1).mean() > 0.5


def test_a_patch_still_inverted_after_its_patience_stops_there():
    """The pinned one-ring patch above keeps an inverted triangle through all its rounds; with
    the patience that :func:`untangle` gives a patch, it stops after that many."""
    p, f, x = _start()
    bad = _half_turn(x)
    energy = Energy(p, f)
    energy.lam = 0.5
    free = near_inverted(energy, bad, rings=1)
    options = dict(rounds=2 * PATCH_PATIENCE, inner=30, memory=8, precondition=True,
                   shift=1e-3, eps_max=0.1)
    _, done = untangle_rounds(Patch(energy, bad, free), bad[free], **options)
    assert done == -2 * PATCH_PATIENCE
    _, done = untangle_rounds(Patch(energy, bad, free), bad[free], patience=PATCH_PATIENCE,
                               **options)
    assert done == -PATCH_PATIENCE


def test_untangle_returns_a_fold_free_map_unchanged():
    p, f, x = _start()
    x2, info = untangle(x, p, f)
    assert info["rounds"] == 0 and info["inverted"] == 0 and np.array_equal(x2, x)


def test_untangle_of_folds_everywhere_moves_the_whole_map():
    p, f, x = _start()
    rng = np.random.default_rng(2)
    noisy = x + 0.05 * rng.normal(size=x.shape)
    noisy /= np.linalg.norm(noisy, axis=1)[:, None]
    assert np.count_nonzero(_orientation(noisy, f) <= 0) > 0.05 * len(f)
    x2, info = untangle(noisy, p, f)
    assert "patch" not in info and info["min_det"] > 0
    assert np.all(_orientation(x2, f) > 0)


def test_untangle_never_returns_more_inverted_triangles_than_it_was_given(monkeypatch):
    """On the coarsest level (64 vertices) of a cut and capped torus, the whole-map untangling
    shrinks the Tutte map with its one inverted triangle toward a point (every triangle then
    degenerate): the map as given is returned instead, the coarser levels carry it on, and the
    map needs no second try at another coarsest level (and takes no log of 0/0 on the way)."""
    import warnings

    import surfidx.sphere.tutte as tutte_module
    from conftest import torus_mesh
    from surfidx.sphere import parameterize
    from surfidx.topology import close_surface
    from surfidx.codec.restore import closed_surfels

    calls = []

    def spy(x, p, f, **kw):
        y, info = untangle(x, p, f, **kw)
        calls.append((int(np.count_nonzero(Energy(p, f).dets(x) <= 0)), info["inverted"]))
        return y, info

    monkeypatch.setattr(tutte_module, "untangle", spy)
    s, _ = closed_surfels(close_surface(*torus_mesh(nu=64, nv=24)))
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        figures = parameterize(s, stress=False).figures()
    assert calls == [(1, 1)]                   # the coarsest level's map kept as it was given
    assert figures["retries"] == 0 and figures["base_vertices"] == 64
    assert figures["folded"] == 0
