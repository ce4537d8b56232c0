"""View-based descriptors: a model's views, a scan's camera direction and views, the partial
view distance, and queries by a single view from Python."""

from __future__ import annotations

import functools
import warnings

import numpy as np
import pytest

from surfidx import InputError
from surfidx.describe import views as V

import helpers
from helpers import one_view, write_off

#: The capsule these tests see: finer than the helper's default.
capsule = functools.partial(helpers.capsule, n=32, rings=12)


def box(extents=(2.0, 1.0, 0.5)):
    import trimesh

    m = trimesh.creation.box(extents=extents).subdivide().subdivide()
    return np.asarray(m.vertices, float), np.asarray(m.faces, np.int64)


def angle(a, b):
    return float(np.degrees(np.arccos(np.clip(np.dot(a, b) / np.linalg.norm(a)
                                              / np.linalg.norm(b), -1, 1))))


def test_model_views_are_one_vector_per_direction_and_the_same_every_time():
    v, f = capsule()
    a = V.model_views(v, f)
    assert a.shape == (len(V.view_directions()), V.view_dim()) and a.dtype == np.float32
    assert np.all(np.isfinite(a))
    assert a.tobytes() == V.model_views(v, f).tobytes()


def _sorted_view(p, d):
    """A view described the plain way: samples sorted per pixel by height (the nearest last),
    ring shares added one pixel at a time (``np.add.at``): what :func:`V.view_vector` must give."""
    d = d / np.linalg.norm(d)
    e1 = np.cross(d, [1.0, 0.0, 0.0] if abs(d[0]) < 0.9 else [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(d, e1)
    u, v, z = p @ e1, p @ e2, p @ d
    n = V.VIEW_PIXELS
    span = max(u.max() - u.min(), v.max() - v.min())
    scale = (n - 1e-9) / span
    px = np.minimum(((u - u.min()) * scale).astype(np.int64), n - 1)
    py = np.minimum(((v - v.min()) * scale).astype(np.int64), n - 1)
    cell = py * n + px
    order = np.lexsort((z, cell))
    cell, z = cell[order], z[order]
    last = np.r_[cell[1:] != cell[:-1], True]
    pix, depth = cell[last], z[last]
    dx, dy = pix % n + 0.5, pix // n + 0.5
    dx, dy = dx - dx.mean(), dy - dy.mean()
    r2 = dx * dx + dy * dy
    rms = np.sqrt(r2.mean())
    height = (depth - depth.mean()) / (rms / scale)
    pos = np.minimum(np.sqrt(r2) / rms / V.VIEW_RMAX * (V.VIEW_RINGS - 1), V.VIEW_RINGS - 1)
    lo = np.minimum(pos.astype(np.int64), V.VIEW_RINGS - 2)
    t = pos - lo
    phase = np.exp(-1j * np.arctan2(dy, dx)[:, None] * np.arange(V.VIEW_HARMONICS)[None, :])
    out = []
    for w in (np.ones_like(height), height):
        acc = np.zeros((V.VIEW_RINGS, V.VIEW_HARMONICS), np.complex128)
        np.add.at(acc, lo, (1.0 - t)[:, None] * (w[:, None] * phase))
        np.add.at(acc, lo + 1, t[:, None] * (w[:, None] * phase))
        out.append(np.abs(acc).ravel() / len(pix))
    return np.concatenate([out[0], out[1] * V.VIEW_DEPTH_WEIGHT])


@pytest.mark.parametrize("rounded", [False, True])
def test_a_view_is_bit_equal_to_the_sorted_per_pixel_description(rounded):
    """The nearest sample per pixel and the ring sums, as the stored views were first computed:
    the same bits, also when samples tie in pixel and height (coordinates rounded)."""
    rng = np.random.default_rng(3)
    v, f = capsule()
    for p in (V.surface_samples(v, f), rng.standard_normal((5000, 3)) * [3.0, 1.0, 0.5]):
        if rounded:
            p = np.round(p, 1)
        for d in V.view_directions()[::5]:
            assert V.view_vector(p, d).tobytes() == _sorted_view(p, d).tobytes()


@pytest.mark.parametrize("direction", [(1.0, 0.3, 0.2), (-0.2, 0.1, -1.0), (0.5, -0.8, 0.4)])
def test_the_camera_direction_of_a_view_is_found(direction):
    v, f = box()                # three faces: seen alike from the whole octant
    sv, sf = one_view(v, f, direction)
    t = sv[sf]
    n = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
    assert np.all(n @ V.scan_direction(sv, sf) > 0)
    v, f = capsule()
    sv, sf = one_view(v, f, direction)
    assert angle(V.scan_direction(sv, sf), direction) < 8.0


def test_a_scan_is_seen_from_its_camera_and_from_tilted_directions_around_it():
    d = np.array([0.2, -0.5, 0.8])
    t = V.tilted_directions(d, tilts=(12.0, 20.0), turns=5)
    assert t.shape == (11, 3)
    assert np.allclose(np.linalg.norm(t, axis=1), 1.0)
    assert angle(t[0], d) < 1e-6
    assert all(angle(x, d) == pytest.approx(12.0) for x in t[1:6])
    assert all(angle(x, d) == pytest.approx(20.0) for x in t[6:])
    side = t[1:] - (t[1:] @ t[0])[:, None] * t[0]       # evenly spaced around d
    assert angle(side[0], side[1]) == pytest.approx(72.0)
    assert angle(side[0], side[2]) == pytest.approx(144.0)
    assert angle(side[0], side[5]) == pytest.approx(36.0)   # the next ring half a step on
    sv, sf = one_view(*capsule(), (1.0, 0.3, 0.2))
    views = V.scan_views(sv, sf)
    assert views.shape == (len(V.SCAN_TILTS) * V.SCAN_TURNS + 2, V.view_dim())
    assert not np.allclose(views[0], views[1])


def test_a_view_is_invariant_to_a_similarity_of_the_model():
    rng = np.random.default_rng(5)
    v, f = capsule(length=3.0)
    p = V.surface_samples(v, f)
    d = np.array([0.3, 0.9, 0.2])
    d /= np.linalg.norm(d)
    a = V.view_vector(p, d)
    from scipy.spatial.transform import Rotation

    rot = Rotation.random(random_state=rng).as_matrix()
    b = V.view_vector(3.7 * p @ rot.T + [1.0, -2.0, 5.0], rot @ d)
    other = V.view_vector(V.surface_samples(*box()), d)
    assert np.linalg.norm(a - b) < 0.2 * np.linalg.norm(a - other)   # pixels differ


def test_a_scan_finds_its_model_among_other_shapes():
    shapes = {"capsule": capsule(), "ball": capsule(length=0.2), "long": capsule(length=5.0),
              "box": box()}
    stored = {"views": np.stack([V.model_views(*m).ravel() for m in shapes.values()])}
    present = {"views": np.ones(len(shapes), bool)}
    names = list(shapes)
    for name, (v, f) in shapes.items():
        sv, sf = one_view(v, f, (1.0, 0.3, 0.2))
        d = V.partial_view_l2({"views": V.scan_views(sv, sf).ravel()}, stored, present)
        assert names[int(np.argmin(d))] == name
    present["views"][0] = False
    sv, sf = one_view(*shapes["capsule"], (1.0, 0.3, 0.2))
    assert np.isinf(V.partial_view_l2({"views": V.scan_views(sv, sf).ravel()}, stored,
                                      present)[0])


def test_view_set_distance_is_zero_for_the_same_model_and_symmetric():
    a, b = V.model_views(*capsule()), V.model_views(*box())
    s = np.stack([a, b])
    assert V.view_set_distance(a, s)[0] == pytest.approx(0.0, abs=1e-6)
    assert V.view_set_distance(a, s)[1] == pytest.approx(V.view_set_distance(b, s)[0])


def test_views_refuse_degenerate_input():
    v = np.array([[0.0, 0, 0], [1, 0, 0], [2, 0, 0]])
    f = np.array([[0, 1, 2]])
    with pytest.raises(InputError, match="zero area; it has no views"):
        V.surface_samples(v, f)
    with pytest.raises(InputError, match="zero area; its camera direction is unknown"):
        V.scan_direction(v, f)
    with pytest.raises(InputError, match="projects to a single point"):
        V.view_vector(np.zeros((5, 3)), [0.0, 0.0, 1.0])
    with pytest.raises(InputError, match="whole views of"):
        V.partial_view_l2({"views": np.zeros(7)}, {"views": np.zeros((2, V.view_dim()))},
                          {"views": np.ones(2, bool)})


def test_describe_grid_stores_views_with_their_conventions():
    from surfidx.describe import DESCRIPTOR_VERSION, describe_grid
    from surfidx.geometry.icosphere import icosphere

    x = np.asarray(icosphere(3).vertices) * [1.0, 0.6, 0.4]
    d = describe_grid(x, 3)
    assert d.vectors["views"].shape == (len(V.view_directions()) * V.view_dim(),)
    assert d.params["views"] == V.view_params() and d.params["version"] == DESCRIPTOR_VERSION


def test_scan_surface_refuses_points_without_faces():
    from types import SimpleNamespace

    from surfidx.pipeline import scan_surface

    part = SimpleNamespace(faces=None)
    model = SimpleNamespace(parts=(part,), face_patch=lambda k: None)
    with pytest.raises(InputError, match="needs a surface with faces"):
        scan_surface(model)


@pytest.fixture(scope="module")
def shapes_db(tmp_path_factory):
    from surfidx.database import Database

    root = tmp_path_factory.mktemp("views")
    models = root / "models"
    models.mkdir()
    for name, m in (("capsule", capsule()), ("ball", capsule(length=0.2)),
                    ("long", capsule(length=5.0))):
        write_off(models / f"{name}.off", *m)
    db_path = root / "v.db"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        with Database(db_path) as db:
            db.ingest([models], workers=1)
    view = write_off(root / "view.off", *one_view(*capsule(), (1.0, 0.3, 0.2)))
    return db_path, view


def test_a_partial_query_compares_views_without_mapping_the_scan(shapes_db, monkeypatch):
    from surfidx import pipeline
    from surfidx.database import Database

    db_path, view = shapes_db
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        with Database(db_path) as db:
            auto = db.query(str(view), k=3)                   # detected after the read
            detected = db.example(str(view))
            whole = db.example(str(view), partial=False)      # --complete: mapped
            monkeypatch.setattr(pipeline, "describe_model", None)   # --partial never maps
            forced = db.query(str(view), k=3, partial=True)
            ex = db.example(str(view), partial=True)
    assert auto[0]["name"] == "capsule"
    assert [(r["name"], r["distance"]) for r in auto] == \
        [(r["name"], r["distance"]) for r in forced]
    assert set(ex.descriptors) == {"views"} and ex.virtual_share > 0.2
    # found partial, it is described by its views alone, as --partial describes it: no map
    assert set(detected.descriptors) == {"views"}
    np.testing.assert_array_equal(detected.descriptors["views"], ex.descriptors["views"])
    assert detected.virtual_share == ex.virtual_share and detected.thumbnail is not None
    assert {"shape", "views"} <= set(whole.descriptors)
    np.testing.assert_array_equal(whole.descriptors["views"], ex.descriptors["views"])


def test_a_database_without_views_falls_back_or_says_to_redescribe(shapes_db, tmp_path):
    import shutil
    import sqlite3

    from surfidx.database import Database

    db_path, view = shapes_db
    old = tmp_path / "old.db"
    shutil.copy(db_path, old)
    with sqlite3.connect(old) as conn:
        conn.execute("DELETE FROM descriptors WHERE kind = 'views'")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        with Database(old) as db:
            rows = db.query(str(view), k=3)         # detected: the default descriptors
            assert len(rows) == 3
            assert "shape" in db.example(str(view)).descriptors    # mapped: nothing else to compare
            with pytest.raises(InputError, match="no stored model has views"):
                db.query(str(view), k=3, partial=True)


def test_expansion_keeps_the_first_match_first_and_blends_the_rest():
    v = np.array([3.0, 1.0, 2.0, np.inf, 4.0])
    c = np.array([0.5, 0.0, 4.0, 1.0, np.inf])      # the first match (index 1) is 0 from itself
    out = V.expand_by_first(v, c, weight=1.0)
    assert int(np.argmin(out)) == 1 and np.isinf(out[3])
    assert out[0] < out[2]                    # close to the first match's complete model
    assert out[4] == pytest.approx(4.0 / 2.5 + 4.0 / 1.0)    # no descriptor: the farthest
    np.testing.assert_allclose(V.expand_by_first(v, c, weight=0.0), v / 2.5)


def test_expansion_refuses_bad_input():
    with pytest.raises(InputError, match="weight must be a finite number >= 0"):
        V.expand_by_first([1.0, 2.0], [0.0, 1.0], weight=-1.0)
    with pytest.raises(InputError, match="must not hold NaN"):
        V.expand_by_first([1.0, np.nan], [0.0, 1.0])
    with pytest.raises(InputError, match="first_dist"):
        V.expand_by_first([1.0, 2.0], [0.0, 1.0, 2.0])


def test_a_partial_query_ranks_by_its_first_matchs_complete_model(shapes_db):
    from surfidx.database import Database

    db_path, view = shapes_db
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        with Database(db_path) as db:
            rows = db.query(str(view), k=3, partial=True)
            ex = db.example(str(view), partial=True)
            ids, stored, present = db.descriptor_rows([r["id"] for r in rows], ("views",))
            first = rows[0]["name"]
            complete = {r["id"]: r["distance"] for r in db.query(first, k=3, include_self=True)}
    dv = V.partial_view_l2({"views": ex.descriptors["views"]}, stored, present)
    assert ids[int(np.argmin(dv))] == rows[0]["id"]
    want = V.expand_by_first(dv, np.array([complete[i] for i in ids.tolist()]))
    got = {r["id"]: r["distance"] for r in rows}
    np.testing.assert_allclose([got[i] for i in ids.tolist()], want, rtol=1e-6)
