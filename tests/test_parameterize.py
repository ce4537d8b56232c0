"""Spherical parameterization: no folds, canonical up to rotation, clear topology errors."""

import dataclasses

import numpy as np
import pytest

from surfidx import InputError, SurfelSet, TopologyError, TriangleMesh, read_surfels
from surfidx.geometry.unitsphere import hull_triangles
from surfidx.sphere import (METHODS, MapOptions, SphericalMap, area_distortion, count_folds,
                            parameterize, sparse_sampling)

from conftest import icosphere_mesh, tube_mesh
from helpers import limbs_surfels


def _rotation(seed=3):
    q, _ = np.linalg.qr(np.random.default_rng(seed).normal(size=(3, 3)))
    return q * np.sign(np.linalg.det(q))


def test_sphere_maps_without_folds(sphere_surfels):
    m = parameterize(sphere_surfels)
    assert isinstance(m, SphericalMap) and m.method == "tutte" == METHODS[0]
    assert m.points.shape == (642, 3)
    np.testing.assert_allclose(np.linalg.norm(m.points, axis=1), 1.0, atol=1e-12)
    assert m.folded == 0 and m.triangles == 2 * 642 - 4
    assert count_folds(sphere_surfels, m.points) == (0, 1280)
    assert m.area_distortion < 0.5
    assert np.isfinite(m.landmark_stress)


def test_identity_map_of_sphere_is_fold_free_and_area_exact(sphere_surfels):
    p = sphere_surfels.positions
    assert count_folds(sphere_surfels, p) == (0, 1280)
    assert area_distortion(sphere_surfels, p) < 0.01  # chord vs spherical areas only
    # a mirror is not a fold
    assert count_folds(sphere_surfels, p * [1, 1, -1])[0] == 0


def test_sparse_sampling_of_even_and_squeezed_maps(sphere_surfels):
    """The identity map of an icosphere spreads the surfels evenly (about 1); squeezing a cap
    of the sphere into a tenth of its area gives the surfels there a tenth of the grid."""
    p = sphere_surfels.positions
    even = sparse_sampling(sphere_surfels, p)
    assert 0.7 < even <= 1.0
    z = p[:, 2]
    squeezed = p.copy()
    cap = z > 0.5
    theta = np.arccos(np.clip(z[cap], -1, 1))          # polar angle < 60 degrees
    scale = np.sin(0.1 * theta) / np.maximum(np.sin(theta), 1e-12)
    squeezed[cap, :2] *= scale[:, None]
    squeezed[cap, 2] = np.cos(0.1 * theta)
    low = sparse_sampling(sphere_surfels, squeezed)
    assert low < 0.05 * even
    m = parameterize(sphere_surfels, stress=False)
    assert m.sparse_sampling == pytest.approx(sparse_sampling(sphere_surfels, m.points))
    with pytest.raises(InputError, match="quantile must lie in"):
        sparse_sampling(sphere_surfels, p, quantile=1.5)


def test_count_folds_detects_a_fold(sphere_surfels):
    p = sphere_surfels.positions.copy()
    i, j = 100, int(np.argsort(np.linalg.norm(p - p[100], axis=1))[1])
    p[[i, j]] = p[[j, i]]
    assert count_folds(sphere_surfels, p)[0] > 0


def test_limbs_no_mesh_folds():
    s = limbs_surfels()
    m = parameterize(s, stress=False)
    assert m.info["mesh_folds"] == 0
    assert m.fold_fraction < 0.01


def test_area_balancing_grows_limbs():
    s = limbs_surfels()
    plain = parameterize(s, stress=False, iterations=0, balance=False)
    m = parameterize(s, stress=False)
    assert m.info["balance_steps"] >= 1 and m.info["mesh_folds"] == 0
    assert m.area_distortion < 0.5 * plain.area_distortion


def test_tube_that_tutte_squeezes_below_the_floor_is_embedded():
    """A tube 80 girths long: a single-level Tutte map squeezes its far end below the
    floating-point floor (triangles turned over whatever the lift); the multilevel map starts
    from a tetrahedron, has no such level, and embeds it."""
    from surfidx.sphere.tutte import tutte_map

    s = TriangleMesh(*tube_mesh(m=100), name="tube").to_surfels()
    _, start = tutte_map(s, balance=False, options=MapOptions(), iterations=0, gamma=1.0)
    assert start["mesh_folds"] > 0
    m = parameterize(s, stress=False, options=MapOptions(final_steps=100))
    assert m.info["mesh_folds"] == 0 == m.folded and m.info["base_vertices"] <= 8


