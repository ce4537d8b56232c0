"""The codec's topology: virtual-region masks (format version 4), the real surface decoded with
the input's holes and genus, multi-part files, damaged masks and part tables, the CLI."""

import json
import struct
import warnings
import zlib

import numpy as np
import pytest
from click.testing import CliRunner
from hypothesis import assume, given, settings, strategies as st

from conftest import torus_mesh
from surfidx import BitstreamError, InputError, SurfelSet, TriangleMesh
from surfidx.codec import container
from surfidx.cli import cli
from surfidx.codec import (Encoder, PartsEncoder, decode, decode_grid, decode_parts, encode_parts,
                           max_file_bytes, stream_summary)
from surfidx.topology import analyse, close_surface
from surfidx.codec.restore import (closed_surfels, grid_regions, mask_regions, regions_at,
                                   restore, restored_vertices, zip_loops)


def _sphere_with_holes(centres, level=4):
    from conftest import icosphere_mesh

    v, f = icosphere_mesh(level)
    f = f[~np.isin(f, centres).any(axis=1)]
    used = np.unique(f)                     # no unused vertex (the CLI would warn)
    remap = np.full(len(v), -1)
    remap[used] = np.arange(len(used))
    return v[used] * [1.0, 0.9, 1.1], remap[f]


def _topology(m):
    r = analyse(m.vertices, m.faces)
    return dict(loops=r.holes, genus=r.genus, parts=r.parts,
                manifold=r.pinched_vertices == 0 and r.nonmanifold_edges == 0)


def _encoder(v, f, **kw):
    s, fp = closed_surfels(close_surface(v, f))
    return Encoder(s, face_patch=fp, **kw)


@pytest.fixture(scope="module")
def holes3():
    return _encoder(*_sphere_with_holes([0, 5, 9]), level=5)


@pytest.fixture(scope="module")
def torus():
    return _encoder(*torus_mesh(nu=64, nv=24), level=5)


@pytest.fixture(scope="module")
def ball():
    """A closed genus-0 part (no virtual patch)."""
    from conftest import icosphere_mesh

    v, f = icosphere_mesh(3)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        s = TriangleMesh(v * 0.5 + [3.0, 0, 0], f).to_surfels()
    return Encoder(s, level=4)


# ----------------------------------------------------------------------------- encoder side
def test_mask_is_in_the_header_and_counted(holes3):
    assert holes3.mask and holes3.regions == (0, 0, 0)
    assert 0 < holes3.virtual_share < 0.05
    for rate in (1.0, 4.0):
        data = holes3.encode(rate)
        assert len(data) <= max_file_bytes(rate, holes3.n_surfels)
        h, _ = container.unpack(data)
        assert h.version == 4 and h.mask == holes3.mask and h.regions == holes3.regions
    full = holes3.encode(4.0)
    cut = container.truncate(full, max_file_bytes(1.0, holes3.n_surfels))
    assert container.unpack(cut)[0].mask == holes3.mask      # the mask is kept whole
    a, _ = decode_grid(cut)
    b, _ = decode_grid(holes3.encode(1.0))
    np.testing.assert_array_equal(a, b)


def test_torus_regions_are_the_two_sides_of_its_cut(torus):
    assert sorted(torus.regions) == [container.region_code(0, 0), container.region_code(0, 1)]
    assert container.region_cut(container.region_code(3, 1)) == (3, 1)
    assert container.region_cut(container.REGION_HOLE) == (-1, 0)


def test_closed_model_has_no_mask_and_writes_version_3(ball):
    from dataclasses import replace

    from surfidx.codec import code

    assert ball.mask == b"" and ball.regions == ()
    # without output-level hints (the default, CodecOptions.level_hints=False) version 3
    data = code(replace(ball.prepared, level_hints=False), 4.0)
    assert data[4] == 3 and container.unpack(data)[0].version == 3
    # with them version 6, the stream shorter by the section
    hinted, stream = container.unpack(code(replace(ball.prepared, level_hints=True), 4.0))
    assert hinted.version == 6 and len(hinted.level_hints) == container.MAX_LEVEL_HINTS
    assert len(stream) == len(container.unpack(data)[1]) - container.HINT_SECTION_BYTES
    assert container.FORMAT_VERSION == 6


