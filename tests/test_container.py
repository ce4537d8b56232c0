"""Container: round trip, truncation to a budget, and every kind of damage."""

import numpy as np
import pytest

from surfidx import BitstreamError, InputError
from surfidx.codec.container import (FORMAT_VERSION, HINT_SECTION_BYTES, MAGIC, Header,
                                     header_size, hint_bytes, hinted_level, pack, storable,
                                     truncate, unpack)


def _header(color=True):
    k = 6 if color else 3
    rng = np.random.default_rng(0)
    q, _ = np.linalg.qr(rng.normal(size=(k, k)))
    return Header(n_surfels=1234, level=5, color=color, lifted=True, mean=rng.normal(size=k),
                  basis=q, weights=np.r_[np.full(3, 0.5), np.full(k - 3, 0.01)],
                  coder=b"\x07\x01abc", map_method=2)


@pytest.mark.parametrize("color", [True, False])
def test_round_trip(color):
    h = _header(color)
    stream = bytes(range(256)) * 10
    data = pack(h, stream)
    assert data[:4] == MAGIC and len(data) == header_size(h.layers, len(h.coder)) + len(stream)
    h2, s2 = unpack(data)
    assert s2 == stream
    # no virtual-region mask: written as version 3, byte for byte as before version 4
    assert (h2.n_surfels, h2.level, h2.color, h2.lifted, h2.coder, h2.map_method, h2.version) == (
        1234, 5, color, True, b"\x07\x01abc", 2, 3)
    assert FORMAT_VERSION == 6
    np.testing.assert_array_equal(h2.basis, np.float16(h.basis))
    np.testing.assert_array_equal(h2.mean, np.float32(h.mean))
    np.testing.assert_array_equal(h2.weights, np.float32(h.weights))
    for a, b in zip(storable(h.mean, h.basis, h.weights), (h2.mean, h2.basis, h2.weights)):
        np.testing.assert_array_equal(a, b)  # what the encoder uses is what the decoder reads


def test_header_sizes():
    # fixed 16 + mean 4k + float16 basis 2k^2 + 1 or 2 group weights + coder + tail 12
    assert header_size(3, 8) == 16 + 12 + 18 + 4 + 8 + 12 == 70
    assert header_size(6, 8) == 16 + 24 + 72 + 8 + 8 + 12 == 140


def test_level_hints_round_trip_and_choose_the_level():
    h = _header(False)
    h.level_hints = (80, 64, 0, 0)
    data = pack(h, bytes(300))
    assert len(data) == header_size(3, len(h.coder), hints=True) + 300
    assert len(data) == len(pack(_header(False), bytes(300))) + HINT_SECTION_BYTES
    h2, s2 = unpack(data)
    assert h2.version == 6 and h2.level_hints == (80, 64, 0, 0) and s2 == bytes(300)
    assert data[13] == 80   # the first code in the fixed header's reserved byte
    for hints in [(0, 0, 0, 0), (255, 225, 195, 165), (9, 9, 9, 1), (200, 170, 0, 0)]:
        h.level_hints = hints
        assert unpack(pack(h, b"abcd"))[0].level_hints == hints
    # codes are rates over the header's 1234 surfels: 128 is 1 bit/surfel, 16 steps an octave
    assert [hint_bytes(c, 1234) for c in (0, 64, 80, 128, 144, 255)] == [
        0, 10, 20, 155, 309, 2 ** 64]
    # level 5 from 20 bytes (80: 1/8 bit/surfel), 4 from 10 bytes (64: 1/16), 3 below
    assert [hinted_level(h2, n) for n in (4, 9, 10, 19, 20, 10 ** 6)] == [3, 3, 4, 4, 5, 5]
    # a truncated file keeps its hints: its level is that of the prefix it holds
    cut, _ = unpack(truncate(data, len(data) - 100))
    assert cut.level_hints == h2.level_hints
    # no section: the stream's level at any length
    assert unpack(pack(_header(False), bytes(10)))[0].level_hints == ()
    assert hinted_level(_header(False), 4) == 5


def _reseal(data: bytearray, tail: int) -> bytes:
    """``data`` with its header checksum recomputed (the header ends at ``tail``)."""
    import struct
    import zlib

    data[tail + 4:tail + 8] = struct.pack("<I", zlib.crc32(bytes(data[:tail + 4])))
    return bytes(data)


