"""Every mesh goes in (issue 24, input side): surfidx.topology.read_model repairs what is not one
closed genus-0 piece into parts whose surfels carry the virtual patches; pipeline, database and
CLI take such models as they are; a closed genus-0 mesh reads exactly as before."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from conftest import icosphere_mesh, torus_mesh
from surfidx import InputError, TopologyError, TriangleMesh, read_surfels
from surfidx.describe import DescribeOptions
from surfidx.options import ProcessOptions
from surfidx.io import model_hash
from surfidx.topology import Model, join_surfels, read_model
from surfidx.topology import RepairOptions, close_surface, closed_mesh, patch_cuts

from helpers import moebius, sphere_with_holes, tetrahedron


def write_obj(path, v, f):
    lines = [f"v {a:.17g} {b:.17g} {c:.17g}" for a, b, c in v]
    lines += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in f]
    path.write_text("\n".join(lines) + "\n")
    return path


# ---------------------------------------------------------------------------- a sphere: unchanged
def test_sphere_reads_exactly_as_read_surfels(tmp_path):
    v, f = icosphere_mesh(3)
    p = write_obj(tmp_path / "ball.obj", v, f)
    m = read_model(p)
    s = read_surfels(p)
    assert isinstance(m, Model) and len(m.parts) == 1 and m.reports == (None,)
    assert not m.repaired and m.kind == "mesh" and m.topology.is_sphere
    assert m.parts[0].patch is None and m.surfels is m.parts[0]
    assert model_hash(m.parts[0]) == model_hash(s)
    mem = read_model((v, f))
    assert model_hash(mem.parts[0]) == model_hash(s)


# ---------------------------------------------------------------------------- repaired inputs
def _check_closed(s):
    topo = TriangleMesh(s.positions, s.faces).topology()
    assert topo.closed and topo.components == 1 and topo.genus == 0


def test_holes_are_filled_with_virtual_surfels(tmp_path):
    v, f = sphere_with_holes([0, 30, 60])
    p = write_obj(tmp_path / "holes.obj", v, f)
    m = read_model(p)
    assert m.repaired and len(m.parts) == 1
    s = m.parts[0]
    _check_closed(s)
    assert s.patch is not None and s.virtual.any()
    assert s.patch_cut.tolist() == [-1, -1, -1]
    # the real surfels are the scan's used vertices, in order; the virtual ones are new
    used = np.unique(f)
    assert np.array_equal(s.positions[~s.virtual][:len(used)], v[used])
    assert set(np.unique(s.patch[s.virtual])) == {0, 1, 2}
    summ = m.summary()
    assert summ["holes_filled"] == 3 and summ["handles_cut"] == 0 and summ["parts"] == 1
    assert 0 < summ["virtual_area_share"] < 0.2
    assert summ["virtual_surfels"] == int(s.virtual.sum())
    assert m.topology.holes == 3


def test_handle_is_cut_and_its_lids_pair():
    v, f = torus_mesh()
    m = read_model((v, f))
    s = m.parts[0]
    _check_closed(s)
    assert m.summary()["handles_cut"] == 1
    assert sorted(s.patch_cut.tolist()) == [0, 0]
    assert m.summary()["genus_before"] == [1]


def test_pinched_vertex_split_without_virtual_surfels():
    from helpers import pinched_sphere

    v, f = pinched_sphere()
    m = read_model((v, f))
    assert m.repaired and m.summary()["pinched_vertices"] == 1
    s = m.parts[0]
    assert s.patch is None                         # nothing added: no mask to code
    _check_closed(s)


def test_pieces_become_parts_tiny_ones_dropped_with_a_warning():
    v1, f1 = icosphere_mesh(3)
    v2, f2 = icosphere_mesh(2)
    vt, ft = tetrahedron((5, 5, 5))
    v = np.vstack([v1, v2 + 3.0, vt])
    f = np.vstack([f1, f2 + len(v1), ft + len(v1) + len(v2)])
    with pytest.warns(UserWarning, match=r"1 tiny pieces \(4 vertices"):
        m = read_model((v, f))
    assert len(m.parts) == 2 and m.parts_dropped == 1 and m.dropped_vertices == 4
    assert [len(p) for p in m.parts] == [len(v1), len(v2)]
    joined = m.surfels
    assert len(joined) == len(v1) + len(v2)
    assert joined.faces.max() == len(joined) - 1
    assert m.summary()["parts"] == 2 and m.summary()["parts_dropped"] == 1


def test_join_surfels_renumbers_patches_and_cuts():
    a = read_model(torus_mesh()).parts[0]
    b = read_model(sphere_with_holes([0])).parts[0]
    j = join_surfels([a, b, a])
    pa, pb = len(a.patch_cut), len(b.patch_cut)
    assert len(j.patch_cut) == 2 * pa + pb
    assert j.patch_cut.tolist() == a.patch_cut.tolist() + [-1] * pb + (a.patch_cut + 1).tolist()
    assert j.patch.max() == 2 * pa + pb - 1
    assert np.array_equal(j.virtual, np.concatenate([a.virtual, b.virtual, a.virtual]))
    with pytest.raises(InputError, match="at least one surfel set"):
        join_surfels([])


def test_colours_go_with_the_scan_and_fill_patches_smoothly():
    v, f = sphere_with_holes([0, 30])
    col = np.tile(np.array([[10, 200, 30]], np.uint8), (len(v), 1))
    col[v[:, 2] > 0] = (250, 0, 0)
    s = read_model((v, f, col)).parts[0]
    assert s.has_color
    used = np.unique(f)
    assert np.array_equal(s.colors[~s.virtual][:len(used)], col[used])
    vc = s.colors[s.virtual].astype(int)
    lo, hi = col.min(axis=0).astype(int), col.max(axis=0).astype(int)
    assert np.all((vc >= lo) & (vc <= hi))         # harmonic: within the rim's range


def test_textured_mesh_with_a_hole_keeps_texture_colours(tmp_path):
    v, f = sphere_with_holes([0])
    uv = (v[:, :2] + 1) / 2
    tex = np.zeros((8, 8, 3), np.uint8)
    tex[..., 0] = 255
    mesh = TriangleMesh(v, f, uv=uv, uv_faces=f, texture=tex)
    s = read_model(mesh).parts[0]
    assert s.has_color and np.all(s.colors[:, 0] == 255) and np.all(s.colors[:, 1:] == 0)


def test_errors_name_the_file_and_the_problem(tmp_path):
    v, f = moebius()
    p = write_obj(tmp_path / "strip.obj", v, f)
    with pytest.raises(TopologyError, match=r"strip\.obj: .*non-orientable"):
        read_model(p)
    p = write_obj(tmp_path / "flat.obj", np.eye(3), np.array([[0, 0, 1], [1, 2, 2]]))
    with pytest.raises(TopologyError, match=r"flat\.obj: .*no triangle at all"):
        read_model(p)
    # a non-orientable piece beside a good one: the message names the piece
    v1, f1 = icosphere_mesh(3)
    vm, fm = moebius(40)
    v = np.vstack([v1, vm + 5])
    f = np.vstack([f1, fm + len(v1)])
    p = write_obj(tmp_path / "two.obj", v, f)
    with pytest.raises(TopologyError, match=r"two\.obj: piece 2 of 2 .*non-orientable"):
        read_model(p)


def test_point_cloud_is_one_part_as_read_surfels(tmp_path):
    v, _ = icosphere_mesh(3)
    p = tmp_path / "pts.xyz"
    np.savetxt(p, v)
    m = read_model(p)
    assert m.kind == "points" and len(m.parts) == 1 and not m.repaired
    assert model_hash(m.parts[0]) == model_hash(read_surfels(p))
    assert read_model(v).kind == "points"


# ---------------------------------------------------------------------------- labels through
def test_face_patch_labels_through_bisection_and_sampling():
    # a long strip: faces 0, 1 real, 2, 3 virtual (patch 0); bisection splits the long edges
    v = np.array([[0, 0, 0], [10, 0, 0], [0, 1, 0], [10, 1, 0], [0, 2, 0], [10, 2, 0]], float)
    f = np.array([[0, 1, 3], [0, 3, 2], [2, 3, 5], [2, 5, 4]])
    mesh = TriangleMesh(v, f, face_patch=[-1, -1, 0, 0])
    assert mesh.vertex_patch().tolist() == [-1, -1, -1, -1, 0, 0]
    b = mesh.bisected(2.0)
    assert len(b.face_patch) == len(b.faces)
    vp = b.vertex_patch()
    new = np.arange(len(v), len(b.vertices))
    mid_y = b.vertices[new, 1]
    # midpoints inside the virtual half (y > 1) are virtual, those on the rim (y = 1) real
    assert np.all(vp[new][mid_y > 1.0 + 1e-9] == 0)
    assert np.all(vp[new][np.abs(mid_y - 1.0) < 1e-9] == -1)
    assert np.all(vp[new][mid_y < 1.0 - 1e-9] == -1)
    s = mesh.to_surfels(samples=200)
    assert s.patch is not None and set(np.unique(s.patch)) <= {-1, 0}
    assert np.all(s.positions[s.patch == 0, 1] >= 1.0 - 1e-9)


def test_face_patch_is_checked():
    v, f = tetrahedron()
    with pytest.raises(InputError, match="face_patch labels must be -1"):
        TriangleMesh(v, f, face_patch=[-2, 0, 0, 0])
    with pytest.raises(InputError, match="patch_cut was given without face_patch"):
        TriangleMesh(v, f, patch_cut=[0, 0])


def test_patch_cuts_pair_the_lids():
    cs = close_surface(*torus_mesh())
    cuts = patch_cuts(cs)
    assert sorted(cuts.tolist()) == [0, 0]
    cm = closed_mesh(cs)
    assert cm.patch_cut.tolist() == cuts.tolist()
    assert closed_mesh(close_surface(*icosphere_mesh(2))).face_patch is None


def test_options_reach_the_repair():
    v1, f1 = icosphere_mesh(3)
    v2, f2 = icosphere_mesh(1)
    v = np.vstack([v1, v2 + 3.0])
    f = np.vstack([f1, f2 + len(v1)])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        m = read_model((v, f), options=RepairOptions(min_part_vertices=10, min_part_share=0.0))
    assert len(m.parts) == 2


# ---------------------------------------------------------------------------- today's streams
@pytest.mark.slow
def test_bundled_example_gives_todays_surfels_and_stream():
    """spot (closed genus 0): the surfels of surfidx before read_model (hash measured at
    ba6312e with read_surfels) and its 2 b/s stream (re-measured when a change of the map, the
    nested-dissection factorisation, Newton steps of the centring, the map that embeds every
    level, its relaxation sweeps (map version 3) and their stop on the energy's fall (map
    version 4), changed every map; and when colour got its own grid and pass schedule, format
    version 5)."""
    import hashlib
    from pathlib import Path

    from surfidx.codec import Encoder

    spot = Path(__file__).resolve().parents[1] / "examples" / "models" / "spot"
    m = read_model(spot / "spot_triangulated.obj", texture=spot / "spot_texture.png")
    assert not m.repaired and len(m.parts) == 1
    assert model_hash(m.parts[0]) == \
        "9b0881e4292e36705768e92f816306117c948fd8fbfb421be74cf61a79614a89"
    stream = Encoder(m.parts[0]).encode(2.0)
    assert hashlib.sha256(stream).hexdigest() == \
        "7e610000d5009adc1ce31485e38526853be17afa115915b6a2a834e4611705f6"


# ---------------------------------------------------------------------------- pipeline, store
@pytest.fixture(scope="module")
def torus_processed():
    from surfidx.pipeline import process_model

    v, f = torus_mesh(nu=30, nv=12)
    return process_model((v, f), bits_per_surfel=4.0, name="ring")


def test_process_model_takes_a_torus(torus_processed):
    p = torus_processed
    assert p.topology is not None and p.topology["handles_cut"] == 1
    assert p.topology["parts"] == 1 and 0 < p.topology["virtual_area_share"] < 0.5
    assert "topology" not in p.params
    assert p.n_surfels > 360 and p.quality["psnr_d2"] > 20


def test_describe_model_equals_process_model(torus_processed):
    from surfidx.pipeline import describe_model

    d = describe_model(torus_mesh(nu=30, nv=12), name="ring")
    assert d.topology == torus_processed.topology
    for k, vec in torus_processed.descriptors.items():
        assert np.array_equal(d.descriptors.vectors[k], vec)


def test_a_query_map_describes_the_model_near_its_stored_descriptors(torus_processed):
    from surfidx.describe import weighted_l2
    from surfidx.pipeline import describe_model
    from surfidx.sphere import MapOptions

    quick = describe_model(torus_mesh(nu=30, nv=12), name="ring", for_query=True)
    other = describe_model(torus_mesh(nu=30, nv=12, r=0.15), name="thin", for_query=True)
    stored = {k: np.asarray(v)[None] for k, v in torus_processed.descriptors.items()}
    present = {k: np.ones(1, bool) for k in stored}

    def dist(d):
        return float(weighted_l2(dict(d.descriptors.vectors), stored, present)[0])

    # fewer balancing steps: other bits, but far nearer its own stored model than another shape
    assert not np.array_equal(quick.descriptors.vectors["shape"],
                              torus_processed.descriptors["shape"])
    assert dist(quick) < 0.1 * dist(other)
    # a query's grid is at most DescribeOptions.query_level, unless a level is asked for
    assert describe_model(torus_mesh(nu=30, nv=12), for_query=True,
                          options=ProcessOptions(describe=DescribeOptions(query_level=2))
                          ).grid_level == 2
    assert describe_model(torus_mesh(nu=30, nv=12), for_query=True, level=3,
                          options=ProcessOptions(describe=DescribeOptions(query_level=2))
                          ).grid_level == 3
    with pytest.raises(InputError, match=r"DescribeOptions\.query_level must be"):
        DescribeOptions(query_level=10)
    q = MapOptions(final_steps=7, query_final_steps=3).for_query()
    assert (q.final_steps, q.final_steps_large) == (3, MapOptions().query_final_steps_large)
    with pytest.raises(InputError,
                       match=r"MapOptions\.query_final_steps must be an integer >= 0, got -1"):
        MapOptions(query_final_steps=-1)


def test_database_records_what_was_added(tmp_path, torus_processed):
    from surfidx.database import Database

    with Database(tmp_path / "t.db") as db:
        mid = db.add(torus_processed)
        rec = db.get_model(mid)
        t = rec["topology"]
        assert t["handles_cut"] == 1 and t["parts"] == 1 and t["genus_before"] == [1]
        assert t["virtual_area_share"] == pytest.approx(
            torus_processed.topology["virtual_area_share"])
        db.delete(mid)
        assert db.conn.execute("SELECT count(*) FROM model_topology").fetchone()[0] == 0


def test_database_refuses_a_bad_topology_record(tmp_path, torus_processed):
    import dataclasses

    from surfidx.database import Database

    with Database(tmp_path / "t.db") as db:
        bad = dataclasses.replace(torus_processed, topology=dict(torus_processed.topology,
                                                                 virtual_area_share=2.0))
        with pytest.raises(InputError, match=r"topology\['virtual_area_share'\] = 2.0 is out"):
            db.add(bad)
        bad = dataclasses.replace(torus_processed, topology=dict(torus_processed.topology,
                                                                 parts="many"))
        with pytest.raises(InputError, match=r"topology\['parts'\] must be a number"):
            db.add(bad)
        with pytest.raises(InputError, match="topology must be a dict or None"):
            db.add(dataclasses.replace(torus_processed, topology=[1]))


def test_combine_descriptors():
    from surfidx.describe.descriptors import DescriptorSet
    from surfidx.pipeline import combine_descriptors

    a = DescriptorSet({"shape": np.array([1.0, 0.0], np.float32),
                       "texture": np.array([1.0], np.float32)}, {"lmax": 24})
    b = DescriptorSet({"shape": np.array([0.0, 1.0], np.float32)}, {"lmax": 24})
    assert combine_descriptors([a], [5]) is a
    c = combine_descriptors([a, b], [3, 1])
    assert np.allclose(c.vectors["shape"], [0.75, 0.25])
    assert np.allclose(c.vectors["texture"], [1.0]) and c.params == {"lmax": 24, "parts": 2}
    with pytest.raises(InputError, match="one weight per descriptor set"):
        combine_descriptors([a, b], [1])
    with pytest.raises(InputError, match="weights must be positive"):
        combine_descriptors([a, b], [1, 0])
    with pytest.raises(InputError, match="different conventions"):
        combine_descriptors([a, DescriptorSet(b.vectors, {"lmax": 12})], [1, 1])


# ---------------------------------------------------------------------------- CLI
def test_cli_info_reports_what_the_repair_would_add(tmp_path):
    import json

    from click.testing import CliRunner

    from surfidx.cli import cli

    v, f = torus_mesh()
    keep = np.ones(len(f), bool)
    keep[:2] = False                              # one hole as well
    p = write_obj(tmp_path / "ring.obj", v, f[keep])
    r = CliRunner().invoke(cli, ["info", str(p), "--json"])
    assert r.exit_code == 0, r.output
    out = json.loads(r.output)
    assert out["holes"] == 1 and out["piece_genus"] == [1] and out["pieces"] == 1
    assert out["repair_handles_cut"] == 1 and out["repair_holes_filled"] == 1
    assert out["repair_patches"] == 3 and not out["stored_as_read"] and out["storable"]
    r = CliRunner().invoke(cli, ["info", str(p)])
    assert "repair_handles_cut     1" in r.output
    vm, fm = moebius(40)
    p = write_obj(tmp_path / "strip.obj", vm, fm)
    out = json.loads(CliRunner().invoke(cli, ["info", str(p), "--json"]).output)
    assert out["orientable"] is False and out["storable"] is False


def test_cli_show_prints_the_topology_record(tmp_path, torus_processed):
    from click.testing import CliRunner

    from surfidx.cli import cli
    from surfidx.database import Database

    path = tmp_path / "t.db"
    with Database(path) as db:
        db.add(torus_processed)
    r = CliRunner().invoke(cli, ["show", "ring", "--db", str(path)])
    assert r.exit_code == 0, r.output
    line = [ln for ln in r.output.splitlines() if ln.startswith("topology")][0]
    assert "1 part;" in line and "handles cut 1" in line and "% of the area" in line


def test_cli_info_of_a_stream_shows_its_parts_and_mask(tmp_path, torus_processed):
    import json

    from click.testing import CliRunner

    from surfidx.cli import cli

    sfz = tmp_path / "ring.sfz"
    sfz.write_bytes(torus_processed.stream)
    out = json.loads(CliRunner().invoke(cli, ["info", str(sfz), "--json"]).output)
    assert out["parts"] == 1 and out["cuts"] == 1 and out["holes"] == 0
    assert 0 < out["mask_share"] < 1 and 0 < out["virtual_share"] < 1
    assert out["input_surfels"] == torus_processed.n_surfels


def test_topology_line():
    from surfidx.cli.db import topology_line

    assert topology_line(None).startswith("stored as read")
    t = topology_line({"parts": 2, "parts_dropped": 3, "holes_filled": 4,
                       "virtual_area_share": 0.25, "virtual_surfels": 9})
    assert t.startswith("2 parts (3 tiny dropped); holes filled 4") and "25.00 %" in t


def test_ingest_records_an_unstorable_file_and_goes_on(tmp_path):
    import ingest
    from surfidx.database import Database

    vm, fm = moebius(40)
    write_obj(tmp_path / "strip.obj", vm, fm)
    write_obj(tmp_path / "flat.obj", np.eye(3), np.array([[0, 0, 1], [1, 2, 2]]))
    s = ingest.run([tmp_path], db=tmp_path / "u.db", progress=False, workers=1)
    assert (s.stored, s.failed) == (0, 2)
    errors = dict(s.errors)
    assert "non-orientable" in errors[str(tmp_path / "strip.obj")]
    assert "zero surface area" in errors[str(tmp_path / "flat.obj")] or \
        "no triangle" in errors[str(tmp_path / "flat.obj")]
    with Database(tmp_path / "u.db") as d:
        assert len(d.errors()) == 2


def test_cli_query_of_an_unstorable_file_is_one_line(tmp_path):
    from click.testing import CliRunner

    from surfidx.cli import cli
    from surfidx.database import Database

    vm, fm = moebius(40)
    p = write_obj(tmp_path / "strip.obj", vm, fm)
    with Database(tmp_path / "q.db"):
        pass
    r = CliRunner().invoke(cli, ["query", str(p), "--db", str(tmp_path / "q.db")])
    assert r.exit_code != 0
    assert "Traceback" not in r.output and "strip.obj" in r.output
    assert "non-orientable" in r.output
