"""Geodesics on surfels: arc lengths on the sphere, exact bunny geodesics, paths, refinement,
landmarks, components, errors and the ``surfidx geodesic`` / ``surfidx render --path`` CLI."""

from __future__ import annotations

import json
import warnings
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from conftest import icosphere_mesh
from PIL import Image
from plyfile import PlyData

from surfidx import FileFormatError, InputError, SurfelSet, TopologyError, TriangleMesh, read_surfels
from surfidx.cli import cli
from surfidx.geometry.geodesics import (GeodesicPath, GeodesicSolver, farthest_point_landmarks,
                               geodesic_distances, geodesic_path)
from surfidx.render import read_polyline

DATA = Path(__file__).resolve().parent / "data"

# the accuracy targets (mean |relative error|)
GRAPH_TARGET = 0.02
REFINED_TARGET = 0.005


def _sphere(level, centre=(0.0, 0.0, 0.0)):
    v, f = icosphere_mesh(level)
    return TriangleMesh(v + np.asarray(centre), f).to_surfels()


def _arc(s, a, b):
    """Exact great-circle distances on the unit sphere between surfel index arrays."""
    pa, pb = s.positions[np.atleast_1d(a)], s.positions[np.atleast_1d(b)]
    return np.arccos(np.clip(pa @ pb.T, -1.0, 1.0))


def _rel(d, exact):
    return np.abs(d / exact - 1.0)


@pytest.fixture(scope="module")
def sphere4():
    """Level-4 unit icosphere (2,562 surfels) and its solver."""
    s = _sphere(4)
    return s, GeodesicSolver(s)


@pytest.fixture(scope="module")
def two_spheres():
    a, b = _sphere(2), _sphere(2, centre=(5.0, 0.0, 0.0))
    return SurfelSet(np.vstack([a.positions, b.positions]), np.vstack([a.normals, b.normals]),
                     np.concatenate([a.radii, b.radii]))


# ---------------------------------------------------------------------- accuracy
def test_sphere_graph_distances_are_arc_lengths(sphere4):
    s, solver = sphere4
    rng = np.random.default_rng(1)
    src = rng.choice(len(s), 8, replace=False)
    d = solver.distances(src)
    assert d.shape == (8, len(s))
    exact = _arc(s, src, np.arange(len(s)))
    assert np.all(d[np.arange(8), src] == 0)
    far = exact > 0.2  # the relative error of the nearest few neighbours is meaningless
    err = _rel(d[far], exact[far])
    assert err.mean() <= GRAPH_TARGET
    assert np.percentile(err, 95) <= 2.5 * GRAPH_TARGET
    # a path through surfels on the sphere is never shorter than the arc (chords are, slightly)
    assert np.all(d[far] >= exact[far] * np.cos(0.1))
    # targets restrict the columns
    tg = rng.choice(len(s), 5, replace=False)
    assert np.array_equal(solver.distances(src, targets=tg), d[:, tg])


def test_sphere_refined_distances(sphere4):
    s, solver = sphere4
    rng = np.random.default_rng(2)
    src = rng.choice(len(s), 2, replace=False)
    tg = rng.choice(len(s), 6, replace=False)
    exact = _arc(s, src, tg)
    ok = exact > 0.2
    graph = solver.distances(src, targets=tg)
    refined = solver.distances(src, targets=tg, refine=True)
    assert _rel(refined[ok], exact[ok]).mean() <= REFINED_TARGET
    assert _rel(refined[ok], exact[ok]).mean() < _rel(graph[ok], exact[ok]).mean() / 4
    # without faces (surfel planes), refinement only shortens the graph paths
    bare = GeodesicSolver(SurfelSet(s.positions, s.normals, s.radii))
    assert np.all(bare.distances(src, targets=tg, refine=True)
                  <= bare.distances(src, targets=tg) + 1e-12)
    # a source among the targets: distance 0
    assert solver.distances(src[:1], targets=[src[0]], refine=True)[0, 0] == 0.0
    # the one-pair helper agrees
    assert solver.distance(src[0], tg[0], refine=True) == pytest.approx(refined[0, 0])
    assert solver.distance(src[0], tg[0]) == pytest.approx(graph[0, 0])