def test_level_hints_are_checked():
    h = _header(False)
    for bad in [(1, 2, 0, 0), (80, 64), (300, 0, 0, 0), (80, 40, 0, 0)]:
        h.level_hints = bad
        with pytest.raises(InputError, match="output-level hints must be 4 non-increasing"):
            pack(h, bytes(20))
    h.level_hints = (80, 64, 0, 0)
    tail = header_size(3, len(h.coder), hints=True) - 12
    data = bytearray(pack(h, bytes(20)))
    data[13] = 10   # a first code below the gap after it
    with pytest.raises(BitstreamError, match=r"corrupt header \(output-level hints"):
        unpack(_reseal(data, tail))
    data = bytearray(pack(h, bytes(20)))
    data[tail - 1] |= 0x80   # the section's unused top bit
    with pytest.raises(BitstreamError, match=r"corrupt header \(output-level hints"):
        unpack(_reseal(data, tail))
    # the flag in an older version is unknown
    older = bytearray(pack(_header(False), bytes(20)))
    older[5] |= 0x40
    with pytest.raises(BitstreamError, match="unknown flags 0x42"):
        unpack(_reseal(older, header_size(3, len(h.coder)) - 12))


def test_weights_must_be_one_per_group():
    h = _header()
    h.weights = np.arange(1.0, 7.0)
    with pytest.raises(InputError, match="one value for x, y, z and one for r, g, b"):
        pack(h, b"")


def test_truncate_keeps_a_valid_prefix():
    data = pack(_header(), bytes(range(200)))
    cut = truncate(data, len(data) - 50)
    assert len(cut) == len(data) - 50
    h, s = unpack(cut)
    assert s == bytes(range(150))
    assert truncate(data, 10 ** 6) == data
    with pytest.raises(InputError, match="does not hold the .*-byte header"):
        truncate(data, 10)


def test_damage_is_detected():
    data = pack(_header(), bytes(range(200)))
    with pytest.raises(BitstreamError, match="bad magic"):
        unpack(b"PK\x03\x04" + data[4:])
    with pytest.raises(BitstreamError, match="too short"):
        unpack(b"ab")
    with pytest.raises(BitstreamError, match="truncated header"):
        unpack(data[:30], path="x.sfz")
    with pytest.raises(BitstreamError, match="x.sfz: truncated stream"):
        unpack(data[:-1], path="x.sfz")
    with pytest.raises(BitstreamError, match="unexpected bytes after the stream"):
        unpack(data + b"\0")
    flipped = bytearray(data)
    flipped[-5] ^= 0x10
    with pytest.raises(BitstreamError, match="stream checksum mismatch"):
        unpack(bytes(flipped))
    flipped = bytearray(data)
    flipped[20] ^= 0x01
    with pytest.raises(BitstreamError, match="header checksum mismatch"):
        unpack(bytes(flipped))
    newer = bytearray(data)
    newer[4] = FORMAT_VERSION + 1
    with pytest.raises(BitstreamError, match="unsupported format version"):
        unpack(bytes(newer))


def test_random_garbage_never_crashes():
    rng = np.random.default_rng(1)
    data = pack(_header(), bytes(100))
    for _ in range(200):
        d = bytearray(data)
        for i in rng.integers(0, len(d), size=3):
            d[i] = rng.integers(0, 256)
        if bytes(d) == data:
            continue
        with pytest.raises(BitstreamError):
            unpack(bytes(d))


def test_pack_validates():
    h = _header()
    h.level = 40
    with pytest.raises(InputError, match="grid level must be 0..9"):
        pack(h, b"")
    h = _header()
    h.n_surfels = 0
    with pytest.raises(InputError, match="n_surfels must be"):
        pack(h, b"")


def test_coder_header_limit():
    h = _header()
    h.coder = bytes(70000)
    with pytest.raises(InputError, match="coder header longer than 65535"):
        pack(h, b"")


def test_layer_count_and_non_finite_values():
    data = bytearray(pack(_header(), b"abc"))
    data[7] = 4
    with pytest.raises(BitstreamError, match="layer count 4, expected 3 or 6"):
        unpack(bytes(data))
    h = _header()
    h.basis = h.basis * 1e6  # overflows float16
    with pytest.raises(InputError, match="must be finite in float32/float16"):
        pack(h, b"")


def _reseal(data: bytearray, tail_off: int) -> bytes:
    """Recompute the header checksum after editing header bytes (tail at ``tail_off``)."""
    import struct
    import zlib

    struct.pack_into("<I", data, tail_off + 4, zlib.crc32(bytes(data[:tail_off + 4])))
    return bytes(data)


@pytest.mark.parametrize("color", [True, False])
def test_frames_and_weight_field_round_trip(color):
    h = _header(color)
    h.tangent_weight = 0.5
    h.weight_field = b"\x02field-bytes"
    stream = bytes(range(100))
    data = pack(h, stream)
    assert len(data) == header_size(h.layers, len(h.coder), frames=True,
                                     field_bytes=len(h.weight_field)) + len(stream)
    h2, s2 = unpack(data)
    assert (h2.tangent_weight, h2.weight_field, s2) == (0.5, b"\x02field-bytes", stream)
    plain, _ = unpack(pack(_header(color), stream))
    assert plain.tangent_weight is None and plain.weight_field == b""
    assert unpack(truncate(data, len(data) - 10))[0].weight_field == h.weight_field


