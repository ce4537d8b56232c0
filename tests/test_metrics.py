"""Distortion measures against an independent brute-force implementation and analytic values."""

import math

import numpy as np
import pytest
from scipy.spatial.distance import cdist

from surfidx import TOL, InputError, SurfelSet, read_surfels
from surfidx.geometry.metrics import Reference, evaluate, hausdorff, psnr_d1, psnr_d2, psnr_luma


# ---------------------------------------------------------------------- independent reference
def brute_force(ref: SurfelSet, test: SurfelSet) -> dict:
    """pc_error's definitions written out with a full distance matrix and explicit loops."""
    peak = math.dist(ref.positions.min(axis=0), ref.positions.max(axis=0))

    def one_way(searched, probed):
        dist = cdist(probed.positions, searched.positions)  # (n_probed, n_searched)
        d1, d2, y, far = [], [], [], 0.0
        for i in range(len(probed)):
            j = int(np.argmin(dist[i]))
            off = probed.positions[i] - searched.positions[j]
            d1.append(sum(c * c for c in off))
            d2.append(float(sum(off[k] * searched.normals[j][k] for k in range(3))) ** 2)
            far = max(far, dist[i, j])
            if probed.has_color and searched.has_color:
                yp = 0.2126 * probed.colors[i, 0] + 0.7152 * probed.colors[i, 1] \
                    + 0.0722 * probed.colors[i, 2]
                ys = 0.2126 * searched.colors[j, 0] + 0.7152 * searched.colors[j, 1] \
                    + 0.0722 * searched.colors[j, 2]
                y.append((float(yp) - float(ys)) ** 2)
        return np.mean(d1), np.mean(d2), (np.mean(y) if y else None), far

    a = one_way(ref, test)
    b = one_way(test, ref)
    mse1, mse2 = max(a[0], b[0]), max(a[1], b[1])
    out = {"psnr_d1": 10 * math.log10(peak ** 2 / mse1),
           "psnr_d2": 10 * math.log10(peak ** 2 / mse2),
           "hausdorff": max(a[3], b[3]) / peak, "peak": peak}
    if a[2] is not None:
        out["psnr_y"] = 10 * math.log10(255 ** 2 / max(a[2], b[2]))
    return out


def random_surfels(n, rng, *, colors=True):
    p = rng.normal(size=(n, 3))
    nrm = rng.normal(size=(n, 3))
    nrm /= np.linalg.norm(nrm, axis=1)[:, None]
    col = rng.integers(0, 256, size=(n, 3)) if colors else None
    return SurfelSet(p, nrm, np.full(n, 0.05), col)


def perturbed(s: SurfelSet, offsets, colors=None) -> SurfelSet:
    return SurfelSet(s.positions + offsets, s.normals, s.radii,
                     s.colors if colors is None else colors)


def sphere_points(n, rng):
    p = rng.normal(size=(n, 3))
    p /= np.linalg.norm(p, axis=1)[:, None]
    return SurfelSet(p, p, np.full(n, 0.05))


# ---------------------------------------------------------------------- agreement
def test_agrees_with_brute_force_on_random_sets():
    rng = np.random.default_rng(1)
    ref = random_surfels(300, rng)
    # a different number of test points, some near the reference, some not
    test = random_surfels(240, rng)
    res = evaluate(ref, test)
    bf = brute_force(ref, test)
    for key in ("psnr_d1", "psnr_d2", "psnr_y"):
        assert abs(res[key] - bf[key]) < TOL.psnr_agreement, key
    assert res["hausdorff"] == pytest.approx(bf["hausdorff"], rel=1e-9)
    assert res["peak"] == pytest.approx(bf["peak"])
    assert res["n_reference"] == 300 and res["n_test"] == 240
    # the one-measure functions give the same numbers as evaluate
    assert psnr_d1(ref, test) == pytest.approx(res["psnr_d1"])
    assert psnr_d2(ref, test) == pytest.approx(res["psnr_d2"])
    assert psnr_luma(ref, test) == pytest.approx(res["psnr_y"])
    assert hausdorff(ref, test) == pytest.approx(res["hausdorff"])
    assert res["rmse_d1"] == pytest.approx(res["peak"] * 10 ** (-res["psnr_d1"] / 20))