def test_mask_regions_anchor_and_join_patches():
    from surfidx.geometry.icosphere import icosphere

    g = icosphere(3)
    lab = np.full(g.n_vertices, -1)
    a, b = 100, 400             # patch 0 split in two far apart, patch 1 on no grid vertex
    lab[[a, b]] = 0
    bits, codes = mask_regions(lab, 3, [-1, -1], anchors=[-1, 7])
    count, region = grid_regions(bits, 3)
    assert count == 2 and codes == (0, 0)
    assert bits[7] and region[a] == region[b]
    # a coarser prefix keeps both regions: the one on level-3 vertices takes an ancestor
    coarse, ccodes = regions_at(region, codes, 3, 1)
    assert len(ccodes) == 2 and coarse.max() == 1


def test_mask_regions_keep_touching_patches_apart():
    """A large patch with a one-vertex patch beside it and an anchor beside both: three regions,
    the large patch giving up its vertices beside the others and staying one region."""
    from surfidx.geometry.icosphere import icosphere

    g = icosphere(3)
    lab = np.full(g.n_vertices, -1)
    cap = np.flatnonzero(g.vertices @ [0.0, 0.0, 1.0] > 0.5)
    lab[cap] = 0
    ptr, nb = g.neighbor_indptr, g.neighbor_indices
    rim = [v for v in range(g.n_vertices) if lab[v] < 0
           and (lab[nb[ptr[v]:ptr[v + 1]]] == 0).any()]
    lab[rim[0]] = 1                          # patch 1 on one grid vertex beside the cap
    bits, codes = mask_regions(lab, 3, [-1, -1, -1], anchors=[-1, -1, rim[-1]])
    count, region = grid_regions(bits, 3)
    assert count == 3 and codes == (0, 0, 0)
    assert bits[rim[0]] and not bits[rim[-1]]          # the anchor went a vertex further
    assert len(np.unique(region[cap][bits[cap]])) == 1 and bits[cap].sum() > 0.8 * len(cap)


def test_zip_loops_is_a_consistent_strip():
    t = 2 * np.pi * np.arange(8) / 8
    ring = np.stack([np.cos(t), np.sin(t), np.zeros(8)], 1)
    P = np.vstack([ring, ring[::-1] + [0, 0, 1.0]])
    a = np.arange(8)
    b = 8 + np.arange(8)
    f = zip_loops(P, a, b)
    assert len(f) == 16
    e = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    assert len({tuple(x) for x in e.tolist()}) == len(e)     # each half-edge once: oriented


# ----------------------------------------------------------------------------- decoder side
@pytest.mark.parametrize("kw", [{}, {"bits_per_surfel": 1.0}, {"level": 4}, {"level": 3},
                                {"bits_per_surfel": 2.0, "level": 4}])
def test_sphere_with_three_holes_decodes_open(holes3, kw):
    data = holes3.encode(4.0)
    m = decode(data, mesh=True, **kw)
    assert _topology(m) == dict(loops=3, genus=(0,), parts=1, manifold=True)
    s = decode(data, **kw)
    assert len(s) == len(m.vertices) and s.faces is not None and not s.virtual.any()


@pytest.mark.parametrize("hops, level", [(3, 3), (4, 3), (3, 2), (4, 2)])
def test_two_holes_closer_than_the_grid_spacing_decode_as_two(hops, level):
    """Two holes 3 or 4 mesh edges apart on a level-4 sphere, coded on the level-3 or level-2
    grid. On level 3 each hole holds one grid vertex and, 3 edges apart, the two are
    neighbours: the encoder moves the smaller hole's to the free vertex nearest its image
    (they were one region of the mask); where their dropped regions meet at grid vertices,
    those stay with the kept surface. On level 2 neither hole holds a grid vertex and their
    nearest grid vertices are neighbours, so the encoder anchors one of them a vertex further.
    The map decides which of these happens; the grid-only tests below cover each case."""
    import scipy.sparse as sp
    from scipy.sparse.csgraph import shortest_path

    from conftest import icosphere_mesh

    v, f = icosphere_mesh(4)
    e = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    g = sp.coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(len(v), len(v))).tocsr()
    far = int(np.flatnonzero(shortest_path(g, unweighted=True, indices=[0])[0] == hops)[0])
    enc = _encoder(*_sphere_with_holes([0, far]), level=level)
    assert enc.regions == (0, 0)
    for rate in (2.0, 4.0):
        m = decode(enc.encode(rate), mesh=True)
        assert _topology(m) == dict(loops=2, genus=(0,), parts=1, manifold=True)