def test_version_2_files_still_read():
    h = _header(False)
    data = bytearray(pack(h, b"stream"))
    data[4] = 2
    tail_off = header_size(3, len(h.coder)) - 12
    h2, s2 = unpack(_reseal(data, tail_off))
    assert (h2.version, h2.tangent_weight, h2.weight_field, s2) == (2, None, b"", b"stream")
    data[5] |= 4   # a version-2 file cannot have local frames
    with pytest.raises(BitstreamError, match="flags 0x06 unknown to version 2"):
        unpack(_reseal(data, tail_off))


def test_new_header_fields_are_validated():
    h = _header(False)
    h.tangent_weight = 1.5
    with pytest.raises(InputError, match=r"tangent_weight must be in \(0, 1\], got 1.5"):
        pack(h, b"")
    h = _header(False)
    h.weight_field = bytes(70000)
    with pytest.raises(InputError, match="density-weight field longer than 65535"):
        pack(h, b"")
    # damaged but correctly sealed headers: unknown flags, a zero tangent weight, an empty field
    h = _header(False)
    tail_off = header_size(3, len(h.coder)) - 12
    data = bytearray(pack(h, b"s"))
    data[5] |= 0x40
    with pytest.raises(BitstreamError, match="unknown flags 0x42"):
        unpack(_reseal(data, tail_off))
    h.tangent_weight = 0.5
    data = bytearray(pack(h, b"s"))
    tail_off = header_size(3, len(h.coder), frames=True) - 12
    data[tail_off - 5:tail_off - 1] = bytes(4)   # the tangent weight, before the anchor count
    with pytest.raises(BitstreamError, match="corrupt header \\(tangent weight 0.0\\)"):
        unpack(_reseal(data, tail_off))
    h = _header(False)
    h.weight_field = b"\x01"
    data = bytearray(pack(h, b"s"))
    tail_off = header_size(3, len(h.coder), field_bytes=1) - 12
    data[tail_off - 3:tail_off] = bytes(3)   # field length 0, and one stray byte
    with pytest.raises(BitstreamError):
        unpack(_reseal(data, tail_off))
    data = bytearray(pack(h, b"s"))
    data = data[:tail_off - 3] + bytearray(2) + data[tail_off:]
    with pytest.raises(BitstreamError, match="empty density-weight field"):
        unpack(_reseal(data, tail_off - 1))


def test_frame_anchors_round_trip_and_are_validated():
    h = _header(False)
    h.tangent_weight, h.anchors = 0.5, (20, 17, 17, 9, 0)
    data = pack(h, b"xyz")
    assert len(data) == header_size(3, len(h.coder), frames=True, anchors=5) + 3
    h2, _ = unpack(data)
    assert h2.anchors == (20, 17, 17, 9, 0)
    h.anchors = (70,)
    with pytest.raises(InputError, match=r"frame anchors must be at most 255 planes in 0..61"):
        pack(h, b"")
    h.anchors = (3,)
    data = bytearray(pack(h, b"s"))
    tail_off = header_size(3, len(h.coder), frames=True, anchors=1) - 12
    data[tail_off - 1] = 99
    with pytest.raises(BitstreamError, match=r"corrupt header \(frame anchors \[99\]\)"):
        unpack(_reseal(data, tail_off))


# ---------------------------------------------------------------------- implausible headers
def _forge(data: bytes, offset: int, fmt: str, *values) -> bytes:
    import struct
    import zlib

    d = bytearray(data)
    struct.pack_into(fmt, d, offset, *values)
    h, stream = unpack(data)
    tail = len(data) - len(stream) - 12
    struct.pack_into("<I", d, tail + 4, zlib.crc32(bytes(d[:tail + 4])))
    return bytes(d)


@pytest.mark.parametrize("offset, fmt, value, match", [
    (8, "<I", 0, r"corrupt header \(0 input surfels\)"),
    (16, "<f", 3.4e38, r"corrupt header \(KLT mean .* beyond ±1e\+12\)"),
    (16 + 24 + 72, "<f", 1e-45, r"corrupt header \(unit weights .* outside \[1e-20, 1e\+20\]\)"),
    (16 + 24 + 72 + 4, "<f", 3e30, r"corrupt header \(unit weights"),
    (16 + 24, "<e", 2.0, r"corrupt header \(KLT basis entries beyond ±1"),
])
def test_implausible_header_values_are_refused(offset, fmt, value, match):
    data = _forge(pack(_header(), bytes(300)), offset, fmt, value)
    with pytest.raises(BitstreamError, match="f.sfz: " + match):
        unpack(data, path="f.sfz")