def test_agrees_with_brute_force_on_real_model(models):
    rng = np.random.default_rng(7)
    full = read_surfels(models / "bunny_hr.obj")
    ref = full.subset(rng.choice(len(full), 1500, replace=False))
    sigma = 0.002 * ref.diagonal
    test = perturbed(ref, rng.normal(scale=sigma, size=ref.positions.shape))
    test = test.subset(rng.choice(len(test), 1200, replace=False))  # unequal sizes
    res = evaluate(ref, test)
    bf = brute_force(ref, test)
    for key in ("psnr_d1", "psnr_d2"):
        assert abs(res[key] - bf[key]) < TOL.psnr_agreement, key
    assert res["psnr_y"] is None  # bunny_hr has no colour
    assert res["hausdorff"] == pytest.approx(bf["hausdorff"], rel=1e-9)
    assert 40 < res["psnr_d1"] < 80  # a plausible range for 0.2% noise


# ---------------------------------------------------------------------- analytic values
def test_identity_gives_inf_and_zero_hausdorff(sphere_surfels):
    res = evaluate(sphere_surfels, sphere_surfels)
    assert res["psnr_d1"] == math.inf and res["psnr_d2"] == math.inf
    assert res["psnr_y"] == math.inf
    assert res["hausdorff"] == 0.0 and res["rmse_d1"] == 0.0


def test_gaussian_noise_on_sparse_points_matches_theory():
    """Isotropic noise of sigma per axis, sigma far below the point spacing.

    Each noisy point's nearest reference point is then its own original (and vice versa), so the
    D1 error is |e|^2 with e ~ N(0, sigma^2 I3): its mean is 3 sigma^2 (RMS = sqrt(3) sigma), and
    the D2 error is (e . n)^2, mean sigma^2. With 4000 points the sample mean of a chi-square with 3
    degrees of freedom is within ~2% (0.1 dB), well inside the tolerance. (On samples dense
    compared to sigma the nearest neighbour would no longer be the original and D1 would tend to
    the normal component only, sigma^2; that regime is not asserted here.)
    """
    rng = np.random.default_rng(3)
    ref = sphere_points(4000, rng)  # spacing about 0.056 on the unit sphere
    sigma = 5e-4
    test = perturbed(ref, rng.normal(scale=sigma, size=ref.positions.shape))
    res = evaluate(ref, test)
    peak = ref.diagonal
    assert res["psnr_d1"] == pytest.approx(20 * math.log10(peak / (math.sqrt(3) * sigma)),
                                           abs=TOL.psnr_agreement)
    assert res["psnr_d2"] == pytest.approx(20 * math.log10(peak / sigma), abs=TOL.psnr_agreement)
    # doubling the noise costs 20 log10(2) = 6.02 dB
    test2 = perturbed(ref, rng.normal(scale=2 * sigma, size=ref.positions.shape))
    assert psnr_d1(ref, test) - psnr_d1(ref, test2) == pytest.approx(20 * math.log10(2),
                                                                     abs=TOL.psnr_agreement)


def test_gaussian_noise_on_dense_points_sees_only_the_normal_component():
    """The opposite regime: noise sigma far above the point spacing.

    A noisy point's nearest reference point is then (nearly) the foot of its perpendicular on the
    surface, so only the normal component of the noise counts: D1 MSE -> sigma^2 (not 3 sigma^2),
    plus the mean squared distance from a surface point to the nearest sample, 1 / (pi * density)
    = 4 / n on the unit sphere (4% of sigma^2 here, 0.2 dB). The other direction (a reference
    point searching the noisy layer) finds a nearer point, so the maximum is this one. Both PSNRs
    sit ~4.8 dB above the sparse regime's D1 value, which the test also rules out.
    """
    rng = np.random.default_rng(8)
    ref = sphere_points(50_000, rng)  # spacing about 0.016
    sigma = 0.04
    test = perturbed(ref, rng.normal(scale=sigma, size=ref.positions.shape))
    res = evaluate(ref, test)
    dense = 20 * math.log10(ref.diagonal / sigma)
    assert res["psnr_d1"] == pytest.approx(dense, abs=TOL.psnr_agreement)
    assert res["psnr_d2"] == pytest.approx(dense, abs=TOL.psnr_agreement)
    assert res["psnr_d1"] - 20 * math.log10(ref.diagonal / (math.sqrt(3) * sigma)) > 4.0


