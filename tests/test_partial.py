"""Queries by a partial scan: detection by the virtual share, the partial distance, the
real-surface descriptors, and ``query --partial`` from Python and the command line."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from surfidx import InputError
from surfidx.describe import (PARTIAL_SHARE, describe_grid, is_partial, part_slices, partial_l2,
                              weighted_l2)
from surfidx.geometry.icosphere import icosphere

from helpers import capsule, one_view, write_off


def test_is_partial_compares_the_virtual_share_with_the_threshold():
    assert not is_partial(0.0)
    assert not is_partial(PARTIAL_SHARE)
    assert is_partial(0.45)
    assert is_partial(0.1, threshold=0.05)
    with pytest.raises(InputError, match=r"virtual_share must be a number in \[0, 1\]"):
        is_partial(1.5)
    with pytest.raises(InputError, match="threshold must be a number"):
        is_partial(0.3, threshold="half")


def test_a_single_view_is_detected_as_partial_and_the_complete_shape_is_not(tmp_path):
    from surfidx.topology import read_model

    v, f = capsule()
    whole = read_model(write_off(tmp_path / "capsule.off", v, f))
    assert not whole.repaired and not is_partial(whole.summary()["virtual_area_share"])
    vv, ff = one_view(v, f)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        view = read_model(write_off(tmp_path / "view.off", vv, ff))
    share = view.summary()["virtual_area_share"]
    assert is_partial(share), share


def _stored(rng, m=5):
    dim = part_slices()["layers"].stop
    stored = {"shape": rng.standard_normal((m, dim)).astype(np.float32),
              "spectrum": rng.random((m, 3)).astype(np.float32)}
    present = {k: np.ones(m, bool) for k in stored}
    query = {"shape": rng.standard_normal(dim).astype(np.float32),
             "spectrum": rng.random(3).astype(np.float32)}
    return query, stored, present


def test_partial_l2_weighs_the_parts_and_is_weighted_l2_with_unit_weights(monkeypatch):
    from surfidx.describe import partial as P

    query, stored, present = _stored(np.random.default_rng(0))
    monkeypatch.setattr(P, "PARTIAL_PART_WEIGHTS", dict.fromkeys(P.PARTIAL_PART_WEIGHTS, 1.0))
    np.testing.assert_allclose(partial_l2(query, stored, present),
                               weighted_l2(query, stored, present), rtol=1e-12)
    only = dict.fromkeys(P.PARTIAL_PART_WEIGHTS, 0.0) | {"d2": 1.0}
    monkeypatch.setattr(P, "PARTIAL_PART_WEIGHTS", only)
    sl = part_slices()["d2"]
    want = np.linalg.norm(stored["shape"][:, sl].astype(float) - query["shape"][sl], axis=1)
    np.testing.assert_allclose(partial_l2(query, stored, present), want, rtol=1e-6)


def test_partial_l2_refuses_other_shape_vectors():
    query, stored, present = _stored(np.random.default_rng(1))
    query["shape"] = query["shape"][:12]
    with pytest.raises(InputError, match="partial_l2 compares shape vectors of 278 values"):
        partial_l2(query, stored, present)
    with pytest.raises(InputError, match="shape_weight must be in"):
        partial_l2(*_stored(np.random.default_rng(1)), shape_weight=2.0)


def _grid(level=3):
    x = icosphere(level).vertices * np.array([1.0, 0.7, 0.5])
    return x


def test_describe_grid_of_the_real_surface_changes_only_the_measure_parts():
    level = 3
    x = _grid(level)
    virtual = x[:, 0] < -0.3
    full = describe_grid(x, level).vectors
    real = describe_grid(x, level, virtual=virtual).vectors
    again = describe_grid(x, level, virtual=virtual).vectors
    for k in full:
        np.testing.assert_array_equal(real[k], again[k])      # deterministic
    sl = part_slices()
    for name in ("spectral", "layers"):
        np.testing.assert_array_equal(full["shape"][sl[name]], real["shape"][sl[name]])
    for name in ("shells", "d2", "radial", "normals", "heat"):
        assert not np.allclose(full["shape"][sl[name]], real["shape"][sl[name]])
    np.testing.assert_array_equal(
        describe_grid(x, level, virtual=np.zeros(len(x), bool)).vectors["shape"], full["shape"])


def test_describe_grid_refuses_a_bad_virtual_mask():
    x = _grid(3)
    with pytest.raises(InputError, match="virtual mask covers every grid vertex"):
        describe_grid(x, 3, virtual=np.ones(len(x), bool))
    with pytest.raises(InputError, match="virtual"):
        describe_grid(x, 3, virtual=np.ones(7, bool))


@pytest.fixture(scope="module")
def capsule_db(tmp_path_factory):
    from surfidx.database import Database

    root = tmp_path_factory.mktemp("partial")
    v, f = capsule()
    models = root / "models"
    models.mkdir()
    write_off(models / "capsule.off", v, f)
    write_off(models / "ball.off", *capsule(length=0.2))
    write_off(models / "long.off", *capsule(length=5.0))
    db_path = root / "p.db"
    with Database(db_path) as db:
        db.ingest([models], workers=1)
    vv, ff = one_view(v, f)
    view = write_off(root / "view.off", vv, ff)
    return db_path, models / "capsule.off", view


def _distances(rows):
    return [(r["name"], r["distance"]) for r in rows]


@pytest.fixture
def spectral_only(monkeypatch):
    """Partial queries ranked by the spectral part alone, so that they rank differently."""
    from surfidx.describe import partial as P

    monkeypatch.setattr(P, "PARTIAL_PART_WEIGHTS",
                        dict.fromkeys(P.PARTIAL_PART_WEIGHTS, 0.0) | {"spectral": 1.0})


def test_query_detects_a_partial_scan_and_partial_forces_either_way(capsule_db, spectral_only):
    from surfidx.database import Database

    db_path, whole, view = capsule_db
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        with Database(db_path) as db:
            auto = db.query(str(view), k=3)
            as_partial = db.query(str(view), k=3, partial=True)
            as_complete = db.query(str(view), k=3, partial=False)
            again = db.query(str(view), k=3)
            complete = db.query(str(whole), k=3, include_self=True)
            complete_default = db.query(str(whole), k=3, include_self=True, partial=False)
            forced = db.query(str(whole), k=3, include_self=True, partial=True)
    assert _distances(auto) == _distances(as_partial) == _distances(again)
    assert _distances(auto) != _distances(as_complete)
    assert _distances(complete) == _distances(complete_default) != _distances(forced)
    assert complete[0]["name"] == "capsule" and set(auto[0]) == {"id", "name", "version",
                                                                 "source", "distance"}


def test_cli_query_partial_and_complete(capsule_db, spectral_only):
    import json

    from click.testing import CliRunner

    from surfidx.cli import cli

    db_path, whole, view = capsule_db
    run = CliRunner().invoke

    def results(*extra):
        r = run(cli, ["query", str(view), "--db", str(db_path), "-k", "2", "--json", *extra])
        assert r.exit_code == 0, r.output
        return [(row["name"], row["distance"]) for row in json.loads(r.stdout)["results"]]

    r = run(cli, ["query", str(view), "--db", str(db_path), "-k", "2"])
    assert r.exit_code == 0, r.output
    assert "compared as a partial scan" in r.output
    assert results() == results("--partial") != results("--complete")
    r = run(cli, ["query", str(whole), "--db", str(db_path), "-k", "2"])
    assert r.exit_code == 0 and "partial scan" not in r.output