def test_small_tutte_start_is_lifted_embedded():
    """The coarsest levels' Tutte map: the lift of the scaled plane keeps every triangle of a
    small mesh counter-clockwise, also for the tetrahedron, whose unscaled lift puts one
    triangle on a great circle."""
    from surfidx.sphere.decimate import decimate
    from surfidx.sphere.tutte import tutte_map

    for size in (4, 12, 40):
        v, f = icosphere_mesh(2)
        h = decimate(v, f, size, shape=False)
        index = np.full(len(v), -1)
        index[h.vertices] = np.arange(len(h.vertices))
        s = TriangleMesh(v[h.vertices], index[h.faces]).to_surfels()
        _, info = tutte_map(s, balance=False, options=MapOptions(), iterations=0, gamma=1.0)
        assert info["mesh_folds"] == 0


def test_centring_takes_newton_steps():
    """The Möbius normalisation of a map pushed far off centre (uneven weights too) puts the
    weighted centre of mass at the origin within a few Newton steps, inverting no triangle."""
    from surfidx.sphere.tutte import centre
    from surfidx.geometry.unitsphere import mobius, orientation

    v, f = icosphere_mesh(3)
    rng = np.random.default_rng(4)
    weights = rng.uniform(0.5, 2.0, len(v))
    x = mobius(v, np.array([0.3, -0.2, 0.25]))
    w = weights / weights.sum()
    assert np.linalg.norm(w @ x) > 0.3
    y = centre(x, weights, f, iterations=8)
    assert np.linalg.norm(w @ y) < 1e-10
    assert np.all(orientation(y, f) > 0)


def test_mobius_normalised(sphere_surfels):
    # area-weighted centre of mass of the vertices at the origin (canonical up to a rotation)
    s = sphere_surfels.transformed(translation=[0.3, 0.0, 0.0])
    m = parameterize(s, stress=False, iterations=0)
    from surfidx.sphere.surface import areas3, oriented_faces

    f = oriented_faces(s)
    va = np.bincount(f.ravel(), np.repeat(areas3(s.positions, f), 3), minlength=len(s))
    assert np.linalg.norm(va @ m.points / va.sum()) < 1e-6


def test_rotation_invariance(sphere_surfels):
    s = limbs_surfels()
    rot = _rotation()
    a = parameterize(s, stress=False)
    b = parameterize(s.transformed(rotation=rot, translation=[1.0, -2.0, 3.0], scale=2.5),
                     stress=False)
    # canonical up to a rotation of the sphere: decimation, energies and normalisation are
    # intrinsic, so round-off may turn the two results against each other, and an iterative
    # level may stop a few steps apart (measured: 1.2e-3), but nothing else
    u, _, vt = np.linalg.svd(b.points.T @ a.points)
    np.testing.assert_allclose(a.points @ (u @ vt).T, b.points, atol=5e-3)
    assert a.folded == b.folded
    assert a.area_distortion == pytest.approx(b.area_distortion, rel=1e-3)


def test_mds_method_available(sphere_surfels):
    m = parameterize(sphere_surfels, method="mds", landmarks=16, iterations=5)
    assert m.method == "mds" and m.points.shape == (642, 3)
    assert m.landmark_stress < 0.5


def test_hull_triangles_are_ccw(sphere_surfels):
    p = sphere_surfels.positions
    t = hull_triangles(p)
    a, b, c = p[t[:, 0]], p[t[:, 1]], p[t[:, 2]]
    assert np.all(np.einsum("ij,ij->i", np.cross(b - a, c - a), a) > 0)


def test_hull_of_points_on_one_great_circle_raises():
    t = np.linspace(0, 2 * np.pi, 12, endpoint=False)
    with pytest.raises(InputError, match="the sphere points span no volume"):
        hull_triangles(np.c_[np.cos(t), np.sin(t), np.zeros_like(t)])


def test_disconnected_raises(sphere_surfels):
    v, f = icosphere_mesh(2)
    two = TriangleMesh(np.vstack([v, v + 5]), np.vstack([f, f + len(v)])).to_surfels()
    with pytest.raises(TopologyError, match="2 separate pieces"):
        parameterize(two)
    with pytest.raises(TopologyError, match="separate pieces"):
        parameterize(two.subset(np.arange(len(two))), method="mds", landmarks=8)


