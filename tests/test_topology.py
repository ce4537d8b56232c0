"""Topology repair (surfidx.topology): every open, pinched, genus > 0 or multi-piece mesh becomes
closed genus-0 pieces; the scan stays as it was, the additions are flagged.

Closedness, manifoldness, orientation, genus and pieces of every result are counted here
independently of the package (``TriangleMesh.topology`` and the directed edges)."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from conftest import icosphere_mesh, torus_mesh
from helpers import moebius, pinched_sphere, sphere_with_holes, tetrahedron, voxel_plate
from surfidx import InputError, TopologyError, TriangleMesh, read_mesh
from surfidx.topology import (ClosedSurface, RepairOptions, analyse, close_surface,
                              split_parts)
from surfidx.topology.analysis import boundary_loops

# ---------------------------------------------------------------------------- synthetic models


def capped_sphere(z=0.4, level=4):
    """An icosphere without its cap above ``z``: one large hole."""
    v, f = icosphere_mesh(level)
    return v, f[~(v[f][:, :, 2] > z).any(axis=1)]


def square_disk(k=10):
    x, y = np.meshgrid(np.arange(k + 1), np.arange(k + 1), indexing="ij")
    v = np.c_[x.ravel(), y.ravel(), np.zeros(x.size)].astype(float)
    i, j = np.meshgrid(np.arange(k), np.arange(k), indexing="ij")
    a = (i * (k + 1) + j).ravel()
    f = np.concatenate([np.stack([a, a + k + 1, a + k + 2], 1), np.stack([a, a + k + 2, a + 1], 1)])
    return v, f


# ---------------------------------------------------------------------------- independent checks


def assert_sphere(cs: ClosedSurface):
    """One closed, manifold, consistently wound genus-0 piece, counted independently."""
    v, f = cs.vertices, cs.faces
    topo = TriangleMesh(v, f).topology()
    assert topo.closed and topo.components == 1 and topo.nonmanifold_vertices == 0
    assert topo.euler == 2 and topo.genus == 0
    n = len(v)
    directed = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    key = directed[:, 0] * n + directed[:, 1]
    assert len(np.unique(key)) == len(key)             # every edge once each way
    twin = directed[:, 1] * n + directed[:, 0]
    assert np.isin(twin, key).all()
    # every used vertex's faces form one fan (a closed manifold): faces around v == edges at v
    used = np.unique(f)
    assert np.bincount(f.ravel(), minlength=n)[used].min() >= 3


def assert_records(cs: ClosedSurface, v, f):
    """The scan first and unchanged, the additions flagged exactly."""
    n0 = len(v)
    assert np.array_equal(cs.vertices[:n0], v)
    real_v = ~cs.virtual_vertices
    assert np.array_equal(cs.vertex_origin >= 0, real_v)
    assert not cs.virtual_vertices[:n0].any()
    assert np.array_equal(cs.vertices[real_v], v[cs.vertex_origin[real_v]])
    m = int((~cs.virtual_faces).sum())
    assert not cs.virtual_faces[:m].any() and cs.virtual_faces[m:].all()
    assert np.array_equal(cs.face_origin >= 0, ~cs.virtual_faces)
    # the real faces are the input's, in order: same vertices (through the origin), same winding
    # unless flipped
    back = cs.vertex_origin[cs.faces[:m]]
    orig = f[cs.face_origin[:m]]
    orig = np.where(cs.flipped[:m, None], orig[:, [0, 2, 1]], orig)
    assert np.array_equal(back, orig)
    assert np.all(np.diff(cs.face_origin[:m]) > 0)
    # every virtual face has a virtual corner or spans a hole (all corners on rims)
    assert np.array_equal(cs.patch >= 0, cs.virtual_faces)
    assert cs.report.virtual_vertices == int(cs.virtual_vertices.sum())
    assert cs.report.virtual_faces == int(cs.virtual_faces.sum())


def face_normals(v, f):
    n = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    return n / np.linalg.norm(n, axis=1)[:, None]


def rim_agreement(cs: ClosedSurface):
    """Cosines between the normals of the faces across every edge between a scan face and a
    patch face, and across every edge between two patch faces."""
    f, n = cs.faces, len(cs.vertices)
    nrm = face_normals(cs.vertices, f)
    directed = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    face = np.tile(np.arange(len(f)), 3)
    key = directed[:, 0] * n + directed[:, 1]
    order = np.argsort(key)
    twin = order[np.searchsorted(key[order], directed[:, 1] * n + directed[:, 0])]
    a, b = face, face[twin]
    rim = cs.virtual_faces[a] & ~cs.virtual_faces[b]
    inner = cs.virtual_faces[a] & cs.virtual_faces[b]
    cos = np.einsum("ij,ij->i", nrm[a], nrm[b])
    return cos[rim], cos[inner]


def reglued(cs: ClosedSurface):
    """The scan faces with every copy merged back onto its original vertex."""
    m = int((~cs.virtual_faces).sum())
    return cs.vertex_origin[cs.faces[:m]]


def same(a: ClosedSurface, b: ClosedSurface) -> bool:
    arrays = ("vertices", "faces", "virtual_vertices", "virtual_faces", "vertex_origin",
              "face_origin", "flipped", "patch")
    return all(getattr(a, k).tobytes() == getattr(b, k).tobytes() for k in arrays) and \
        all(x.vertices.tobytes() == y.vertices.tobytes()
            and x.copies.tobytes() == y.copies.tobytes()
            for x, y in zip(a.cuts, b.cuts)) and a.report == b.report


# ---------------------------------------------------------------------------- analysis


def test_analyse_counts_holes_genus_pieces_pinches():
    v, f = sphere_with_holes([0, 3, 7])
    r = analyse(v, f)
    assert (r.holes, r.hole_sizes, r.genus, r.parts, r.closed) == (3, (5, 5, 5), (0,), 1, False)
    assert not r.is_sphere and r.patches == 3
    v, f = torus_mesh()
    r = analyse(v, f)
    assert (r.holes, r.genus, r.handles, r.closed, r.euler) == (0, (1,), 1, True, 0)
    assert r.patches == 2
    v, f = voxel_plate(5, [(1, 1), (3, 1)])
    assert analyse(v, f).genus == (2,)
    v, f = icosphere_mesh(2)
    r = analyse(v, f)
    assert r.is_sphere and r.as_dict()["is_sphere"]
    # two tetrahedra sharing a vertex: one component by vertices, two pieces, one pinch
    v1, f1 = tetrahedron()
    v2, f2 = tetrahedron((-1, -1, -1))
    v = np.vstack([v1, v2[:3]])
    f = np.vstack([f1, np.where(f2 == 3, 0, f2 + 4)])
    r = analyse(v, f, options=RepairOptions(min_part_vertices=1))
    assert (r.components, r.parts, r.pinched_vertices, r.closed) == (1, 2, 1, False)
    assert r.genus == (0, 0)


def test_analyse_non_orientable_piece():
    v, f = moebius()
    r = analyse(v, f)
    assert not r.orientable and r.genus == (-1,) and r.holes == 1


# ---------------------------------------------------------------------------- holes


@pytest.mark.parametrize("centres", [[0], [0, 3, 7], [0, 3, 7, 8, 10]])
def test_sphere_with_holes_closes_fair(centres):
    v, f = sphere_with_holes(centres)
    cs = close_surface(v, f)
    assert_sphere(cs)
    assert_records(cs, v, f)
    assert np.array_equal(cs.faces[:len(f)], f)         # nothing split or flipped
    assert cs.report.holes_filled == len(centres) and cs.report.handles_cut == 0
    rim, inner = rim_agreement(cs)
    assert rim.min() > 0.5 and (inner.min() > 0.5 if len(inner) else True)
    # the patch lies where the removed star was: its new vertices near the unit sphere
    if cs.virtual_vertices.any():
        r = np.linalg.norm(cs.vertices[cs.virtual_vertices], axis=1)
        assert np.all(np.abs(r - 1) < 0.05)


@pytest.mark.parametrize("dp_max_loop", [300, 20])   # dynamic programme, chord splitting
def test_large_hole_is_refined_and_faired(dp_max_loop):
    v, f = capped_sphere()
    loop = boundary_loops(f, len(v))[0]
    # the default vertex budget bounds the patch (a cap of 76 rim vertices)
    small = close_surface(v, f, options=RepairOptions(dp_max_loop=dp_max_loop))
    assert_sphere(small)
    assert small.report.virtual_vertices <= 2 * (2 * len(loop) + 200)
    options = RepairOptions(dp_max_loop=dp_max_loop, patch_vertex_factor=100.0)
    cs = close_surface(v, f, options=options)
    assert_sphere(cs)
    assert_records(cs, v, f)
    rim_edge = np.linalg.norm(v[loop] - v[np.roll(loop, -1)], axis=1).mean()
    pf = cs.faces[cs.virtual_faces]
    e = np.linalg.norm(cs.vertices[pf] - cs.vertices[np.roll(pf, -1, axis=1)], axis=2)
    assert e.max() <= 3 * rim_edge                        # refined to the rim's edge length
    assert cs.report.virtual_vertices > 10
    rim, inner = rim_agreement(cs)
    assert rim.min() > 0 and inner.min() > 0              # no fold at the rim or inside
    # the cap bulges out like the sphere it replaces (bi-Laplacian: tangents continue)
    top = cs.vertices[cs.virtual_vertices][:, 2].max()
    assert top > 0.6


def test_disk_closes_without_internal_folds():
    v, f = square_disk()
    cs = close_surface(v, f)
    assert_sphere(cs)
    assert_records(cs, v, f)
    _, inner = rim_agreement(cs)
    assert inner.min() > 0
    # the patch is the disk's back: every patch face turns away from the disk's normal (+z)
    nz = face_normals(cs.vertices, cs.faces[cs.virtual_faces])[:, 2]
    assert np.all(nz < 0)


def test_closed_sphere_is_unchanged():
    v, f = icosphere_mesh(3)
    cs = close_surface(v, f)
    assert np.array_equal(cs.vertices, v) and np.array_equal(cs.faces, f)
    assert not cs.virtual_vertices.any() and not cs.virtual_faces.any() and not cs.cuts
    assert cs.report.virtual_area_share == 0


def test_inconsistent_winding_is_flipped():
    v, f = sphere_with_holes([0])
    f = f.copy()
    bad = np.arange(0, len(f), 7)
    f[bad] = f[bad][:, [0, 2, 1]]
    cs = close_surface(v, f)
    assert_sphere(cs)
    assert_records(cs, v, f)
    assert cs.report.flipped_faces == len(bad)
    assert np.array_equal(np.flatnonzero(cs.flipped), bad)


# ---------------------------------------------------------------------------- handles


@pytest.mark.parametrize("make,genus", [(torus_mesh, 1),
                                        (lambda: voxel_plate(5, [(1, 1), (3, 1)]), 2),
                                        (lambda: voxel_plate(7, [(1, 1), (3, 1), (5, 1)]), 3)])
def test_handles_are_cut_and_reglue(make, genus):
    v, f = make()
    cs = close_surface(v, f)
    assert_sphere(cs)
    assert_records(cs, v, f)
    assert cs.report.handles_cut == genus and cs.report.genus_before == genus
    assert len(cs.cuts) == genus
    for cut in cs.cuts:
        assert len(cut.vertices) == len(cut.copies) >= 3
        assert np.array_equal(cs.vertices[cut.vertices], cs.vertices[cut.copies])
        assert np.array_equal(cs.vertex_origin[cut.copies], cs.vertex_origin[cut.vertices])
    # merging the copies and dropping the patches gives the input's topology back
    topo = TriangleMesh(v, reglued(cs)).topology()
    assert topo.closed and topo.genus == genus
    assert np.array_equal(np.sort(reglued(cs), axis=None), np.sort(f, axis=None))


def test_torus_cut_is_a_meridian():
    v, f = torus_mesh()
    cs = close_surface(v, f)
    # the shortest non-separating cycle goes round the tube (16 vertices, about 2 pi r)
    assert len(cs.cuts[0].vertices) == 16
    assert cs.report.cut_lengths[0] < 2 * np.pi * 0.7 * 1.1
    # its two lids are membranes across the tube: flat, square to the tube's wall at the rim
    rim, inner = rim_agreement(cs)
    assert np.abs(rim).max() < 0.3 and inner.min() > 0.9


def warped_torus(nu=24, nv=24, warp=0.3, waves=3, cluster=0.8):
    """A genus-1 mesh like ``torus_mesh`` (R 2, r 0.7) whose meridian rings are bent out of their
    planes (``warp`` radians of longitude times ``sin(waves w)``) and whose ring vertices bunch
    (``cluster``: spacing from ``1 - cluster`` to ``1 + cluster`` times the mean), as the handle
    of retrieval model d067 (a vase) is round its cut."""
    R, r = 2.0, 0.7
    t = np.arange(nv) / nv
    w = 2 * np.pi * t + cluster * np.sin(2 * np.pi * t)
    U, W = np.meshgrid(2 * np.pi * np.arange(nu) / nu, w, indexing="ij")
    U = U + warp * np.sin(waves * W)
    v = np.stack([(R + r * np.cos(W)) * np.cos(U), (R + r * np.cos(W)) * np.sin(U),
                  r * np.sin(W)], -1).reshape(-1, 3)
    _, f = torus_mesh(nu=nu, nv=nv)
    return v, f


def test_bent_cut_lids_have_no_degenerate_face():
    # the lids of a bent cut, faired as membranes only after the bi-Laplacian's flips, squeezed
    # clusters of their vertices to a point (12 faces of zero area here, 10 on d067), which
    # to_surfels drops: the surfels' surface was open again
    v, f = warped_torus()
    cs = close_surface(v, f)
    assert_sphere(cs)
    assert cs.report.handles_cut == 1
    mesh = TriangleMesh(cs.vertices, cs.faces)
    assert mesh.nondegenerate_faces().all()
    with warnings.catch_warnings():
        warnings.simplefilter("error")      # no "degenerate faces dropped" warning
        mesh.to_surfels()
    topo = TriangleMesh(v, reglued(cs)).topology()
    assert topo.closed and topo.genus == 1


def test_handle_and_holes_together():
    v, f = torus_mesh(nu=48, nv=20)
    # two holes: stars of two vertices on the outer equator
    f = f[~np.isin(f, [0, 24 * 20]).any(axis=1)]
    cs = close_surface(v, f)
    assert_sphere(cs)
    assert_records(cs, v, f)
    assert cs.report.holes_filled == 2 and cs.report.handles_cut == 1
    topo = TriangleMesh(v, reglued(cs)).topology()
    assert topo.boundary_edges == 12 and topo.euler == -2    # torus with two holes again


# ---------------------------------------------------------------------------- pinches, pieces


def test_pinched_vertex_is_split():
    v, f = pinched_sphere()
    r = analyse(v, f)
    assert r.pinched_vertices == 1 and r.parts == 1 and not r.closed
    cs = close_surface(v, f)
    assert_sphere(cs)
    assert_records(cs, v, f)
    assert cs.report.pinched_vertices == 1 and cs.report.duplicated_vertices == 1
    assert cs.vertex_origin[len(v)] == 0
    assert not cs.virtual_faces.any()                     # splitting alone closed it


def test_two_tetrahedra_sharing_a_vertex_are_two_parts():
    v1, f1 = tetrahedron()
    v2, f2 = tetrahedron((-1, -1, -1))
    v = np.vstack([v1, v2[:3]])
    f = np.vstack([f1, np.where(f2 == 3, 0, f2 + 4)])
    with pytest.raises(TopologyError, match="falls apart into 2 pieces.*split_parts"):
        close_surface(v, f)
    parts = split_parts(v, f, options=RepairOptions(min_part_vertices=1))
    assert len(parts.parts) == 2 and parts.dropped == 0
    for p in parts.parts:
        assert p.vertex_index[0] == 0 or 0 in p.vertex_index
        assert_sphere(close_surface(p.vertices, p.faces))
        assert np.array_equal(p.vertices, v[p.vertex_index])
        assert np.array_equal(p.vertex_index[p.faces], f[p.face_index])


def test_bowtie_edge_flap_is_split_off_and_dropped():
    v, f = icosphere_mesh(3)
    a, b = f[0, 0], f[0, 1]
    v = np.vstack([v, [[3.0, 3.0, 3.0]]])
    f = np.vstack([f, [[a, b, len(v) - 1]]])          # a third face on edge a-b
    r = analyse(v, f)
    assert r.nonmanifold_edges == 1 and r.parts == 2 and r.parts_dropped == 1
    with pytest.raises(TopologyError, match="falls apart"):
        close_surface(v, f)
    with pytest.warns(UserWarning, match="1 tiny pieces"):
        parts = split_parts(v, f)
    assert len(parts.parts) == 1 and parts.dropped == 1 and parts.dropped_vertices == 3
    cs = close_surface(parts.parts[0].vertices, parts.parts[0].faces)
    assert_sphere(cs)
    assert len(cs.vertices) == 642


def test_pieces_split_tiny_ones_dropped():
    pieces, off = [], 0
    for make, shift in [(lambda: icosphere_mesh(3), 0), (lambda: icosphere_mesh(2), 3),
                        (lambda: sphere_with_holes([0]), 6), (lambda: tetrahedron(), 9),
                        (lambda: tetrahedron(), 12)]:
        v, f = make()
        pieces.append((v + [shift, 0, 0], f + off))
        off += len(v)
    v = np.vstack([p[0] for p in pieces])
    f = np.vstack([p[1] for p in pieces])
    with pytest.warns(UserWarning, match="2 tiny pieces \\(8 vertices"):
        parts = split_parts(v, f)
    assert [len(p.vertices) for p in parts.parts] == [642, 641, 162]
    assert parts.dropped == 2 and parts.dropped_vertices == 8 and parts.threshold == 50
    for p in parts.parts:
        assert_sphere(close_surface(p.vertices, p.faces))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert len(split_parts(v, f, options=RepairOptions(min_part_vertices=1,
                                                          min_part_share=0.0)).parts) == 5


# ---------------------------------------------------------------------------- determinism


def test_deterministic_byte_equal():
    for v, f in (capped_sphere(), voxel_plate(5, [(1, 1), (3, 1)]), pinched_sphere()):
        assert same(close_surface(v, f), close_surface(v.copy(), f.copy()))


# ---------------------------------------------------------------------------- errors


def test_errors_name_the_problem():
    v, f = icosphere_mesh(1)
    with pytest.raises(TopologyError, match="no triangle at all"):
        close_surface(v, np.zeros((0, 3), int))
    with pytest.raises(TopologyError, match="all 2 faces repeat a corner"):
        analyse(v, [[0, 0, 1], [2, 3, 3]])
    with pytest.raises(InputError, match="faces index vertices outside"):
        split_parts(v, [[0, 1, 99]])
    with pytest.raises(InputError, match="faces must have shape"):
        close_surface(v, [0, 1, 2])
    with pytest.raises(InputError, match="options must be a RepairOptions"):
        close_surface(v, f, options={"dp_max_loop": 4})
    mv, mf = moebius()
    with pytest.raises(TopologyError, match="non-orientable"):
        close_surface(mv, mf)


@pytest.mark.parametrize("kwargs,match", [
    ({"min_part_vertices": -1}, "RepairOptions.min_part_vertices must be an integer >= 0"),
    ({"flip_rounds": 1.5}, "RepairOptions.flip_rounds must be an integer >= 0"),
    ({"dp_max_loop": 2}, "dp_max_loop must be at least 3"),
    ({"handle_roots": 0}, "handle_roots must be at least 1"),
    ({"refine_ratio": float("nan")}, "RepairOptions.refine_ratio must be a finite number >= 0"),
    ({"min_part_share": 1.0}, "min_part_share must be below 1"),
    ({"refine_ratio": 0.1}, "refine_ratio must be at least 0.5"),
    ({"rim_penalty": 0.5}, "rim_penalty must be at least 1"),
])
def test_options_are_checked(kwargs, match):
    with pytest.raises(InputError, match=match):
        RepairOptions(**kwargs)


def test_boundary_loops_refuses_a_pinched_vertex():
    # two triangles meeting at vertex 0 only: 0 starts two boundary half-edges
    with pytest.raises(ValueError, match="starts two boundary half-edges"):
        boundary_loops(np.array([[0, 1, 2], [0, 3, 4]]), 5)


# ---------------------------------------------------------------------------- real models


def _close_all(mesh):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        parts = split_parts(mesh.vertices, mesh.faces)
    return parts, [close_surface(p.vertices, p.faces) for p in parts.parts]


@pytest.mark.slow
@pytest.mark.parametrize("name,holes,pinched,genus,pieces", [
    ("stanford-bunny.obj", 5, 0, 0, 1),
    ("cow.obj", 0, 1, 0, 1),
    ("rocker-arm.obj", 0, 0, 1, 1),
    ("ycb_scissors/textured_simple_reoriented.obj", 0, 0, 3, 1),
    ("frag_115.ply", 16, 0, 0, 10),
])
def test_real_models(models, name, holes, pinched, genus, pieces):
    mesh = read_mesh(models / name)
    r = analyse(mesh.vertices, mesh.faces)
    assert (r.holes, r.pinched_vertices, r.genus[0], r.parts) == (holes, pinched, genus, pieces)
    parts, closed = _close_all(mesh)
    assert len(closed) + parts.dropped == pieces
    for p, cs in zip(parts.parts, closed):
        assert_sphere(cs)
        assert_records(cs, p.vertices, p.faces)
        topo = TriangleMesh(p.vertices, reglued(cs)).topology()
        tp = TriangleMesh(p.vertices, p.faces).topology()
        assert (topo.euler, topo.boundary_edges, topo.nonmanifold_vertices) == \
            (tp.euler, tp.boundary_edges, tp.nonmanifold_vertices)
    main = closed[0].report
    assert main.handles_cut == genus and main.pinched_vertices == pinched
    assert main.virtual_area_share < (0.6 if name == "frag_115.ply" else 0.1)
    if name == "ycb_scissors/textured_simple_reoriented.obj":
        assert mesh.texture is not None


@pytest.mark.slow
def test_closed_cow_maps(models):
    from surfidx.sphere import parameterize
    mesh = read_mesh(models / "cow.obj")
    _, (cs,) = _close_all(mesh)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        m = parameterize(TriangleMesh(cs.vertices, cs.faces).to_surfels(), stress=False)
    assert m.folded == 0


# ---------------------------------------------------------------------------- virtual mask


def test_mask_round_trip_and_size():
    from surfidx.geometry.icosphere import Icosphere
    from surfidx.codec.mask import decode_mask, encode_mask
    rng = np.random.default_rng(0)
    noise = rng.random(642) < 0.3
    assert np.array_equal(decode_mask(encode_mask(noise, 3), 3), noise)
    g = Icosphere(6)
    cap = (g.vertices[:, 2] > 0.7) | (g.vertices[:, 0] > 0.95)
    data = encode_mask(cap, 6)
    assert np.array_equal(decode_mask(data, 6), cap)
    assert len(data) < 120                    # two caps on 40,962 grid vertices
    assert len(encode_mask(np.zeros(len(g.vertices), bool), 6)) <= 8
    assert encode_mask(cap.astype(int), 6) == data


def test_mask_errors():
    from surfidx import BitstreamError
    from surfidx.codec.mask import decode_mask, encode_mask
    with pytest.raises(InputError, match="one entry per vertex of the level-2 grid \\(162\\)"):
        encode_mask(np.zeros(100, bool), 2)
    with pytest.raises(InputError, match="bits must be 0 or 1"):
        encode_mask(np.full(162, 2), 2)
    with pytest.raises(InputError, match="level must be at most"):
        decode_mask(b"", 99)
    with pytest.raises(BitstreamError, match="mask starts with an impossible code value"):
        decode_mask(b"\xff\xff\xff\xff", 2)