@pytest.mark.slow
def test_bunny_against_frozen_exact_geodesics(shared_data):
    ref = json.loads((DATA / "geodesic_bunny_hr.json").read_text())
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        s = read_surfels(shared_data / "models" / ref["model"])
    assert len(s) == ref["surfels"]
    exact = np.asarray(ref["distances"])
    solver = GeodesicSolver(s)
    graph = solver.distances(ref["sources"], targets=ref["targets"])
    err = _rel(graph, exact)
    assert err.mean() <= GRAPH_TARGET
    assert np.percentile(err, 95) <= 2.5 * GRAPH_TARGET
    # the graph overestimates (zig-zag), never much below the exact distance
    assert np.all(graph >= exact * (1 - 0.01))
    k = 8
    refined = solver.distances(ref["sources"][:1], targets=ref["targets"][:k], refine=True)
    assert _rel(refined, exact[:1, :k]).mean() <= REFINED_TARGET


# ---------------------------------------------------------------------- paths
def test_graph_path_is_chain_of_edges(sphere4):
    s, solver = sphere4
    m = solver.graph.matrix
    a, b = 3, 1999
    p = solver.path(a, b)
    assert isinstance(p, GeodesicPath) and not p.refined
    assert p.indices[0] == a and p.indices[-1] == b
    assert len(np.unique(p.indices)) == len(p.indices)
    steps = np.asarray(m[p.indices[:-1], p.indices[1:]]).ravel()
    assert np.all(steps > 0)  # consecutive surfels are linked
    chords = np.linalg.norm(np.diff(p.points, axis=0), axis=1)
    # arc weights: no shorter than the chords, and close to them on a fine sphere
    assert np.all(steps >= chords * (1 - 1e-12)) and np.allclose(steps, chords, rtol=1e-2)
    assert p.length == pytest.approx(steps.sum())
    assert p.length == pytest.approx(solver.distances([a], targets=[b])[0, 0], rel=1e-12)
    assert np.array_equal(p.points, s.positions[p.indices])
    assert np.array_equal(p.surfels, p.indices)
    # reversed path: same length
    assert solver.path(b, a).length == pytest.approx(p.length, rel=1e-12)
    # the one-call helpers agree with the solver
    q = geodesic_path(s, a, b)
    assert np.array_equal(q.indices, p.indices)
    assert np.allclose(geodesic_distances(s, [a]), solver.distances([a]))


def test_trivial_path(sphere4):
    _, solver = sphere4
    p = solver.path(7, 7, refine=True)
    assert list(p.indices) == [7] and p.length == 0.0 and len(p.points) == 1
    assert solver.distance(7, 7) == 0.0


def test_refined_path_on_surface_and_shorter(sphere4):
    s, solver = sphere4
    a, b = 3, 1999
    g = solver.path(a, b)
    r = solver.path(a, b, refine=True)
    assert r.refined and r.indices[0] == a and r.indices[-1] == b
    assert r.length < g.length
    exact = _arc(s, a, b)[0, 0]
    assert r.length == pytest.approx(exact, rel=REFINED_TARGET)
    assert np.allclose(r.points[[0, -1]], s.positions[[a, b]])
    assert r.length == pytest.approx(np.linalg.norm(np.diff(r.points, axis=0), axis=1).sum())
    # on the sphere: radius 1 up to the flatness of the surfel planes (spacing^2 / 8)
    spacing = np.median(solver.graph.matrix.data)
    assert np.abs(np.linalg.norm(r.points, axis=1) - 1).max() < spacing ** 2
    # on the mesh: every point lies on one of the triangles
    assert _mesh_distance(r.points, s).max() < 1e-9
    # and so does every segment (the midpoints are on triangles too: no chord cuts through)
    assert _mesh_distance(0.5 * (r.points[1:] + r.points[:-1]), s).max() < 1e-9
    # without faces: on the local surfel planes (distance to the nearest surfel's plane)
    bare = GeodesicSolver(SurfelSet(s.positions, s.normals, s.radii)).path(a, b, refine=True)
    near = np.argmin(((bare.points[:, None, :] - s.positions[None]) ** 2).sum(-1), axis=1)
    off = np.einsum("ij,ij->i", bare.points - s.positions[near], s.normals[near])
    assert np.abs(off).max() < spacing ** 2
    # refined points are finer than the graph path and carry -1 for in-between points
    assert len(r.points) > len(g.points)
    assert r.surfels[0] == a and r.surfels[-1] == b and np.all(r.surfels[1:-1] == -1)