def test_grid_level_needs_a_file_that_can_justify_it():
    from surfidx.codec.container import min_file_bytes

    assert [min_file_bytes(lv) for lv in (5, 7, 8, 9)] == [6, 81, 321, 1281]
    h = _header()
    h.level = 9
    with pytest.raises(InputError, match="a level-9 container needs at least 1281 bytes"):
        pack(h, bytes(20))
    data = pack(h, bytes(1200))
    assert unpack(data)[0].level == 9
    with pytest.raises(InputError, match="or the 1281 bytes a level-9 container needs"):
        truncate(data, 1000)
    # a small level-5 file that claims level 9
    forged = _forge(pack(_header(), bytes(20)), 6, "<B", 9)
    with pytest.raises(BitstreamError, match=r"corrupt header \(grid level 9 in a file of 157 "
                                             r"bytes; that grid needs at least 1281\)"):
        unpack(forged)


def test_pack_refuses_values_it_would_not_read():
    h = _header()
    h.mean = np.full(6, 1e13)
    with pytest.raises(InputError, match="the KLT values cannot be stored: KLT mean"):
        pack(h, b"")


def test_one_plane_bound_for_anchors_and_zerotree():
    """The container's anchors and the zerotree's planes share one bound."""
    from surfidx.codec import container, zerotree

    assert zerotree.MAX_PLANE is container.MAX_PLANE
    assert container.min_file_bytes(9) == -(-(10 * 4 ** 9 + 2) // container.GRID_PER_BYTE)


@pytest.mark.parametrize("color", [True, False])
def test_mask_section_round_trip(color):
    from surfidx.codec.container import region_code

    h = _header(color)
    h.mask, h.regions = b"\x12\x34\x56", (0, region_code(0, 0), region_code(0, 1))
    h.tangent_weight, h.anchors = 0.5, (3, 2, 1, 1, 0)
    stream = bytes(range(100))
    data = pack(h, stream)
    assert data[4] == 4 and data[5] & 16
    assert len(data) == header_size(h.layers, len(h.coder), frames=True, anchors=5,
                                    mask_bytes=3, regions=3) + len(stream)
    h2, s2 = unpack(data)
    assert (h2.version, h2.mask, h2.regions, s2) == (4, h.mask, h.regions, stream)
    assert h2.tangent_weight == 0.5 and h2.anchors == h.anchors
    cut = truncate(data, len(data) - 40)
    h3, s3 = unpack(cut)
    assert h3.mask == h.mask and h3.regions == h.regions and s3 == stream[:60]


def test_multi_part_container():
    from surfidx.codec.container import (is_multipart, pack_parts, parts_overhead, split_budget,
                                   unpack_parts)

    a = pack(_header(False), bytes(range(200)))
    h = _header(True)
    h.n_surfels = 3 * 1234
    b = pack(h, bytes(range(250)) * 4)
    data = pack_parts([a, b])
    assert is_multipart(data) and not is_multipart(a)
    assert len(data) == parts_overhead(2) + len(a) + len(b) == 8 + 8 + 4 + len(a) + len(b)
    assert unpack_parts(data) == [a, b] and unpack_parts(a) == [a]
    budgets = split_budget(700, [1234, 3 * 1234])
    assert sum(budgets) == 700 - parts_overhead(2) and budgets[1] in (3 * budgets[0],
                                                                     3 * budgets[0] + 1,
                                                                     3 * budgets[0] + 2)
    cut = truncate(data, 700)
    assert len(cut) <= 700
    pa, pb = unpack_parts(cut)
    assert unpack(pa)[1] == unpack(a)[1][:budgets[0] - (len(a) - 200)]
    assert unpack(pb)[1] == unpack(b)[1][:budgets[1] - (len(b) - 1000)]
    assert truncate(data, 10 ** 6) == data
    with pytest.raises(InputError, match="part 0 of 2: a budget of"):
        truncate(data, 100)


def test_random_multi_part_garbage_never_crashes():
    import struct
    import zlib

    from surfidx.codec.container import FLAG_PARTS, unpack_parts

    rng = np.random.default_rng(1)
    for _ in range(200):
        count = int(rng.integers(0, 70000))
        body = rng.bytes(int(rng.integers(0, 400)))
        head = struct.pack("<4sBBH", MAGIC, 4, FLAG_PARTS, count & 0xFFFF)
        data = head + body
        if rng.random() < 0.5 and 8 + 4 * (count & 0xFFFF) <= len(data):
            n = count & 0xFFFF
            data = data[:8 + 4 * n] + struct.pack("<I", zlib.crc32(data[:8 + 4 * n])) + data[
                8 + 4 * n:]
        try:
            for p in unpack_parts(data):
                unpack(p)
        except BitstreamError:
            pass