def _grid_holes(level, labels, centres=None):
    """Patch labels on the grid's vertices through :func:`mask_regions` and :func:`restore`
    (the grid's own vertices as the decoded positions): the mask's region count and the
    topology of the restored mesh. No map and no rate: the codec's hole handling alone."""
    from surfidx.geometry.icosphere import icosphere

    V = np.asarray(icosphere(level).vertices)
    P = int(labels.max()) + 1
    bits, codes = mask_regions(labels, level, [-1] * P, centres=centres)
    count, region = grid_regions(bits, level)
    assert len(codes) == count
    r = restore(V, level, region, codes)
    return count, _topology(TriangleMesh(V[r.vertices], r.faces))


def _grid_graph(level):
    import scipy.sparse as sp
    from surfidx.geometry.icosphere import icosphere

    g = icosphere(level)
    ptr, nb = np.asarray(g.neighbor_indptr), np.asarray(g.neighbor_indices)
    rows = np.repeat(np.arange(g.n_vertices), np.diff(ptr))
    return sp.csr_matrix((np.ones(len(nb)), (rows, nb)), shape=(g.n_vertices, g.n_vertices))


def _hops(level, sources):
    """(len(sources), n) grid hops from each source vertex."""
    from scipy.sparse.csgraph import shortest_path

    return shortest_path(_grid_graph(level), unweighted=True, indices=sources)


@pytest.mark.parametrize("hops", [1, 2, 3, 4])
@pytest.mark.parametrize("radii", [(0, 0), (0, 1), (1, 1)])
@pytest.mark.parametrize("a", [0, 300])           # an icosahedron vertex (valence 5), and not
def test_two_patches_at_any_distance_are_two_holes_on_the_grid(a, radii, hops):
    """Two patches given on the level-3 grid (a vertex, or a vertex and its neighbours) whose
    centres are 1 to 4 grid hops apart, overlapping or touching included: two regions of the
    mask and two boundary loops of one manifold piece, whatever the map did to bring them
    together (neighbouring patches were one region, two hops apart one hole)."""
    from surfidx.geometry.icosphere import icosphere

    level = 3
    d = _hops(level, [a])[0]
    b = int(np.flatnonzero(d == hops)[0])
    db = _hops(level, [b])[0]
    lab = np.full(len(d), -1)
    lab[db <= radii[1]] = 1
    lab[d <= radii[0]] = 0                       # the first patch keeps a shared vertex
    if not (lab == 1).any():
        pytest.skip("the second patch lies inside the first")
    V = np.asarray(icosphere(level).vertices)
    count, topo = _grid_holes(level, lab, centres=V[[a, b]])
    assert count == 2
    assert topo == dict(loops=2, genus=(0,), parts=1, manifold=True)


def test_touching_one_vertex_patches_part_toward_the_centre():
    """Two patches on neighbouring grid vertices, each its patch's only one: patch 1 (equal
    sizes: the higher index) moves to the free vertex nearest its centre, or without centres
    to the free vertex of smallest index; patch 0 stays."""
    from surfidx.geometry.icosphere import icosphere

    level = 3
    V = np.asarray(icosphere(level).vertices)
    G = _grid_graph(level)
    a = 300
    b = int(G[a].indices.max())
    free = [w for w in G[b].indices.tolist() if w != a and a not in G[w].indices]
    lab = np.full(len(V), -1)
    lab[[a, b]] = [0, 1]
    for want in free:
        c = V[b] + V[want]
        bits, codes = mask_regions(lab, level, [-1, -1],
                                   centres=np.stack([V[a], c / np.linalg.norm(c)]))
        assert codes == (0, 0) and np.flatnonzero(bits).tolist() == sorted([a, want])
    bits, _ = mask_regions(lab, level, [-1, -1])
    assert np.flatnonzero(bits).tolist() == sorted([a, min(free)])