def test_tangential_noise_costs_little_in_d2():
    """Noise in the tangent plane of a sphere: D2 only sees the curvature's second-order term."""
    rng = np.random.default_rng(4)
    ref = sphere_points(3000, rng)
    e = rng.normal(scale=2e-3, size=ref.positions.shape)
    e -= np.einsum("ij,ij->i", e, ref.normals)[:, None] * ref.normals  # tangential
    test = perturbed(ref, e)
    res = evaluate(ref, test)
    assert res["psnr_d2"] >= res["psnr_d1"]
    assert res["psnr_d2"] - res["psnr_d1"] > 30  # D2 error ~ (|e|^2 / 2)^2, far below |e|^2
    # and for normal noise both agree (the offset lies along the normal)
    test_n = perturbed(ref, 2e-3 * rng.normal(size=(len(ref), 1)) * ref.normals)
    res_n = evaluate(ref, test_n)
    assert res_n["psnr_d2"] == pytest.approx(res_n["psnr_d1"], abs=0.05)


def test_d2_never_worse_than_d1():
    rng = np.random.default_rng(5)
    for _ in range(5):
        ref = random_surfels(200, rng, colors=False)
        test = perturbed(ref, rng.normal(scale=0.05, size=(200, 3)))
        assert psnr_d2(ref, test) >= psnr_d1(ref, test)


def test_luma_constant_shift_is_analytic(sphere_surfels):
    """Adding delta to R, G and B adds delta to Y (the weights sum to 1).

    Hence PSNR_Y = 20 log10(255 / delta) exactly.
    """
    c = sphere_surfels.colors.astype(int)
    keep = np.all(c <= 249, axis=1)
    ref = sphere_surfels.subset(keep)
    test = perturbed(ref, 0.0, colors=ref.colors.astype(int) + 6)
    assert psnr_luma(ref, test) == pytest.approx(20 * math.log10(255 / 6), abs=1e-9)
    res = evaluate(ref, test)
    assert res["psnr_d1"] == math.inf and res["psnr_y"] == pytest.approx(20 * math.log10(255 / 6))


def test_hausdorff_of_one_outlier(sphere_surfels):
    s = sphere_surfels
    pos = s.positions.copy()
    pos[10] = pos[10] * 1.5  # 0.5 away from its original; nearest other point is farther
    test = SurfelSet(pos, s.normals, s.radii, s.colors)
    expected = np.min(np.linalg.norm(s.positions - pos[10], axis=1)) / s.diagonal
    assert hausdorff(s, test) == pytest.approx(expected)
    assert hausdorff(s, test, peak=1.0) == pytest.approx(expected * s.diagonal)


def test_evaluate_without_colour_reports_none(sphere_surfels):
    res = evaluate(sphere_surfels, sphere_surfels.without_color())
    assert res["psnr_y"] is None
    assert set(res) == {"psnr_d1", "psnr_d2", "psnr_y", "hausdorff", "rmse_d1", "rmse_d2",
                        "peak", "n_reference", "n_test"}


def test_explicit_peak_shifts_psnr(sphere_surfels):
    rng = np.random.default_rng(0)
    test = perturbed(sphere_surfels, rng.normal(scale=1e-3, size=sphere_surfels.positions.shape))
    base = psnr_d1(sphere_surfels, test)
    ten = psnr_d1(sphere_surfels, test, peak=10 * sphere_surfels.diagonal)
    assert ten == pytest.approx(base + 20)  # 10x the peak: +20 dB


def test_a_reference_measures_as_psnr_d2_does():
    """A reference searched for many test sets gives psnr_d2's numbers exactly, and its
    ``psnr_d2_at_least`` the same answer as comparing them, whichever direction fails: a
    sparse test set fails where the reference is searched for it, a test set with one far
    outlier where its points are probed."""
    rng = np.random.default_rng(3)
    ref = random_surfels(400, rng)
    reference = Reference(ref)
    sparse = ref.subset(rng.choice(400, 40, replace=False))
    noisy = perturbed(ref, rng.normal(scale=0.01, size=(400, 3)))
    outlier = SurfelSet(np.vstack([ref.positions, [[50.0, 0, 0]]]),
                        np.vstack([ref.normals, [[1.0, 0, 0]]]), np.full(401, 0.05))
    for test in (sparse, noisy, outlier, ref):
        value = psnr_d2(ref, test)
        assert reference.psnr_d2(test) == value
        for floor in (value - 1e-9, value, value + 1e-9, -math.inf, math.inf):
            assert reference.psnr_d2_at_least(test, floor) is (value >= floor)
    assert reference.psnr_d2(ref) == math.inf
    assert Reference(ref, peak=10 * ref.diagonal).psnr_d2(noisy) == pytest.approx(
        psnr_d2(ref, noisy) + 20)


