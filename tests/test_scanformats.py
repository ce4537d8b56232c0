"""Scanner formats: LAS/LAZ (laspy + lazrs) and E57 (pye57), their colour and intensity, scan
poses and invalid points, and hostile files (truncated, absurd counts, foreign files)."""

from __future__ import annotations

import re
import struct
import subprocess
import sys

import numpy as np
import pytest

from surfidx import FileFormatError, InputError, read_surfels

laspy = pytest.importorskip("laspy")
pye57 = pytest.importorskip("pye57")
libe57 = pye57.libe57


def _ball(n=200, seed=0):
    """``n`` points on the unit sphere (a cloud the surfel conversion accepts)."""
    v = np.random.default_rng(seed).normal(size=(n, 3))
    return v / np.linalg.norm(v, axis=1)[:, None]


def _las(path, *, point_format=3, version="1.2", n=200, rgb=None, intensity=None,
         scale=1e-3, offset=(1000.0, -2000.0, 50.0)):
    """A LAS/LAZ (by suffix) of a ball of radius 5 around ``offset``; returns the records'
    expected positions (the stored integers times the scale plus the offset)."""
    h = laspy.LasHeader(point_format=point_format, version=version)
    h.scales = [scale] * 3
    h.offsets = list(offset)
    las = laspy.LasData(h)
    p = 5 * _ball(n) + offset
    las.x, las.y, las.z = p[:, 0], p[:, 1], p[:, 2]
    if rgb is not None:
        las.red, las.green, las.blue = rgb[:, 0], rgb[:, 1], rgb[:, 2]
    if intensity is not None:
        las.intensity = intensity
    las.write(str(path))
    return np.stack([las.X * scale + offset[0], las.Y * scale + offset[1],
                     las.Z * scale + offset[2]], axis=1)


def _rgb8(n=200):
    return np.stack([np.arange(n) % 256, np.full(n, 7), 255 - np.arange(n) % 256], axis=1)


def test_las_and_laz_positions_scale_offset_and_16_bit_colour(tmp_path):
    c8 = _rgb8()
    for suffix in (".las", ".laz"):
        for pf, version in ((3, "1.2"), (2, "1.2"), (7, "1.4"), (8, "1.4")):
            path = tmp_path / f"c{pf}{suffix}"
            expect = _las(path, point_format=pf, version=version, rgb=c8 * 257)
            s = read_surfels(path)
            assert len(s) == 200 and np.array_equal(s.positions, expect)
            assert np.array_equal(s.colors, c8)
    path = tmp_path / "shifted.las"             # colour written as value * 256: the same bytes
    _las(path, rgb=c8 * 256)
    assert np.array_equal(read_surfels(path).colors, c8)
    path = tmp_path / "eight.laz"               # 8-bit colour in the 16-bit fields: kept
    _las(path, rgb=c8)
    assert np.array_equal(read_surfels(path).colors, c8)


def test_las_intensity_is_grey_without_colour(tmp_path):
    n = 200
    for pf, version in ((1, "1.2"), (6, "1.4")):
        path = tmp_path / f"i{pf}.las"
        _las(path, point_format=pf, version=version, intensity=np.arange(n) * 20)   # 12-bit
        grey = np.round(np.arange(n) * 20 * 255 / 4095).astype(np.uint8)
        assert np.array_equal(read_surfels(path).colors, np.repeat(grey[:, None], 3, 1))
    _las(tmp_path / "i8.laz", point_format=0, intensity=np.arange(n))          # 8-bit
    assert np.array_equal(read_surfels(tmp_path / "i8.laz").colors[:, 0], np.arange(n))
    _las(tmp_path / "i16.las", point_format=0, intensity=np.arange(n) * 300)   # 16-bit
    assert read_surfels(tmp_path / "i16.las").colors[-1, 0] == round(199 * 300 * 255 / 65535)
    _las(tmp_path / "none.las", point_format=1)                  # no intensity: no colour
    assert read_surfels(tmp_path / "none.las").colors is None
    _las(tmp_path / "zero.las", point_format=3, rgb=np.zeros((n, 3), int),
         intensity=np.full(n, 255))                              # RGB all zero: intensity
    assert np.all(read_surfels(tmp_path / "zero.las").colors == 255)


def _patch(path, offset, fmt, *values):
    data = bytearray(path.read_bytes())
    struct.pack_into(fmt, data, offset, *values)
    path.write_bytes(bytes(data))