@settings(max_examples=60)
@given(st.integers(0, 641), st.lists(st.tuples(st.integers(0, 3), st.integers(0, 5),
                                               st.integers(0, 1)), min_size=2, max_size=4))
def test_crowded_patches_are_one_hole_each_on_the_grid(start, walks):
    """2 to 4 patches (a vertex, or a vertex and its neighbours) crowded within a few hops of
    one grid vertex: one region and one boundary loop each, on one manifold piece."""
    level = 3
    g = _grid_graph(level)
    lab = np.full(g.shape[0], -1)
    for p, (steps, turn, radius) in enumerate(walks):
        v = start
        for k in range(steps):                   # a short walk from the start vertex
            nb = g[v].indices
            v = int(nb[(turn + k) % len(nb)])
        ball = np.flatnonzero(_hops(level, [v])[0] <= radius)
        ball = ball[lab[ball] < 0]
        assume(len(ball) and grid_regions(np.isin(np.arange(len(lab)), ball), level)[0] == 1)
        lab[ball] = p
    count, topo = _grid_holes(level, lab)
    assert count == len(walks)
    assert topo == dict(loops=len(walks), genus=(0,), parts=1, manifold=True)


def test_regions_two_hops_apart_decode_as_two_holes():
    """The decoder alone: across a grid edge ``(c, e)``, each of the two vertices opposite it
    with its neighbours other than ``c`` and ``e`` is a region of the mask (two grid hops
    apart). Their dropped faces cut the edge's two faces off the kept surface by edges; that
    piece stays kept (it went to one region, joining the two holes) and the pinch at ``c`` and
    ``e`` joins it to the surface again."""
    from surfidx.geometry.icosphere import icosphere

    level = 3
    g = icosphere(level)
    F = np.asarray(g.faces)
    V = np.asarray(g.vertices)
    G = _grid_graph(level)
    for f in F:          # the first edge with room (no icosahedron vertex close by)
        c, e = int(f[0]), int(f[1])
        x, y = np.setdiff1d(F[(F == c).any(axis=1) & (F == e).any(axis=1)].ravel(), [c, e])
        A = sorted({int(x), *G[x].indices.tolist()} - {c, e})
        B = sorted({int(y), *G[y].indices.tolist()} - {c, e})
        if _hops(level, A)[:, B].min() == 2:
            break
    bits = np.zeros(len(V), bool)
    bits[A + B] = True
    count, region = grid_regions(bits, level)
    assert count == 2
    r = restore(V, level, region, (0, 0))
    assert _topology(TriangleMesh(V[r.vertices], r.faces)) == dict(
        loops=2, genus=(0,), parts=1, manifold=True)


def test_restored_vertices_are_those_of_any_decoding(holes3, torus):
    """The vertices restore keeps follow from the regions alone: the same for every prefix of
    a stream (the output-level hints score each prefix with them), at its level and a coarser
    one."""
    from surfidx.codec.mask import decode_mask
    from surfidx.geometry.icosphere import icosphere, vertex_count

    for enc in (holes3, torus):
        data = enc.encode(8.0)
        header = container.unpack(data)[0]
        L = header.level
        _, fine = grid_regions(decode_mask(header.mask, L), L)
        for level in (L, L - 1):
            region, codes = regions_at(fine, header.regions, L, level)
            keep = restored_vertices(level, region, len(codes))
            assert 0 < len(keep) < vertex_count(level)
            for rate in (1.0, 2.0, None):
                values, _ = decode_grid(data, bits_per_surfel=rate)
                r = restore(values[:vertex_count(level), :3], level, region, codes)
                assert np.array_equal(r.vertices, keep)
                # the kept faces are the grid faces restore names, in their corner order; a
                # strip zipping the torus's cut is none (-1)
                kept = r.grid_faces >= 0
                assert len(r.grid_faces) == len(r.faces)
                assert (kept.sum() < len(kept)) == (r.zipped > 0)
                np.testing.assert_array_equal(r.vertices[r.faces[kept]],
                                              np.asarray(icosphere(level).faces)[
                                                  r.grid_faces[kept]])
            if enc is torus and level == L:
                assert r.zipped == 1