def _mesh_distance(points, s):
    """Distance of each point to the nearest triangle of ``s.faces`` (barycentric clamp)."""
    from surfidx.sphere.proxy import closest_on_triangle

    tri = s.positions[s.faces]
    out = []
    for p in points:
        q = [np.dot(closest_on_triangle(p, *t), t) for t in tri]
        out.append(np.min(np.linalg.norm(np.asarray(q) - p, axis=1)))
    return np.asarray(out)


def test_refined_path_on_a_flat_plane_is_straight():
    # a jittered planar grid: the graph path zig-zags, the refined one is the straight segment
    rng = np.random.default_rng(3)
    x, y = np.meshgrid(np.arange(30) * 0.1, np.arange(30) * 0.1)
    pos = np.stack([x.ravel(), y.ravel(), np.zeros(900)], 1)
    pos[:, :2] += rng.uniform(-0.02, 0.02, (900, 2))
    s = SurfelSet(pos, np.tile([0, 0, 1.0], (900, 1)), np.full(900, 0.08))
    solver = GeodesicSolver(s)
    a, b = 0, 10 * 30 + 29  # grid (0, 0) to (29, 10): no lattice direction
    r = solver.path(a, b, refine=True)
    straight = np.linalg.norm(pos[a] - pos[b])
    g = solver.path(a, b).length
    assert g > straight
    assert r.length == pytest.approx(straight, rel=1e-3)
    assert r.length - straight < (g - straight) / 4
    assert np.abs(r.points[:, 2]).max() < 1e-9


def test_write_ply_and_read_polyline(sphere4, tmp_path):
    _, solver = sphere4
    r = solver.path(3, 1999, refine=True)
    out = tmp_path / "p.ply"
    r.write_ply(out)
    v = PlyData.read(str(out))["vertex"]
    assert np.array_equal(np.asarray(v["surfel"]), r.surfels)
    assert np.array_equal(read_polyline(out), r.points)


# ---------------------------------------------------------------------- landmarks
def test_landmarks_farthest_point_property(sphere4):
    s, solver = sphere4
    k = 6
    lm = solver.landmarks(k, seed=5)
    assert lm.shape == (k,) and len(set(lm.tolist())) == k
    d = solver.distances(lm)
    for i in range(1, k):
        nearest = d[:i].min(axis=0)
        assert nearest[lm[i]] == pytest.approx(nearest.max(), rel=1e-12)
    # the first landmark is the farthest from the seed's random start
    start = int(np.random.default_rng(5).integers(len(s)))
    d0 = solver.distances([start])[0]
    assert d0[lm[0]] == pytest.approx(d0.max())
    # two landmarks on a sphere are (nearly) antipodal
    assert _arc(s, lm[0], lm[1])[0, 0] > 0.95 * np.pi
    assert np.array_equal(farthest_point_landmarks(s, k, seed=5), lm)
    assert np.array_equal(solver.landmarks(k, seed=5), lm)


def test_landmarks_all_surfels():
    s = _sphere(1)
    lm = GeodesicSolver(s).landmarks(len(s))
    assert sorted(lm.tolist()) == list(range(len(s)))


# ---------------------------------------------------------------------- components, errors
def test_disconnected_input_names_components(two_spheres):
    with pytest.raises(TopologyError, match=r"disconnected: 2 components \(sizes 162, 162 "
                                            r"surfels\).*bridge=True"):
        GeodesicSolver(two_spheres)
    with pytest.raises(TopologyError, match="2 components"):
        geodesic_distances(two_spheres, [0])
    with pytest.warns(UserWarning, match="bridged them with 1 straight links"):
        solver = GeodesicSolver(two_spheres, bridge=True)
    d = solver.distances([0])[0]
    assert np.all(np.isfinite(d))
    # across the bridge: at least the 3-unit gap between the spheres
    assert d[162:].min() > 3.0 - 0.1