def test_hostile_las_and_laz(tmp_path):
    las, laz = tmp_path / "a.las", tmp_path / "a.laz"
    _las(las, rgb=_rgb8() * 257)
    _las(laz, rgb=_rgb8() * 257)
    for src in (las, laz):
        cut = tmp_path / f"cut{src.suffix}"
        cut.write_bytes(src.read_bytes()[:len(src.read_bytes()) * 2 // 3])
        with pytest.raises(FileFormatError, match=f"cut{src.suffix}: .*(more than the .* bytes "
                                                  "of point data hold|cannot be read).*truncated"):
            read_surfels(cut)
    big = tmp_path / "big.las"                       # 10^12 points in a LAS 1.4 header
    _las(big, point_format=6, version="1.4")
    _patch(big, 247, "<Q", 10 ** 12)
    with pytest.raises(FileFormatError, match=r"big.las: LAS header announces "
                                              r"1,000,000,000,000 points of 30 bytes"):
        read_surfels(big)
    bigz = tmp_path / "big.laz"
    bigz.write_bytes(laz.read_bytes())
    _patch(bigz, 107, "<I", 4_000_000_000)
    with pytest.raises(FileFormatError, match=r"big.laz: LAZ header announces 4,000,000,000 "
                                              r"points, more than 256 a byte of its [\d,]+ "
                                              r"compressed bytes; the header is damaged"):
        read_surfels(bigz)
    fewer = tmp_path / "fewer.las"                   # a count below the data: warned
    fewer.write_bytes(las.read_bytes())
    _patch(fewer, 107, "<I", 150)
    with pytest.warns(UserWarning, match="fewer.las: 50 point records follow the 150 the LAS "
                                         "header announces; they are not read"):
        assert len(read_surfels(fewer)) == 150
    (tmp_path / "text.las").write_text("x y z\n0 0 0\n" * 30)
    with pytest.raises(FileFormatError, match="text.las: not a LAS/LAZ file .*LASF signature"):
        read_surfels(tmp_path / "text.las")
    short14 = tmp_path / "short14.las"
    _las(short14, point_format=6, version="1.4")
    short14.write_bytes(short14.read_bytes()[:300])
    with pytest.raises(FileFormatError, match="short14.las: LAS 1.4 header is truncated "
                                              r"\(300 of 375 bytes\)"):
        read_surfels(short14)
    (tmp_path / "short.las").write_bytes(b"LASF" + b"\0" * 100)
    with pytest.raises(FileFormatError, match="short.las: LAS header is truncated"):
        read_surfels(tmp_path / "short.las")
    v2 = tmp_path / "v2.las"
    v2.write_bytes(las.read_bytes())
    _patch(v2, 24, "<BB", 2, 0)
    with pytest.raises(FileFormatError, match="LAS version 2.0 is not supported"):
        read_surfels(v2)
    off = tmp_path / "off.las"
    off.write_bytes(las.read_bytes())
    _patch(off, 96, "<I", 10 ** 9)
    with pytest.raises(FileFormatError, match="point data offset 1,000,000,000 do not fit"):
        read_surfels(off)
    vlrs = tmp_path / "vlrs.laz"                     # the LASzip VLR's length past the points
    vlrs.write_bytes(laz.read_bytes())
    _patch(vlrs, 100, "<I", 4_000_000_000)
    with pytest.raises(FileFormatError, match="announces 4,000,000,000 variable-length records; "
                                              "record 1 runs past"):
        read_surfels(vlrs)
    head = struct.unpack_from("<H", laz.read_bytes(), 94)[0]
    _patch(vlrs, 100, "<I", 1)
    _patch(vlrs, head + 20, "<H", 60000)
    with pytest.raises(FileFormatError, match="announces 1 variable-length records; the last "
                                              "runs past"):
        read_surfels(vlrs)
    ev = tmp_path / "ev.las"                         # an extended record of 2^60 bytes
    _las(ev, point_format=6, version="1.4")
    data = ev.read_bytes()
    ev.write_bytes(data + struct.pack("<H16sHQ32s", 0, b"x", 1, 2 ** 60, b""))
    _patch(ev, 235, "<QI", len(data), 1)
    with pytest.raises(FileFormatError, match="ev.las: LAS header announces 1 extended records; "
                                              "the last runs past"):
        read_surfels(ev)
    _patch(ev, 235, "<QI", 10 ** 15, 1)
    with pytest.raises(FileFormatError, match="extended records at byte 1,000,000,000,000,000, "
                                              "outside the file"):
        read_surfels(ev)
    _patch(ev, 235, "<QI", len(data), 5)
    with pytest.raises(FileFormatError, match="announces 5 extended records; record 1 runs"):
        read_surfels(ev)
    for name, off, fmt, value, msg in (
            ("fmt", 104, "<B", 99, "LAS point data format 99 is not one of 0 to 10"),
            ("rec", 105, "<H", 20, "LAS point records of 20 bytes are shorter than point data "
                                   "format 3's 34")):
        bad = tmp_path / f"{name}.las"
        bad.write_bytes(las.read_bytes())
        _patch(bad, off, fmt, value)
        with pytest.raises(FileFormatError, match=f"{name}.las: {msg}"):
            read_surfels(bad)
    empty = tmp_path / "empty.las"
    _las(empty, n=0)
    with pytest.raises(FileFormatError, match="empty.las: LAS file holds no points"):
        read_surfels(empty)


def test_hostile_laz_chunk_table_and_layers(tmp_path):
    """lazrs reserves an entry per chunk the table lists and a buffer per layer size a chunk
    announces, and panics on some damaged data: refused before it reads, or caught."""
    src = tmp_path / "src.laz"
    _las(src, point_format=7, version="1.4", rgb=_rgb8() * 257)
    data = src.read_bytes()
    head, offset = struct.unpack_from("<HI", data, 94)
    laszip = head + 54                               # the LASzip record's data
    table = struct.unpack_from("<q", data, offset)[0]
    cases = (
        ("chunks", table + 4, "<I", 4_000_000_000, "LAZ chunk table lists 4,000,000,000 "
                                                   "chunks, more than the"),
        ("zero", laszip + 12, "<I", 0, "LAZ file.s LASzip record gives chunks of 0 points"),
        ("few", laszip + 12, "<I", 10, "LAZ chunk table lists 1 chunks of 10 points, fewer "
                                       "than the 200 points"),
        ("short", head + 20, "<H", 20, "LAZ file's LASzip record is 20 bytes, shorter than "
                                       "the 34"),
        ("offset", 96, "<I", len(data) - 4, "LAZ point data is shorter than its 8-byte chunk "
                                            "table offset"),
        ("items", laszip + 40, "<H", 10, "LAZ chunk 0's layers announce [\\d,]+ bytes, more "
                                         "than the 1,855 left"),
        ("layer", offset + 8 + 36 + 4, "<I", 4_000_000_000, "LAZ chunk 0's layers announce "
                                                            "4,000,001,045 bytes"),
        ("empty", offset + 8 + 36, "<I", 0, "LAZ chunk 0 holds no points"),
        ("more", 247, "<Q", 250, "LAZ chunk 1 runs past byte"))
    for name, off, fmt, value, msg in cases:
        bad = tmp_path / f"{name}.laz"
        bad.write_bytes(data)
        _patch(bad, off, fmt, value)
        with pytest.raises(FileFormatError, match=f"{name}.laz: {msg}"):
            read_surfels(bad)
    class PanicException(BaseException):             # what lazrs raises when it panics
        pass

    def panic(self, n):
        raise PanicException("mid > len")
        yield

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(laspy.LasReader, "chunk_iterator", panic)
        with pytest.raises(FileFormatError, match="src.laz: LAZ points cannot be decompressed "
                                                  r"\(mid > len\); the file is damaged"):
            read_surfels(src)
    three = tmp_path / "three.laz"                   # layered chunks walked one by one
    _las(three, point_format=6, version="1.4", n=120_000, intensity=np.arange(120_000) % 256)
    assert len(read_surfels(three)) == 120_000
    moved = tmp_path / "moved.laz"                   # the table's offset at the end instead
    moved.write_bytes(data + struct.pack("<q", table))
    _patch(moved, offset, "<q", -1)
    assert len(read_surfels(moved)) == 200


def test_las_that_shrinks_while_read(tmp_path, monkeypatch):
    """laspy returns what it could read of a file that shrank after its header was checked
    (it logs the shortfall): the count is compared, and laspy's log goes nowhere else."""
    path = tmp_path / "shrunk.las"
    _las(path, rgb=_rgb8() * 257)

    def short(self, n):
        laspy.lasreader.logger.error("Could only read 150 of the requested 200 points")
        yield self.read_points(150)

    monkeypatch.setattr(laspy.LasReader, "chunk_iterator", short)
    with pytest.raises(FileFormatError, match="shrunk.las: LAS header announces 200 points and "
                                              "the file holds 150"):
        read_surfels(path)

    def chatty(self, n):
        laspy.lasreader.logger.warning("a VLR it cannot parse")
        yield self.read_points(n)

    monkeypatch.setattr(laspy.LasReader, "chunk_iterator", chatty)
    with pytest.warns(UserWarning, match="shrunk.las: laspy: a VLR it cannot parse"):
        assert len(read_surfels(path)) == 200


def test_las_nan_and_huge_coordinates(tmp_path):
    path = tmp_path / "nan.las"
    _las(path)
    _patch(path, 131, "<d", float("nan"))            # the x scale
    with pytest.raises(InputError, match="nan.las: points contains 200 NaN"):
        read_surfels(path)
    _patch(path, 131, "<d", 1e28)
    with pytest.raises(InputError, match="nan.las: .* vertices have coordinates beyond ±1e\\+30"):
        read_surfels(path)


def test_missing_extra_is_named(tmp_path, monkeypatch):
    _las(tmp_path / "a.laz")
    _e57(tmp_path / "a.e57", [{"xyz": 5 * _ball(20)}])
    monkeypatch.setitem(sys.modules, "lazrs", None)
    with pytest.raises(FileFormatError, match=r"a.laz: reading LAZ needs laspy's lazrs backend; "
                                              r"install it with pip install 'surfidx\[scanners\]'"):
        read_surfels(tmp_path / "a.laz")
    monkeypatch.setitem(sys.modules, "laspy", None)
    with pytest.raises(FileFormatError, match=r"reading LAS/LAZ needs laspy; .*surfidx\[scanners"):
        read_surfels(tmp_path / "a.laz")
    monkeypatch.setitem(sys.modules, "pye57", None)
    with pytest.raises(FileFormatError, match=r"a.e57: reading E57 needs pye57; .*\[scanners"):
        read_surfels(tmp_path / "a.e57")


# --- E57 -------------------------------------------------------------------------------------

def _e57(path, scans, *, images=False):
    """An E57 of ``scans``, written with libE57 so every field, range and limit can be chosen.

    A scan is a dict: ``xyz`` (n, 3) or ``rae`` (n, 3) spherical; optional ``rgb`` (n, 3) with
    ``rgb_range`` (default 0..255) and ``color_limits``; ``intensity`` (n,) float with
    ``intensity_limits``; ``invalid`` (n,) int; ``color_invalid`` (n,) int; ``pose``
    ``(w, x, y, z), (tx, ty, tz)`` (a string entry is written as a string node; a string pose
    as a string node in its place). Coordinates are doubles.
    """
    e = pye57.E57(str(path), mode="w")
    imf = e.image_file
    for i, sc in enumerate(scans):
        node = libe57.StructureNode(imf)
        node.set("guid", libe57.StringNode(imf, f"{{scan-{i}}}"))
        proto = libe57.StructureNode(imf)
        data = {}
        if "rae" in sc:
            names = ("sphericalRange", "sphericalAzimuth", "sphericalElevation")
            cols = sc["rae"]
        else:
            names = ("cartesianX", "cartesianY", "cartesianZ")
            cols = sc["xyz"]
        for k, name in enumerate(names):
            proto.set(name, libe57.FloatNode(imf, 0.0, libe57.E57_DOUBLE))
            data[name] = np.ascontiguousarray(cols[:, k], np.float64)
        if "intensity" in sc:
            proto.set("intensity", libe57.FloatNode(imf, 0.0, libe57.E57_DOUBLE))
            data["intensity"] = np.asarray(sc["intensity"], np.float64)
            if "intensity_limits" in sc:
                lim = libe57.StructureNode(imf)
                lim.set("intensityMinimum", libe57.FloatNode(imf, sc["intensity_limits"][0]))
                lim.set("intensityMaximum", libe57.FloatNode(imf, sc["intensity_limits"][1]))
                node.set("intensityLimits", lim)
        if "rgb" in sc:
            lo, hi = sc.get("rgb_range", (0, 255))
            for k, name in enumerate(("colorRed", "colorGreen", "colorBlue")):
                proto.set(name, libe57.IntegerNode(imf, lo, lo, hi))
                data[name] = np.ascontiguousarray(sc["rgb"][:, k], np.float64)
            if "color_limits" in sc:
                lim = libe57.StructureNode(imf)
                for name in ("colorRed", "colorGreen", "colorBlue"):
                    lim.set(name + "Minimum", libe57.IntegerNode(imf, sc["color_limits"][0]))
                    lim.set(name + "Maximum", libe57.IntegerNode(imf, sc["color_limits"][1]))
                node.set("colorLimits", lim)
        for key, name in (("invalid", "cartesianInvalidState" if "xyz" in sc else
                           "sphericalInvalidState"), ("color_invalid", "isColorInvalid")):
            if key in sc:
                proto.set(name, libe57.IntegerNode(imf, 0, 0, 2))
                data[name] = np.asarray(sc[key], np.float64)
        if isinstance(sc.get("pose"), str):
            node.set("pose", libe57.StringNode(imf, sc["pose"]))
        elif "pose" in sc:
            (w, x, y, z), t = sc["pose"]
            pose, rot, tr = (libe57.StructureNode(imf) for _ in range(3))
            for k, v in zip("wxyz", (w, x, y, z)):
                rot.set(k, libe57.StringNode(imf, v) if isinstance(v, str)
                        else libe57.FloatNode(imf, float(v)))
            for k, v in zip("xyz", t):
                tr.set(k, libe57.FloatNode(imf, float(v)))
            pose.set("rotation", rot)
            pose.set("translation", tr)
            node.set("pose", pose)
        points = libe57.CompressedVectorNode(imf, proto, libe57.VectorNode(imf, True))
        node.set("points", points)
        e.data3d.append(node)
        n = len(cols)
        buffers = libe57.VectorSourceDestBuffer()
        for name, arr in data.items():
            buffers.append(libe57.SourceDestBuffer(imf, name, arr, n, True, True))
        if n:
            writer = points.writer(buffers)
            writer.write(n)
            writer.close()
    if images:
        e.root["images2D"].append(libe57.StructureNode(imf))
    e.close()


def _crc32c(data: bytes) -> int:
    table = []
    for i in range(256):
        c = i
        for _ in range(8):
            c = (c >> 1) ^ 0x82F63B78 if c & 1 else c >> 1
        table.append(c)
    crc = 0xFFFFFFFF
    for b in data:
        crc = table[(crc ^ b) & 0xFF] ^ (crc >> 8)
    return crc ^ 0xFFFFFFFF


def _edit_e57_xml(path, old: bytes, new: bytes):
    """Replace ``old`` by ``new`` in an E57's XML, keeping its length (indentation spaces
    taken out or added), and rewrite the pages' CRC-32C checksums."""
    data = bytearray(path.read_bytes())
    logical = bytearray(b"".join(data[i:i + 1020] for i in range(0, len(data), 1024)))
    grow = len(new) - len(old)
    at = logical.index(old)
    logical[at:at + len(old)] = new
    pad = logical.index(b"\n" + b" " * 10, at)        # an indented line after it
    if grow > 0:
        del logical[pad + 1:pad + 1 + grow]
    else:
        logical[pad + 1:pad + 1] = b" " * -grow
    for k, i in enumerate(range(0, len(data), 1024)):
        page = bytes(logical[k * 1020:(k + 1) * 1020])
        data[i:i + 1020] = page
        data[i + 1020:i + 1024] = struct.pack(">I", _crc32c(page))
    path.write_bytes(bytes(data))


def _rot_z90(p):
    return np.stack([-p[:, 1], p[:, 0], p[:, 2]], axis=1)


def test_e57_scans_poses_colour_and_invalid_points(tmp_path):
    a, b = 4 * _ball(60, seed=1), 4 * _ball(50, seed=2)
    ca = np.stack([np.arange(60) * 4, np.full(60, 9), np.full(60, 250)], axis=1)
    cb = np.stack([np.full(50, 1), np.arange(50) * 5, np.full(50, 2)], axis=1)
    invalid = np.zeros(60, int)
    invalid[7] = 2
    h = np.sqrt(0.5)
    path = tmp_path / "two.e57"
    _e57(path, [{"xyz": a, "rgb": ca, "invalid": invalid, "pose": ((h, 0, 0, h), (10, 20, 30))},
                {"xyz": b, "rgb": cb, "pose": ((1, 0, 0, 0), (0, 0, -5))}])
    with pytest.warns(UserWarning, match="two.e57: skipped 1 of 110 points marked invalid"):
        s = read_surfels(path)
    keep = invalid == 0
    expect = np.concatenate([_rot_z90(a[keep]) + [10, 20, 30], b + [0, 0, -5]])
    assert len(s) == 109
    np.testing.assert_allclose(s.positions, expect, rtol=0, atol=1e-12)
    assert np.array_equal(s.colors, np.concatenate([ca[keep], cb]))


def test_e57_colour_limits_intensity_and_spherical(tmp_path):
    p = 3 * _ball(40)
    c16 = np.stack([np.arange(40) * 1000, np.full(40, 65535), np.zeros(40)], axis=1)
    path = tmp_path / "c16.e57"                      # 16-bit colour, limits from the fields
    _e57(path, [{"xyz": p, "rgb": c16, "rgb_range": (0, 65535)}])
    s = read_surfels(path)
    assert np.array_equal(s.colors, np.round(c16 * 255 / 65535).astype(np.uint8))
    _e57(path, [{"xyz": p, "rgb": c16, "rgb_range": (0, 65535), "color_limits": (0, 40000)}])
    with pytest.warns(UserWarning, match="c16.e57: 40 points with colour outside its limits "
                                         "0..40000, 0..40000, 0..40000 clipped"):
        s = read_surfels(path)
    assert s.colors[:, 1].tolist() == [255] * 40 and s.colors[10, 0] == round(10000 * 255 / 4e4)
    inten = np.linspace(0.25, 0.75, 40)
    path = tmp_path / "grey.e57"
    _e57(path, [{"xyz": p, "intensity": inten, "intensity_limits": (0.0, 1.0)}])
    grey = np.round(inten * 255).astype(np.uint8)
    assert np.array_equal(read_surfels(path).colors, np.repeat(grey[:, None], 3, 1))
    _e57(path, [{"xyz": p, "intensity": inten}])     # no limits: the scan's own range
    assert read_surfels(path).colors[[0, -1], 0].tolist() == [0, 255]
    r = np.linalg.norm(p, axis=1)
    rae = np.stack([r, np.arctan2(p[:, 1], p[:, 0]), np.arcsin(p[:, 2] / r)], axis=1)
    path = tmp_path / "sph.e57"
    _e57(path, [{"rae": rae, "invalid": [0] * 39 + [1]}])
    with pytest.warns(UserWarning, match="skipped 1 of 40"):
        np.testing.assert_allclose(read_surfels(path).positions, p[:39], atol=1e-12)


def test_e57_mixed_scans_flags_and_images(tmp_path):
    p, q = 3 * _ball(40, seed=3), 3 * _ball(30, seed=4) + 10
    rgb = np.full((40, 3), 200)
    path = tmp_path / "mix.e57"
    flags = np.zeros(40, int)
    flags[:3] = 1
    _e57(path, [{"xyz": p, "rgb": rgb, "color_invalid": flags}, {"xyz": q},
                {"xyz": np.empty((0, 3))}], images=True)
    with pytest.warns(UserWarning) as rec:
        s = read_surfels(path)
    said = " | ".join(str(w.message) for w in rec)
    assert "mix.e57: 3 points flagged isColorInvalid coloured grey" in said
    assert "mix.e57: scans 1 have neither colour nor intensity; their points are grey" in said
    assert "mix.e57: its 1 2D image not read" in said
    assert len(s) == 70 and np.all(s.colors[3:40] == 200) and np.all(s.colors[:3] == 128)
    assert np.all(s.colors[40:] == 128)


def test_hostile_e57(tmp_path):
    good = tmp_path / "good.e57"
    _e57(good, [{"xyz": 2 * _ball(300)}])
    data = good.read_bytes()
    cut = tmp_path / "cut.e57"
    cut.write_bytes(data[:len(data) // 2])
    with pytest.raises(FileFormatError, match=r"cut.e57: E57 header gives a length of "
                                              r"[\d,]+ bytes and the file has [\d,]+; it is "
                                              "truncated"):
        read_surfels(cut)
    (tmp_path / "text.e57").write_text("x y z\n" * 100)
    with pytest.raises(FileFormatError, match="text.e57: not an E57 file"):
        read_surfels(tmp_path / "text.e57")
    (tmp_path / "short.e57").write_bytes(b"ASTM-E57\1\0")
    with pytest.raises(FileFormatError, match="short.e57: E57 header is truncated"):
        read_surfels(tmp_path / "short.e57")
    for name, fmt, off, value, msg in (
            ("v2", "<I", 8, 2, "E57 version 2 is not supported"),
            ("page", "<Q", 40, 512, "E57 header gives a page size of 512 bytes"),
            ("xml", "<Q", 24, 10 ** 12, "E57 header puts its XML section .* outside the file")):
        bad = tmp_path / f"{name}.e57"
        bad.write_bytes(data)
        _patch(bad, off, fmt, value)
        with pytest.raises(FileFormatError, match=f"{name}.e57: {msg}"):
            read_surfels(bad)
    odd = tmp_path / "odd.e57"
    odd.write_bytes(data[:-1])
    _patch(odd, 16, "<Q", len(data) - 1)
    with pytest.raises(FileFormatError, match="odd.e57: E57 file of [\\d,]+ bytes is not a whole "
                                              "number of 1024-byte pages"):
        read_surfels(odd)
    # a damaged page, found by libE57's checksums: in the XML (opening fails) or in the
    # points (reading fails)
    xml_at = struct.unpack_from("<Q", data, 24)[0]
    for name, at in (("flipxml", xml_at + 10), ("flippoints", 2148)):
        flip = tmp_path / f"{name}.e57"
        flip.write_bytes(data[:at] + bytes([data[at] ^ 0xFF]) + data[at + 1:])
        with pytest.raises(FileFormatError, match=f"{name}.e57: E57 file cannot be read "
                                                  r"\(checksum mismatch"):
            read_surfels(flip)
    huge = tmp_path / "huge.e57"
    huge.write_bytes(data)
    _edit_e57_xml(huge, b'recordCount="300"', b'recordCount="1000000000000"')
    with pytest.raises(FileFormatError, match="huge.e57: E57 scan 0 announces "
                                              "1,000,000,000,000 points of 192 bits, more than"):
        read_surfels(huge)
    less = tmp_path / "less.e57"
    less.write_bytes(data)
    _edit_e57_xml(less, b'recordCount="300"', b'recordCount="301"')
    with pytest.raises(FileFormatError, match="less.e57: E57 scan 0 announces 301 points and "
                                              "holds 300"):
        read_surfels(less)
    empty = tmp_path / "empty.e57"
    _e57(empty, [])
    with pytest.raises(FileFormatError, match="empty.e57: E57 file holds no 3D scans"):
        read_surfels(empty)
    _e57(empty, [{"xyz": np.empty((0, 3))}])
    with pytest.raises(FileFormatError, match="empty.e57: E57 file's scans hold no points"):
        read_surfels(empty)
    dead = tmp_path / "dead.e57"
    _e57(dead, [{"xyz": _ball(10), "invalid": [2] * 10}])
    with pytest.raises(FileFormatError, match="dead.e57: E57 file holds no valid points"), \
            pytest.warns(UserWarning, match="skipped 10 of 10"):
        read_surfels(dead)
    zero = tmp_path / "zero.e57"
    _e57(zero, [{"xyz": _ball(10), "pose": ((0, 0, 0, 0), (0, 0, 0))}])
    with pytest.raises(FileFormatError, match="zero.e57: E57 scan 0's pose rotation .* is not "
                                              "a rotation quaternion"):
        read_surfels(zero)
    nan = tmp_path / "nan.e57"
    p = _ball(10)
    p[4, 1] = np.nan
    _e57(nan, [{"xyz": p}])
    with pytest.raises(InputError, match="nan.e57: points contains 1 NaN"):
        read_surfels(nan)
    _e57(nan, [{"xyz": _ball(10) * 1e31}])
    with pytest.raises(InputError, match="nan.e57: 10 vertices have coordinates beyond"):
        read_surfels(nan)


def _odd_e57(path, build):
    """An E57 with one scan whose nodes ``build(imf, scan)`` sets."""
    e = pye57.E57(str(path), mode="w")
    imf = e.image_file
    node = libe57.StructureNode(imf)
    node.set("guid", libe57.StringNode(imf, "{odd}"))
    build(imf, node)
    e.data3d.append(node)
    e.close()


def test_e57_with_damaged_structure(tmp_path):
    def no_coordinates(imf, node):
        proto = libe57.StructureNode(imf)
        proto.set("intensity", libe57.FloatNode(imf, 0.0))
        node.set("points", libe57.CompressedVectorNode(imf, proto, libe57.VectorNode(imf, True)))

    path = tmp_path / "odd.e57"
    _odd_e57(path, no_coordinates)
    with pytest.raises(FileFormatError, match="odd.e57: E57 scan 0 has neither cartesianX/Y/Z "
                                              "nor sphericalRange"):
        read_surfels(path)
    _odd_e57(path, lambda imf, node: node.set("points", libe57.StringNode(imf, "none")))
    with pytest.raises(FileFormatError, match="odd.e57: E57 scan 0 has no point records"):
        read_surfels(path)
    _e57(path, [{"xyz": _ball(10), "pose": "upright"}])
    with pytest.raises(FileFormatError, match="odd.e57: E57 scan 0's pose is not a structure"):
        read_surfels(path)
    _e57(path, [{"xyz": _ball(10), "pose": (("w", 0, 0, 0), (0, 0, 0))}])
    with pytest.raises(FileFormatError, match="odd.e57: E57 scan 0's pose rotation w is not a "
                                              "number"):
        read_surfels(path)


def test_e57_colour_or_intensity_without_range_is_said(tmp_path):
    path = tmp_path / "flat.e57"
    _e57(path, [{"xyz": _ball(20), "rgb": np.full((20, 3), 9), "color_limits": (5, 5),
                 "intensity": np.full(20, 0.5)}])
    with pytest.warns(UserWarning) as rec:
        assert read_surfels(path).colors is None
    said = " | ".join(str(w.message) for w in rec)
    assert "flat.e57: scan 0's colour limits are empty or not finite; its colour is not used" \
        in said
    assert "scan 0's intensity has an empty or non-finite range; it is not used as grey" in said


# --- discovery, command line, import cost -----------------------------------------------------

def test_cli_info_and_ingest_of_scanner_files(tmp_path):
    import ingest
    from click.testing import CliRunner

    from surfidx import Database
    from surfidx.cli import cli

    _las(tmp_path / "one.las", rgb=_rgb8() * 257)
    r = CliRunner().invoke(cli, ["info", str(tmp_path / "one.las"), "--json"])
    assert r.exit_code == 0, r.output
    assert '"surfels": 200' in r.output and '"color": true' in r.output
    folder = tmp_path / "scans"
    (folder / "sub").mkdir(parents=True)
    _las(folder / "sub" / "ball.laz", rgb=_rgb8() * 257)
    (folder / "b.LAS").write_bytes((tmp_path / "one.las").read_bytes())
    _e57(folder / "c.e57", [{"xyz": _ball(30)}])
    found = sorted(p.name for p in ingest.discover([folder]))
    assert found == ["b.LAS", "ball.laz", "c.e57"]
    (folder / "b.LAS").unlink()
    (folder / "c.e57").unlink()
    db = tmp_path / "s.db"
    r = CliRunner().invoke(cli, ["ingest", str(folder), "--db", str(db)])
    assert r.exit_code == 0, r.output
    assert "stored 1, skipped 0, failed 0" in r.output
    with Database(db) as d:
        (row,) = d.list_models()
        assert row["name"] == "ball" and row["n_surfels"] == 200 and row["has_color"]


def test_import_surfidx_io_loads_no_scanner_library():
    code = ("import sys, surfidx.io.registry; "
            "print(sorted({'laspy', 'lazrs', 'pye57'} & set(sys.modules)))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True, timeout=120).stdout
    assert out.strip() == "[]"


def test_las_record_layout_matches_laspy(tmp_path):
    """The header offsets the size checks read are the ones laspy writes."""
    path = tmp_path / "h.las"
    _las(path, point_format=7, version="1.4", n=33)
    data = path.read_bytes()
    hs, offset, n_vlrs, fmt, record = struct.unpack_from("<HIIBH", data, 94)
    assert (hs, fmt, record) == (375, 7, 36)
    assert struct.unpack_from("<Q", data, 247)[0] == 33
    assert len(data) == offset + 33 * record
    assert re.match(rb"LASF", data)