@pytest.mark.parametrize("kw", [{}, {"bits_per_surfel": 1.0}, {"level": 4}, {"level": 3}])
def test_torus_decodes_closed_with_genus_1(torus, kw):
    m = decode(torus.encode(4.0), mesh=True, **kw)
    assert _topology(m) == dict(loops=0, genus=(1,), parts=1, manifold=True)


def test_keep_virtual_returns_the_closed_surface(holes3, torus):
    for e in (holes3, torus):
        m = decode(e.encode(4.0), mesh=True, keep_virtual=True)
        assert _topology(m) == dict(loops=0, genus=(0,), parts=1, manifold=True)
        assert len(decode(e.encode(4.0), keep_virtual=True)) == len(e.grid)


def test_handle_and_hole_together():
    v, f = torus_mesh(nu=64, nv=24)
    f = f[~np.isin(f, [5]).any(axis=1)]
    e = _encoder(v, f, level=5)
    assert sorted(e.regions) == [0, 1, 2]
    m = decode(e.encode(4.0), mesh=True)
    assert _topology(m) == dict(loops=1, genus=(1,), parts=1, manifold=True)


def test_real_surface_stays_close_to_the_input(holes3):
    from surfidx.geometry.metrics import psnr_d2

    v, f = _sphere_with_holes([0, 5, 9])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ref = TriangleMesh(v, f).to_surfels(max_edge_ratio=None)
    real = decode(holes3.encode(8.0))
    closed = decode(holes3.encode(8.0), keep_virtual=True)
    assert psnr_d2(ref, real) > 50
    # the decoded real surface covers only the scan: no point far out over a hole
    from scipy.spatial import cKDTree

    d_real, _ = cKDTree(ref.positions).query(real.positions)
    d_closed, _ = cKDTree(ref.positions).query(closed.positions)
    assert d_real.max() < d_closed.max()


# ----------------------------------------------------------------------------- several parts
def test_parts_encoder_single_part_is_the_encoders_bytes(ball):
    from conftest import icosphere_mesh

    v, f = icosphere_mesh(3)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        s = TriangleMesh(v * 0.5 + [3.0, 0, 0], f).to_surfels()
    assert PartsEncoder([s], level=4).encode(3.0) == ball.encode(3.0)
    assert encode_parts([s], bits_per_surfel=3.0, level=4) == ball.encode(3.0)


@pytest.fixture(scope="module")
def two(holes3, ball):
    pe = PartsEncoder.__new__(PartsEncoder)    # the parts' encoders, built once above
    pe.encoders = [holes3, ball]
    pe.n_surfels = holes3.n_surfels + ball.n_surfels
    return pe


def test_multi_part_rate_split_and_truncation(two):
    n = two.n_surfels
    full = two.encode(4.0)
    assert container.is_multipart(full) and full[4] == 4
    assert len(full) <= max_file_bytes(4.0, n)
    parts = container.unpack_parts(full)
    budgets = container.split_budget(max_file_bytes(4.0, n), [e.n_surfels for e in two.encoders])
    assert all(len(p) <= b for p, b in zip(parts, budgets))
    assert sum(budgets) + container.parts_overhead(2) == max_file_bytes(4.0, n)
    low = container.truncate(full, max_file_bytes(2.0, n))
    assert len(low) <= max_file_bytes(2.0, n)
    a = decode(full, bits_per_surfel=2.0, mesh=True)
    b = decode(low, mesh=True)
    c = decode(two.encode(2.0), mesh=True)
    np.testing.assert_array_equal(a.vertices, b.vertices)
    np.testing.assert_array_equal(a.vertices, c.vertices)


def test_multi_part_decodes_to_all_parts_together(two):
    data = two.encode(4.0)
    ps = decode_parts(data, mesh=True)
    assert len(ps) == 2
    assert _topology(ps[0])["loops"] == 3 and _topology(ps[1])["loops"] == 0
    m = decode(data, mesh=True)
    assert len(m.vertices) == sum(len(p.vertices) for p in ps)
    assert _topology(m) == dict(loops=3, genus=(0, 0), parts=2, manifold=True)
    s = decode(data)
    assert len(s) == len(m.vertices)
    for kw in ({"level": 3}, {"bits_per_surfel": 1.5}):
        assert _topology(decode(data, mesh=True, **kw))["loops"] == 3
    with pytest.raises(InputError, match="parts decode to"):
        decode(data, max_surfels=100)
    with pytest.raises(InputError, match="level must be an integer"):
        decode(data, level=9)