def test_bad_indices_and_options(sphere4):
    s, solver = sphere4
    n = len(s)
    with pytest.raises(InputError, match=f"sources: surfel index {n} is out of range 0..{n - 1}"):
        solver.distances([0, n])
    with pytest.raises(InputError, match="sources: surfel index -1 is out of range"):
        solver.distances(-1)
    with pytest.raises(InputError, match="targets: surfel index 9999 is out of range"):
        solver.distances([0], targets=[9999])
    with pytest.raises(InputError, match="refine=True needs targets"):
        solver.distances([0], refine=True)
    with pytest.raises(InputError, match="b: surfel index 99999 is out of range"):
        solver.path(0, 99999)
    with pytest.raises(InputError, match="a: surfel index -3 is out of range"):
        solver.distance(-3, 0)
    with pytest.raises(InputError, match="a must have shape"):
        solver.path([0, 1], 2)
    with pytest.raises(InputError, match="sources must hold integers"):
        solver.distances([0.5])
    with pytest.raises(InputError, match="k must be at most the number of surfels"):
        solver.landmarks(n + 1)
    with pytest.raises(InputError, match="k must be at least 1"):
        solver.landmarks(0)
    with pytest.raises(InputError, match=r"max_angle must lie in \(0, 180\]"):
        GeodesicSolver(s, max_angle=200)
    with pytest.raises(InputError, match="radius must be one of"):
        geodesic_path(s, 0, 1, radius="far")


def test_write_ply_unwritable(sphere4, tmp_path):
    _, solver = sphere4
    with pytest.raises(FileFormatError, match="cannot write"):
        solver.path(0, 5).write_ply(tmp_path / "missing" / "p.ply")


def test_radius_variants_give_close_distances(sphere4):
    s, solver = sphere4
    exact = _arc(s, [0], np.arange(len(s)))[0]
    far = exact > 0.2
    for kw in ({"radius": "nearest", "scale": 2.0}, {"radius": "knn", "k": 8, "scale": 1.0}):
        d = GeodesicSolver(s, **kw).distances([0])[0]
        assert _rel(d[far], exact[far]).mean() < 0.1


# ---------------------------------------------------------------------- CLI
def run(*args):
    return CliRunner().invoke(cli, [str(a) for a in args])


@pytest.fixture(scope="module")
def sphere_obj(tmp_path_factory):
    """The level-3 icosphere as an OBJ (surfel indices = its vertex order)."""
    v, f = icosphere_mesh(3)
    path = tmp_path_factory.mktemp("geo") / "sphere.obj"
    lines = [f"v {x:.17g} {y:.17g} {z:.17g}" for x, y, z in v] + [f"f {a + 1} {b + 1} {c + 1}"
                                                         for a, b, c in f]
    path.write_text("\n".join(lines) + "\n")
    return path, v


def test_cli_geodesic_json_matches_library(sphere_obj):
    path, v = sphere_obj
    res = run("geodesic", path, "--source", 4, "--target", 500, "--json")
    assert res.exit_code == 0, res.output
    out = json.loads(res.output)
    solver = GeodesicSolver(read_surfels(path))
    p = solver.path(4, 500)
    assert out["distance"] == pytest.approx(p.length, rel=1e-12)
    assert out["path"] == p.indices.tolist()
    assert out["path"][0] == 4 and out["path"][-1] == 500
    exact = np.arccos(np.clip(v[4] @ v[500], -1, 1))
    assert out["distance"] == pytest.approx(exact, rel=0.1)