def test_a_reference_probes_large_sets_in_blocks_with_the_same_answers():
    """A test set of more points than one query block (its errors far off in the last block,
    or everywhere) gives psnr_d2's numbers to the bit, and ``psnr_d2_at_least`` the comparison's
    answer for floors just around the value, far above it (where the blocks stop early),
    far below it and beyond float range."""
    block = 1 << 17                               # the points of one query block

    rng = np.random.default_rng(5)
    ref = sphere_points(2000, rng)
    n = block + 5000
    dense = sphere_points(n, rng)
    far_tail = SurfelSet(dense.positions * np.where(np.arange(n) >= block, 1.3, 1.0)[:, None],
                         dense.normals, dense.radii)
    for test in (dense, far_tail):
        reference = Reference(ref)
        value = psnr_d2(ref, test)
        assert reference.psnr_d2(test) == value
        for floor in (value - 1e-9, value, value + 1e-9, value + 10.0, value + 60.0,
                      value - 60.0, 1e4, -1e4, math.inf, -math.inf):
            assert reference.psnr_d2_at_least(test, floor) is (value >= floor)


def test_a_sampled_psnr_d2_estimates_it_from_a_seeded_sample():
    """Sets no larger than the sample measure as psnr_d2 does (to rounding); larger ones near
    it, the same for the same seed, and the sample size is checked."""
    rng = np.random.default_rng(7)
    ref = sphere_points(3000, rng)
    test = perturbed(sphere_points(5000, rng), rng.normal(scale=0.002, size=(5000, 3)))
    reference = Reference(ref)
    assert reference.psnr_d2_sampled(test, 5000) == pytest.approx(psnr_d2(ref, test), abs=1e-9)
    value = reference.psnr_d2_sampled(test, 1000)
    assert value == pytest.approx(psnr_d2(ref, test), abs=0.5)
    assert Reference(ref).psnr_d2_sampled(test, 1000) == value
    assert reference.psnr_d2_sampled(test, 1000, seed=1) != value
    with pytest.raises(InputError, match="samples must be at least 1, got 0"):
        reference.psnr_d2_sampled(test, 0)
    with pytest.raises(InputError, match="test surfel set is empty"):
        reference.psnr_d2_sampled(test.subset(np.zeros(0, int)), 10)


def test_a_sampled_psnr_d2_of_arrays_is_that_of_their_surfels():
    """psnr_d2_sampled_points gives the SurfelSet's figure to the bit, and checks its arrays."""
    rng = np.random.default_rng(8)
    ref = sphere_points(3000, rng)
    test = perturbed(sphere_points(5000, rng), rng.normal(scale=0.002, size=(5000, 3)))
    reference = Reference(ref)
    for samples in (1000, 5000):
        assert reference.psnr_d2_sampled_points(test.positions, test.normals, samples) == \
            reference.psnr_d2_sampled(test, samples)
    with pytest.raises(InputError, match=r"normals must have shape \(5000, 3\)"):
        reference.psnr_d2_sampled_points(test.positions, test.normals[:10], 100)
    with pytest.raises(InputError, match="test set is empty"):
        reference.psnr_d2_sampled_points(np.zeros((0, 3)), np.zeros((0, 3)), 100)
    with pytest.raises(InputError, match="samples must be at least 1, got 0"):
        reference.psnr_d2_sampled_points(test.positions, test.normals, 0)


def test_a_reference_checks_its_sets(sphere_surfels):
    empty = SurfelSet(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0))
    with pytest.raises(InputError, match="reference surfel set is empty"):
        Reference(empty)
    with pytest.raises(InputError, match="test must be a SurfelSet, got ndarray"):
        Reference(sphere_surfels).psnr_d2(np.zeros((3, 3)))
    with pytest.raises(InputError, match="test surfel set is empty"):
        Reference(sphere_surfels).psnr_d2_at_least(empty, 50.0)
    with pytest.raises(InputError, match="diagonal is zero"):
        Reference(sphere_surfels.subset([0]))


# ---------------------------------------------------------------------- errors
def test_empty_set_is_rejected(sphere_surfels):
    empty = SurfelSet(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0))
    with pytest.raises(InputError, match="test surfel set is empty"):
        evaluate(sphere_surfels, empty)
    with pytest.raises(InputError, match="reference surfel set is empty"):
        psnr_d1(empty, sphere_surfels)