def test_stream_summary(two, holes3, ball):
    s = stream_summary(two.encode(4.0))
    assert s["parts"] == 2 and s["version"] == 4
    assert s["part_surfels"] == [holes3.n_surfels, ball.n_surfels]
    assert s["holes"] == [3, 0] and s["cuts"] == [0, 0]
    assert s["mask_bytes"][0] == 6 + len(holes3.mask) + 2 * 3 and s["mask_bytes"][1] == 0
    assert 0 < s["mask_share"] < 0.2 and s["virtual_share"][0] == holes3.virtual_share
    one = stream_summary(ball.encode(4.0))
    assert one["parts"] == 1 and one["version"] == 3 and one["mask_share"] == 0


def test_parts_encoder_errors(two):
    with pytest.raises(InputError, match="at least one part"):
        PartsEncoder([])
    with pytest.raises(InputError, match="parts must be SurfelSets"):
        PartsEncoder([np.zeros((3, 3))])
    with pytest.raises(InputError, match="face_patches has 2 entries for 1 parts"):
        PartsEncoder([SurfelSet(np.eye(3), np.eye(3), np.ones(3))], face_patches=[None, None])
    with pytest.raises(InputError, match="leaves part 0"):
        two.encode(0.3)
    with pytest.raises(InputError, match="2..4096 parts"):
        container.pack_parts([b"x"])


# ----------------------------------------------------------------------------- damaged files
def _rewrite(data, mask=None, regions=None):
    """The container with its mask section replaced (checksums recomputed)."""
    h, stream = container.unpack(data)
    if mask is not None:
        h.mask = mask
    if regions is not None:
        h.regions = regions
    return container.pack(h, stream)


def test_damaged_mask_or_region_table(holes3):
    data = holes3.encode(4.0)
    with pytest.raises(BitstreamError, match="m.sfz: bad region table: it lists 2 regions"):
        decode(_rewrite(data, regions=(0, 0)), path="m.sfz")
    with pytest.raises(BitstreamError, match="names cut 7"):
        decode(_rewrite(data, regions=(0, 0, container.region_code(7))), path="m.sfz")
    with pytest.raises(BitstreamError, match="m.sfz: .*impossible code value"):
        decode(_rewrite(data, mask=b"\xff\xff\xff\xff" + holes3.mask), path="m.sfz")
    bad = bytearray(data)
    bad[80] ^= 0xFF                                        # inside the header: CRC
    with pytest.raises(BitstreamError, match="header checksum mismatch"):
        decode(bytes(bad))
    with pytest.raises(InputError, match="region table of 1..65535"):
        _rewrite(data, regions=())


def test_mask_flag_unknown_to_version_3(holes3):
    data = bytearray(holes3.encode(4.0))
    data[4] = 3
    h_end = len(data) - container.unpack(bytes(holes3.encode(4.0)))[1].__len__()
    struct.pack_into("<I", data, h_end - 8, zlib.crc32(bytes(data[:h_end - 8])))
    with pytest.raises(BitstreamError, match="unknown to version 3"):
        container.unpack(bytes(data))


def test_empty_mask_section_is_corrupt(holes3):
    h, stream = container.unpack(holes3.encode(4.0))
    h.level_hints = ()   # the mask section last, as in version 4
    raw = bytearray(container.pack(h, stream))
    off = len(raw) - len(stream) - 12 - (6 + len(h.mask) + 2 * len(h.regions))
    struct.pack_into("<I", raw, off, 0)               # mask length 0, bytes stay: recompute
    body = bytes(raw[:off + 4]) + bytes(raw[off + 4 + len(h.mask):len(raw) - len(stream) - 8])
    fixed = body + struct.pack("<II", zlib.crc32(body), zlib.crc32(stream)) + stream
    with pytest.raises(BitstreamError, match="virtual-region mask of 0 bytes"):
        container.unpack(fixed)