def test_cli_geodesic_refine_writes_path_and_render_draws_it(sphere_obj, tmp_path):
    path, v = sphere_obj
    ply = tmp_path / "path.ply"
    res = run("geodesic", path, "--source", 4, "--target", 500, "--refine", "-o", ply, "--json")
    assert res.exit_code == 0, res.output
    out = json.loads(res.output)
    graph = json.loads(run("geodesic", path, "--source", 4, "--target", 500, "--json").output)
    assert out["refined"] and out["distance"] < graph["distance"]
    exact = np.arccos(np.clip(v[4] @ v[500], -1, 1))
    assert out["distance"] == pytest.approx(exact, rel=REFINED_TARGET)
    pts = read_polyline(ply)
    assert len(pts) == out["points"]
    assert np.allclose(pts[[0, -1]], v[[4, 500]])
    # plain-text output
    res = run("geodesic", path, "--source", 4, "--target", 500)
    assert res.exit_code == 0 and res.output.startswith("distance ")
    assert f"path     {' '.join(map(str, graph['path']))}" in res.output
    # the path overlay: the same view with and without the path differs
    png, bare = tmp_path / "with.png", tmp_path / "bare.png"
    res = run("render", path, "--path", ply, "-o", png, "--size", "96x96", "--view", "front")
    assert res.exit_code == 0, res.output
    assert run("render", path, "-o", bare, "--size", "96x96", "--view", "front").exit_code == 0
    a, b = np.asarray(Image.open(png)), np.asarray(Image.open(bare))
    assert a.shape == (96, 96, 3) and np.any(a != b)


@pytest.mark.parametrize("args, message", [
    (("--source", 642, "--target", 0), "a: surfel index 642 is out of range 0..641"),
    (("--source", 0, "--target", -2), "b: surfel index -2 is out of range 0..641"),
    (("--source", 0, "--target", 1, "--max-angle", 0), "max_angle must lie in"),
])
def test_cli_geodesic_bad_arguments_one_line(sphere_obj, args, message):
    """One line naming the input file, then the problem."""
    path, _ = sphere_obj
    res = run("geodesic", path, *args)
    assert res.exit_code != 0
    assert res.output.startswith(f"Error: {path}: {message}")
    assert len(res.output.strip().splitlines()) == 1
    assert "Traceback" not in res.output and not isinstance(res.exception, InputError)


def test_cli_geodesic_disconnected_and_bridge(two_spheres, tmp_path):
    from surfidx import write_ply

    path = tmp_path / "two.ply"
    write_ply(two_spheres, path)
    res = run("geodesic", path, "--source", 0, "--target", 200)
    assert res.exit_code != 0 and "2 components" in res.output
    assert len(res.output.strip().splitlines()) == 1
    res = run("geodesic", path, "--source", 0, "--target", 200, "--bridge", "--json")
    assert res.exit_code == 0
    assert "warning: the spheres-of-influence graph has 2 components" in res.stderr
    assert json.loads(res.stdout)["distance"] > 2.9


def test_cli_geodesic_missing_file(tmp_path):
    res = run("geodesic", tmp_path / "none.ply", "--source", 0, "--target", 1)
    assert res.exit_code != 0 and "Traceback" not in res.output
    assert len(res.output.strip().splitlines()) == 1


def _u_strip(arm=1.0, gap=0.12, h=0.02, width=0.2):
    """A strip bent into a U: arm z=0 (normal -z), half-circle of radius gap/2 at x=arm, arm
    z=gap (normal +z); surfel radii 0.05 reach across the gap."""
    t = np.arange(0.0, 2 * arm + np.pi * gap / 2 + h / 2, h)  # arc length along the U
    r = gap / 2
    pts, nrm = [], []
    for u in t:
        if u <= arm:
            pts.append((u, -r)), nrm.append((0.0, -1.0))
        elif u <= arm + np.pi * r:
            a = (u - arm) / r - np.pi / 2
            pts.append((arm + r * np.cos(a), r * np.sin(a))), nrm.append((np.cos(a), np.sin(a)))
        else:
            pts.append((arm - (u - arm - np.pi * r), r)), nrm.append((0.0, 1.0))
    pts, nrm = np.asarray(pts), np.asarray(nrm)
    ys = np.arange(0.0, width + h / 2, h)
    P = np.array([(x, y, z) for y in ys for x, z in pts])
    N = np.array([(nx, 0.0, nz) for y in ys for nx, nz in nrm])
    return SurfelSet(P, N, np.full(len(P), 0.05)), t, len(pts)


