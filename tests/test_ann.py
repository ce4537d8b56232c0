"""The approximate index beside the database (surfidx.db.ann) and its use by surfidx.db.search: the
re-ranked candidates are the exact scan's top k, a stale or damaged index is repaired, removed
models never come back, a read-only query never writes the database."""

from __future__ import annotations

import json
import os

import numpy as np
import pytest
from click.testing import CliRunner

from surfidx.db import ann
from surfidx.errors import DatabaseError, InputError
from surfidx.database import Database
from surfidx.db.catalog import utc_now
from surfidx.db.search import SearchIndex

DIM, TEX = 40, 12


def rows(m, seed=0):
    """Clustered shape (m, DIM + 3) and texture (m, TEX) vectors, 60 % coloured."""
    rng = np.random.default_rng(seed)
    centres = rng.standard_normal((max(m // 25, 2), DIM + 3)) * 3
    tcent = rng.standard_normal((len(centres), TEX)) * 3
    sub = rng.integers(len(centres), size=m)
    shape = (centres[sub] + rng.standard_normal((m, DIM + 3))).astype(np.float32)
    tex = (tcent[sub] + rng.standard_normal((m, TEX))).astype(np.float32)
    return shape, tex, rng.random(m) < 0.6


def fill(db, shape, tex, color, *, start=1, conv="{}"):
    now = utc_now()
    ins = ("INSERT INTO descriptors (model_id, kind, dimension, vector, convention) "
           "VALUES (?, ?, ?, ?, ?)")
    with db.transaction():
        for j in range(len(shape)):
            i = start + j
            db.conn.execute(
                "INSERT INTO models (id, name, source, content_hash, n_surfels, has_color, "
                "bbox_min_x, bbox_min_y, bbox_min_z, bbox_max_x, bbox_max_y, bbox_max_z, "
                "ingested_at, params) VALUES (?, ?, ?, ?, 10, ?, 0, 0, 0, 1, 1, 1, ?, '{}')",
                (i, f"m{i}", f"/s/m{i}.ply", f"{i:064x}", int(color[j]), now))
            db.conn.execute("INSERT INTO thumbnails (model_id, png) VALUES (?, ?)", (i, b""))
            db.conn.execute(ins, (i, "shape", DIM, shape[j, :DIM].tobytes(), conv))
            db.conn.execute(ins, (i, "spectrum", 3, shape[j, DIM:].tobytes(), conv))
            if color[j]:
                db.conn.execute(ins, (i, "texture", TEX, tex[j].tobytes(), conv))
        db.descriptors_changed()


def query_of(shape, tex, i, *, colour):
    q = {"shape": shape[i, :DIM], "spectrum": shape[i, DIM:]}
    if colour:
        q["texture"] = tex[i]
    return q


@pytest.fixture
def big(tmp_path):
    path = tmp_path / "big.db"
    shape, tex, color = rows(1500)
    with Database(path) as db:
        fill(db, shape, tex, color)
    return path, shape, tex, color


def noisy(shape, tex, seed=1, n=24):
    rng = np.random.default_rng(seed)
    pick = rng.integers(len(shape), size=n)
    return ((shape[pick] + 0.5 * rng.standard_normal((n, shape.shape[1]))).astype(np.float32),
            (tex[pick] + 0.5 * rng.standard_normal((n, TEX))).astype(np.float32))


def test_reranked_candidates_are_the_exact_top_k(big):
    path, shape, tex, _ = big
    qs, qt = noisy(shape, tex)
    with Database(path, readonly=True) as db:
        exact = SearchIndex(db, exact=True)
        approx = SearchIndex(db, threshold=0)
        assert approx.approximate and not exact.approximate
        assert len(approx) == 1500
        for i in range(len(qs)):
            for colour in (False, True):
                for w in (0.7, 1.0, 0.2):
                    q = query_of(qs, qt, i, colour=colour)
                    ei, ed = exact.query(q, k=10, shape_weight=w)
                    ai, ad = approx.query(q, k=10, shape_weight=w)
                    assert ai.tolist() == ei.tolist()
                    np.testing.assert_allclose(ad, ed, rtol=1e-9)
        q = query_of(shape, tex, 7, colour=True)
        ai, _ = approx.query(q, k=5, exclude=[8])
        ei, _ = exact.query(q, k=5, exclude=[8])
        assert ai.tolist() == ei.tolist() and 8 not in ai.tolist()


def test_index_is_persisted_and_reused(big):
    path = big[0]
    d = ann.index_dir(path)
    with Database(path, readonly=True) as db:
        SearchIndex(db, threshold=0)
    man = json.loads((d / "manifest.json").read_text())
    assert set(man["graphs"]) == {"shape", "texture"} and ann.index_size(path) > 0
    assert man["kinds"] == ["shape", "spectrum", "texture"]
    with Database(path, readonly=True) as db:
        assert man["state"] == db.index_state()
        SearchIndex(db, threshold=0)
    assert json.loads((d / "manifest.json").read_text())["graphs"] == man["graphs"]  # not rebuilt


def test_same_rows_give_the_same_index_files(tmp_path):
    shape, tex, color = rows(600)
    digests = []
    for name in ("a.db", "b.db"):
        with Database(tmp_path / name) as db:
            fill(db, shape, tex, color)
            ann.build(db)
        d = ann.index_dir(tmp_path / name)
        man = json.loads((d / "manifest.json").read_text())
        digests.append((d / man["graphs"]["shape"]["file"]).read_bytes())
    assert digests[0] == digests[1]


def test_removed_model_never_appears(big):
    path, shape, tex, _ = big
    with Database(path, readonly=True) as db:
        SearchIndex(db, threshold=0)
    with Database(path) as db:
        db.delete(5)                       # close() updates the index
    with Database(path, readonly=True) as db:
        assert json.loads((ann.index_dir(path) / "manifest.json").read_text())["state"] \
            == db.index_state()
        ids, _ = SearchIndex(db, threshold=0).query(query_of(shape, tex, 4, colour=True), k=20)
        assert 5 not in ids.tolist()           # its own vector: it would be first


def test_stale_index_is_patched_after_a_crashed_writer(big):
    """A writer that died before updating the index (no close): the next query finds the state
    changed and patches the index from the stored rows (redescribed, removed, new models)."""
    path, shape, tex, color = big
    with Database(path, readonly=True) as db:
        SearchIndex(db, threshold=0)
    db = Database(path)
    new = np.full(DIM, 50.0, np.float32)
    db.set_descriptors(3, {"shape": new, "spectrum": np.zeros(3, np.float32)}, {})
    db.delete(9)
    s2, t2, c2 = rows(5, seed=7)
    fill(db, s2, t2, c2, start=2000)
    db._index_dirty = False                # as if the process was killed here
    db.close()
    with Database(path, readonly=True) as db:
        idx = SearchIndex(db, threshold=0)
        ids, d = idx.query({"shape": new, "spectrum": np.zeros(3, np.float32)}, k=3)
        assert ids[0] == 3 and d[0] == 0.0
        ids, _ = idx.query(query_of(shape, tex, 8, colour=False), k=30)
        assert 9 not in ids.tolist()
        ids, _ = idx.query(query_of(s2, t2, 2, colour=bool(c2[2])), k=1)
        assert ids[0] == 2002
        assert json.loads((ann.index_dir(path) / "manifest.json").read_text())["state"] \
            == db.index_state()


def test_state_change_without_row_changes_rewrites_only_the_manifest(big):
    """A new state whose rows all match their digests (here a bare generation bump, as a schema
    upgrade or an undone change): the same files under a manifest of the state now."""
    path, shape, tex, _ = big
    d = ann.index_dir(path)
    with Database(path, readonly=True) as db:
        before = SearchIndex(db, threshold=0).query(query_of(shape, tex, 7, colour=True), k=5)
    man = json.loads((d / "manifest.json").read_text())
    stamps = {f: (d / f).stat().st_mtime_ns for f in ann.index_files(man)}
    with Database(path) as db:
        db.descriptors_changed()
        db._index_dirty = False                # the next reader catches up
    with Database(path, readonly=True) as db:
        assert man["state"] != db.index_state()
        after = SearchIndex(db, threshold=0).query(query_of(shape, tex, 7, colour=True), k=5)
        now = json.loads((d / "manifest.json").read_text())
        assert now["state"] == db.index_state()
    assert {k: v for k, v in now.items() if k != "state"} == \
        {k: v for k, v in man.items() if k != "state"}
    assert {f: (d / f).stat().st_mtime_ns for f in ann.index_files(now)} == stamps
    assert sorted(p.name for p in d.iterdir()) == sorted([*stamps, "manifest.json"])
    np.testing.assert_array_equal(before[0], after[0])
    np.testing.assert_array_equal(before[1], after[1])


def test_changes_lists_gone_and_changed_models():
    gone, changed = ann.index_changes(np.array([1, 2, 3, 5], np.int64),
                                 np.array([10, 20, 30, 50], np.uint64),
                                 np.array([2, 3, 4, 5], np.int64),
                                 np.array([20, 31, 40, 50], np.uint64))
    assert gone == [1] and changed == [3, 4]
    gone, changed = ann.index_changes(np.zeros(0, np.int64), np.zeros(0, np.uint64),
                                 np.array([7], np.int64), np.array([1], np.uint64))
    assert gone == [] and changed == [7]


def test_mapped_index_searches_as_the_loaded_one(big):
    """Indexes opened for queries are memory-mapped read-only; their candidates are the loaded
    index's, and with every list probed the 40 candidates of a stored model hold its exact 10
    nearest by the shape vector."""
    path, shape, tex, _ = big
    with Database(path, readonly=True) as db:
        ann.open_index(db)
        index = ann.open_index(db)
        loaded, _ = ann.load_index(ann.index_dir(path), index.manifest, view=False)
        full = loaded["shape"]
        assert full.nlist == ann.list_count(1500) == 38
        full.nprobe = ann.DEFAULT_PROBES
        for i in (3, 700, 1499):
            v = shape[i]
            for n in (1, 10, 40):
                got = index.candidates("shape", v, n)
                np.testing.assert_array_equal(got, full.search(v[None], n)[1][0])
            every = index.candidates("shape", v, 40, probes=full.nlist)
            nearest = np.argsort(np.linalg.norm(shape - v, axis=1), kind="stable")[:10] + 1
            assert set(nearest.tolist()) <= set(every.tolist())
        assert index._graph("shape").ntotal == 1500


def test_index_file_not_matching_its_manifest_is_refused(big):
    path = big[0]
    with Database(path, readonly=True) as db:
        man = ann.open_index(db).manifest
    d = ann.index_dir(path)
    g = man["graphs"]["shape"]
    with pytest.raises(OSError, match="is not of its manifest's size"):
        ann.open_graph(d / g["file"], dict(g, bytes=g["bytes"] + 1), view=True)
    with pytest.raises(OSError, match="does not match its manifest"):
        ann.open_graph(d / g["file"], dict(g, count=g["count"] + 1), view=True)
    assert ann.open_graph(d / g["file"], g, view=False).ntotal == 1500


def test_list_count_follows_the_square_root():
    assert [ann.list_count(n) for n in (0, 1, 38, 39, 1500, 100_000, 1_000_000)] == \
        [1, 1, 1, 1, 38, 1265, 4000]


def test_crash_between_index_write_and_replace_keeps_a_working_index(big, monkeypatch):
    path, shape, tex, _ = big
    with Database(path, readonly=True) as db:
        SearchIndex(db, threshold=0)
    d = ann.index_dir(path)
    before = (d / "manifest.json").read_bytes()
    real_replace = os.replace

    def crash(src, dst):
        if str(dst).endswith("manifest.json"):
            raise OSError("killed")
        real_replace(src, dst)

    monkeypatch.setattr(ann.os, "replace", crash)
    with Database(path) as db:
        db.delete(11)                      # the update's manifest replace fails: old index kept
    monkeypatch.setattr(ann.os, "replace", real_replace)
    assert (d / "manifest.json").read_bytes() == before
    with Database(path, readonly=True) as db:
        exact = SearchIndex(db, exact=True)
        approx = SearchIndex(db, threshold=0)
        q = query_of(shape, tex, 10, colour=True)
        assert approx.query(q, k=10)[0].tolist() == exact.query(q, k=10)[0].tolist()
        assert 11 not in approx.query(q, k=10)[0].tolist()


def test_readonly_query_never_writes_the_database(big):
    path = big[0]
    before = path.read_bytes()
    with Database(path, readonly=True) as db:
        SearchIndex(db, threshold=0)
    assert path.read_bytes() == before and (ann.index_dir(path) / "manifest.json").exists()


def test_unwritable_index_folder_keeps_the_index_in_memory(big):
    path, shape, tex, _ = big
    ann.index_dir(path).write_text("not a folder")
    with Database(path, readonly=True) as db:
        idx = SearchIndex(db, threshold=0)
        assert idx.approximate
        assert idx.query(query_of(shape, tex, 0, colour=False), k=1)[0].tolist() == [1]
    assert ann.index_size(path) == 0


def test_damaged_index_file_is_rebuilt(big):
    path, shape, tex, _ = big
    with Database(path, readonly=True) as db:
        SearchIndex(db, threshold=0)
    d = ann.index_dir(path)
    man = json.loads((d / "manifest.json").read_text())
    (d / man["graphs"]["shape"]["file"]).write_bytes(b"garbage")
    with Database(path, readonly=True) as db:
        ids, _ = SearchIndex(db, threshold=0).query(query_of(shape, tex, 0, colour=False), k=1)
    assert ids.tolist() == [1]


@pytest.mark.parametrize("cut", [0.5, 0.999])
def test_truncated_index_file_is_rebuilt(big, cut):
    """A truncated index file is never mapped (its lists would point past the end): its size is
    not the manifest's, the index is rebuilt and answers as the exact scan."""
    path, shape, tex, _ = big
    with Database(path, readonly=True) as db:
        SearchIndex(db, threshold=0)
    d = ann.index_dir(path)
    man = json.loads((d / "manifest.json").read_text())
    f = d / man["graphs"]["shape"]["file"]
    data = f.read_bytes()
    f.write_bytes(data[:int(len(data) * cut)])
    with Database(path, readonly=True) as db:
        q = query_of(shape, tex, 5, colour=True)
        ids, _ = SearchIndex(db, threshold=0).query(q, k=5)
        assert ids.tolist() == SearchIndex(db, exact=True).query(q, k=5)[0].tolist()
    man2 = json.loads((d / "manifest.json").read_text())
    assert man2["graphs"]["shape"]["file"] != man["graphs"]["shape"]["file"]


def test_threshold_and_exact_choose_the_scan(big):
    with Database(big[0], readonly=True) as db:
        assert not SearchIndex(db).approximate            # 1500 < DEFAULT_THRESHOLD
        assert not SearchIndex(db, threshold=0, exact=True).approximate
        assert SearchIndex(db, threshold=1500).approximate


def test_mixed_descriptor_versions_are_refused(tmp_path):
    path = tmp_path / "mixed.db"
    shape, tex, color = rows(60)
    with Database(path) as db:
        fill(db, shape[:30], tex[:30], color[:30], conv='{"lmax": 24}')
        fill(db, shape[30:], tex[30:], color[30:], start=31, conv='{"lmax": 16}')
    with Database(path, readonly=True) as db:
        with pytest.raises(DatabaseError, match="different conventions"):
            SearchIndex(db, threshold=0)


def test_query_of_the_wrong_size_is_refused(big):
    with Database(big[0], readonly=True) as db:
        idx = SearchIndex(db, threshold=0)
        with pytest.raises(InputError, match="has 7 values but the stored ones have 40"):
            idx.query({"shape": np.zeros(7)}, k=3)
        with pytest.raises(InputError, match="no 'shape' descriptor"):
            idx.query({"spectrum": np.zeros(3)}, k=3)
        with pytest.raises(InputError, match="factor"):
            SearchIndex(db, threshold=0, factor=0)


def test_descriptor_rows_and_generation(big):
    path, shape, _, color = big
    with Database(path) as db:
        g = db.index_state()["generation"]
        db.descriptors_changed()
        assert db.index_state()["generation"] == g + 1
        ids, stored, present = db.descriptor_rows([3, 1, 99999, 3], ("shape", "texture"))
        assert ids.tolist() == [1, 3]
        np.testing.assert_array_equal(stored["shape"][1], shape[2, :DIM])
        assert present["texture"].tolist() == [bool(color[0]), bool(color[2])]


def test_cli_query_exact_and_approximate_agree(at_threshold):
    from surfidx.cli import cli

    path = at_threshold[0]
    runner = CliRunner()
    out = []
    for extra in ([], ["--exact"]):
        res = runner.invoke(cli, ["query", "id:12", "--db", str(path), "-k", "5", "--json",
                                  *extra])
        assert res.exit_code == 0, res.output
        out.append(json.loads(res.output)["results"])
    assert out[0] == out[1] and len(out[0]) == 5
    assert ann.index_size(path) > 0


# ---------------------------------------------------------------------- AnnIndex.query
from surfidx.describe.distance import DEFAULT_KINDS, weighted_l2  # noqa: E402


def ann_query(index, q, **kw):
    kw.setdefault("shape_weight", 0.7)
    return index.query(q, distance=weighted_l2, **kw)


def test_ann_query_on_row_copies_is_the_exact_top_k(big):
    path, shape, tex, _ = big
    qs, qt = noisy(shape, tex, seed=3)
    with Database(path, readonly=True) as db:
        exact = SearchIndex(db, exact=True)
        ann.open_index(db, kinds=DEFAULT_KINDS)             # built and written
        index = ann.open_index(db, kinds=DEFAULT_KINDS)     # memory-mapped
        for i in range(len(qs)):
            for colour in (False, True):
                for w in (0.7, 1.0, 0.0):
                    q = query_of(qs, qt, i, colour=colour)
                    ei, ed = exact.query(q, k=10, shape_weight=w)
                    ai, ad = ann_query(index, q, k=10, shape_weight=w, factor=4)
                    assert ai.tolist() == ei.tolist()
                    np.testing.assert_allclose(ad, ed, rtol=1e-9)
        q = query_of(shape, tex, 7, colour=True)
        ai, _ = ann_query(index, q, k=5, exclude=[8])
        assert ai.tolist() == exact.query(q, k=5, exclude=[8])[0].tolist()
        ids, stored, present = index.rows([3, 1, 99999, 3])
        rid, rstored, rpresent = db.descriptor_rows([3, 1, 99999, 3], DEFAULT_KINDS)
        assert ids.tolist() == rid.tolist() == [1, 3]
        for kind in DEFAULT_KINDS:
            np.testing.assert_array_equal(stored[kind], rstored[kind])
            assert present[kind].tolist() == rpresent[kind].tolist()
        copy = index._rows["shape"][1]              # a plain array over the mapped file
        assert type(copy) is np.ndarray and isinstance(copy.base, np.memmap)


def test_ann_query_follows_changes_made_after_it_was_opened(big):
    """Another connection removes and redescribes models and adds new ones without updating
    the index (a writer killed before close), then this connection's own changes: every query
    answers for the rows stored at its time."""
    path, shape, tex, color = big
    db = Database(path)
    try:
        index = ann.open_index(db, kinds=DEFAULT_KINDS)
        exact_before = SearchIndex(db, exact=True).query(query_of(shape, tex, 4, colour=True),
                                                         k=10)
        assert ann_query(index, query_of(shape, tex, 4, colour=True), k=10)[0].tolist() \
            == exact_before[0].tolist()
        other = Database(path)
        other.delete(5)
        new = np.full(DIM, 40.0, np.float32)
        other.set_descriptors(3, {"shape": new, "spectrum": np.zeros(3, np.float32)}, {})
        s2, t2, c2 = rows(4, seed=9)
        fill(other, s2, t2, c2, start=5000)
        other._index_dirty = False             # killed before its close updated the index
        other.close()
        ids, d = ann_query(index, {"shape": new, "spectrum": np.zeros(3, np.float32)}, k=2)
        assert ids[0] == 3 and d[0] == 0.0
        ids, _ = ann_query(index, query_of(shape, tex, 4, colour=True), k=20)
        assert 5 not in ids.tolist()
        ids, d = ann_query(index, query_of(s2, t2, 1, colour=bool(c2[1])), k=1)
        assert ids.tolist() == [5001] and d[0] == 0.0
        db.delete(5001)                        # this connection: the generation moves
        db.set_descriptors(7, {"shape": new + 1, "spectrum": np.zeros(3, np.float32)}, {})
        ids, _ = ann_query(index, query_of(s2, t2, 1, colour=bool(c2[1])), k=5)
        assert 5001 not in ids.tolist()
        ids, d = ann_query(index, {"shape": new + 1, "spectrum": np.zeros(3, np.float32)}, k=1)
        assert ids.tolist() == [7] and d[0] == 0.0
        exact = SearchIndex(db, exact=True)
        for i in range(0, 60, 7):
            q = query_of(shape, tex, i, colour=bool(i % 2))
            assert ann_query(index, q, k=10)[0].tolist() == exact.query(q, k=10)[0].tolist()
        assert index.state == db.index_state()
    finally:
        db.close()


def test_index_is_generic_over_the_search_kinds(big):
    """A search with a fourth kind: its graph holds it, its rows are copied, and a distance
    using it gets the exact top k; an index of other kinds is rebuilt for the search's."""
    path, shape, tex, _ = big
    rng = np.random.default_rng(5)
    layers = (shape[:, :6] * 2 + 0.1 * rng.standard_normal((len(shape), 6))).astype(np.float32)
    with Database(path) as db:
        with db.transaction():
            db.conn.executemany(
                "INSERT INTO descriptors (model_id, kind, dimension, vector, convention) "
                "VALUES (?, 'layers', 6, ?, '{}')",
                [(i + 1, layers[i].tobytes()) for i in range(0, len(shape), 2)])   # half
            db.descriptors_changed()
    kinds = ("shape", "spectrum", "texture", "layers")

    def with_layers(q, stored, present, *, shape_weight):
        d = weighted_l2(q, stored, present, shape_weight=shape_weight)
        if "layers" in q:
            dl = np.sqrt(((stored["layers"] - q["layers"]) ** 2).sum(1))
            d = d + np.where(present["layers"], dl, 0.0)
        return d

    with Database(path, readonly=True) as db:
        ann.open_index(db, kinds=DEFAULT_KINDS)
        index = ann.open_index(db, kinds=kinds)
        man = json.loads((ann.index_dir(path) / "manifest.json").read_text())
        assert man["kinds"] == list(kinds) and man["graphs"]["shape"]["ndim"] == DIM + 3 + 6
        assert man["graphs"]["shape"]["kinds"] == ["shape", "spectrum", "layers"]
        assert index.dims["layers"] == 6 and index._rows["layers"][0].size == 750
        full = SearchIndex(db, kinds=kinds, exact=True)
        for i in range(0, 40, 3):
            q = dict(query_of(shape, tex, i, colour=bool(i % 2)), layers=layers[i])
            ei, ed = full.query(q, k=10, distance=with_layers)
            ai, ad = index.query(q, k=10, distance=with_layers, shape_weight=0.7)
            assert ai.tolist() == ei.tolist()
            np.testing.assert_allclose(ad, ed, rtol=1e-6)
        again = ann.open_index(db)                # the kinds on disk
        assert again.kinds == kinds


def test_ann_query_and_kinds_errors(big):
    with Database(big[0], readonly=True) as db:
        index = ann.open_index(db, kinds=DEFAULT_KINDS)
        q = {"shape": np.zeros(DIM), "spectrum": np.zeros(3)}
        with pytest.raises(InputError, match="has 7 values but the stored ones have 40"):
            ann_query(index, {"shape": np.zeros(7)})
        with pytest.raises(InputError, match="no 'shape' descriptor"):
            ann_query(index, {"spectrum": np.zeros(3)})
        with pytest.raises(InputError, match="factor must be at least 1"):
            ann_query(index, q, factor=0)
        with pytest.raises(InputError, match="k must be at least 1"):
            ann_query(index, q, k=0)
        with pytest.raises(InputError, match=r"distance function returned shape \(3,\)"):
            index.query(q, distance=lambda *a, **kw: np.zeros(3), shape_weight=0.7)
        with pytest.raises(InputError, match="query vector of 'shape' has 5 values but the "
                                             "index holds 43"):
            index.candidates("shape", np.zeros(5), 10)
        with pytest.raises(InputError, match="distinct descriptor kinds"):
            ann.open_index(db, kinds=("shape", "shape"))
        with pytest.raises(InputError, match="distinct descriptor kinds"):
            ann.build(db, kinds=())
        with pytest.raises(InputError, match="cannot be 'texture'"):
            ann.build(db, kinds=("texture", "shape"))
    with pytest.raises(InputError, match="1100 values are too wide"):
        ann.row_digest(np.zeros((2, 1100), np.float32))


@pytest.mark.parametrize("scan_limit", [0, 10**9])
def test_filtered_ann_query_is_the_exact_top_k_of_the_allowed(big, scan_limit):
    """Inside the index (the others skipped while it scans, scan_limit 0) or all allowed
    ranked exactly: the exact scan's top k among the allowed models, whatever their share."""
    path, shape, tex, _ = big
    qs, qt = noisy(shape, tex, seed=5, n=12)
    rng = np.random.default_rng(9)
    with Database(path, readonly=True) as db:
        exact = SearchIndex(db, exact=True)
        index = ann.open_index(db, kinds=DEFAULT_KINDS)
        for share in (0.5, 0.05, 0.004):
            allowed = np.flatnonzero(rng.random(1500) < share) + 1
            for i in range(len(qs)):
                for colour in (False, True):
                    q = query_of(qs, qt, i, colour=colour)
                    ei, ed = exact.query(q, k=10, allowed=allowed)
                    ai, ad = ann_query(index, q, k=10, allowed=allowed, scan_limit=scan_limit)
                    assert set(ai.tolist()) <= set(allowed.tolist())
                    assert ai.size == min(10, allowed.size)
                    assert ai.tolist() == ei.tolist()
                    np.testing.assert_allclose(ad, ed, rtol=1e-9)
        q = query_of(shape, tex, 7, colour=True)
        ai, _ = ann_query(index, q, k=5, allowed=[8, 9, 1400], exclude=[8], scan_limit=0)
        assert sorted(ai.tolist()) == [9, 1400]
        assert ann_query(index, q, k=5, allowed=[], scan_limit=0)[0].size == 0
        assert ann_query(index, q, k=5, allowed=[99999], scan_limit=0)[0].size == 0


def test_exact_scan_takes_allowed_ids_as_a_filter(big):
    path, shape, tex, _ = big
    with Database(path, readonly=True) as db:
        exact = SearchIndex(db, exact=True)
        q = query_of(shape, tex, 3, colour=True)
        ids, d = exact.query(q, k=1500)
        allowed = np.arange(2, 1501, 7)
        keep = np.isin(ids, allowed)
        fi, fd = exact.query(q, k=30, allowed=allowed, exclude=[9])
        assert fi.tolist() == [i for i in ids[keep].tolist() if i != 9][:30]
        np.testing.assert_allclose(fd, d[keep][ids[keep] != 9][:30], rtol=1e-9)


# ---------------------------------------------------------------------- at the threshold
@pytest.fixture(scope="module")
def at_threshold(tmp_path_factory):
    """A database of DEFAULT_THRESHOLD models: the CLI's query uses the index by itself."""
    path = tmp_path_factory.mktemp("thr") / "thr.db"
    shape, tex, color = rows(ann.DEFAULT_THRESHOLD, seed=11)
    with Database(path) as db:
        fill(db, shape, tex, color)            # close() builds the index
    assert (ann.index_dir(path) / "manifest.json").exists()
    return path, shape, tex, color


def test_cli_query_by_id_imports_no_heavy_module(at_threshold):
    """``surfidx query id:N`` on a database using the index imports neither numba, scipy,
    trimesh, pyshtools nor sqlite-utils."""
    import subprocess
    import sys

    path = at_threshold[0]
    code = ("import sys, json\n"
            "from surfidx.cli import cli\n"
            f"cli.main(['query', 'id:12', '--db', {str(path)!r}, '-k', '3', '--json'], "
            "standalone_mode=False)\n"
            "heavy = {'numba', 'scipy', 'trimesh', 'pyshtools', 'sqlite_utils'}\n"
            "print(json.dumps(sorted({m.split('.')[0] for m in sys.modules} & heavy)))\n"
            "print(json.dumps(sorted(m for m in sys.modules if m.startswith('surfidx.cli.'))))\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         timeout=120, check=True).stdout.strip().splitlines()
    assert json.loads(out[-1]) == ["surfidx.cli.common", "surfidx.cli.db",
                                   "surfidx.cli.group"]      # no other command module
    out.pop()
    assert json.loads(out[-1]) == []
    assert len(json.loads("\n".join(out[:-1]))["results"]) == 3


def test_cli_queries_stay_exact_while_models_are_removed_and_redescribed(at_threshold, tmp_path):
    """The index beside a database at the threshold, changed by ``surfidx rm`` and by a
    redescribe through the library: every CLI query agrees with ``--exact``."""
    import shutil

    from surfidx.cli import cli

    src, shape, tex, color = at_threshold
    path = tmp_path / "thr.db"
    shutil.copy(src, path)
    shutil.copytree(ann.index_dir(src), ann.index_dir(path))
    runner = CliRunner()

    def both(ref):
        out = []
        for extra in ([], ["--exact"]):
            res = runner.invoke(cli, ["query", ref, "--db", str(path), "-k", "10", "--json",
                                      *extra])
            assert res.exit_code == 0, res.output
            out.append(json.loads(res.output)["results"])
        assert out[0] == out[1]
        return [r["id"] for r in out[0]]

    near = both("id:40")
    res = runner.invoke(cli, ["rm", f"id:{near[0]}", "--db", str(path)])
    assert res.exit_code == 0, res.output
    assert near[0] not in both("id:40")
    with Database(path) as db:                 # id 41 now holds id 40's descriptors
        db.set_descriptors(41, db.get_descriptors(40), {})
    got = both("id:40")
    assert got[0] == 41
    with Database(path, readonly=True) as db:
        assert json.loads((ann.index_dir(path) / "manifest.json").read_text())["state"] \
            == db.index_state()


def test_filtered_query_on_the_index_path_equals_the_exact_one(at_threshold):
    """At the threshold ``Database.query(where=)`` goes through the index (the passing models
    asked of it, or all ranked exactly when few pass) and gives ``exact=True``'s answer."""
    path, shape, tex, _ = at_threshold
    with Database(path, readonly=True) as db:
        assert db._approximate()
        for where in ("id > 3000", "id <= 400 and colour = true", "id = 77"):
            for ref in (12, 40, 5000):
                got = db.query(ref, k=10, where=where)
                want = db.query(ref, k=10, where=where, exact=True)
                assert [r["id"] for r in got] == [r["id"] for r in want]
                np.testing.assert_allclose([r["distance"] for r in got],
                                           [r["distance"] for r in want], rtol=1e-9)
        assert [r["id"] for r in db.query(12, k=3, where="id = 77")] == [77]


def test_cli_query_defaults_come_from_the_library():
    from surfidx.cli import cli
    from surfidx.describe.distance import DEFAULT_SHAPE_WEIGHT

    params = {p.name: p for p in cli.get_command(None, "query").params}
    assert params["shape_weight"].default == DEFAULT_SHAPE_WEIGHT
    assert f"{ann.DEFAULT_THRESHOLD:,}" in params["exact"].help


def test_graphs_are_opened_when_a_query_needs_them(big):
    path, shape, tex, _ = big
    with Database(path, readonly=True) as db:
        ann.open_index(db, kinds=DEFAULT_KINDS)
        index = ann.open_index(db, kinds=DEFAULT_KINDS)
        assert index._ix == {} and index.count == 1500
        ann_query(index, query_of(shape, tex, 0, colour=False), k=3)
        assert set(index._ix) == {"shape"}
        ann_query(index, query_of(shape, tex, 0, colour=True), k=3)
        assert set(index._ix) == {"shape", "texture"}


def test_cli_commands_are_imported_when_asked_for():
    """Every command is found by name through the group (its module imported then), the
    module map names each command's module, and listing the commands finds them all."""
    import click

    from surfidx.cli import COMMAND_MODULES, cli, load_all

    for name, module in COMMAND_MODULES.items():
        cmd = cli.get_command(None, name)
        assert cmd is not None and cmd.callback.__module__ == f"surfidx.cli.{module}", name
    load_all()
    assert set(cli.commands) == set(COMMAND_MODULES)
    with click.Context(cli) as ctx:
        assert cli.list_commands(ctx) == sorted(COMMAND_MODULES)
        assert cli.get_command(ctx, "no-such-command") is None
    res = CliRunner().invoke(cli, ["no-such-command"])
    assert res.exit_code == 2 and "No such command" in res.output


def test_database_query_keeps_its_index_and_follows_changes(at_threshold, tmp_path):
    """``surfidx.Database.query`` keeps the approximate search between queries (its graphs
    are opened once) and it follows the database's own changes: a removed model is gone, a
    redescribed one is found by its new rows, every answer as the exact scan's."""
    import shutil

    from surfidx.database import Database as Store

    src, shape, tex, color = at_threshold
    path = tmp_path / "thr.db"
    shutil.copy(src, path)
    shutil.copytree(ann.index_dir(src), ann.index_dir(path))
    with Store(path) as db:
        s2, t2, c2 = rows(1, seed=5)
        fill(db, s2, t2, c2, start=ann.DEFAULT_THRESHOLD + 1)   # one above: after a removal
        first = db.query("id:40", k=5)                           # still at the threshold
        kept = db._kept_search
        assert kept is not None and kept.approximate
        assert db.query("id:40", k=5) == first == db.query("id:40", k=5, exact=True)
        assert db._kept_search is kept
        db.remove(first[0]["id"])
        got = db.query("id:40", k=5)
        assert first[0]["id"] not in [r["id"] for r in got]
        assert got == db.query("id:40", k=5, exact=True)
        db.set_descriptors(41, db.get_descriptors(40), {})
        got = db.query("id:40", k=5)
        assert got[0]["id"] == 41 and got[0]["distance"] == 0.0
        assert got == db.query("id:40", k=5, exact=True)
        assert db._kept_search is kept
        db.remove(42)                              # below the threshold: the exact scan
        assert db.query("id:40", k=5) == db.query("id:40", k=5, exact=True)
        assert db._kept_search is None