def test_hostile_part_tables(two):
    data = two.encode(4.0)
    with pytest.raises(BitstreamError, match="multi-part file.*unpack_parts"):
        container.unpack(data)

    def outer(count, lengths, tail=b""):
        head = struct.pack("<4sBBH", container.MAGIC, 4, container.FLAG_PARTS, count)
        head += struct.pack(f"<{len(lengths)}I", *lengths)
        return head + struct.pack("<I", zlib.crc32(head)) + tail

    with pytest.raises(BitstreamError, match=r"x.sfz: corrupt multi-part header \(65535 parts"):
        decode(outer(65535, [1, 2]), path="x.sfz")
    with pytest.raises(BitstreamError, match=r"\(1 parts"):
        decode(outer(1, [10], bytes(200)))
    parts = container.unpack_parts(data)
    with pytest.raises(BitstreamError, match="truncated its parts"):
        decode(outer(2, [len(parts[0]), len(parts[1]) + 5], parts[0] + parts[1]))
    with pytest.raises(BitstreamError, match="unexpected bytes after its parts"):
        decode(data + b"\0")
    bad = bytearray(data)
    bad[9] ^= 1
    with pytest.raises(BitstreamError, match="multi-part header checksum mismatch"):
        decode(bytes(bad))
    bad = bytearray(data)
    bad[5] |= 1
    with pytest.raises(BitstreamError, match="corrupt multi-part header \\(flags"):
        decode(bytes(bad))
    with pytest.raises(BitstreamError, match="truncated multi-part header"):
        container.unpack_parts(data[:7])


# ----------------------------------------------------------------------------- CLI
def test_cli_encode_decode_open_and_genus_1(tmp_path):
    from surfidx.io import read_mesh, write_model

    runner = CliRunner()
    for name, (v, f), want in [("holes", _sphere_with_holes([0, 5, 9]),
                                dict(loops=3, genus=(0,), parts=1, manifold=True)),
                               ("torus", torus_mesh(nu=64, nv=24),
                                dict(loops=0, genus=(1,), parts=1, manifold=True))]:
        src = tmp_path / f"{name}.obj"
        write_model(TriangleMesh(v, f), src)
        sfz = tmp_path / f"{name}.sfz"
        r = runner.invoke(cli, ["encode", str(src), "-o", str(sfz), "--bits-per-surfel", "4",
                                "--level", "5", "--json", "-q"])
        assert r.exit_code == 0, r.output
        out = json.loads(r.output)
        assert out["parts"] == 1 and out["mask_bytes"] > 0
        obj = tmp_path / f"{name}_out.obj"
        r = runner.invoke(cli, ["decode", str(sfz), "-o", str(obj)])
        assert r.exit_code == 0, r.output
        assert _topology(read_mesh(obj)) == want
        low = tmp_path / f"{name}_low.sfz"
        r = runner.invoke(cli, ["decode", str(sfz), "-o", str(low), "--bits-per-surfel", "1"])
        assert r.exit_code == 0, r.output
        assert container.unpack(low.read_bytes())[0].mask


def test_cli_two_pieces_and_damaged_file(tmp_path):
    from conftest import icosphere_mesh
    from surfidx.io import read_mesh, write_model

    v, f = icosphere_mesh(3)
    v2, f2 = _sphere_with_holes([0, 5, 9])
    src = tmp_path / "two.obj"
    write_model(TriangleMesh(np.vstack([v * 0.8 + [4.0, 0, 0], v2]),
                             np.vstack([f, f2 + len(v)])), src)
    sfz = tmp_path / "two.sfz"
    runner = CliRunner()
    r = runner.invoke(cli, ["encode", str(src), "-o", str(sfz), "--bits-per-surfel", "4",
                            "--level", "4", "--json", "-q"])
    assert r.exit_code == 0, r.output
    assert json.loads(r.output)["parts"] == 2
    obj = tmp_path / "two_out.obj"
    r = runner.invoke(cli, ["decode", str(sfz), "-o", str(obj)])
    assert r.exit_code == 0, r.output
    t = _topology(read_mesh(obj))
    assert t["parts"] == 2 and t["loops"] == 3
    low = tmp_path / "two_low.sfz"
    r = runner.invoke(cli, ["decode", str(sfz), "-o", str(low), "--bits-per-surfel", "2"])
    assert r.exit_code == 0, r.output
    assert len(low.read_bytes()) <= max_file_bytes(2.0, stream_summary(sfz.read_bytes())[
        "surfels"])
    bad = bytearray(sfz.read_bytes())
    bad[6] = 0xFF
    (tmp_path / "bad.sfz").write_bytes(bytes(bad))
    r = runner.invoke(cli, ["decode", str(tmp_path / "bad.sfz"), "-o", str(obj)])
    assert r.exit_code != 0 and "bad.sfz" in r.output and "multi-part" in r.output