def test_u_strip_paths_do_not_cut_across():
    s, t, m = _u_strip()
    row = 5 * m  # a row of the strip in the middle of its width
    a, b = row, row + m - 1  # the two free ends, 0.12 apart in space
    exact = t[-1]
    # normal test off: only the surface test keeps the arms apart
    cut = GeodesicSolver(s, max_angle=180.0, max_offset=None)
    assert cut.distance(a, b) < 0.5 * exact
    solver = GeodesicSolver(s, max_angle=180.0)
    d = solver.distance(a, b)
    assert d == pytest.approx(exact, rel=0.03)
    p = solver.path(a, b, refine=True)
    assert p.length == pytest.approx(exact, rel=0.01)
    # every refined point lies on the strip (within the half-circle or on an arm)
    x, z = p.points[:, 0], p.points[:, 2]
    on_arm = (x <= 1.0 + 1e-9) & (np.abs(np.abs(z) - 0.06) < 2e-3)
    on_bend = (x > 1.0 - 1e-9) & (np.abs(np.hypot(x - 1.0, z) - 0.06) < 2e-3)
    assert np.all(on_arm | on_bend)
    # the default solver (normal test on) agrees
    assert GeodesicSolver(s).distance(a, b, refine=True) == pytest.approx(exact, rel=0.01)


def _u_strip_mesh(arm=1.0, gap=0.12, h=0.02, width=0.2):
    """The U strip of :func:`_u_strip`, triangulated (two triangles per grid cell)."""
    s, t, m = _u_strip(arm, gap, h, width)
    rows = len(s) // m
    q = np.arange((rows - 1) * (m - 1))
    r, c = q // (m - 1), q % (m - 1)
    v = r * m + c
    faces = np.concatenate([np.stack([v, v + 1, v + m], 1), np.stack([v + 1, v + m + 1, v + m], 1)])
    return SurfelSet(s.positions, s.normals, s.radii, faces=faces), m


def test_u_strip_mesh_paths_follow_the_triangles():
    s, m = _u_strip_mesh()
    a, b = 5 * m, 5 * m + m - 1
    # the exact polyhedral geodesic between the two ends of a row: the row's polyline
    exact = np.linalg.norm(np.diff(s.positions[a:b + 1], axis=0), axis=1).sum()
    solver = GeodesicSolver(s, max_angle=180.0)
    p = solver.path(a, b, refine=True)
    assert p.refined and p.length == pytest.approx(exact, rel=1e-9)
    # between two rows: the unfolded strip is a rectangle, the geodesic its diagonal
    c = 9 * m + m - 1
    rise = s.positions[c, 1] - s.positions[b, 1]
    assert solver.distance(a, c, refine=True) == pytest.approx(np.hypot(exact, rise), rel=1e-9)
    # every point and segment midpoint on the strip's triangles
    mids = np.concatenate([p.points, 0.5 * (p.points[1:] + p.points[:-1])])
    assert _mesh_distance(mids, s).max() < 1e-9


def test_mesh_path_on_a_flat_jittered_mesh_is_straight():
    from scipy.spatial import Delaunay

    rng = np.random.default_rng(4)
    xy = rng.uniform(0, 1, (400, 2))
    xy = np.concatenate([xy, [[0.05, 0.1], [0.93, 0.8]]])
    faces = Delaunay(xy).simplices.astype(np.int64)
    pos = np.column_stack([xy, np.zeros(len(xy))])
    s = SurfelSet(pos, np.tile([0, 0, 1.0], (len(xy), 1)), np.full(len(xy), 0.1), faces=faces)
    solver = GeodesicSolver(s)
    a, b = len(xy) - 2, len(xy) - 1
    straight = np.linalg.norm(pos[a] - pos[b])
    r = solver.path(a, b, refine=True)
    assert r.length == pytest.approx(straight, rel=1e-9)
    # found around the mesh-edge path, which zig-zags
    assert np.linalg.norm(np.diff(pos[r.indices], axis=0), axis=1).sum() > straight * 1.01
