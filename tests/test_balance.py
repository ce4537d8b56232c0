"""Balancing of spherical embeddings: exact gradients, monotone, never leaving an embedding."""

import numpy as np
import pytest

from surfidx.sphere import MapOptions
from surfidx.sphere.balance import Energy, balance, inverted, segment_embedded
from surfidx.sphere.surface import oriented_faces
from surfidx.sphere.tutte import tutte_map
from surfidx.geometry.unitsphere import orientation as _orientation
from helpers import limbs_surfels


def _start():
    s = limbs_surfels()
    f = oriented_faces(s)
    x, _ = tutte_map(s, options=MapOptions(), iterations=0, gamma=0.15, balance=False)
    return s.positions, f, x


@pytest.mark.parametrize("eps, lam", [(-1.0, 1.0), (0.0, 1.0), (0.0, 0.3)],
                         ids=["symmetric-dirichlet", "conformal-area", "conformal-area-0.3"])
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


def test_segment_check_sees_a_triangle_that_turns_over_and_back():
    """Two corners moved so that the triangle turns over and back within one step: both ends
    are counter-clockwise, the middle is not, and the check refuses the step; a short step
    that stays on the near side passes."""
    y = np.array([[1.0, 0.0, 1.0], [0.0, 1.0, 1.0], [-1.0, -1.0, 1.0]])
    f = np.array([[0, 1, 2]])
    d = np.array([[-3.0, -4.0, -4.0], [-1.0, -4.0, -4.0], [0.0, 0.0, 0.0]])
    assert inverted(y, f) == 0 == inverted(y + d, f) and inverted(y + 0.5 * d, f) == 1
    assert not segment_embedded(y, d, f, 1.0)
    assert segment_embedded(y, d, f, 0.2)
    assert not segment_embedded(y + 0.5 * d, d, f, 0.1)     # an inverted start


def test_balance_keeps_every_iterate_embedded(monkeypatch):
    """Every step the line search takes is a segment along which no triangle degenerates."""
    import surfidx.sphere.balance as B

    p, f, x = _start()
    taken = []
    real = B.segment_embedded

    def watch(y, d, faces, step):
        ok = real(y, d, faces, step)
        if ok:
            taken.append(all(inverted(y + s * d, faces) == 0 for s in np.linspace(0, step, 5)))
        return ok

    monkeypatch.setattr(B, "segment_embedded", watch)
    balance(x, p, f, iterations=40)
    assert taken and all(taken)


@pytest.mark.parametrize("eps", [-1.0, 0.0], ids=["symmetric-dirichlet", "conformal-area"])
def test_energy_bound_and_reuse_give_the_same_numbers(eps):
    """The blocked energy equals a plain sum of its triangle terms; with a ``bound`` below it,
    a trial stops with some value above the bound; at or above it, the energy itself; and
    ``again`` (the same point) gives the same energy and gradient bit for bit."""
    p, f, x = _start()
    energy = Energy(p, f)
    energy.eps, energy.lam = eps, 0.5
    e, g = energy(x)
    assert len(f) > 256          # more than one block of triangles
    q = x * energy.radius
    a, b, c = q[f[:, 0]], q[f[:, 1]], q[f[:, 2]]
    s = a + b + c
    ar = 0.5 * np.einsum("ij,ij->i", np.cross(b - a, c - a), s) / np.linalg.norm(s, axis=1)
    ct = energy.cot
    d = 0.5 * (ct[:, 0] * ((c - b) ** 2).sum(1) + ct[:, 1] * ((a - c) ** 2).sum(1)
               + ct[:, 2] * ((b - a) ** 2).sum(1))
    if eps < 0:
        terms = d * (1 + (energy.area3 / ar) ** 2)
    else:
        det = ar / energy.area3
        terms = (d + 0.5 * energy.area3 * (det ** 2 + 1)) / det
    assert e == pytest.approx(terms.sum(), rel=1e-12)
    below, _ = energy(x, grad=False, bound=0.5 * e)
    assert below > 0.5 * e
    assert energy(x, grad=False, bound=e)[0] == e
    assert energy(x, grad=False)[0] == e
    e2, g2 = energy(x, again=True)
    assert e2 == e and np.array_equal(g2, g)
