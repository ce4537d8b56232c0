"""Vertex-by-vertex relaxation of the balancing energy: lowers it, keeps the embedding, and
opens up squeezed stars faster than the global steps alone."""

import numpy as np

from surfidx.geometry.unitsphere import orientation
from surfidx.sphere import MapOptions
from surfidx.sphere.balance import Energy, balance
from surfidx.sphere.relax import Relaxation
from surfidx.sphere.surface import oriented_faces
from surfidx.sphere.tutte import tutte_map
from helpers import limbs_surfels


def _start():
    s = limbs_surfels()
    f = oriented_faces(s)
    x, _ = tutte_map(s, options=MapOptions(), iterations=0, gamma=0.15, balance=False)
    energy = Energy(s.positions, f, max_cot=np.inf)
    energy.eps, energy.lam = 0.0, 0.5
    return s.positions, f, x, energy


def test_sweeps_lower_the_energy_and_keep_every_triangle_counter_clockwise():
    _, f, x, energy = _start()
    relax = Relaxation(f, energy.cot, energy.area3, energy.radius, energy.lam, len(x))
    e = [energy(x, grad=False)[0]]
    y = x
    for _ in range(3):
        y, moves = relax(y, 2)
        assert moves > 0 and np.all(orientation(y, f) > 0)
        e.append(energy(y, grad=False)[0])
    assert all(b < a for a, b in zip(e, e[1:]))
    np.testing.assert_allclose(np.linalg.norm(y, axis=1), 1.0, atol=1e-12)


def test_a_squeezed_vertex_is_moved_out_of_its_corner():
    """A vertex pushed almost onto a neighbour (its star nearly degenerate) is moved back: each
    sweep's first try doubles the last accepted move, so a few sweeps grow the smallest area
    ratio of its star by orders of magnitude."""
    _, f, x, energy = _start()
    x = x.copy()
    v = int(f[0, 0])
    w = int(f[0, 1])
    x[v] = x[w] + 1e-4 * (x[v] - x[w])
    x[v] /= np.linalg.norm(x[v])
    star = np.flatnonzero((f == v).any(axis=1))
    before = energy.dets(x)[star].min()
    assert before > 0
    y, _ = Relaxation(f, energy.cot, energy.area3, energy.radius, energy.lam, len(x))(x, 20)
    assert energy.dets(y)[star].min() > 100 * before
    assert np.all(orientation(y, f) > 0)


def test_balance_with_sweeps_reaches_a_lower_energy_in_the_same_steps():
    p, f, x, _ = _start()
    _, plain = balance(x, p, f, iterations=30, lam=0.5, max_cot=np.inf)
    y, swept = balance(x, p, f, iterations=30, sweeps=5, rounds=2, lam=0.5, max_cot=np.inf)
    assert swept["moves"] > 0 and plain["moves"] == 0
    assert swept["energy"] < plain["energy"]
    assert np.all(orientation(y, f) > 0)


def test_sweeps_are_deterministic():
    _, f, x, energy = _start()
    a, _ = Relaxation(f, energy.cot, energy.area3, energy.radius, energy.lam, len(x))(x, 3)
    b, _ = Relaxation(f, energy.cot, energy.area3, energy.radius, energy.lam, len(x))(x, 3)
    assert np.array_equal(a, b)


def test_sweeps_stop_after_one_that_gains_less_than_the_tolerance():
    """With ``tol``, the sweeps stop after the first whose fall of the energy is below that
    fraction of it: fewer sweeps than asked, each a prefix of the untolerant run's."""
    _, f, x, energy = _start()
    full = Relaxation(f, energy.cot, energy.area3, energy.radius, energy.lam, len(x))
    a, _ = full(x, 40)
    assert full.passes == 40
    short = Relaxation(f, energy.cot, energy.area3, energy.radius, energy.lam, len(x))
    b, moves = short(x, 40, tol=1e-2)
    assert moves > 0 and 1 <= short.passes < 40
    again = Relaxation(f, energy.cot, energy.area3, energy.radius, energy.lam, len(x))
    c, _ = again(x, short.passes)
    assert np.array_equal(b, c)         # the same sweeps, stopped by a count of them
    e = energy(b, grad=False)[0]
    assert energy(a, grad=False)[0] <= e < energy(x, grad=False)[0]
    assert np.all(orientation(b, f) > 0)
