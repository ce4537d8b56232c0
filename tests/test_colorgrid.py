"""Colour on its own finer grid, sampled from the texture, and the order of geometry and colour
bit planes in one embedded stream (format version 5)."""

from __future__ import annotations

import numpy as np
import pytest

from surfidx import BitstreamError, InputError, TriangleMesh
from surfidx.codec import Encoder, container, decode, decode_grid
from surfidx.codec.colorgrid import (TextureSource, color_level, fixed_schedule,
                                     pass_distortions, rd_schedule, texels)
from surfidx.codec.options import CodecOptions
from surfidx.codec import zerotree
from surfidx.geometry.metrics import psnr_luma_surface

from helpers import checker_sphere


@pytest.fixture(scope="module")
def checker():
    mesh = checker_sphere(3, checks=4)
    surfels = mesh.to_surfels(max_edge_ratio=None)
    return mesh, surfels, Encoder(surfels, texture=mesh)


def test_colour_grid_is_finer_than_the_geometry_for_a_texture(checker):
    mesh, _, enc = checker
    assert enc.prepared.color_level > enc.level
    assert enc.prepared.color_level == color_level(enc.level, texels(mesh))
    assert color_level(5, None) == 5
    assert color_level(5, 1e12) == 6


def test_checkerboard_decodes_above_a_luma_floor_and_beats_vertex_colours(checker):
    mesh, surfels, enc = checker
    data = enc.encode(64.0)
    header, _ = container.unpack(data)
    assert header.version == 5 and header.color_level == enc.prepared.color_level
    textured = decode(data, mesh=True, texture=True)
    luma = psnr_luma_surface(mesh, textured, samples=20000)
    assert luma > 24.0      # measured 25.0 dB; vertex colours on the geometry's grid 14.5
    old = Encoder(surfels, sphere_map=enc.sphere_map,
                  options=CodecOptions(color_level=enc.level, allocation="fixed"))
    vertex = decode(old.encode(64.0), mesh=True, texture=True)
    assert luma > psnr_luma_surface(mesh, vertex, samples=20000) + 8.0


def test_prefixes_decode_as_streams_coded_at_that_rate(checker):
    _, _, enc = checker
    full = enc.encode(16.0)
    for rate in (4.0, 10.0):
        a, _ = decode_grid(full, bits_per_surfel=rate)
        b, _ = decode_grid(enc.encode(rate))
        np.testing.assert_array_equal(a, b)
    assert enc.encode(8.0) == enc.encode(8.0)


def test_coarser_output_levels_decode(checker):
    _, _, enc = checker
    data = enc.encode(8.0)
    m = decode(data, level=1, mesh=True, texture=True)
    assert len(m.vertices) > 0 and m.texture is not None
    s = decode(data, level=enc.level)
    assert s.colors is not None and len(s) == len(enc.grid)


def test_colourless_streams_keep_their_format(checker):
    _, surfels, _ = checker
    # without output-level hints (version 6): version 3, as before colour grids
    plain = Encoder(surfels, color=False, options=CodecOptions(level_hints=False)).encode(4.0)
    assert container.unpack(plain)[0].version == 3


def test_pass_bits_add_up_to_the_stream(checker):
    from surfidx.codec.encoder import pass_bits

    _, surfels, enc = checker
    groups, bits = pass_bits(enc.prepared)
    assert tuple(groups) == enc.prepared.schedule and np.all(bits >= 0)
    full = enc.encode_bytes(10 ** 8)      # every plane
    assert abs(bits.sum() / 8 - (len(full) - enc.header_bytes())) < 8
    with pytest.raises(InputError, match="needs a stream with colour"):
        pass_bits(Encoder(surfels, color=False, sphere_map=enc.sphere_map).prepared)


def test_rd_schedule_orders_by_gain_per_bit():
    order = rd_schedule([6, 6, 6], [1, 2, 4], [6, 6, 6], [1, 2, 4], 1.0)
    assert sorted(order) == [0, 0, 0, 1, 1, 1]
    # colour worth nothing: geometry first
    assert rd_schedule([6, 6], [1, 1], [6, 6], [1, 1], 1e-6) == (0, 0, 1, 1)
    assert fixed_schedule(3, 1, 0) == (0, 0, 0, 1, 0, 1)
    with pytest.raises(InputError, match="beyond its planes"):
        zerotree.group_schedule([0, 0, 0], (1, 1), 0)
    with pytest.raises(InputError, match="uncoded"):
        zerotree.group_schedule([0], (1, 1), 0)


def test_pass_distortions_are_the_array_expressions_bit_for_bit():
    # the schedule (and so the stream) depends on these sums: the kernel must repeat the
    # array expression's floating-point operations exactly
    rng = np.random.default_rng(7)
    full = rng.laplace(size=(5000, 6)) * 10.0 ** rng.uniform(-3, 1, size=(5000, 1))
    step = float(np.float32(3e-4))
    top = int(np.floor(np.log2(np.abs(full).max() / step + 0.5)))
    for c, w in ((full[:3000, :3], np.ones(3)), (full[:, 3:], np.array([0.6, 0.2, 0.2]))):
        q = np.floor(np.abs(c) / step + 0.5).astype(np.int64)
        want = [float((c * c).sum(axis=0) @ w)]
        for p in range(top, -1, -1):
            kept = (q >> p) << p
            frac = (2.0 ** (p - 1) - 0.5) if p > 0 else 0.0
            err = np.abs(c) - np.where(kept > 0, (kept + frac) * step, 0.0)
            want.append(float((err * err).sum(axis=0) @ w))
        assert pass_distortions(c, step, top, 0, w).tobytes() == np.array(want).tobytes()


def test_importance_moves_bits_to_colour(checker):
    mesh, surfels, enc = checker
    low = Encoder(surfels, texture=mesh, sphere_map=enc.sphere_map,
                  options=CodecOptions(color_importance=0.05))
    high = Encoder(surfels, texture=mesh, sphere_map=enc.sphere_map,
                   options=CodecOptions(color_importance=20.0))

    def first_colour(order):
        return order.index(1)

    assert first_colour(high.prepared.schedule) <= first_colour(low.prepared.schedule)
    assert high.prepared.schedule != low.prepared.schedule


def test_bad_colour_options_fail_cleanly(checker):
    _, surfels, enc = checker
    with pytest.raises(InputError, match="below the geometry's grid level"):
        Encoder(surfels, sphere_map=enc.sphere_map,
                options=CodecOptions(color_level=enc.level - 1))
    with pytest.raises(InputError, match="allocation"):
        CodecOptions(allocation="greedy")
    with pytest.raises(InputError, match="color_importance"):
        CodecOptions(color_importance=0)
    with pytest.raises(InputError, match="TextureSource needs"):
        TextureSource(TriangleMesh(np.eye(3), np.array([[0, 1, 2]])))


def test_damaged_colour_grid_headers_are_refused(checker):
    _, _, enc = checker
    data = enc.encode(4.0)
    header, stream = container.unpack(data)
    bad = container.Header(**{**header.__dict__, "schedule": header.schedule[:-1]})
    with pytest.raises(BitstreamError, match="schedule"):
        decode(container.pack(bad, stream))
    with pytest.raises(InputError, match="colour grid needs"):
        container.pack(container.Header(**{**header.__dict__, "color_level": header.level - 1}),
                       stream)