def test_open_surface_raises():
    v, f = icosphere_mesh(2)
    s = TriangleMesh(v, f[:-3]).to_surfels()
    with pytest.raises(TopologyError, match="not closed"):
        parameterize(s)


def test_bad_arguments(sphere_surfels):
    with pytest.raises(InputError, match="method must be one of"):
        parameterize(sphere_surfels, method="conformal-ish")
    with pytest.raises(InputError, match="too few surfels"):
        parameterize(sphere_surfels.subset(np.arange(5)))
    with pytest.raises(InputError, match="gamma"):
        parameterize(sphere_surfels, gamma=5)
    with pytest.raises(InputError, match="SurfelSet"):
        parameterize(np.zeros((10, 3)))
    with pytest.raises(InputError, match="unit vectors"):
        count_folds(sphere_surfels, 2 * sphere_surfels.positions)


def test_genus_one_raises(models):
    with pytest.raises(TopologyError, match="genus 1"):
        parameterize(read_surfels(models / "rocker-arm.obj"))


def test_genus_three_raises(models):
    s = read_surfels(models / "ycb_scissors" / "textured_simple_reoriented.obj")
    with pytest.raises(TopologyError, match="genus 3"):
        parameterize(s)


def test_pinched_vertex_raises(models):
    with pytest.raises(TopologyError, match="pinched"):
        parameterize(read_surfels(models / "cow.obj"))


@pytest.mark.parametrize("name", ["spot/spot_triangulated.obj", "homer.obj"])
def test_real_models_no_mesh_folds(models, name):
    s = read_surfels(models / name)
    m = parameterize(s, stress=False)
    assert m.info["mesh_folds"] == 0 == m.folded   # the mesh embedding is bijective
    assert count_folds(s, m.points)[0] < 0.01 * len(s)   # Delaunay swaps where anisotropic
    # the balanced multilevel map leaves less area distortion than the harmonic start
    plain = parameterize(s, stress=False, iterations=0, balance=False)
    assert m.area_distortion < plain.area_distortion


@pytest.fixture(scope="module")
def horse(models):
    """Horse's surfels and their map, made once for the tests below."""
    s = read_surfels(models / "horse.ply")
    return s, parameterize(s, stress=False)


@pytest.mark.slow
def test_horse_full_size(horse):
    """Legs and head keep their share of the sphere: the grid resampling leaves no holes."""
    from surfidx.geometry.icosphere import choose_level
    from surfidx.codec.resample import grid_to_surfels, resample
    from scipy.spatial import cKDTree

    s, m = horse
    assert m.stage("multilevel").figures["mesh_folds"] == 0 == m.folded
    assert m.info["levels"] >= 4
    assert m.area_distortion < 1.2         # measured 0.90 (single-level Tutte: 6.6)
    g = grid_to_surfels(resample(s, m.points, choose_level(len(s))))
    spacing = cKDTree(s.positions).query(s.positions, k=2)[0][:, 1].mean()
    d, _ = cKDTree(g.positions).query(s.positions)
    assert np.mean(d > 2 * spacing) < 0.005   # holes: measured 0.01 % (single-level: 30 %)


def test_multilevel_map_has_levels_down_to_a_small_base():
    s = limbs_surfels(4)
    m = parameterize(s, stress=False)
    assert [st.name for st in m.stages] == ["multilevel"]
    levels = m.stage("multilevel").figures
    assert levels["levels"] >= 3 and levels["base_vertices"] <= 8
    assert levels["mesh_folds"] == 0


def test_finest_level_stops_on_its_step_count():
    """The finest level's balancing ends after ``final_steps`` steps, a count: the same map on
    every run."""
    s = limbs_surfels(4)
    options = MapOptions(final_steps=4)
    m = parameterize(s, stress=False, options=options)
    assert m.info["balance_steps"] == 4
    m2 = parameterize(s, stress=False, options=options)
    assert np.array_equal(m.points, m2.points)


def test_single_level_steps_bound_steps_times_vertices():
    """The single-level balancing's step count falls with the vertex count, so its cost is
    bounded at any size."""
    from surfidx.sphere.tutte import single_level_steps

    o = MapOptions()
    assert single_level_steps(64, o) == o.single_level_max_steps == 3000
    assert single_level_steps(50_000, o) * 50_000 <= o.single_level_work
    assert single_level_steps(10 ** 7, o) == o.single_level_min_steps == 300