def test_luma_needs_colours_on_both(sphere_surfels):
    with pytest.raises(InputError, match="test set has none"):
        psnr_luma(sphere_surfels, sphere_surfels.without_color())
    bare = sphere_surfels.without_color()
    with pytest.raises(InputError, match="reference and test sets have none"):
        psnr_luma(bare, bare)


def test_not_a_surfel_set():
    with pytest.raises(InputError, match="reference must be a SurfelSet"):
        psnr_d2(np.zeros((3, 3)), np.zeros((3, 3)))


def test_degenerate_reference_needs_a_peak(sphere_surfels):
    one = sphere_surfels.subset([0])
    with pytest.raises(InputError, match="diagonal is zero"):
        psnr_d1(one, sphere_surfels)
    assert math.isfinite(psnr_d1(one, sphere_surfels, peak=1.0))
    with pytest.raises(InputError, match="peak must be a positive number"):
        psnr_d1(sphere_surfels, sphere_surfels, peak=-1.0)
    with pytest.raises(InputError, match="peak contains 1 NaN"):
        hausdorff(sphere_surfels, sphere_surfels, peak=float("nan"))


# ---------------------------------------------------------------------- luma on the surface
def checker_sphere(offset=0, squares=8, size=64):
    """A unit icosphere textured with a sharp checkerboard (lumas 30 and 220, plus ``offset``)
    through a planar projection."""
    from conftest import icosphere_mesh
    from surfidx import TriangleMesh

    v, f = icosphere_mesh(3)
    yy, xx = np.mgrid[:size, :size] * squares // size
    grey = np.where((xx + yy) % 2 == 0, 30, 220) + offset
    texture = np.repeat(grey[:, :, None], 3, axis=2).astype(np.uint8)
    uv = 0.5 * (v[:, :2] + 1.0)
    return TriangleMesh(v, f, uv=uv, uv_faces=f, texture=texture)


def test_surface_luma_has_no_sampling_floor_where_nearest_neighbours_have_one():
    from surfidx.geometry.metrics import psnr_luma_surface

    m = checker_sphere()
    # two samplings of one sharp-edged texture: nearest neighbours straddle the edges
    floor = psnr_luma(m.to_surfels(samples=20_000, seed=0), m.to_surfels(samples=20_000, seed=5))
    assert floor < 35.0
    assert psnr_luma_surface(m, m, samples=20_000) > 100.0
    assert psnr_luma_surface(m, m, samples=20_000, seed=7) > 100.0


def test_surface_luma_of_a_constant_shift_is_analytic():
    from surfidx.geometry.metrics import psnr_luma_surface

    got = psnr_luma_surface(checker_sphere(), checker_sphere(offset=10), samples=5_000)
    assert got == pytest.approx(20 * math.log10(255 / 10), abs=1e-6)


def test_surface_luma_compares_vertex_colours_with_a_texture():
    from surfidx import TriangleMesh
    from surfidx.geometry.metrics import psnr_luma_surface

    m = checker_sphere(squares=1)   # one square: luma 30 everywhere
    flat = TriangleMesh(m.vertices, m.faces, vertex_colors=np.full((len(m.vertices), 3), 55))
    assert psnr_luma_surface(m, flat, samples=5_000) == pytest.approx(
        20 * math.log10(255 / 25), abs=1e-6)
    assert psnr_luma_surface(flat, m, samples=5_000) == pytest.approx(
        20 * math.log10(255 / 25), abs=1e-6)


def test_surface_luma_checks_its_meshes():
    from surfidx import TriangleMesh
    from surfidx.geometry.metrics import psnr_luma_surface

    m = checker_sphere()
    bare = TriangleMesh(m.vertices, m.faces)
    with pytest.raises(InputError, match="must be a TriangleMesh"):
        psnr_luma_surface(m.to_surfels(samples=100), m)
    with pytest.raises(InputError, match="the test mesh has no colour"):
        psnr_luma_surface(m, bare)
    with pytest.raises(InputError, match="the reference mesh has no surface"):
        psnr_luma_surface(TriangleMesh(m.vertices, m.faces[:0]), m)
    with pytest.raises(InputError, match="samples must be at least 1"):
        psnr_luma_surface(m, m, samples=0)
    with pytest.raises(InputError, match=r"face indices must lie in 0\.\.1279"):
        m.colors_at([1280], [[1.0, 0.0, 0.0]])
    with pytest.raises(InputError, match="the mesh has no colour"):
        bare.colors_at([0], [[1.0, 0.0, 0.0]])