def test_too_coarse_a_grid_still_decodes_manifold():
    """A genus-2 voxel plate of 56 surfels on a level-3 grid: its cut lids are two faces each,
    so regions touch and a cut may stay open, but the decoded mesh is manifold at every level
    and rate (a strip that would double an edge or pinch a vertex is not added)."""
    from helpers import voxel_plate

    v, f = voxel_plate(5, [(1, 1), (3, 1)])
    e = _encoder(np.asarray(v, float), np.asarray(f))
    data = e.encode(8.0 * (e.lowest_bytes() + 200) / e.n_surfels)
    for kw in ({}, {"level": e.level - 1}, {"level": e.level - 2},
               {"bits_per_surfel": 8.0 * (e.lowest_bytes() + 20) / e.n_surfels}):
        t = _topology(decode(data, mesh=True, **kw))
        assert t["manifold"] and t["parts"] == 1


def test_more_new_errors(holes3):
    from surfidx.codec.resample import grid_patches

    with pytest.raises(InputError, match="at most 4096 parts"):
        PartsEncoder([None] * 4097)
    data = holes3.encode(4.0)
    with pytest.raises(BitstreamError, match="m.sfz: .*impossible code value"):
        stream_summary(_rewrite(data, mask=b"\xff\xff\xff\xff"), path="m.sfz")
    big = bytearray(data)
    big[6] = 10                                          # a grid finer than the format's
    with pytest.raises(BitstreamError, match="grid level 10; format version 4 allows 0 … 9"):
        stream_summary(bytes(big))

    class Huge(bytes):
        def __len__(self):
            return 2 ** 32

    h, stream = container.unpack(data)
    h.mask = Huge(b"x")
    with pytest.raises(InputError, match="longer than 2"):
        container.pack(h, stream)
    s, fp = closed_surfels(close_surface(*_sphere_with_holes([0, 5, 9])))
    pts = s.positions / np.linalg.norm(s.positions, axis=1)[:, None]
    with pytest.raises(InputError, match="face_patch must hold -1 or a patch index below 3"):
        grid_patches(s, pts, 2, face_patch=np.full(len(s.faces), 5))
    assert (grid_patches(s, pts, 2, face_patch=fp) >= 0).any()


def test_cli_bad_region_table_names_the_file(tmp_path, holes3):
    bad = tmp_path / "regions.sfz"
    bad.write_bytes(_rewrite(holes3.encode(4.0), regions=(0, 0)))
    r = CliRunner().invoke(cli, ["decode", str(bad), "-o", str(tmp_path / "o.obj")])
    assert r.exit_code != 0
    assert "regions.sfz" in r.output and "bad region table" in r.output
    assert "Traceback" not in r.output


def test_grid_regions_are_the_components_numbered_by_smallest_vertex():
    from scipy.sparse import csr_matrix
    from scipy.sparse.csgraph import connected_components

    from surfidx.geometry.icosphere import icosphere

    g = icosphere(4)
    n = g.n_vertices
    ptr, nb = np.asarray(g.neighbor_indptr), np.asarray(g.neighbor_indices)
    adj = csr_matrix((np.ones(len(nb)), (np.repeat(np.arange(n), np.diff(ptr)), nb)), (n, n))
    rng = np.random.default_rng(3)
    for density in (0.0, 0.2, 0.55, 1.0):
        bits = rng.random(n) < density
        count, region = grid_regions(bits, 4)
        on = np.flatnonzero(bits)
        want, lab = connected_components(adj[on][:, on], directed=False) if len(on) else (0, on)
        assert count == want
        assert np.array_equal(region < 0, ~bits)
        # the same partition, numbered in the order of each region's smallest vertex
        firsts = [int(on[lab == c].min()) for c in range(want)]
        for r, c in enumerate(np.argsort(firsts, kind="stable")):
            assert np.array_equal(np.flatnonzero(region == r), on[lab == c])