def test_unbalanced_levels_stay_embedded():
    """Without balancing, every level is still an embedding: removed vertices whose mean
    would fold go into their ring's kernel."""
    m = parameterize(limbs_surfels(4), stress=False, balance=False)
    assert m.info["levels"] >= 3 and m.info["balance_steps"] == 0
    assert m.info["mesh_folds"] == 0 == m.folded and m.info["kernel_insertions"] > 0


def test_level_with_a_squeezed_start_is_prolonged_round_by_round():
    """A level whose prolonged start has a balancing energy above ``settle_energy`` is
    prolonged again with each round's mesh balanced; the map stays an embedding."""
    s = limbs_surfels(4)
    plain = parameterize(s, stress=False)
    m = parameterize(s, stress=False, options=MapOptions(settle_energy=0.0))
    assert plain.info["settled_levels"] == 0
    assert m.info["settled_levels"] == m.info["levels"] - 1
    assert m.folded == 0 and m.info["mesh_folds"] == 0


@pytest.mark.parametrize("name", ["d024", "d062", "d041", "d043", "d037", "d012", "d055"])
def test_shapes_that_folded_are_embedded(shared_data, name):
    """Glasses, chairs, an octopus and tables of the retrieval collection (their maps kept
    folds, or turned input triangles over, before the map embedded every level): every input
    triangle is counter-clockwise on the sphere, counted afresh from the points."""
    from surfidx.geometry.unitsphere import orientation
    from surfidx.io import read_geometry
    from surfidx.topology import repair_model

    s = repair_model(read_geometry(shared_data / "retrieval" / "meshes" / f"{name}.off")).parts[0]
    m = parameterize(s, stress=False)
    f = s.faces[(s.faces[:, 0] != s.faces[:, 1]) & (s.faces[:, 1] != s.faces[:, 2])
                & (s.faces[:, 0] != s.faces[:, 2])]
    o = orientation(m.points, f)
    assert min(np.count_nonzero(o <= 0), np.count_nonzero(o >= 0)) == 0 == m.folded
    # the map covers the sphere once, so the codec interpolates in the mesh's own faces
    from surfidx.codec.resample import map_triangles
    assert len(map_triangles(s, m.points)) == len(f)


def test_point_cloud_mapped_through_proxy_mesh():
    """Surfels without faces (a point cloud) get the Tutte map through a closed proxy mesh: the
    map is fold-free on a sampled ellipsoid-like shape and keeps its limbs apart."""
    s = limbs_surfels()
    cloud = SurfelSet(s.positions, s.normals, s.radii)
    m = parameterize(cloud, stress=False)
    assert [st.name for st in m.stages] == ["proxy", "multilevel"]
    assert m.info["proxy_vertices"] > 0 and m.info["mesh_folds"] == 0
    np.testing.assert_allclose(np.linalg.norm(m.points, axis=1), 1.0, atol=1e-12)
    assert m.fold_fraction <= 0.01
    assert len(np.unique(np.round(m.points, 9), axis=0)) == len(cloud)


def test_point_cloud_of_genus_one_refused():
    u, v = np.meshgrid(np.linspace(0, 2 * np.pi, 80, endpoint=False),
                       np.linspace(0, 2 * np.pi, 40, endpoint=False))
    u, v = u.ravel(), v.ravel()
    p = np.column_stack([(1 + 0.4 * np.cos(v)) * np.cos(u), (1 + 0.4 * np.cos(v)) * np.sin(u),
                         0.4 * np.sin(v)])
    c = np.column_stack([np.cos(u), np.sin(u), np.zeros_like(u)])
    n = p - c
    n /= np.linalg.norm(n, axis=1)[:, None]
    torus = SurfelSet(p, n, np.full(len(p), 0.08))
    with pytest.raises(TopologyError, match="genus"):
        parameterize(torus, stress=False)


def test_map_options_are_checked(sphere_surfels):
    """Bad options fail when the options are made, naming the field; a map takes only a
    MapOptions."""
    import dataclasses

    with pytest.raises(InputError, match="MapOptions.balance must be True or False"):
        MapOptions(balance=1)
    with pytest.raises(InputError, match=r"MapOptions.round_steps must be an integer >= 0"):
        MapOptions(round_steps=-1)
    with pytest.raises(InputError, match=r"MapOptions.final_steps must be an integer >= 0"):
        MapOptions(final_steps=2.5)
    with pytest.raises(InputError, match=r"MapOptions.settle_energy must be a finite number"):
        MapOptions(settle_energy=float("nan"))
    with pytest.raises(InputError, match="MapOptions.level_ratio must be at least 2"):
        MapOptions(level_ratio=1)
    with pytest.raises(InputError, match=r"MapOptions.coarse_vertices must be at least 4"):
        MapOptions(coarse_vertices=3)
    with pytest.raises(InputError, match="options must be a MapOptions, got dict"):
        parameterize(sphere_surfels, options={"balance": False})
    with pytest.raises(dataclasses.FrozenInstanceError):
        MapOptions().balance = False        # frozen: a map's options cannot change under it


def test_map_result_records_its_stages(sphere_surfels):
    """The result is frozen; its stages are records with read-only figures, merged in
    ``info`` and in ``figures()`` (the CLI's JSON)."""
    m = parameterize(limbs_surfels(), stress=False)
    assert [s.name for s in m.stages] == ["multilevel"]
    assert m.stage("mds") is None
    with pytest.raises(TypeError):
        m.info["levels"] = 0
    with pytest.raises(TypeError):
        m.stages[0].figures["levels"] = 0
    fig = m.figures()
    assert fig["levels"] == m.info["levels"] and fig["stages"] == [s.name for s in m.stages]
    mds = parameterize(sphere_surfels, method="mds", landmarks=8, iterations=2, stress=False)
    assert [s.name for s in mds.stages] == ["mds"] and mds.info["landmarks"] == 8


def test_grid_level_is_choose_level_of_the_map():
    """The default grid level of a map: one rule (icosphere.choose_level) for codec and CLI."""
    from surfidx.geometry.icosphere import choose_level

    s = TriangleMesh(*icosphere_mesh(2)).to_surfels()
    m = parameterize(s, stress=False)
    assert m.grid_level == choose_level(len(s), sparse_sampling=m.sparse_sampling)


def test_figures_of_the_map_are_the_public_measures():
    """parameterize checks its points once and computes the figures with the private kernels:
    the same values as the public functions."""
    s = TriangleMesh(*icosphere_mesh(2)).to_surfels()
    m = parameterize(s, stress=False)
    assert count_folds(s, m.points) == (0, len(s.faces))
    assert (m.folded, m.triangles) == (0, len(s.faces))    # the faces the codec uses
    assert m.area_distortion == area_distortion(s, m.points)
    assert m.sparse_sampling == sparse_sampling(s, m.points)


def test_method_names_and_options_import_without_the_stages():
    """The CLI reads sphere.METHODS at startup: the package exports the stages lazily."""
    import subprocess
    import sys

    code = ("import sys; from surfidx.sphere import METHODS, MapOptions; import surfidx.cli; "
            "print(METHODS, 'numba' in sys.modules, 'scipy' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.split() == ["('tutte',", "'mds')", "False", "False"]
    import surfidx.sphere as S
    with pytest.raises(AttributeError, match="nothing"):
        S.nothing


@pytest.mark.parametrize("scan", ["d029_view", "d006_view"])
def test_scan_with_coincident_points_maps(scan):
    """Single-view scans (retrieval models d029 and d006 seen from one camera, as
    ``benchmarks/retrieval.py --partial view`` makes them, seeds 102900 and 100602) with
    coincident points. d029: a zero-length edge made the prolongation's ring weights overflow,
    a vertex came back at the origin and the balancing divided by zero. d006: decimated to a
    tetrahedron with two corners at one point, whose Tutte circle put them at one place, and
    the whole map collapsed to five points. Both map, every input triangle counter-clockwise."""
    import warnings
    from pathlib import Path

    import trimesh

    from surfidx import read_model

    z = np.load(Path(__file__).parent / "data" / f"{scan}.npz")
    mesh = trimesh.Trimesh(z["vertices"], z["faces"], process=False)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")          # the repair's notes on the scan's holes
        model = read_model(mesh)
    m = parameterize(model.parts[0], stress=False)
    assert np.isfinite(m.points).all() and m.info["mesh_folds"] == 0
